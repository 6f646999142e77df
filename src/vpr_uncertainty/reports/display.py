"""How report figures look and are drawn: styles, atomic saving, and Display objects in scikit-learn's style.

Like :class:`sklearn.metrics.PrecisionRecallDisplay`, each Display is made by a ``from_*`` class method that draws at
once on the ``ax`` given (or a new figure) and keeps ``ax_``, ``figure_`` and its artists (``lines_`` by method
name, or ``line_``); ``plot(ax=None)`` draws the same data again. Displays pick no backend and save nothing; the
file writers (:func:`plot_rejection_curves`, :func:`plot_reliability`, :func:`save_figure`) draw off-screen and
write atomically: a 300-dpi PNG for ``report.html`` and a vector PDF beside it.

Paper sizes: every figure function takes ``width="column"`` (3.5 in, one column of a two-column paper) or
``"page"`` (7.16 in, the text width); its height follows from its content, and its fonts are 8 pt (9 pt titles),
set for that figure only (:func:`figure_rc`, a ``matplotlib.rc_context``; the global rcParams are left alone).
Colours are Okabe and Ito's colour-blind-safe palette and every series also has its own marker and dash
(:func:`method_styles`), so a figure printed in grey still tells them apart.

Captions: a figure is described by a :class:`FigureSpec` (its panels, its series with their styles, its axes,
its notes) from which the drawing code takes its titles, legend labels and styles and from which
:meth:`FigureSpec.caption` writes the caption of ``report.html``.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vpr_uncertainty.cache import array_digest, figure_is_current, fingerprint, write_figure
from vpr_uncertainty.calibration.quality import Reliability, reliability_diagram
from vpr_uncertainty.evaluation.metrics import RejectionCurve, rejection_curve

if TYPE_CHECKING:  # pragma: no cover
    from vpr_uncertainty.calibration.gate import Gate
    from vpr_uncertainty.evaluation.results import Evaluation

__all__ = [
    "AREA_NOTE",
    "DPI",
    "FIGURE_WIDTHS",
    "FONT_SIZE",
    "OKABE_ITO",
    "VECTOR_SUFFIX",
    "FigureSpec",
    "RecallAtNDisplay",
    "RejectionCurveDisplay",
    "ReliabilityDisplay",
    "SeriesSpec",
    "capped_height",
    "coinciding",
    "curve_area",
    "describe_style",
    "draw_rejection_curves",
    "figure_rc",
    "figure_width",
    "legend_outside",
    "method_styles",
    "plot_rejection_curves",
    "plot_reliability",
    "pyplot",
    "rejection_curves_inputs",
    "rejection_curves_spec",
    "save_figure",
    "write_rejection_curves",
]

#: Resolution of every PNG a report writes.
DPI = 300
#: The vector format written beside each PNG.
VECTOR_SUFFIX = ".pdf"
#: Okabe and Ito's colour-blind-safe palette (yellow last: faint on white), as hex.
OKABE_ITO: tuple[str, ...] = (
    "#0072B2",  # blue
    "#D55E00",  # vermillion
    "#009E73",  # bluish green
    "#CC79A7",  # reddish purple
    "#E69F00",  # orange
    "#56B4E9",  # sky blue
    "#000000",  # black
    "#F0E442",  # yellow
)
_COLOURS = OKABE_ITO
_DASHES: tuple[Any, ...] = ("-", "--", "-.", ":", (0, (5, 1, 1, 1, 1, 1)))
_MARKERS = ("o", "s", "^", "v", "D", "P", "X")
#: How a caption names a marker and a dash.
_MARKER_WORDS = {
    "o": "circles",
    "s": "squares",
    "^": "triangles up",
    "v": "triangles down",
    "D": "diamonds",
    "P": "plus signs",
    "X": "crosses",
    "*": "stars",
}
_DASH_WORDS = {"-": "solid", "--": "dashed", "-.": "dash-dot", ":": "dotted", "None": "no line", "none": "no line"}

#: Figure widths in inches: one column of a two-column paper, and the text width of a page.
FIGURE_WIDTHS: dict[str, float] = {"column": 3.5, "page": 7.16}
#: Tallest figure in inches per width (the panels shrink to fit).
MAX_HEIGHTS: dict[str, float] = {"column": 7.0, "page": 9.0}
#: Font size in points of every text (titles one point larger).
FONT_SIZE = 8.0
TITLE_SIZE = 9.0


def figure_width(width: str = "page") -> float:
    """The width in inches of ``"column"`` (3.5) or ``"page"`` (7.16); anything else is a ValueError.

    Examples
    --------
    >>> figure_width("column"), figure_width("page")
    (3.5, 7.16)
    """
    if width not in FIGURE_WIDTHS:
        raise ValueError(f"figure width must be one of {', '.join(FIGURE_WIDTHS)}, got {width!r}")
    return FIGURE_WIDTHS[width]


def capped_height(height: float, width: str = "page") -> float:
    """``height`` rounded to 0.01 in, at most :data:`MAX_HEIGHTS` of ``width`` and at least 1.5 in."""
    return round(min(max(height, 1.5), MAX_HEIGHTS[width]), 2)


@contextlib.contextmanager
def figure_rc(width: str = "page") -> Iterator[None]:
    """Fonts, line widths and colours of a paper figure, for the figures made and saved inside this block only."""
    import matplotlib

    figure_width(width)
    rc = {
        "font.size": FONT_SIZE,
        "axes.titlesize": TITLE_SIZE,
        "axes.labelsize": FONT_SIZE,
        "xtick.labelsize": FONT_SIZE,
        "ytick.labelsize": FONT_SIZE,
        "legend.fontsize": FONT_SIZE,
        "legend.title_fontsize": FONT_SIZE,
        "figure.titlesize": TITLE_SIZE,
        "figure.labelsize": FONT_SIZE,
        "axes.linewidth": 0.6,
        "grid.linewidth": 0.4,
        "lines.linewidth": 1.2,
        "lines.markersize": 4,
        "xtick.major.width": 0.6,
        "ytick.major.width": 0.6,
        "axes.prop_cycle": matplotlib.cycler(color=list(OKABE_ITO)),
        "pdf.fonttype": 42,  # TrueType in the PDF: editable text, accepted by publishers
    }
    with matplotlib.rc_context(rc):
        yield


def describe_style(style: Mapping[str, Any]) -> str:
    """How a caption names a series' marker and dash ("circles, dashed"), for readers without colour.

    Examples
    --------
    >>> describe_style({"marker": "s", "linestyle": "--"})
    'squares, dashed'
    """
    marker = _MARKER_WORDS.get(str(style.get("marker", "")))
    dash = style.get("linestyle", "-")
    dash_word = _DASH_WORDS.get(dash, "dash-dot-dot") if isinstance(dash, str) else "dash-dot-dot"
    return ", ".join(word for word in (marker, dash_word) if word)


@dataclass(frozen=True)
class SeriesSpec:
    """One series of a figure: its legend label, what it is (for the caption) and its style."""

    label: str
    meaning: str = ""
    style: Mapping[str, Any] | None = None


@dataclass(frozen=True)
class FigureSpec:
    """What a figure draws, from which the drawing code and the caption are both made.

    Attributes
    ----------
    what : str
        One sentence: what the figure shows, on which data.
    panels : tuple of str
        The title of each panel drawn, in order (empty for a single unnamed axis).
    panel_rule : str
        How the panels are chosen ("one panel per VPR method").
    series : tuple of SeriesSpec
        The legend entries, in order.
    x, y : str
        The axis labels drawn.
    shared_y : bool
        Whether every panel has the same y range.
    notes : tuple of str
        Further sentences of the caption (what a number means, what a colour means).
    """

    what: str
    panels: tuple[str, ...] = ()
    panel_rule: str = ""
    series: tuple[SeriesSpec, ...] = ()
    x: str = ""
    y: str = ""
    shared_y: bool = False
    notes: tuple[str, ...] = ()

    @property
    def labels(self) -> list[str]:
        """The legend labels, in order."""
        return [series.label for series in self.series]

    def caption(self) -> str:
        """The caption: what it shows, its panels, its series (label, style, meaning), its axes and notes."""
        parts = [self.what.rstrip(".") + "."]
        if self.panels:
            rule = f" ({self.panel_rule})" if self.panel_rule else ""
            shared = "; the same y range in every panel" if self.shared_y and len(self.panels) > 1 else ""
            parts.append(f"Panels{rule}: " + "; ".join(self.panels).replace("\n", " ") + f"{shared}.")
        if self.series:
            items = []
            for series in self.series:
                style = describe_style(series.style) if series.style else ""
                inside = ", ".join(t for t in (style, series.meaning) if t)
                items.append(f"{series.label} ({inside})" if inside else series.label)
            parts.append("Legend: " + "; ".join(items) + ".")
        if self.x or self.y:
            parts.append("; ".join(f"{axis}: {text}" for axis, text in (("x", self.x), ("y", self.y)) if text) + ".")
        parts.extend(note.rstrip(".") + "." for note in self.notes)
        return " ".join(parts).replace("\n", " ")


def pyplot() -> Any:
    """``matplotlib.pyplot`` with the off-screen backend."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def method_styles(names: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``{name: {"color", "linestyle", "marker"}}``: a colour-blind-safe colour (:data:`OKABE_ITO`), a dash and a
    marker; no two of the first 35 names share a (marker, dash), no two of the first 280 all three.

    Examples
    --------
    >>> styles = method_styles(["RS", "SD", "SU"])
    >>> styles["SD"]
    {'color': '#D55E00', 'linestyle': '--', 'marker': 's'}
    """
    return {
        name: {
            "color": _COLOURS[index % len(_COLOURS)],
            "linestyle": _DASHES[index % len(_DASHES)],
            "marker": _MARKERS[index % len(_MARKERS)],
        }
        for index, name in enumerate(names)
    }


def coinciding(curves: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> list[list[str]]:
    """Groups of names whose curves (x, y) are identical, in the order of ``curves`` (singletons included).

    Examples
    --------
    >>> x = np.array([0.0, 0.5, 1.0])
    >>> coinciding({"BM": (x, x), "SU": (x, x**2), "L2": (x, x.copy())})
    [['BM', 'L2'], ['SU']]
    """
    groups: list[list[str]] = []
    for name, (x, y) in curves.items():
        for group in groups:
            gx, gy = curves[group[0]]
            if np.shape(gx) == np.shape(x) and np.array_equal(gx, x) and np.array_equal(gy, y):
                group.append(name)
                break
        else:
            groups.append([name])
    return groups


def legend_outside(axis: Any, **options: Any) -> Any:
    """A legend to the right of ``axis``, outside the data (save with :func:`save_figure`, which keeps it)."""
    options = {"loc": "upper left", "bbox_to_anchor": (1.02, 1.0), "borderaxespad": 0.0, **options}
    return axis.legend(**options)


def save_figure(figure: Any, path: str | Path, *, tight: bool = True) -> list[Path]:
    """Write ``path`` (a ``.png`` at :data:`DPI`) and the same figure as a PDF beside it; returns both paths.

    ``tight`` crops to the drawn content (legends outside the axes included); False keeps the figure's size.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"save_figure writes a .png and a {VECTOR_SUFFIX} beside it, got {path}")
    options = {"bbox_inches": "tight", "pad_inches": 0.05} if tight else {}
    return [write_figure(figure, target, dpi=DPI, **options) for target in (path, path.with_suffix(VECTOR_SUFFIX))]


#: Why the area under an end-to-end curve is not the uncertainty's AUC-PR (said in the caption; drawn under the
#: axes only with ``note=True``).
AREA_NOTE = (
    "The area under an end-to-end curve is not the AUC-PR of the uncertainty (Table 1): that AUC-PR is the area "
    "of precision against the recall of correct answers; here recall counts all answerable queries, so the x axis "
    "is shrunk by recall@1 ({recall:.2f}) and the area is about AUC-PR × recall@1."
)
#: What the number in a PR legend is, by the ``number`` option of :class:`RejectionCurveDisplay`.
LEGEND_NUMBERS: dict[str, str] = {
    "area": "the number in the legend is the area under the curve drawn (trapezoids between its points)",
    "auc_pr": "the number in the legend is the AUC-PR of the uncertainty (Table 1), not the area of the curve drawn",
    "none": "",
}
_RECALL_LABEL = "recall (correct accepted / answerable)"
_PRECISION_LABEL = "precision (correct / accepted)"


def _axis(ax: Any) -> Any:
    """The axis to draw on: ``ax``, or a new figure's (pyplot imported only here, so the backend is the user's)."""
    if ax is not None:
        if not hasattr(ax, "plot") or not hasattr(ax, "figure"):
            raise TypeError(f"ax must be a matplotlib Axes, got {type(ax).__name__}")
        return ax
    import matplotlib.pyplot as plt

    _, ax = plt.subplots()
    return ax


def curve_area(curve: RejectionCurve) -> float:
    """The area under an end-to-end curve as drawn: trapezoids of precision over recall between its points.

    Examples
    --------
    >>> curve_area(rejection_curve([True, False, True, True], [0.1, 0.9, 0.2, 0.5]))
    0.5
    """
    if len(curve.recall) < 2:
        return 0.0
    return float(np.trapezoid(curve.precision, curve.recall))


def _curve_entries(
    curves: Mapping[str, RejectionCurve], auc_pr: Mapping[str, float | None], number: str
) -> list[tuple[str, str, list[str]]]:
    """(legend label, style key, methods) per drawn line: methods whose curves coincide share one line."""
    if number not in LEGEND_NUMBERS:
        raise ValueError(f"number must be one of {', '.join(LEGEND_NUMBERS)}, got {number!r}")
    entries = []
    for group in coinciding({name: (curve.recall, curve.precision) for name, curve in curves.items()}):
        key = " = ".join(group)
        label = key
        if number == "area":
            label = f"{key} (area {curve_area(curves[group[0]]):.3f})"
        elif number == "auc_pr" and auc_pr.get(group[0]) is not None:
            label = f"{key} (AUC-PR of the uncertainty {auc_pr[group[0]]:.3f})"
        entries.append((label, key, group))
    return entries


class RejectionCurveDisplay:
    """End-to-end precision-recall curves with rejection: accept the answers whose uncertainty is <= a threshold.

    Parameters
    ----------
    curves : mapping of str to RejectionCurve
        One curve per method, in drawing order.
    auc_pr : mapping of str to float or None, optional
        AUC-PR of each method (shown in the legend with ``number="auc_pr"``).
    accept_all : float, optional
        Precision when every answer is accepted (the share of correct top-1 answers): a grey reference line.
    n_queries : int, optional
        Shown in the default title.
    recall_at_1 : float, optional
        The retrieval's recall@1: with ``note=True``, a note under the axes (:data:`AREA_NOTE`) says why the area
        under a curve is not the uncertainty's AUC-PR.

    Attributes
    ----------
    ax_, figure_ : matplotlib Axes and Figure
        Where the curves were drawn (after :meth:`plot`).
    lines_ : dict of str to matplotlib Line2D
        The curve of each method; methods whose curves coincide (the same ranking of the queries, e.g. BM and L2)
        share one line, labelled ``"BM = L2"``.

    Examples
    --------
    >>> import matplotlib.pyplot as plt
    >>> display = RejectionCurveDisplay.from_predictions([True, False, True, True], [0.1, 0.9, 0.2, 0.5], name="SU")
    >>> display.lines_["SU"].get_ydata().tolist(), display.lines_["SU"].get_label()
    ([1.0, 1.0, 1.0, 0.75], 'SU (area 0.500)')
    >>> plt.close(display.figure_)
    """

    def __init__(
        self,
        curves: Mapping[str, RejectionCurve],
        *,
        auc_pr: Mapping[str, float | None] | None = None,
        accept_all: float | None = None,
        n_queries: int | None = None,
        recall_at_1: float | None = None,
    ) -> None:
        if not curves:
            raise ValueError("curves is empty: nothing to draw")
        self.curves = dict(curves)
        self.auc_pr = dict(auc_pr or {})
        self.accept_all = accept_all
        self.n_queries = n_queries
        self.recall_at_1 = recall_at_1

    def labels(self, number: str = "area") -> list[str]:
        """The legend labels :meth:`plot` draws, in order (the accept-all line last)."""
        labels = [label for label, _, _ in _curve_entries(self.curves, self.auc_pr, number)]
        return labels + ([f"accept all ({self.accept_all:.3f})"] if self.accept_all is not None else [])

    def plot(
        self,
        ax: Any = None,
        *,
        title: str | None = None,
        legend: bool = True,
        number: str = "area",
        note: bool = False,
    ) -> RejectionCurveDisplay:
        """Draw the curves on ``ax`` (a new figure when None); returns ``self`` with ``ax_``, ``figure_``, ``lines_``.

        Parameters
        ----------
        ax : matplotlib Axes, optional
        title : str, optional
            Axis title; by default "Rejecting uncertain answers (Q queries)".
        legend : bool, default=True
            Draw the legend, to the right of the axes (outside the data).
        number : {"area", "auc_pr", "none"}, default="area"
            The number after each method in the legend: the area under the curve drawn, the AUC-PR of the
            uncertainty (a different number: see :data:`AREA_NOTE`), or none.
        note : bool, default=False
            Write :data:`AREA_NOTE` under the axes (needs ``recall_at_1``); a paper says it in the caption instead.
        """
        ax = _axis(ax)
        self.lines_ = {}
        entries = _curve_entries(self.curves, self.auc_pr, number)
        styles = method_styles([key for _, key, _ in entries])
        for label, key, group in entries:
            curve = self.curves[group[0]]
            (line,) = ax.plot(
                curve.recall,
                curve.precision,
                label=label,
                linewidth=1.2,
                markersize=4,
                markevery=max(len(curve.recall) // 8, 1),
                **styles[key],
            )
            self.lines_.update(dict.fromkeys(group, line))
        lowest = [float(curve.precision.min()) for curve in self.curves.values() if len(curve.precision)]
        if self.accept_all is not None:
            ax.axhline(
                self.accept_all, color="grey", linestyle=":", linewidth=1, label=f"accept all ({self.accept_all:.3f})"
            )
            lowest.append(self.accept_all)
        ax.set_xlabel(_RECALL_LABEL)
        ax.set_ylabel(_PRECISION_LABEL)
        ax.set_xlim(0, 1.0)
        ax.set_ylim(max(0.0, np.floor((min(lowest, default=0.0) - 0.05) * 10) / 10), 1.02)
        ax.grid(alpha=0.3)
        if legend:
            legend_outside(ax, title="uncertainty method")
        queries = f" ({self.n_queries} queries)" if self.n_queries is not None else ""
        ax.set_title(title or f"Rejecting uncertain answers{queries}")
        if note and self.recall_at_1 is not None:
            text = AREA_NOTE.format(recall=self.recall_at_1)
            ax.text(0.0, -0.2, text, transform=ax.transAxes, fontsize=FONT_SIZE, va="top", wrap=True, color="0.3")
        self.ax_, self.figure_ = ax, ax.figure
        return self

    @classmethod
    def from_evaluation(
        cls,
        evaluation: Evaluation,
        *,
        methods: Sequence[str] | None = None,
        ax: Any = None,
        title: str | None = None,
        legend: bool = True,
        number: str = "area",
        note: bool = False,
    ) -> RejectionCurveDisplay:
        """Draw the curves of an evaluation's methods.

        Parameters
        ----------
        evaluation : Evaluation
            The result of :func:`vpr_uncertainty.evaluate`.
        methods : sequence of str, optional
            The methods to draw, in this order; by default all, in the evaluation's order.
        ax, title, legend, number, note
            As in :meth:`plot`.
        """
        return cls._of_evaluation(evaluation, methods).plot(ax, title=title, legend=legend, number=number, note=note)

    @classmethod
    def _of_evaluation(cls, evaluation: Evaluation, methods: Sequence[str] | None = None) -> RejectionCurveDisplay:
        names = list(evaluation.methods) if methods is None else list(methods)
        unknown = [name for name in names if name not in evaluation.methods]
        if unknown:
            raise ValueError(
                f"methods {unknown} are not in the evaluation; it has {', '.join(evaluation.methods) or 'none'}"
            )
        chosen = [evaluation.methods[name] for name in names]
        return cls(
            {method.name: method.curve for method in chosen},
            auc_pr={method.name: method.auc_pr for method in chosen},
            accept_all=float(np.mean(evaluation.correct)),
            n_queries=evaluation.n_queries,
            recall_at_1=evaluation.recall_at_n.get(1, float(np.mean(evaluation.correct))),
        )

    @classmethod
    def from_predictions(
        cls,
        correct: object,
        uncertainty: object,
        *,
        name: str = "uncertainty",
        n_answerable: int | None = None,
        ax: Any = None,
        title: str | None = None,
        legend: bool = True,
        number: str = "area",
    ) -> RejectionCurveDisplay:
        """Draw the curve of one uncertainty on labelled queries.

        Parameters
        ----------
        correct : array-like of shape (Q,), bool
            Whether each query's top-1 answer is correct.
        uncertainty : array-like of shape (Q,)
            Higher = less trustworthy.
        name : str, default="uncertainty"
            Legend label.
        n_answerable : int, optional
            Queries with at least one positive (the recall denominator); by default all.
        ax, title, legend, number
            As in :meth:`plot`.
        """
        curve = rejection_curve(correct, uncertainty, n_answerable=n_answerable)
        labels = np.asarray(correct).astype(bool)
        display = cls({name: curve}, accept_all=float(labels.mean()), n_queries=labels.size)
        return display.plot(ax, title=title, legend=legend, number=number)


def rejection_curves_spec(
    evaluation: Evaluation, *, title: str | None = None, number: str = "area", what: str | None = None
) -> FigureSpec:
    """The :class:`FigureSpec` of :func:`draw_rejection_curves`: one axis, one legend entry per drawn line."""
    display = RejectionCurveDisplay._of_evaluation(evaluation)
    entries = _curve_entries(display.curves, display.auc_pr, number)
    styles = method_styles([key for _, key, _ in entries])
    series = [
        SeriesSpec(label, "one ranking of the queries" if len(group) > 1 else "", styles[key])
        for label, key, group in entries
    ]
    series.append(SeriesSpec(display.labels(number)[-1], "precision when every answer is accepted", {"linestyle": ":"}))
    notes = [
        "Precision against recall of the VPR system as the most uncertain answers are rejected; methods that "
        "rank the queries identically share one line (e.g. “BM = L2”)",
        "recall = correct answers accepted / answerable queries; precision = correct answers / accepted answers",
    ]
    if LEGEND_NUMBERS[number]:
        notes.append(LEGEND_NUMBERS[number][0].upper() + LEGEND_NUMBERS[number][1:])
    if display.recall_at_1 is not None:
        notes.append(AREA_NOTE.format(recall=display.recall_at_1))
    queries = f" ({evaluation.n_queries} queries)"
    return FigureSpec(
        what=what or (title or "Rejecting uncertain answers") + queries + ": end-to-end precision-recall",
        series=tuple(series),
        x=_RECALL_LABEL,
        y=_PRECISION_LABEL,
        notes=tuple(notes),
    )


class ReliabilityDisplay:
    """Reliability diagram of a predicted P(correct top-1): observed share of correct answers against mean P per bin.

    Parameters
    ----------
    reliability : Reliability
        From :func:`vpr_uncertainty.calibration.quality.reliability_diagram`.
    name : str, default="observed"
        Legend label of the curve.

    Attributes
    ----------
    ax_, figure_ : matplotlib Axes and Figure
        Where the diagram was drawn (after :meth:`plot`).
    line_ : matplotlib Line2D
        The observed curve (one marker per non-empty bin, annotated with its count).

    Examples
    --------
    >>> import matplotlib.pyplot as plt
    >>> figure, ax = plt.subplots()
    >>> display = ReliabilityDisplay.from_predictions([False, True, True], [0.1, 0.15, 0.9], n_bins=2, ax=ax)
    >>> display.ax_ is ax, display.line_.get_ydata().tolist()
    (True, [0.5, 1.0])
    >>> plt.close(figure)
    """

    def __init__(self, reliability: Reliability, *, name: str = "observed") -> None:
        if not isinstance(reliability, Reliability):
            raise TypeError(f"reliability must be a Reliability (see reliability_diagram), got {type(reliability)}")
        self.reliability = reliability
        self.name = name

    def plot(self, ax: Any = None, *, title: str | None = None) -> ReliabilityDisplay:
        """Draw on ``ax`` (a new figure when None); returns ``self`` with ``ax_``, ``figure_`` and ``line_``."""
        ax = _axis(ax)
        ax.plot([0, 1], [0, 1], ":", color="grey", label="perfect calibration")
        reliability = self.reliability
        bins = [
            (mean, accuracy, count)
            for mean, accuracy, count in zip(
                reliability.mean_probability, reliability.accuracy, reliability.counts, strict=True
            )
            if count
        ]
        (self.line_,) = ax.plot([b[0] for b in bins], [b[1] for b in bins], "o-", label=self.name)
        for mean, accuracy, count in bins:
            ax.annotate(f"n={count}", (mean, accuracy), textcoords="offset points", xytext=(4, -10), fontsize=FONT_SIZE)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("predicted P(correct top-1), mean of the bin")
        ax.set_ylabel("share of correct top-1 answers")
        ax.legend(loc="upper left")
        if title:
            ax.set_title(title)
        self.ax_, self.figure_ = ax, ax.figure
        return self

    @classmethod
    def from_reliability(
        cls, reliability: Reliability, *, name: str = "observed", ax: Any = None, title: str | None = None
    ) -> ReliabilityDisplay:
        """Draw a reliability diagram already computed (e.g. ``results.json``'s ``calibration_quality``)."""
        return cls(reliability, name=name).plot(ax, title=title)

    @classmethod
    def from_predictions(
        cls,
        correct: object,
        probability: object,
        *,
        n_bins: int = 10,
        name: str = "observed",
        ax: Any = None,
        title: str | None = None,
    ) -> ReliabilityDisplay:
        """Bin predicted probabilities (equal-width bins over [0, 1]) against outcomes and draw the diagram.

        Parameters
        ----------
        correct : array-like of shape (Q,), bool
            Whether each query's top-1 answer is correct.
        probability : array-like of shape (Q,)
            Predicted P(correct top-1), in [0, 1].
        n_bins : int, default=10
        name, ax, title
            As in :meth:`plot`.
        """
        return cls(reliability_diagram(probability, correct, n_bins=n_bins), name=name).plot(ax, title=title)

    @classmethod
    def from_gate(
        cls,
        gate: Gate,
        scores: object,
        correct: object,
        *,
        n_bins: int = 10,
        ax: Any = None,
        title: str | None = None,
    ) -> ReliabilityDisplay:
        """Reliability of a gate's P(correct) on labelled queries (use held-out ones: in-sample looks better).

        Parameters
        ----------
        gate : Gate
            From :func:`vpr_uncertainty.calibrate` or :meth:`Gate.load`.
        scores : array-like of shape (Q, K)
            Top-k similarities of the labelled queries, sorted descending.
        correct : array-like of shape (Q,), bool
            Whether each query's top-1 answer is correct.
        n_bins, ax, title
            As in :meth:`from_predictions`.
        """
        probability = gate.probability_correct(scores)
        return cls.from_predictions(correct, probability, n_bins=n_bins, name="gate P(correct)", ax=ax, title=title)


class RecallAtNDisplay:
    """recall@N against N for one or several VPR methods: the share of queries with a positive in the top N.

    Parameters
    ----------
    recalls : mapping of str to mapping of int to float
        Per VPR method (in drawing order), recall@N by N (:attr:`Evaluation.recall_at_n`).

    Attributes
    ----------
    ax_, figure_ : matplotlib Axes and Figure
        Where the curves were drawn (after :meth:`plot`).
    lines_ : dict of str to matplotlib Line2D
        The curve of each VPR method (one marker per N).

    Examples
    --------
    >>> import matplotlib.pyplot as plt
    >>> display = RecallAtNDisplay({"NetVLAD": {1: 0.5, 5: 0.75, 10: 1.0}}).plot()
    >>> display.lines_["NetVLAD"].get_xdata().tolist(), display.lines_["NetVLAD"].get_ydata().tolist()
    ([1, 5, 10], [0.5, 0.75, 1.0])
    >>> plt.close(display.figure_)
    """

    def __init__(self, recalls: Mapping[str, Mapping[int, float]]) -> None:
        if not recalls or not any(recalls.values()):
            raise ValueError("recalls is empty: nothing to draw (give recall@N by N for at least one VPR method)")
        self.recalls = {
            name: dict(sorted((int(n), float(v)) for n, v in curve.items())) for name, curve in recalls.items()
        }

    def plot(self, ax: Any = None, *, title: str | None = None, legend: bool = True) -> RecallAtNDisplay:
        """Draw on ``ax`` (a new figure when None); returns ``self`` with ``ax_``, ``figure_`` and ``lines_``.

        The x axis is logarithmic when the largest N is at least 10 times the smallest; its ticks are the Ns.
        """
        import matplotlib.ticker

        ax = _axis(ax)
        styles = method_styles(list(self.recalls))
        self.lines_ = {}
        for name, curve in self.recalls.items():
            (self.lines_[name],) = ax.plot(list(curve), list(curve.values()), label=name, markersize=4, **styles[name])
        ns = sorted({n for curve in self.recalls.values() for n in curve})
        if ns[-1] >= 10 * ns[0]:
            ax.set_xscale("log")
            ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.set_xticks(ns, [str(n) for n in ns])
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("N (database images retrieved)")
        ax.set_ylabel("recall@N")
        ax.grid(alpha=0.3)
        if legend and len(self.recalls) > 1:
            ax.legend(title="VPR method", loc="lower right")
        if title:
            ax.set_title(title)
        self.ax_, self.figure_ = ax, ax.figure
        return self

    @classmethod
    def from_evaluation(
        cls,
        evaluation: Evaluation | Mapping[str, Evaluation],
        *,
        name: str = "VPR method",
        ax: Any = None,
        title: str | None = None,
        legend: bool = True,
    ) -> RecallAtNDisplay:
        """Draw the recall@N an evaluation stores (or several: ``{VPR method: Evaluation}``).

        Parameters
        ----------
        evaluation : Evaluation or mapping of str to Evaluation
            One VPR method's evaluation (labelled ``name``), or one per VPR method.
        name : str, default="VPR method"
            The label of a single evaluation.
        ax, title, legend
            As in :meth:`plot`.
        """
        evaluations = evaluation if isinstance(evaluation, Mapping) else {name: evaluation}
        recalls = {}
        for label, one in evaluations.items():
            if not hasattr(one, "recall_at_n"):
                raise TypeError(f"{label!r}: expected an Evaluation (with recall_at_n), got {type(one).__name__}")
            recalls[label] = one.recall_at_n
        return cls(recalls).plot(ax, title=title, legend=legend)


# --- file writers ---


def _pr_figure_size(width: str, n_entries: int) -> tuple[float, float]:
    """One axis with the legend below it: ``n_entries`` legend entries in rows of one (column) or two (page)."""
    columns = 1 if width == "column" else 2
    axis_height = 2.4 if width == "column" else 3.2
    rows = -(-max(n_entries, 1) // columns)
    return figure_width(width), capped_height(axis_height + 0.75 + 0.19 * rows, width)


def draw_rejection_curves(
    evaluation: Evaluation, *, title: str | None = None, width: str = "page", number: str = "area"
) -> Any:
    """The figure of :func:`plot_rejection_curves` at a paper ``width`` (the caller closes it, outside any rc block:
    its fonts are set when drawn). The legend is below the axis; :func:`rejection_curves_spec` describes it."""
    plt = pyplot()
    display = RejectionCurveDisplay._of_evaluation(evaluation)
    labels = display.labels(number)
    with figure_rc(width):
        figure, axes = plt.subplots(figsize=_pr_figure_size(width, len(labels)), layout="constrained")
        display.plot(axes, title=title, legend=False, number=number)
        handles, texts = axes.get_legend_handles_labels()
        figure.legend(handles, texts, loc="outside lower center", ncol=1 if width == "column" else 2, frameon=False)
    return figure


@functools.lru_cache(maxsize=1)
def _drawing_code() -> str:
    """A hash of this module's source: the code that draws the figures (a change of it draws them again)."""
    return hashlib.blake2b(Path(__file__).read_bytes(), digest_size=16).hexdigest()


def rejection_curves_inputs(evaluation: Evaluation, *, title: str | None = None, width: str = "page") -> str:
    """The fingerprint of what :func:`plot_rejection_curves` draws, without drawing it (nor importing matplotlib).

    Hashed: each method's name (in order), AUC-PR and curve (recall and precision), the share of correct answers,
    the number of queries, recall@1, the title, the width, the resolution and the source of this module.
    """
    methods = [
        [name, method.auc_pr, array_digest(method.curve.recall, method.curve.precision)]
        for name, method in evaluation.methods.items()
    ]
    return fingerprint(
        "figure",
        {"figure": "rejection_curves", "title": title, "width": width, "dpi": DPI, "code": _drawing_code()},
        {
            "methods": methods,
            "accept_all": float(np.mean(evaluation.correct)),
            "n_queries": evaluation.n_queries,
            "recall_at_1": evaluation.recall_at_n.get(1),
        },
    )


def plot_rejection_curves(
    evaluation: Evaluation, path: str | Path, *, title: str | None = None, reuse: bool = False, width: str = "page"
) -> Path:
    """Draw the end-to-end precision-recall curves of all methods in one figure and save it.

    Each curve is the VPR system's precision and recall as the uncertainty threshold for accepting an answer is
    relaxed; the legend gives the area under each curve drawn. To draw on your own axis:
    :class:`RejectionCurveDisplay`; its caption: :func:`rejection_curves_spec`.

    Parameters
    ----------
    evaluation : Evaluation
        The result of :func:`vpr_uncertainty.evaluate`.
    path : str or Path
        Output file; the format follows its suffix (``.png`` at 300 dpi, ``.pdf``, ``.svg``).
    title : str, optional
        Figure title.
    reuse : bool, default=False
        Keep a PNG at ``path`` already drawn from the same inputs (:func:`rejection_curves_inputs`, stored in the
        PNG with a checksum: :func:`~vpr_uncertainty.cache.figure_is_current`) instead of drawing it again; a
        missing, corrupted or outdated figure is drawn.
    width : {"page", "column"}, default="page"
        7.16 or 3.5 inches wide, 8-pt fonts.
    """
    path = Path(path)
    figure_width(width)
    png = (path.suffix.lower() or ".png") == ".png"
    inputs = rejection_curves_inputs(evaluation, title=title, width=width) if png else None
    if reuse and inputs is not None and figure_is_current(path, inputs):
        return path
    plt = pyplot()
    figure = draw_rejection_curves(evaluation, title=title, width=width)
    try:
        with figure_rc(width):
            return write_figure(figure, path, inputs=inputs, dpi=DPI)
    finally:
        plt.close(figure)


def write_rejection_curves(
    evaluation: Evaluation, path: str | Path, *, title: str | None = None, width: str = "page"
) -> list[Path]:
    """:func:`plot_rejection_curves` as a 300-dpi PNG (``path``) and a PDF beside it; returns both."""
    plt = pyplot()
    figure = draw_rejection_curves(evaluation, title=title, width=width)
    try:
        with figure_rc(width):
            return save_figure(figure, path, tight=False)
    finally:
        plt.close(figure)


def plot_reliability(
    reliability: Reliability, path: str | Path, *, title: str | None = None, width: str = "page"
) -> Path:
    """Draw observed accuracy against mean P per bin (with the count of each bin) and save it
    (:class:`ReliabilityDisplay` draws on your own axis).

    Parameters
    ----------
    reliability : Reliability
        From :func:`vpr_uncertainty.calibration.quality.reliability_diagram`.
    path : str or Path
        Output file; the format follows its suffix (``.png``, ``.pdf``, ``.svg``).
    title : str, optional
        Figure title.
    width : {"page", "column"}, default="page"
        3.5 or 7.16 inches wide (a square-ish diagram, at most 4.5 in tall), 8-pt fonts.
    """
    plt = pyplot()
    size = (figure_width(width), 3.4 if width == "column" else 4.5)
    with figure_rc(width):
        figure, axes = plt.subplots(figsize=size, dpi=DPI, layout="constrained")
        try:
            ReliabilityDisplay.from_reliability(reliability, ax=axes, title=title)
            return write_figure(figure, path, dpi=DPI)
        finally:
            plt.close(figure)
