"""`vpr-uncertainty retrieve` then `vpr-uncertainty evaluate retrieval.npz`, end to end."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from vpr_uncertainty import cli
from vpr_uncertainty.pipeline import retrieve as retrieve_command
from vpr_uncertainty.retrieval import load_retrieval

pytest.importorskip("faiss")


def run_retrieve(argv: list[str], *, through_cli: bool = True) -> int:
    """Through the CLI when the command is wired (errors become exit status 2), else through its own parser."""
    if through_cli:
        return cli.main(["retrieve", *argv])
    parser = argparse.ArgumentParser(prog="vpr-uncertainty")
    retrieve_command.add_cli(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["retrieve", *argv])
    return args.handler(args)


@pytest.fixture
def problem(tmp_path):
    """Descriptors that follow positions along a road, written as .npy files."""
    rng = np.random.default_rng(0)
    n_database, n_queries, dim = 300, 60, 32
    database_positions = np.column_stack([np.arange(n_database) * 8.0, rng.normal(scale=2, size=n_database)])
    database_positions += [584000.0, 4477000.0]
    source = rng.integers(0, n_database, size=n_queries)
    query_positions = database_positions[source] + rng.normal(scale=4.0, size=(n_queries, 2))
    database = rng.standard_normal((n_database, dim)).astype(np.float32)
    noise = rng.uniform(0.3, 4.0, size=(n_queries, 1))
    queries = (database[source] + noise * rng.standard_normal((n_queries, dim))).astype(np.float32)
    paths = {}
    for name, array in {
        "db": database,
        "q": queries,
        "db_pos": database_positions,
        "q_pos": query_positions,
    }.items():
        paths[name] = tmp_path / f"{name}.npy"
        np.save(paths[name], array)
    return paths


def test_retrieve_then_evaluate_with_no_other_argument(problem, tmp_path, capsys):
    out = tmp_path / "runs" / "retrieval.npz"
    status = run_retrieve(
        [
            "--database", str(problem["db"]),
            "--queries", str(problem["q"]),
            "--out", str(out),
            "--database-positions", str(problem["db_pos"]),
            "--query-positions", str(problem["q_pos"]),
            "--radius", "25",
            "--no-progress",
        ]
    )  # fmt: skip
    assert status == 0
    printed = capsys.readouterr().out
    assert "wrote" in printed and "recall@1" in printed
    retrieval = load_retrieval(out)
    assert retrieval.k == 10 and retrieval.positives is not None and retrieval.database_positions is not None
    assert retrieval.config["position_kind"] == "metres" and retrieval.config["database"] == str(problem["db"])

    assert cli.main(["evaluate", str(out)]) == 0
    table = capsys.readouterr().out
    for method in ("SU", "PA", "L2", "BM"):
        assert method in table

    results = tmp_path / "results.json"
    assert cli.main(["evaluate", str(out), "--methods", "SU,SUE,PA", "--json", str(results)]) == 0
    summary = json.loads(results.read_text())
    assert set(summary["methods"]) == {"SU", "SUE", "PA"}
    assert 0 < summary["recall@1"] < 1
    assert summary["methods"]["SUE"]["auc_pr"] is not None


def test_retrieve_without_positions_then_evaluate_asks_for_ground_truth(problem, tmp_path, capsys):
    out = tmp_path / "r.npz"
    argv = ["--database", str(problem["db"]), "--queries", str(problem["q"]), "--out", str(out), "--top-k", "5"]
    assert run_retrieve([*argv, "--index", "HNSW16", "--search-params", "efSearch=64"]) == 0
    retrieval = load_retrieval(out)
    assert retrieval.k == 5 and retrieval.positives is None and retrieval.config["index"] == "HNSW16"
    assert cli.main(["evaluate", str(out)]) == 2
    assert "ground truth" in capsys.readouterr().err


def test_retrieve_with_explicit_ground_truth(problem, tmp_path):
    gt = tmp_path / "gt.json"
    gt.write_text(json.dumps([[i % 300] for i in range(60)]))
    out = tmp_path / "r.npz"
    argv = ["--database", str(problem["db"]), "--queries", str(problem["q"]), "--out", str(out), "--gt", str(gt)]
    assert run_retrieve(argv) == 0
    retrieval = load_retrieval(out)
    assert retrieval.positives.shape == (60, 300) and retrieval.positives.nnz == 60


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--device", "cuda"], "GPU Faiss"),
        (["--database-positions", "{q_pos}"], "database positions must have shape"),
        (["--index", "Nonsense"], "index-factory"),
    ],
)
def test_retrieve_errors_are_clear(problem, tmp_path, extra, message):
    import faiss

    if "cuda" in extra and hasattr(faiss, "StandardGpuResources") and faiss.get_num_gpus() > 0:
        pytest.skip("a GPU is available")
    extra = [item.format(**{key: str(value) for key, value in problem.items()}) for item in extra]
    argv = ["--database", str(problem["db"]), "--queries", str(problem["q"]), "--out", str(tmp_path / "r.npz")]
    with pytest.raises(ValueError, match=message):
        run_retrieve([*argv, *extra], through_cli=False)


def test_retrieve_through_the_wired_cli(problem, tmp_path, monkeypatch, capsys):
    argv = ["retrieve", "--database", str(problem["db"]), "--queries", str(problem["q"])]
    assert cli.main([*argv, "--out", str(tmp_path / "r.npz"), "--top-k", "3"]) == 0
    assert load_retrieval(tmp_path / "r.npz").k == 3
    assert cli.main([*argv, "--out", str(tmp_path / "r.npz"), "--index", "Nonsense"]) == 2
    assert "index-factory" in capsys.readouterr().err


@pytest.mark.realdata
def test_sue_on_real_pittsburgh_positions(data_dir):
    """Synthetic descriptors that vary with the real Pittsburgh30k camera positions (UTM, ~4.5e6 m).

    Pittsburgh photographs every place 24 times (headings and pitches) from one position: when the descriptors
    depend on the position alone, the top-10 all lie at one place and SUE is exactly 0 (the limiting case).
    """
    from sklearn.metrics import roc_auc_score

    from vpr_uncertainty import evaluate
    from vpr_uncertainty.data.dataset import attach_ground_truth
    from vpr_uncertainty.retrieval import retrieve

    poses = np.load(data_dir / "poses" / "pitts30k_test.npz")
    database_positions, query_positions = poses["utmDb"], poses["utmQ"][::8]
    rng = np.random.default_rng(0)
    directions = rng.normal(scale=1 / 40.0, size=(2, 64))  # descriptors vary over tens of metres
    phases = rng.uniform(0, 2 * np.pi, size=64)

    def features(positions, noise):
        clean = np.cos((positions - database_positions.mean(axis=0)) @ directions + phases)
        return (clean + noise * rng.standard_normal(clean.shape)).astype(np.float32)

    options = {"database_positions": database_positions, "query_positions": query_positions, "radius": 25.0}
    queries = features(query_positions, rng.uniform(0.0, 2.0, size=(len(query_positions), 1)))
    same_place = attach_ground_truth(retrieve(features(database_positions, 0.0), queries, top_k=10), **options)
    assert same_place.config["position_kind"] == "metres"
    assert (evaluate(same_place, ["SUE"], timing_repeats=1).methods["SUE"].uncertainty == 0).all()

    result = attach_ground_truth(retrieve(features(database_positions, 0.5), queries, top_k=10), **options)
    evaluation = evaluate(result, ["SUE"], timing_repeats=1)
    uncertainty = evaluation.methods["SUE"].uncertainty
    assert 0.5 < evaluation.recall_at_n[1] < 0.95
    assert np.isfinite(uncertainty).all() and (uncertainty >= 0).all()
    assert roc_auc_score(~evaluation.correct, uncertainty) > 0.5  # wrong answers are more spread out


def test_retrieve_from_a_descriptor_cache(tmp_path, capsys):
    """The HDF5 cache of the feature extraction, written here by hand in its documented layout."""
    h5py = pytest.importorskip("h5py")
    cache = pytest.importorskip("vpr_uncertainty.descriptors.cache")
    rng = np.random.default_rng(3)
    path = tmp_path / "descriptors.h5"
    with h5py.File(path, "w") as handle:
        handle.attrs["format"] = cache.FORMAT
        handle.attrs["format_version"] = cache.FORMAT_VERSION
        for split, count in (("database", 40), ("queries", 6)):
            group = handle.create_group(split)
            group.attrs["complete"] = True
            values = rng.standard_normal((count, 16))
            values /= np.linalg.norm(values, axis=1, keepdims=True)
            group.create_dataset("descriptors", data=values.astype(np.float16))  # float16 storage: renormalised
            names = [f"{split}/{i:03d}.jpg" for i in range(count)]
            group.create_dataset("names", data=names, dtype=h5py.string_dtype())
    out = tmp_path / "r.npz"
    assert (
        cli.main(["retrieve", "--database", str(path), "--queries", str(path), "--out", str(out), "--top-k", "4"]) == 0
    )
    retrieval = load_retrieval(out)
    assert retrieval.query_names.tolist() == [f"queries/{i:03d}.jpg" for i in range(6)]
    assert retrieval.database_names[39] == "database/039.jpg" and retrieval.n_database == 40
    assert retrieval.scores.shape == (6, 4) and np.all(retrieval.scores <= 1 + 1e-6)
