"""One significance rule (issue 45, item 2): the ΔAUC-PR heatmaps star exactly what the paired tests of Table 1 and
results.json call significant (Holm over one method's comparisons in its cell), and a bootstrap too small for any
difference to survive Holm says so with the size that would allow it."""

from types import SimpleNamespace

import numpy as np

from vpr_uncertainty import Retrieval, evaluate, read_results
from vpr_uncertainty.evaluation.bootstrap import significance_notice
from vpr_uncertainty.reports import plots

METHODS = ["RS", "SD", "SU", "BM", "L2", "PA", "margin"]  # 6 comparisons of SU against the others


def test_heatmap_stars_are_the_holm_significance_of_the_paired_tests_on_the_corridor(
    corridor_matches_dir, corridor_dir
):
    """The heatmap starred 12 differences of SU that its Holm-corrected tests do not call significant (e.g. BM on
    AlexNet_VPR: +0.088, Holm p 0.060): its stars came from an uncorrected interval."""
    cells = []
    for name in ("AlexNet_VPR", "HOG", "HybridNet", "denseVLAD"):
        retrieval = read_results(
            corridor_matches_dir / name / "precomputed_data_corrected.npy",
            ground_truth=corridor_dir / "ground_truth_new.npy",
        )
        evaluation = evaluate(retrieval, METHODS, bootstrap=1000, seed=0, timing_repeats=1)  # reference SU
        cells.append(SimpleNamespace(vpr_method=name, dataset="corridor", evaluation=evaluation))
    distributions = plots.heatmap_distributions(cells, 1000, 0)
    checked = stars = 0
    for baseline in ("RS", "SD", "BM", "L2", "PA", "margin"):
        _, _, delta, starred = plots.delta_matrix(cells, "SU", baseline, distributions)
        for row, cell in enumerate(cells):
            test = cell.evaluation.methods[baseline].vs_reference
            assert bool(starred[row, 0]) == test["significant"], (cell.vpr_method, baseline, delta[row, 0], test)
            checked, stars = checked + 1, stars + bool(starred[row, 0])
    assert checked == 24 and 0 < stars < 24  # some differences survive Holm, most do not
    caption = plots.heatmap_spec(cells, "SU", bootstrap=1000, seed=0).caption()
    assert "Holm-adjusted p <= 0.05" in caption and "not corrected" not in caption


def _retrieval(n_queries: int = 60) -> Retrieval:
    rng = np.random.default_rng(0)
    scores = np.sort(rng.uniform(0.2, 1.0, (n_queries, 10)), axis=1)[:, ::-1]
    positives = np.zeros((n_queries, 10), dtype=bool)
    positives[np.arange(n_queries), rng.integers(0, 3, n_queries)] = True
    return Retrieval(scores=scores, indices=np.tile(np.arange(10), (n_queries, 1)), positives=positives)


def test_a_bootstrap_too_small_for_holm_says_so_with_the_size_that_would_allow_it():
    # smallest paired p = 2 / (B + 1); Holm over m comparisons multiplies it by m: 6 × 2/201 = 0.0597 > 0.05
    assert significance_notice(200, 6) == (
        "no difference can be significant with B = 200 resamples over 6 comparisons; use B >= 239"
    )
    assert 6 * 2 / (239 + 1) <= 0.05 < 6 * 2 / (238 + 1)  # 239 is the smallest that allows it
    assert significance_notice(239, 6) is None and significance_notice(200, 5) is None  # 5 × 2/201 = 0.0498
    assert significance_notice(200, 10).endswith("use B >= 399")
    seven = evaluate(_retrieval(), METHODS, bootstrap=200, seed=0, timing_repeats=1)
    assert [note for note in seven.notes if "no difference can be significant" in note] == [significance_notice(200, 6)]
    six = evaluate(_retrieval(), METHODS[:6], bootstrap=200, seed=0, timing_repeats=1)
    assert not any("no difference can be significant" in note for note in six.notes)


def test_table1_and_compare_state_the_rule_and_the_notice():
    """Table 1 said "Holm-corrected at 0.05" and bolded tied leaders where no difference could be significant, without
    a word; ``compare`` gave Holm p-values without saying what is called significant, nor that B = 40 over 5 methods
    leaves nothing significant."""
    from vpr_uncertainty.evaluation.compare import compare
    from vpr_uncertainty.reports.latex import latex_escape
    from vpr_uncertainty.reports.tables import build_table1, marks_note, table1_latex, table1_markdown

    cells = [SimpleNamespace(vpr_method="A", dataset="d", evaluation=evaluate(_retrieval(), METHODS, timing_repeats=1))]
    table = build_table1(cells, bootstrap=200, seed=0)
    note = marks_note(table)
    assert "significant: Holm-adjusted p <= 0.05" in note and f"Note: {significance_notice(200, 6)}." in note
    latex = table1_latex(table)  # the paper's caption too, with < and > as LaTeX text (OT1 prints ¡ and ¿)
    assert note in table1_markdown(table) and latex_escape(significance_notice(200, 6)) in latex
    assert r"Holm-adjusted p \textless{}= 0.05" in latex and r"B \textgreater{}= 239" in latex
    assert "Note:" not in marks_note(build_table1(cells, bootstrap=239, seed=0))
    evaluation = evaluate(_retrieval(), ["SU", "RS", "SD", "BM", "PA"], timing_repeats=1)
    text = str(compare(evaluation, evaluation, n_resamples=40, labels=("X", "Y")))
    assert "significant: Holm-adjusted p <= 0.05 (Holm over the methods compared, per metric)" in text
    assert f"note: {significance_notice(40, 5)}" in text and "use B >= 199" in text
    assert "note: no difference" not in str(compare(evaluation, evaluation, n_resamples=199, labels=("X", "Y")))
