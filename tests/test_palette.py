"""One palette (issue 45, item 6): at least 12 series told apart by colour and by marker, no method drawn with the
best-α star, and a method keeps its colour and marker in every figure of a study (``reproduce``'s report)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from vpr_uncertainty import Retrieval, evaluate, register_method
from vpr_uncertainty.methods import METHODS
from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_reports
from vpr_uncertainty.reports import REPORT_FIGURES, register_report_figure
from vpr_uncertainty.reports.display import draw_rejection_curves
from vpr_uncertainty.reports.style import PALETTE, method_styles, pyplot, study_styles
from vpr_uncertainty.retrieval import save_retrieval

#: The issue's study: the built-in methods, a cascade and two plugin methods (ENT and GAP2 hash to one slot).
STUDY = ["RS", "SD", "SU", "BM", "L2", "PA", "margin", "GV-SIFT", "SU+GV-SIFT", "ENT", "GAP2"]


def _pairs(styles: dict) -> tuple[set, set]:
    return {s["color"] for s in styles.values()}, {s["marker"] for s in styles.values()}


@pytest.mark.parametrize("n", [2, 7, 8, 11, 12])
def test_up_to_twelve_series_share_neither_colour_nor_marker(n):
    """Okabe-Ito's seven colours repeated from the eighth series on: SU+GV-SIFT green like SU, a plugin pink like
    BM; GV-SIFT and SU+GV-SIFT shared the ">" marker."""
    for names in ([*STUDY, "SUE"][:n], [*STUDY, "SUE"][-n:], [f"plugin{i}" for i in range(n)]):
        colours, markers = _pairs(method_styles(names))
        assert len(colours) == len(markers) == n, names
    assert len(set(PALETTE)) == 12 and "#F0E442" not in PALETTE  # no yellow: faint on white
    styles = method_styles(STUDY)
    assert styles["GV-SIFT"]["marker"] != styles["SU+GV-SIFT"]["marker"]
    assert styles["SU+GV-SIFT"]["color"] != styles["SU"]["color"]


def test_no_method_is_drawn_with_the_star_that_marks_the_best_alpha():
    """HybridNet, the 19th styled name, was drawn with stars in the α ablation, whose big stars mark each best α."""
    vpr = ["AMOSNet", "AlexNet_VPR", "CALC", "CoHOG", "HOG", "HybridNet", "NetVLAD", "RegionVLAD", "ap-gem-r101"]
    for names in (STUDY, [*vpr, "denseVLAD"], [f"m{i}" for i in range(40)]):
        assert all(style["marker"] != "*" for style in method_styles(names).values())


def test_a_name_keeps_its_style_in_every_figure_of_a_study():
    """A figure with ENT alone drew it olive with pentagons, the study's PR curve wine-red: by the figure's names."""
    with study_styles(STUDY):
        whole = method_styles(STUDY)
        for subset in (["ENT"], ["GAP2", "SU"], ["margin = GAP2", "GV-SIFT"], STUDY[::-1]):
            styles = method_styles(subset)
            assert all(styles[name] == whole[name.split(" = ")[0]] for name in subset), subset
        vpr = method_styles(["HOG", "CALC"])  # names of another kind (VPR methods): styled among themselves
    assert method_styles(["ENT"]) != whole["ENT"]  # outside the block: the figure's names alone
    assert vpr == method_styles(["HOG", "CALC"])


@pytest.fixture
def plugin_methods():
    """ENT and GAP2 of the issue's plugin (hashed to the same slot), unregistered afterwards."""
    register_method("ENT", lambda retrieval, *, k=10: -retrieval.scores[:, 0], description="entropy stand-in")
    register_method(
        "GAP2", lambda retrieval, *, k=10: retrieval.scores[:, 1] - retrieval.scores[:, 0], description="gap"
    )
    yield
    for name in ("ENT", "GAP2"):
        METHODS.unregister(name)


def test_pr_curves_of_two_cells_draw_a_method_alike(plugin_methods):
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((60, 6)), axis=1)
    positives = np.zeros((60, 6), dtype=bool)
    positives[np.arange(60), rng.integers(0, 3, 60)] = True
    retrieval = Retrieval(scores=scores, indices=np.tile(np.arange(6), (60, 1)), positives=positives)
    drawn = []
    with study_styles(["SU", "ENT", "GAP2"]):
        for methods in (["SU", "ENT", "GAP2"], ["GAP2", "SU"]):
            figure = draw_rejection_curves(evaluate(retrieval, methods, k=5))
            try:
                lines = figure.axes[0].get_lines()
                drawn.append({line.get_label().split(" ")[0]: (line.get_color(), line.get_marker()) for line in lines})
            finally:
                pyplot().close(figure)
    assert drawn[0]["GAP2"] == drawn[1]["GAP2"] and drawn[0]["SU"] == drawn[1]["SU"]


def test_reproduce_styles_a_method_as_in_the_whole_study(tmp_path, plugin_methods):
    """write_reports draws every figure inside study_styles: a figure of GAP2 alone styles it as the PR curves do."""
    rng = np.random.default_rng(1)
    scores = -np.sort(-rng.random((30, 5)), axis=1).astype(np.float32)
    positives = np.zeros((30, 5), dtype=bool)
    positives[np.arange(30), rng.integers(0, 2, 30)] = True
    save_retrieval(
        Retrieval(scores=scores, indices=np.tile(np.arange(5), (30, 1)), positives=positives), tmp_path / "a.npz"
    )
    lines = ['out = "out"', 'methods = ["SU", "ENT", "GAP2"]', "k = 5", "alphas = []", "ks = []", "[[inputs]]"]
    (tmp_path / "grid.toml").write_text("\n".join([*lines, 'vpr_method = "A"', 'dataset = "d"', 'scores = "a.npz"']))
    seen = []
    register_report_figure(
        "styles", lambda cells, config, out: seen.append(method_styles(["GAP2"])) or [], description="x"
    )
    try:
        config = load_config(tmp_path / "grid.toml")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            write_reports(run_grid(config, progress=False), config, figures=["styles"], html=False)
    finally:
        REPORT_FIGURES.unregister("styles")
    assert seen == [{"GAP2": method_styles(["SU", "ENT", "GAP2"])["GAP2"]}]
    assert seen[0]["GAP2"] != method_styles(["GAP2"])["GAP2"]  # GAP2 alone, outside a study, takes ENT's slot
