"""One cache protocol for every artefact the toolkit writes: content keys, fingerprints, atomic writes.

A stage's artefact (``descriptors.h5``, ``retrieval.npz``, a grid cell, a local-feature file, ...) stores the
:func:`fingerprint` of the stage's configuration and of the *content* of its inputs, and is reused only when the
stored fingerprint equals the one the current run computes. Per-image stages also store each image's
:func:`content_key`, so that a rerun recomputes exactly the images that changed.

- :func:`content_key` of a file: its size, its modification time in nanoseconds and a BLAKE2b hash of its bytes.
  Files up to :data:`FULL_HASH_BYTES` (every image) are hashed whole; larger files (similarity matrices,
  descriptor files of millions of rows) hash their first and last :data:`EDGE_BYTES` only, a documented cheap key
  that catches any rewrite which changes the size, the modification time or either end of the file.
- :func:`array_digest` of in-memory arrays: dtype, shape and every byte.
- :func:`fingerprint`: SHA-256 of the canonical JSON of ``{"protocol", "stage", "config", "inputs"}``.
- :func:`atomic_path` / :func:`atomic_write`: write to a temporary file in the target's folder, flush and fsync
  it, then :func:`os.replace` it over the target: an interrupted write (crash, SIGKILL, disk full) never leaves a
  truncated artefact, only the previous one or none.
- :func:`stale_notice`: the one-line warning (:class:`CacheWarning`) given when a cache is truncated, foreign or of
  an older layout and is rebuilt.

Examples
--------
>>> fingerprint("retrieval", {"k": 20}) == fingerprint("retrieval", {"k": 20})
True
>>> fingerprint("retrieval", {"k": 20}) == fingerprint("retrieval", {"k": 10})
False
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
import warnings
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any, TypeVar

import numpy as np

__all__ = [
    "EDGE_BYTES",
    "FULL_HASH_BYTES",
    "PROTOCOL",
    "CacheWarning",
    "array_digest",
    "atomic_path",
    "atomic_write",
    "content_key",
    "fingerprint",
    "read_if_fresh",
    "stale_notice",
    "write_json",
    "write_text",
]

#: Version of this protocol; part of every fingerprint, so a change of the protocol rebuilds every cache.
PROTOCOL = 1
#: Files up to this size are hashed whole by :func:`content_key`.
FULL_HASH_BYTES = 64 * 2**20
#: Bytes hashed at each end of a larger file.
EDGE_BYTES = 2**20
_BLOCK = 2**20

T = TypeVar("T")


class CacheWarning(UserWarning):
    """A cache was truncated, foreign or of an older layout, and is rebuilt (the message names it and why)."""


def content_key(path: str | Path) -> str:
    """A key that changes when the content of the file changes: ``"size:mtime_ns:blake2b"``.

    Parameters
    ----------
    path : str or Path
        A file (symbolic links are followed).

    Returns
    -------
    str
        Files up to :data:`FULL_HASH_BYTES` are hashed whole; larger ones by their first and last
        :data:`EDGE_BYTES` (with the size and modification time, a cheap key for large result files).

    Examples
    --------
    >>> import tempfile
    >>> file = Path(tempfile.mkdtemp()) / "a.txt"
    >>> _ = file.write_text("a")
    >>> first = content_key(file)
    >>> _ = file.write_text("b")
    >>> content_key(file) != first
    True
    """
    path = Path(path)
    stat = path.stat()
    hasher = hashlib.blake2b(digest_size=16)
    with path.open("rb") as handle:
        if stat.st_size <= FULL_HASH_BYTES:
            while block := handle.read(_BLOCK):
                hasher.update(block)
        else:
            hasher.update(handle.read(EDGE_BYTES))
            handle.seek(-EDGE_BYTES, os.SEEK_END)
            hasher.update(handle.read(EDGE_BYTES))
    return f"{stat.st_size}:{stat.st_mtime_ns}:{hasher.hexdigest()}"


def array_digest(*arrays: Any) -> str:
    """A hash of the dtype, shape and bytes of each array (None counts as an absent array).

    Arrays are hashed in pieces of at most 16 MiB (no copy of a whole array). An object with a ``row_blocks()``
    method, ``shape`` and ``dtype`` (a :class:`~vpr_uncertainty.retrieval.descriptor_rows.DescriptorRows` on
    disk) is hashed one block of rows at a time, with the digest of the same rows in memory.

    Examples
    --------
    >>> array_digest(np.zeros(3)) == array_digest(np.zeros(3)), array_digest(np.zeros(3)) == array_digest(np.ones(3))
    (True, False)
    """
    hasher = hashlib.blake2b(digest_size=16)
    for array in arrays:
        if array is None:
            hasher.update(b"none;")
            continue
        if hasattr(array, "row_blocks") and not isinstance(array, np.ndarray):
            hasher.update(f"{np.dtype(array.dtype).str}{tuple(array.shape)};".encode())
            for block in array.row_blocks():
                _hash_bytes(hasher, np.ascontiguousarray(block, dtype=array.dtype))
                del block  # before the next block is read
            continue
        array = np.ascontiguousarray(array)
        if array.dtype.hasobject:
            raise TypeError("array_digest cannot hash object arrays")
        hasher.update(f"{array.dtype.str}{array.shape};".encode())
        _hash_bytes(hasher, array)
    return hasher.hexdigest()


def _hash_bytes(hasher: Any, array: np.ndarray, piece_bytes: int = 1 << 24) -> None:
    """Feed the bytes of a C-ordered array to ``hasher`` in pieces (the same digest as all bytes at once)."""
    flat = array.reshape(-1)
    step = max(1, piece_bytes // max(array.itemsize, 1))
    for start in range(0, flat.size, step):
        hasher.update(flat[start : start + step].tobytes())


def _canonical(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(key): _canonical(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(item) for item in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return {"array": array_digest(value)}
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return repr(value)


def fingerprint(stage: str, config: Mapping[str, Any], inputs: Mapping[str, Any] | None = None) -> str:
    """SHA-256 (hex) of a stage's name, configuration and input keys, as canonical JSON.

    Parameters
    ----------
    stage : str
        The stage's name; the same configuration in two stages gives two fingerprints.
    config : mapping
        The stage's options (JSON-like values; paths become strings, arrays their :func:`array_digest`).
    inputs : mapping, optional
        Keys of the inputs' content: :func:`content_key` of files, :func:`array_digest` of arrays, fingerprints
        of upstream artefacts.

    Returns
    -------
    str
    """
    document = {"protocol": PROTOCOL, "stage": stage, "config": _canonical(config), "inputs": _canonical(inputs or {})}
    text = json.dumps(document, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def stale_notice(path: str | Path, reason: str, action: str = "rebuilding it", *, stacklevel: int = 3) -> None:
    """Warn in one line that the cache at ``path`` cannot be used (``reason``) and what happens instead."""
    reason = " ".join(str(reason).split())
    warnings.warn(f"cache {path}: {reason}; {action}", CacheWarning, stacklevel=stacklevel)


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
        yield path
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
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    _fsync_folder(path.parent)


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


def read_if_fresh(
    path: str | Path,
    expected: str,
    read: Callable[[Path], T],
    stored: Callable[[T], str | None],
    *,
    errors: tuple[type[BaseException], ...] = (OSError, ValueError, KeyError, EOFError),
) -> T | None:
    """Read a cached artefact when it exists, is readable and holds the ``expected`` fingerprint; else None.

    Parameters
    ----------
    path : str or Path
    expected : str
        The fingerprint the current run computed.
    read : callable
        Reads the artefact (raising one of ``errors`` when it is truncated or foreign).
    stored : callable
        The fingerprint stored in what ``read`` returned (None when it holds none: a previous layout).
    errors : tuple of exception types
        What ``read`` raises for an unusable file; reported with :func:`stale_notice` (one line) and rebuilt.

    Returns
    -------
    The artefact, or None when it must be (re)built.
    """
    path = Path(path)
    if not path.is_file():
        return None
    try:
        value = read(path)
    except PermissionError:
        raise
    except errors as error:
        stale_notice(path, f"unreadable (truncated or foreign: {error})")
        return None
    found = stored(value)
    if found is None:
        stale_notice(path, "written by an earlier version (no fingerprint)")
        return None
    return value if found == expected else None
