"""The bootstrap options shared by ``evaluate``, ``run`` and ``reproduce``: ``--bootstrap N``, ``--seed S`` and
``--reference NAME`` (see :mod:`vpr_uncertainty.evaluation.bootstrap`)."""

from __future__ import annotations

import argparse

from vpr_uncertainty.commands._arguments import integer_at_least

__all__ = ["add_bootstrap_options"]


def add_bootstrap_options(
    parser: argparse.ArgumentParser, *, seed: bool = True, defaults_from_config: bool = False
) -> None:
    """Add ``--bootstrap``, ``--reference`` and (when ``seed``) ``--seed`` in one argument group.

    With ``defaults_from_config`` the options default to None: the values of a config file apply unless given.
    """
    where = " (default: the config's, else {})" if defaults_from_config else " (default {})"
    group = parser.add_argument_group(
        "confidence intervals and paired tests (paired bootstrap over queries: the same resamples for every method)"
    )
    group.add_argument(
        "--bootstrap",
        type=integer_at_least(0),
        default=None if defaults_from_config else 0,
        metavar="N",
        help="bootstrap resamples for 95 %% intervals of AUC-PR, AP and AURC, a paired test of each method's AUC-PR "
        "against the reference (Holm-corrected) and a best marked only where significant; 0 = none, 1000 is usual"
        + where.format(0),
    )
    if seed:
        group.add_argument(
            "--seed",
            type=integer_at_least(0),
            default=None if defaults_from_config else 0,
            help="seed of the bootstrap resamples" + where.format(0),
        )
    group.add_argument(
        "--reference",
        metavar="NAME",
        default=None,
        help="the method every other one is tested against (default: SU when evaluated, else the first method)",
    )
