"""Bootstrap intervals and significance marks of Table 1 (see :mod:`vpr_uncertainty.reports.table1`).

A column of Table 1 averages a metric over the datasets of one VPR method; ``Mean`` averages the columns. The
bootstrap follows the same averages resample by resample: each cell is resampled over its queries with
:func:`~vpr_uncertainty.evaluation.bootstrap.resample_indices` (the same seed, so the cells of one dataset share
their resamples, and a one-dataset column has the very intervals of its cell in ``results.json``), every
uncertainty method on the same resamples (paired). In a column, the best method is compared with each other one
(:func:`~vpr_uncertainty.evaluation.bootstrap.leaders`, Holm-corrected): it is marked alone when it is
significantly better than every other one, otherwise every method not significantly worse than it is marked.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from vpr_uncertainty.evaluation.bootstrap import evaluation_distributions, leaders, percentile_interval

__all__ = ["column_distributions", "table_significance"]


def column_distributions(
    cells: Sequence[Any], columns: Sequence[str], n_resamples: int, seed: int
) -> dict[str, dict[tuple[str, str], np.ndarray]]:
    """``metric -> (method, column) -> (B,)``: each column's average over its cells, per resample.

    ``columns`` are the VPR methods followed by ``Mean`` (the average over the VPR-method columns where the method
    has a value). A resample skipped in one cell (one class only) is skipped in the averages that include it.
    """
    per_cell = [(cell, evaluation_distributions(cell.evaluation, n_resamples, seed)) for cell in cells]
    result: dict[str, dict[tuple[str, str], np.ndarray]] = {}
    for metric in per_cell[0][1] if per_cell else ():
        by_key: dict[tuple[str, str], np.ndarray] = {}
        methods = list(dict.fromkeys(name for cell in cells for name in cell.evaluation.methods))
        for method in methods:
            for column in columns[:-1]:
                found = [
                    distributions[metric][method]
                    for cell, distributions in per_cell
                    if cell.vpr_method == column
                    and getattr(cell.evaluation.methods.get(method), metric, None) is not None
                ]
                if found:
                    by_key[method, column] = np.mean(found, axis=0)
            row = [by_key[method, column] for column in columns[:-1] if (method, column) in by_key]
            if row:
                by_key[method, columns[-1]] = np.mean(row, axis=0)
        result[metric] = by_key
    return result


def table_significance(table: Any, distributions: dict[tuple[str, str], np.ndarray], level: float = 0.05) -> None:
    """Set ``table.intervals`` (95 % percentile) and ``table.leaders`` / ``table.significant`` in place.

    Only informative cells with a value compete in a column; fewer than two: nothing is marked.
    """
    intervals, marked = [], []
    for method in table.rows:
        intervals.append(
            [
                percentile_interval(distributions[method, column]) if (method, column) in distributions else None
                for column in table.columns
            ]
        )
        marked.append([False] * len(table.columns))
    significant = []
    for j, column in enumerate(table.columns):
        values = {
            method: table.values[i][j]
            for i, method in enumerate(table.rows)
            if table.values[i][j] is not None and table.is_informative(i, j) and (method, column) in distributions
        }
        names, alone = leaders(
            {method: distributions[method, column] for method in values},
            values,
            higher_is_better=table.higher_is_better,
            level=level,
        )
        for name in names:
            marked[table.rows.index(name)][j] = True
        significant.append(alone)
    table.intervals, table.leaders, table.significant = intervals, marked, significant
