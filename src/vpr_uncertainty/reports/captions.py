"""What ``report.html`` says about each figure: a caption naming what it shows and on which data
(:func:`figure_caption`), and the grid's settings as a table (:func:`settings_table`)."""

from __future__ import annotations

from collections.abc import Sequence
from html import escape
from pathlib import Path
from typing import Any

__all__ = ["figure_caption", "settings_table"]


def _names(values: Sequence[str]) -> str:
    values = list(dict.fromkeys(values))
    return values[0] if len(values) == 1 else ", ".join(values[:-1]) + " and " + values[-1]


def _cell_of(path: Path, cells: Sequence[Any]) -> Any:
    from vpr_uncertainty.reports.figures import slug

    for cell in cells:
        if path.stem.endswith(f"{slug(cell.vpr_method)}__{slug(cell.dataset)}"):
            return cell
    return None


def figure_caption(name: str, path: Path, cells: Sequence[Any]) -> str:
    """The caption of the figure file ``path`` written by the report figure ``name``."""
    datasets = _names([cell.dataset for cell in cells]) if cells else "no dataset"
    n_vpr = len({cell.vpr_method for cell in cells})
    cell = _cell_of(path, cells)
    stem = path.stem
    if name == "heatmaps" and stem.startswith("delta_"):
        method = stem[len("delta_") :]
        return (
            f"ΔAUC-PR of {method} against each baseline (one panel per baseline) on {datasets}: rows are the "
            f"{n_vpr} VPR methods, columns the datasets; blue (> 0): {method} predicts correct answers better."
        )
    if name == "ablations" and stem == "ablation_alpha":
        return (
            f"AUC-PR of SU against α (0 = SD, 1 = RS), averaged over the {n_vpr} VPR methods, one line per dataset "
            f"({datasets})."
        )
    if name == "ablations" and stem == "ablation_k":
        return (
            f"AUC-PR of RS (solid) and SD (dashed) against k, the candidates used, averaged over the {n_vpr} VPR "
            f"methods, one colour per dataset ({datasets})."
        )
    if name == "pr_curves" and cell is not None:
        return (
            f"{cell.vpr_method} on {cell.dataset} ({cell.evaluation.n_queries} queries): end-to-end precision "
            "against recall as the most uncertain answers are rejected, one line per uncertainty method (methods "
            "with the same ranking share a line, e.g. “BM = L2”). The area under a line is not the AUC-PR of the "
            "legend (see the note under the plot)."
        )
    if name == "cascade" and stem.startswith("cascade__"):
        return (
            f"AUC-PR of the cascade against the fraction of queries geometrically verified on {datasets}: 0 is the "
            "score method alone, 1 geometric verification on every query; grey: one VPR method, blue: their mean, "
            "red diamond: the cascade as run (its verified fraction and AUC-PR)."
        )
    if name == "qualitative" and cell is not None:
        return (
            f"{cell.vpr_method} on {cell.dataset}: a confident and an uncertain query, each with a correct and a "
            "wrong top-1 answer; each row shows the query and its top-4 answers (green frame: correct, red: wrong) "
            "with their similarities and the query's uncertainties."
        )
    return f"{name}: {stem.replace('__', ' on ').replace('_', ' ')} ({datasets})"


def settings_table(cells: Sequence[Any], config: Any) -> str:
    """The grid's settings and data as an HTML table (the introduction of ``report.html``)."""
    settings = config.settings()
    rows = [
        ("datasets", _names([cell.dataset for cell in cells]) if cells else "none"),
        ("VPR methods", _names([cell.vpr_method for cell in cells]) if cells else "none"),
        ("cells (VPR method × dataset)", str(len(cells))),
        ("queries per cell", _names([str(cell.evaluation.n_queries) for cell in cells]) if cells else "none"),
        ("uncertainty methods", ", ".join(settings["methods"])),
        ("k (candidates of RS, SD, SU)", str(settings["k"])),
        ("α (weight of RS in SU)", f"{settings['alpha']:g}"),
        ("α ablation", ", ".join(f"{a:g}" for a in settings["alphas"]) or "none"),
        ("k ablation", ", ".join(str(k) for k in settings["ks"]) or "none"),
    ]
    if settings.get("verify_fraction") is not None:
        rows.append(("fraction verified by cascades", f"{settings['verify_fraction']:g}"))
    for key, value in settings.items():  # settings added later (bootstrap, calibration, ...) are shown too
        if key not in {"methods", "k", "alpha", "alphas", "ks", "verify_fraction"}:
            rows.append((key, str(value)))
    body = "".join(f"<tr><th>{escape(key)}</th><td>{escape(value)}</td></tr>" for key, value in rows)
    return f'<table class="settings"><caption>Settings of this run</caption><tbody>{body}</tbody></table>'
