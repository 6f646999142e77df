"""Table 1 of the study: AUC-PR (or AP, or AURC) of each uncertainty method (rows) for each VPR method (columns).

Each cell is the metric averaged over the datasets on which it is defined; ``Mean`` averages a row over the VPR
methods and ``ms/query`` is the row's mean time per query. The best value of each column (highest; lowest for
AURC) is marked: bold in Markdown and LaTeX, listed in the ``best_for`` column of the CSV.

With a bootstrap (``build_table1(..., bootstrap=N)``, see :mod:`vpr_uncertainty.reports.table1_bootstrap`) each
cell also shows its 95 % interval (``0.850 [0.79, 0.90]``; ``_ci_low``/``_ci_high`` columns in the CSV), and the
marks follow the paired tests: the best alone where it is significantly better than every other method of its
column (``significant_best_for`` in the CSV), otherwise every method not significantly worse than it (tied leaders).

A cell is *uninformative* when on every one of its datasets the method gave the same uncertainty to all queries
(no ranking: AUC-PR at chance level). Such cells are marked ``†`` and never bold; a column with fewer than two
informative cells has no best value.
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vpr_uncertainty.reports.tables import markdown_cell

__all__ = [
    "METRIC_NAMES",
    "Table1",
    "build_table1",
    "marks_note",
    "table1_csv",
    "table1_html",
    "table1_latex",
    "table1_markdown",
]

#: The metrics a Table 1 can hold: display name and whether higher is better.
METRIC_NAMES: dict[str, tuple[str, bool]] = {
    "auc_pr": ("AUC-PR", True),
    "average_precision": ("AP", True),
    "aurc": ("AURC", False),
}


@dataclass
class Table1:
    """rows: uncertainty methods; columns: VPR methods followed by ``Mean``; values[i][j] may be None.

    ``informative[i][j]`` is False for a cell whose every underlying result had a constant uncertainty (None:
    every cell is informative).
    """

    rows: list[str]
    columns: list[str]
    values: list[list[float | None]]
    time_ms: list[float | None]
    informative: list[list[bool]] | None = None
    metric: str = "auc_pr"
    higher_is_better: bool = True
    intervals: list[list[tuple[float, float] | None]] | None = None
    leaders: list[list[bool]] | None = None
    significant: list[bool] | None = None
    bootstrap: dict[str, Any] | None = None

    def is_informative(self, i: int, j: int) -> bool:
        return self.informative is None or self.informative[i][j]

    def best(self) -> list[float | None]:
        """The best informative value of each column (None where fewer than two informative values compete)."""
        best = []
        for j in range(len(self.columns)):
            column = [row[j] for i, row in enumerate(self.values) if row[j] is not None and self.is_informative(i, j)]
            best.append((max if self.higher_is_better else min)(column) if len(column) >= 2 else None)
        return best

    def marks(self) -> list[list[bool]]:
        """Per cell, whether it is marked: a bootstrap leader, or (no bootstrap) equal to the column's best."""
        if self.leaders is not None:
            return [list(row) for row in self.leaders]
        return [
            [
                v is not None and b is not None and bool(np.isclose(v, b, rtol=0, atol=5e-7))
                for v, b in zip(r, bs, strict=True)
            ]
            for r, bs in zip(self.values, self.cell_best(), strict=True)
        ]

    def cell_best(self) -> list[list[float | None]]:
        """Per cell: the column's best value where the cell is informative, else None (never marked)."""
        best = self.best()
        return [[b if self.is_informative(i, j) else None for j, b in enumerate(best)] for i in range(len(self.values))]


def _mean(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def build_table1(
    cells: Sequence, metric: str = "auc_pr", *, bootstrap: int = 0, seed: int = 0, level: float = 0.05
) -> Table1:
    """Average a metric of the grid over datasets; ``cells`` are :class:`vpr_uncertainty.pipeline.grid_report.Cell`.

    Parameters
    ----------
    cells : sequence of Cell
        The grid's results.
    metric : {"auc_pr", "average_precision", "aurc"}
        The metric of the table.
    bootstrap : int, default=0
        Paired bootstrap resamples for the intervals and the significance marks (0: none, the best value marked).
    seed : int, default=0
        Seed of the resamples.
    level : float, default=0.05
        Family-wise level of the tests of each column.
    """
    if metric not in METRIC_NAMES:
        raise ValueError(f"metric must be one of {', '.join(METRIC_NAMES)}, got {metric!r}")
    vpr_methods = list(dict.fromkeys(cell.vpr_method for cell in cells))
    methods = list(dict.fromkeys(name for cell in cells for name in cell.evaluation.methods))
    values, times, informative = [], [], []
    for method in methods:
        row = []
        row_times = []
        row_informative = []
        for vpr in vpr_methods:
            found = [
                c.evaluation.methods[method] for c in cells if c.vpr_method == vpr and method in c.evaluation.methods
            ]
            row.append(_mean([getattr(m, metric) for m in found]))
            row_times += [m.time_per_query_ms for m in found]
            row_informative.append(
                any(getattr(m, "informative", True) for m in found if getattr(m, metric) is not None)
            )
        row.append(_mean(row[: len(vpr_methods)]))
        row_informative.append(any(row_informative))
        values.append(row)
        times.append(_mean(row_times))
        informative.append(row_informative)
    table = Table1(
        rows=methods,
        columns=[*vpr_methods, "Mean"],
        values=values,
        time_ms=times,
        informative=informative,
        metric=metric,
        higher_is_better=METRIC_NAMES[metric][1],
    )
    if bootstrap and cells:
        from vpr_uncertainty.reports.table1_bootstrap import column_distributions, table_significance

        distributions = column_distributions(cells, table.columns, bootstrap, seed)
        table_significance(table, distributions[metric], level)
        table.bootstrap = {"resamples": int(bootstrap), "seed": int(seed), "level": level}
    return table


def _cell_text(
    value: float | None,
    marked: bool,
    bold: tuple[str, str],
    dagger: str = "",
    interval: tuple[float, float] | None = None,
    around: tuple[str, str] = ("", ""),
) -> str:
    if value is None:
        return "–"
    text = f"{bold[0]}{value:.3f}{bold[1]}" if marked else f"{value:.3f}{dagger}"
    if interval is not None:
        text += f" {around[0]}[{interval[0]:.2f}, {interval[1]:.2f}]{around[1]}"
    return text


def _interval(table: Table1, i: int, j: int) -> tuple[float, float] | None:
    return None if table.intervals is None else table.intervals[i][j]


def marks_note(table: Table1) -> str:
    """What the marks mean: the best value, or (bootstrap) significant best vs tied leaders."""
    direction = "highest" if table.higher_is_better else "lowest"
    if table.bootstrap is None:
        return f"Bold: the best ({direction}) value of each column; no significance test (bootstrap = 0)."
    return (
        f"Bold alone: the best ({direction}) of its column and significantly better than every other method; "
        "several in bold: tied leaders, none significantly worse than the best (paired bootstrap over queries, "
        f"{table.bootstrap['resamples']} resamples, seed {table.bootstrap['seed']}, Holm-corrected at "
        f"{table.bootstrap['level']:g}). [low, high]: 95 % percentile interval."
    )


def _dagger(table: Table1, i: int, j: int, mark: str) -> str:
    return "" if table.is_informative(i, j) else mark


_FOOTNOTE = "† uninformative: the same uncertainty for every query on every dataset (AUC-PR at chance level)."


def _any_uninformative(table: Table1) -> bool:
    return any(
        not table.is_informative(i, j) and table.values[i][j] is not None
        for i in range(len(table.rows))
        for j in range(len(table.columns))
    )


def table1_markdown(table: Table1) -> str:
    """GitHub Markdown; the marked values of each column in bold, then what the marks mean."""
    marks = table.marks()
    lines = [
        "| method | " + " | ".join(markdown_cell(c) for c in table.columns) + " | ms/query |",
        "|---|" + "---:|" * (len(table.columns) + 1),
    ]
    for i, (name, row, time_ms) in enumerate(zip(table.rows, table.values, table.time_ms, strict=True)):
        cells = [
            _cell_text(v, marks[i][j], ("**", "**"), _dagger(table, i, j, "†"), _interval(table, i, j))
            for j, v in enumerate(row)
        ]
        time_text = "–" if time_ms is None else f"{time_ms:.4f}"
        lines.append(f"| {markdown_cell(name)} | " + " | ".join(cells) + f" | {time_text} |")
    lines += ["", marks_note(table)]
    if _any_uninformative(table):
        lines += ["", _FOOTNOTE]
    return "\n".join(lines) + "\n"


def table1_csv(table: Table1) -> str:
    """CSV with numeric cells (empty where undefined) and ``best_for``: the columns where the row is marked.

    An uninformative cell keeps its number but never appears in ``best_for``. With a bootstrap, each column ``C``
    is followed by ``C_ci_low`` and ``C_ci_high``, and ``significant_best_for`` lists the columns where the row is
    the best alone, significantly better than every other method.
    """
    marks = table.marks()
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    with_ci = table.intervals is not None
    columns = [part for c in table.columns for part in ((c, f"{c}_ci_low", f"{c}_ci_high") if with_ci else (c,))]
    extra = ["significant_best_for"] if with_ci else []
    writer.writerow(["method", *columns, "time_per_query_ms", "best_for", *extra])
    for i, (name, row, time_ms) in enumerate(zip(table.rows, table.values, table.time_ms, strict=True)):
        best_for = [column for j, column in enumerate(table.columns) if marks[i][j]]
        numbers = []
        for j, v in enumerate(row):
            numbers.append("" if v is None else f"{v:.6f}")
            if with_ci:
                interval = _interval(table, i, j)
                numbers += ["", ""] if interval is None else [f"{interval[0]:.6f}", f"{interval[1]:.6f}"]
        numbers.append("" if time_ms is None else f"{time_ms:.6f}")
        sole = [c for j, c in enumerate(table.columns) if marks[i][j] and table.significant and table.significant[j]]
        writer.writerow([name, *numbers, ";".join(best_for), *([";".join(sole)] if with_ci else [])])
    return buffer.getvalue()


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
}


def _latex_escape(text: str) -> str:
    """``text`` with LaTeX's ten special characters escaped, in one pass (so no escape is escaped again).

    Examples
    --------
    >>> print(_latex_escape("SU$^2$ ~ {50%} & A_b"))
    SU\\$\\textasciicircum{}2\\$ \\textasciitilde{} \\{50\\%\\} \\& A\\_b
    """
    return re.sub(r"[\\&%$#_{}~^]", lambda match: _LATEX_SPECIAL[match.group()], text)


def table1_latex(table: Table1, *, caption: str | None = None) -> str:
    """A booktabs ``table`` environment (needs ``\\usepackage{booktabs}``); the marked values per column in bold."""
    if caption is None:
        caption = f"{METRIC_NAMES[table.metric][0]} of each uncertainty method, averaged over datasets. "
        caption += marks_note(table)
    marks = table.marks()
    header = " & ".join(["Method", *(_latex_escape(c) for c in table.columns), "ms/query"])
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        rf"\caption{{{_latex_escape(caption)}}}",
        r"\begin{tabular}{l" + "r" * (len(table.columns) + 1) + "}",
        r"\toprule",
        header + r" \\",
        r"\midrule",
    ]
    for i, (name, row, time_ms) in enumerate(zip(table.rows, table.values, table.time_ms, strict=True)):
        cells = [
            _cell_text(
                v,
                marks[i][j],
                (r"\textbf{", "}"),
                _dagger(table, i, j, r"$^\dagger$"),
                _interval(table, i, j),
                (r"{\scriptsize ", "}"),
            ).replace("–", "--")
            for j, v in enumerate(row)
        ]
        time_text = "--" if time_ms is None else f"{time_ms:.4f}"
        lines.append(" & ".join([_latex_escape(name), *cells, time_text]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    if _any_uninformative(table):
        lines.append(r"\par\smallskip{\footnotesize $^\dagger$ uninformative: constant uncertainty (chance level).}")
    lines.append(r"\end{table}")
    return "\n".join(lines) + "\n"


def table1_html(table: Table1) -> str:
    """An HTML ``<table>``; the marked values per column in bold."""
    from html import escape

    marks = table.marks()
    head = "".join(f"<th>{escape(c)}</th>" for c in ["method", *table.columns, "ms/query"])
    body = []
    for i, (name, row, time_ms) in enumerate(zip(table.rows, table.values, table.time_ms, strict=True)):
        cells = "".join(
            f"<td>{_cell_text(v, marks[i][j], ('<b>', '</b>'), _dagger(table, i, j, '†'), _interval(table, i, j))}</td>"
            for j, v in enumerate(row)
        )
        time_text = "–" if time_ms is None else f"{time_ms:.4f}"
        body.append(f"<tr><th>{escape(name)}</th>{cells}<td>{time_text}</td></tr>")
    return f'<table class="table1"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table>'
