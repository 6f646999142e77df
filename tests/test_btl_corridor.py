"""BTL on the real VPR-Bench corridor: descriptors of the offline model, training, evaluation, command line.

A plumbing test, not a measurement: the head is trained with the corridor queries as anchors (89 training + 22
validation) and then evaluated on those same queries, so its AUC-PR says nothing about BTL's quality. The
README's BTL figures come from benchmarks/btl_protocol.py, whose protocols (btl/protocol.py, tested in
test_btl_protocol.py) never test on a training query.

The descriptors are extracted with the offline model ``efficientnet-lite0-gem`` (default preprocessing: native
resolution) once, into an HDF5 cache kept in pytest's cache folder, so that later sessions read them back; the
cache is recomputed whenever the model's weights or preprocessing change.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from conftest import assert_close

torch = pytest.importorskip("torch")
pytest.importorskip("efficientnet_lite_pytorch")

from vpr_uncertainty.btl import btl_retrieval, load_btl_head, save_btl_head, train_btl_head  # noqa: E402
from vpr_uncertainty.btl.method import resolve_btl_inputs  # noqa: E402
from vpr_uncertainty.data.dataset import attach_ground_truth  # noqa: E402
from vpr_uncertainty.descriptors import extract_descriptors, load_model  # noqa: E402
from vpr_uncertainty.evaluation import evaluate  # noqa: E402
from vpr_uncertainty.formats.ground_truth import load_vprbench_ground_truth  # noqa: E402
from vpr_uncertainty.reports.tables import format_table  # noqa: E402
from vpr_uncertainty.retrieval import retrieve, save_retrieval  # noqa: E402

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _descriptor_cache(config: pytest.Config, tmp_path_factory) -> Path:
    """The corridor descriptors' file, kept in pytest's cache folder between runs: one per pytest-xdist worker, since
    two workers filling one HDF5 file at once fail on its lock (a fresh clone's `make test` did)."""
    pytest_cache = getattr(config, "cache", None)  # absent with -p no:cacheprovider
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    cache_root = pytest_cache.mkdir(f"vpr-uncertainty-corridor-{worker}") if pytest_cache is not None else None
    return Path(cache_root or tmp_path_factory.mktemp("corridor")) / "efficientnet-lite0-gem.h5"


def test_each_worker_fills_its_own_descriptor_file(request, tmp_path_factory, monkeypatch):
    paths = set()
    for worker in ("gw0", "gw1"):
        monkeypatch.setenv("PYTEST_XDIST_WORKER", worker)
        paths.add(_descriptor_cache(request.config, tmp_path_factory))
    assert len(paths) == 2


@pytest.fixture(scope="module")
def corridor(corridor_dir: Path, request, tmp_path_factory):
    cache = _descriptor_cache(request.config, tmp_path_factory)
    model = load_model("efficientnet-lite0-gem")
    result: dict = {"h5": cache, "gt_path": corridor_dir / "ground_truth_new.npy"}
    for split, folder in (("queries", "query"), ("database", "ref")):
        paths = sorted((corridor_dir / folder).glob("*.jpg"))
        result[f"{split}_names"], result[split] = extract_descriptors(
            model, paths, None, cache, split, batch_size=32, progress=False
        )
    result["positives"] = load_vprbench_ground_truth(result["gt_path"], n_database=len(result["database"]))
    return result


CORRIDOR = {
    "embedding_dim": 128,
    "hidden_dim": 32,
    "epochs": 8,
    "patience": 2,
    "n_negatives": 5,
    "max_positives": 5,
}


@pytest.fixture(scope="module")
def corridor_head(corridor, tmp_path_factory):
    head, history = train_btl_head(
        corridor["database"], corridor["positives"], query_descriptors=corridor["queries"], progress=False, **CORRIDOR
    )
    path = save_btl_head(head, tmp_path_factory.mktemp("btl") / "head.pt", metadata=head.metadata)
    return path, history


def test_training_on_corridor_lowers_the_validation_loss(corridor_head):
    path, history = corridor_head
    assert history.n_train_anchors == 89 and history.n_val_anchors == 22  # 20 % of the 111 queries
    assert history.best_epoch >= 1
    assert history.best_val_loss < 0.8 * history.initial_val_loss
    assert_close(load_btl_head(path).metadata["history"]["best_val_loss"], history.best_val_loss)


def test_btl_evaluated_end_to_end_with_its_own_retrieval(corridor, corridor_head):
    head_path, _ = corridor_head
    retrieval = attach_ground_truth(
        retrieve(corridor["database"], corridor["queries"], top_k=10),
        positives=corridor["positives"],
        database_names=corridor["database_names"],
        query_names=corridor["queries_names"],
    )
    h5 = str(corridor["h5"])  # descriptors read back from the cache, names checked against the retrieval
    options = {"btl_head": head_path, "query_descriptors": h5, "database_descriptors": h5}
    # the head was trained on these very queries: refused unless asked for, and then marked in every output
    with pytest.raises(ValueError, match="was trained on 111 of these 111 queries"):
        evaluate(retrieval, ["BTL", "BM", "SU"], **options)
    options["allow_train_queries"] = True
    evaluation = evaluate(retrieval, ["BTL", "BM", "SU"], **options)
    results = json.loads(json.dumps(evaluation.to_dict()))  # what `evaluate --json` writes
    btl = results["methods"]["BTL"]
    assert btl["correctness_from"] == "own retrieval" and btl["trained_on_queries"] == 111
    assert any("BTL was trained on 111 of these 111 queries" in note for note in results["notes"])
    table = format_table(evaluation)
    assert "BTL‡" in table and "BTL*" not in table and "BTL‡*" not in table
    resolved = resolve_btl_inputs(retrieval, options)  # files read by the hook
    resolved.pop("allow_train_queries")
    assert len(resolved.pop("query_keys")) == 111  # the cache's content keys: the leakage check's, not the retrieval's
    own, variance = btl_retrieval(retrieval, **resolved)
    own_correct = corridor["positives"].toarray()[np.arange(111), own.indices[:, 0]]
    assert_close(btl["own_recall@1"], own_correct.mean())
    assert 0.0 < btl["auc_pr"] <= 1.0 and 0.0 <= btl["aurc"] <= 1.0
    assert_close(evaluation.methods["BTL"].uncertainty, variance)
    assert "correctness_from" not in results["methods"]["SU"]
    assert any("BTL retrieves with its own embeddings" in note for note in results["notes"])
    with pytest.raises(ValueError, match="names"):
        reversed_names = attach_ground_truth(
            retrieve(corridor["database"], corridor["queries"], top_k=10),
            positives=corridor["positives"],
            query_names=corridor["queries_names"][::-1],
        )
        evaluate(reversed_names, ["BTL"], **options)


def _run_cli(argv: list[str]) -> int:
    from vpr_uncertainty.pipeline import train_btl

    parser = argparse.ArgumentParser(prog="vpr-uncertainty")
    train_btl.add_cli(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.handler(args)


def test_cli_on_corridor_from_positive_lists_and_from_a_run_directory(corridor, tmp_path, capsys):
    quick = ["--embedding-dim", "32", "--hidden-dim", "16", "--epochs", "1", "--negatives", "3", "--no-progress"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = _run_cli(
            ["train-btl", "--descriptors", str(corridor["h5"]), "--gt", str(corridor["gt_path"]),
             "--out", str(tmp_path / "gt.pt"), *quick]
        )  # fmt: skip
    assert code == 0 and "111 queries as anchors" in capsys.readouterr().out
    assert load_btl_head(tmp_path / "gt.pt").metadata["source"]["positives"] == str(corridor["gt_path"])

    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(corridor["h5"], run / "descriptors.h5")
    save_retrieval(
        attach_ground_truth(
            retrieve(corridor["database"], corridor["queries"]),
            positives=corridor["positives"],
            database_names=corridor["database_names"],
            query_names=corridor["queries_names"],
        ),
        run / "retrieval.npz",
    )
    assert _run_cli(["train-btl", "--run", str(run), "--out", str(run / "head.pt"), *quick]) == 0
    assert (run / "head.curve.json").is_file() and (run / "head.curve.png").is_file()
    assert load_btl_head(run / "head.pt").metadata["source"]["anchors"] == "queries"


def test_evaluate_command_refuses_training_queries_unless_allowed(corridor, corridor_head, tmp_path, capsys):
    from vpr_uncertainty.cli import main

    head_path, _ = corridor_head
    retrieval = attach_ground_truth(
        retrieve(corridor["database"], corridor["queries"], top_k=10),
        positives=corridor["positives"],
        database_names=corridor["database_names"],
        query_names=corridor["queries_names"],
    )
    path = save_retrieval(retrieval, tmp_path / "retrieval.npz")
    argv = ["evaluate", str(path), "--methods", "BTL,SU", "--btl-head", str(head_path)]
    argv += ["--descriptors", str(corridor["h5"])]
    assert main(argv) == 2
    assert "was trained on 111 of these 111 queries" in capsys.readouterr().err
    assert main([*argv, "--allow-train-queries"]) == 0
    out = capsys.readouterr().out
    assert "BTL‡" in out and "BTL was trained on 111 of these 111 queries" in out
