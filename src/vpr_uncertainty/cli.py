"""Command line: ``vpr-uncertainty <command> --help`` explains each command.

Thin by design: each command lives in :mod:`vpr_uncertainty.commands` and calls the library functions.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from collections.abc import Sequence

__all__ = ["COMMANDS", "build_parser", "main"]

#: Command modules in :mod:`vpr_uncertainty.commands`, in the order ``--help`` lists them.
COMMANDS: tuple[str, ...] = ("demo", "run", "evaluate", "reproduce", "datasets", "extract", "retrieve", "train-btl")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vpr-uncertainty",
        description="How much to doubt each answer of a visual place recognition system, and how good that "
        "doubt is. Uncertainty is higher for answers to trust less.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"vpr_uncertainty.commands.{name.replace('-', '_')}").add_parser(subparsers)
    return parser


def _short_warning(message, category, filename, lineno, line=None) -> str:
    return f"warning: {message}\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``vpr-uncertainty`` command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.formatwarning = _short_warning
    try:
        return args.handler(args)
    except (ValueError, TypeError, FileNotFoundError, KeyError, ImportError) as error:
        message = error.args[0] if isinstance(error, KeyError) and error.args else error
        print(f"vpr-uncertainty {args.command}: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
