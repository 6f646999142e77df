"""Checks of the descriptor cache (:mod:`vpr_uncertainty.descriptors.cache`): the payload checksum of a split, and
the diagnosis of a file that cannot be opened or resumed.

A complete split stores ``checksum`` (group attribute): :func:`vpr_uncertainty.cache.payload_checksum` of its
names, its descriptors as stored (float32 or float16 bytes), its content keys and its ``failed`` attribute, in this
order. The descriptors are hashed one block of rows at a time (never read whole for the hash).
"""

from __future__ import annotations

import errno
import json
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty import cache as protocol

__all__ = ["split_checksum", "verify_split"]

_HASH_BLOCK_BYTES = 1 << 24


class _StoredRows:
    """The first ``count`` rows of an HDF5 dataset, read one block at a time (for :func:`~vpr_uncertainty.cache.
    array_digest`)."""

    def __init__(self, dataset: Any, count: int) -> None:
        self.dataset = dataset
        self.shape = (count, *dataset.shape[1:])
        self.dtype = dataset.dtype

    def row_blocks(self) -> Iterator[np.ndarray]:
        row_bytes = max(1, int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize)
        step = max(1, _HASH_BLOCK_BYTES // row_bytes)
        for start in range(0, self.shape[0], step):
            yield self.dataset[start : min(start + step, self.shape[0])]


def _parts(group: Any, count: int, descriptors: Any = None) -> tuple[Any, ...]:
    names = np.asarray(group["names"].asstr()[:count], dtype=str) if "names" in group else None
    keys = np.asarray(group["keys"].asstr()[:count], dtype=str) if "keys" in group else None
    if descriptors is None and "descriptors" in group:
        descriptors = _StoredRows(group["descriptors"], count)
    return names, descriptors, keys, str(group.attrs.get("failed", "[]"))


def split_checksum(group: Any, count: int) -> str:
    """The payload checksum of the first ``count`` rows of a split (an ``h5py`` group), read from the file."""
    return protocol.payload_checksum(*_parts(group, count))


def verify_split(path: Path, group: Any, split: str, count: int, descriptors: np.ndarray | None = None) -> None:
    """Raise :class:`~vpr_uncertainty.cache.ChecksumError` naming ``path`` when a complete split that holds a
    checksum no longer matches it (``descriptors``: its rows as stored, when already read)."""
    stored = group.attrs.get("checksum")
    if not group.attrs.get("complete", False) or stored is None:
        return  # being written (rows appended), or sealed by the next run that completes it
    protocol.verify_checksum(path, stored, *_parts(group, count, descriptors), what=f"the {split!r} descriptors")


def is_lock_error(error: OSError) -> bool:
    """Whether HDF5 refused to open the file because another process holds its lock (not "sblock" of truncation)."""
    text = str(error).lower()
    return "unable to lock file" in text or getattr(error, "errno", None) in (errno.EAGAIN, errno.EWOULDBLOCK)


def first_line(error: BaseException) -> str:
    return (str(error).strip().splitlines() or [type(error).__name__])[0]


def write_error(path: Path, error: BaseException) -> OSError:
    """An OSError with the errno of a failed HDF5 write (h5py puts it in the text of a RuntimeError)."""
    number = getattr(error, "errno", None)
    if not number:
        found = re.search(r"errno = (\d+)", str(error))
        number = int(found.group(1)) if found else errno.EIO
    return OSError(number, f"{os.strerror(number)} (writing the descriptor cache)", str(path))


def looks_like_hdf5(path: Path) -> bool:
    """Whether the file starts with the HDF5 signature (or with a part of it: a file cut within its first bytes)."""
    with open(path, "rb") as handle:
        head = handle.read(8)
    return bool(head) and b"\x89HDF\r\n\x1a\n".startswith(head)


def describe_change(stored: str, current: str) -> str:
    try:
        old, new = json.loads(stored or "{}"), json.loads(current)
    except json.JSONDecodeError:
        return "unreadable fingerprint"
    changed = sorted(key for key in set(old) | set(new) if old.get(key) != new.get(key))
    return "changed: " + ", ".join(changed) if changed else "fingerprint differs"
