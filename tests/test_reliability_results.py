"""Issue 10, item 3 (and the retrieval-file part of item 5): never silently compute something other than what was
asked. The k asked is the k used (or a warning says why not), every field of a retrieval file is checked,
d² = 2 − 2s is refused outside [−1, 1], tied uncertainties are never "best", and the s_1 <= 0 rule is counted."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty import evaluate
from vpr_uncertainty.cli import main
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation import FewerCandidatesWarning
from vpr_uncertainty.reports.tables import (
    Table1,
    build_table1,
    format_table,
    table1_csv,
    table1_html,
    table1_latex,
    table1_markdown,
)
from vpr_uncertainty.retrieval import Retrieval, load_retrieval, save_retrieval, top_k_from_similarity
from vpr_uncertainty.scores import (
    l2_distance,
    perceptual_aliasing,
    ratio_spread,
    similarity_distribution,
    squared_distances_from_similarities,
)

# --- shared synthetic input ---------------------------------------------------------------------------------------


def _matrix(n_queries: int = 40, n_database: int = 150, seed: int = 0) -> tuple[np.ndarray, list[list[int]]]:
    """Cosine-like similarities in (0, 1) where about half of the queries find their own place (index = query)."""
    rng = np.random.default_rng(seed)
    similarity = rng.uniform(0.05, 0.8, size=(n_queries, n_database)).astype(np.float32)
    found = rng.random(n_queries) < 0.5
    similarity[found, np.flatnonzero(found)] = 0.95
    return similarity, [[i] for i in range(n_queries)]


def _write_matrix(tmp_path: Path) -> tuple[Path, Path, np.ndarray]:
    similarity, positives = _matrix()
    matrix_path, gt_path = tmp_path / "sim.npy", tmp_path / "gt.json"
    np.save(matrix_path, similarity)
    gt_path.write_text(json.dumps(positives))
    return matrix_path, gt_path, similarity


def _retrieval(n_queries: int = 6, k: int = 4, n_database: int = 10) -> Retrieval:
    rng = np.random.default_rng(1)
    similarity = rng.uniform(0.1, 0.9, size=(n_queries, n_database)).astype(np.float32)
    scores, indices = top_k_from_similarity(similarity, k)
    positives = sparse.csr_array(np.eye(n_queries, n_database, dtype=bool))
    return Retrieval(
        scores=scores,
        indices=indices,
        distances=np.maximum(2 - 2 * scores, 0),
        positives=positives,
        query_names=np.array([f"q{i}.jpg" for i in range(n_queries)]),
        database_names=np.array([f"d{i}.jpg" for i in range(n_database)]),
        query_positions=rng.uniform(0, 100, size=(n_queries, 2)),
        database_positions=rng.uniform(0, 100, size=(n_database, 2)),
        config={"source": "test"},
    )


# --- 1. the k asked is the k used -----------------------------------------------------------------------------------


def test_evaluate_command_on_a_matrix_uses_the_k_asked(tmp_path, capsys):
    matrix_path, gt_path, similarity = _write_matrix(tmp_path)
    out = tmp_path / "results.json"
    argv = ["evaluate", str(matrix_path), "--gt", str(gt_path), "--k", "100", "--methods", "RS,SD", "--json", str(out)]
    assert main(argv) == 0
    result = json.loads(out.read_text())
    assert result["k"] == 100 and "k_requested" not in result
    scores, _ = top_k_from_similarity(similarity, 100)
    correct = np.array([row[0] == i for i, row in enumerate(top_k_from_similarity(similarity, 1)[1])])
    from vpr_uncertainty.evaluation import auc_pr

    assert result["methods"]["RS"]["auc_pr"] == pytest.approx(auc_pr(correct, ratio_spread(scores, 100)), rel=1e-12)
    assert result["methods"]["SD"]["auc_pr"] == pytest.approx(
        auc_pr(correct, similarity_distribution(scores, 100)), rel=1e-12
    )
    # and k = 50 would give another number: the test can tell 100 from 50
    assert result["methods"]["SD"]["auc_pr"] != pytest.approx(auc_pr(correct, similarity_distribution(scores, 50)))


def test_evaluation_records_the_k_used():
    retrieval = _retrieval(k=8)
    result = evaluate(retrieval, ["SU", "BM"], k=5, timing_repeats=1).to_dict()
    assert result["k"] == 5 and "k_requested" not in result


def test_fewer_candidates_than_k_is_a_warning_a_note_and_recorded():
    retrieval = _retrieval(k=4)
    with pytest.warns(FewerCandidatesWarning, match=r"k = 10 was asked but the retrieval \(test\) holds 4"):
        evaluation = evaluate(retrieval, ["SU", "BM"], k=10, timing_repeats=1)
    result = evaluation.to_dict()
    assert result["k"] == 4 and result["k_requested"] == 10
    assert any("SU used k = 4" in note for note in result["notes"])
    assert "k = 10 was asked" in format_table(evaluation)


def test_fewer_candidates_is_silent_for_methods_that_do_not_use_k():
    with warnings.catch_warnings():
        warnings.simplefilter("error", FewerCandidatesWarning)
        evaluation = evaluate(_retrieval(k=4), ["BM", "L2"], k=10, timing_repeats=1)
    assert not any("was asked" in note for note in evaluation.notes)


def _grid_config(tmp_path: Path, matrix_path: Path, gt_path: Path, k: int, ks: list[int]) -> Path:
    config = tmp_path / "grid.toml"
    config.write_text(
        "\n".join(
            [
                f'out = "{tmp_path / "out"}"',
                'methods = ["RS", "SD", "SU"]',
                f"k = {k}",
                f"ks = {json.dumps(ks)}",
                "alphas = []",
                "[[inputs]]",
                'vpr_method = "mine"',
                'dataset = "synthetic"',
                f'scores = "{matrix_path}"',
                f'ground_truth = "{gt_path}"',
            ]
        )
        + "\n"
    )
    return config


def test_reproduce_with_k_100_computes_k_100_and_keeps_every_k_of_the_ablation(tmp_path):
    from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_results

    matrix_path, gt_path, similarity = _write_matrix(tmp_path)
    config = load_config(_grid_config(tmp_path, matrix_path, gt_path, 100, [10, 60, 100]))
    (cell,) = run_grid(config, progress=False)
    scores, _ = top_k_from_similarity(similarity, 100)
    np.testing.assert_allclose(cell.evaluation.methods["RS"].uncertainty, ratio_spread(scores, 100), rtol=1e-5)
    assert sorted(cell.ablation_k["RS"]) == [10, 60, 100]
    document = json.loads(write_results([cell], config)["results_json"].read_text())
    assert document["cells"][0]["k"] == 100
    assert sorted(document["cells"][0]["ablation_k"]["SD"], key=int) == ["10", "60", "100"]
    # the cached cell keeps the k used
    (cached,) = run_grid(config, progress=False)
    assert cached.cached and cached.evaluation.to_dict()["k"] == 100


def test_reproduce_notes_ks_left_out_when_a_retrieval_file_has_fewer_candidates(tmp_path):
    from vpr_uncertainty.pipeline.grid import load_config, run_grid

    retrieval = _retrieval(n_queries=20, k=6, n_database=30)
    retrieval.positives = sparse.csr_array(np.eye(20, 30, dtype=bool))
    path = save_retrieval(retrieval, tmp_path / "r.npz")
    config = load_config(_grid_config(tmp_path, path, path, 10, [3, 5, 8]))
    with pytest.warns(FewerCandidatesWarning):
        (cell,) = run_grid(config, progress=False)
    assert sorted(cell.ablation_k["RS"]) == [3, 5]
    notes = cell.evaluation.notes
    assert any("k ablation: k = 8 left out" in note for note in notes)
    assert cell.evaluation.to_dict()["k"] == 6 and cell.evaluation.to_dict()["k_requested"] == 10


# --- 2. every field of a retrieval file is checked ------------------------------------------------------------------


@pytest.fixture
def saved(tmp_path) -> tuple[Path, dict[str, np.ndarray]]:
    path = save_retrieval(_retrieval(), tmp_path / "good.npz")
    with np.load(path) as archive:
        arrays = {key: archive[key] for key in archive.files}
    return path, arrays


def _mutated(path: Path, arrays: dict[str, np.ndarray], **changes: object) -> Path:
    arrays = {**arrays, **changes}
    arrays = {key: value for key, value in arrays.items() if value is not None}
    bad = path.with_name("bad.npz")
    np.savez(bad, **arrays)
    return bad


def _with(arrays: dict[str, np.ndarray], key: str, position: tuple[int, ...], value: object, dtype=None):
    array = arrays[key].astype(dtype) if dtype is not None else arrays[key].copy()
    array[position] = value
    return array


BAD_FIELDS = {
    "index -5": (lambda a: {"indices": _with(a, "indices", (0, 1), -5)}, "indices", "holds -5"),
    "wrapped uint64 index": (
        lambda a: {"indices": _with(a, "indices", (0, 1), np.uint64(2**64 - 5), np.uint64)},
        "indices",
        "beyond the int64 range",
    ),
    "-1 beside a finite score": (lambda a: {"indices": _with(a, "indices", (2, 3), -1)}, "indices", "index -1"),
    "float indices": (lambda a: {"indices": a["indices"].astype(np.float64)}, "indices", "must hold integers"),
    "index beyond the database": (lambda a: {"indices": _with(a, "indices", (1, 0), 10)}, "indices", "covers only"),
    "positives_indices out of range": (
        lambda a: {"positives_indices": _with(a, "positives_indices", (0,), 99)},
        "positives_indices",
        "outside the database",
    ),
    "positives_indptr too short": (
        lambda a: {"positives_indptr": a["positives_indptr"][:-1]},
        "positives_indptr",
        "expected 7",
    ),
    "positives_indptr decreasing": (
        lambda a: {"positives_indptr": _with(a, "positives_indptr", (2,), 0)},
        "positives_indptr",
        "decreas",
    ),
    "positives_indptr end != nnz": (
        lambda a: {"positives_indptr": _with(a, "positives_indptr", (-1,), 9)},
        "positives_indptr",
        "rise from 0",
    ),
    "positives_indices without indptr": (
        lambda a: {"positives_indptr": None},
        "positives_indices",
        "without positives_indptr",
    ),
    "format version 0": (lambda a: {"format_version": np.array(0)}, "format_version", "got 0"),
    "format version -5": (lambda a: {"format_version": np.array(-5)}, "format_version", "got -5"),
    "format version 1.9": (lambda a: {"format_version": np.array(1.9)}, "format_version", "got 1.9"),
    'format version "x"': (lambda a: {"format_version": np.array("x")}, "format_version", "got 'x'"),
    "format version 2": (lambda a: {"format_version": np.array(2)}, "format_version", "reads up to 1"),
    "format version bool": (lambda a: {"format_version": np.array(True)}, "format_version", "got True"),
    "indices narrower than scores": (lambda a: {"indices": a["indices"][:, :3]}, "indices", "has shape"),
    "scores one row short": (lambda a: {"scores": a["scores"][:-1]}, "indices", "must agree"),
    "distances of another shape": (lambda a: {"distances": a["distances"][:, :2]}, "distances", "must agree"),
    "negative distance": (lambda a: {"distances": _with(a, "distances", (0, 0), -0.5)}, "distances", "holds -0.5"),
    "unsorted distances": (lambda a: {"distances": a["distances"][:, ::-1]}, "distances", "ascending"),
    "query_names of wrong length": (lambda a: {"query_names": a["query_names"][:-1]}, "query_names", "5 entries"),
    "database_names of wrong length": (
        lambda a: {"database_names": a["database_names"][:-1]},
        "database_names",
        "database sizes disagree",
    ),
    "query_positions of wrong length": (
        lambda a: {"query_positions": a["query_positions"][:-1]},
        "query_positions",
        "5 entries",
    ),
    "database_positions of wrong length": (
        lambda a: {"database_positions": a["database_positions"][:-2]},
        "database_positions",
        "database sizes disagree",
    ),
    "NaN position": (
        lambda a: {"database_positions": _with(a, "database_positions", (3, 1), np.nan)},
        "database_positions",
        "non-finite",
    ),
    "numeric names": (lambda a: {"query_names": np.arange(6)}, "query_names", "strings"),
    "score NaN": (lambda a: {"scores": _with(a, "scores", (1, 2), np.nan)}, "scores", "NaN"),
    "score +inf": (lambda a: {"scores": _with(a, "scores", (1, 0), np.inf)}, "scores", r"\+inf"),
    "unsorted scores": (lambda a: {"scores": a["scores"][:, ::-1].copy()}, "scores", "descending"),
    "boolean scores": (lambda a: {"scores": a["scores"] > 0.5}, "scores", "real numbers"),
    "config not JSON": (lambda a: {"config": np.array("{oops")}, "config", "not valid JSON"),
    "config a list": (lambda a: {"config": np.array("[1, 2]")}, "config", "JSON object"),
}


@pytest.mark.parametrize("case", list(BAD_FIELDS))
def test_every_bad_field_of_a_retrieval_file_is_a_clear_error(saved, case):
    path, arrays = saved
    change, field, problem = BAD_FIELDS[case]
    bad = _mutated(path, arrays, **change(arrays))
    with pytest.raises(ValueError, match=problem) as raised:
        load_retrieval(bad)
    message = str(raised.value)
    assert str(bad) in message and field in message, message


@pytest.mark.parametrize("case", ["index -5", "-1 beside a finite score", "float indices", "score NaN"])
def test_the_same_checks_hold_for_a_retrieval_made_in_memory(saved, case):
    _, arrays = saved
    change, field, problem = BAD_FIELDS[case]
    arrays = {**arrays, **change(arrays)}
    with pytest.raises(ValueError, match=problem) as raised:
        Retrieval(scores=arrays["scores"], indices=arrays["indices"])
    assert field in str(raised.value)


def test_missing_candidates_marked_by_minus_one_and_minus_inf_still_load(tmp_path):
    retrieval = _retrieval(k=4)
    retrieval.scores[1, 2:] = -np.inf
    retrieval.indices[1, 2:] = -1
    retrieval.distances[1, 2:] = np.inf
    loaded = load_retrieval(save_retrieval(Retrieval(**vars(retrieval)), tmp_path / "missing.npz"))
    np.testing.assert_array_equal(loaded.indices, retrieval.indices)


def test_files_the_toolkit_writes_load_back(saved):
    path, _ = saved
    loaded, original = load_retrieval(path), _retrieval()
    np.testing.assert_array_equal(loaded.indices, original.indices)
    np.testing.assert_array_equal(loaded.scores, original.scores)
    assert (loaded.positives != original.positives).nnz == 0
    assert loaded.config == {"source": "test"}


def test_a_version_1_file_of_the_previous_release_loads(tmp_path):
    """The exact layout the previous release's save_retrieval wrote (format 1), built by hand."""
    original = _retrieval()
    path = tmp_path / "v1.npz"
    with path.open("wb") as handle:
        np.savez_compressed(
            handle,
            format_version=np.array(1),
            scores=original.scores.astype(np.float32),
            indices=original.indices.astype(np.int64),
            config=np.array(json.dumps({"source": "faiss", "k": 4}, sort_keys=True)),
            distances=original.distances.astype(np.float32),
            positives_indptr=original.positives.indptr.astype(np.int64),
            positives_indices=original.positives.indices.astype(np.int64),
            n_database=np.array(10),
            query_names=np.asarray(original.query_names, dtype=str),
            database_names=np.asarray(original.database_names, dtype=str),
            query_positions=original.query_positions.astype(np.float64),
            database_positions=original.database_positions.astype(np.float64),
        )
    loaded = load_retrieval(path)
    assert loaded.k == 4 and loaded.n_database == 10 and loaded.config["source"] == "faiss"
    # a minimal file from another tool (no format_version, no ground truth) loads too
    minimal = tmp_path / "minimal.npz"
    np.savez(minimal, scores=original.scores, indices=original.indices.astype(np.int32))
    assert load_retrieval(minimal).indices.dtype == np.int64


@pytest.mark.parametrize("size", [0, 22, 200, -30])
def test_empty_or_truncated_retrieval_file_names_the_file(saved, tmp_path, size):
    path, _ = saved
    data = path.read_bytes()
    broken = tmp_path / "broken.npz"
    broken.write_bytes(data[:size])
    with pytest.raises(ValueError, match=r"broken\.npz") as raised:
        load_retrieval(broken)
    assert "Traceback" not in str(raised.value)


def test_a_npy_array_named_npz_is_a_clear_error(tmp_path):
    path = tmp_path / "array.npz"
    with path.open("wb") as handle:
        np.save(handle, np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"array\.npz is a \.npy array, not a retrieval file"):
        load_retrieval(path)


def test_evaluate_command_reports_a_truncated_retrieval_file_in_one_line(saved, tmp_path, capsys):
    path, _ = saved
    broken = tmp_path / "broken.npz"
    broken.write_bytes(path.read_bytes()[:100])
    assert main(["evaluate", str(broken)]) == 2
    error = capsys.readouterr().err
    assert "broken.npz" in error and len(error.strip().splitlines()) == 1


# --- 3. d² = 2 − 2s only for cosine similarities --------------------------------------------------------------------


@pytest.mark.parametrize("method", [l2_distance, perceptual_aliasing])
@pytest.mark.parametrize(
    "scores",
    [np.array([[90, 40, 10], [70, 60, 5]]), np.array([[3.5, 2.0, 1.5], [2.5, 1.2, 1.1]]), np.array([[-1.2, -1.5]])],
)
def test_l2_and_pa_refuse_similarities_outside_minus_one_one(method, scores):
    name = "L2" if method is l2_distance else "PA"
    with pytest.raises(ValueError, match=rf"{name} needs descriptor distances: the similarities lie in \[.*outside"):
        method(scores)


def test_l2_and_pa_accept_rounding_above_one_and_real_distances():
    scores = np.array([[1.0004, 0.5], [0.9, 0.2]], dtype=np.float32)
    assert np.isfinite(l2_distance(scores)).all() and np.isfinite(perceptual_aliasing(scores)).all()
    big = np.array([[90.0, 40.0], [70.0, 60.0]])
    distances = np.array([[1.0, 4.0], [2.0, 3.0]])
    np.testing.assert_allclose(l2_distance(big, distances=distances), [1.0, np.sqrt(2.0)], rtol=1e-12)
    np.testing.assert_allclose(perceptual_aliasing(big, distances=distances), [0.5, np.sqrt(2 / 3)], rtol=1e-12)


def test_the_conversion_keeps_missing_candidates_and_names_no_method_by_default():
    np.testing.assert_array_equal(squared_distances_from_similarities(np.array([[0.5, -np.inf]])), [[1.0, np.inf]])
    with pytest.raises(ValueError, match="converting similarities to distances needs"):
        squared_distances_from_similarities(np.array([[2.0]]))
    np.testing.assert_array_equal(squared_distances_from_similarities(np.array([[2.0]]), check=False), [[0.0]])


def test_evaluate_on_an_integer_matrix_refuses_l2_instead_of_starring_a_constant(tmp_path):
    similarity, positives = _matrix()
    matrix_path, gt_path = tmp_path / "int.npy", tmp_path / "gt.json"
    np.save(matrix_path, (similarity * 100).astype(np.int64))
    gt_path.write_text(json.dumps(positives))
    retrieval = read_results(matrix_path, ground_truth=gt_path)
    with pytest.raises(ValueError, match=r"L2 needs descriptor distances: the similarities lie in \[\d+, 95\]"):
        evaluate(retrieval, ["SU", "L2"], timing_repeats=1)
    with pytest.raises(ValueError, match="PA needs"):
        evaluate(retrieval, ["PA"], timing_repeats=1)
    assert evaluate(retrieval, ["SU", "BM"], timing_repeats=1).methods["SU"].informative


def test_sue_refuses_similarities_outside_minus_one_one():
    from vpr_uncertainty.methods import get_method

    retrieval = _retrieval()
    retrieval.distances = None
    retrieval.scores = retrieval.scores * 10
    with pytest.raises(ValueError, match="SUE needs descriptor distances"):
        get_method("SUE")(retrieval, k=4)


# --- 4. tied uncertainties are uninformative, never best ------------------------------------------------------------


def _all_equal_retrieval() -> Retrieval:
    n_queries, n_database = 37, 40
    similarity = np.full((n_queries, n_database), 0.5, dtype=np.float32)
    scores, indices = top_k_from_similarity(similarity, 10)
    positives = np.zeros((n_queries, n_database), dtype=bool)
    positives[:, 0] = True  # every top-1 is image 0 (lowest index wins ties)
    positives[1:, 0] = np.arange(1, n_queries) % 3 == 0
    positives[~positives[:, 0], 5] = True
    return Retrieval(scores=scores, indices=indices, positives=sparse.csr_array(positives))


def test_all_equal_matrix_is_uninformative_and_nothing_is_starred():
    evaluation = evaluate(_all_equal_retrieval(), ["RS", "SD", "SU", "BM", "L2", "PA"], timing_repeats=1)
    result = evaluation.to_dict()
    assert all(m["informative"] is False and m["distinct_values"] == 1 for m in result["methods"].values())
    table = format_table(evaluation)
    assert "*" not in table.split("\n", 2)[2].split("no best AUC-PR")[0]
    assert "RS†" in table and "uninformative" in table
    assert any("the same uncertainty for all 37 queries" in note for note in result["notes"])


def test_a_single_informative_method_is_not_declared_best():
    retrieval = _all_equal_retrieval()
    retrieval.scores[::2, 1:] -= 0.1  # only some queries get a margin: RS/SD/SU vary, BM stays constant
    evaluation = evaluate(retrieval, ["SU", "BM"], timing_repeats=1)
    assert evaluation.methods["SU"].informative and not evaluation.methods["BM"].informative
    table = format_table(evaluation)
    assert "SU*" not in table and "BM*" not in table and "fewer than two informative methods" in table


def test_the_best_informative_method_is_starred_and_a_tied_one_is_not():
    retrieval = _all_equal_retrieval()
    retrieval.scores[::2, 1:] -= 0.1
    retrieval.scores[::3, 2:] -= 0.05
    evaluation = evaluate(retrieval, ["RS", "SD", "BM"], timing_repeats=1)
    table = format_table(evaluation)
    best = max(("RS", "SD"), key=lambda name: evaluation.methods[name].auc_pr)
    assert f"{best}*" in table and "BM†" in table and "BM*" not in table


def test_table1_never_bolds_an_uninformative_cell():
    table = Table1(
        rows=["SU", "BM", "L2"],
        columns=["A", "B", "Mean"],
        values=[[0.6, 0.7, 0.65], [0.9, 0.5, 0.7], [0.8, 0.4, 0.6]],
        time_ms=[1.0, 1.0, 1.0],
        informative=[[True, True, True], [False, True, True], [True, False, True]],
    )
    markdown = table1_markdown(table)
    assert "| BM | 0.900† |" in markdown and "**0.800**" in markdown and "**0.900**" not in markdown
    assert "† uninformative" in markdown
    # column B: only SU and BM are informative -> SU (0.7) is best; column A: L2 (0.8) beats SU (0.6)
    assert "**0.700**" in markdown
    assert "0.900$^\\dagger$" in table1_latex(table) and "<td>0.900†</td>" in table1_html(table)
    rows = {row.split(",")[0]: row.split(",")[-1] for row in table1_csv(table).splitlines()[1:]}
    assert rows["BM"] == "Mean" and rows["L2"] == "A"


def test_table1_from_cells_marks_the_all_equal_cell():
    from types import SimpleNamespace

    tied = evaluate(_all_equal_retrieval(), ["SU", "BM"], timing_repeats=1)
    similarity, _ = _matrix()
    scores, indices = top_k_from_similarity(similarity, 10)
    positives = sparse.csr_array(np.eye(*similarity.shape, dtype=bool))
    real = Retrieval(scores=scores, indices=indices, positives=positives)
    informative = evaluate(real, ["SU", "BM"], timing_repeats=1)
    cells = [
        SimpleNamespace(vpr_method="flat", dataset="d", evaluation=tied),
        SimpleNamespace(vpr_method="real", dataset="d", evaluation=informative),
    ]
    table = build_table1(cells)
    assert table.informative[0][:2] == [False, True]
    assert table.best()[0] is None  # no informative value in the "flat" column


# --- 5. the s_1 <= 0 rule is counted and pointed to -----------------------------------------------------------------


def test_queries_with_nonpositive_best_similarity_are_counted_in_the_notes():
    retrieval = _retrieval(n_queries=12, k=5, n_database=20)
    retrieval.scores[[2, 7, 9]] -= 1.0  # s_1 <= 0 for three queries
    evaluation = evaluate(retrieval, ["SU", "BM"], timing_repeats=1)
    (note,) = [note for note in evaluation.to_dict()["notes"] if "s_1 <= 0" in note]
    assert note.startswith("3 of 12 queries have a best similarity s_1 <= 0: SU rank them as the most uncertain")
    assert "docs/explanation/conventions.md" in note
    lines = [line for line in format_table(evaluation).splitlines() if "s_1 <= 0" in line]
    assert len(lines) == 1 and lines[0].startswith("note: 3 of 12 queries")


def test_the_nonpositive_note_names_every_method_that_divides_by_the_best_similarity():
    """SU-adaptive divides by s_1 as RS, SD and SU do (its entry says scores="similarity"): it is named too."""
    retrieval = _retrieval(n_queries=12, k=5, n_database=20)
    retrieval.scores[[2, 7]] -= 1.0
    evaluation = evaluate(retrieval, ["SU", "SU-adaptive", "BM"], k=5, timing_repeats=1)
    (note,) = [note for note in evaluation.notes if "s_1 <= 0" in note]
    assert note.startswith("2 of 12 queries have a best similarity s_1 <= 0: SU, SU-adaptive rank them")


def test_no_nonpositive_note_without_ratio_methods_or_without_such_queries():
    retrieval = _retrieval(n_queries=12, k=5, n_database=20)
    assert not any("s_1" in note for note in evaluate(retrieval, ["SU"], timing_repeats=1).notes)
    retrieval.scores -= 1.0
    assert not any("s_1" in note for note in evaluate(retrieval, ["BM"], timing_repeats=1).notes)


@pytest.mark.realdata
def test_corridor_matrices_have_no_query_with_nonpositive_best_similarity(corridor_matches_dir, corridor_dir):
    """denseVLAD has negative similarities on the corridor, but no query whose best one is <= 0: no note."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        retrieval = read_results(
            corridor_matches_dir / "denseVLAD" / "precomputed_data_corrected.npy",
            ground_truth=corridor_dir / "ground_truth_new.npy",
        )
        evaluation = evaluate(retrieval, ["SU", "L2", "PA"], timing_repeats=1)
    assert not any("s_1" in note for note in evaluation.notes)
    assert all(method.informative for method in evaluation.methods.values())
