"""Tables, figures and ``report.html`` of evaluation results; report figures are plugins (:data:`REPORT_FIGURES`)."""

from vpr_uncertainty.reports.display import (
    RecallAtNDisplay,
    RejectionCurveDisplay,
    ReliabilityDisplay,
    plot_rejection_curves,
    plot_reliability,
)
from vpr_uncertainty.reports.figures import REPORT_FIGURES, ReportFigure, register_report_figure
from vpr_uncertainty.reports.html import write_report
from vpr_uncertainty.reports.plots import plot_alpha_ablation, plot_delta_heatmaps, plot_k_ablation, plot_qualitative
from vpr_uncertainty.reports.style import FigureSpec
from vpr_uncertainty.reports.tables import build_table1, format_table, table1_csv, table1_latex, table1_markdown

__all__ = [
    "REPORT_FIGURES",
    "FigureSpec",
    "RecallAtNDisplay",
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
    "plot_reliability",
    "register_report_figure",
    "table1_csv",
    "table1_latex",
    "table1_markdown",
    "write_report",
]
