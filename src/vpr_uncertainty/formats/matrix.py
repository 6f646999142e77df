"""Full (queries × database) similarity or distance matrices in ``.npy`` (plain, or VPR-Bench's precomputed matches),
and descriptor files (plain ``.npy`` arrays, hloc's HDF5, the toolkit's descriptor cache), read without running code
from them and one block of rows at a time."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty.formats.ground_truth import load_ground_truth, read_npy
from vpr_uncertainty.formats.hloc import is_hloc_file, read_hloc_descriptors
from vpr_uncertainty.retrieval.blocks import DescriptorRows, MappedRows, top_k_blocks
from vpr_uncertainty.retrieval.result import Retrieval, check_positive_int

DESCRIPTOR_SPLITS: tuple[str, ...] = ("database", "queries")
DESCRIPTOR_SUFFIXES: tuple[str, ...] = (".npy", ".h5", ".hdf5")


def read(
    path: Path,
    *,
    ground_truth: str | Path | None,
    top_k: int,
    file_format: str = "auto",
    scores: str = "similarity",
    pool: bool = False,
    **_: Any,
) -> Retrieval:
    """The top-k of a matrix file with its ground truth (``pool``: or without, as ``calibrate`` and ``label`` read a
    pool: no positives, ``config["n_database"]``); distances (``scores``, a kind of
    :data:`~vpr_uncertainty.retrieval.result.SCORE_KINDS`) converted by :meth:`Retrieval.from_distances`."""
    from vpr_uncertainty.evaluation.metrics import positives_against_mean

    if ground_truth is None and not pool:
        raise ValueError(
            f"{path} is a similarity matrix without ground truth; give the ground truth (argument ground_truth)"
        )
    higher_is_better = scores == "similarity"
    read: dict[str, Any] = {"ordering": [0, 0], "largest": 0.0, "positives": None}  # positives above / below ...

    def measure(block: np.ndarray, first_row: int, shape: tuple[int, int]) -> None:
        if not higher_is_better and np.isfinite(block).any():
            read["largest"] = max(read["largest"], float(block[np.isfinite(block)].max()))
        if ground_truth is None:
            return
        if first_row == 0:  # sized by the matrix: a positive beyond its columns is an error naming the file
            read["positives"] = _fitting_ground_truth(ground_truth, path, block, shape)
        rows, columns = read["positives"][first_row : first_row + len(block)].nonzero()
        for side, count in enumerate(positives_against_mean(block if higher_is_better else -block, rows, columns)):
            read["ordering"][side] += count  # ... their row's mean

    # Memory-mapped and cut to its top-k one block of queries at a time: never the whole matrix in memory.
    top, indices, shape = read_similarity_top_k(
        path, top_k, file_format=file_format, higher_is_better=higher_is_better, on_block=measure
    )
    config: dict[str, Any] = {"source": str(path), "top_k": int(top.shape[1]), "n_database": shape[1]}
    if ground_truth is not None:
        config.update(ground_truth=str(ground_truth), positives_vs_mean=read["ordering"])
    if higher_is_better:
        return Retrieval(scores=top, indices=indices, positives=read["positives"], config=config)
    kind, largest, positives = scores, read["largest"], read["positives"]
    return Retrieval.from_distances(-top, indices, kind=kind, largest=largest, positives=positives, config=config)


def _fitting_ground_truth(ground_truth: str | Path, path: Path, block: np.ndarray, shape: tuple[int, int]) -> Any:
    """The ground truth sized by the (Q, D) matrix of ``path``; when it does not fit, the error says what the shape
    suggests: a transposed (database × queries) matrix, or a (queries × k) array of top-k scores (sorted rows)."""
    try:
        return load_ground_truth(ground_truth, n_queries=shape[0], n_database=shape[1])
    except ValueError as error:
        queries, database = load_ground_truth(ground_truth).shape  # its own size (or the error of reading it)
        steps, shown = np.diff(block, axis=1), f"{path} is {shape[0]} × {shape[1]} (queries × database)"
        if queries == shape[1] != shape[0] and database <= shape[0]:
            why = f"looks transposed (database × queries; the ground truth holds {queries} queries): save matrix.T"
        elif queries == shape[0] and database > shape[1] and ((steps <= 0).all() or (steps >= 0).all()):
            why = "looks like top-k scores (sorted rows, and the ground truth names database images up to "
            why += f"{database - 1}): give the whole matrix, or a retrieval file (.npz) with the candidates' indices"
        else:
            raise
        raise ValueError(f"{shown}: it {why} ({error})") from None


_MATRIX = "a numeric (queries × database) similarity matrix"


def _check_similarity_shape(matrix: np.ndarray, path: Path) -> np.ndarray:
    """Dtype and shape of a similarity matrix read (or memory-mapped) from ``path``."""
    if matrix.dtype.kind not in "iuf":
        raise ValueError(f"{path}: a similarity matrix must hold integers or floats, got dtype {matrix.dtype}")
    if matrix.ndim != 2:
        raise ValueError(f"{path}: a similarity matrix must be 2-D (queries × database), got shape {matrix.shape}")
    if matrix.shape[0] == 0 or matrix.shape[1] == 0:
        raise ValueError(f"{path}: the similarity matrix is empty (shape {matrix.shape}); expected queries × database")
    return matrix


def _check_similarity_values(
    block: np.ndarray, path: Path, first_row: int = 0, *, higher_is_better: bool = True
) -> None:
    """No NaN or +inf in rows ``first_row`` … of a similarity matrix; -inf (no candidate) is allowed. For a distance
    matrix (``higher_is_better=False``) the other way round: no NaN or -inf; +inf marks no candidate."""
    # NaN when any value is NaN; one pass, no temporary the size of the block
    extreme = block.max() if higher_is_better else block.min()
    wrong_infinity = np.inf if higher_is_better else -np.inf
    if np.isnan(extreme) or extreme == wrong_infinity:
        bad = np.isnan(block) | (block == wrong_infinity)
        row, column = (int(i) for i in np.argwhere(bad)[0])
        rows, count = first_row + np.unique(bad.nonzero()[0]), int(bad.sum())  # name the queries, not the block
        listed = ", ".join(map(str, rows[:5])) + (", ..." if rows.size > 5 else "")
        where = f"all in query {rows[0]}" if rows.size == 1 else f"in {rows.size} queries: {listed}"
        where = f"{count} such value{'s' * (count > 1)} among queries {first_row}–{first_row + len(block) - 1}, {where}"
        matrix, what, missing = (
            ("similarity", "similarities", "-inf") if higher_is_better else ("distance", "distances", "+inf")
        )
        raise ValueError(
            f"{path}: the {matrix} matrix holds {block[row, column]} at query {first_row + row}, database image "
            f"{column} ({where}); expected finite "
            f"{what} ({missing} marks a database image that is no candidate)"
        )


def _open_similarity(path: Path, file_format: str, *, mmap: bool) -> np.ndarray:
    """The matrix of ``path`` with dtype and shape checked (values not yet); memory-mapped when ``mmap``."""
    if not is_regular_file(path, "a similarity matrix"):
        raise FileNotFoundError(f"similarity file not found: {path}")
    if file_format == "vprbench":
        return _check_similarity_shape(load_vprbench_similarity(path), path)
    if file_format == "matrix":
        what = f"{_MATRIX} (VPR-Bench's precomputed matches are read with format 'vprbench' or 'auto')"
        return _check_similarity_shape(read_npy(path, what=what, mmap=mmap), path)
    what = f"{_MATRIX} or VPR-Bench precomputed matches (an object array of 6 items)"
    matrix = read_npy(path, what=what, allow_objects=True, mmap=mmap)
    if matrix.dtype == object:
        if matrix.shape != (6,):
            raise ValueError(f"{path} holds Python objects (an object array of shape {matrix.shape}); expected {what}")
        return _check_similarity_shape(load_vprbench_similarity(path), path)
    return _check_similarity_shape(matrix, path)


def load_similarity_matrix(path: str | Path, *, file_format: str = "auto") -> np.ndarray:
    """Read a whole (queries × database) similarity matrix, higher = more similar, from ``.npy`` (plain or VPR-Bench's).

    ``file_format``: ``"matrix"``, ``"vprbench"`` or ``"auto"`` (whichever the file is; VPR-Bench's object arrays are
    read without running code from the file). Returns a (Q, D) integer or float array, Q, D ≥ 1, without NaN or
    +inf (``-inf`` marks a database image that is no candidate). Raises FileNotFoundError for a missing file and
    ValueError naming the file (and the query) for an empty, truncated, foreign or malformed one.
    """
    path = Path(path)
    matrix = _open_similarity(path, file_format, mmap=False)
    _check_similarity_values(matrix, path)
    return matrix


def read_similarity_top_k(
    path: str | Path,
    top_k: int,
    *,
    file_format: str = "auto",
    block_rows: int | None = None,
    higher_is_better: bool = True,
    on_block: Callable[[np.ndarray, int, tuple[int, int]], None] | None = None,
) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """The top-k of every query of a similarity matrix file, memory-mapped and read one block of queries at a time.

    Peak memory is the (Q × k) result plus one block (``block_rows`` queries, by default about 4 M values); values are
    checked block by block with the errors of :func:`load_similarity_matrix`; VPR-Bench's legacy files are read whole.
    Returns scores and indices of shape (Q, min(top_k, D)) as :func:`~vpr_uncertainty.retrieval.top_k_from_similarity`
    does, and the matrix's shape (Q, D). ``higher_is_better=False``: the file holds distances; the k nearest are
    returned with their distances negated (the scores of a Retrieval are higher = better). ``on_block(block,
    first_row, shape)`` sees every block of values as stored, once checked.
    """
    path = Path(path)
    matrix = _open_similarity(path, file_format, mmap=True)
    check_positive_int(top_k, "top_k")
    shape = (int(matrix.shape[0]), int(matrix.shape[1]))

    def check_block(block: np.ndarray, first_row: int) -> None:
        _check_similarity_values(block, path, first_row, higher_is_better=higher_is_better)
        if on_block is not None:
            on_block(block, first_row, shape)

    if isinstance(matrix, np.memmap) and matrix.flags.c_contiguous:
        matrix = MappedRows(matrix)  # one mapping per block: read pages do not pile up in resident memory
    scores, indices = top_k_blocks(
        matrix, top_k, block_rows=block_rows, check_block=check_block, higher_is_better=higher_is_better
    )
    return scores, indices, shape


_MATCHES = (
    "VPR-Bench precomputed matches (an object array of 6 items: query indices, top-1 indices, top-1 scores, "
    "similarity matrix, encoding time, matching time)"
)


def load_vprbench_similarity(path: str | Path) -> np.ndarray:
    """The (Q, D) float32 similarity matrix of VPR-Bench's ``precomputed_data_corrected.npy``.

    The file holds [query indices, top-1 indices, top-1 scores, similarity matrix, encoding time, matching time],
    read without running code from it; another layout raises a ValueError naming the file.
    """
    path = Path(path)
    content = read_npy(path, what=_MATCHES, allow_objects=True)
    if content.dtype != object:
        raise ValueError(
            f"{path} is a plain {content.dtype} array of shape {content.shape}, not {_MATCHES}; "
            "read it as a similarity matrix (format 'matrix')"
        )
    if content.shape != (6,):
        raise ValueError(f"{path}: expected {_MATCHES}, got an object array of shape {content.shape}")
    similarity = content[3]
    if not isinstance(similarity, np.ndarray) or similarity.dtype.kind not in "iuf" or similarity.ndim != 2:
        found = (
            f"a {similarity.dtype} array of shape {similarity.shape}"
            if isinstance(similarity, np.ndarray)
            else type(similarity).__name__
        )
        raise ValueError(f"{path}: item 3 should be the numeric (queries × database) similarity matrix, got {found}")
    order = content[0]
    # Some of VPR-Bench's own files (ap-gem-r101) store the query indices as floats 0.0, 1.0, ...: compared exactly.
    if not isinstance(order, np.ndarray) or order.dtype.kind not in "iuf" or order.ndim != 1:
        raise ValueError(f"{path}: item 0 should be the query indices 0..{similarity.shape[0] - 1}, got {order!r:.80}")
    if len(order) != similarity.shape[0] or not np.array_equal(order, np.arange(len(order))):
        raise ValueError(f"{path}: expected query indices 0..{similarity.shape[0] - 1} in order")
    return similarity.astype(np.float32)


def _descriptor_file(path: str | Path, split: str | None) -> tuple[Path, bool]:
    """The path of an existing descriptor file and whether it is HDF5 (which needs a valid ``split``)."""
    path = Path(path)
    if not is_regular_file(path, "a descriptor file"):
        raise FileNotFoundError(f"descriptor file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return path, False
    if suffix not in (".h5", ".hdf5"):
        raise ValueError(
            f"unsupported descriptor file {path}: expected one of {', '.join(DESCRIPTOR_SUFFIXES)} "
            "(a .npy array of shape (N, dim) or the HDF5 descriptor cache)"
        )
    if split not in DESCRIPTOR_SPLITS:
        raise ValueError(f"reading the descriptor cache {path} needs split in {DESCRIPTOR_SPLITS}, got {split!r}")
    return path, True


def _read_npy_descriptors(path: Path, *, mmap: bool) -> np.ndarray:
    """The numeric 2-D array of a ``.npy`` descriptor file (memory-mapped when ``mmap``)."""
    array = read_npy(path, what="a descriptor array of shape (n_images, dimension)", mmap=mmap)
    if array.dtype.kind not in "biuf":
        raise ValueError(f"{path} is not a numeric descriptor array (it holds dtype {array.dtype})")
    if array.ndim != 2:
        raise ValueError(f"{path}: descriptors must be 2-D (n_images, dimension), got shape {array.shape}")
    return array


def load_descriptors(path: str | Path, split: str | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """Read descriptors from a ``.npy`` array (N × dim), the HDF5 descriptor cache or hloc's global features.

    Parameters
    ----------
    path : str or Path
        ``.npy`` file (read without running code from it), descriptor cache ``.h5`` / ``.hdf5`` written by the
        feature extraction, or hloc's global features (:mod:`vpr_uncertainty.formats.hloc`).
    split : {"database", "queries"}, optional
        Which images to read from an HDF5 file; required for ``.h5``, ignored for ``.npy``. An hloc file whose
        names carry no split prefix (``query/``, ``db/``, ...) is read whole.

    Returns
    -------
    names : ndarray of str of shape (N,), or None
        Image names (None for ``.npy``).
    descriptors : ndarray of shape (N, dim), float32
        A new array owned by the caller (it may be normalised in place).

    Raises
    ------
    FileNotFoundError
        When ``path`` is not a file.
    ValueError
        For another suffix, a ``.h5`` without a valid ``split``, an unreadable file or an array that is not 2-D.
    """
    path, hdf5 = _descriptor_file(path, split)
    if not hdf5:  # the readers check the shape: (N, dim), one name per row
        return None, np.ascontiguousarray(_read_npy_descriptors(path, mmap=False), dtype=np.float32)
    from vpr_uncertainty.descriptors.cache import read_descriptors  # imported here: h5py only when needed

    names, array = (read_hloc_descriptors if is_hloc_file(path) else read_descriptors)(path, split)
    return np.asarray(names, dtype=str), np.ascontiguousarray(array, dtype=np.float32)


def open_descriptors(path: str | Path, split: str | None = None) -> tuple[np.ndarray | None, DescriptorRows]:
    """Open a descriptor file without reading its descriptors: rows are read later, one block at a time.

    The same files, arguments and errors as :func:`load_descriptors`; the rows stay on disk in a
    :class:`~vpr_uncertainty.retrieval.DescriptorRows` (hloc's files are read whole: no rows to slice).

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
    path, hdf5 = _descriptor_file(path, split)
    if not hdf5:
        return None, _open_npy(path)
    if is_hloc_file(path):
        names, array = read_hloc_descriptors(path, split)
        return np.asarray(names, dtype=str), DescriptorRows.from_array(np.asarray(array), source=str(path))
    return _open_cache(path, split)


def _open_npy(path: Path) -> DescriptorRows:
    """Rows of a ``.npy`` file: each block of a C-ordered file read from the file at its offset (not through a
    mapping, whose pages would count in resident memory); a Fortran-ordered one sliced through the mapping."""
    array = _read_npy_descriptors(path, mmap=True)
    if not isinstance(array, np.memmap) or not array.flags.c_contiguous:
        return DescriptorRows.from_array(array, source=str(path))  # empty, or Fortran-ordered: sliced
    shape, dtype, offset = array.shape, array.dtype, int(array.offset)  # a fresh mapping of the whole file
    dimension, row_bytes = shape[1], shape[1] * dtype.itemsize
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
    import h5py

    from vpr_uncertainty.descriptors.cache import check_finite, split_layout, verify_split

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
