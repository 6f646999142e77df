"""Descriptor files read lazily, one block of rows at a time: databases larger than memory.

:func:`open_descriptors` is the lazy counterpart of :func:`~vpr_uncertainty.retrieval.readers.load_descriptors`:
the same files, the same checks and errors, but the descriptors stay on disk in a :class:`DescriptorRows`, which
reads any range of rows as a new float32 array:

* a ``.npy`` array is opened memory-mapped by :func:`vpr_uncertainty.data.npy.read_npy` (which checks its header
  and length and never runs code from the file); each block of a C-ordered file is then read from the file into
  a new array at its offset, not through the mapping, because the pages of a mapping count in
  the resident memory of the process while it is mapped: a block read costs one block of memory. A
  Fortran-ordered file is sliced through the mapping instead (its rows are not contiguous);
* the HDF5 descriptor cache (:mod:`vpr_uncertainty.descriptors.cache`) is read by slices of its ``descriptors``
  dataset (float32 or float16 storage), the file opened for each block; the image names are read whole; a block
  holding NaN or infinite values is refused with a ValueError naming the file, the split and the image;
* hloc's global-feature files (:mod:`vpr_uncertainty.descriptors.hloc`, one HDF5 group per image) are read whole.

:func:`~vpr_uncertainty.retrieval.search.search_descriptors` searches a :class:`DescriptorRows` database block by
block (exact search); :func:`vpr_uncertainty.cache.array_digest` hashes it block by block, with the digest of the
same data in memory.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["DEFAULT_BLOCK_BYTES", "DescriptorRows", "default_block_rows", "open_descriptors"]

#: Bytes of float32 descriptors per block when no block size is given (64 MiB: 65,536 rows of dimension 256).
DEFAULT_BLOCK_BYTES = 1 << 26


def default_block_rows(dimension: int) -> int:
    """Rows of float32 descriptors of ``dimension`` that fill :data:`DEFAULT_BLOCK_BYTES` (at least one).

    Examples
    --------
    >>> default_block_rows(256)
    65536
    """
    return max(1, DEFAULT_BLOCK_BYTES // (4 * max(int(dimension), 1)))


class DescriptorRows:
    """A (N, dim) descriptor array on disk (or in memory), read as float32 one range of rows at a time.

    Parameters
    ----------
    read : callable
        ``read(start, stop)`` returns rows ``start:stop`` (0 ≤ start ≤ stop ≤ N) as an array of any numeric dtype.
    shape : tuple of int
        (N, dim).
    source : str
        What the rows are, for messages (usually the file).

    Attributes
    ----------
    shape : tuple of int
    dtype : numpy.dtype
        Always float32: the dtype of the blocks returned by :meth:`read`.
    source : str
    """

    ndim = 2
    dtype = np.dtype(np.float32)

    def __init__(self, read: Callable[[int, int], np.ndarray], shape: tuple[int, int], *, source: str) -> None:
        if len(shape) != 2:
            raise ValueError(f"{source}: descriptors must be 2-D (n_images, dimension), got shape {tuple(shape)}")
        self._read = read
        self.shape = (int(shape[0]), int(shape[1]))
        self.source = source

    @classmethod
    def from_array(cls, array: np.ndarray, *, source: str = "array") -> DescriptorRows:
        """Rows of an array (a :class:`numpy.memmap` is sliced: the pages read stay mapped while it lives)."""
        array = np.asarray(array) if not isinstance(array, np.ndarray) else array
        if array.ndim != 2:
            raise ValueError(f"{source}: descriptors must be 2-D (n_images, dimension), got shape {array.shape}")
        return cls(lambda start, stop: array[start:stop], array.shape, source=source)

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return f"DescriptorRows({self.source}, shape={self.shape})"

    def read(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start:stop`` (clipped to the array) as a new float32 C-ordered array that the caller owns."""
        start, stop = max(int(start), 0), min(int(stop), self.shape[0])
        if stop <= start:
            return np.empty((0, self.shape[1]), dtype=np.float32)
        block = self._read(start, stop)
        if isinstance(block, np.memmap) or not block.flags.owndata:
            return np.array(block, dtype=np.float32, order="C")  # a view of the caller's array or of a mapping
        return np.require(block, np.float32, ["C_CONTIGUOUS", "WRITEABLE"])  # a new block: no second copy

    def row_blocks(self, rows: int | None = None) -> Iterator[np.ndarray]:
        """Consecutive blocks of ``rows`` rows (by default :func:`default_block_rows`), each a new float32 array."""
        rows = default_block_rows(self.shape[1]) if rows is None else int(rows)
        if rows < 1:
            raise ValueError(f"rows must be a positive integer, got {rows!r}")
        for start in range(0, self.shape[0], rows):
            yield self.read(start, start + rows)

    def to_array(self) -> np.ndarray:
        """All rows in memory, as a new float32 array."""
        return self.read(0, self.shape[0])

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        array = self.to_array()
        return array if dtype is None else array.astype(dtype, copy=False)


def _open_npy(path: Path) -> DescriptorRows:
    from vpr_uncertainty.data.npy import read_npy

    array = read_npy(path, what="a descriptor array of shape (n_images, dimension)", mmap=True)
    if array.dtype.kind not in "biuf":
        raise ValueError(f"{path} is not a numeric descriptor array (it holds dtype {array.dtype})")
    if array.ndim != 2:
        raise ValueError(f"{path}: descriptors must be 2-D (n_images, dimension), got shape {array.shape}")
    if not isinstance(array, np.memmap) or not array.flags.c_contiguous:
        return DescriptorRows.from_array(array, source=str(path))  # empty, or Fortran-ordered: sliced
    shape, dtype, offset = array.shape, array.dtype, int(array.offset)  # a fresh mapping of the whole file
    dimension = shape[1]
    row_bytes = dimension * dtype.itemsize
    del array

    def read(start: int, stop: int) -> np.ndarray:
        block = np.empty((stop - start, dimension), dtype=dtype)
        with path.open("rb") as handle:
            handle.seek(offset + start * row_bytes)
            count = handle.readinto(memoryview(block).cast("B"))
        if count != block.nbytes:
            raise ValueError(f"{path} changed while it was read: rows {start}–{stop - 1} are no longer all there")
        return block

    return DescriptorRows(read, shape, source=str(path))


def _open_cache(path: Path, split: str) -> tuple[np.ndarray, DescriptorRows]:
    """Names and lazily read rows of one split of the descriptor cache, checked as ``read_descriptors`` does
    (payload checksum included: one pass over the rows when the file is opened)."""
    from vpr_uncertainty.descriptors._checks import check_finite, verify_split
    from vpr_uncertainty.descriptors.cache import _import_h5py, split_layout

    h5py = _import_h5py()
    names, count, dimension = split_layout(path, split, stacklevel=3)
    with h5py.File(path, "r") as handle:  # the payload checksum, one block of rows at a time
        verify_split(path, handle[split], split, count)
    if count == 0:
        return names, DescriptorRows.from_array(np.empty((0, 0), np.float32), source=str(path))

    def read(start: int, stop: int) -> np.ndarray:
        with h5py.File(path, "r") as block_handle:
            block = block_handle[split]["descriptors"][start:stop]
        check_finite(path, split, block, names, first_row=start)  # naming the file, not only "database row i"
        return block

    return names, DescriptorRows(read, (count, dimension), source=f"{path} ({split})")


def open_descriptors(path: str | Path, split: str | None = None) -> tuple[np.ndarray | None, DescriptorRows]:
    """Open a descriptor file without reading its descriptors: rows are read later, one block at a time.

    The same files and errors as :func:`~vpr_uncertainty.retrieval.readers.load_descriptors`; only hloc's files
    are read whole (one HDF5 group per image has no rows to slice).

    Parameters
    ----------
    path : str or Path
        ``.npy`` array (N × dim, memory-mapped), descriptor cache ``.h5`` / ``.hdf5``, or hloc's global features.
    split : {"database", "queries"}, optional
        Which images to read from an HDF5 file; required for ``.h5``, ignored for ``.npy``.

    Returns
    -------
    names : ndarray of str of shape (N,), or None
        Image names (from an HDF5 file; None for ``.npy``).
    rows : DescriptorRows
        The descriptors, read as float32 on demand.

    Raises
    ------
    FileNotFoundError
        When ``path`` is not a file.
    ValueError
        For another suffix, a ``.h5`` without a valid ``split``, an unreadable file or an array that is not 2-D.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> np.save(folder / "db.npy", np.arange(6, dtype=np.float64).reshape(3, 2))
    >>> names, rows = open_descriptors(folder / "db.npy")
    >>> rows.shape, rows.read(1, 3)
    ((3, 2), array([[2., 3.],
           [4., 5.]], dtype=float32))
    """
    from vpr_uncertainty.retrieval.readers import DESCRIPTOR_SPLITS, DESCRIPTOR_SUFFIXES

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"descriptor file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return None, _open_npy(path)
    if suffix not in (".h5", ".hdf5"):
        raise ValueError(
            f"unsupported descriptor file {path}: expected one of {', '.join(DESCRIPTOR_SUFFIXES)} "
            "(a .npy array of shape (N, dim) or the HDF5 descriptor cache)"
        )
    if split not in DESCRIPTOR_SPLITS:
        raise ValueError(f"reading the descriptor cache {path} needs split in {DESCRIPTOR_SPLITS}, got {split!r}")
    from vpr_uncertainty.descriptors.hloc import is_hloc_file, read_hloc_descriptors

    if is_hloc_file(path):
        names, array = read_hloc_descriptors(path, split)
        return np.asarray(names, dtype=str), DescriptorRows.from_array(np.asarray(array), source=str(path))
    return _open_cache(path, split)
