"""The former name of :mod:`vpr_uncertainty.study` (the reproduction grid), kept so old imports work."""

from vpr_uncertainty.study import (
    DEFAULT_ALPHAS,
    DEFAULT_KS,
    VPRBENCH_FILE,
    Cell,
    GridConfig,
    InputEntry,
    load_config,
    run_cell,
    run_grid,
    write_reports,
    write_results,
)

__all__ = [
    "DEFAULT_ALPHAS",
    "DEFAULT_KS",
    "VPRBENCH_FILE",
    "Cell",
    "GridConfig",
    "InputEntry",
    "load_config",
    "run_cell",
    "run_grid",
    "write_reports",
    "write_results",
]
