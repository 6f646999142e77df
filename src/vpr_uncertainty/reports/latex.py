"""LaTeX pieces of the tables (:mod:`vpr_uncertainty.reports.tables`): escaping, and a booktabs ``table`` float that
fits a column width."""

from __future__ import annotations

import re
from collections.abc import Sequence

__all__ = ["LATEX_PACKAGES", "latex_escape", "latex_float"]

_LATEX_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "<": r"\textless{}",  # in text, < and > are ¡ and ¿ in the default (OT1) font encoding
    ">": r"\textgreater{}",
}


def latex_escape(text: str) -> str:
    """``text`` with LaTeX's ten special characters and ``<``, ``>`` escaped, in one pass (no escape escaped again).

    Examples
    --------
    >>> print(latex_escape("SU$^2$ ~ {50%} & A_b"))
    SU\\$\\textasciicircum{}2\\$ \\textasciitilde{} \\{50\\%\\} \\& A\\_b
    """
    return re.sub(r"[\\&%$#_{}~^<>]", lambda match: _LATEX_SPECIAL[match.group()], text)


#: What a document needs for the LaTeX tables: booktabs rules, and graphicx's \\resizebox that fits the width.
LATEX_PACKAGES = r"\usepackage{booktabs}\usepackage{graphicx}"


def latex_float(
    caption: str, label: str, column_spec: str, header: Sequence[str], rows: Sequence[Sequence[str]], width: str | None
) -> list[str]:
    """A ``table`` float (``table*``, two columns wide, for ``width=r"\\textwidth"``): caption and label above,
    booktabs rules, the tabular shrunk to ``width`` when wider.

    ``\\resizebox{\\ifdim\\width>W W\\else\\width\\fi}{!}{...}`` scales the tabular down to ``W`` only when its natural
    width exceeds it (never up), so a table fits ``\\columnwidth`` whatever the number of its columns.
    """
    tabular = [
        r"\begin{tabular}{" + column_spec + "}",
        r"\toprule",
        " & ".join(header) + r" \\",
        r"\midrule",
        *(" & ".join(row) + r" \\" for row in rows),
        r"\bottomrule",
        r"\end{tabular}",
    ]
    if width is not None:
        tabular = [rf"\resizebox{{\ifdim\width>{width}{width}\else\width\fi}}{{!}}{{%", *tabular, "}"]
    return [
        r"\begin{table*}[t]" if width == r"\textwidth" else r"\begin{table}[t]",
        r"\centering",
        rf"\caption{{{latex_escape(caption)}}}",
        rf"\label{{{label}}}",
        *tabular,
    ]
