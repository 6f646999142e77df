"""Cascades SCORE+GV (methods/cascade.py): endpoints equal the score method and GV alone, only the verified queries
are verified (and timed), verified_fraction is reported, and names, options and flags are checked."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.stats import rankdata

from conftest import assert_close
from vpr_uncertainty import Retrieval, evaluate, read_results
from vpr_uncertainty.evaluation import Evaluation
from vpr_uncertainty.methods import METHODS, get_method, register_method
from vpr_uncertainty.methods.cascade import combine_cascade, most_uncertain

CALLS: list[int] = []


def _fake_gv(retrieval: Retrieval, *, delay: float = 0.0, query_paths=None, database_paths=None) -> np.ndarray:
    """−"inliers" that depend on the query only (its top-1 score, coarsely: many ties), as GV's do."""
    CALLS.append(retrieval.n_queries)
    time.sleep(delay * retrieval.n_queries)
    return -np.floor(np.asarray(retrieval.scores[:, 0], dtype=np.float64) * 20)


@pytest.fixture
def fake_gv():
    register_method("FAKE-GV", _fake_gv, description="test GV", kind="geometric", overwrite=True)
    CALLS.clear()
    yield "FAKE-GV"
    METHODS.unregister("FAKE-GV")


def _retrieval(n_queries: int = 60, seed: int = 0) -> Retrieval:
    rng = np.random.default_rng(seed)
    scores = np.sort(rng.uniform(0.2, 1.0, (n_queries, 10)), axis=1)[:, ::-1].astype(np.float32)
    indices = np.tile(np.arange(10), (n_queries, 1))
    indices[:, 0] = np.arange(n_queries) % 10
    positives = np.zeros((n_queries, 10), dtype=bool)
    positives[np.arange(n_queries), np.where(rng.random(n_queries) < 0.6, indices[:, 0], (indices[:, 0] + 1) % 10)] = 1
    return Retrieval(scores=scores, indices=indices, positives=positives)


def test_fraction_zero_is_the_score_method_and_verifies_nothing(fake_gv):
    retrieval = _retrieval()
    result = evaluate(retrieval, ["SU", "SU+FAKE-GV"], verify_fraction=0.0, timing_repeats=1)
    np.testing.assert_array_equal(
        result.methods["SU+FAKE-GV"].uncertainty, result.methods["SU"].uncertainty.astype(np.float64)
    )
    assert result.methods["SU+FAKE-GV"].auc_pr == result.methods["SU"].auc_pr
    assert CALLS == []
    assert result.to_dict()["methods"]["SU+FAKE-GV"]["verified_fraction"] == 0.0


def test_fraction_one_ranks_as_gv_alone(fake_gv):
    retrieval = _retrieval()
    result = evaluate(retrieval, ["FAKE-GV", "SU+FAKE-GV:verify_fraction=1"], timing_repeats=1)
    gv, cascade = result.methods["FAKE-GV"], result.methods["SU+FAKE-GV:verify_fraction=1"]
    np.testing.assert_array_equal(rankdata(cascade.uncertainty), rankdata(gv.uncertainty))  # ties kept
    for metric in ("auc_pr", "average_precision", "aurc"):
        assert_close(getattr(cascade, metric), getattr(gv, metric), dtype=np.float64, err_msg=metric)
    assert cascade.details == {"verified_fraction": 1.0, "verified_queries": retrieval.n_queries}


def test_verifies_the_most_uncertain_fraction_only_and_orders_them_by_gv(fake_gv):
    retrieval = _retrieval(n_queries=50)
    result = evaluate(retrieval, ["SU", "SU+FAKE-GV"], timing_repeats=1)  # default fraction 0.3
    su, cascade = result.methods["SU"].uncertainty, result.methods["SU+FAKE-GV"].uncertainty
    assert CALLS == [15]
    verified = np.argsort(-su, kind="stable")[:15]
    unverified = np.setdiff1d(np.arange(50), verified)
    assert cascade[verified].min() > cascade[unverified].max()
    np.testing.assert_array_equal(cascade[unverified], su[unverified].astype(np.float64))
    gv = -np.floor(retrieval.scores[verified, 0].astype(np.float64) * 20)  # the GV values of those queries
    np.testing.assert_array_equal(rankdata(cascade[verified]), rankdata(gv))
    document = result.to_dict()["methods"]["SU+FAKE-GV"]
    assert document["verified_fraction"] == 15 / 50 and document["verified_queries"] == 15
    again = Evaluation.from_dict(
        result.to_dict(), correct=result.correct, uncertainties={n: m.uncertainty for n, m in result.methods.items()}
    )
    assert again.methods["SU+FAKE-GV"].details == {"verified_fraction": 0.3, "verified_queries": 15}


def test_time_per_query_counts_only_the_verified_queries(fake_gv):
    retrieval = _retrieval(n_queries=40)
    result = evaluate(
        retrieval, ["FAKE-GV", "SU+FAKE-GV:verify_fraction=0.25"], delay=0.004, timing_repeats=1
    )  # GV: 4 ms per query it verifies
    gv, cascade = result.methods["FAKE-GV"], result.methods["SU+FAKE-GV:verify_fraction=0.25"]
    assert CALLS == [40, 10]
    assert gv.time_per_query_ms >= 4.0
    assert cascade.time_per_query_ms < 0.5 * gv.time_per_query_ms  # ~ 1 ms: a quarter of GV's 4 ms


def test_combine_and_selection_helpers():
    np.testing.assert_array_equal(most_uncertain(np.array([0.1, 0.9, 0.5, 0.9]), 0.5), [1, 3])
    assert most_uncertain(np.arange(7.0), 0.3).tolist() == [5, 6]  # round(2.1) = 2 queries
    combined = combine_cascade(np.array([0.2, 0.9, 0.5, 0.8]), np.array([1, 3]), np.array([-3.0, -3.0]))
    assert combined[1] == combined[3] > 0.5  # tied GV values stay tied, above every unverified query
    with pytest.raises(ValueError, match="one value per verified query"):
        combine_cascade(np.zeros(3), np.array([0]), np.zeros(2))


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("GV-SIFT+SU", "expected a score method before '\\+' and a geometric-verification method after it"),
        ("SU+BM", "got SU \\(score\\) and BM \\(score\\)"),
        ("SU+GV-SIFT:verify_fraction=1.5", "verify_fraction must lie in \\[0, 1\\], got 1.5"),
        ("SU+GV-SIFT:verify_fraction=half", "must be a finite number"),
        ("SU+", "a cascade is named SCORE\\+GV"),
    ],
)
def test_bad_cascades_are_one_clear_error(name, message):
    with pytest.raises(ValueError, match=message):
        get_method(name)


def test_unknown_component_names_the_closest_method():
    with pytest.raises(KeyError, match="did you mean 'GV-SIFT'"):
        get_method("SU+GV-SFT")


def test_any_pair_resolves_with_the_needs_and_extra_of_its_gv():
    entry = get_method("RS+GV-DISK-LG:verify_fraction=0.5")
    assert (entry.name, entry.kind, entry.requires, entry.extra) == (
        "RS+GV-DISK-LG:verify_fraction=0.5",
        "cascade",
        ("images",),
        "gv",
    )
    assert entry.bound == {"verify_fraction": 0.5}
    with pytest.raises(ValueError, match="hold no ':', ',', '=' or '\\+'"):
        register_method("A+B", _fake_gv, description="x")


def test_verify_fraction_without_a_cascade_is_an_error():
    with pytest.raises(ValueError, match="takes the option 'verify_fraction'"):
        evaluate(_retrieval(), ["SU"], verify_fraction=0.3)


def test_sift_cascade_on_the_corridor(corridor_dir, corridor_matches_dir):
    pytest.importorskip("cv2")
    from vpr_uncertainty.data import load_vprbench_dataset

    dataset = load_vprbench_dataset(corridor_dir)
    retrieval = read_results(
        corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy",
        ground_truth=corridor_dir / "ground_truth_new.npy",
    )
    paths = {
        "query_paths": list(map(str, dataset.query_paths)),
        "database_paths": list(map(str, dataset.database_paths)),
    }
    result = evaluate(retrieval, ["SU", "GV-SIFT", "SU+GV-SIFT:verify_fraction=1", "SU+GV-SIFT"], workers=1, **paths)
    methods = result.methods
    assert_close(methods["SU+GV-SIFT:verify_fraction=1"].auc_pr, methods["GV-SIFT"].auc_pr, dtype=np.float64)
    verified = most_uncertain(methods["SU"].uncertainty, 0.3)
    expected = combine_cascade(methods["SU"].uncertainty, verified, methods["GV-SIFT"].uncertainty[verified])
    np.testing.assert_array_equal(methods["SU+GV-SIFT"].uncertainty, expected)  # GV on a subset: same inliers
    assert methods["SU+GV-SIFT"].details["verified_queries"] == 33


def _config(tmp_path, corridor_matches_dir, corridor_dir, *lines: str):
    from vpr_uncertainty.pipeline.grid import load_config

    path = tmp_path / "grid.toml"
    path.write_text(
        "\n".join(
            [
                *lines,
                "[[inputs]]",
                f'precomputed_matches = "{corridor_matches_dir}"',
                f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"',
                f'images = "{corridor_dir}"',
            ]
        )
        + "\n"
    )
    return load_config(path)


def test_reproduce_config_takes_verify_fraction_for_a_cascade_only(tmp_path, corridor_matches_dir, corridor_dir):
    config = _config(
        tmp_path,
        corridor_matches_dir,
        corridor_dir,
        'methods = ["SU", "GV-SIFT", "SU+GV-SIFT"]',
        "verify_fraction = 0.5",
    )
    assert config.verify_fraction == 0.5 and config.settings()["verify_fraction"] == 0.5
    assert config.method_options() == {"verify_fraction": 0.5}
    with pytest.raises(ValueError) as error:
        _config(
            tmp_path,
            corridor_matches_dir,
            corridor_dir,
            'methods = ["SU"]',
            "verify_fraction = 1.5",
            'report = ["cascade"]',
        )
    text = str(error.value)
    assert "verify_fraction must lie in [0, 1], got 1.5" in text
    assert "report figure 'cascade' needs a cascade SCORE+GV among the methods" in text


def test_verify_fraction_flag_is_checked():
    import argparse

    from vpr_uncertainty.pipeline import evaluate as evaluate_command

    parser = argparse.ArgumentParser()
    evaluate_command.add_cli(parser.add_subparsers())
    args = parser.parse_args(["evaluate", "x.npz", "--verify-fraction", "0.4", "--methods", "SU+GV-SIFT"])
    assert args.verify_fraction == 0.4 and args.methods == ["SU+GV-SIFT"]
    with pytest.raises(SystemExit):
        parser.parse_args(["evaluate", "x.npz", "--verify-fraction", "1.2"])
