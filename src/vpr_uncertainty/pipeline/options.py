"""Options declared once: a stage's configuration is a frozen dataclass whose fields carry their command-line help;
:func:`add_options` derives the flags from it and :func:`conf_from_args` reads them back.

Also the argument types that reject bad values with a message argparse prints as is, and the option groups that
several commands share (progress, executor, bootstrap).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import re
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from vpr_uncertainty.executors import CONNECT_TIMEOUT, executor_names

# --- argument types ------------------------------------------------------------------------------------------


def _number_type(
    convert: Callable[[str], Any], expected: str, accept: Callable[[Any], bool], rule: str, name: str
) -> Callable[[str], Any]:
    """An argparse type: ``convert(text)`` ("expected EXPECTED" when it fails) that ``accept`` must hold ("RULE")."""

    def parse(text: str) -> Any:
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not accept(value):
            raise argparse.ArgumentTypeError(f"{rule}, got {text}")
        return value

    parse.__name__ = name
    return parse


def integer_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type accepting integers >= ``minimum``."""
    return _number_type(
        lambda text: int(text if text.isascii() else "?"),  # int() also reads other scripts' digits (٣)
        f"an integer >= {minimum}",
        lambda value: value >= minimum,
        f"must be an integer >= {minimum}",
        f"integer_at_least_{minimum}",
    )


#: Positive integers (batch sizes, epochs, k of a search).
positive_int = integer_at_least(1)
#: Candidates per query for RS/SD/SU: the best match and at least one runner-up.
candidate_count = integer_at_least(2)
#: Finite numbers >= 0.
non_negative_float = _number_type(
    float, "a number", lambda v: 0 <= v < math.inf, "must be a finite number >= 0", "non_negative_float"
)
#: Numbers in [0, 1] (``--alpha``, ``--verify-fraction``).
fraction = _number_type(float, "a number in [0, 1]", lambda v: 0.0 <= v <= 1.0, "must lie in [0, 1]", "fraction")
#: Numbers strictly between 0 and 1 (a probability, a share of the queries).
open_fraction = _number_type(
    float, "a number in (0, 1)", lambda v: 0.0 < v < 1.0, "must lie strictly between 0 and 1", "open_fraction"
)


def checked_number(check: Callable[[float], Any]) -> Callable[[str], float]:
    """An argparse type for a number that the library's own check accepts (the check is written once, there)."""

    def parse(text: str) -> float:
        try:
            return check(float(text))
        except (TypeError, ValueError) as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    parse.__name__ = getattr(check, "__name__", "number")
    return parse


_DEVICE = re.compile(r"(cpu|mps|cuda(:\d+)?)")


def device_name(text: str) -> str:
    """An argparse type accepting cpu, cuda, cuda:N and mps (whether the device is present is checked where used)."""
    if not _DEVICE.fullmatch(text):
        raise argparse.ArgumentTypeError(f"expected cpu, cuda, cuda:N or mps, got {text!r}")
    return text


def _check_writable(path: Path) -> None:
    """Raise ArgumentTypeError unless ``path`` could be created (probed with a temporary file in its nearest
    existing ancestor, removed at once)."""
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
    """An argparse type for a file the command writes: not a folder, and creatable or writable (not ``-``: a file
    named so would be written, where the user meant standard output)."""
    path = Path(text)
    if text == "-":
        raise argparse.ArgumentTypeError("'-' (standard output) is not supported here: name a file")
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a folder; expected a file name")
    if path.exists():
        if not os.access(path, os.W_OK):
            raise argparse.ArgumentTypeError(f"{path} exists and is not writable")
    else:
        _check_writable(path)
    return path


def output_file_or_stdout(text: str) -> Path:
    """:func:`output_file`, or ``-``: standard output."""
    return Path(text) if text == "-" else output_file(text)


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
    """Write ``text`` to ``path`` atomically (creating its folder); an OSError always names the file."""
    from vpr_uncertainty.cache import write_text

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, text)
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


def write_json(path: Path, document: Any) -> None:
    """``--json FILE``: the document as indented JSON in ``FILE``, or on standard output for ``-``."""
    text = json.dumps(document, indent=2) + "\n"
    if str(path) == "-":
        print(text, end="")
        return
    write_output(path, text)
    print(f"wrote {path}")


def add_json_option(parser: argparse.ArgumentParser, what: str) -> None:
    """``--json FILE`` (:func:`output_file_or_stdout`), which :func:`write_json` writes: ``what`` as JSON."""
    help_text = f"write {what} as JSON to FILE ('-': standard output)"
    parser.add_argument("--json", type=output_file_or_stdout, metavar="FILE", help=help_text)


# --- options declared once, on the configuration -------------------------------------------------------------


def option(
    default: Any = None, help: str | Callable[[], str] = "", *, flag: str | None = None, **argparse_options: Any
) -> Any:
    """A configuration field that is also a command-line option.

    ``help`` is the flag's help, or a function that writes it when the parser is built (a default that plugins
    can change); the default is appended unless it is None or False; ``flag`` overrides the
    name derived from the field (``batch_size`` -> ``--batch-size``); ``argparse_options`` (``type``,
    ``choices``, ``metavar``) are passed to ``add_argument``. A field declared with plain ``dataclasses.field``
    (or a default) is not an option.
    """
    metadata = {"help": help, "flag": flag, "argparse": argparse_options}
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def _options(conf_class: type, names: Iterable[str] | None) -> list[dataclasses.Field]:
    chosen = None if names is None else set(names)
    found = [f for f in dataclasses.fields(conf_class) if "help" in f.metadata]
    if chosen is not None:
        unknown = chosen - {f.name for f in found}
        if unknown:
            raise ValueError(f"{conf_class.__name__} has no option {sorted(unknown)}")
        found = [f for f in found if f.name in chosen]
    return found


def add_options(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    conf_class: type,
    *,
    only: Iterable[str] | None = None,
    help: dict[str, str] | None = None,
    defaults: dict[str, Any] | None = None,
) -> None:
    """Add one flag per option of ``conf_class`` (a dataclass built with :func:`option`).

    ``only`` restricts the options; ``help`` and ``defaults`` replace the help and default of some (a command
    whose defaults come from elsewhere, e.g. a config file, says so in its help).
    """
    for field in _options(conf_class, only):
        meta = field.metadata
        text = (help or {}).get(field.name, meta["help"])
        text = text() if callable(text) else text
        flag = meta["flag"] or "--" + field.name.replace("_", "-")
        if defaults and field.name in defaults:
            default = defaults[field.name]
        elif field.default is not dataclasses.MISSING:
            default = field.default
        else:
            default = field.default_factory()  # type: ignore[misc]
        if default is False and not meta["argparse"]:
            parser.add_argument(flag, dest=field.name, action="store_true", help=text)
            continue
        if default is not None and "(default" not in text:
            text += f" (default {default})"
        parser.add_argument(flag, dest=field.name, default=default, help=text, **meta["argparse"])


def conf_from_args(conf_class: type, args: argparse.Namespace, **values: Any) -> Any:
    """``conf_class`` with the options that ``args`` holds (those :func:`add_options` added), then ``values``."""
    given = {f.name: getattr(args, f.name) for f in _options(conf_class, None) if hasattr(args, f.name)}
    return conf_class(**{**given, **values})


# --- option groups shared by several commands ----------------------------------------------------------------

#: Help of ``--verify-fraction`` (evaluate, run, reproduce).
VERIFY_FRACTION_HELP = (
    "cascades SCORE+GV (e.g. SU+GV-SIFT): the fraction of the queries, the most uncertain by SCORE, that are "
    "geometrically verified, in [0, 1] (default 0.3; per method: SU+GV-SIFT:verify_fraction=0.5)"
)


def add_progress_options(parser: argparse.ArgumentParser, *, top_level: bool = False) -> None:
    """``--progress`` / ``--no-progress`` (progress bars on stderr; default: only when stderr is a terminal). On a
    command, they override the same flags given before the command."""
    group = parser.add_mutually_exclusive_group()
    default = None if top_level else argparse.SUPPRESS
    for flag, value, text in (
        ("--progress", True, "show progress bars on stderr even when it is not a terminal (a log file, a pipe)"),
        ("--no-progress", False, "no progress bars (default: shown only when stderr is a terminal)"),
    ):
        group.add_argument(flag, dest="progress", action="store_const", const=value, default=default, help=text)


def apply_threads(threads: int | None) -> None:
    """``torch.set_num_threads(threads)`` when ``--threads`` was given."""
    if threads is not None:
        import torch

        torch.set_num_threads(threads)


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
    """``--executor``, ``--address``, ``--workers``, ``--connect-timeout``, ``--gpus-per-worker``.

    ``--workers`` is the one name for "how many parallel workers": with Ray, the tasks or actors in flight
    (``ray_workers`` says which); locally, ``local_workers`` (e.g. :data:`DECODING_THREADS`), or refused when None.
    """
    group = parser.add_argument_group("executor (where the work runs, and how many workers run it)")
    group.add_argument(
        "--executor",
        choices=executor_names(),
        default="local",
        help="local: in this process (default); ray: as tasks on a Ray cluster (needs the [ray] extra)",
    )
    group.add_argument(
        "--address",
        metavar="ADDRESS",
        help="Ray cluster to connect to (host:port, ray://host:port, 'auto' or 'local'); default: start a local one "
        "(--executor ray only)",
    )
    local = local_workers or "no meaning, so it is refused (the work runs one item after another)"
    group.add_argument(
        "--workers",
        type=integer_at_least(0),
        metavar="N",
        help=f"how many parallel workers. With --executor ray: {ray_workers}. With --executor local: {local}",
    )
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
    group.add_argument(
        "--verbose",
        action="store_true",
        help=f"show Ray's own log lines (start-up notices, warnings) on the terminal; by default they are appended "
        f"to {ray_log_file()}",
    )
    parser.set_defaults(workers_mean_locally=local_workers is not None)


def add_image_options(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    images: str = "dataset folder with query/ and ref/ (VPR-Bench) or queries/ and database/ image subfolders",
) -> None:
    """``--images DIR`` (help: ``images``), ``--query-images DIR`` and ``--database-images DIR``: the image folders."""
    parser.add_argument("--images", type=Path, metavar="DIR", help=images)
    parser.add_argument("--query-images", type=Path, metavar="DIR", help="folder of the query images")
    parser.add_argument("--database-images", type=Path, metavar="DIR", help="folder of the database images")


def add_results_options(parser: argparse.ArgumentParser, what: str, *, gt: str | None = None) -> None:
    """``--gt GT`` (help: ``gt``, else the formats), ``--format`` and ``--scores KIND`` (``args.score_kind``, of
    :data:`~vpr_uncertainty.retrieval.result.SCORE_KINDS`): how a command reads its results ``what``."""
    from vpr_uncertainty.data import input_formats
    from vpr_uncertainty.retrieval.result import SCORE_KINDS

    formats = "VPR-Bench ground_truth_new.npy, boolean (Q x D) .npy, .json list of lists, .txt with one line of "
    formats += f"positive indices per query, or .npz; required unless {what} holds it"
    parser.add_argument("--gt", type=Path, help=gt or f"ground truth: {formats}")
    parser.add_argument("--format", choices=input_formats(), default="auto", help=f"how to read {what} (default: auto)")
    parser.add_argument(
        "--scores",
        dest="score_kind",
        choices=SCORE_KINDS,
        default="similarity",
        help="what a matrix file holds: similarity, higher = more similar (default: cosine similarities, dot "
        "products, HOG scores); cosine-distance (1 - cos) or l2-distance between unit-norm descriptors (squared, as "
        "Faiss IndexFlatL2 returns, or plain: detected, or say l2-distance:squared / l2-distance:plain), converted "
        "exactly to cosine similarities so that every method runs; or distance, any other lower-is-better score, "
        "negated, with the methods that need similarities (RS, SD, SU divide by s_1; L2, PA, SUE need cosine "
        "similarities or distances) left out of the default list with one notice",
    )


def ray_log_file() -> Path:
    """Where the command line sends Ray's log lines without ``--verbose``: ``logs/ray.log`` in the toolkit's cache
    folder (:func:`~vpr_uncertainty.cache.user_cache_dir`, ``$XDG_CACHE_HOME/vpr-uncertainty``)."""
    from vpr_uncertainty.cache import user_cache_dir

    return user_cache_dir() / "logs" / "ray.log"


def executor_options(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments of :func:`~vpr_uncertainty.executors.get_executor` that the options ask for; a
    ValueError for a Ray-only option with ``--executor local`` or ``--workers 0`` with Ray."""
    workers = args.workers
    if args.executor == "local":
        given = [flag for flag, value in (("--address", args.address),) if value is not None]
        if workers is not None and not getattr(args, "workers_mean_locally", False):
            given.append("--workers")
        if args.gpus_per_worker:
            given.append("--gpus-per-worker")
        if given:
            raise ValueError(f"{', '.join(given)}: only with --executor ray")
        return {"name": "local"}
    if workers == 0:
        raise ValueError("--workers 0: --executor ray needs at least 1 worker (omit it for the cluster's CPUs)")
    return {
        "name": args.executor,
        "address": args.address,
        "workers": workers,
        "gpus_per_worker": args.gpus_per_worker,
        "connect_timeout": args.connect_timeout,
        "log_file": None if args.verbose else ray_log_file(),
    }


def local_workers(args: argparse.Namespace) -> int | None:
    """``--workers`` in its local meaning (image decoding threads) with ``--executor local``; None with Ray."""
    return args.workers if args.executor == "local" else None


def executor_from_args(args: argparse.Namespace) -> Any:
    """The executor the options ask for (a context manager), after :func:`executor_options`' checks."""
    from vpr_uncertainty.executors import get_executor  # looked up at the call (tests stand in for it)

    options = executor_options(args)
    return get_executor(options.pop("name"), **options)


# --- figure width (reproduce, run, demo, evaluate --plot, calibrate --plot) ------------------------------------

#: The widths a figure is drawn at (the inches: :data:`vpr_uncertainty.reports.style.FIGURE_WIDTHS`).
FIGURE_WIDTHS = ("page", "column")
#: Help of ``--figure-width``.
FIGURE_WIDTH_HELP = (
    "width of the figures: page (7.16 in, the text width of a two-column paper) or column (3.5 in); fonts 8 pt, "
    "height from the content"
)


def add_figure_width_option(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--figure-width page|column`` (default page), read back as ``args.figure_width``."""
    parser.add_argument(
        "--figure-width", choices=FIGURE_WIDTHS, default="page", help=FIGURE_WIDTH_HELP + " (default page)"
    )
