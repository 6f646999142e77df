"""Table 1 of the study: AUC-PR of each uncertainty method (rows) for each VPR method (columns).

Each cell is the AUC-PR averaged over the datasets on which it is defined; ``Mean`` averages a row over the VPR
methods and ``ms/query`` is the row's mean time per query. The best (highest) value of each column is marked:
bold in Markdown and LaTeX, listed in the ``best_for`` column of the CSV.

A cell is *uninformative* when on every one of its datasets the method gave the same uncertainty to all queries
(no ranking: AUC-PR at chance level). Such cells are marked ``†`` and never bold; a column with fewer than two
informative cells has no best value.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Table1", "build_table1", "table1_csv", "table1_html", "table1_latex", "table1_markdown"]


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

    def is_informative(self, i: int, j: int) -> bool:
        return self.informative is None or self.informative[i][j]

    def best(self) -> list[float | None]:
        """The highest informative value of each column (None where fewer than two informative values compete)."""
        best = []
        for j in range(len(self.columns)):
            column = [row[j] for i, row in enumerate(self.values) if row[j] is not None and self.is_informative(i, j)]
            best.append(max(column) if len(column) >= 2 else None)
        return best

    def cell_best(self) -> list[list[float | None]]:
        """Per cell: the column's best value where the cell is informative, else None (never marked)."""
        best = self.best()
        return [[b if self.is_informative(i, j) else None for j, b in enumerate(best)] for i in range(len(self.values))]


def _mean(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def build_table1(cells: Sequence) -> Table1:
    """Average the grid's AUC-PR over datasets; ``cells`` are :class:`vpr_uncertainty.study.Cell`."""
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
            row.append(_mean([m.auc_pr for m in found]))
            row_times += [m.time_per_query_ms for m in found]
            row_informative.append(any(getattr(m, "informative", True) for m in found if m.auc_pr is not None))
        row.append(_mean(row[: len(vpr_methods)]))
        row_informative.append(any(row_informative))
        values.append(row)
        times.append(_mean(row_times))
        informative.append(row_informative)
    return Table1(rows=methods, columns=[*vpr_methods, "Mean"], values=values, time_ms=times, informative=informative)


def _cell_text(value: float | None, best: float | None, bold: tuple[str, str], dagger: str = "") -> str:
    if value is None:
        return "–"
    text = f"{value:.3f}"
    if best is not None and np.isclose(value, best, rtol=0, atol=5e-7):
        return f"{bold[0]}{text}{bold[1]}"
    return text + dagger


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
    """GitHub Markdown; the best value of each column in bold."""
    best = table.cell_best()
    lines = [
        "| method | " + " | ".join(table.columns) + " | ms/query |",
        "|---|" + "---:|" * (len(table.columns) + 1),
    ]
    for i, (name, row, time_ms) in enumerate(zip(table.rows, table.values, table.time_ms, strict=True)):
        cells = [
            _cell_text(v, b, ("**", "**"), _dagger(table, i, j, "†"))
            for j, (v, b) in enumerate(zip(row, best[i], strict=True))
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {'–' if time_ms is None else f'{time_ms:.4f}'} |")
    if _any_uninformative(table):
        lines += ["", _FOOTNOTE]
    return "\n".join(lines) + "\n"


def table1_csv(table: Table1) -> str:
    """CSV with numeric cells (empty where undefined) and ``best_for``: the columns where the row is best.

    An uninformative cell keeps its number but never appears in ``best_for``.
    """
    best = table.cell_best()
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["method", *table.columns, "time_per_query_ms", "best_for"])
    for i, (name, row, time_ms) in enumerate(zip(table.rows, table.values, table.time_ms, strict=True)):
        best_for = [
            column
            for column, v, b in zip(table.columns, row, best[i], strict=True)
            if v is not None and b is not None and np.isclose(v, b, rtol=0, atol=5e-7)
        ]
        numbers = ["" if v is None else f"{v:.6f}" for v in [*row, time_ms]]
        writer.writerow([name, *numbers, ";".join(best_for)])
    return buffer.getvalue()


def _latex_escape(text: str) -> str:
    for char, replacement in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("_", r"\_"), ("#", r"\#")):
        text = text.replace(char, replacement)
    return text


def table1_latex(table: Table1, *, caption: str = "AUC-PR of each uncertainty method, averaged over datasets.") -> str:
    """A booktabs ``table`` environment (needs ``\\usepackage{booktabs}``); the best value per column in bold."""
    best = table.cell_best()
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
            _cell_text(v, b, (r"\textbf{", "}"), _dagger(table, i, j, r"$^\dagger$")).replace("–", "--")
            for j, (v, b) in enumerate(zip(row, best[i], strict=True))
        ]
        time_text = "--" if time_ms is None else f"{time_ms:.4f}"
        lines.append(" & ".join([_latex_escape(name), *cells, time_text]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    if _any_uninformative(table):
        lines.append(r"\par\smallskip{\footnotesize $^\dagger$ uninformative: constant uncertainty (chance level).}")
    lines.append(r"\end{table}")
    return "\n".join(lines) + "\n"


def table1_html(table: Table1) -> str:
    """An HTML ``<table>``; the best value per column in bold."""
    from html import escape

    best = table.cell_best()
    head = "".join(f"<th>{escape(c)}</th>" for c in ["method", *table.columns, "ms/query"])
    body = []
    for i, (name, row, time_ms) in enumerate(zip(table.rows, table.values, table.time_ms, strict=True)):
        cells = "".join(
            f"<td>{_cell_text(v, b, ('<b>', '</b>'), _dagger(table, i, j, '†'))}</td>"
            for j, (v, b) in enumerate(zip(row, best[i], strict=True))
        )
        time_text = "–" if time_ms is None else f"{time_ms:.4f}"
        body.append(f"<tr><th>{escape(name)}</th>{cells}<td>{time_text}</td></tr>")
    return f'<table class="table1"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table>'
