"""Atomic file writes (re-exported by :mod:`vpr_uncertainty.cache`, part of its protocol).

:func:`atomic_path` / :func:`atomic_write`: write to a temporary file in the target's folder, flush and fsync it,
then :func:`os.replace` it over the target: an interrupted write (crash, SIGKILL, disk full) never leaves a truncated
artefact, only the previous one or none. A failed write (disk full, quota, I/O error) raises an :class:`OSError`
that names the target file (never its temporary file, never no file): ``No space left on device: PATH``.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_path", "atomic_write", "write_json", "write_text"]


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` (same suffix) to write to; renamed over ``path`` when the block succeeds.

    The temporary file is fsynced before the rename; on any exception (KeyboardInterrupt included) it is removed
    and ``path`` is left as it was. A symbolic link is followed (the file it points to is replaced); a path that
    exists and is not a regular file (a device, a pipe) is yielded itself and written in place.

    Examples
    --------
    >>> import tempfile
    >>> target = Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_path(target) as temporary:
    ...     _ = temporary.write_text("whole")
    >>> target.read_text(), [p.name for p in target.parent.iterdir()]
    ('whole', ['a.txt'])
    """
    path = Path(os.path.realpath(path))  # through a symbolic link: replace the file it points to, not the link
    if path.exists() and not path.is_file():  # a device or a pipe (/dev/stdout, /dev/full): written in place
        try:
            yield path
        except OSError as error:
            named = _naming_target(error, path, path)
            if named is error:
                raise
            raise named from error
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=f".tmp{path.suffix}")
    os.close(handle)
    temporary = Path(name)
    os.chmod(temporary, _file_mode(path))  # mkstemp makes 0600; give the file the mode open() would have
    try:
        yield temporary
        with open(temporary, "rb+") as written:
            os.fsync(written.fileno())
        os.replace(temporary, path)
    except OSError as error:
        temporary.unlink(missing_ok=True)
        named = _naming_target(error, temporary, path)
        if named is error:
            raise
        raise named from error
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    _fsync_folder(path.parent)


#: Errors of a write that say nothing of which file: named after the file being written when they carry no name.
_WRITE_ERRNOS = frozenset(
    getattr(errno, name) for name in ("ENOSPC", "EDQUOT", "EFBIG", "EIO", "EROFS") if hasattr(errno, name)
)


def _naming_target(error: OSError, temporary: Path, path: Path) -> OSError:
    """``error`` naming ``path`` (the file being written) instead of none or of its temporary file.

    An error that names another file (an input read within the block) or that has no errno is returned unchanged.
    The new error is of the class :class:`OSError` gives its errno (``ENOSPC``: OSError, ``EACCES``:
    PermissionError), so that ``str`` and the command line's one-line message read ``No space left on device: PATH``.
    """
    if not error.errno or error.filename2 is not None:
        return error
    if error.filename is None:
        if error.errno not in _WRITE_ERRNOS:
            return error
    elif str(error.filename) != str(temporary):
        return error
    return OSError(error.errno, error.strerror or os.strerror(error.errno), str(path))


def _file_mode(path: Path) -> int:
    """The mode of the file at ``path`` when it exists, else what the process's umask gives a new file."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _fsync_folder(folder: Path) -> None:
    try:
        descriptor = os.open(folder, os.O_RDONLY)
    except OSError:  # e.g. Windows: folders cannot be opened
        return
    try:
        os.fsync(descriptor)
    except OSError:
        pass
    finally:
        os.close(descriptor)


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "w", **open_options: Any) -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path`` for writing; it replaces ``path`` when the block succeeds.

    Parameters
    ----------
    path : str or Path
    mode : {"w", "wb"}
    **open_options
        Passed to :func:`open` (``encoding``, ``newline``).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    if mode == "w":
        open_options.setdefault("encoding", "utf-8")
    with atomic_path(path) as temporary, open(temporary, mode, **open_options) as handle:
        yield handle


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically and return the path."""
    with atomic_write(path) as handle:
        handle.write(text)
    return Path(path)


def write_json(path: str | Path, document: Any) -> Path:
    """Write ``document`` as indented JSON (one trailing newline) to ``path`` atomically and return the path."""
    return write_text(path, json.dumps(document, indent=2, default=str) + "\n")
