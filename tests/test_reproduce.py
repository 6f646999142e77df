"""The reproduction grid on the ten real VPR-Bench corridor matrices: same numbers as `evaluate`, ablations,
caching, figures of the expected size, report.html rendered in headless Chromium, config validation."""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import struct
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest
from sklearn.metrics import auc, average_precision_score, precision_recall_curve

from conftest import assert_close
from vpr_uncertainty import evaluate
from vpr_uncertainty.data import read_results
from vpr_uncertainty.pipeline import grid as reproduce_command
from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_reports, write_results
from vpr_uncertainty.reports.plots import ablation_figsize, heatmap_figure_size, heatmap_spec, qualitative_figsize
from vpr_uncertainty.reports.style import DPI

METHODS = ["RS", "SD", "SU", "PA", "L2", "BM"]
CHROMIUM = Path("/usr/bin/chromium")


def _ci() -> bool:
    return os.environ.get("CI", "").lower() in {"1", "true", "yes"}


def _main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    reproduce_command.add_cli(parser.add_subparsers())
    args = parser.parse_args(["reproduce", *argv])
    return args.handler(args)


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    assert len(data) > 2000, f"{path} is suspiciously small ({len(data)} bytes)"
    return struct.unpack(">II", data[16:24])


def _write_config(path: Path, corridor_matches_dir: Path, corridor_dir: Path, **extra: str) -> Path:
    lines = [f'out = "{path.parent / "out"}"', f"methods = {json.dumps(METHODS)}", "k = 10"]
    lines += [f"{key} = {value}" for key, value in extra.items()]
    lines += [
        "[[inputs]]",
        f'precomputed_matches = "{corridor_matches_dir}"',
        f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"',
        f'images = "{corridor_dir}"',
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def grid(tmp_path_factory, corridor_matches_dir, corridor_dir):
    """The grid and its reports, written once for this module."""
    config_path = _write_config(tmp_path_factory.mktemp("grid") / "grid.toml", corridor_matches_dir, corridor_dir)
    config = load_config(config_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cells = run_grid(config, progress=False)
        paths = write_results(cells, config)
        paths.update(write_reports(cells, config))
    return config, cells, paths


def _reference_uncertainties(scores: np.ndarray, k: int = 10, alpha: float = 0.5) -> dict[str, np.ndarray]:
    """RS, SD, SU, BM, L2 and PA written out row by row from their definitions (README, Conventions)."""
    top = scores[:, :k].astype(np.float64)
    rs = np.array([np.mean(row[1:] / row[0]) for row in top])
    sd = np.array([np.median(row) / row[0] for row in top])
    distances = np.sqrt(np.maximum(2.0 - 2.0 * scores[:, :2].astype(np.float64), 0.0))
    pa = np.array([1.0 if d2 == 0 else d1 / d2 for d1, d2 in distances])
    return {"RS": rs, "SD": sd, "SU": alpha * rs + (1 - alpha) * sd, "BM": -top[:, 0], "L2": distances[:, 0], "PA": pa}


def _reference_aurc(correct: np.ndarray, uncertainty: np.ndarray) -> float:
    """Loop over the distinct thresholds: coverage gained × error rate among the accepted queries."""
    area, covered = 0.0, 0
    for threshold in sorted(set(uncertainty.tolist())):
        accepted = uncertainty <= threshold
        area += (accepted.sum() - covered) / len(correct) * (1 - correct[accepted].mean())
        covered = accepted.sum()
    return area


@pytest.mark.realdata
def test_grid_numbers_match_independent_references(grid, corridor_matches_dir, corridor_dir):
    """Every cell against the definitions: correctness by a loop over the ground truth, the uncertainties
    from their formulas, AUC-PR and AP by scikit-learn directly, AURC by a loop."""
    _, cells, paths = grid
    assert len(cells) == 10
    by_name = {cell.vpr_method: cell for cell in cells}
    assert sorted(by_name) == sorted(p.name for p in corridor_matches_dir.iterdir() if p.is_dir())
    rows = list(csv.DictReader(paths["results_csv"].open()))
    assert len(rows) == 10 * len(METHODS)
    document = json.loads(paths["results_json"].read_text())
    for name, cell in by_name.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            retrieval = read_results(
                corridor_matches_dir / name / "precomputed_data_corrected.npy",
                ground_truth=corridor_dir / "ground_truth_new.npy",
            )
        positives = retrieval.positives.toarray()
        correct = np.array([bool(positives[q, retrieval.indices[q, 0]]) for q in range(retrieval.n_queries)])
        np.testing.assert_array_equal(cell.evaluation.correct, correct)
        assert_close(cell.evaluation.recall_at_n[1], correct[positives.any(axis=1)].mean())
        stored = next(c for c in document["cells"] if c["vpr_method"] == name)
        for method, uncertainty in _reference_uncertainties(np.asarray(retrieval.scores)).items():
            got = cell.evaluation.methods[method]
            assert_close(got.uncertainty, uncertainty, rtol=1e-5)
            precision, recall, _ = precision_recall_curve(correct, -got.uncertainty)
            expected_auc_pr = auc(recall, precision)
            assert_close(got.auc_pr, expected_auc_pr)
            assert_close(got.average_precision, average_precision_score(correct, -got.uncertainty))
            assert_close(got.aurc, _reference_aurc(correct, np.asarray(got.uncertainty, dtype=np.float64)))
            assert_close(stored["methods"][method]["auc_pr"], expected_auc_pr)
            row = next(r for r in rows if r["vpr_method"] == name and r["uncertainty_method"] == method)
            assert row["dataset"] == "corridor"
            assert_close(float(row["auc_pr"]), expected_auc_pr)
            assert_close(float(row["recall@1"]), cell.evaluation.recall_at_n[1])
    # The published NetVLAD corridor numbers (README).
    netvlad = by_name["NetVLAD"].evaluation.methods
    assert [round(netvlad[m].auc_pr, 3) for m in ("RS", "SD", "SU", "BM", "PA")] == [0.85, 0.844, 0.847, 0.822, 0.814]


@pytest.mark.realdata
def test_alpha_ablation_ends_at_sd_and_rs(grid):
    _, cells, _ = grid
    for cell in cells:
        methods = cell.evaluation.methods
        assert_close(sorted(cell.ablation_alpha), [round(0.1 * i, 1) for i in range(11)])
        assert_close(cell.ablation_alpha[0.0], methods["SD"].auc_pr)
        assert_close(cell.ablation_alpha[1.0], methods["RS"].auc_pr)
        assert_close(cell.ablation_alpha[0.5], methods["SU"].auc_pr)
        assert sorted(cell.ablation_k["RS"]) == [2, 3, 5, 10, 15, 20, 30, 50]
        assert_close(cell.ablation_k["RS"][10], methods["RS"].auc_pr)
        assert_close(cell.ablation_k["SD"][10], methods["SD"].auc_pr)


@pytest.mark.realdata
def test_figures_are_pngs_of_the_expected_size(grid):
    _, cells, paths = grid
    # one dataset: one panel whose columns are the baselines (PA, and BM = L2: the same Δ everywhere)
    assert heatmap_spec(cells, "RS").panels == ("corridor",)
    heatmap = heatmap_figure_size(cells, "RS")
    pngs = {name: [p for p in paths[name] if p.suffix == ".png"] for name in ("heatmaps", "ablations", "pr_curves")}
    assert [p.name for p in pngs["heatmaps"]] == ["delta_RS.png", "delta_SD.png", "delta_SU.png"]
    for path in pngs["heatmaps"]:
        assert _png_size(path) == (round(heatmap[0] * DPI), round(heatmap[1] * DPI))
    assert [p.name for p in pngs["ablations"]] == ["ablation_alpha.png", "ablation_k.png"]
    # One α panel (a line per VPR method); RS and SD panels for two groups of five VPR methods, page wide.
    assert _png_size(pngs["ablations"][0]) == tuple(round(x * DPI) for x in ablation_figsize(1, 1, 11, aspect=0.55))
    assert [_png_size(path)[0] for path in pngs["ablations"]] == [round(7.16 * DPI)] * 2
    assert len(pngs["pr_curves"]) == len(cells)
    for name in ("heatmaps", "ablations", "pr_curves"):  # each PNG has its vector PDF beside it
        assert [p.with_suffix(".png") for p in paths[name] if p.suffix == ".pdf"] == pngs[name]
    (qualitative, _) = paths["qualitative"]
    size = qualitative_figsize(4)
    assert _png_size(qualitative) == (round(size[0] * DPI), round(size[1] * DPI))
    # Not blank: the qualitative figure shows photographs (many distinct colours).
    from matplotlib.image import imread

    pixels = imread(qualitative)[::3, ::3]
    assert np.unique(pixels.reshape(-1, pixels.shape[-1]), axis=0).shape[0] > 1000


@pytest.mark.realdata
def test_table1_files(grid):
    _, _, paths = grid
    markdown = paths["table1_md"].read_text()
    assert markdown.splitlines()[0].startswith("| method | AMOSNet |")
    assert "| NetVLAD |" in markdown.splitlines()[0] or "NetVLAD" in markdown.splitlines()[0]
    assert markdown.count("**") >= 2 * 11  # one best per column (ties may add more)
    rows = list(csv.DictReader(paths["table1_csv"].open()))
    assert [row["method"] for row in rows] == METHODS
    rs = next(row for row in rows if row["method"] == "RS")
    assert_close(float(rs["NetVLAD"]), 0.850, atol=5e-4)
    assert "NetVLAD" in rs["best_for"]
    latex = paths["table1_tex"].read_text()
    for command in (r"\toprule", r"\midrule", r"\bottomrule", r"\textbf{", r"ap-gem-r101"):
        assert command in latex
    # 14 columns: two columns wide (table*), and the caption says what is averaged: one dataset, so none
    assert latex.startswith(r"\begin{table*}[t]") and latex.rstrip().endswith(r"\end{table*}")
    assert r"\resizebox{\ifdim\width>\textwidth" in latex and "for each VPR method, on corridor." in latex
    assert "averaged over datasets" not in latex


@pytest.mark.realdata
def test_cells_are_cached_and_force_recomputes(grid):
    config, cells, _ = grid
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        again = run_grid(config, progress=False)
        assert all(cell.cached for cell in again)
        for old, new in zip(cells, again, strict=True):
            assert new.evaluation.methods["SU"].auc_pr == old.evaluation.methods["SU"].auc_pr
            assert new.ablation_alpha == old.ablation_alpha
            np.testing.assert_array_equal(new.evaluation.correct, old.evaluation.correct)
            np.testing.assert_array_equal(
                new.evaluation.methods["PA"].curve.precision, old.evaluation.methods["PA"].curve.precision
            )
        subset = type(config)(**{**config.__dict__, "inputs": config.inputs[:1]})
        (forced,) = run_grid(subset, force=True, progress=False)
    assert not forced.cached


@pytest.mark.realdata
def test_report_html_is_self_contained(grid):
    _, _, paths = grid
    text = paths["report_html"].read_text()
    sources = re.findall(r'<img[^>]*src="([^"]*)"', text)
    figures = ("heatmaps", "ablations", "pr_curves", "qualitative")
    n_figures = sum(path.suffix == ".png" for key in figures for path in paths[key])  # the PDFs are not embedded
    assert len(sources) == n_figures == 3 + 2 + 10 + 1
    assert all(source.startswith("data:image/png;base64,") for source in sources)
    assert "http://" not in text and "https://" not in text
    assert '<table class="table1">' in text
    assert "<h2>Table 1: AUC-PR on corridor</h2>" in text and "averaged over datasets" not in text
    assert '<table class="ties">' in text and "<pre>" not in text  # the ties as a table, not raw Markdown
    ties = text[text.index('<table class="ties">') :].split("</table>")[0]
    assert "<th>NetVLAD</th>" in ties and ties.count("<tr>") == 1 + len(METHODS)


@pytest.mark.realdata
def test_report_html_renders_in_headless_chromium(grid, tmp_path):
    if not CHROMIUM.exists():
        message = f"{CHROMIUM} not found (apt-get install -y chromium)"
        if _ci():
            pytest.fail(message)
        pytest.skip(message)
    _, _, paths = grid
    command = [
        str(CHROMIUM),
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={tmp_path / 'profile'}",
        "--virtual-time-budget=10000",
        "--dump-dom",
        paths["report_html"].resolve().as_uri(),
    ]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    marker = re.search(r"figures rendered: (\d+)/(\d+)", result.stdout)
    assert marker, f"the render check did not run; DOM starts with {result.stdout[:500]!r}"
    assert marker.group(1) == marker.group(2) == str(16)


@pytest.mark.realdata
def test_missing_inputs_are_all_reported_before_any_work(tmp_path, corridor_matches_dir, corridor_dir, monkeypatch):
    config_path = tmp_path / "grid.toml"
    config_path.write_text(
        f'out = "{tmp_path / "out"}"\nmethods = ["SU", "NOPE"]\n'
        f'[[inputs]]\nprecomputed_matches = "{corridor_matches_dir}"\nground_truth = "{tmp_path / "gt.npy"}"\n'
        f'[[inputs]]\nvpr_method = "x"\ndataset = "corridor"\nscores = "missing.npz"\n'
    )
    import vpr_uncertainty.pipeline.grid as module

    def no_work(*args, **kwargs):
        raise AssertionError("work started before the configuration was validated")

    monkeypatch.setattr(module, "run_cell", no_work)
    with pytest.raises(ValueError) as error:
        _main([str(config_path)])
    message = str(error.value)
    assert "3 problem(s)" in message
    assert "NOPE" in message
    assert f"ground truth not found: {tmp_path / 'gt.npy'}" in message
    assert f"scores file not found: {tmp_path / 'missing.npz'}" in message
    assert not (tmp_path / "out").exists()


@pytest.mark.realdata
def test_model_entry_runs_the_pipeline(tmp_path, corridor_dir, corridor_matches_dir, monkeypatch, capsys):
    """An entry with dataset + model goes through pipeline.run (stubbed here: extraction is tested elsewhere)."""
    import types

    import vpr_uncertainty.pipeline.run as pipeline

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        retrieval = read_results(
            corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy",
            ground_truth=corridor_dir / "ground_truth_new.npy",
        )
    calls = []

    def fake_run(conf, dataset, out):
        calls.append((conf, out))
        evaluation = evaluate(retrieval, conf.evaluate.methods, k=conf.evaluate.k)
        return types.SimpleNamespace(retrieval=retrieval, evaluation=evaluation, stage_seconds={"extraction": 1.5})

    monkeypatch.setattr(pipeline, "run", fake_run)
    config_path = tmp_path / "grid.toml"
    config_path.write_text(
        f'out = "out"\nmethods = ["SU", "BM"]\nks = [2, 30]\n'
        f'[[inputs]]\ndataset = "{corridor_dir}"\nmodel = "efficientnet-lite0-gem"\ndevice = "cpu"\n'
    )
    assert _main([str(config_path), "--check"]) == 0
    assert not calls and "1 cells x 2 uncertainty methods" in capsys.readouterr().out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert _main([str(config_path)]) == 0
    ((call, out),) = calls
    assert call.extract.model == "efficientnet-lite0-gem" and call.extract.device == "cpu"
    assert call.retrieve.top_k == 30 and out == tmp_path / "out" / "runs" / "efficientnet-lite0-gem__corridor"
    cell = json.loads((tmp_path / "out" / "cells" / "efficientnet-lite0-gem__corridor.json").read_text())
    assert len(cell["query_paths"]) == 111 and cell["query_paths"][0].endswith("query/0000000.jpg")
    assert cell["cell"]["stage_seconds"]["pipeline_extraction"] == 1.5  # the pipeline's stages, per cell
    assert (tmp_path / "out" / "figures" / "qualitative__efficientnet-lite0-gem__corridor.png").is_file()
    assert (tmp_path / "out" / "report.html").is_file()


@pytest.mark.realdata
def test_image_methods_get_the_images_of_the_config(tmp_path, corridor_matches_dir, corridor_dir):
    """Regression: the grid did not pass the config's images to geometric verification, which then failed."""
    lines = [
        f'out = "{tmp_path / "out"}"',
        'methods = ["SU", "GV-SIFT"]',
        "alphas = []",
        "ks = []",
        "[[inputs]]",
        'vpr_method = "NetVLAD"',
        'dataset = "corridor"',
        f'scores = "{corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"}"',
        f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"',
        f'images = "{corridor_dir}"',
    ]
    (tmp_path / "gv.toml").write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (cell,) = run_grid(load_config(tmp_path / "gv.toml"), progress=False)
    sift = cell.evaluation.methods["GV-SIFT"]
    assert sift.auc_pr > cell.evaluation.methods["SU"].auc_pr - 0.1  # a real verification, not a constant
    assert len(np.unique(sift.uncertainty)) > 5
    assert list((tmp_path / "out" / "local_features").glob("sift-*.h5"))


def test_grid_main_runs_a_config_file_and_returns_results_json(tmp_path, corridor_matches_dir, corridor_dir):
    from vpr_uncertainty.pipeline import grid

    config_path = tmp_path / "grid.toml"
    config_path.write_text(
        f'out = "out"\nmethods = ["SU", "BM"]\nalphas = []\nks = []\n[[inputs]]\nvpr_method = "NetVLAD"\n'
        f'dataset = "corridor"\nscores = "{corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"}"\n'
        f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"\n'
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        path = grid.main(config_path, tmp_path / "elsewhere", report=False)
    assert path == tmp_path / "elsewhere" / "results.json"
    document = json.loads(path.read_text())
    assert document["cells"][0]["vpr_method"] == "NetVLAD"


def test_a_misspelt_config_key_gets_the_near_one(tmp_path, capsys):
    """Issue 45, item 7: the config key ``bootstrp`` listed the valid keys without 'bootstrap'."""
    from vpr_uncertainty.cli import main

    (tmp_path / "c.toml").write_text('out = "x"\nbootstrp = 200\n[[inputs]]\nscores = "a.npy"\n')
    assert main(["reproduce", str(tmp_path / "c.toml")]) == 2
    assert "unknown top-level key 'bootstrp'; did you mean 'bootstrap'?" in capsys.readouterr().err
