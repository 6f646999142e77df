"""One cache protocol for every artefact the toolkit writes: content keys, fingerprints, atomic writes.

A stage's artefact (``descriptors.h5``, ``retrieval.npz``, a grid cell, a local-feature file, ...) stores the
:func:`fingerprint` of the stage's configuration and of the *content* of its inputs, and is reused only when the
stored fingerprint equals the one the current run computes. Per-image stages also store each image's
:func:`content_key`, so that a rerun recomputes exactly the images that changed.

- :func:`content_key` of a file: its size, its modification time in nanoseconds and a BLAKE2b hash of its bytes.
  Files up to :data:`FULL_HASH_BYTES` (every image) are hashed whole; larger files (similarity matrices,
  descriptor files of millions of rows) hash their first and last :data:`EDGE_BYTES` only and add their status
  change time (``st_ctime_ns``, which every write updates and :func:`os.utime` cannot set back): a documented cheap
  key that catches any rewrite on a filesystem that keeps the change time. :func:`file_digest` hashes every byte
  (what ``reproduce --verify`` checks such files with).
- :func:`array_digest` of in-memory arrays: dtype, shape and every byte.
- :func:`fingerprint`: SHA-256 of the canonical JSON of ``{"protocol", "stage", "config", "inputs"}``.
- :func:`payload_checksum` / :func:`verify_checksum`: ``"blake2b:"`` + :func:`array_digest` of what an artefact
  stores (its arrays, and its text as UTF-8 bytes), written with the artefact and recomputed on read; a mismatch
  (:class:`ChecksumError`, naming the file) means the artefact was changed after it was written, whatever its size
  and modification time say.
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

import hashlib
import json
import os
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from vpr_uncertainty.atomic_files import atomic_path, atomic_write, write_json, write_text

__all__ = [
    "EDGE_BYTES",
    "FULL_HASH_BYTES",
    "PROTOCOL",
    "CacheWarning",
    "ChecksumError",
    "array_digest",
    "atomic_path",
    "atomic_write",
    "content_key",
    "file_digest",
    "fingerprint",
    "is_partly_hashed",
    "named_files_key",
    "payload_checksum",
    "read_if_fresh",
    "stale_notice",
    "verify_checksum",
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


class ChecksumError(ValueError):
    """An artefact's payload does not match the checksum stored with it (changed on disk after it was written)."""


def content_key(path: str | Path) -> str:
    """A key that changes when the content of the file changes: ``"size:mtime_ns:blake2b"``.

    Parameters
    ----------
    path : str or Path
        A file (symbolic links are followed).

    Returns
    -------
    str
        Files up to :data:`FULL_HASH_BYTES` are hashed whole (``"size:mtime_ns:blake2b"``); larger ones by their
        first and last :data:`EDGE_BYTES`, with their status change time (``"size:mtime_ns:ctime_ns:blake2b"``), a
        cheap key for large result files; :func:`file_digest` hashes every byte.

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
            return f"{stat.st_size}:{stat.st_mtime_ns}:{_change_time(stat)}:{hasher.hexdigest()}"
    return f"{stat.st_size}:{stat.st_mtime_ns}:{hasher.hexdigest()}"


def _change_time(stat: os.stat_result) -> int:
    """The status change time in nanoseconds (a write updates it; :func:`os.utime` cannot set it back)."""
    return stat.st_ctime_ns


def is_partly_hashed(path: str | Path) -> bool:
    """Whether :func:`content_key` hashes only the ends of this file (larger than :data:`FULL_HASH_BYTES`)."""
    return Path(path).stat().st_size > FULL_HASH_BYTES


def file_digest(path: str | Path) -> str:
    """``"blake2b:"`` and the BLAKE2b hash of every byte of a file, whatever its size (read in 1 MiB blocks).

    Examples
    --------
    >>> import tempfile
    >>> file = Path(tempfile.mkdtemp()) / "a.txt"
    >>> _ = file.write_text("a")
    >>> file_digest(file) == "blake2b:" + hashlib.blake2b(b"a", digest_size=16).hexdigest()
    True
    """
    hasher = hashlib.blake2b(digest_size=16)
    with Path(path).open("rb") as handle:
        while block := handle.read(_BLOCK):
            hasher.update(block)
    return "blake2b:" + hasher.hexdigest()


def named_files_key(values: Any) -> dict[str, str]:
    """The :func:`content_key` of every value that names an existing file (a str or path), by resolved path.

    For the options of a stage (``CAL:gate=gate.json``, ``btl_head=head.pt``): whatever file an option names is
    part of the fingerprint by its content, whichever option and method name it. Values that are not paths of
    existing files (numbers, words such as ``one-sided``) are left out. Relative paths are taken from the working
    folder, as the methods that open them do.

    Examples
    --------
    >>> named_files_key(["one-sided", 3.0, None])
    {}
    """
    keys = {}
    for value in values:
        if isinstance(value, (str, os.PathLike)) and str(value) and Path(value).is_file():
            keys[str(Path(value).resolve())] = content_key(value)
    return dict(sorted(keys.items()))


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


def payload_checksum(*parts: Any) -> str:
    """The checksum of an artefact's payload: ``"blake2b:"`` + :func:`array_digest` of ``parts``.

    Parameters
    ----------
    *parts : ndarray, str, bytes, None or row blocks
        What the artefact stores, in a fixed order: arrays (or objects with ``row_blocks()``, hashed block by block),
        text (hashed as its UTF-8 bytes) and None (an absent part).

    Returns
    -------
    str

    Examples
    --------
    >>> payload_checksum(np.arange(3), "text") == payload_checksum(np.arange(3), "text")
    True
    >>> payload_checksum(np.arange(3), "text") == payload_checksum(np.arange(3), "texT")
    False
    """
    arrays = [_as_bytes_array(part) if isinstance(part, (str, bytes)) else part for part in parts]
    return "blake2b:" + array_digest(*arrays)


def _as_bytes_array(part: str | bytes) -> np.ndarray:
    data = part.encode("utf-8") if isinstance(part, str) else bytes(part)
    return np.frombuffer(data, dtype=np.uint8)


def verify_checksum(path: str | Path, stored: Any, *parts: Any, what: str = "payload") -> None:
    """Raise :class:`ChecksumError` naming ``path`` unless ``stored`` is the :func:`payload_checksum` of ``parts``.

    Parameters
    ----------
    path : str or Path
        The artefact (named in the message).
    stored : str or None
        The checksum stored with the artefact (None or "": it holds none).
    *parts
        What :func:`payload_checksum` was given when the artefact was written, read back from it.
    what : str
        What the checksum covers, for the message (e.g. ``"the 'database' descriptors"``).
    """
    if not stored:
        raise ChecksumError(f"{path}: {what} has no checksum (written by an earlier version)")
    found = payload_checksum(*parts)
    if found != str(stored):
        raise ChecksumError(
            f"{path}: checksum mismatch of {what} (stored {str(stored)[:24]}..., read {found[:24]}...): "
            "changed on disk after it was written"
        )


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
