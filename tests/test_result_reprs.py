"""Every public result type has a short ``repr``: shapes and key numbers, never a whole array (< 300 characters per
line, a few lines at most), built on small data."""

from __future__ import annotations

import numpy as np
import pytest

from vpr_uncertainty import Retrieval, compare, evaluate, threshold_at_precision
from vpr_uncertainty.calibration import Calibrator
from vpr_uncertainty.evaluation.metrics import rank_queries, rejection_curve
from vpr_uncertainty.geometric.verify import Reranking, VerificationResult
from vpr_uncertainty.pipeline.evaluate import Evaluated
from vpr_uncertainty.pipeline.retrieve import Retrieved


def _retrieval(n_queries: int = 500) -> Retrieval:
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((n_queries, 10)), axis=1)
    indices = np.array([rng.permutation(50)[:10] for _ in range(n_queries)])
    positives = [[int(indices[q, 0])] if q % 3 else [int(indices[q, 4])] for q in range(n_queries)]
    return Retrieval(scores=scores, indices=indices, positives=positives)


def _results(tmp_path):
    retrieval = _retrieval()
    evaluation = evaluate(retrieval, ["SU", "BM"], k=10, timing_repeats=1)
    su = evaluation.methods["SU"].uncertainty
    correct = evaluation.correct
    big = np.arange(2000, dtype=np.int64)
    yield "Retrieval", retrieval, 1
    yield "Evaluation", evaluation, 4
    yield "MethodEvaluation", evaluation.methods["SU"], 1
    yield "RejectionCurve", rejection_curve(correct, su), 1
    yield "UncertaintyRanking", rank_queries(correct, su), 1
    yield "ThresholdChoice", threshold_at_precision(su, correct, 0.8), 1
    yield "Comparison", compare(evaluation, evaluation), 8
    yield "Calibrator", Calibrator(model="isotonic", features=("SU",), x=list(range(500)), y=[0.5] * 500), 1
    verification = VerificationResult(inliers=big, matches=big)
    yield "VerificationResult", verification, 1
    yield "Reranking", Reranking(indices=big.reshape(200, 10), inliers=big, verification=verification, recall={}), 1
    yield "Evaluated", Evaluated(evaluation=evaluation, fingerprint="f" * 64, path=tmp_path / "u.npz"), 1
    yield "Retrieved", Retrieved(path=tmp_path / "r.npz", retrieval=retrieval, fingerprint="f" * 64), 1


def test_reprs_are_short_and_print_no_array(tmp_path):
    for name, result, max_lines in _results(tmp_path):
        text = repr(result)
        lines = text.splitlines()
        assert text.startswith(name) or name == "Comparison", text  # Comparison: its readable table
        assert len(lines) <= max_lines, text
        assert all(len(line) < 300 for line in lines), text
        assert "array(" not in text and "[[" not in text, text  # no numpy print of an array


@pytest.mark.parametrize("calibrated", [True])
def test_gate_repr_is_short(calibrated):
    from vpr_uncertainty import calibrate

    gate = calibrate(_retrieval(300), target_precision=0.5)
    text = repr(gate)
    assert len(text.splitlines()) <= 3 and all(len(line) < 300 for line in text.splitlines()), text
