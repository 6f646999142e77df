"""Reproduce the study: VPR methods × datasets × uncertainty methods, then tables, figures and one HTML report.

A grid is described by a TOML file (read with :mod:`tomllib`) or a YAML file (needs ``pyyaml``)::

    out = "runs/reproduce"              # relative paths are relative to the config file
    methods = ["RS", "SD", "SU", "PA", "L2", "BM"]
    k = 10
    alpha = 0.5
    alphas = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]   # α ablation (SU); [] to skip
    ks = [2, 3, 5, 10, 15, 20, 30, 50]                                  # k ablation (RS, SD); [] to skip
    calibration = {fraction = 0.3, repeats = 20, seed = 0}   # optional: held-out Table 1 (study.heldout)

    [[inputs]]                          # a VPR-Bench precomputed_matches folder: one cell per method subfolder
    precomputed_matches = "precomputed_matches/corridor"
    ground_truth = "corridor/ground_truth_new.npy"
    dataset = "corridor"                # name of the dataset column (default: the folder name)
    images = "corridor"                 # optional: VPR-Bench image folder (query/, ref/) for the qualitative figure
    vpr_methods = ["NetVLAD", "HOG"]    # optional subset of the subfolders

    [[inputs]]                          # one similarity matrix (.npy) or retrieval file (.npz)
    vpr_method = "mine"
    dataset = "corridor"
    scores = "mine.npz"
    ground_truth = "corridor/ground_truth_new.npy"   # optional for a retrieval file that holds its positives

    [[inputs]]                          # from images: pipeline.run (descriptors, retrieval, all cached)
    dataset = "corridor"                # dataset path or name (see vpr_uncertainty.data.load_dataset)
    model = "efficientnet-lite0-gem"
    root = "~/vpr-data"                 # optional options of RunConfig: root, device, batch_size, index, split

``methods`` may carry method options (``"SUE:clip=one-sided"``, see
:func:`vpr_uncertainty.methods.parse_method_spec`); ``qualitative = ["NetVLAD"]`` picks the VPR methods whose cells
get a qualitative figure (default: the first cell with images); ``report = ["table1", "pr_curves"]`` picks the
report figures to write (default: every registered one, see :mod:`vpr_uncertainty.reports.figures`; options as in
a method spec, ``"qualitative:rank_by=RS"``). One grid cell = one (VPR method, dataset). Each
cell is cached under ``out/cells``: a rerun skips the cells whose inputs and settings did not change
(``force=True`` recomputes them). The whole configuration is validated (every file exists, every method is known,
every need of every method is met by every cell's inputs) before any work
starts, by :mod:`vpr_uncertainty.study.config`.

Modules: :mod:`~vpr_uncertainty.study.config` (the schema, checked once, all problems together) and
:mod:`~vpr_uncertainty.study.needs` (what each method needs from each cell); :mod:`~vpr_uncertainty.study.runner`
(the cell runner and its cache); :mod:`~vpr_uncertainty.study.cell` (the typed result of a cell, with
``to_dict``/``from_dict``); :mod:`~vpr_uncertainty.study.ablations`; :mod:`~vpr_uncertainty.study.report` (results
files, the selected report figures and the HTML report; :mod:`~vpr_uncertainty.study.report_config` checks the
``report`` and ``qualitative`` keys). ``vpr-uncertainty reproduce`` composes them.
"""

from vpr_uncertainty.study.cell import Cell
from vpr_uncertainty.study.config import DEFAULT_ALPHAS, DEFAULT_KS, VPRBENCH_FILE, GridConfig, InputEntry, load_config
from vpr_uncertainty.study.report import write_reports, write_results
from vpr_uncertainty.study.runner import run_cell, run_grid

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
