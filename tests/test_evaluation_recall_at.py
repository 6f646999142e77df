"""recall@N for any N: ``evaluate(..., recall_at=)``, ``evaluate --recall-at``; an N above the candidates retrieved is
None with a warning and a note (never dropped or capped silently), exact when the candidates cover the database."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from vpr_uncertainty import Retrieval, cli, evaluate, read_results, save_retrieval
from vpr_uncertainty.evaluation import Evaluation, FewerCandidatesWarning, recall_at_n


def _reference_recall(indices, mask, n):
    """Slow and obvious: loop over answerable queries and their first n candidates."""
    hits, answerable = 0, 0
    for row, positives in zip(indices, mask, strict=True):
        if not positives.any():
            continue
        answerable += 1
        hits += any(0 <= index and positives[index] for index in row[:n])
    return hits / answerable


@pytest.mark.parametrize("seed", range(5))
def test_recall_at_n_equals_a_loop_and_n_above_k_is_none(seed):
    rng = np.random.default_rng(seed)
    n_queries, n_database, k = 40, 30, 8
    indices = np.array([rng.permutation(n_database)[:k] for _ in range(n_queries)])
    mask = rng.random((n_queries, n_database)) < 0.05
    mask[0, indices[0, 0]] = True  # at least one answerable query
    ns = (1, 2, 3, 5, 8, 9, 100)
    with pytest.warns(FewerCandidatesWarning, match=r"recall@9, recall@100 need 100 candidates .* holds 8"):
        found = recall_at_n(indices, mask, ns)
    assert list(found) == list(ns)
    for n in ns:
        assert found[n] == (None if n > k else pytest.approx(_reference_recall(indices, mask, n), rel=1e-12))


def test_candidates_covering_the_database_answer_every_n_exactly():
    indices = np.array([[2, 0, 1, -1], [1, 2, 0, -1]])  # k = 4 > D = 3: every image retrieved
    mask = np.array([[1, 0, 0], [0, 0, 0]], bool)
    mask[1, 0] = True
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        found = recall_at_n(indices, mask, (1, 2, 3, 50))
    assert found == {1: 0.0, 2: 0.5, 3: 1.0, 50: 1.0}  # hand-computed: ranks 1 and 2


def test_bad_n_are_refused():
    indices, mask = np.array([[0]]), np.array([[True]])
    for bad, error in (((0, 1), ValueError), ((), ValueError), ("15", TypeError), ((1.5,), TypeError)):
        with pytest.raises(error, match="recall@N"):
            recall_at_n(indices, mask, bad)


def _small_retrieval(k: int = 3) -> Retrieval:
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((20, k)), axis=1)
    indices = np.array([rng.permutation(10)[:k] for _ in range(20)])
    positives = [[int(indices[q, q % k])] if q % 4 else [int(rng.integers(10))] for q in range(20)]
    return Retrieval(scores=scores, indices=indices, positives=positives)


def test_evaluate_takes_any_n_with_a_note_and_a_warning():
    retrieval = _small_retrieval()
    with pytest.warns(
        FewerCandidatesWarning, match=r"recall@100 needs 100 candidates per query, the retrieval holds 3"
    ):
        evaluation = evaluate(retrieval, ["SU"], k=3, recall_at=(100, 1, 3), timing_repeats=1)
    assert list(evaluation.recall_at_n) == [1, 3, 100] and evaluation.recall_at_n[100] is None
    assert evaluation.recall_at_n[3] == pytest.approx(
        _reference_recall(retrieval.indices, retrieval.positives.toarray(), 3)
    )
    assert any("recall@100" in note for note in evaluation.notes)
    document = json.loads(json.dumps(evaluation.to_dict()))
    assert document["recall@100"] is None and document["recall@3"] == evaluation.recall_at_n[3]
    back = Evaluation.from_dict(
        document, correct=evaluation.correct, uncertainties={"SU": evaluation.methods["SU"].uncertainty}
    )
    assert back.recall_at_n == evaluation.recall_at_n
    assert "recall@100=n/a" in repr(evaluation)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FewerCandidatesWarning)
        default = evaluate(retrieval, ["SU"], k=3, timing_repeats=1)  # default: those of (1, 5, 10, 20) it holds
    assert list(default.recall_at_n) == [1]


def test_cli_recall_at_above_fifty_on_a_full_matrix_and_none_on_a_short_retrieval(
    corridor_dir, corridor_matches_dir, tmp_path, capsys
):
    matrix = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    gt = corridor_dir / "ground_truth_new.npy"
    out = tmp_path / "full.json"
    argv = ["evaluate", str(matrix), "--gt", str(gt), "--methods", "SU", "--recall-at", "1,5,100", "--json", str(out)]
    assert cli.main(argv) == 0
    document = json.loads(out.read_text())
    full = read_results(matrix, ground_truth=gt, top_k=111)  # every database image: the reference
    assert document["recall@100"] == pytest.approx(_reference_recall(full.indices, full.positives.toarray(), 100))
    assert "R@100" in capsys.readouterr().out
    short = tmp_path / "r20.npz"
    save_retrieval(read_results(matrix, ground_truth=gt, top_k=20), short)
    with pytest.warns(FewerCandidatesWarning):
        assert cli.main(["evaluate", str(short), "--methods", "SU", "--recall-at", "1,100", "--json", str(out)]) == 0
    document = json.loads(out.read_text())
    assert document["recall@100"] is None and "recall@100 needs 100 candidates" in " ".join(document["notes"])
    assert "R@100 n/a" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="2"):
        cli.main(["evaluate", str(short), "--recall-at", "0,5"])
