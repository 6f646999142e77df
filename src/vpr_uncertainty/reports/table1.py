"""Table 1 of the study: AUC-PR of each uncertainty method (rows) for each VPR method (columns).

Each cell is the AUC-PR averaged over the datasets on which it is defined; ``Mean`` averages a row over the VPR
methods and ``ms/query`` is the row's mean time per query. The best (highest) value of each column is marked:
bold in Markdown and LaTeX, listed in the ``best_for`` column of the CSV.
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
    """rows: uncertainty methods; columns: VPR methods followed by ``Mean``; values[i][j] may be None."""

    rows: list[str]
    columns: list[str]
    values: list[list[float | None]]
    time_ms: list[float | None]

    def best(self) -> list[float | None]:
        """The highest value of each column (None where the column is empty)."""
        best = []
        for j in range(len(self.columns)):
            column = [row[j] for row in self.values if row[j] is not None]
            best.append(max(column) if column else None)
        return best


def _mean(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def build_table1(cells: Sequence) -> Table1:
    """Average the grid's AUC-PR over datasets; ``cells`` are :class:`vpr_uncertainty.reproduce.Cell`."""
    vpr_methods = list(dict.fromkeys(cell.vpr_method for cell in cells))
    methods = list(dict.fromkeys(name for cell in cells for name in cell.evaluation.methods))
    values, times = [], []
    for method in methods:
        row = []
        row_times = []
        for vpr in vpr_methods:
            found = [
                c.evaluation.methods[method] for c in cells if c.vpr_method == vpr and method in c.evaluation.methods
            ]
            row.append(_mean([m.auc_pr for m in found]))
            row_times += [m.time_per_query_ms for m in found]
        row.append(_mean(row[: len(vpr_methods)]))
        values.append(row)
        times.append(_mean(row_times))
    return Table1(rows=methods, columns=[*vpr_methods, "Mean"], values=values, time_ms=times)


def _cell_text(value: float | None, best: float | None, bold: tuple[str, str]) -> str:
    if value is None:
        return "–"
    text = f"{value:.3f}"
    return f"{bold[0]}{text}{bold[1]}" if best is not None and np.isclose(value, best, rtol=0, atol=5e-7) else text


def table1_markdown(table: Table1) -> str:
    """GitHub Markdown; the best value of each column in bold."""
    best = table.best()
    lines = [
        "| method | " + " | ".join(table.columns) + " | ms/query |",
        "|---|" + "---:|" * (len(table.columns) + 1),
    ]
    for name, row, time_ms in zip(table.rows, table.values, table.time_ms, strict=True):
        cells = [_cell_text(v, b, ("**", "**")) for v, b in zip(row, best, strict=True)]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {'–' if time_ms is None else f'{time_ms:.4f}'} |")
    return "\n".join(lines) + "\n"


def table1_csv(table: Table1) -> str:
    """CSV with numeric cells (empty where undefined) and ``best_for``: the columns where the row is best."""
    best = table.best()
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["method", *table.columns, "time_per_query_ms", "best_for"])
    for name, row, time_ms in zip(table.rows, table.values, table.time_ms, strict=True):
        best_for = [
            column
            for column, v, b in zip(table.columns, row, best, strict=True)
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
    best = table.best()
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
    for name, row, time_ms in zip(table.rows, table.values, table.time_ms, strict=True):
        cells = [_cell_text(v, b, (r"\textbf{", "}")).replace("–", "--") for v, b in zip(row, best, strict=True)]
        time_text = "--" if time_ms is None else f"{time_ms:.4f}"
        lines.append(" & ".join([_latex_escape(name), *cells, time_text]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def table1_html(table: Table1) -> str:
    """An HTML ``<table>``; the best value per column in bold."""
    from html import escape

    best = table.best()
    head = "".join(f"<th>{escape(c)}</th>" for c in ["method", *table.columns, "ms/query"])
    body = []
    for name, row, time_ms in zip(table.rows, table.values, table.time_ms, strict=True):
        cells = "".join(f"<td>{_cell_text(v, b, ('<b>', '</b>'))}</td>" for v, b in zip(row, best, strict=True))
        time_text = "–" if time_ms is None else f"{time_ms:.4f}"
        body.append(f"<tr><th>{escape(name)}</th>{cells}<td>{time_text}</td></tr>")
    return f'<table class="table1"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table>'
