"""The GV-* uncertainty methods take the command's executor: their pairs are verified on Ray with the same inliers.

One local Ray cluster (2 CPUs) for the module. Real data: NetVLAD's top-1 answers on a few corridor queries,
verified with GV-SIFT in this process and on Ray through the evaluation (the stage input ``executor``), a
cascade SU+GV-SIFT, and the ``evaluate`` command with ``--executor ray --workers 2``.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("cv2")
ray = pytest.importorskip("ray")

from vpr_uncertainty import read_results  # noqa: E402
from vpr_uncertainty.evaluation import correct_at_n, evaluate  # noqa: E402
from vpr_uncertainty.executors import get_executor  # noqa: E402
from vpr_uncertainty.geometric import verify as distributed  # noqa: E402

pytestmark = [pytest.mark.realdata, pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")]


@pytest.fixture(scope="module")
def corridor(corridor_dir: Path, corridor_matches_dir: Path) -> SimpleNamespace:
    matrix = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        retrieval = read_results(matrix, ground_truth=corridor_dir / "ground_truth_new.npy")
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    rows = np.concatenate([np.flatnonzero(correct)[::15][:4], np.flatnonzero(~correct)[::8][:4]])  # both classes
    query_paths = sorted((corridor_dir / "query").glob("*.jpg"))
    return SimpleNamespace(
        retrieval=retrieval.subset_queries(rows),
        query_paths=[query_paths[row] for row in rows],
        database_paths=sorted((corridor_dir / "ref").glob("*.jpg")),
        matrix=matrix,
        ground_truth=corridor_dir / "ground_truth_new.npy",
        folder=corridor_dir,
    )


@pytest.fixture
def ray_calls(monkeypatch):
    """How many times the pairs were sent to the executor (geometric/verify.py)."""
    calls = []
    original = distributed.verify_on_executor

    def spy(verifier, features, pairs):
        calls.append((verifier.executor.name, len(pairs)))
        return original(verifier, features, pairs)

    monkeypatch.setattr(distributed, "verify_on_executor", spy)
    return calls


def _evaluate(corridor: SimpleNamespace, cache_dir: Path, **options):
    return evaluate(
        corridor.retrieval,
        ["SU", "GV-SIFT", "SU+GV-SIFT:verify_fraction=0.5"],
        query_paths=corridor.query_paths,
        database_paths=corridor.database_paths,
        cache_dir=cache_dir,
        timing_repeats=1,
        **options,
    )


def test_gv_sift_on_ray_equals_the_local_run(ray_executor, corridor, tmp_path, ray_calls):
    local = _evaluate(corridor, tmp_path / "local")
    assert not ray_calls
    remote = _evaluate(corridor, tmp_path / "ray", executor=ray_executor)
    assert ray_calls and {name for name, _ in ray_calls} == {"ray"}
    assert (8, 4) == (max(pairs for _, pairs in ray_calls), min(pairs for _, pairs in ray_calls))  # GV, cascade
    for name in local.methods:  # −inliers are integers, and SU the very same code path: exactly equal
        np.testing.assert_array_equal(remote.methods[name].uncertainty, local.methods[name].uncertainty, err_msg=name)
        assert remote.methods[name].auc_pr == local.methods[name].auc_pr
    assert local.methods["GV-SIFT"].uncertainty.min() < 0  # some inliers were found


def test_the_local_executor_verifies_in_this_process(corridor, tmp_path, ray_calls):
    expected = _evaluate(corridor, tmp_path / "none")
    with get_executor("local") as local:
        result = _evaluate(corridor, tmp_path / "local", executor=local)
    assert not ray_calls
    for name in expected.methods:
        np.testing.assert_array_equal(result.methods[name].uncertainty, expected.methods[name].uncertainty)


def test_evaluate_command_on_ray_equals_the_local_command(ray_executor, corridor, tmp_path, capsys, ray_calls):
    from vpr_uncertainty.cli import main

    argv = ["evaluate", str(corridor.matrix), "--gt", str(corridor.ground_truth), "--images", str(corridor.folder)]
    argv += ["--methods", "SU,SU+GV-SIFT", "--verify-fraction", "0.05"]
    assert main([*argv, "--json", str(tmp_path / "local.json")]) == 0
    assert main([*argv, "--executor", "ray", "--workers", "2", "--json", str(tmp_path / "ray.json")]) == 0
    capsys.readouterr()
    assert ray_calls and {name for name, _ in ray_calls} == {"ray"}  # the second command (timed calls: 1 or more)
    local, remote = (json.loads((tmp_path / name).read_text()) for name in ("local.json", "ray.json"))
    for name in ("SU", "SU+GV-SIFT"):
        for metric in ("auc_pr", "average_precision", "aurc"):
            assert remote["methods"][name][metric] == local["methods"][name][metric], (name, metric)


def test_a_wrong_executor_is_refused_with_one_clear_message(corridor):
    with pytest.raises(ValueError, match=r"executor must be an executor of vpr_uncertainty\.executors\.get_executor"):
        evaluate(
            corridor.retrieval,
            ["GV-SIFT"],
            query_paths=corridor.query_paths,
            database_paths=corridor.database_paths,
            executor="ray",
        )
