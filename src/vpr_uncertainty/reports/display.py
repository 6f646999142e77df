"""How report figures look and are drawn: styles, atomic saving, and Display objects in scikit-learn's style.

Like :class:`sklearn.metrics.PrecisionRecallDisplay`, each Display is made by a ``from_*`` class method that draws at
once on the ``ax`` given (or a new figure) and keeps ``ax_``, ``figure_`` and its artists (``lines_`` by method
name, or ``line_``); ``plot(ax=None)`` draws the same data again. Displays pick no backend and save nothing; the
file writers (:func:`plot_rejection_curves`, :func:`plot_reliability`, :func:`save_figure`) draw off-screen and
write atomically: a 300-dpi PNG for ``report.html`` and a vector PDF beside it.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Mapping, Sequence
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
    "VECTOR_SUFFIX",
    "RejectionCurveDisplay",
    "ReliabilityDisplay",
    "coinciding",
    "draw_rejection_curves",
    "legend_outside",
    "method_styles",
    "plot_rejection_curves",
    "plot_reliability",
    "pyplot",
    "rejection_curves_inputs",
    "save_figure",
    "write_rejection_curves",
]

#: Resolution of every PNG a report writes.
DPI = 300
#: The vector format written beside each PNG.
VECTOR_SUFFIX = ".pdf"
_COLOURS = tuple(f"C{i}" for i in range(10))
_DASHES = ("-", "--", "-.", ":")
_MARKERS = ("o", "s", "^", "v", "D", "P", "X")


def pyplot() -> Any:
    """``matplotlib.pyplot`` with the off-screen backend."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def method_styles(names: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``{name: {"color", "linestyle", "marker"}}``: no two of the first 140 names share all three.

    Examples
    --------
    >>> styles = method_styles(["RS", "SD", "SU"])
    >>> styles["SD"]
    {'color': 'C1', 'linestyle': '--', 'marker': 's'}
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
    options = {"loc": "upper left", "bbox_to_anchor": (1.02, 1.0), "borderaxespad": 0.0, "fontsize": "small", **options}
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


#: Why the area under an end-to-end curve is not the AUC-PR of the legend (written under the curves).
AREA_NOTE = (
    "Area under a curve ≠ the AUC-PR in the legend: the AUC-PR is the area of precision against the recall of "
    "correct answers; here recall counts all answerable queries, so the x axis is shrunk by recall@1 "
    "({recall:.2f}) and the area is about AUC-PR × recall@1."
)


def _axis(ax: Any) -> Any:
    """The axis to draw on: ``ax``, or a new figure's (pyplot imported only here, so the backend is the user's)."""
    if ax is not None:
        if not hasattr(ax, "plot") or not hasattr(ax, "figure"):
            raise TypeError(f"ax must be a matplotlib Axes, got {type(ax).__name__}")
        return ax
    import matplotlib.pyplot as plt

    _, ax = plt.subplots()
    return ax


class RejectionCurveDisplay:
    """End-to-end precision-recall curves with rejection: accept the answers whose uncertainty is <= a threshold.

    Parameters
    ----------
    curves : mapping of str to RejectionCurve
        One curve per method, in drawing order.
    auc_pr : mapping of str to float or None, optional
        AUC-PR of each method, shown in the legend.
    accept_all : float, optional
        Precision when every answer is accepted (the share of correct top-1 answers): a grey reference line.
    n_queries : int, optional
        Shown in the default title.
    recall_at_1 : float, optional
        The retrieval's recall@1: with it, a note under the axes (:data:`AREA_NOTE`) says why the area under a
        curve is not the AUC-PR of the legend.

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
    >>> display.lines_["SU"].get_ydata().tolist()
    [1.0, 1.0, 1.0, 0.75]
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

    def plot(self, ax: Any = None, *, title: str | None = None, legend: bool = True) -> RejectionCurveDisplay:
        """Draw the curves on ``ax`` (a new figure when None); returns ``self`` with ``ax_``, ``figure_``, ``lines_``.

        Parameters
        ----------
        ax : matplotlib Axes, optional
        title : str, optional
            Axis title; by default "Rejecting uncertain answers (Q queries)".
        legend : bool, default=True
            Draw the legend, to the right of the axes (outside the data).
        """
        ax = _axis(ax)
        self.lines_ = {}
        groups = coinciding({name: (curve.recall, curve.precision) for name, curve in self.curves.items()})
        styles = method_styles([" = ".join(group) for group in groups])
        for group in groups:
            label = " = ".join(group)
            curve, score = self.curves[group[0]], self.auc_pr.get(group[0])
            (line,) = ax.plot(
                curve.recall,
                curve.precision,
                label=label if score is None else f"{label} (AUC-PR {score:.3f})",
                linewidth=1.4,
                markersize=4,
                markevery=max(len(curve.recall) // 8, 1),
                **styles[label],
            )
            self.lines_.update(dict.fromkeys(group, line))
        lowest = [float(curve.precision.min()) for curve in self.curves.values() if len(curve.precision)]
        if self.accept_all is not None:
            ax.axhline(
                self.accept_all, color="grey", linestyle=":", linewidth=1, label=f"accept all ({self.accept_all:.3f})"
            )
            lowest.append(self.accept_all)
        ax.set_xlabel("recall: correct answers accepted / answerable queries")
        ax.set_ylabel("precision: correct answers / accepted answers")
        ax.set_xlim(0, 1.0)
        ax.set_ylim(max(0.0, np.floor((min(lowest, default=0.0) - 0.05) * 10) / 10), 1.02)
        ax.grid(alpha=0.3)
        if legend:
            legend_outside(ax, title="uncertainty method")
        queries = f" ({self.n_queries} queries)" if self.n_queries is not None else ""
        ax.set_title(title or f"Rejecting uncertain answers{queries}", fontsize=10)
        if self.recall_at_1 is not None:
            note = AREA_NOTE.format(recall=self.recall_at_1)
            ax.text(0.0, -0.16, note, transform=ax.transAxes, fontsize=7, va="top", wrap=True, color="0.3")
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
    ) -> RejectionCurveDisplay:
        """Draw the curves of an evaluation's methods.

        Parameters
        ----------
        evaluation : Evaluation
            The result of :func:`vpr_uncertainty.evaluate`.
        methods : sequence of str, optional
            The methods to draw, in this order; by default all, in the evaluation's order.
        ax, title, legend
            As in :meth:`plot`.
        """
        names = list(evaluation.methods) if methods is None else list(methods)
        unknown = [name for name in names if name not in evaluation.methods]
        if unknown:
            raise ValueError(
                f"methods {unknown} are not in the evaluation; it has {', '.join(evaluation.methods) or 'none'}"
            )
        chosen = [evaluation.methods[name] for name in names]
        display = cls(
            {method.name: method.curve for method in chosen},
            auc_pr={method.name: method.auc_pr for method in chosen},
            accept_all=float(np.mean(evaluation.correct)),
            n_queries=evaluation.n_queries,
            recall_at_1=evaluation.recall_at_n.get(1, float(np.mean(evaluation.correct))),
        )
        return display.plot(ax, title=title, legend=legend)

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
        ax, title, legend
            As in :meth:`plot`.
        """
        curve = rejection_curve(correct, uncertainty, n_answerable=n_answerable)
        labels = np.asarray(correct).astype(bool)
        display = cls({name: curve}, accept_all=float(labels.mean()), n_queries=labels.size)
        return display.plot(ax, title=title, legend=legend)


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
            ax.annotate(f"n={count}", (mean, accuracy), textcoords="offset points", xytext=(4, -10), fontsize=7)
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


# --- file writers ---


def draw_rejection_curves(evaluation: Evaluation, *, title: str | None = None) -> Any:
    """The figure of :func:`plot_rejection_curves` (the caller closes it)."""
    plt = pyplot()
    figure, axes = plt.subplots(figsize=(6.4, 4.2))
    RejectionCurveDisplay.from_evaluation(evaluation, ax=axes, title=title)
    return figure


@functools.lru_cache(maxsize=1)
def _drawing_code() -> str:
    """A hash of this module's source: the code that draws the figures (a change of it draws them again)."""
    return hashlib.blake2b(Path(__file__).read_bytes(), digest_size=16).hexdigest()


def rejection_curves_inputs(evaluation: Evaluation, *, title: str | None = None) -> str:
    """The fingerprint of what :func:`plot_rejection_curves` draws, without drawing it (nor importing matplotlib).

    Hashed: each method's name (in order), AUC-PR and curve (recall and precision), the share of correct answers,
    the number of queries, recall@1, the title, the resolution and the source of this module.
    """
    methods = [
        [name, method.auc_pr, array_digest(method.curve.recall, method.curve.precision)]
        for name, method in evaluation.methods.items()
    ]
    return fingerprint(
        "figure",
        {"figure": "rejection_curves", "title": title, "dpi": DPI, "code": _drawing_code()},
        {
            "methods": methods,
            "accept_all": float(np.mean(evaluation.correct)),
            "n_queries": evaluation.n_queries,
            "recall_at_1": evaluation.recall_at_n.get(1),
        },
    )


def plot_rejection_curves(
    evaluation: Evaluation, path: str | Path, *, title: str | None = None, reuse: bool = False
) -> Path:
    """Draw the end-to-end precision-recall curves of all methods in one figure and save it.

    Each curve is the VPR system's precision and recall as the uncertainty threshold for accepting an answer is
    relaxed; the legend gives each method's AUC-PR. To draw on your own axis: :class:`RejectionCurveDisplay`.

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
    """
    path = Path(path)
    png = (path.suffix.lower() or ".png") == ".png"
    inputs = rejection_curves_inputs(evaluation, title=title) if png else None
    if reuse and inputs is not None and figure_is_current(path, inputs):
        return path
    plt = pyplot()
    figure = draw_rejection_curves(evaluation, title=title)
    try:
        return write_figure(figure, path, inputs=inputs, dpi=DPI, bbox_inches="tight")
    finally:
        plt.close(figure)


def write_rejection_curves(evaluation: Evaluation, path: str | Path, *, title: str | None = None) -> list[Path]:
    """:func:`plot_rejection_curves` as a 300-dpi PNG (``path``) and a PDF beside it; returns both."""
    plt = pyplot()
    figure = draw_rejection_curves(evaluation, title=title)
    try:
        return save_figure(figure, path)
    finally:
        plt.close(figure)


def plot_reliability(reliability: Reliability, path: str | Path, *, title: str | None = None) -> Path:
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
    """
    plt = pyplot()
    figure, axes = plt.subplots(figsize=(5.2, 4.8), dpi=120)
    try:
        ReliabilityDisplay.from_reliability(reliability, ax=axes, title=title)
        figure.tight_layout()
        return write_figure(figure, path)
    finally:
        plt.close(figure)
