"""Argument types shared by the commands: each rejects bad values with a message argparse prints as is."""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = [
    "VERIFY_FRACTION_HELP",
    "add_alias",
    "add_deprecated_alias",
    "add_image_options",
    "add_progress_options",
    "apply_threads",
    "candidate_count",
    "command_wording",
    "device_name",
    "fraction",
    "integer_at_least",
    "non_negative_float",
    "output_directory",
    "output_file",
    "positive_int",
    "write_output",
]


def integer_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type accepting integers >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}, got {text}")
        return value

    parse.__name__ = f"integer_at_least_{minimum}"
    return parse


#: Positive integers (batch sizes, epochs, k of a search).
positive_int = integer_at_least(1)
#: Candidates per query for RS/SD/SU: the best match and at least one runner-up.
candidate_count = integer_at_least(2)


def non_negative_float(text: str) -> float:
    """An argparse type accepting finite numbers >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0 <= value < math.inf:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def fraction(text: str) -> float:
    """An argparse type accepting numbers in [0, 1] (e.g. ``--verify-fraction``)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must lie in [0, 1], got {text}")
    return value


#: Help of ``--verify-fraction`` (evaluate, run, reproduce).
VERIFY_FRACTION_HELP = (
    "cascades SCORE+GV (e.g. SU+GV-SIFT): the fraction of the queries, the most uncertain by SCORE, that are "
    "geometrically verified, in [0, 1] (default 0.3; per method: SU+GV-SIFT:verify_fraction=0.5)"
)


_DEVICE = re.compile(r"(cpu|mps|cuda(:\d+)?)")


def device_name(text: str) -> str:
    """An argparse type accepting the device names the toolkit supports: cpu, cuda, cuda:N, mps.

    Whether the device is present is checked where it is used (torch or Faiss says which ones are).
    """
    if not _DEVICE.fullmatch(text):
        raise argparse.ArgumentTypeError(f"expected cpu, cuda, cuda:N or mps, got {text!r}")
    return text


def _check_writable(path: Path) -> None:
    """Raise ArgumentTypeError unless ``path`` could be created: its nearest existing ancestor must be a folder
    in which a file can be created (probed with a temporary file, removed at once)."""
    ancestor = path.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise argparse.ArgumentTypeError(f"{ancestor} is a file, so {path} cannot be created under it")
    try:
        with tempfile.NamedTemporaryFile(dir=ancestor, prefix=".vpr-uncertainty-probe-"):
            pass
    except OSError as error:
        raise argparse.ArgumentTypeError(f"cannot write in {ancestor}: {error.strerror or error}") from None


def output_file(text: str) -> Path:
    """An argparse type for a file the command writes: not a folder, and creatable or writable."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a folder; expected a file name")
    if path.exists():
        if not os.access(path, os.W_OK):
            raise argparse.ArgumentTypeError(f"{path} exists and is not writable")
    else:
        _check_writable(path)
    return path


def output_directory(text: str) -> Path:
    """An argparse type for a folder the command writes into: not an existing file, and creatable."""
    path = Path(text)
    if path.exists():
        if not path.is_dir():
            raise argparse.ArgumentTypeError(f"{path} exists and is not a folder; expected an output folder")
        if not os.access(path, os.W_OK | os.X_OK):
            raise argparse.ArgumentTypeError(f"{path} is not writable")
    else:
        _check_writable(path)
    return path


def write_output(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` (creating its folder); an OSError always names the file (disk full included)."""
    from vpr_uncertainty.cache import write_text

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, text)  # atomically: never a truncated file
    except OSError as error:
        if error.filename is None and error.errno is not None:
            raise OSError(error.errno, error.strerror, str(path)) from error
        raise


@contextmanager
def command_wording(**flags: str) -> Iterator[None]:
    """Re-word library errors for the command line: ``(argument NAME)`` becomes the command's flag.

    The library names its arguments (``"give the ground truth (argument ground_truth)"``); a command says
    ``command_wording(ground_truth="--gt GT")`` around its calls, and the user reads the flag to type.
    """
    try:
        yield
    except (ValueError, TypeError, FileNotFoundError, FloatingPointError) as error:
        text = str(error.args[0]) if len(error.args) == 1 else ""
        reworded = text
        for argument, flag in flags.items():
            reworded = reworded.replace(f"argument {argument}", flag)
        if reworded == text:
            raise
        raise type(error)(reworded) from error


def add_deprecated_alias(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    old: str,
    *,
    new: str,
    dest: str | None = None,
    **kwargs: Any,
) -> None:
    """Accept the former flag ``old`` as a hidden alias of ``new``, with a one-line note that names ``new``.

    ``dest`` is that of ``new`` (default: derived from ``new``); ``kwargs`` are those of ``new`` that parse the
    value (``type``, ``metavar``). The alias is left out of ``--help`` and does not change ``new``'s default.
    """
    dest = dest or new.lstrip("-").replace("-", "_")

    class _Alias(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None) -> None:
            print(f"note: {option_string} is deprecated; use {new}", file=sys.stderr)
            setattr(namespace, self.dest, values)

    parser.add_argument(old, dest=dest, action=_Alias, help=argparse.SUPPRESS, default=argparse.SUPPRESS, **kwargs)


def add_alias(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    alias: str,
    *,
    new: str,
    dest: str | None = None,
    **kwargs: Any,
) -> None:
    """Accept ``alias`` (another tool's name for the flag ``new``, e.g. VPR-methods-evaluation's
    ``--positive_dist_threshold``) as a hidden synonym: no note, left out of ``--help``, ``new``'s default kept.

    ``dest`` is that of ``new`` (default: derived from ``new``); ``kwargs`` are those of ``new`` that parse the
    value (``type``, ``metavar``).
    """
    dest = dest or new.lstrip("-").replace("-", "_")
    parser.add_argument(alias, dest=dest, help=argparse.SUPPRESS, default=argparse.SUPPRESS, **kwargs)


def add_progress_options(parser: argparse.ArgumentParser, *, top_level: bool = False) -> None:
    """``--progress`` / ``--no-progress``: show or hide the progress bars (on stderr; default: shown only when
    stderr is a terminal). On a command, they override the same flags given before the command."""
    group = parser.add_mutually_exclusive_group()
    default = None if top_level else argparse.SUPPRESS
    group.add_argument(
        "--progress",
        dest="progress",
        action="store_const",
        const=True,
        default=default,
        help="show progress bars on stderr even when it is not a terminal (a log file, a pipe)",
    )
    group.add_argument(
        "--no-progress",
        dest="progress",
        action="store_const",
        const=False,
        default=default,
        help="no progress bars (default: shown only when stderr is a terminal)",
    )


def add_image_options(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """Preprocessing and threads of the descriptor extraction, shared by ``extract`` and ``run``:
    ``--image-size``, ``--max-side``, ``--threads`` (``--workers``, the image decoding threads with the local
    executor, is an executor option: :func:`vpr_uncertainty.commands._executor.add_executor_options`)."""
    from vpr_uncertainty.descriptors.images import DEFAULT_MAX_SIDE

    parser.add_argument(
        "--image-size",
        type=positive_int,
        help="resize so that the shorter image side has this many pixels (default: the model's own setting)",
    )
    add_alias(parser, "--image_size", new="--image-size", type=positive_int)
    parser.add_argument(
        "--max-side",
        type=integer_at_least(32),
        help=f"cap on the longer side of the model input, in pixels (default {DEFAULT_MAX_SIDE}); larger images "
        "are shrunk keeping their aspect ratio, so memory per batch is bounded: about 235 bytes per pixel for "
        f"the default model on CPU, i.e. about 2 GB for 16 images of {DEFAULT_MAX_SIDE} x {DEFAULT_MAX_SIDE}",
    )
    parser.add_argument(
        "--threads",
        type=positive_int,
        help="CPU threads of the model (torch.set_num_threads; default torch's choice). On a CPU shared with "
        "other jobs, 1 can be several times faster",
    )


def apply_threads(threads: int | None) -> None:
    """``torch.set_num_threads(threads)`` when ``--threads`` was given."""
    if threads is not None:
        import torch

        torch.set_num_threads(threads)
