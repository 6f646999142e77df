"""Report figures: what ``reproduce`` writes after the grid (Table 1, heatmaps, ablations, PR curves, ...), each a
:class:`ReportFigure` of :data:`REPORT_FIGURES` added by :func:`register_report_figure`, selected by a spec such as
``"qualitative:rank_by=RS"`` (:func:`parse_figure_spec`). What a figure declares and how ``reproduce`` calls it: see
docs/explanation/reports.md (docs/how-to/extend.md writes one from scratch).

Examples
--------
>>> REPORT_FIGURES.names()  # doctest: +NORMALIZE_WHITESPACE
['table1', 'heatmaps', 'ablations', 'pr_curves', 'cascade', 'qualitative', 'table1_ap', 'table1_aurc', 'ties',
 'reliability']
>>> parse_figure_spec("qualitative:rank_by=RS")
('qualitative', {'rank_by': 'RS'})
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from html import escape
from pathlib import Path
from typing import Any

from vpr_uncertainty.cache import slug, write_text
from vpr_uncertainty.calibration.quality import Reliability
from vpr_uncertainty.methods import spec_options
from vpr_uncertainty.plugins import Registry, load_target, merge_options
from vpr_uncertainty.reports.display import plot_reliability, rejection_curves_spec, write_rejection_curves
from vpr_uncertainty.reports.html import averaged_over, cell_stem, figure_caption, html_table
from vpr_uncertainty.reports.plots import (
    alpha_ablation_spec,
    cascade_spec,
    cascades,
    heatmap_spec,
    k_ablation_spec,
    plot_alpha_ablation,
    plot_cascade,
    plot_delta_heatmaps,
    plot_k_ablation,
    plot_qualitative,
    qualitative_spec,
)
from vpr_uncertainty.reports.style import VECTOR_SUFFIX
from vpr_uncertainty.reports.tables import (
    METRIC_NAMES,
    build_table1,
    build_ties_table,
    marks_note,
    table1_cells,
    table1_csv,
    table1_html,
    table1_latex,
    table1_markdown,
    table1_note,
    ties_csv,
    ties_markdown,
)

__all__ = [
    "FIGURE_NEEDS",
    "REPORT_FIGURES",
    "ReportFigure",
    "parse_figure_spec",
    "register_report_figure",
    "unmet_figure_needs",
]

FigureWriter = Callable[..., "list[Path]"]

#: What a figure may need from the grid, and how to say it.
FIGURE_NEEDS: dict[str, str] = {
    "evaluation": "every cell's evaluation (AUC-PR, curves, recall@N)",
    "uncertainties": "every cell's stored per-query uncertainties",
    "images": "a cell with query and database images (images = ... in an input, or a model input)",
    "ablations": "the α or k ablation (non-empty alphas or ks)",
    "calibration": "CAL evaluated on held-out queries (CAL in methods and calibration = {fraction, repeats, seed})",
    "cascade": "a cascade SCORE+GV among the methods, with SCORE and GV also evaluated alone (e.g. SU, GV-SIFT, "
    "SU+GV-SIFT)",
}


@dataclass(frozen=True)
class ReportFigure:
    """One registered report figure (or table); its fields are the arguments of :func:`register_report_figure`."""

    name: str
    description: str
    target: FigureWriter | str = field(repr=False)
    title: str = ""
    requires: tuple[str, ...] = ()
    options: Mapping[str, Any] = field(default_factory=dict)
    section: Callable[..., str] | str | None = field(default=None, repr=False)
    extra: str | None = None
    caption: Callable[..., str] | str | None = field(default=None, repr=False)

    @property
    def heading(self) -> str:
        return self.title or self.description

    def _call(self, hook: Callable[..., Any] | str, *args: Any, **options: Any) -> Any:
        """Call ``hook`` (or the function at its dotted path) with ``options`` merged over the figure's defaults."""
        function = load_target(hook, what=f"report figure {self.name!r}", extra=self.extra)
        return function(*args, **merge_options(self.options, options, what=f"report figure {self.name!r}"))

    def write(self, cells: Any, config: Any, out_dir: str | Path, **options: Any) -> list[Path]:
        """Write the figure with ``options`` merged over its defaults; returns the files written."""
        written = self._call(self.target, cells, config, Path(out_dir), **options)
        if not isinstance(written, (list, tuple)) or not all(isinstance(path, Path) for path in written):
            raise TypeError(f"report figure {self.name!r} must return a list of the Paths it wrote, got {written!r}")
        return list(written)

    def section_html(self, cells: Any, config: Any, written: list[Path], **options: Any) -> str:
        """The HTML above the figures in ``report.html`` ("" without a ``section`` hook)."""
        return "" if self.section is None else self._call(self.section, cells, config, written, **options)

    def caption_of(self, cells: Any, config: Any, path: Path, **options: Any) -> str:
        """The caption of the file ``path`` it wrote: its ``caption`` hook's, else a generic one."""
        text = None if self.caption is None else self._call(self.caption, cells, config, Path(path), **options)
        return text or figure_caption(self.name, Path(path), cells)

    def unmet_needs(self, available: Collection[str]) -> list[str]:
        """The entries of ``requires`` not in ``available``."""
        return [need for need in self.requires if need not in available]


#: The registered report figures, in the order ``report.html`` shows them.
REPORT_FIGURES: Registry[ReportFigure] = Registry("report figure", label="available")


def register_report_figure(
    name: str,
    target: FigureWriter | str,
    *,
    description: str,
    title: str = "",
    requires: tuple[str, ...] = (),
    options: Mapping[str, Any] | None = None,
    section: Callable[..., str] | str | None = None,
    extra: str | None = None,
    caption: Callable[..., str] | str | None = None,
    overwrite: bool = False,
) -> ReportFigure:
    """Add a report figure (shown after those registered before it) and return its entry.

    Parameters
    ----------
    name : str
        The name a configuration selects (``report = ["table1", "pr_curves"]``); new unless ``overwrite=True``, and
        without ``:``, ``,`` or ``=``.
    target : callable or str
        ``write(cells, config, out_dir, **options) -> list[Path]`` (the files written), or its dotted path
        ``"package.module:function"`` (imported when first used).
    description : str
        One line: what it shows (written under the section title in ``report.html``).
    title : str, optional
        The section title in ``report.html`` (default: ``description``).
    requires : tuple of str
        Names of :data:`FIGURE_NEEDS`; a grid that cannot meet them skips the figure (selecting it by name is then
        an error).
    options : mapping, optional
        The options a spec may set, with their defaults (whose types type the values).
    section : callable or str, optional
        ``section(cells, config, written, **options) -> str``: HTML above the figures (e.g. a table), or its path.
    extra : str, optional
        The pip extra its dependencies come from.
    caption : callable or str, optional
        ``caption(cells, config, path, **options) -> str``: the caption of the file ``path`` in ``report.html``, or
        its path (default: a generic one).
    overwrite : bool
        Replace an existing entry of that name.
    """
    if not isinstance(name, str) or not name or any(character in name for character in ":,="):
        raise ValueError(f"a report figure name must be non-empty and hold no ':', ',' or '=', got {name!r}")
    unknown = [need for need in requires if need not in FIGURE_NEEDS]
    if unknown:
        raise ValueError(f"report figure {name!r}: unknown need {unknown[0]!r} (valid: {', '.join(FIGURE_NEEDS)})")
    if not (callable(target) or isinstance(target, str)):
        raise TypeError(f"report figure {name!r}: target must be a function or a 'module:function' path")
    entry = ReportFigure(
        name=name,
        description=description,
        target=target,
        title=title,
        requires=tuple(requires),
        options=dict(options or {}),
        section=section,
        extra=extra,
        caption=caption,
    )
    return REPORT_FIGURES.register(entry, overwrite=overwrite)


def parse_figure_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """Split ``"NAME[:option=value[,option=value...]]"`` into a registered figure's name and its options.

    Values are typed like the option's default; an unknown name or option is an error that lists the valid ones.
    """
    if not isinstance(spec, str):
        raise TypeError(f"a report figure must be named by a string, got {spec!r}")
    name, colon, _ = (part.strip() for part in spec.partition(":"))
    entry = REPORT_FIGURES.get(name)
    return entry.name, spec_options(spec, entry.options, "report figure") if colon else {}


def unmet_figure_needs(entry: ReportFigure, available: Collection[str]) -> str | None:
    """One line saying what ``entry`` needs that ``available`` lacks, or None."""
    missing = entry.unmet_needs(available)
    return f"report figure {entry.name!r} needs " + "; ".join(FIGURE_NEEDS[n] for n in missing) if missing else None


# --- the built-in figures ---


def _with_vectors(pngs: Sequence[Path]) -> list[Path]:
    """Each PNG followed by the vector file written beside it."""
    return [path for png in pngs for path in (png, png.with_suffix(VECTOR_SUFFIX)) if path == png or path.is_file()]


def _table1(cells: Sequence[Any], config: Any, metric: str):
    # With the calibration option, Table 1 (AUC-PR) holds the held-out means; AP and AURC stay on all queries.
    chosen = table1_cells(cells) if metric == "auc_pr" else cells
    return build_table1(chosen, metric, **_bootstrap(config))


def _write_table1(cells: Sequence[Any], config: Any, out_dir: Path, *, metric: str, stem: str) -> list[Path]:
    """``STEM.md``, ``STEM.csv`` and ``STEM.tex`` (a booktabs ``table*``, two columns wide): Table 1 of ``metric``,
    with intervals when bootstrapped; the caption says over what each value is averaged."""
    table = _table1(cells, config, metric)
    note = table1_note(cells) if metric == "auc_pr" else None
    caption = f"{METRIC_NAMES[metric][0]} of each uncertainty method for each VPR method, {averaged_over(cells)}. "
    latex = partial(table1_latex, caption=caption + marks_note(table).split(" [low")[0], width=r"\textwidth")
    return [
        write_text(out_dir / f"{stem}.{suffix}", render(table) + (f"\n{note}\n" if note and suffix == "md" else ""))
        for suffix, render in (("md", table1_markdown), ("csv", table1_csv), ("tex", latex))
    ]


def _section(metric: str):
    def section(cells: Sequence[Any], config: Any, written: list[Path]) -> str:
        table = _table1(cells, config, metric)
        html = table1_html(table) + f'<p class="note">{escape(marks_note(table))} ms/query: mean time per query.</p>'
        held_out = table1_note(cells) if metric == "auc_pr" else None
        return html + (f'<p class="note">{escape(held_out)}</p>' if held_out else "")

    section.__name__ = f"{metric}_section"
    return section


def write_ties(cells: Sequence[Any], config: Any, out_dir: Path) -> list[Path]:
    """``ties.md`` and ``ties.csv``: the share of tied queries and the distinct values of every method."""
    table = build_ties_table(cells)
    return [
        write_text(out_dir / f"ties.{suffix}", render(table))
        for suffix, render in (("md", ties_markdown), ("csv", ties_csv))
    ]


def ties_section(cells: Sequence[Any], config: Any, written: list[Path]) -> str:
    """The ties table in HTML: ``97 % (8)`` = 97 % of the queries tied, 8 distinct values; then what it means."""
    table = build_ties_table(cells)
    rows = [
        [name, *("–" if s is None else f"{s:.0%} ({d:.0f})" for s, d in zip(shares, distinct, strict=True))]
        for name, shares, distinct in zip(table.rows, table.tied_share, table.distinct, strict=True)
    ]
    note = ties_markdown(table).rstrip().split("\n\n")[-1]  # the sentence under the Markdown table
    return html_table(["method", *table.columns], rows, "ties") + f'<p class="note">{escape(note)}</p>'


def write_heatmaps(cells: Sequence[Any], config: Any, out_dir: Path, *, width: str = "page") -> list[Path]:
    """``figures/delta_<RS|SD|SU>.png`` (and ``.pdf``): ΔAUC-PR against each baseline."""
    return _with_vectors(plot_delta_heatmaps(cells, out_dir / "figures", width=width, **_bootstrap(config)))


def _bootstrap(config: Any) -> dict[str, int]:
    return {"bootstrap": getattr(config, "bootstrap", 0), "seed": getattr(config, "seed", 0)}


def heatmaps_caption(cells: Sequence[Any], config: Any, path: Path, **options: Any) -> str:
    return heatmap_spec(cells, path.stem.removeprefix("delta_"), **_bootstrap(config)).caption()


def write_ablations(cells: Sequence[Any], config: Any, out_dir: Path, *, width: str = "page") -> list[Path]:
    """``figures/ablation_alpha.png`` and ``figures/ablation_k.png`` (and ``.pdf``), for the ablations the cells
    hold."""
    paths = []
    if any(cell.ablation_alpha for cell in cells):
        path = out_dir / "figures" / "ablation_alpha.png"
        paths.append(plot_alpha_ablation(cells, path, width=width, reference=getattr(config, "alpha", 0.5)))
    if any(curve for cell in cells for curve in cell.ablation_k.values()):
        paths.append(plot_k_ablation(cells, out_dir / "figures" / "ablation_k.png", width=width))
    return _with_vectors(paths)


def ablations_caption(cells: Sequence[Any], config: Any, path: Path, *, width: str = "page", **options: Any) -> str:
    if path.stem == "ablation_alpha":
        return alpha_ablation_spec(cells, getattr(config, "alpha", 0.5)).caption()
    return k_ablation_spec(cells, width).caption()


def _pr_title(cell: Any) -> str:
    return f"{cell.vpr_method} on {cell.dataset}"


def write_pr_curves(cells: Sequence[Any], config: Any, out_dir: Path, *, width: str = "page") -> list[Path]:
    """``figures/pr/<vpr method>__<dataset>.png`` (and ``.pdf``) for every cell."""
    return [
        path
        for cell in cells
        for path in write_rejection_curves(
            cell.evaluation,
            out_dir / "figures" / "pr" / f"{cell_stem(cell)}.png",
            title=f"{_pr_title(cell)} ({cell.evaluation.n_queries} queries)",
            width=width,
        )
    ]


def pr_curves_caption(cells: Sequence[Any], config: Any, path: Path, **options: Any) -> str:
    cell = next((c for c in cells if cell_stem(c) == path.stem), None)
    return "" if cell is None else rejection_curves_spec(cell.evaluation, title=_pr_title(cell)).caption()


def write_cascade(cells: Sequence[Any], config: Any, out_dir: Path, *, width: str = "page") -> list[Path]:
    """``figures/cascade__<SCORE>_<GV>.png`` (and ``.pdf``): AUC-PR against the fraction verified."""
    return plot_cascade(cells, out_dir / "figures", width=width)


def cascade_caption(cells: Sequence[Any], config: Any, path: Path, **options: Any) -> str:
    for name, score, gv in cascades(cells):
        if path.stem == f"cascade__{slug(score)}_{slug(gv)}":
            return cascade_spec(cells, name, score, gv).caption()
    return ""


def cascade_section(cells: Sequence[Any], config: Any, written: list[Path], **options: Any) -> str:
    """Each cascade's measured fraction verified, AUC-PR and time per query beside its two methods, as a table."""
    rows = []
    for name, score, gv in cascades(cells):
        for cell in cells:
            methods = cell.evaluation.methods
            if not {name, score, gv} <= set(methods):
                continue
            values = [methods[m] for m in (score, gv, name)]
            auc = ["n/a" if m.auc_pr is None else f"{m.auc_pr:.3f}" for m in values]
            fraction = methods[name].details.get("verified_fraction", float("nan"))
            times = [f"{m.time_per_query_ms:.3g}" for m in values[1:]]
            rows.append([f"{cell.vpr_method} on {cell.dataset}", escape(name), f"{fraction:.2f}", *auc, *times])
    head = ["cell", "cascade", "verified", "AUC-PR score alone", "AUC-PR GV alone", "AUC-PR cascade"]
    return html_table([*head, "ms/query GV", "ms/query cascade"], rows) if rows else ""


def write_qualitative(
    cells: Sequence[Any], config: Any, out_dir: Path, *, rank_by: str = "SU", width: str = "page"
) -> list[Path]:
    """``figures/qualitative__<vpr method>__<dataset>.png`` for the cells of ``config.qualitative`` (default: the
    first cell with images); queries chosen by the uncertainties of ``rank_by``."""
    chosen = [c for c in cells if c.query_paths and (config.qualitative is None or c.vpr_method in config.qualitative)]
    if config.qualitative is None:
        chosen = chosen[:1]
    paths = []
    for cell in chosen:
        path = out_dir / "figures" / f"qualitative__{cell_stem(cell)}.png"
        written = plot_qualitative(cell, path, rank_by=rank_by, alpha=config.alpha, width=width)
        if written is not None:
            paths.append(written)
    return _with_vectors(paths)


def qualitative_caption(cells: Sequence[Any], config: Any, path: Path, **options: Any) -> str:
    cell = next((c for c in cells if path.stem == f"qualitative__{cell_stem(c)}"), None)
    spec = None if cell is None else qualitative_spec(cell, alpha=config.alpha, **options)  # rank_by, width
    return "" if spec is None else spec.caption()


def _calibrated(cells: Sequence[Any]) -> list[tuple[Any, dict[str, Any]]]:
    """(cell, CAL's held-out quality) of each cell that has one."""
    return [(cell, q) for cell in cells if (q := (cell.held_out or {}).get("calibration_quality", {}).get("CAL"))]


def write_reliability(cells: Sequence[Any], config: Any, out_dir: Path, *, width: str = "page") -> list[Path]:
    """``figures/reliability/<vpr method>__<dataset>.png``: CAL's held-out reliability diagram of each cell."""
    paths = []
    for cell, quality in _calibrated(cells):
        title = f"{cell.vpr_method} on {cell.dataset}: mean Brier {quality['brier']:.3f}"
        path = out_dir / "figures" / "reliability" / f"{cell_stem(cell)}.png"
        ece = f"CAL (ECE {quality['ece']:.3f}, mean over the {cell.held_out['calibration']['repeats']} splits)"
        paths.append(plot_reliability(Reliability(**quality["reliability"]), path, title=title, width=width, label=ece))
    return paths


def _mean_std(mean: float | None, std: float | None) -> str:
    if mean is None:
        return "–"
    return f"{mean:.3f}" if std is None else f"{mean:.3f} ± {std:.3f}"


def reliability_section(cells: Sequence[Any], config: Any, written: list[Path], **options: Any) -> str:
    """An HTML table: per cell, CAL's held-out AUC-PR, ECE and Brier (mean ± std over the splits) and the split."""
    rows = []
    for cell, quality in _calibrated(cells):
        cal = cell.held_out["methods"].get("CAL", {})
        split = cell.held_out["calibration"]
        rows.append(
            [
                cell.vpr_method,
                escape(cell.dataset),
                _mean_std(cal.get("auc_pr"), cal.get("auc_pr_std")),
                _mean_std(quality["ece"], quality.get("ece_std")),
                _mean_std(quality["brier"], quality.get("brier_std")),
                f"{split.get('n_calibration', '–')} / {split.get('n_held_out', '–')}",
            ]
        )
    head = ["VPR method", "dataset", "AUC-PR of CAL", "ECE", "Brier", "calibration / held-out queries"]
    note = (
        '<p class="note">Mean ± standard deviation over the random splits; each diagram pools the held-out '
        "predictions of all splits, with the number of queries in each bin (its legend: the ECE of this table).</p>"
    )
    return html_table(head, rows, "reliability") + note


def _register_table(metric: str, stem: str, title: str, description: str) -> None:
    """Register a Table 1 by ``metric`` (md, csv, tex), with its HTML section."""
    write = partial(_write_table1, metric=metric, stem=stem)
    register_report_figure(
        stem, write, title=title, description=description, section=_section(metric), requires=("evaluation",)
    )


def _register_figure(name: str, target: FigureWriter, title: str, description: str, **hooks: Any) -> None:
    """Register a figure drawn at a paper width (a page by default), needing the evaluations unless ``requires``."""
    hooks = {"requires": ("evaluation",), "options": {"width": "page"}, **hooks}
    register_report_figure(name, target, title=title, description=description, **hooks)


_register_table(
    "auc_pr",
    "table1",
    "Table 1: AUC-PR {where}",
    "AUC-PR of each uncertainty method for each VPR method (md, csv, tex)",
)
_register_figure(
    "heatmaps",
    write_heatmaps,
    "ΔAUC-PR of RS, SD and SU against each baseline",
    "AUC-PR of RS, SD and SU minus that of each baseline, per VPR method and dataset",
    caption=heatmaps_caption,
)
_register_figure(
    "ablations",
    write_ablations,
    "Ablations",
    "mean AUC-PR of SU for each α, and of RS and SD for each k",
    requires=("ablations",),
    caption=ablations_caption,
)
_register_figure(
    "pr_curves",
    write_pr_curves,
    "End-to-end precision-recall with rejection",
    "precision against recall when the most uncertain answers are rejected, one figure per cell",
    caption=pr_curves_caption,
)
_register_figure(
    "cascade",
    write_cascade,
    "Cascade: geometric verification of the most uncertain queries only",
    "AUC-PR of each cascade SCORE+GV against the fraction of queries verified (0: SCORE alone, 1: GV on every query)",
    requires=("evaluation", "uncertainties", "cascade"),
    section=cascade_section,
    caption=cascade_caption,
)
_register_figure(
    "qualitative",
    write_qualitative,
    "Qualitative examples",
    "confident/uncertain × correct/wrong queries with their top-4 answers (top-2 at column width) and RS/SD/SU "
    "(cells of config.qualitative, default: the first cell with images)",
    requires=("images", "uncertainties"),
    options={"rank_by": "SU", "width": "page"},
    caption=qualitative_caption,
)
_register_table(
    "average_precision",
    "table1_ap",
    "Table 1 by average precision {where}",
    "average precision (step-wise area, no interpolation between tied groups), as Table 1 (md, csv, tex)",
)
_register_table(
    "aurc",
    "table1_aurc",
    "Table 1 by AURC {where} (lower is better)",
    "area under the risk-coverage curve, as Table 1 (md, csv, tex)",
)
register_report_figure(
    "ties",
    write_ties,
    title="Tied uncertainties",
    description="share of queries tied with another and distinct uncertainty values of each method (md, csv)",
    requires=("uncertainties",),
    section=ties_section,
)
_register_figure(
    "reliability",
    write_reliability,
    "Calibration of CAL on held-out queries",
    "reliability diagram of CAL (held-out predictions of all splits, count per bin), ECE and Brier, per cell",
    requires=("calibration",),
    section=reliability_section,
)
