"""Issue 28, the edges where a user's methods and matrices come in: each test is the attack as a user runs it.

* row 14: ``compare`` on two results files whose stored positives differ was compared (McNemar p = 6.6e-05); the
  same file twice gave no notice;
* row 16: a distance matrix read as similarities gave R@1 0.000 and every AUC-PR "n/a", exit 0, with no hint unless
  every value was negative (and the reverse: similarities read with ``--scores distance``);
* row 17: the numba and numpy paths of RS, SD and SU disagreed on rows that are exact scalings of each other
  (RS AUC-PR 0.499 against 0.584): the ties differed;
* unclear messages: a plugin returning strings or complex numbers, a plugin that raises, a plugin that edits the
  retrieval in place (the next method was blamed), ``--scores distance`` with negative values, CSV cells that a
  spreadsheet runs as formulas, ``--recall-at`` with non-ASCII digits.

Every test fails on the code before the fix.
"""

from __future__ import annotations

import csv
import json
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy import sparse

from vpr_uncertainty import Retrieval, _fast, evaluate, ratio_spread, similarity_distribution, statistical_uncertainty
from vpr_uncertainty.cli import main
from vpr_uncertainty.methods import METHODS, register_method

needs_numba = pytest.mark.skipif(_fast._load() is False, reason="numba is not installed (the fast extra)")

RATIO_METRICS = (ratio_spread, similarity_distribution, statistical_uncertainty)


def _both_paths(metric, scores, monkeypatch, **options):
    """``metric`` on the numba kernel (VPR_UNCERTAINTY_NUMBA=1) and on the numpy path (=0)."""
    monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, "1")
    fast = metric(scores, **options)
    monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, "0")
    return fast, metric(scores, **options)


def _outcome(metric, scores, monkeypatch, **options) -> tuple:
    """What each path gives: the bits of its values, or the message it refuses with (a true value beyond the dtype)."""
    outcomes = []
    for mode in ("1", "0"):
        monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, mode)
        try:
            outcomes.append(metric(scores, **options).tobytes())
        except ValueError as error:
            outcomes.append(str(error))
    return tuple(outcomes)


def _scaled_rows(dtype, n_rows: int = 120, k: int = 10, seed: int = 3) -> np.ndarray:
    """Rows that are exact scalings of one row (RS, SD and SU are equal on all of them in exact arithmetic)."""
    rng = np.random.default_rng(seed)
    base = -np.sort(-rng.uniform(0.2, 0.9, size=k))
    return -np.sort(-(rng.uniform(0.5, 2.0, size=(n_rows, 1)) * base).astype(dtype), axis=1)


# --- row 17: the numba and numpy paths give the same bits, so the same ties ---------------------------------------


@needs_numba
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_scaled_rows_get_the_same_auc_pr_from_the_numba_and_numpy_paths(dtype, monkeypatch):
    scores = _scaled_rows(dtype)
    positives = [[0] if row % 3 else [5] for row in range(len(scores))]  # a third of the answers wrong
    retrieval = Retrieval(scores=scores, indices=np.tile(np.arange(10), (len(scores), 1)), positives=positives)
    results = []
    for mode in ("1", "0"):
        monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, mode)
        results.append(evaluate(retrieval, ["RS", "SD", "SU"], timing_repeats=1))
    for name in ("RS", "SD", "SU"):
        fast, reference = (result.methods[name] for result in results)
        assert np.array_equal(fast.uncertainty, reference.uncertainty), name
        assert fast.auc_pr == reference.auc_pr and fast.n_distinct == reference.n_distinct, name


@needs_numba
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("k", [3, 7, 10, 20])  # general and specialised kernels
def test_scaled_rows_are_bit_identical_on_both_paths(dtype, k, monkeypatch):
    scores = _scaled_rows(dtype, k=k)
    scores[::5, k - 1 :] = -np.inf  # rows with a missing candidate go through the general kernel and the redo path
    scores[1] = np.minimum(scores[1], 0) - 0.1  # s_1 <= 0: the most uncertain, 1 - s_1, on both paths
    for metric, options in zip(RATIO_METRICS, ({}, {}, {"alpha": 0.3}), strict=True):
        fast, reference = _both_paths(metric, scores, monkeypatch, k=k, **options)
        assert fast.dtype == reference.dtype == dtype
        assert np.array_equal(fast.view(np.uint8), reference.view(np.uint8)), metric.__name__


@needs_numba
@settings(max_examples=150, deadline=None)
@given(
    dtype=st.sampled_from([np.float32, np.float64]),
    base=st.lists(st.floats(-1, 1, width=32), min_size=2, max_size=12),
    scales=st.lists(st.floats(1e-3, 1e3), min_size=1, max_size=8),
    alpha=st.floats(0, 1),
)
# a subnormal s_1 before negative runners-up: SD = -3.6e44 is beyond float32, so both paths refuse with one message
@example(dtype=np.float32, base=[1.401298464324817e-45, -0.5], scales=[1.0], alpha=0.0)
def test_any_scaled_rows_are_bit_identical_on_both_paths(dtype, base, scales, alpha):
    scores = -np.sort(-(np.array(scales)[:, None] * np.array(base)).astype(dtype), axis=1)
    with pytest.MonkeyPatch.context() as monkeypatch:
        for metric, options in zip(RATIO_METRICS, ({}, {}, {"alpha": alpha}), strict=True):
            fast, reference = _outcome(metric, scores, monkeypatch, k=len(base), **options)
            assert fast == reference, metric.__name__


# --- row 14: compare refuses results whose ground truth differs; the same file twice gets one notice -----------------


@pytest.fixture
def corridor_retrievals(tmp_path, corridor_dir, corridor_matches_dir):
    """NetVLAD's and AMOSNet's corridor results as retrieval files, with the corridor ground truth stored."""
    from vpr_uncertainty.data import read_results
    from vpr_uncertainty.retrieval import save_retrieval

    ground_truth = corridor_dir / "ground_truth_new.npy"
    paths = {}
    for name in ("NetVLAD", "AMOSNet"):
        retrieval = read_results(
            corridor_matches_dir / name / "precomputed_data_corrected.npy", ground_truth=ground_truth
        )
        paths[name] = save_retrieval(retrieval, tmp_path / f"{name.lower()}.npz")
    return paths


def _with_positives(path: Path, out: Path, change) -> Path:
    from vpr_uncertainty.retrieval import load_retrieval, save_retrieval

    retrieval = load_retrieval(path)
    retrieval.positives = sparse.csr_array(change(retrieval.positives.toarray()))
    retrieval.__post_init__()
    return save_retrieval(retrieval, out)


def test_compare_refuses_results_whose_stored_positives_differ(corridor_retrievals, corridor_dir, tmp_path, capsys):
    other = _with_positives(
        corridor_retrievals["AMOSNet"], tmp_path / "amosnet_shifted.npz", lambda m: np.roll(m, 3, 1)
    )
    argv = ["compare", str(corridor_retrievals["NetVLAD"]), str(other), "--methods", "SU,BM", "--resamples", "50"]
    status = main(argv)
    captured = capsys.readouterr()
    assert status == 2 and "McNemar" not in captured.out
    (line,) = captured.err.strip().splitlines()
    assert "netvlad and amosnet_shifted hold different ground truth" in line and "111 of 111 queries" in line
    assert main([*argv, "--gt", str(corridor_dir / "ground_truth_new.npy")]) == 0  # --gt: both the same positives
    assert "McNemar" in capsys.readouterr().out


def test_compare_refuses_results_of_another_database(corridor_retrievals, tmp_path, capsys):
    wider = _with_positives(
        corridor_retrievals["AMOSNet"], tmp_path / "amosnet_wider.npz", lambda m: np.pad(m, ((0, 0), (0, 9)))
    )
    assert main(["compare", str(corridor_retrievals["NetVLAD"]), str(wider), "--methods", "SU"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "must hold the same database images: they have 111 and 120 database images" in line


def test_compare_a_file_with_itself_gives_one_notice(corridor_retrievals, capsys):
    path = str(corridor_retrievals["NetVLAD"])
    assert main(["compare", path, path, "--methods", "SU,BM", "--resamples", "50"]) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if "the same retrieval" in line]
    assert notes == ["note: A and B hold the same retrieval: every difference is 0"]


# --- row 16: scores that rank the ground truth backwards get one notice naming --scores distance ----------------------


def _corridor_matrices(corridor_matches_dir: Path) -> list[Path]:
    paths = sorted(corridor_matches_dir.glob("*/precomputed_data_corrected.npy"))
    assert len(paths) == 10
    return paths


def _backwards_notes(evaluation) -> list[str]:
    return [note for note in evaluation.notes if "rank the ground truth backwards" in note]


def test_the_ten_corridor_similarity_matrices_get_no_direction_notice(corridor_dir, corridor_matches_dir):
    from vpr_uncertainty.data import read_results

    for path in _corridor_matrices(corridor_matches_dir):
        retrieval = read_results(path, ground_truth=corridor_dir / "ground_truth_new.npy")
        with warnings.catch_warnings():
            warnings.simplefilter("error", UserWarning)  # the notice is a UserWarning
            warnings.filterwarnings("ignore", "left out of the default methods")
            evaluation = evaluate(retrieval, ["SU", "BM"], timing_repeats=1)
        assert not _backwards_notes(evaluation), path
        retrieval.config.pop("positives_vs_mean")  # the candidates alone (a retrieval file) do not fire either
        assert not _backwards_notes(evaluate(retrieval, ["BM"], timing_repeats=1)), path


TURNED = {
    "negated": lambda s: -s,
    "one minus": lambda s: 1 - s,
    "L2 distance": lambda s: np.sqrt(np.maximum(2 - 2 * s, 0)),
}


#: The kind each turned matrix is told to be read as (retrieval.result.distance_kind_hint).
KIND = {"negated": "distance (values in [", "one minus": "l2-distance (of unit-norm", "L2 distance": "l2-distance (of"}


@pytest.mark.parametrize("turn", list(TURNED))
def test_each_corridor_matrix_turned_into_distances_gets_the_notice(turn, corridor_dir, corridor_matches_dir, tmp_path):
    from vpr_uncertainty.data import read_results
    from vpr_uncertainty.formats.matrix import load_vprbench_similarity

    for path in _corridor_matrices(corridor_matches_dir):
        matrix = tmp_path / "distances.npy"
        np.save(matrix, TURNED[turn](load_vprbench_similarity(path).astype(np.float64)))
        retrieval = read_results(matrix, ground_truth=corridor_dir / "ground_truth_new.npy")
        with pytest.warns(UserWarning, match="rank the ground truth backwards") as caught:
            evaluation = evaluate(retrieval, ["BM"], timing_repeats=1)
        assert len([w for w in caught if "backwards" in str(w.message)]) == 1
        (note,) = _backwards_notes(evaluation)
        advice = note.split("read them as distances (--scores, or score_kind in a reproduce config): ")[1]
        # negated similarities are negative: no distance of unit-norm descriptors; the others lie in [0, 2]
        assert "read as similarities" in note and advice.startswith(KIND[turn]), (path, advice)


def test_the_command_line_suggests_scores_distance_once(corridor_dir, corridor_matches_dir, tmp_path, capsys):
    from vpr_uncertainty.formats.matrix import load_vprbench_similarity

    similarity = load_vprbench_similarity(corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy")
    np.save(tmp_path / "distances.npy", np.sqrt(np.maximum(2 - 2 * similarity, 0)))
    ground_truth = str(corridor_dir / "ground_truth_new.npy")
    with pytest.warns(UserWarning) as caught:
        assert (
            main(
                ["evaluate", str(tmp_path / "distances.npy"), "--gt", ground_truth, "--json", str(tmp_path / "r.json")]
            )
            == 0
        )
    assert len([w for w in caught if "read them as distances (--scores" in str(w.message)]) == 1
    assert len(_backwards_notes(SimpleNamespace(**json.loads((tmp_path / "r.json").read_text())))) == 1
    # read as distances, as suggested: no notice, and the numbers of the similarity matrix
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        warnings.filterwarnings("ignore", "left out of the default methods")
        argv = ["evaluate", str(tmp_path / "distances.npy"), "--gt", ground_truth, "--scores", "distance"]
        assert main([*argv, "--methods", "BM,PA"]) == 0


def test_similarities_read_as_distances_get_the_reverse_notice(corridor_dir, corridor_matches_dir, capsys):
    path = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    argv = ["evaluate", str(path), "--gt", str(corridor_dir / "ground_truth_new.npy"), "--scores", "distance"]
    with pytest.warns(UserWarning, match=r"read as distances \(--scores\).*drop --scores"):
        assert main([*argv, "--methods", "BM"]) == 0


def test_a_full_retrieval_read_backwards_gets_the_notice_without_the_readers_measure():
    rng = np.random.default_rng(0)
    similarity = rng.normal(size=(60, 30)) + 3 * np.eye(60, 30)  # query i's positive is database image i
    distance = -similarity
    order = np.argsort(-distance, axis=1, kind="stable")  # read as similarities: the farthest first
    retrieval = Retrieval(
        scores=np.take_along_axis(distance, order, axis=1), indices=order, positives=[[i % 30] for i in range(60)]
    )
    with pytest.warns(UserWarning, match="backwards"):
        assert len(_backwards_notes(evaluate(retrieval, ["BM"], timing_repeats=1))) == 1


def test_reproduce_notes_a_distance_matrix_in_its_cell(corridor_dir, corridor_matches_dir, tmp_path):
    from vpr_uncertainty.formats.matrix import load_vprbench_similarity
    from vpr_uncertainty.pipeline.grid import load_config, run_grid

    similarity = load_vprbench_similarity(corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy")
    np.save(tmp_path / "distances.npy", 1 - similarity)
    (tmp_path / "grid.toml").write_text(
        'out = "out"\nmethods = ["SU", "BM"]\n[[inputs]]\nvpr_method = "NetVLAD"\ndataset = "corridor"\n'
        f'scores = "distances.npy"\nground_truth = "{corridor_dir / "ground_truth_new.npy"}"\n'
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (cell,) = run_grid(load_config(tmp_path / "grid.toml"), progress=False)
    assert len(_backwards_notes(cell.evaluation)) == 1


# --- unclear messages: a user's uncertainty method -------------------------------------------------------------------


def _plugin(tmp_path: Path, monkeypatch, name: str, body: str) -> str:
    """A plugin module registering the method ``name`` with the function body ``body`` (of ``retrieval``)."""
    module = "edge_plugin_" + "".join(c if c.isalnum() else "_" for c in tmp_path.name)  # one module per test
    (tmp_path / f"{module}.py").write_text(
        "import numpy as np\n"
        "from vpr_uncertainty.methods import register_method\n"
        f"def method(retrieval, *, k=10):\n    {body}\n"
        f"register_method({name!r}, method, description='test', overwrite=True)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    return module


@pytest.fixture
def small_matrix(tmp_path):
    rng = np.random.default_rng(0)
    similarity = rng.random((12, 15)).astype(np.float32) + np.eye(12, 15, dtype=np.float32) * 0.5
    np.save(tmp_path / "sim.npy", similarity)
    (tmp_path / "gt.json").write_text(json.dumps([[i] if i % 3 else [14] for i in range(12)]))
    return [str(tmp_path / "sim.npy"), "--gt", str(tmp_path / "gt.json")]


@pytest.fixture
def unregister():
    names = []
    yield names
    for name in names:
        if name in METHODS:
            METHODS.unregister(name)


def _evaluate_with(module: str, name: str, small_matrix, *extra: str) -> int:
    return main(["--plugin", module, "evaluate", *small_matrix, "--methods", f"{name},BM", *extra])


@pytest.mark.parametrize(
    ("body", "what"),
    [
        ("return np.array(['low'] * retrieval.n_queries)", "strings"),
        ("return retrieval.scores[:, 0] + 1j", "complex numbers"),
        ("return np.array([object()] * retrieval.n_queries)", "Python objects"),
    ],
)
def test_a_plugin_returning_no_real_numbers_is_named(
    body, what, tmp_path, monkeypatch, small_matrix, unregister, capsys
):
    unregister.append("ODD")
    assert _evaluate_with(_plugin(tmp_path, monkeypatch, "ODD", body), "ODD", small_matrix) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"uncertainty method 'ODD' returned {what}; it must return one real number per query" in line


@pytest.mark.parametrize(("error", "status"), [("ValueError", 2), ("RuntimeError", 1), ("ZeroDivisionError", 1)])
def test_a_plugin_that_raises_is_named(error, status, tmp_path, monkeypatch, small_matrix, unregister, capsys):
    unregister.append("ENT")
    module = _plugin(tmp_path, monkeypatch, "ENT", f"raise {error}('boom')")
    assert _evaluate_with(module, "ENT", small_matrix) == status
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == "vpr-uncertainty evaluate: error: uncertainty method 'ENT' failed: boom"
    assert _evaluate_with(module, "ENT", small_matrix) == status  # the traceback is one --debug away
    assert main(["--debug", "--plugin", module, "evaluate", *small_matrix, "--methods", "ENT"]) == status
    assert f"{error}: boom" in capsys.readouterr().err


def test_a_plugin_that_edits_the_retrieval_in_place_is_named_and_the_next_method_is_not_blamed(
    tmp_path, monkeypatch, small_matrix, unregister, capsys
):
    unregister.append("EDIT")
    module = _plugin(
        tmp_path, monkeypatch, "EDIT", "retrieval.scores[:] = retrieval.scores[:, ::-1]; return -retrieval.scores[:, 0]"
    )
    assert main(["--plugin", module, "evaluate", *small_matrix, "--methods", "EDIT,SU"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "uncertainty method 'EDIT' failed: assignment destination is read-only" in line and "'SU'" not in line


def test_the_retrieval_is_unchanged_and_writable_after_a_method_wrote_into_it(unregister):
    unregister.append("EDIT")
    register_method("EDIT", lambda retrieval: retrieval.scores.sort(axis=1), description="test")
    retrieval = Retrieval(
        scores=np.array([[0.9, 0.5], [0.8, 0.1]]), indices=np.array([[0, 1], [1, 0]]), positives=[[0], [0]]
    )
    before = retrieval.scores.copy()
    with pytest.raises(ValueError, match=r"uncertainty method 'EDIT' failed: .*read-only"):
        evaluate(retrieval, ["EDIT"], timing_repeats=1)
    assert np.array_equal(retrieval.scores, before) and retrieval.scores.flags.writeable


def test_negative_distances_are_any_lower_is_better_score(tmp_path, small_matrix, capsys):
    np.save(tmp_path / "sim.npy", -1 - np.load(tmp_path / "sim.npy"))  # lower = more similar, every value < 0
    argv = ["evaluate", *small_matrix, "--scores", "distance"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(argv) == 0
        assert main([*argv, "--methods", "BM,margin"]) == 0
    assert "BM" in capsys.readouterr().out
    assert main([*argv, "--methods", "L2"]) == 2  # L2 needs squared L2 distances: one line naming it and the file
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"uncertainty method 'L2' on {tmp_path / 'sim.npy'}: it needs squared L2 distances" in line


# --- unclear messages: CSV cells that a spreadsheet runs, non-ASCII digits -------------------------------------------


def test_a_method_name_that_starts_like_a_formula_is_text_in_evaluate_csv(
    tmp_path, monkeypatch, small_matrix, unregister
):
    unregister.append("@SUM")
    module = _plugin(tmp_path, monkeypatch, "@SUM", "return -retrieval.scores[:, 0]")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert _evaluate_with(module, "@SUM", small_matrix, "--csv", str(tmp_path / "t.csv")) == 0
    rows = list(csv.reader((tmp_path / "t.csv").open()))
    assert rows[1][0] == "'@SUM" and rows[2][0] == "BM"


def test_a_vpr_method_label_that_starts_like_a_formula_is_text_in_results_csv(tmp_path):
    from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_reports, write_results
    from vpr_uncertainty.retrieval import save_retrieval

    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((30, 10)), axis=1)
    indices = np.tile(np.arange(10), (30, 1))
    save_retrieval(
        Retrieval(scores=scores, indices=indices, positives=[[i % 2] for i in range(30)]), tmp_path / "r.npz"
    )
    label = '=HYPERLINK("http://example.com/x","click")'
    (tmp_path / "grid.toml").write_text(
        'out = "out"\nmethods = ["SU", "BM"]\n[[inputs]]\n'
        f"vpr_method = '{label}'\ndataset = '-2+3'\nscores = \"r.npz\"\n"
    )
    config = load_config(tmp_path / "grid.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cells = run_grid(config, progress=False)
        paths = {**write_results(cells, config), **write_reports(cells, config, html=False, figures=["table1"])}
    rows = list(csv.DictReader(paths["results_csv"].open()))
    assert {row["vpr_method"] for row in rows} == {"'" + label} and {row["dataset"] for row in rows} == {"'-2+3"}
    assert all(not row["auc_pr"].startswith("'") for row in rows)  # numbers stay numbers
    table = (tmp_path / "out" / "table1.csv").read_text()
    assert "'" + label.replace('"', '""') in table and '\n"=' not in table and ",=" not in table


@pytest.mark.parametrize("value", ["٣", "1,٥", "１０"])
def test_recall_at_takes_ascii_digits_only(value, small_matrix, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["evaluate", *small_matrix, "--recall-at", value])
    assert exit_.value.code == 2 and "--recall-at: expected a comma-separated list of ints" in capsys.readouterr().err
