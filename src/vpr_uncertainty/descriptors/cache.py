"""HDF5 descriptor cache: one row per image, resumable per image, following :mod:`vpr_uncertainty.cache`. The layout:
see docs/reference/file-formats.md; which rows a rerun computes again, which files it rebuilds or refuses: see
docs/explanation/caches.md.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty import cache as protocol
from vpr_uncertainty.cache import open_present

_HASH_BLOCK_BYTES = 1 << 24


class _StoredRows:
    """The first ``count`` rows of an HDF5 dataset (or array), read one block at a time."""

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


def row_checksums(names: Sequence[str], descriptors: Any, keys: Sequence[str]) -> list[str]:
    """The checksum of each row: BLAKE2b of its name, content key and descriptor bytes as stored (block by block)."""
    blocks = descriptors.row_blocks() if hasattr(descriptors, "row_blocks") else [np.asarray(descriptors)]
    rows = (row for block in blocks for row in np.ascontiguousarray(block))
    return [
        hashlib.blake2b(f"{name}\0{key}\0".encode() + row.tobytes(), digest_size=8).hexdigest()
        for name, key, row in zip(names, keys, rows, strict=True)
    ]


def _rows_of(group: Any, key: str, count: int) -> np.ndarray:
    """The first ``count`` rows of dataset ``key`` of a split (strings as an object array)."""
    dataset = group[key]
    return np.asarray(dataset[:count]) if key == "descriptors" else np.asarray(dataset.asstr()[:count], dtype=object)


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


def _non_finite(rows: _StoredRows) -> np.ndarray:
    """Indices of the rows holding NaN or infinite values, found one block at a time."""
    found, start = [np.zeros(0, dtype=np.int64)], 0
    for block in rows.row_blocks():
        found.append(start + np.flatnonzero(~np.isfinite(block).all(axis=1)))
        start += len(block)
    return np.concatenate(found)


def blank_non_finite(path: Path, group: Any, split: str, names: Any, keys: Any) -> list[str]:
    """``keys`` with the key of every row holding NaN or infinite values blanked (the extraction recomputes those
    images), with a one-line :class:`~vpr_uncertainty.cache.CacheWarning` naming ``path``."""
    keys = list(keys)
    bad = _non_finite(_StoredRows(group["descriptors"], len(keys))) if "descriptors" in group else np.zeros(0)
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
    bad = _non_finite(_StoredRows(descriptors, len(descriptors)))
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


FORMAT = "vpr-uncertainty descriptors"

FORMAT_VERSION = 2

#: Name of the stage in the fingerprint.
STAGE = "descriptors"

SPLITS = ("database", "queries")

_DATASETS = ("names", "descriptors", "keys", "checksums")

DTYPES = ("float32", "float16")

_CHUNK_ROWS = 256


# No raw-data chunk cache in the writer: each batch goes to disk when written, so a failed write (disk full)
# raises there, as an OSError, instead of leaving a dirty chunk that HDF5 cannot flush on close and that crashes
# the interpreter at exit (HDF5 2.0 / h5py 3.16: segmentation fault).
_WRITER_OPTIONS = {"rdcc_nbytes": 0}


def _check_split(split: str) -> str:
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    return split


def _valid_length(group: Any) -> int:
    """Rows present in every dataset (a kill between the writes leaves at most one batch unmatched)."""
    if "names" not in group or "descriptors" not in group:
        return 0
    return min(group[key].shape[0] for key in _DATASETS if key in group)


def is_whole(path: Path) -> bool:
    """Whether ``path`` is a descriptor file whose every split is complete and sealed by its checksum."""
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            groups = [handle[split] for split in SPLITS if split in handle]
            return bool(groups) and all(g.attrs.get("complete") and "checksum" in g.attrs for g in groups)
    except (OSError, RuntimeError, KeyError):
        return False


def split_layout(path: Path, split: str, *, stacklevel: int = 2) -> tuple[np.ndarray, int, int]:
    """``(names, rows, dimension)`` of one split of a descriptor cache, checked: the file's format, the split
    present, and a warning (at ``stacklevel`` above the caller) when its extraction did not complete."""
    import h5py

    try:
        handle = h5py.File(path, "r")
    except OSError as error:
        raise ValueError(f"{path} is not a readable HDF5 descriptor file: {error}") from error
    with handle:
        if handle.attrs.get("format") != FORMAT:
            raise ValueError(f"{path} is not a vpr-uncertainty descriptor file (no format attribute {FORMAT!r})")
        if split not in handle:
            raise KeyError(f"{path} holds no {split!r} descriptors (it has: {', '.join(handle) or 'none'})")
        open_present(handle, tuple(f"{split}/{key}" for key in _DATASETS), path)  # refuses bytes from outside it
        group = handle[split]
        count = _valid_length(group)
        if not group.attrs.get("complete", False):
            warnings.warn(
                f"{path}: the {split!r} descriptors are incomplete (interrupted extraction?); reading {count} rows",
                stacklevel=stacklevel + 1,
            )
        dimension = int(group["descriptors"].shape[1]) if count else 0
        return np.array(group["names"].asstr()[:count], dtype=str), count, dimension


def read_descriptors(
    path: str | Path, split: str, *, names: Sequence[str] | None = None, verify: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Read the descriptors of one split from a descriptor cache.

    Parameters
    ----------
    path : str or Path
        The HDF5 file written by :func:`~vpr_uncertainty.descriptors.extract.extract_descriptors`.
    split : {"database", "queries"}
    names : sequence of str, optional
        Return exactly these images, in this order (KeyError naming the missing ones otherwise). By default
        every row, in file order (the dataset's order once extraction completed).
    verify : bool, default=True
        Check the split's payload checksum (:class:`~vpr_uncertainty.cache.ChecksumError` naming the file when it
        no longer matches); the extraction reads back a split it has just verified or sealed without it.

    Returns
    -------
    names : ndarray of shape (N,), str
    descriptors : ndarray of shape (N, D), float32
    """
    _check_split(split)
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"descriptor file not found: {path}")
    import h5py

    stored_names, count, _ = split_layout(path, split, stacklevel=3)
    if count == 0:
        return stored_names, np.empty((0, 0), dtype=np.float32)
    with h5py.File(path, "r") as handle:
        stored = np.asarray(handle[split]["descriptors"][:count])
        if verify:
            verify_split(path, handle[split], split, count, stored)
    check_finite(path, split, stored, stored_names)  # a checksum proves the bytes, not that they are numbers
    descriptors = stored.astype(np.float32, copy=False)
    if names is None:
        return stored_names, descriptors
    index = {name: row for row, name in enumerate(stored_names)}
    missing = [name for name in names if name not in index]
    if missing:
        shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        raise KeyError(f"{path}: no {split!r} descriptors for {len(missing)} image(s): {shown}")
    rows = np.array([index[name] for name in names], dtype=np.int64)
    return np.array(list(names), dtype=str), descriptors[rows]


def read_complete(
    path: str | Path, config: dict[str, Any], split: str, names: Sequence[str], keys: Sequence[str], *, dtype: str
) -> tuple[np.ndarray, np.ndarray] | None:
    """The descriptors of ``names`` when the cache at ``path`` holds exactly those rows, ready to use; else None.

    "Ready" is what a rerun of the extraction would find with nothing to compute and nothing to rewrite: the
    file's fingerprint is that of ``config`` (the model's :attr:`~.models.DescriptorModel.fingerprint`) and
    ``dtype``; the split is complete and sealed, with no image left out; its rows are ``names`` in this order, each
    computed from the file of content key ``keys[i]``; its checksum verifies and every value is finite. Anything
    else returns None, and the extraction then opens the cache (:class:`DescriptorCache`), which says why it cannot
    be used and computes what is missing. This only reads (no lock held, nothing written, no warning), so it can be
    asked before the model is loaded.

    Returns
    -------
    names : ndarray of shape (N,), str
    descriptors : ndarray of shape (N, D), float32
    """
    import h5py

    _check_split(split)
    path = Path(path)
    names, keys = [str(name) for name in names], [str(key) for key in keys]
    if not path.is_file() or len(keys) != len(names) or not all(keys):
        return None
    expected = DescriptorCache(path, config, dtype=dtype).fingerprint  # computed, not opened
    try:
        with h5py.File(path, "r") as handle:
            attrs = handle.attrs
            if attrs.get("format") != FORMAT or int(attrs.get("format_version", 0)) != FORMAT_VERSION:
                return None
            if attrs.get("fingerprint") != expected or split not in handle:
                return None
            datasets = open_present(handle, tuple(f"{split}/{key}" for key in _DATASETS), path)
            group = handle[split]
            if len(datasets) < len(_DATASETS) - 1 or not group.attrs.get("complete", False):  # checksums: optional
                return None
            if "checksum" not in group.attrs or group.attrs.get("failed") != json.dumps([]):
                return None
            count = len(names)
            if any(dataset.shape[0] != count for dataset in datasets.values()):
                return None
            if list(group["names"].asstr()[:]) != names or list(group["keys"].asstr()[:]) != keys:
                return None
            stored = np.asarray(group["descriptors"][:])
            verify_split(path, group, split, count, stored)
    except (OSError, RuntimeError, ValueError, KeyError):  # unreadable, cut short, foreign, corrupted, in use
        return None
    if _non_finite(_StoredRows(stored, count)).size:
        return None
    return np.array(names, dtype=str), stored.astype(np.float32, copy=False)


def cache_info(path: str | Path) -> dict[str, Any]:
    """Summary of a descriptor file: fingerprint, dtype, and per split the row count, size D, completeness."""
    import h5py

    with h5py.File(path, "r") as handle:
        version = int(handle.attrs.get("format_version", 0))
        config = handle.attrs.get("config" if version >= 2 else "fingerprint", "{}")
        info: dict[str, Any] = {
            "format_version": version,
            "model": str(handle.attrs.get("model", "")),
            "dtype": str(handle.attrs.get("dtype", "")),
            "config": json.loads(config),
            "fingerprint": str(handle.attrs.get("fingerprint", "")) if version >= 2 else "",
        }
        for split in SPLITS:
            if split in handle:
                group = handle[split]
                info[split] = {
                    "count": _valid_length(group),
                    "dim": int(group["descriptors"].shape[1]) if "descriptors" in group else 0,
                    "complete": bool(group.attrs.get("complete", False)),
                    "failed": json.loads(group.attrs.get("failed", "[]")),
                }
    return info


class DescriptorCache:
    """Writer side of the cache, used by the extraction. Open with ``with DescriptorCache(...) as cache``.

    Parameters
    ----------
    path : str or Path
    config : dict
        What produced the descriptors (JSON-serialisable: the model's fingerprint). A file of another
        configuration is rebuilt.
    dtype : {"float32", "float16"}
    model_name : str
    overwrite : bool
        Recreate the file even when the configuration matches.
    verify : sequence of str
        The complete splits whose payload checksum is verified when the file is opened (a mismatch rebuilds it).
    """

    def __init__(
        self,
        path: str | Path,
        config: dict[str, Any],
        *,
        dtype: str = "float32",
        model_name: str = "",
        overwrite: bool = False,
        verify: Sequence[str] = SPLITS,
    ) -> None:
        if dtype not in DTYPES:
            raise ValueError(f"dtype must be one of {DTYPES}, got {dtype!r}")
        self.path = Path(path)
        self.dtype = dtype
        self.model_name = model_name
        self.config = json.dumps({**config, "dtype": dtype}, sort_keys=True)
        self.fingerprint = protocol.fingerprint(STAGE, json.loads(self.config))
        self.overwrite = overwrite
        self.verify = tuple(verify)
        self.invalidated = False
        self._handle: Any = None

    def __enter__(self) -> DescriptorCache:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def open(self) -> None:
        import h5py

        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.overwrite and self.path.exists():
            refuse_if_in_use(self.path, h5py)  # never replaced while another process writes it
        if self.path.exists() and not self.overwrite:
            reason = self._stale_reason(h5py)
            if reason is None:
                self._handle = h5py.File(self.path, "a", **_WRITER_OPTIONS)
                return
            protocol.stale_notice(self.path, reason, "recomputing all descriptors", stacklevel=4)
            self.invalidated = True
        with self._writing(), protocol.atomic_path(self.path) as temporary:  # created whole, then renamed
            with h5py.File(temporary, "w") as handle:
                handle.attrs["format"] = FORMAT
                handle.attrs["format_version"] = FORMAT_VERSION
                handle.attrs["config"] = self.config
                handle.attrs["fingerprint"] = self.fingerprint
                handle.attrs["model"] = self.model_name
                handle.attrs["dtype"] = self.dtype
        self._handle = h5py.File(self.path, "a", **_WRITER_OPTIONS)

    def _stale_reason(self, h5py: Any) -> str | None:
        """Why the existing file cannot be resumed (None: it can); ValueError for a file that is not ours."""
        try:
            with h5py.File(self.path, "r") as handle:
                if handle.attrs.get("format") != FORMAT:
                    if len(handle) or len(handle.attrs):
                        raise ValueError(
                            f"{self.path} exists and is not a vpr-uncertainty descriptor file; "
                            "choose another path or delete it"
                        )
                    return "empty HDF5 file"
                version = int(handle.attrs.get("format_version", 0))
                if version != FORMAT_VERSION:
                    return f"written by an earlier version (format version {version}, without per-image content keys)"
                stored, stored_config = handle.attrs.get("fingerprint", ""), handle.attrs.get("config", "")
        except OSError as error:
            if is_lock_error(error):
                raise in_use_error(self.path) from error
            if self.path.stat().st_size == 0:
                return "empty file (0 bytes)"
            if looks_like_hdf5(self.path):
                return f"truncated or damaged HDF5 file ({first_line(error)})"
            raise ValueError(f"{self.path} exists and is not an HDF5 file; choose another path or delete it") from error
        if stored != self.fingerprint:
            return f"made by another model or preprocessing ({describe_change(stored_config, self.config)})"
        try:
            with h5py.File(self.path, "r") as handle:
                open_present(handle, tuple(f"{split}/{key}" for split in SPLITS for key in _DATASETS), self.path)
                for split in self.verify:
                    if split in handle:
                        verify_split(self.path, handle[split], split, _valid_length(handle[split]))
        except protocol.ChecksumError as error:
            return f"corrupted ({str(error).removeprefix(f'{self.path}: ')})"
        except (OSError, RuntimeError) as error:  # a write cut short (disk full, file size limit): its links dangle
            return f"truncated or damaged HDF5 file ({first_line(error)})"
        return None

    def close(self) -> None:
        handle, self._handle = self._handle, None
        if handle is not None:
            with self._writing():
                handle.close()

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """Report a failed HDF5 write (disk full, I/O error) as an OSError naming the errno and this file."""
        try:
            yield
        except (OSError, RuntimeError) as error:
            raise write_error(self.path, error) from error

    def keys(self, split: str) -> dict[str, str]:
        """The content key of each name stored for ``split`` (the newest row of a name wins)."""
        _check_split(split)
        if split not in self._handle:
            return {}
        group = self._handle[split]
        count = _valid_length(group)
        if not count:
            return {}
        names = group["names"].asstr()[:count]
        keys = list(group["keys"].asstr()[:count]) if "keys" in group else [""] * count
        if not group.attrs.get("complete", False):  # no whole-split checksum yet: each row proves itself
            stored = group["checksums"].asstr()[:count] if "checksums" in group else [""] * count
            found = row_checksums(names, _StoredRows(group["descriptors"], count), keys)
            changed = [row for row, (old, new) in enumerate(zip(stored, found, strict=True)) if old != new]
            if changed:
                reason = f"{len(changed)} {split!r} row(s) do not match their checksum (first: {names[changed[0]]!r})"
                protocol.stale_notice(self.path, reason, "recomputing them", stacklevel=4)
                for row in changed:
                    keys[row] = ""
        keys = blank_non_finite(self.path, group, split, names, keys)  # rows holding NaN are recomputed
        return dict(zip(names, keys, strict=True))

    def append(self, split: str, names: Sequence[str], descriptors: np.ndarray, keys: Sequence[str]) -> None:
        """Append rows (with the content key of each image) and flush them to disk."""
        _check_split(split)
        descriptors = np.asarray(descriptors)
        if descriptors.ndim != 2 or descriptors.shape[0] != len(names) or len(keys) != len(names):
            raise ValueError(
                f"expected descriptors of shape ({len(names)}, D) and {len(names)} keys, got {descriptors.shape} "
                f"and {len(keys)}"
            )
        if not len(names):
            return
        group = self._handle.require_group(split)
        group.attrs["complete"] = False
        if "checksum" in group.attrs:
            del group.attrs["checksum"]  # rows change: sealed again by finalize
        if "descriptors" not in group:
            self._create(group, descriptors.shape[1])
        stored = group["descriptors"]
        if stored.shape[1] != descriptors.shape[1]:
            raise ValueError(
                f"descriptor size changed from {stored.shape[1]} to {descriptors.shape[1]} within {self.path}"
            )
        start = _valid_length(group)
        stop = start + len(names)
        with self._writing():
            # Descriptors and keys first, names last: a name on disk always has its descriptor and key.
            stored.resize((stop, stored.shape[1]))
            stored[start:stop] = descriptors.astype(self.dtype)
            checksums = row_checksums(names, stored[start:stop], keys)
            for key, values in (("keys", keys), ("checksums", checksums), ("names", names)):
                group[key].resize((stop,))
                group[key][start:stop] = np.asarray(list(values), dtype=object)
            self._handle.flush()

    def _create(self, group: Any, dim: int) -> None:
        import h5py

        for key in _DATASETS:
            if key in group:
                del group[key]
        group.create_dataset(
            "descriptors", shape=(0, dim), maxshape=(None, dim), dtype=self.dtype, chunks=(_CHUNK_ROWS, dim)
        )
        for key in ("names", "keys", "checksums"):
            group.create_dataset(
                key, shape=(0,), maxshape=(None,), dtype=h5py.string_dtype("utf-8"), chunks=(_CHUNK_ROWS,)
            )

    def finalize(self, split: str, names: Sequence[str], failed: Sequence[dict[str, str]] = ()) -> None:
        """Mark ``split`` complete, its rows exactly ``names`` in this order (other and older rows dropped)."""
        _check_split(split)
        group = self._handle.require_group(split)
        count = _valid_length(group)
        stored = list(group["names"].asstr()[:count]) if count else []
        failed_text = json.dumps(list(failed))
        unchanged = stored == list(names) and "names" in group and count == group["names"].shape[0]
        sealed = "checksum" in group.attrs
        if unchanged and sealed and group.attrs.get("complete", False) and group.attrs.get("failed") == failed_text:
            return  # a rerun that computed nothing leaves the file untouched
        if not unchanged:
            index = {name: row for row, name in enumerate(stored)}  # the newest row of a name wins
            missing = [name for name in names if name not in index]
            if missing:
                raise RuntimeError(f"cannot finalise {split!r}: {len(missing)} names were never written")
            with self._writing():
                if names:
                    rows = np.array([index[name] for name in names], dtype=np.int64)
                    kept = {key: _rows_of(group, key, count)[rows] for key in _DATASETS if key in group}
                    self._create(group, kept["descriptors"].shape[1])
                    for key, values in kept.items():
                        group[key].resize((len(names), *values.shape[1:]))
                        group[key][:] = values
                else:
                    for key in _DATASETS:
                        if key in group:
                            del group[key]
        with self._writing():
            group.attrs["failed"] = failed_text
            group.attrs["checksum"] = split_checksum(group, _valid_length(group))
            group.attrs["complete"] = True
            self._handle.flush()
