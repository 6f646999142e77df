"""The report part of a grid configuration: which figures to write (``report``) and which cells get a
qualitative figure (``qualitative``). Each function appends its problems to ``problems`` (all reported together by
:func:`vpr_uncertainty.study.load_config`)."""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from vpr_uncertainty.methods import split_method_list
from vpr_uncertainty.reports.figures import REPORT_FIGURES, parse_figure_spec, unmet_figure_needs

if TYPE_CHECKING:
    from vpr_uncertainty.study.config import InputEntry

__all__ = ["qualitative_methods", "report_figures"]


def qualitative_methods(raw: Any, entries: list[InputEntry], problems: list[str]) -> list[str] | None:
    """The VPR methods whose cells get a qualitative figure; a name that matches no cell is a problem."""
    if raw is None:
        return None
    names = [raw] if isinstance(raw, str) else raw
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        problems.append(f"qualitative must be a list of VPR method names (cells of the grid), got {raw!r}")
        return None
    known = sorted({entry.vpr_method for entry in entries})
    with_images = {entry.vpr_method for entry in entries if entry.images is not None or entry.model is not None}
    lower = {name.lower(): name for name in known}
    for name in names:
        if name not in known:
            close = difflib.get_close_matches(name.lower(), list(lower), n=1, cutoff=0.6)
            hint = f"; did you mean {lower[close[0]]!r}?" if close else ""
            problems.append(
                f"qualitative names {name!r}, which is no VPR method of the grid{hint} VPR methods: {', '.join(known)}"
            )
        elif name not in with_images:
            problems.append(f"qualitative names {name!r}, but no input of that VPR method has images (images = ...)")
    return names


def report_figures(
    raw: Any,
    entries: list[InputEntry],
    ablations: bool,
    problems: list[str],
    methods: Sequence[str] = (),
    *,
    calibrated: bool = False,
) -> list[str] | None:
    """The report figures to write (names or specs, see :mod:`vpr_uncertainty.reports.figures`); None: all.

    ``methods`` (the grid's uncertainty methods) tell whether the cascade figure can be drawn; ``calibrated``: CAL
    runs on held-out queries (the ``calibration`` option with CAL among the methods).
    """
    if raw is None:
        return None
    try:
        specs = split_method_list(raw) if isinstance(raw, str) else raw
    except ValueError as error:
        problems.append(f"report: {error}")
        return None
    if not isinstance(specs, list) or not all(isinstance(spec, str) for spec in specs):
        problems.append(f'report must be a list of report figure names such as ["table1", "pr_curves"], got {raw!r}')
        return None
    if not specs:
        problems.append(f"report is empty: name at least one report figure ({', '.join(REPORT_FIGURES.names())})")
    available = {"evaluation", "uncertainties"} | ({"ablations"} if ablations else set())
    if calibrated:
        available.add("calibration")
    if any(entry.images is not None or entry.model is not None for entry in entries):
        available.add("images")
    bases = {name.split(":")[0] for name in methods}
    if any(set(name.split("+")) <= bases for name in bases if name.count("+") == 1):
        available.add("cascade")
    names = []
    for spec in specs:
        try:
            name, _ = parse_figure_spec(spec)
        except (KeyError, ValueError) as error:
            problems.append(str(error.args[0]) if error.args else str(error))
            continue
        names.append(name)
        note = unmet_figure_needs(REPORT_FIGURES.get(name), available)
        if note:
            problems.append(f"{note}, which no input of the grid gives")
    problems += [
        f"report figure {name!r} is listed more than once" for name in sorted({n for n in names if names.count(n) > 1})
    ]
    return list(specs)
