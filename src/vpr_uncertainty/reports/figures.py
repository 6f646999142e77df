"""Report figures: what ``reproduce`` writes after the grid (Table 1, heatmaps, ablations, PR curves, ...).

Each :class:`ReportFigure` in :data:`REPORT_FIGURES` (a :class:`~vpr_uncertainty.plugins.Registry`) declares its
name, a description, what it needs from the grid (:data:`FIGURE_NEEDS`), its default options and the function
that writes it::

    write(cells, config, out_dir, **options) -> list[Path]

``cells`` are the grid's typed results (``Cell``, with their stored uncertainties), ``config`` its ``GridConfig``,
``out_dir`` the output folder (figures go to ``out_dir / "figures"`` by convention). ``reproduce`` calls every
selected figure in registration order and gives each a section of ``report.html`` that embeds the PNG files it
wrote. A figure is selected by name, optionally with options as in a method spec (``"qualitative:rank_by=RS"``,
:func:`parse_figure_spec`); the ``report`` key of a grid configuration lists the selected ones.

Examples
--------
>>> REPORT_FIGURES.names()  # doctest: +NORMALIZE_WHITESPACE
['table1', 'heatmaps', 'ablations', 'pr_curves', 'cascade', 'qualitative', 'table1_ap', 'table1_aurc', 'ties',
 'reliability']
>>> parse_figure_spec("qualitative:rank_by=RS")
('qualitative', {'rank_by': 'RS'})
"""

from __future__ import annotations

import re
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vpr_uncertainty.methods import typed_option
from vpr_uncertainty.plugins import Registry, load_target, merge_options

__all__ = [
    "FIGURE_NEEDS",
    "REPORT_FIGURES",
    "ReportFigure",
    "parse_figure_spec",
    "register_report_figure",
    "slug",
    "unmet_figure_needs",
]


def slug(text: str) -> str:
    """``text`` as a file-name part: runs of characters other than letters, digits, ``_.-`` become ``_``."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "x"


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
    """One registered report figure (or table).

    Attributes
    ----------
    name : str
        The name a configuration selects (``report = ["table1", "pr_curves"]``).
    description : str
        One line: what it shows. Written under the section title in ``report.html``.
    target : callable or str
        ``write(cells, config, out_dir, **options) -> list[Path]`` (the files written), or its dotted path
        ``"package.module:function"`` (imported when first used).
    title : str
        The section title in ``report.html`` (default: the description).
    requires : tuple of str
        Names of :data:`FIGURE_NEEDS`; a grid that cannot meet them skips the figure (and a configuration that
        selects it by name is an error).
    options : dict
        The options a spec may set, with their defaults (whose types type the values).
    section : callable or str or None
        ``section(cells, config, written, **options) -> str``: HTML shown above the figures in ``report.html``
        (e.g. a table), or its dotted path.
    extra : str or None
        The pip extra its dependencies come from.
    """

    name: str
    description: str
    target: FigureWriter | str = field(repr=False)
    title: str = ""
    requires: tuple[str, ...] = ()
    options: Mapping[str, Any] = field(default_factory=dict)
    section: Callable[..., str] | str | None = field(default=None, repr=False)
    extra: str | None = None

    @property
    def heading(self) -> str:
        return self.title or self.description

    def write(self, cells: Any, config: Any, out_dir: str | Path, **options: Any) -> list[Path]:
        """Write the figure with ``options`` merged over its defaults; returns the files written."""
        function = load_target(self.target, what=f"report figure {self.name!r}", extra=self.extra)
        options = merge_options(self.options, options, what=f"report figure {self.name!r}")
        written = function(cells, config, Path(out_dir), **options)
        if not isinstance(written, (list, tuple)) or not all(isinstance(path, Path) for path in written):
            raise TypeError(f"report figure {self.name!r} must return a list of the Paths it wrote, got {written!r}")
        return list(written)

    def section_html(self, cells: Any, config: Any, written: list[Path], **options: Any) -> str:
        """The HTML above the figures in ``report.html`` ("" without a ``section`` hook)."""
        if self.section is None:
            return ""
        hook = load_target(self.section, what=f"report figure {self.name!r}", extra=self.extra)
        return hook(cells, config, written, **merge_options(self.options, options, what=f"report figure {self.name!r}"))

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
    overwrite: bool = False,
) -> ReportFigure:
    """Add a report figure (shown after those registered before it) and return its entry.

    Parameters
    ----------
    name : str
        The name a configuration selects; must be new unless ``overwrite=True``, and hold no ``:``, ``,`` or ``=``.
    target : callable or str
        ``write(cells, config, out_dir, **options) -> list[Path]``, or its dotted path.
    description : str
        One line: what the figure shows.
    title : str, optional
        Section title in ``report.html`` (default: ``description``).
    requires : tuple of str
        Names of :data:`FIGURE_NEEDS`.
    options : mapping, optional
        The options a spec may set, with their defaults.
    section : callable or str, optional
        ``section(cells, config, written, **options) -> str``: HTML above the figures.
    extra : str, optional
        The pip extra that provides its dependencies.
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
    )
    return REPORT_FIGURES.register(entry, overwrite=overwrite)


def parse_figure_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """Split ``"NAME[:option=value[,option=value...]]"`` into a registered figure's name and its options.

    Values are typed like the option's default; an unknown name or option is an error that lists the valid ones.
    """
    if not isinstance(spec, str):
        raise TypeError(f"a report figure must be named by a string, got {spec!r}")
    name, colon, rest = (part.strip() for part in spec.partition(":"))
    entry = REPORT_FIGURES.get(name)
    options: dict[str, Any] = {}
    if not colon:
        return entry.name, options
    for item in rest.split(","):
        key, equals, value = (part.strip() for part in item.partition("="))
        if not key or not equals or not value:
            raise ValueError(f"report figure {spec!r}: expected option=value after {name}:, got {item.strip()!r}")
        if key not in entry.options:
            valid = ", ".join(sorted(entry.options)) or "none"
            raise ValueError(f"report figure {spec!r}: {name} has no option {key!r} (its options: {valid})")
        if key in options:
            raise ValueError(f"report figure {spec!r}: option {key!r} is given twice")
        options[key] = typed_option(value, entry.options[key], f"report figure {spec!r}: option {key!r}")
    return entry.name, options


def unmet_figure_needs(entry: ReportFigure, available: Collection[str]) -> str | None:
    """One line saying what ``entry`` needs that ``available`` lacks, or None."""
    missing = entry.unmet_needs(available)
    if not missing:
        return None
    return f"report figure {entry.name!r} needs " + "; ".join(FIGURE_NEEDS[need] for need in missing)


# --- the built-in figures, in the order of report.html ---------------------------------------------------------

_HERE = "vpr_uncertainty.reports.builtin:"
register_report_figure(
    "table1",
    _HERE + "write_table1",
    title="Table 1: AUC-PR averaged over datasets",
    description="AUC-PR of each uncertainty method for each VPR method, averaged over datasets (md, csv, tex)",
    requires=("evaluation",),
    section=_HERE + "table1_section",
)
register_report_figure(
    "heatmaps",
    _HERE + "write_heatmaps",
    title="ΔAUC-PR of RS, SD and SU against each baseline",
    description="AUC-PR of RS, SD and SU minus that of each baseline, per VPR method and dataset",
    requires=("evaluation",),
)
register_report_figure(
    "ablations",
    _HERE + "write_ablations",
    title="Ablations",
    description="mean AUC-PR of SU for each α, and of RS and SD for each k",
    requires=("ablations",),
)
register_report_figure(
    "pr_curves",
    _HERE + "write_pr_curves",
    title="End-to-end precision-recall with rejection",
    description="precision against recall when the most uncertain answers are rejected, one figure per cell",
    requires=("evaluation",),
    section=_HERE + "pr_curves_section",
)
register_report_figure(
    "cascade",
    _HERE + "write_cascade",
    title="Cascade: geometric verification of the most uncertain queries only",
    description="AUC-PR of each cascade SCORE+GV against the fraction of queries verified (0: SCORE alone, 1: GV "
    "on every query); grey: one VPR method, blue: their mean, red: the cascade as run",
    requires=("evaluation", "uncertainties", "cascade"),
    section=_HERE + "cascade_section",
)
register_report_figure(
    "qualitative",
    _HERE + "write_qualitative",
    title="Qualitative examples",
    description="confident/uncertain × correct/wrong queries with their top-4 answers and RS/SD/SU "
    "(cells of config.qualitative, default: the first cell with images)",
    requires=("images", "uncertainties"),
    options={"rank_by": "SU"},
)
register_report_figure(
    "table1_ap",
    _HERE + "write_table1_ap",
    title="Table 1 by average precision",
    description="average precision (step-wise area, no interpolation between tied groups), as Table 1 (md, csv, tex)",
    requires=("evaluation",),
    section=_HERE + "table1_ap_section",
)
register_report_figure(
    "table1_aurc",
    _HERE + "write_table1_aurc",
    title="Table 1 by AURC (lower is better)",
    description="area under the risk-coverage curve, as Table 1 (md, csv, tex)",
    requires=("evaluation",),
    section=_HERE + "table1_aurc_section",
)
register_report_figure(
    "ties",
    _HERE + "write_ties",
    title="Tied uncertainties",
    description="share of queries tied with another and distinct uncertainty values of each method (md, csv)",
    requires=("uncertainties",),
    section=_HERE + "ties_section",
)
register_report_figure(
    "reliability",
    "vpr_uncertainty.reports.held_out:write_reliability",
    title="Calibration of CAL on held-out queries",
    description="reliability diagram of CAL (held-out predictions of all splits, count per bin), ECE and Brier, "
    "per cell",
    requires=("calibration",),
    section="vpr_uncertainty.reports.held_out:reliability_section",
)
