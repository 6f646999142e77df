"""The held-out calibration option in the report: Table 1 from held-out means, and the ``reliability`` figure.

With the grid's ``calibration`` option (``calibration`` in ``reproduce --help``) every cell holds ``held_out``: each
method's AUC-PR on the held-out queries of every split, CAL's included. :func:`table1_cells` shows Table 1 those
means instead of the AUC-PR on all queries (CAL has no number on all queries: its gate is fitted per split), and
:func:`table1_note` says so. :func:`write_reliability` draws CAL's reliability diagram of each cell (held-out
predictions of all splits pooled, the count of each bin written beside it) and :func:`reliability_section` lists
ECE and Brier per cell in ``report.html``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from html import escape
from pathlib import Path
from typing import Any

from vpr_uncertainty.calibration.quality import Reliability
from vpr_uncertainty.reports.figures import slug
from vpr_uncertainty.reports.reliability import plot_reliability

__all__ = ["HeldOutCell", "reliability_section", "table1_cells", "table1_note", "write_reliability"]


@dataclass
class HeldOutMethod:
    """One method's held-out numbers in the shape Table 1 reads (``auc_pr``, ``time_per_query_ms``, ...)."""

    name: str
    auc_pr: float | None
    auc_pr_std: float | None
    time_per_query_ms: float | None
    informative: bool = True


@dataclass
class HeldOutEvaluationView:
    """The ``methods`` of a cell's held-out evaluation, by name."""

    methods: dict[str, HeldOutMethod] = field(default_factory=dict)


@dataclass
class HeldOutCell:
    """A cell as Table 1 sees it with the calibration option: its names and its held-out numbers."""

    vpr_method: str
    dataset: str
    evaluation: HeldOutEvaluationView


def _held_out_cell(cell: Any) -> HeldOutCell:
    methods = {}
    for name, numbers in cell.held_out["methods"].items():
        full = cell.evaluation.methods.get(name)
        methods[name] = HeldOutMethod(
            name=name,
            auc_pr=numbers.get("auc_pr"),
            auc_pr_std=numbers.get("auc_pr_std"),
            time_per_query_ms=numbers.get("time_per_query_ms"),
            informative=True if full is None else full.informative,
        )
    return HeldOutCell(cell.vpr_method, cell.dataset, HeldOutEvaluationView(methods))


def table1_cells(cells: Sequence[Any]) -> list[Any]:
    """The cells Table 1 is built from: ``cells`` themselves, or their held-out views when they hold one.

    Parameters
    ----------
    cells : sequence of Cell

    Returns
    -------
    list
        ``cells`` unchanged when none has a held-out evaluation; else a :class:`HeldOutCell` per cell (every
        cell of a grid with the option has one).
    """
    if not any(cell.held_out is not None for cell in cells):
        return list(cells)
    missing = [f"{cell.vpr_method} / {cell.dataset}" for cell in cells if cell.held_out is None]
    if missing:
        raise ValueError(f"cells without a held-out evaluation among cells with one: {', '.join(missing)}")
    return [_held_out_cell(cell) for cell in cells]


def table1_note(cells: Sequence[Any]) -> str | None:
    """One sentence saying that Table 1 holds held-out means, with the option's values; None without it."""
    found = next((cell.held_out for cell in cells if cell.held_out is not None), None)
    if found is None:
        return None
    option = found["calibration"]
    return (
        f"AUC-PR on held-out queries: mean over {option['repeats']} random splits (seed {option['seed']}), each "
        f"fitting CAL on {option['fraction']:.0%} of the queries; every method is measured on the same held-out "
        "queries (standard deviations in results.json)."
    )


def _quality(cell: Any) -> dict[str, Any] | None:
    return (cell.held_out or {}).get("calibration_quality", {}).get("CAL")


def write_reliability(cells: Sequence[Any], config: Any, out_dir: Path) -> list[Path]:
    """``figures/reliability/<vpr method>__<dataset>.png``: CAL's held-out reliability diagram of each cell."""
    paths = []
    for cell in cells:
        quality = _quality(cell)
        if quality is None:
            continue
        title = f"{cell.vpr_method} on {cell.dataset}: ECE {quality['ece']:.3f}, Brier {quality['brier']:.3f}"
        path = out_dir / "figures" / "reliability" / f"{slug(cell.vpr_method)}__{slug(cell.dataset)}.png"
        paths.append(plot_reliability(Reliability(**quality["reliability"]), path, title=title))
    return paths


def _mean_std(mean: float | None, std: float | None) -> str:
    if mean is None:
        return "–"
    return f"{mean:.3f}" if std is None else f"{mean:.3f} ± {std:.3f}"


def reliability_section(cells: Sequence[Any], config: Any, written: list[Path]) -> str:
    """An HTML table: per cell, CAL's held-out AUC-PR, ECE and Brier (mean ± std over the splits) and the split."""
    head = "".join(
        f"<th>{name}</th>"
        for name in ("VPR method", "dataset", "AUC-PR of CAL", "ECE", "Brier", "calibration / held-out queries")
    )
    rows = []
    for cell in cells:
        quality = _quality(cell)
        if quality is None:
            continue
        cal = cell.held_out["methods"].get("CAL", {})
        split = cell.held_out["calibration"]
        values = [
            _mean_std(cal.get("auc_pr"), cal.get("auc_pr_std")),
            _mean_std(quality["ece"], quality.get("ece_std")),
            _mean_std(quality["brier"], quality.get("brier_std")),
            f"{split.get('n_calibration', '–')} / {split.get('n_held_out', '–')}",
        ]
        rows.append(
            f"<tr><th>{escape(cell.vpr_method)}</th><td>{escape(cell.dataset)}</td>"
            + "".join(f"<td>{value}</td>" for value in values)
            + "</tr>"
        )
    note = (
        '<p class="note">Mean ± standard deviation over the random splits; each diagram pools the held-out '
        "predictions of all splits, with the number of queries in each bin.</p>"
    )
    return f'<table class="reliability"><thead><tr>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table>' + note
