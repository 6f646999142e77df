"""How report figures look and are saved, so that each can go into a paper as it is.

- :func:`save_figure`: a 300-dpi PNG (for ``report.html`` and slides) and a vector PDF beside it, both written
  atomically;
- :func:`method_styles`: a distinct colour + dash + marker for every method, stable for a given list of names;
- :func:`coinciding`: the methods whose curves coincide (same ranking of the queries, e.g. BM and L2 on
  L2-normalised descriptors), to draw once with a label such as ``"BM = L2"`` instead of one hiding the other;
- :func:`legend_outside`: the legend to the right of the axes, never over the data.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.cache import atomic_path

__all__ = ["DPI", "VECTOR_SUFFIX", "coinciding", "legend_outside", "method_styles", "pyplot", "save_figure"]

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
    """Write ``path`` (a ``.png`` at :data:`DPI`) and the same figure as a vector PDF beside it.

    Parameters
    ----------
    figure : matplotlib.figure.Figure
    path : str or Path
        The PNG file; the PDF gets the same name with :data:`VECTOR_SUFFIX`.
    tight : bool, default=True
        Crop to the drawn content (legends outside the axes included); False keeps the figure's size exactly.

    Returns
    -------
    list of Path
        The PNG and the PDF.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"save_figure writes a .png and a {VECTOR_SUFFIX} beside it, got {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    options = {"bbox_inches": "tight", "pad_inches": 0.05} if tight else {}
    written = []
    for target in (path, path.with_suffix(VECTOR_SUFFIX)):
        with atomic_path(target) as temporary:
            figure.savefig(temporary, dpi=DPI, format=target.suffix.lstrip("."), **options)
        written.append(target)
    return written
