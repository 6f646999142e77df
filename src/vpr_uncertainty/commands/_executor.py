"""The executor options shared by ``run``, ``extract`` and ``reproduce``: ``--executor``, ``--address``,
``--ray-workers`` and ``--gpus-per-worker`` (see :mod:`vpr_uncertainty.executors`)."""

from __future__ import annotations

import argparse
from typing import Any

from vpr_uncertainty.commands._arguments import non_negative_float, positive_int

__all__ = ["add_executor_options", "executor_from_args"]


def add_executor_options(parser: argparse.ArgumentParser) -> None:
    """Add the executor option group to ``parser``."""
    group = parser.add_argument_group("executor (where the work runs)")
    group.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help="local: in this process (default); ray: as tasks on a Ray cluster (needs the [ray] extra)",
    )
    group.add_argument(
        "--address",
        metavar="ADDRESS",
        help="Ray cluster to connect to (host:port or 'auto'); default: start a local one (--executor ray only)",
    )
    group.add_argument(
        "--ray-workers",
        type=positive_int,
        metavar="N",
        help="Ray tasks or actors at once (default: the cluster's CPUs; --workers is image decoding threads)",
    )
    group.add_argument(
        "--gpus-per-worker",
        type=non_negative_float,
        default=0.0,
        metavar="G",
        help="GPUs Ray assigns to each worker (default 0; fractions share a GPU)",
    )


def executor_from_args(args: argparse.Namespace) -> Any:
    """The executor the options ask for (a context manager); the Ray-only options are refused with ``local``."""
    from vpr_uncertainty.executors import get_executor

    if args.executor == "local":
        given = [flag for flag, value in (("--address", args.address), ("--ray-workers", args.ray_workers)) if value]
        if args.gpus_per_worker:
            given.append("--gpus-per-worker")
        if given:
            raise ValueError(f"{', '.join(given)}: only with --executor ray")
    workers, gpus = args.ray_workers, args.gpus_per_worker
    return get_executor(args.executor, address=args.address, workers=workers, gpus_per_worker=gpus)
