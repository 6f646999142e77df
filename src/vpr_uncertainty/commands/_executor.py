"""The executor options shared by ``run``, ``extract``, ``reproduce`` and ``evaluate``: ``--executor``, ``--address``,
``--workers`` and ``--gpus-per-worker`` (see :mod:`vpr_uncertainty.executors`).

``--workers N`` is the one name for "how many parallel workers". With ``--executor ray`` it is the number of Ray
workers (tasks or actors in flight; default: the cluster's CPUs). With ``--executor local`` it keeps the meaning
the command gives it there (``run``/``extract``: image decoding threads), or is refused where the command has
none (``reproduce``, ``evaluate``). ``--ray-workers`` is its former, deprecated name.
"""

from __future__ import annotations

import argparse
from typing import Any

from vpr_uncertainty.commands._arguments import (
    add_alias,
    add_deprecated_alias,
    integer_at_least,
    non_negative_float,
    positive_int,
)
from vpr_uncertainty.executors import CONNECT_TIMEOUT

__all__ = [
    "DECODING_THREADS",
    "add_executor_options",
    "executor_from_args",
    "executor_options",
    "local_workers",
]

#: What ``--workers`` means with ``--executor local`` in ``run`` and ``extract``.
DECODING_THREADS = "image decoding threads (default min(4, CPUs); 0 = none)"
_RAY_WORKERS = "the Ray tasks or actors in flight (default: the cluster's CPUs)"


def _seconds(text: str) -> float:
    value = non_negative_float(text)
    if value == 0:
        raise argparse.ArgumentTypeError(f"must be a number of seconds > 0, got {text}")
    return value


def add_executor_options(
    parser: argparse.ArgumentParser, *, local_workers: str | None = None, ray_workers: str = _RAY_WORKERS
) -> None:
    """Add the executor option group to ``parser``.

    Parameters
    ----------
    parser : ArgumentParser
    local_workers : str, optional
        What ``--workers`` means with ``--executor local`` (its help, e.g. :data:`DECODING_THREADS`); None: it
        means nothing there and is refused (the command's work items then run one after another).
    ray_workers : str
        What ``--workers`` means with ``--executor ray`` (its help).
    """
    group = parser.add_argument_group("executor (where the work runs, and how many workers run it)")
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
    local = local_workers or "no meaning, so it is refused (the work runs one item after another)"
    group.add_argument(
        "--workers",
        type=integer_at_least(0),
        metavar="N",
        help=f"how many parallel workers. With --executor ray: {ray_workers}. With --executor local: {local}. "
        "(--ray-workers, its former name, is still accepted)",
    )
    if local_workers:
        add_alias(group, "--num_workers", new="--workers", type=integer_at_least(0))
    add_deprecated_alias(group, "--ray-workers", new="--workers", dest="ray_workers", type=positive_int, metavar="N")
    group.add_argument(
        "--connect-timeout",
        type=_seconds,
        default=CONNECT_TIMEOUT,
        metavar="SECONDS",
        help=f"how long to wait for the Ray cluster at --address to answer (default {CONNECT_TIMEOUT:g} s)",
    )
    group.add_argument(
        "--gpus-per-worker",
        type=non_negative_float,
        default=0.0,
        metavar="G",
        help="GPUs Ray assigns to each worker (default 0; fractions share a GPU)",
    )
    parser.set_defaults(workers_mean_locally=local_workers is not None)


def executor_options(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments of :func:`~vpr_uncertainty.executors.get_executor` that the options ask for.

    Raises ValueError for a Ray-only option given with ``--executor local``, for ``--workers`` and the former
    ``--ray-workers`` given different values, and for ``--workers 0`` with ``--executor ray``.
    """
    workers = args.workers
    former = getattr(args, "ray_workers", None)  # absent unless given (a hidden alias without a default)
    if former is not None and workers is not None and former != workers:
        raise ValueError(
            f"--workers {workers} and --ray-workers {former} disagree: give --workers only "
            "(--ray-workers is its former name)"
        )
    if args.executor == "local":
        given = [flag for flag, value in (("--address", args.address), ("--ray-workers", former)) if value is not None]
        if workers is not None and not getattr(args, "workers_mean_locally", False):
            given.append("--workers")
        if args.gpus_per_worker:
            given.append("--gpus-per-worker")
        if given:
            raise ValueError(f"{', '.join(given)}: only with --executor ray")
        return {"name": "local"}
    workers = former if workers is None else workers
    if workers == 0:
        raise ValueError("--workers 0: --executor ray needs at least 1 worker (omit it for the cluster's CPUs)")
    return {
        "name": "ray",
        "address": args.address,
        "workers": workers,
        "gpus_per_worker": args.gpus_per_worker,
        "connect_timeout": args.connect_timeout,
    }


def local_workers(args: argparse.Namespace) -> int | None:
    """``--workers`` in its local meaning (e.g. image decoding threads): its value with ``--executor local``, None
    with Ray (where it counts the Ray workers, which decode their own images)."""
    return args.workers if args.executor == "local" else None


def executor_from_args(args: argparse.Namespace) -> Any:
    """The executor the options ask for (a context manager), after :func:`executor_options`' checks."""
    from vpr_uncertainty.executors import get_executor

    options = executor_options(args)
    return get_executor(options.pop("name"), **options)
