"""Paired comparisons (:func:`vpr_uncertainty.compare`, ``vpr-uncertainty compare``): McNemar by hand, the paired
bootstrap against a slow reference loop, degenerate and mismatched inputs, and two real corridor VPR methods."""

from __future__ import annotations

import json
from math import comb

import numpy as np
import pytest
from sklearn.metrics import auc, average_precision_score, precision_recall_curve

from conftest import assert_close
from vpr_uncertainty import Retrieval, compare, evaluate
from vpr_uncertainty.cli import main
from vpr_uncertainty.evaluation import mcnemar
from vpr_uncertainty.evaluation.bootstrap import resample_indices


def test_mcnemar_by_hand():
    # b = 1 query only A answers correctly, c = 6 only B; 3 both, 2 neither.
    a = np.array([1, 0, 0, 0, 0, 0, 0, 1, 1, 1, 0, 0], dtype=bool)
    b = np.array([0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0], dtype=bool)
    test = mcnemar(a, b)
    assert (test.a_only, test.b_only, test.both_correct, test.both_wrong) == (1, 6, 3, 2)
    expected = 2 * sum(comb(7, i) for i in range(2)) / 2**7
    assert expected == 0.125
    assert_close(test.p_value, expected)
    assert_close(mcnemar(b, a).p_value, expected)  # symmetric
    assert mcnemar(a, a).p_value == 1.0 and mcnemar(a, a).a_only == 0
    with pytest.raises(ValueError, match="same shape"):
        mcnemar(a, b[:-1])


def _retrieval(seed: int, n_queries: int = 40, names: list[str] | None = None) -> Retrieval:
    rng = np.random.default_rng(seed)
    scores = -np.sort(-rng.random((n_queries, 5)), axis=1)
    indices = np.stack([rng.permutation(8)[:5] for _ in range(n_queries)])
    positives = [[int(i)] for i in rng.integers(0, 3, n_queries)]
    return Retrieval(
        scores=scores,
        indices=indices,
        positives=positives,
        query_names=None if names is None else np.array(names),
    )


def _reference(correct_a, u_a, correct_b, u_b, n_resamples, seed):
    """Slow, obviously correct paired bootstrap of AUC-PR and AP differences with scikit-learn, one resample at a
    time, on the resamples the toolkit documents (resample_indices)."""
    indices = np.concatenate(list(resample_indices(correct_a.size, n_resamples, seed)))
    deltas: dict[str, list[float]] = {"auc_pr": [], "average_precision": []}
    for idx in indices:
        ya, yb = correct_a[idx], correct_b[idx]
        if ya.all() or not ya.any() or yb.all() or not yb.any():
            continue
        values = {}
        for side, (y, u) in {"a": (ya, u_a[idx]), "b": (yb, u_b[idx])}.items():
            precision, recall, _ = precision_recall_curve(y, -u)
            values[side] = (auc(recall, precision), average_precision_score(y, -u))
        deltas["auc_pr"].append(values["a"][0] - values["b"][0])
        deltas["average_precision"].append(values["a"][1] - values["b"][1])
    result = {}
    for metric, d in deltas.items():
        d = np.array(d)
        other = min(int((d <= 0).sum()), int((d >= 0).sum()))
        result[metric] = (np.percentile(d, [2.5, 97.5]), min(1.0, 2 * (1 + other) / (d.size + 1)), d.size)
    return result


def test_two_vpr_methods_match_a_slow_reference_bootstrap():
    first, second = evaluate(_retrieval(1), ["SU", "BM"], k=5), evaluate(_retrieval(2), ["SU", "BM"], k=5)
    result = compare(first, second, n_resamples=300, seed=7)
    for name in ("SU", "BM"):
        m_a, m_b = first.methods[name], second.methods[name]
        reference = _reference(first.correct, m_a.uncertainty, second.correct, m_b.uncertainty, 300, 7)
        for metric, (interval, p_value, kept) in reference.items():
            row = result.difference(metric, name)
            assert_close(row.difference, getattr(m_a, metric) - getattr(m_b, metric))
            assert_close(np.array(row.interval), interval)
            assert_close(row.p_value, p_value)
            assert row.skipped == 300 - kept
    # Holm over the two methods, per metric.
    p = [result.difference("auc_pr", name).p_value for name in ("SU", "BM")]
    holm = sorted(p)
    expected = [min(1, 2 * holm[0]), max(min(1, 2 * holm[0]), holm[1])]
    assert_close(sorted(result.difference("auc_pr", name).p_value_holm for name in ("SU", "BM")), expected)
    mc = result.mcnemar
    assert mc.a_only == int((first.correct & ~second.correct).sum())
    assert mc.b_only == int((~first.correct & second.correct).sum())
    document = json.loads(json.dumps(result.to_dict()))
    assert document["mcnemar_recall@1"]["a_only"] == mc.a_only and len(document["differences"]) == 4
    assert "AUC-PR" in str(result) and "McNemar" in repr(result)


def test_two_uncertainty_methods_match_the_reference():
    evaluation = evaluate(_retrieval(3), ["SU", "BM"], k=5)
    result = compare(evaluation, method_a="SU", method_b="BM", n_resamples=200, seed=1)
    su, bm = evaluation.methods["SU"], evaluation.methods["BM"]
    reference = _reference(evaluation.correct, su.uncertainty, evaluation.correct, bm.uncertainty, 200, 1)
    for metric, (interval, p_value, _) in reference.items():
        row = result.difference(metric, "SU")
        assert (row.method_a, row.method_b) == ("SU", "BM")
        assert_close(np.array(row.interval), interval)
        assert_close(row.p_value, p_value)
        assert row.p_value_holm == row.p_value  # one comparison per metric
    assert result.mcnemar is None and result.to_dict()["mcnemar_recall@1"] is None


def test_identical_evaluations_differ_by_zero():
    evaluation = evaluate(_retrieval(4), ["SU", "BM"], k=5)
    result = compare(evaluation, evaluation, n_resamples=100)
    for row in result.differences:
        assert row.difference == 0.0 and row.p_value == 1.0 and row.p_value_holm == 1.0
        assert row.interval[0] <= 0.0 <= row.interval[1]
    assert result.mcnemar.p_value == 1.0 and result.mcnemar.a_only == result.mcnemar.b_only == 0


def test_mismatched_queries_and_bad_arguments_raise():
    names = [f"q{i}.jpg" for i in range(40)]
    first = evaluate(_retrieval(5, names=names), ["SU"], k=5)
    with pytest.raises(ValueError, match="same queries: they have 40 and 30 queries"):
        compare(first, evaluate(_retrieval(6, n_queries=30), ["SU"], k=5))
    other = evaluate(_retrieval(6), ["SU"], k=5)
    with pytest.raises(ValueError, match="1 query names differ, first at query 3"):
        compare(first, other, query_names_a=names, query_names_b=[*names[:3], "x.jpg", *names[4:]])
    with pytest.raises(ValueError, match="no uncertainty method is evaluated in both"):
        compare(first, evaluate(_retrieval(6), ["BM"], k=5))
    with pytest.raises(ValueError, match="'RS' is not evaluated in A"):
        compare(first, other, methods=["RS"])
    with pytest.raises(ValueError, match="give evaluation_b"):
        compare(first)
    with pytest.raises(ValueError, match="n_resamples"):
        compare(first, other, n_resamples=0)


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_cli_compares_two_real_corridor_methods(corridor_dir, corridor_matches_dir, tmp_path, capsys):
    gt = corridor_dir / "ground_truth_new.npy"
    paths = [corridor_matches_dir / name / "precomputed_data_corrected.npy" for name in ("NetVLAD", "AMOSNet")]
    out = tmp_path / "comparison.json"
    argv = ["compare", *map(str, paths), "--gt", str(gt), "--methods", "SU,BM", "--resamples", "200"]
    assert main([*argv, "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "A = NetVLAD, B = AMOSNet: 111 queries" in printed and "McNemar" in printed
    document = json.loads(out.read_text())
    assert document["n_queries"] == 111 and document["bootstrap"]["resamples"] == 200
    assert {(row["metric"], row["method_a"]) for row in document["differences"]} == {
        (metric, name) for metric in ("auc_pr", "average_precision") for name in ("SU", "BM")
    }
    for row in document["differences"]:
        assert {"a", "b", "difference", "ci", "p_value", "p_value_holm"} <= set(row)
        assert row["ci"][0] <= row["difference"] <= row["ci"][1]

    # recall@1 vectors by hand, from the raw files
    ground_truth = {int(q): set(p) for q, p in np.load(gt, allow_pickle=True, encoding="latin1")}
    correct = [
        np.array([int(np.argmax(row)) in ground_truth[q] for q, row in enumerate(np.asarray(raw[3], dtype=float))])
        for raw in (np.load(path, allow_pickle=True, encoding="latin1") for path in paths)
    ]
    counts = document["mcnemar_recall@1"]
    assert counts["a_only"] == int((correct[0] & ~correct[1]).sum())
    assert counts["b_only"] == int((~correct[0] & correct[1]).sum())
    assert counts["both_correct"] == int((correct[0] & correct[1]).sum())
    assert_close(counts["recall@1_a"], correct[0].mean())
    b, c = counts["a_only"], counts["b_only"]
    assert_close(counts["p_value"], min(1.0, 2 * sum(comb(b + c, i) for i in range(min(b, c) + 1)) / 2 ** (b + c)))

    assert main(["compare", str(paths[0]), "--gt", str(gt), "--uncertainty", "SU,BM", "--resamples", "100"]) == 0
    assert "A = SU, B = BM" in capsys.readouterr().out


def test_cli_bad_input_is_one_line(corridor_dir, corridor_matches_dir, tmp_path, capsys):
    gt = str(corridor_dir / "ground_truth_new.npy")
    matches = str(corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy")
    assert main(["compare", str(tmp_path / "missing.npy"), matches, "--gt", gt]) == 2
    err = capsys.readouterr().err
    assert "not found" in err and err.count("\n") == 1
    with pytest.raises(SystemExit) as exit_:
        main(["compare", matches, matches, "--gt", gt, "--resamples", "0"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "--resamples: must be an integer >= 1" in err and err.count("\n") == 1
    assert main(["compare", matches, "--gt", gt]) == 2
    assert "give B" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_stage_module_has_hlocs_shape(corridor_dir, corridor_matches_dir, tmp_path):
    import dataclasses

    from vpr_uncertainty.pipeline import compare as stage

    assert dataclasses.is_dataclass(stage.default_conf) and stage.default_conf.__dataclass_params__.frozen
    conf = dataclasses.replace(
        stage.default_conf, resamples=50, evaluate=dataclasses.replace(stage.default_conf.evaluate, methods=["SU"])
    )
    paths = [corridor_matches_dir / name / "precomputed_data_corrected.npy" for name in ("HOG", "CALC")]
    out = stage.main(conf, paths, tmp_path / "c.json", ground_truth=corridor_dir / "ground_truth_new.npy")
    document = json.loads(out.read_text())
    assert (document["a"], document["b"]) == ("HOG", "CALC") and len(document["differences"]) == 2


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_docs_compare_example_prints_what_it_shows(data_dir, capsys, monkeypatch):
    """The docs' `compare` example (evaluate tutorial, "Compare two methods on the same queries") prints its table."""
    import re
    import shlex
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "tutorials" / "evaluate-your-method.md").read_text()
    section = re.search(r"^## Compare two methods on the same queries\n(.*?)(?=^## )", page, re.S | re.M).group(1)
    command = re.search(r"```bash\n(.*?)```", section, re.S).group(1).replace("\\\n", " ")
    shown = re.search(r"```text\n(.*?)```", section, re.S).group(1)
    monkeypatch.setenv("VPR_UNCERTAINTY_DATA", str(data_dir))
    argv = shlex.split(command.replace("$VPR_UNCERTAINTY_DATA", str(data_dir)))
    assert argv[:2] == ["vpr-uncertainty", "compare"]
    assert main(argv[1:]) == 0
    assert [line.rstrip() for line in capsys.readouterr().out.splitlines()] == shown.splitlines()
