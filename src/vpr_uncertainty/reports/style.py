"""How the report figures look: paper sizes, fonts, the colour-blind-safe palette with a marker and a dash per
series (:func:`method_styles`, :func:`figure_rc`), the figure specs that captions are written from
(:class:`FigureSpec`), and atomic saving. The choices and why: see docs/explanation/reports.md.
"""

from __future__ import annotations

import contextlib
import contextvars
import zlib
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.cache import write_figure

#: Resolution of every PNG a report writes.
DPI = 300
#: The vector format written beside each PNG.
VECTOR_SUFFIX = ".pdf"
#: Okabe and Ito's colour-blind-safe palette without its yellow (faint on white): blue, vermillion, bluish green,
#: reddish purple, orange, sky blue, black.
OKABE_ITO: tuple[str, ...] = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000")
#: The series colours: Okabe-Ito, then Paul Tol's wine, olive, indigo, brown and purple: 12 colours, as many markers.
PALETTE: tuple[str, ...] = (*OKABE_ITO, "#882255", "#999933", "#332288", "#661100", "#AA4499")
_DASHES: tuple[Any, ...] = ("-", "--", "-.", ":", (0, (5, 1, 1, 1, 1, 1)))
_MARKERS = ("o", "s", "^", "v", "D", "P", "X", "d", "<", ">", "h", "p")  # no "*": the best-α mark
#: Names with a fixed style, by position (the toolkit's uncertainty methods, then VPR-Bench's VPR methods); any
#: other name starts at a slot chosen by a hash of the name.
STYLED_NAMES: tuple[str, ...] = (
    *("RS", "SD", "SU", "BM", "L2", "PA", "margin", "SUE", "BTL", "GV-SIFT", "GV-DISK-LG", "CAL", "SU-adaptive"),
    *("AMOSNet", "AlexNet_VPR", "CALC", "CoHOG", "HOG", "HybridNet", "NetVLAD", "RegionVLAD", "ap-gem-r101"),
    "denseVLAD",
)
#: How a caption names a marker and a dash.
_MARKER_WORDS = {"o": "circles", "s": "squares", "^": "triangles up", "v": "triangles down", "D": "diamonds"}
_MARKER_WORDS |= {"P": "plus signs", "X": "crosses", "*": "stars", "<": "triangles left", ">": "triangles right"}
_MARKER_WORDS |= {"h": "hexagons", "p": "pentagons", "d": "thin diamonds"}
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
    sizes = ("font.", "axes.label", "xtick.label", "ytick.label", "legend.font", "legend.title_font", "figure.label")
    rc = {f"{key}size": FONT_SIZE for key in sizes} | {"axes.titlesize": TITLE_SIZE, "figure.titlesize": TITLE_SIZE}
    rc |= {"axes.linewidth": 0.6, "grid.linewidth": 0.4, "lines.linewidth": 1.2, "lines.markersize": 4}
    rc |= {"xtick.major.width": 0.6, "ytick.major.width": 0.6, "axes.prop_cycle": matplotlib.cycler(color=OKABE_ITO)}
    rc["pdf.fonttype"] = 42  # TrueType in the PDF: editable text, accepted by publishers
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


def _slot_style(slot: int) -> dict[str, Any]:
    """Slot ``i``: colour ``i % 12``, marker ``(i + i // 12) % 12`` (no two of 144 slots share both), dash ``i % 5``."""
    colours = len(PALETTE)
    marker = _MARKERS[(slot + slot // colours) % len(_MARKERS)]
    return {"color": PALETTE[slot % colours], "linestyle": _DASHES[slot % len(_DASHES)], "marker": marker}


#: The names of the study being drawn (:func:`study_styles`), one tuple per kind (uncertainty, VPR methods).
_STUDY: contextvars.ContextVar[tuple[tuple[str, ...], ...]] = contextvars.ContextVar("study", default=())


@contextlib.contextmanager
def study_styles(*kinds: Sequence[str]) -> Iterator[None]:
    """Inside this block, :func:`method_styles` styles a name as among all ``kinds`` names of the study (those of
    the figure if one kind does not hold them all), so a name keeps its colour and marker in every figure."""
    token = _STUDY.set(tuple(tuple(names) for names in kinds))
    try:
        yield
    finally:
        _STUDY.reset(token)


def method_styles(names: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``{name: {"color", "linestyle", "marker"}}``, the same for a name in every figure: a colour (:data:`PALETTE`),
    a dash and a marker from the name's slot (its place in :data:`STYLED_NAMES`, else a hash of it); in slot order,
    a name whose colour or marker another name of ``names`` (or of the study, :func:`study_styles`) already has
    takes the next free slot (past 12 names, one whose (colour, marker) or (marker, dash) is taken). Coinciding methods
    ``"BM = L2"`` take the style of the first of them in :data:`STYLED_NAMES`.

    Examples
    --------
    >>> styles = method_styles(["SU", "SD"])
    >>> styles["SD"], styles["SU"]["color"] == method_styles(["BM", "L2", "SU"])["SU"]["color"]
    ({'color': '#D55E00', 'linestyle': '--', 'marker': 's'}, True)
    """
    first = {name: min(name.split(" = "), key=_slot) for name in names}
    pool = next((kind for kind in _STUDY.get() if set(first.values()) <= set(kind)), first.values())
    styles: dict[str, dict[str, Any]] = {}
    for name in sorted(set(pool), key=lambda name: (_slot(name), name)):
        slot = _slot(name)
        while any(_clashes(_slot_style(slot), taken, len(styles)) for taken in styles.values()) and slot < 300:
            slot += 1
        styles[name] = _slot_style(slot)
    return {name: styles[part] for name, part in first.items()}


def _slot(name: str) -> int:
    return STYLED_NAMES.index(name) if name in STYLED_NAMES else 23 + zlib.crc32(name.encode()) % 26


def _clashes(a: Mapping[str, Any], b: Mapping[str, Any], taken: int) -> bool:
    same, marker = a["color"] == b["color"], a["marker"] == b["marker"]
    return (same or marker) if taken < len(PALETTE) else marker and (same or a["linestyle"] == b["linestyle"])


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
