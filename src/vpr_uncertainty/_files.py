"""Files a user names are read only when they are regular files: a FIFO, device or socket could block a read for
ever (``/dev/zero`` never ends), so it is refused, naming it, before anything opens it."""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import IO

_KINDS = {stat.S_IFDIR: "a folder", stat.S_IFIFO: "a FIFO", stat.S_IFSOCK: "a socket", stat.S_IFBLK: "a block device"}


def special_file_error(path: str | Path, mode: int, what: str = "an input file") -> ValueError | None:
    """The ValueError naming ``path`` (and its link target) when ``mode`` is not a regular file's, else None."""
    if stat.S_ISREG(mode):
        return None
    link = f" (a link to {os.readlink(path)})" if os.path.islink(path) else ""
    kind = _KINDS.get(stat.S_IFMT(mode), "a character device")
    return ValueError(f"{path}{link} is {kind}, not a regular file; {what} must be a regular file")


def is_regular_file(path: str | Path, what: str = "an input file") -> bool:
    """Whether ``path`` is a regular file (links followed), False for nothing or a folder; a FIFO, device or socket
    raises :func:`special_file_error` (``what``: its role in the message).

    Examples
    --------
    >>> is_regular_file("/dev/null", "ground truth")
    Traceback (most recent call last):
    ...
    ValueError: /dev/null is a character device, not a regular file; ground truth must be a regular file
    """
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return False
    if not stat.S_ISDIR(mode) and (error := special_file_error(path, mode, what)):
        raise error
    return stat.S_ISREG(mode)


def open_regular(path: str | Path) -> IO[bytes]:
    """``path`` opened for reading once :func:`is_regular_file` says so; opened non-blocking and checked again on the
    open file, so a FIFO swapped in between can neither block the open nor be read."""
    is_regular_file(path)
    handle = os.fdopen(os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY), "rb")
    if error := special_file_error(path, os.fstat(handle.fileno()).st_mode):
        handle.close()
        raise error
    return handle


def _identity(path: str | Path) -> tuple:
    """A file's identity: its device and inode when it exists (symbolic and hard links lead to one), else the path
    with every link resolved."""
    try:
        status = os.stat(path)
    except OSError:
        return ("path", os.path.realpath(path))
    return ("inode", status.st_dev, status.st_ino)


def refuse_shared_files(inputs: dict[str, str | Path | None], outputs: dict[str, str | Path | None]) -> None:
    """Raise a ValueError when an output is one of the inputs or another output (``-``, standard output, and None
    are skipped); the keys name each file's role in the message, e.g. ``{"--out": path}``.

    Examples
    --------
    >>> refuse_shared_files({"GRAPH": "/tmp/g.g2o"}, {"--out": "/tmp/../tmp/g.g2o"})
    Traceback (most recent call last):
    ...
    ValueError: --out /tmp/../tmp/g.g2o is GRAPH /tmp/g.g2o, which this command never overwrites: name another file
    """
    seen = {_identity(path): (role, path) for role, path in inputs.items() if path is not None and str(path) != "-"}
    for role, path in outputs.items():
        if path is None or str(path) == "-":
            continue
        if (identity := _identity(path)) in seen:
            other, other_path = seen[identity]
            never = "this command never overwrites" if other in inputs else "this command also writes"
            raise ValueError(f"{role} {path} is {other} {other_path}, which {never}: name another file")
        seen[identity] = (role, path)
