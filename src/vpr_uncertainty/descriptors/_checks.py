"""Checks of the descriptor cache (:mod:`vpr_uncertainty.descriptors.cache`): the payload checksum of a split, and
the diagnosis of a file that cannot be opened or resumed.

A complete split stores ``checksum`` (group attribute): :func:`vpr_uncertainty.cache.payload_checksum` of its
names, its descriptors as stored (float32 or float16 bytes), its content keys and its ``failed`` attribute, in this
order. The descriptors are hashed one block of rows at a time (never read whole for the hash).

A checksum proves that rows are what was written, not that they are numbers: rows holding NaN or infinite values
(an unsealed split, or a model that once produced them) are found by :func:`non_finite_rows`, recomputed by the
extraction (:func:`blank_non_finite`, with a one-line notice naming the file) and refused by the readers
(:func:`check_finite`, naming the file, the split and the image).
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

__all__ = [
    "blank_non_finite",
    "check_finite",
    "non_finite_rows",
    "refuse_if_in_use",
    "split_checksum",
    "verify_split",
]

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


def non_finite_rows(group: Any, count: int) -> np.ndarray:
    """Indices of the first ``count`` rows of a split whose descriptors hold NaN or infinite values (block by block)."""
    if count == 0 or "descriptors" not in group:
        return np.empty(0, dtype=np.int64)
    found, start = [], 0
    for block in _StoredRows(group["descriptors"], count).row_blocks():
        found.append(start + np.flatnonzero(~np.isfinite(block).all(axis=1)))
        start += len(block)
    return np.concatenate(found)


def blank_non_finite(path: Path, group: Any, split: str, names: Any, keys: Any) -> list[str]:
    """``keys`` with the key of every row holding NaN or infinite values blanked (the extraction recomputes those
    images), with a one-line :class:`~vpr_uncertainty.cache.CacheWarning` naming ``path``."""
    keys = list(keys)
    bad = non_finite_rows(group, len(keys))
    if bad.size:
        protocol.stale_notice(
            path,
            f"{bad.size} {split!r} row(s) hold NaN or infinite values (first: image {str(names[int(bad[0])])!r})",
            "recomputing them",
            stacklevel=5,
        )
        for row in bad:
            keys[int(row)] = ""
    return keys


def check_finite(path: Path | str, split: str, descriptors: np.ndarray, names: Any, first_row: int = 0) -> None:
    """Raise ValueError naming ``path`` when rows ``first_row`` … of ``split`` hold NaN or infinite values (checked
    one block of rows at a time: no temporary the size of ``descriptors``)."""
    row_bytes = max(1, int(np.prod(descriptors.shape[1:], dtype=np.int64)) * descriptors.dtype.itemsize)
    step = max(1, _HASH_BLOCK_BYTES // row_bytes)
    found = [np.zeros(0, dtype=np.int64)]
    for start in range(0, len(descriptors), step):
        found.append(start + np.flatnonzero(~np.isfinite(descriptors[start : start + step]).all(axis=1)))
    bad = np.concatenate(found)
    if bad.size:
        row = int(bad[0])
        name = f" (image {str(names[first_row + row])!r})" if names is not None else ""
        raise ValueError(
            f"{path}: the {split!r} descriptors hold NaN or infinite values ({bad.size} row(s), first row "
            f"{first_row + row}{name}); rebuild the file (vpr-uncertainty extract, or run, recomputes those rows)"
        )


def in_use_error(path: Path) -> ValueError:
    """The error for a descriptor cache another process holds open for writing (its HDF5 file lock)."""
    return ValueError(
        f"{path} is open for writing in another process (HDF5 file lock); wait for it to finish or choose another path"
    )


def refuse_if_in_use(path: Path, h5py: Any) -> None:
    """Raise :func:`in_use_error` when another process holds ``path`` open for writing; anything else (a file
    HDF5 cannot open, readers holding shared locks) is left for the caller to replace."""
    try:
        handle = h5py.File(path, "r")
    except OSError as error:
        if is_lock_error(error):
            raise in_use_error(path) from error
        return
    handle.close()


def is_lock_error(error: OSError) -> bool:
    """Whether HDF5 refused to open the file because another process holds its lock (not "sblock" of truncation)."""
    text = str(error).lower()
    return "unable to lock file" in text or getattr(error, "errno", None) in (errno.EAGAIN, errno.EWOULDBLOCK)


def first_line(error: BaseException) -> str:
    return (str(error).strip().splitlines() or [type(error).__name__])[0]


def write_error(path: Path, error: BaseException, what: str = "the descriptor cache") -> OSError:
    """An OSError naming ``path`` with the errno of a failed HDF5 write (h5py puts it in the text of a RuntimeError)."""
    number = getattr(error, "errno", None)
    if not number:
        found = re.search(r"errno = (\d+)", str(error))
        number = int(found.group(1)) if found else errno.EIO
    return OSError(number, f"{os.strerror(number)} (writing {what})", str(path))


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
