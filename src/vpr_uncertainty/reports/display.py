"""How report figures are drawn: Display objects in scikit-learn's style (a ``from_*`` class method draws, ``plot``
draws again, ``ax_``, ``figure_`` and the artists are kept), and the file writers that save a PNG and a PDF
atomically. See docs/explanation/reports.md.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.cache import array_digest, figure_is_current, fingerprint, write_figure
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.calibration.quality import Reliability, reliability_diagram
from vpr_uncertainty.evaluation.metrics import RejectionCurve, rejection_curve
from vpr_uncertainty.evaluation.results import Evaluation
from vpr_uncertainty.reports import style
from vpr_uncertainty.reports.style import (
    DPI,
    FONT_SIZE,
    FigureSpec,
    SeriesSpec,
    capped_height,
    coinciding,
    figure_rc,
    figure_width,
    legend_outside,
    method_styles,
    pyplot,
    save_figure,
)

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
#: The PR legend's title, by ``number``: it names the number when the labels do not.
_LEGEND_TITLES = {"auc_pr": "uncertainty method (AUC-PR, Table 1)"}
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
    return float(np.trapezoid(curve.precision, curve.recall)) if len(curve.recall) > 1 else 0.0


def _curve_entries(
    curves: Mapping[str, RejectionCurve], auc_pr: Mapping[str, float | None], number: str
) -> list[tuple[str, str, list[str]]]:
    """(legend label, style key, methods) per drawn line: methods whose curves coincide share one line."""
    if number not in LEGEND_NUMBERS:
        raise ValueError(f"number must be one of {', '.join(LEGEND_NUMBERS)}, got {number!r}")
    entries = []
    for group in coinciding({name: (curve.recall, curve.precision) for name, curve in curves.items()}):
        key, auc = " = ".join(group), auc_pr.get(group[0])
        numbers = {
            "area": f" (area {curve_area(curves[group[0]]):.3f})",
            "auc_pr": "" if auc is None else f" {auc:.3f}",
        }
        entries.append((key + numbers.get(number, ""), key, group))  # auc_pr: named by the legend's title
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
            uncertainty (a different number: see :data:`AREA_NOTE`; the legend's title names it), or none.
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
        ylim = (max(0.0, np.floor((min(lowest, default=0.0) - 0.05) * 10) / 10), 1.02)
        end = max((float(curve.recall.max()) for curve in self.curves.values() if len(curve.recall)), default=1.0)
        ax.set(xlabel=_RECALL_LABEL, ylabel=_PRECISION_LABEL, xlim=(0, end or 1.0), ylim=ylim)  # ends at recall@1
        ax.grid(alpha=0.3)
        if legend:
            legend_outside(ax, title=_LEGEND_TITLES.get(number, "uncertainty method"))
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
        **options: Any,
    ) -> RejectionCurveDisplay:
        """Draw the curves of an evaluation's methods.

        Parameters
        ----------
        evaluation : Evaluation
            The result of :func:`vpr_uncertainty.evaluate`.
        methods : sequence of str, optional
            The methods to draw, in this order; by default all, in the evaluation's order.
        ax, **options
            As in :meth:`plot` (``title``, ``legend``, ``number``, ``note``).
        """
        return cls._of_evaluation(evaluation, methods).plot(ax, **options)

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
        **options: Any,
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
        ax, **options
            As in :meth:`plot` (``title``, ``legend``, ``number``, ``note``).
        """
        curve = rejection_curve(correct, uncertainty, n_answerable=n_answerable)
        labels = np.asarray(correct).astype(bool)
        display = cls({name: curve}, accept_all=float(labels.mean()), n_queries=labels.size)
        return display.plot(ax, **options)


def rejection_curves_spec(
    evaluation: Evaluation, *, title: str | None = None, number: str = "auc_pr", what: str | None = None
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
        The observed curve (one marker per non-empty bin).
    counts_ : list of matplotlib Text
        The count of each non-empty bin, above its bar in the strip under the diagram.

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

    def plot(
        self, ax: Any = None, *, title: str | None = None, threshold: float | None = None, label: str | None = None
    ) -> ReliabilityDisplay:
        """Draw on ``ax`` (a new figure when None); returns ``self`` with ``ax_``, ``figure_`` and ``line_``.

        The legend (where it covers the fewest points) gives ``label`` (default: the name and the ECE of the bins
        drawn); ``threshold`` (a gate's P threshold) is a vertical line. Under y = 0, bars show how many queries each
        bin holds, the count above each (upright beyond 10 bins): one bin apart, no count overlaps another or a point.
        """
        ax = _axis(ax)
        ax.plot([0, 1], [0, 1], ":", color="grey", label="perfect calibration")
        reliability = self.reliability
        counted = zip(reliability.mean_probability, reliability.accuracy, reliability.counts, strict=True)
        bins = [(mean, accuracy, count) for mean, accuracy, count in counted if count]
        ece = sum(count * abs(accuracy - mean) for mean, accuracy, count in bins) / max(sum(reliability.counts), 1)
        label = label or f"{self.name} (ECE {ece:.3f})"
        (self.line_,) = ax.plot([b[0] for b in bins], [b[1] for b in bins], "o-", label=label)
        edges, counts = np.asarray(reliability.edges), np.asarray(reliability.counts)
        centres, tops = (edges[:-1] + edges[1:]) / 2, 0.2 * counts / max(counts.max(initial=0), 1) - 0.45
        ax.bar(centres, tops + 0.45, 0.9 * np.diff(edges), -0.45, color="0.8", label="queries per bin")  # y < -0.25
        ax.axhline(-0.08, color="0.6", linewidth=0.6)
        upright = 90 if counts.size > 10 else 0  # side by side, more counts than 10 would touch at column width
        where = zip(centres, tops + 0.01, counts, strict=True)
        self.counts_ = [ax.text(x, y, f"{n}", ha="center", va="bottom", rotation=upright) for x, y, n in where if n]
        if threshold is not None:
            ax.axvline(threshold, color="0.3", linestyle="--", linewidth=1, label=f"gate threshold P ≥ {threshold:.3f}")
        ax.set(xlim=(-0.02, 1.02), ylim=(-0.47, 1.05), yticks=np.linspace(0, 1, 6))
        ax.set(xlabel="predicted P(correct top-1), mean of the bin", ylabel="share of correct top-1 answers")
        ax.legend(loc="best")
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
        scores : array-like of shape (Q, gate.k)
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
        ax.set(ylim=(0, 1.02), xlabel="N (database images retrieved)", ylabel="recall@N")
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
        **options: Any,
    ) -> RecallAtNDisplay:
        """Draw the recall@N an evaluation stores (or several: ``{VPR method: Evaluation}``).

        Parameters
        ----------
        evaluation : Evaluation or mapping of str to Evaluation
            One VPR method's evaluation (labelled ``name``), or one per VPR method.
        name : str, default="VPR method"
            The label of a single evaluation.
        ax, **options
            As in :meth:`plot` (``title``, ``legend``).
        """
        evaluations = evaluation if isinstance(evaluation, Mapping) else {name: evaluation}
        recalls = {}
        for label, one in evaluations.items():
            if not hasattr(one, "recall_at_n"):
                raise TypeError(f"{label!r}: expected an Evaluation (with recall_at_n), got {type(one).__name__}")
            recalls[label] = one.recall_at_n
        return cls(recalls).plot(ax, **options)


# --- file writers ---


#: Legend columns of a PR figure by width (short labels: the number is named by the legend's title).
_PR_LEGEND_COLUMNS = {"column": 2, "page": 3}


def draw_rejection_curves(
    evaluation: Evaluation, *, title: str | None = None, width: str = "page", number: str = "auc_pr"
) -> Any:
    """The figure of :func:`plot_rejection_curves` at a paper ``width`` (the caller closes it, outside any rc block:
    its fonts are set when drawn). The legend is below the axis, in :data:`_PR_LEGEND_COLUMNS` columns, its number
    by default Table 1's AUC-PR; :func:`rejection_curves_spec` describes it."""
    plt = pyplot()
    display = RejectionCurveDisplay._of_evaluation(evaluation)
    rows = -(-len(display.labels(number)) // _PR_LEGEND_COLUMNS[width])
    size = figure_width(width), capped_height((2.4 if width == "column" else 3.2) + 0.95 + 0.19 * rows, width)
    with figure_rc(width):
        figure, axes = plt.subplots(figsize=size, layout="constrained")
        display.plot(axes, title=title, legend=False, number=number)
        heading = _LEGEND_TITLES.get(number, "uncertainty method")
        figure.legend(loc="outside lower center", ncol=_PR_LEGEND_COLUMNS[width], frameon=False, title=heading)
    return figure


@functools.lru_cache(maxsize=1)
def _drawing_code() -> str:
    """A hash of the code that draws the figures, this module and :mod:`~vpr_uncertainty.reports.style` (its sizes,
    fonts and palette): a change of either draws them again."""
    digest = hashlib.blake2b(digest_size=16)
    for source in (Path(__file__), Path(style.__file__)):
        digest.update(source.read_bytes())
    return digest.hexdigest()


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
    relaxed; the legend gives each method's AUC-PR (Table 1's). To draw on your own axis:
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
    reliability: Reliability,
    path: str | Path,
    *,
    title: str | None = None,
    width: str = "page",
    threshold: float | None = None,
    label: str | None = None,
) -> Path:
    """Draw observed accuracy against mean P per bin (with the count of each bin and the ECE of the bins, or
    ``label`` in the legend) and save it (:class:`ReliabilityDisplay` draws on your own axis).

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
    threshold : float, optional
        A gate's threshold on P, drawn as a vertical line.
    label : str, optional
        The legend entry (default: ``"observed (ECE x)"``, the ECE of the bins drawn).
    """
    plt = pyplot()
    size = (figure_width(width), 3.4 if width == "column" else 4.5)
    with figure_rc(width):
        figure, axes = plt.subplots(figsize=size, dpi=DPI, layout="constrained")
        try:
            ReliabilityDisplay(reliability).plot(axes, title=title, threshold=threshold, label=label)
            axes.get_legend().remove()  # under the axes, where it covers no point
            figure.legend(loc="outside lower center", ncol=1 if width == "column" else 3, frameon=False)
            return write_figure(figure, path, dpi=DPI)
        finally:
            plt.close(figure)
