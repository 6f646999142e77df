"""How tied each method's uncertainties are: per uncertainty method (rows) and VPR method (columns), the share of
queries whose uncertainty equals another query's and the number of distinct values, averaged over datasets.

Ties matter because the trapezoid AUC-PR joins the points of tied groups by straight lines: a method with a few
distinct values (geometric verification's inlier counts) gets a curve of a few points whose linear interpolation
lies above the step-wise curve of average precision. Read AUC-PR beside AP and AURC for such methods.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["TiesTable", "build_ties_table", "ties_csv", "ties_markdown"]


@dataclass
class TiesTable:
    """rows: uncertainty methods; columns: VPR methods; ``tied_share``/``distinct`` may hold None (no cell)."""

    rows: list[str]
    columns: list[str]
    tied_share: list[list[float | None]]
    distinct: list[list[float | None]]
    n_queries: list[float | None]


def build_ties_table(cells: Sequence) -> TiesTable:
    """Average each method's tied share and distinct values over the datasets of each VPR method."""
    columns = list(dict.fromkeys(cell.vpr_method for cell in cells))
    rows = list(dict.fromkeys(name for cell in cells for name in cell.evaluation.methods))
    shares, distinct = [], []
    for method in rows:
        found = [
            [c.evaluation.methods[method] for c in cells if c.vpr_method == vpr and method in c.evaluation.methods]
            for vpr in columns
        ]
        shares.append([float(np.mean([m.tied_share for m in f])) if f else None for f in found])
        distinct.append([float(np.mean([m.n_distinct for m in f])) if f else None for f in found])
    n_queries = [float(np.mean([c.evaluation.n_queries for c in cells if c.vpr_method == vpr])) for vpr in columns]
    return TiesTable(rows=rows, columns=columns, tied_share=shares, distinct=distinct, n_queries=n_queries)


def ties_markdown(table: TiesTable) -> str:
    """GitHub Markdown: ``97 % (8)`` = 97 % of the queries tied, 8 distinct values."""
    lines = ["| method | " + " | ".join(table.columns) + " |", "|---|" + "---:|" * len(table.columns)]
    for name, shares, distinct in zip(table.rows, table.tied_share, table.distinct, strict=True):
        cells = ["–" if s is None else f"{s:.0%} ({d:.0f})" for s, d in zip(shares, distinct, strict=True)]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    queries = ", ".join(f"{n:.0f}" for n in dict.fromkeys(q for q in table.n_queries if q is not None))
    lines += [
        "",
        f"Share of queries whose uncertainty equals another query's (distinct values in brackets; {queries} queries "
        "per cell). The trapezoid AUC-PR interpolates linearly between tied groups: compare it with AP and AURC for "
        "methods with few distinct values.",
    ]
    return "\n".join(lines) + "\n"


def ties_csv(table: TiesTable) -> str:
    """CSV: ``C_tied_share`` and ``C_distinct_values`` for each VPR method ``C`` (empty where undefined)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["method", *(f"{c}_{part}" for c in table.columns for part in ("tied_share", "distinct_values"))])
    for name, shares, distinct in zip(table.rows, table.tied_share, table.distinct, strict=True):
        values = []
        for share, count in zip(shares, distinct, strict=True):
            values += ["", ""] if share is None else [f"{share:.6f}", f"{count:g}"]
        writer.writerow([name, *values])
    return buffer.getvalue()
