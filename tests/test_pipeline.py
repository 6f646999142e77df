"""The end-to-end pipeline (`run`, `demo`) on the real corridor images with the offline default model."""

from __future__ import annotations

import json
import shutil
import urllib.error

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty.cli import main
from vpr_uncertainty.data import named_datasets as download
from vpr_uncertainty.methods import default_method_names

pytest.importorskip("torch")
pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")


@pytest.fixture(scope="module")
def demo_run(data_dir, tmp_path_factory):
    """One demo run shared by the tests of this module (extraction is the slow part)."""
    out = tmp_path_factory.mktemp("demo")
    status = main(["demo", "--root", str(data_dir), "--no-download", "--out", str(out)])
    assert status == 0
    return out


def test_demo_evaluates_every_score_only_method_on_every_query(demo_run):
    results = json.loads((demo_run / "results.json").read_text())
    assert results["n_queries"] == 111
    # 111 database images with about 4 positives each: chance recall@1 is below 0.05
    assert results["recall@1"] > 0.4
    # the default list of evaluate (the registry's default entries); no SUE: the corridor has no positions
    assert set(results["methods"]) == set(default_method_names())
    uncertainties = np.load(demo_run / "uncertainties.npz")
    for name in default_method_names():
        assert uncertainties[name].shape == (111,) and np.isfinite(uncertainties[name]).all()
    assert_close(uncertainties["correct"].mean(), results["recall@1"])
    for stage in ("extraction", "retrieval", "uncertainty_and_evaluation"):
        assert results["stage_seconds"][stage] >= 0
    assert (demo_run / "results.md").read_text().startswith("# corridor")
    assert (demo_run / "pr_curves.png").stat().st_size > 10_000


def test_rerun_reuses_descriptors_and_retrieval(demo_run, data_dir, monkeypatch):
    from vpr_uncertainty.descriptors import extract

    calls = []
    original = extract._forward
    monkeypatch.setattr(extract, "_forward", lambda *args: calls.append(1) or original(*args))
    retrieval_mtime = (demo_run / "retrieval.npz").stat().st_mtime_ns
    before = json.loads((demo_run / "results.json").read_text())
    assert main(["demo", "--root", str(data_dir), "--no-download", "--out", str(demo_run)]) == 0
    after = json.loads((demo_run / "results.json").read_text())
    assert calls == []  # no image went through the model again
    assert (demo_run / "retrieval.npz").stat().st_mtime_ns == retrieval_mtime
    assert after["methods"]["SU"]["auc_pr"] == before["methods"]["SU"]["auc_pr"]


def test_run_with_unknown_method_fails_before_any_work(tmp_path, corridor_dir, capsys):
    with pytest.raises(SystemExit):
        main(["run", "--dataset", str(corridor_dir), "--out", str(tmp_path / "run"), "--methods", "SU,XX"])
    assert "unknown uncertainty method 'XX'" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_corridor_checksums_match_the_real_data(corridor_dir):
    assert download.verify_corridor(corridor_dir) == []
    assert download.ensure_corridor(corridor_dir.parent.parent, download=False) == corridor_dir


def test_missing_corridor_says_where_to_put_it(tmp_path, monkeypatch):
    with pytest.raises(FileNotFoundError, match=r"223 corridor files are missing.*Put the VPR-Bench corridor"):
        download.ensure_corridor(tmp_path, download=False)

    def offline(*args, **kwargs):
        raise urllib.error.URLError("no network")

    monkeypatch.setattr(download.urllib.request, "urlopen", offline)
    with pytest.raises(FileNotFoundError, match=r"may be offline.*VPR_UNCERTAINTY_DATA"):
        download.ensure_corridor(tmp_path)


def test_download_verifies_checksums(tmp_path, corridor_dir, monkeypatch):
    served = tmp_path / "served"
    shutil.copytree(corridor_dir, served)
    monkeypatch.setattr(download, "CORRIDOR_URL", served.as_uri())
    target = tmp_path / "data"
    folder = download.ensure_corridor(target)
    assert folder == target / "vprbench" / "corridor" and download.verify_corridor(folder) == []

    (folder / "query" / "0000005.jpg").write_bytes(b"corrupt")  # repaired on the next call
    (served / "query" / "0000005.jpg").write_bytes(b"tampered")  # and the source is bad too
    with pytest.raises(FileNotFoundError, match=r"checksum mismatch for query/0000005\.jpg"):
        download.ensure_corridor(target)
    assert (folder / "query" / "0000005.jpg").read_bytes() == b"corrupt"  # a bad download never lands


def test_cuda_extraction_searches_on_cpu_without_gpu_faiss(monkeypatch, tmp_path, corridor_dir, capsys):
    """Regression: --device cuda was passed on to faiss-cpu, which rejects it."""
    from vpr_uncertainty import retrieval
    from vpr_uncertainty.pipeline.evaluate import EvaluateConf
    from vpr_uncertainty.pipeline.extract import ExtractConf
    from vpr_uncertainty.pipeline.run import RunConf, run

    seen = {}
    real_retrieve = retrieval.retrieve

    def spy(*args, **kwargs):
        seen["device"] = kwargs["device"]
        return real_retrieve(*args, **kwargs)

    def fake_extract(model, paths, names, cache_path, split, **options):
        seen.setdefault("extraction_devices", []).append(options["device"])
        rng = np.random.default_rng(len(split))
        descriptors = rng.normal(size=(len(names), 8)).astype(np.float32)
        return np.asarray(names), descriptors / np.linalg.norm(descriptors, axis=1, keepdims=True)

    from vpr_uncertainty.descriptors import extract, models

    monkeypatch.setattr(retrieval, "retrieve", spy)
    monkeypatch.setattr(retrieval, "faiss_gpu_available", lambda: False)
    monkeypatch.setattr(extract, "extract_descriptors", fake_extract)
    monkeypatch.setattr(models, "load_model", lambda name, device: type("M", (), {"name": name})())
    conf = RunConf(extract=ExtractConf(device="cuda"), evaluate=EvaluateConf(methods=["SU"]))
    result = run(conf, corridor_dir, tmp_path / "run")
    assert seen == {"device": "cpu", "extraction_devices": ["cuda", "cuda"]}
    assert capsys.readouterr().out == ""  # the library prints nothing: the note is returned for the command
    assert any("searching on the CPU" in note for note in result.notes)
    assert result.evaluation.methods["SU"].auc_pr is not None


def test_rerank_reports_recall_before_and_after(demo_run, corridor_dir, capsys):
    status = main(
        ["run", "--dataset", str(corridor_dir), "--out", str(demo_run), "--methods", "SU", "--rerank", "GV-SIFT"]
    )
    assert status == 0
    reranking = json.loads((demo_run / "results.json").read_text())["reranking"]
    assert reranking["method"] == "GV-SIFT" and reranking["top_k"] == 10
    results = json.loads((demo_run / "results.json").read_text())
    assert_close(reranking["global"]["1"], results["recall@1"])
    # re-ranking only reorders the top 10: recall@10 cannot change, recall@1 can
    assert_close(reranking["reranked"]["10"], reranking["global"]["10"])
    assert "re-ranking the top 10 by GV-SIFT inliers: R@1" in capsys.readouterr().out
    assert main(["run", "--dataset", str(corridor_dir), "--out", str(demo_run), "--rerank", "SU"]) == 2
    assert "rerank needs a geometric verification method" in capsys.readouterr().err


def test_method_needing_positions_fails_before_extraction(tmp_path, corridor_dir, capsys, monkeypatch):
    import vpr_uncertainty.descriptors as features

    monkeypatch.setattr(features, "extract_descriptors", lambda *a, **k: pytest.fail("extraction started"))
    assert main(["run", "--dataset", str(corridor_dir), "--out", str(tmp_path / "run"), "--methods", "SU,SUE"]) == 2
    assert "'SUE' needs database_positions, which dataset 'corridor' lacks" in capsys.readouterr().err
