"""Tables and figures of evaluation results, and the report figures of a grid (:data:`REPORT_FIGURES`).

A new report figure is one :func:`register_report_figure` call (see :mod:`vpr_uncertainty.reports.figures`).
:class:`RejectionCurveDisplay` and :class:`ReliabilityDisplay` draw on a matplotlib axis of your own, in
scikit-learn's Display style (:mod:`vpr_uncertainty.reports.display`).
"""

from vpr_uncertainty.reports.ablations import plot_alpha_ablation, plot_k_ablation
from vpr_uncertainty.reports.display import RejectionCurveDisplay, ReliabilityDisplay
from vpr_uncertainty.reports.figures import REPORT_FIGURES, ReportFigure, register_report_figure
from vpr_uncertainty.reports.heatmaps import plot_delta_heatmaps
from vpr_uncertainty.reports.html import write_report
from vpr_uncertainty.reports.plots import plot_rejection_curves
from vpr_uncertainty.reports.qualitative import plot_qualitative
from vpr_uncertainty.reports.table1 import build_table1, table1_csv, table1_latex, table1_markdown
from vpr_uncertainty.reports.tables import format_table

__all__ = [
    "REPORT_FIGURES",
    "RejectionCurveDisplay",
    "ReliabilityDisplay",
    "ReportFigure",
    "build_table1",
    "format_table",
    "plot_alpha_ablation",
    "plot_delta_heatmaps",
    "plot_k_ablation",
    "plot_qualitative",
    "plot_rejection_curves",
    "register_report_figure",
    "table1_csv",
    "table1_latex",
    "table1_markdown",
    "write_report",
]
