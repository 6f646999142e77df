"""``vpr-uncertainty reproduce``: the study's grid, tables, figures and HTML report from one config file."""

from __future__ import annotations

import argparse
from pathlib import Path

from vpr_uncertainty.commands._arguments import VERIFY_FRACTION_HELP, fraction, output_directory
from vpr_uncertainty.commands._bootstrap import add_bootstrap_options
from vpr_uncertainty.commands._executor import add_executor_options, executor_from_args, executor_options

__all__ = ["add_parser"]

_EXAMPLE = """example config (TOML; relative paths are relative to the config file):
  out = "runs/reproduce"
  methods = ["RS", "SD", "SU", "PA", "L2", "BM"]   # options in the name: "SUE:clip=one-sided" (needs positions)
  k = 10
  # calibration = {fraction = 0.3, repeats = 20, seed = 0}   # held-out Table 1 (add "CAL" to methods)

  [[inputs]]
  precomputed_matches = "data/vprbench/precomputed_matches/corridor"
  ground_truth = "data/vprbench/corridor/ground_truth_new.npy"
  images = "data/vprbench/corridor"

  [[inputs]]
  dataset = "data/vprbench/corridor"
  model = "efficientnet-lite0-gem"
"""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``reproduce`` command."""
    parser = subparsers.add_parser(
        "reproduce",
        help="run VPR methods x datasets x uncertainty methods and write tables, figures and report.html",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Run every (VPR method, dataset) cell of CONFIG with every uncertainty method, from precomputed\n"
            "similarity matrices, retrieval files or images, then write results.json, results.csv, Table 1\n"
            "(md/csv/tex), the ΔAUC-PR heatmaps, the α and k ablations, the PR curves, a qualitative figure and\n"
            "report.html into the output folder. The whole config is checked before any work; cells already\n"
            "computed with the same inputs and settings are read from out/cells (use --force to recompute)."
        ),
        epilog=_EXAMPLE,
    )
    parser.add_argument("config", type=Path, metavar="CONFIG", help="grid configuration (.toml, or .yaml with pyyaml)")
    parser.add_argument("--out", type=output_directory, help="output folder (default: `out` of the config)")
    parser.add_argument("--force", action="store_true", help="recompute every cell, ignoring the cache")
    parser.add_argument(
        "--verify",
        action="store_true",
        help="before reusing a cached cell, hash every byte of its input files over 64 MiB (a plain rerun keys "
        "them by size, modification and change times and their first and last MiB) and recompute the cell when "
        "one differs",
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="only validate the configuration: files, methods and their options, and what every method needs "
        "from every cell (positions, images, a head), all problems listed at once",
    )
    parser.add_argument("--no-report", action="store_true", help="write results.json/csv only (no tables, figures)")
    add_bootstrap_options(parser, defaults_from_config=True)
    parser.add_argument(
        "--verify-fraction",
        type=fraction,
        metavar="F",
        help=VERIFY_FRACTION_HELP.replace("(default 0.3;", "(default: verify_fraction of CONFIG, else 0.3;"),
    )
    add_executor_options(parser, ray_workers="the grid cells run as Ray tasks at once (default: the cluster's CPUs)")
    parser.set_defaults(handler=_run_reproduce)


def _run_reproduce(args: argparse.Namespace) -> int:
    from vpr_uncertainty.study import load_config, run_grid, write_reports, write_results

    executor_options(args)  # bad executor options fail before any work
    config = load_config(args.config, out=args.out, bootstrap=args.bootstrap, seed=args.seed, reference=args.reference)
    if args.verify_fraction is not None:
        if not any("+" in name.split(":")[0] for name in config.methods):
            raise ValueError(f"--verify-fraction: {args.config} selects no cascade SCORE+GV (e.g. SU+GV-SIFT)")
        config.verify_fraction = args.verify_fraction
    cells = {(e.vpr_method, e.dataset) for e in config.inputs}
    print(f"{args.config}: {len(cells)} cells x {len(config.methods)} uncertainty methods -> {config.out}")
    if args.check:
        return 0
    with executor_from_args(args) as executor:
        results = run_grid(config, force=args.force, executor=executor, verify=args.verify)
    cached = sum(cell.cached for cell in results)
    if cached:
        print(f"{cached} of {len(results)} cells read from the cache")
    paths = write_results(results, config)
    if not args.no_report:
        paths.update(write_reports(results, config))
        if "table1_md" in paths:
            print(paths["table1_md"].read_text(), end="")
    for name in ("results_json", "results_csv", "report_html"):
        if name in paths:
            print(f"wrote {paths[name]}")
    return 0
