"""Tables and figures of evaluation results."""

from vpr_uncertainty.reports.plots import plot_rejection_curves
from vpr_uncertainty.reports.tables import format_table

__all__ = ["format_table", "plot_rejection_curves"]
