"""Command line: ``vpr-uncertainty <command> --help`` explains each command.

It only collects the commands of the stage modules (:mod:`vpr_uncertainty.pipeline`), loads the plugins (the
entry-point group ``vpr_uncertainty.plugins``, ``--plugin MODULE`` and ``--plugin FILE.py``), and turns what goes
wrong into one line on stderr and an exit status (see :data:`EXIT_STATUS_HELP`). Its global options (``--plugin``,
``--debug``, ``--progress``) are accepted before or after the command name.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pickle
import signal
import sys
import threading
import traceback
import warnings
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from vpr_uncertainty.pipeline import COMMAND_MODULES, COMMANDS
from vpr_uncertainty.pipeline.options import add_progress_options

__all__ = [
    "EXIT_INPUT",
    "EXIT_INTERRUPTED",
    "EXIT_RUNTIME",
    "build_parser",
    "command_names",
    "exit_status",
    "main",
    "package_version",
]

#: Exit statuses: a usage or input error (what the user can fix in the command line or the files it names), a
#: failure while running (disk full, a library or device failure), an interrupt (Ctrl-C, as the shells do).
EXIT_INPUT, EXIT_RUNTIME, EXIT_INTERRUPTED = 2, 1, 130

#: Environment variable that, set to anything but "" or "0", shows tracebacks like ``--debug``.
DEBUG_VARIABLE = "VPR_UNCERTAINTY_DEBUG"

EXIT_STATUS_HELP = f"""exit status:
  0    success
  1    runtime failure (disk full, I/O error, library or device failure); one line on stderr
  2    usage or input error (bad option, missing or unreadable file, invalid data); one line on stderr
  130  interrupted (Ctrl-C); caches stay consistent and a rerun resumes
  An unexpected error (a bug) prints its traceback. --debug (or {DEBUG_VARIABLE}=1) prints the traceback of
  every error."""

# Errors about what the user gave: options, paths, file contents.
_INPUT_ERRORS: tuple[type[BaseException], ...] = (
    ValueError,  # includes UnicodeError, json/TOML decode errors
    TypeError,
    KeyError,
    ImportError,  # a missing optional dependency: the message names the extra to install
    EOFError,  # truncated input file
    zipfile.BadZipFile,
    pickle.UnpicklingError,
    FileNotFoundError,
    FileExistsError,
    IsADirectoryError,
    NotADirectoryError,
    PermissionError,
)
# Failures of the environment or of a library while running: disk full, I/O, h5py/Faiss/torch RuntimeErrors.
_RUNTIME_ERRORS: tuple[type[BaseException], ...] = (OSError, RuntimeError, MemoryError)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (the usage is one ``--help`` away)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser(plugins: Sequence[str] = (), *, command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command, after loading the plugins (entry points, then ``plugins``: the ``--plugin``
    modules and files); with ``command``, only that command's (importing only its stage module), as :func:`main`
    builds it for the command it runs."""
    from vpr_uncertainty.plugins import load_plugins

    load_plugins(plugins)
    parser = _Parser(
        prog="vpr-uncertainty",
        description="How much to doubt each answer of a visual place recognition system, and how good that "
        "doubt is. Uncertainty is higher for answers to trust less.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EXIT_STATUS_HELP,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    _add_global_options(parser, top_level=True)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    modules = (COMMANDS[command],) if command in COMMANDS else COMMAND_MODULES
    for module in modules:
        importlib.import_module(f"vpr_uncertainty.pipeline.{module}").add_cli(subparsers)
    for command in subparsers.choices.values():  # the global options are accepted after the command name too
        _add_global_options(command, progress="--progress" not in command._option_string_actions)
    return parser


def _add_global_options(parser: argparse.ArgumentParser, *, top_level: bool = False, progress: bool = True) -> None:
    """``--debug``, ``--plugin`` and the progress flags; on a command, they add to those given before it."""
    default = {} if top_level else {"default": argparse.SUPPRESS}
    parser.add_argument(
        "--debug",
        action="store_true",
        help=f"show the full Python traceback of an error (also: environment variable {DEBUG_VARIABLE}=1)",
        **default,
    )
    parser.add_argument(
        "--plugin",
        action="append",
        default=[] if top_level else argparse.SUPPRESS,
        metavar="MODULE|FILE.py",
        help="import MODULE (on the Python path or in this folder) or the file FILE.py before anything else: its "
        "uncertainty methods, models, formats and figures are then available to every command (repeatable; "
        "installed packages register theirs through the entry-point group vpr_uncertainty.plugins)",
    )
    if progress:
        add_progress_options(parser, top_level=top_level)


def command_names() -> list[str]:
    """The commands, in the order ``--help`` lists them."""
    parser = build_parser()
    return [name for action in parser._subparsers._group_actions for name in action.choices]  # type: ignore[union-attr]


def _early_arguments(argv: Sequence[str]) -> argparse.Namespace:
    """The ``plugin`` modules, ``debug`` and ``command`` (None when there is none) of ``argv``, wherever they are, read
    before the parser is built so that only that command's module is imported."""
    early = argparse.ArgumentParser(add_help=False)
    early.add_argument("--plugin", action="append", default=[])
    early.add_argument("--debug", action="store_true")
    known, rest = early.parse_known_args(list(argv))
    known.command = next((word for word in rest if not word.startswith("-")), None)
    return known


def package_version() -> str:
    """The installed version of the package (its source tree's ``__version__`` when it is not installed)."""
    from importlib import metadata

    try:
        return metadata.version("vpr-uncertainty")
    except metadata.PackageNotFoundError:
        from vpr_uncertainty import __version__

        return __version__


def _task_cause(error: BaseException) -> BaseException:
    """The error a Ray task raised, for the ``RayTaskError`` that carries it (whose text is the remote traceback)."""
    cause = getattr(error, "cause", None)
    if isinstance(cause, BaseException) and any(kind.__name__ == "RayTaskError" for kind in type(error).__mro__):
        return _task_cause(cause)
    return error


def exit_status(error: BaseException) -> int | None:
    """Exit status for ``error``: 2 input, 1 runtime, 130 interrupt; None for an unexpected error (a bug)."""
    error = _task_cause(error)
    if isinstance(error, KeyboardInterrupt):
        return EXIT_INTERRUPTED
    if isinstance(error, _INPUT_ERRORS):
        return EXIT_INPUT
    if isinstance(error, _RUNTIME_ERRORS):
        return EXIT_RUNTIME
    return None


def _message(error: BaseException) -> str:
    """The one line that describes ``error`` (for an error raised in a Ray task, the task's own error)."""
    error = _task_cause(error)
    if isinstance(error, KeyError) and error.args:
        return str(error.args[0])
    if isinstance(error, OSError) and error.strerror and error.filename is not None:
        target = f"{error.filename} -> {error.filename2}" if error.filename2 is not None else str(error.filename)
        text = f"{error.strerror}: {target}"
    else:
        text = str(error) or type(error).__name__
    if isinstance(error, _RUNTIME_ERRORS) and not isinstance(error, _INPUT_ERRORS):
        text = " ".join(text.split())  # third-party messages (h5py, Faiss) span lines
    return text


def _refuse_outputs_that_are_inputs(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse a file the command writes (an option of type :func:`output_file`) that is a file it reads (any other
    path option, and the ``--plugin`` files) or another file it writes."""
    from vpr_uncertainty._files import refuse_shared_files
    from vpr_uncertainty.pipeline.options import output_file, output_file_or_stdout

    inputs: dict[str, Path] = {
        f"--plugin {i + 1}": Path(p) for i, p in enumerate(getattr(args, "plugin", [])) if p.endswith(".py")
    }
    outputs: dict[str, Path] = {}
    command = parser._subparsers._group_actions[0].choices.get(args.command)  # type: ignore[union-attr]
    for action in command._actions if command is not None else ():
        value = getattr(args, action.dest, None)
        paths = [v for v in (value if isinstance(value, list | tuple) else [value]) if isinstance(v, Path)]
        role = action.option_strings[0] if action.option_strings else (action.metavar or action.dest.upper())
        for index, path in enumerate(paths):
            name = f"{role} {index + 1}" if len(paths) > 1 else role
            (outputs if action.type in (output_file, output_file_or_stdout) else inputs)[name] = path
    refuse_shared_files(inputs, outputs)


def _debug_requested(args: argparse.Namespace | None) -> bool:
    return bool(getattr(args, "debug", False)) or os.environ.get(DEBUG_VARIABLE, "") not in {"", "0"}


def _terminated(signum: int, frame: object) -> None:
    """SIGTERM: unwind like Ctrl-C, so that every context closes (a Ray cluster the command started shuts down)."""
    raise SystemExit(128 + signum)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``vpr-uncertainty`` command; returns the exit status."""
    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminated) if in_main_thread else None
    args: argparse.Namespace | None = None
    prefix = "vpr-uncertainty"
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        # one line per warning, from the first: a plugin that fails to load is one line too
        warnings.formatwarning = lambda message, *_: f"warning: {message}\n"
        args = _early_arguments(argv)  # until parsed: a plugin that fails to load shows its traceback with --debug
        parser = build_parser(args.plugin, command=args.command)
        args = parser.parse_args(argv)
        prefix = f"vpr-uncertainty {args.command}"
        _refuse_outputs_that_are_inputs(parser, args)
        from vpr_uncertainty.progress import progress_default

        with progress_default(getattr(args, "progress", None)):
            return args.handler(args)
    except BrokenPipeError:  # the reader of stdout went away (`... | head`): stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_RUNTIME
    except KeyboardInterrupt:
        if _debug_requested(args):
            traceback.print_exc()
        print(f"\n{prefix}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as error:
        status = exit_status(error)
        if status is None or _debug_requested(args):
            traceback.print_exc()
        if status is None:
            print(
                f"{prefix}: internal error: {type(error).__name__}: {_message(error)} "
                "(a bug: please report it with the traceback above)",
                file=sys.stderr,
            )
            return EXIT_RUNTIME
        print(f"{prefix}: error: {_message(error)}", file=sys.stderr)
        return status
    finally:
        if in_main_thread:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
