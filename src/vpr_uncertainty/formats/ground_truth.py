"""Ground truth files, and .npy files read safely (VPR-Bench's legacy object arrays included)."""

from __future__ import annotations

import errno
import json
import math
import pickle
import re
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.lib import format as npy_format
from scipy import sparse

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty.retrieval.result import (
    check_n_database,
    is_index,
    positives_from_csr,
    positives_from_lists,
    positives_from_mask,
    read_npz,
)

_INTEGER_FIELD = re.compile(r"[+-]?[0-9]+")
#: What VPR-Bench's ``ground_truth_new.npy`` holds, for error messages.
VPRBENCH_GROUND_TRUTH = (
    "VPR-Bench ground truth (an object array of rows [query index, list of positive database indices])"
)


def positives_from_vprbench_rows(rows: np.ndarray, path: str | Path, *, n_database: int | None) -> sparse.csr_array:
    """Positives from VPR-Bench's rows [query index, positive indices (list, array or int)]; errors name ``path``.

    The query indices must be a permutation of 0..Q-1; ``n_database`` defaults to the largest positive index + 1.
    """
    if not isinstance(rows, np.ndarray) or rows.dtype != object or rows.ndim != 2 or rows.shape[1] != 2:
        found = f"a {rows.dtype} array of shape {rows.shape}" if isinstance(rows, np.ndarray) else type(rows).__name__
        raise ValueError(f"{path}: expected {VPRBENCH_GROUND_TRUTH} of shape (n_queries, 2), got {found}")
    n_queries = len(rows)
    lists: list[object | None] = [None] * n_queries
    for row, (query, positives) in enumerate(rows):
        if not is_index(query) or not 0 <= query < n_queries:
            raise ValueError(
                f"{path}: row {row}: the query index must be an integer in [0, {n_queries}), got {query!r}"
            )
        if lists[query] is not None:
            raise ValueError(
                f"{path}: row {row}: query {query} appears twice; expected each of 0..{n_queries - 1} once"
            )
        lists[query] = [positives] if is_index(positives) else positives
    return positives_from_lists(lists, n_database, source=path)  # errors name the file, the query and the value


def positives_to_lists(positives: sparse.csr_array) -> list[np.ndarray]:
    """One sorted int64 array of positive database indices per query."""
    positives = sparse.csr_array(positives)
    positives.sort_indices()
    return [
        positives.indices[positives.indptr[q] : positives.indptr[q + 1]].astype(np.int64)
        for q in range(positives.shape[0])
    ]


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path} is not a UTF-8 text file; expected ground truth as text") from None


def _from_text(path: Path, n_database: int | None) -> sparse.csr_array:
    lists = []
    for line_number, line in enumerate(_read_text(path).splitlines(), start=1):
        fields = line.replace(",", " ").split()
        bad = next((field for field in fields if not _INTEGER_FIELD.fullmatch(field)), None)
        if bad is not None:
            raise ValueError(
                f"{path}:{line_number}: expected integer database indices (line {line_number} = query "
                f"{line_number - 1}), got {bad!r} in {line!r}"
            )
        lists.append([int(field) for field in fields])
    return positives_from_lists(lists, n_database, source=path)


def _from_json(path: Path, n_database: int | None) -> sparse.csr_array:
    try:
        content = json.loads(_read_text(path))
    except json.JSONDecodeError as error:
        raise ValueError(f"{path} is not valid JSON ({error}); expected a list of lists of database indices") from None
    except RecursionError:
        raise ValueError(
            f"{path}: the JSON is nested too deeply to read; expected a list of lists of database indices"
        ) from None
    lists = content.get("positives") if isinstance(content, dict) else content
    if not isinstance(lists, list) or not all(isinstance(item, list) for item in lists):
        raise ValueError(f"{path}: expected a JSON list of lists of database indices (one list per query)")
    return positives_from_lists(lists, n_database, source=path)


def _from_npz(path: Path, n_database: int | None) -> sparse.csr_array:
    arrays = read_npz(path, "ground truth in a .npz archive (positives_indptr, positives_indices, n_database)")
    try:
        positives = positives_from_csr(arrays, n_database=n_database)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    if positives is None:
        found = ", ".join(sorted(arrays))
        raise ValueError(f"{path} has no ground truth: expected positives_indptr and positives_indices, found {found}")
    return positives


def _from_npy(path: Path, n_database: int | None) -> sparse.csr_array:
    array = read_npy(
        path, what="ground truth (a boolean mask or VPR-Bench's object array of positives)", allow_objects=True
    )
    if array.dtype == object:
        return positives_from_vprbench_rows(array, path, n_database=n_database)
    return positives_from_mask(array, source=path)


def load_ground_truth(
    path: str | Path, *, n_queries: int | None = None, n_database: int | None = None
) -> sparse.csr_array:
    """Read ground truth, one row of positive database indices per query, from a file in any supported format.

    * ``.npy``: a boolean (Q × D) mask (0/1 numbers accepted), or VPR-Bench's ``ground_truth_new.npy`` (an object
      array read without running code from the file);
    * ``.npz``: ``positives_indptr``, ``positives_indices`` (and ``n_database``), the layout of retrieval files;
    * ``.json``: a list of lists of indices (or ``{"positives": ...}``);
    * ``.txt`` / ``.csv`` / ``.tsv``: one line of whitespace- or comma-separated indices per query.

    Parameters
    ----------
    path : str or Path
    n_queries, n_database : int, optional
        Expected shape: sizes the matrix of list formats, checked against the others.

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool

    Raises
    ------
    FileNotFoundError
        When the file does not exist.
    ValueError
        Naming the file (and the query and value at fault) when it is empty or no regular file (a FIFO, a device),
        cannot be read, holds anything but integer
        database indices in range (or a 0/1 mask), or does not match the expected shape.
    """
    path = Path(path)
    if not is_regular_file(path, "ground truth"):
        raise FileNotFoundError(f"ground truth file not found: {path}")
    if path.stat().st_size == 0:
        raise ValueError(f"{path} is empty (0 bytes); expected ground truth, one row of positives per query")
    n_database = None if n_database is None else check_n_database(n_database)
    suffix = path.suffix.lower()
    text = dict.fromkeys((".txt", ".csv", ".tsv"), _from_text)
    reader = {".npy": _from_npy, ".npz": _from_npz, ".json": _from_json, **text}.get(suffix)
    if reader is None:
        raise ValueError(
            f"unknown ground truth format {suffix!r} for {path}; expected .npy (boolean mask or VPR-Bench), "
            ".npz, .json or .txt/.csv"
        )
    positives = reader(path, n_database)
    if n_queries is not None and positives.shape[0] != n_queries:
        raise ValueError(f"ground truth {path} has {positives.shape[0]} queries, expected {n_queries}")
    if n_database is not None and positives.shape[1] != n_database:
        raise ValueError(
            f"ground truth {path} covers {positives.shape[1]} database images, expected {n_database} "
            "(a mask needs one column per database image)"
        )
    return positives


def load_vprbench_ground_truth(path: str | Path, *, n_database: int | None = None) -> sparse.csr_array:
    """Read VPR-Bench's ``ground_truth_new.npy`` (rows of [query index, positives]) as a (Q, D) boolean csr_array.

    Nothing from the file runs (see :func:`restricted_unpickle`); ``n_database`` defaults to the largest positive + 1.
    """
    path = Path(path)
    rows = read_npy(path, what=VPRBENCH_GROUND_TRUTH, allow_objects=True)
    return positives_from_vprbench_rows(rows, path, n_database=n_database)


def read_positions(path: str | Path | None, *, expected: int, name: str) -> np.ndarray | None:
    """Positions (n, m) or (n,) from a ``.npy`` file (by :func:`read_npy`: nothing in it runs) with ``expected`` rows,
    one per image, or a ValueError naming the file and ``name``; None without a file."""
    if path is None:
        return None
    array = read_npy(path, what=f"{name}, a numeric array with one row per image")
    if array.ndim not in (1, 2) or not np.issubdtype(array.dtype, np.number) or len(array) != expected:
        raise ValueError(
            f"{path}: {name} must have shape ({expected}, 2) or ({expected},), one row per image; "
            f"got {array.dtype} of shape {array.shape}"
        )
    return array


_MAGIC = b"\x93NUMPY"
_ZIP_MAGIC = b"PK"


def _describe(head: bytes) -> str:
    if head.startswith(_ZIP_MAGIC):
        return "a zip archive (an .npz?)"
    if head.lstrip()[:1] in (b"[", b"{"):
        return "text (JSON?)"
    try:
        head.decode("utf-8")
    except UnicodeDecodeError:
        return "binary data of another format"
    return "text"


def read_npy(path: str | Path, *, what: str, allow_objects: bool = False, mmap: bool = False) -> np.ndarray:
    """Read one array from a ``.npy`` file, with one clear error for every way it can be wrong, never running its code.

    The magic bytes, header and data length are checked first, so an empty, truncated or foreign file gives a
    ``ValueError`` naming the file and ``what`` was expected. Object arrays are refused unless ``allow_objects``;
    then they are read by :func:`restricted_unpickle`. ``mmap`` returns a read-only :class:`numpy.memmap` of a
    numeric array (empty and object arrays are read whole). A file that cannot be mapped or read for lack of memory
    or address space (``ulimit -v``) raises a :class:`MemoryError` naming it and its size.
    """
    path = Path(path)
    if not is_regular_file(path, what):
        raise FileNotFoundError(f"file not found: {path} (expected {what})")
    file_size = path.stat().st_size
    if file_size == 0:
        raise ValueError(f"{path} is empty (0 bytes); expected {what} in a NumPy .npy file")
    with path.open("rb") as handle:
        head = handle.read(len(_MAGIC))
        if head != _MAGIC:
            if _MAGIC.startswith(head):
                raise ValueError(f"{path} is truncated ({file_size} bytes, not even a .npy header); expected {what}")
            raise ValueError(f"{path} is not a NumPy .npy file (it holds {_describe(head)}); expected {what}")
        handle.seek(0)
        try:
            version = npy_format.read_magic(handle)
            if version == (1, 0):
                shape, _, dtype = npy_format.read_array_header_1_0(handle)
            elif version == (2, 0):
                shape, _, dtype = npy_format.read_array_header_2_0(handle)
            else:  # format 3.0 (utf-8 field names): never used for object arrays; let NumPy read it all
                handle.seek(0)
                return _read_data(handle, path, what, mmap=mmap)
        except ValueError as error:
            message = str(error)
            if message.startswith("EOF"):
                raise ValueError(f"{path} is truncated: its .npy header is incomplete; expected {what}") from None
            raise ValueError(f"{path} has an invalid .npy header ({message}); expected {what}") from None
        if dtype.hasobject:
            if not allow_objects:
                raise ValueError(
                    f"{path} holds Python objects (an object array of shape {shape}), not numbers; expected {what}"
                )
            return _read_object_array(handle, path, shape)
        expected = math.prod(shape) * dtype.itemsize
        available = file_size - handle.tell()
        if available < expected:
            raise ValueError(
                f"{path} is truncated: its header announces a {dtype} array of shape {shape} ({expected} bytes of "
                f"data) but only {available} bytes follow; expected {what}"
            )
        handle.seek(0)
        return _read_data(handle, path, what, mmap=mmap and expected > 0)  # mmap cannot map zero bytes


def _read_data(handle, path: Path, what: str, *, mmap: bool) -> np.ndarray:
    """The array of the open file ``handle`` (at its start), memory-mapped when ``mmap``; MemoryError names the file."""
    try:
        if mmap:
            return npy_format.open_memmap(path, mode="r")
        return npy_format.read_array(handle, allow_pickle=False)
    except (MemoryError, OSError) as error:
        if isinstance(error, OSError) and error.errno != errno.ENOMEM:
            raise
        size = path.stat().st_size / 2**30
        how = "map" if mmap else "read"
        raise MemoryError(
            f"{path}: cannot {how} the {size:.2f} GiB file holding {what} ({_reason(error)}): this process's "
            "memory or address-space limit (ulimit -v) is below its size; raise the limit (or free memory); a "
            "similarity matrix can also be given as the top-k of each query (a retrieval .npz)"
        ) from error


def _reason(error: BaseException) -> str:
    if isinstance(error, OSError) and error.strerror:
        return f"[Errno {error.errno}] {error.strerror}"
    return str(error) or type(error).__name__


def _read_object_array(handle, path: Path, shape: tuple[int, ...]) -> np.ndarray:
    array = restricted_unpickle(handle, path)
    if not isinstance(array, np.ndarray) or array.dtype != object or array.shape != tuple(shape):
        found = f"shape {array.shape}, dtype {array.dtype}" if isinstance(array, np.ndarray) else type(array).__name__
        raise ValueError(
            f"{path} is corrupt: its header announces an object array of shape {tuple(shape)} but the data holds "
            f"{found}"
        )
    return array


_MULTIARRAY_MODULES = ("numpy.core.multiarray", "numpy._core.multiarray")
_BUILTIN_MODULES = ("builtins", "__builtin__")


# Plain dtypes only: bool, integers, floats, complex, bytes/str of a fixed size, object references.
_DTYPE_SPEC = re.compile(r"[biufcOSU]\d*")


class UnsafePickleError(ValueError):
    """A pickle names a global other than NumPy array reconstruction or an inert builtin."""


class _NDArrayMarker:
    """Stands in for ``numpy.ndarray``: only accepted as the first argument of ``_reconstruct``."""

    def __repr__(self) -> str:
        return "numpy.ndarray"


_NDARRAY = _NDArrayMarker()


class _PickledDType:
    """Records ``numpy.dtype(spec, align, copy)`` and its ``__setstate__`` instead of building a dtype."""

    __slots__ = ("spec", "state")

    def __init__(self, spec: object, align: object = False, copy: object = False) -> None:
        self.spec = spec
        self.state = None

    def __setstate__(self, state: object) -> None:
        self.state = state


class _PickledArray:
    """Records ``_reconstruct(ndarray, ...)`` and the array state set by the following BUILD."""

    __slots__ = ("state",)

    def __init__(self) -> None:
        self.state = None

    def __setstate__(self, state: object) -> None:
        self.state = state


def _reconstruct(subtype: object, shape: object, typecode: object) -> _PickledArray:
    if subtype is not _NDARRAY:
        raise pickle.UnpicklingError(f"_reconstruct of {subtype!r}: only plain numpy.ndarray is allowed")
    return _PickledArray()


def _scalar(dtype: object, data: object = None) -> object:
    resolved = _make_dtype(dtype)
    if resolved.hasobject:
        raise pickle.UnpicklingError("a NumPy scalar of object dtype is not allowed")
    raw = _raw_bytes(data)
    if len(raw) != resolved.itemsize:
        raise pickle.UnpicklingError(f"a {resolved} scalar needs {resolved.itemsize} bytes, got {len(raw)}")
    return np.frombuffer(raw, dtype=resolved)[0]


_ALLOWED: dict[tuple[str, str], object] = {
    **{(module, "_reconstruct"): _reconstruct for module in _MULTIARRAY_MODULES},
    **{(module, "scalar"): _scalar for module in _MULTIARRAY_MODULES},
    ("numpy", "ndarray"): _NDARRAY,
    ("numpy", "dtype"): _PickledDType,
    **{(module, "set"): set for module in _BUILTIN_MODULES},
    **{(module, "frozenset"): frozenset for module in _BUILTIN_MODULES},
    **{(module, "complex"): complex for module in _BUILTIN_MODULES},
}


class _RestrictedUnpickler(pickle.Unpickler):
    def __init__(self, handle: IO[bytes], path: Path) -> None:
        super().__init__(handle, encoding="latin1")
        self._path = path

    def find_class(self, module: str, name: str) -> Any:
        try:
            return _ALLOWED[(module, name)]
        except KeyError:
            raise UnsafePickleError(
                f"{self._path}: refusing to load the pickled global '{module}.{name}'; a legacy object array may "
                "only hold NumPy arrays, numbers, strings, lists, tuples and dicts"
            ) from None

    def persistent_load(self, pid: object) -> Any:
        raise UnsafePickleError(f"{self._path}: refusing a pickled persistent id; expected plain arrays and lists")


def _raw_bytes(data: object) -> bytes:
    if isinstance(data, str):  # Python 2 str read with encoding="latin1"
        return data.encode("latin1")
    if isinstance(data, (bytes, bytearray)):
        return bytes(data)
    raise pickle.UnpicklingError(f"expected raw array bytes, got {type(data).__name__}")


def _make_dtype(stub: object) -> np.dtype:
    if not isinstance(stub, _PickledDType) or not hasattr(stub, "spec"):
        raise pickle.UnpicklingError(f"expected a dtype, got {type(stub).__name__}")
    spec = stub.spec.decode("latin1") if isinstance(stub.spec, bytes) else stub.spec
    if not isinstance(spec, str) or not _DTYPE_SPEC.fullmatch(spec):
        raise pickle.UnpicklingError(f"dtype {spec!r} is not allowed (only bool, numbers, strings and objects)")
    dtype = np.dtype(spec)
    state = stub.state
    if state is None:
        return dtype
    if not isinstance(state, tuple) or len(state) not in (8, 9) or state[2:5] != (None, None, None):
        raise pickle.UnpicklingError(f"dtype {spec!r}: only plain (unstructured) dtypes are allowed")
    if len(state) == 9 and state[8] not in (None, {}):
        raise pickle.UnpicklingError(f"dtype {spec!r}: dtype metadata is not allowed")
    endian = state[1]
    if endian not in ("<", ">", "|", "="):
        raise pickle.UnpicklingError(f"dtype {spec!r}: invalid byte order {endian!r}")
    return dtype.newbyteorder(endian) if endian in ("<", ">") else dtype


def _check_shape(shape: object) -> tuple[int, ...]:
    if not isinstance(shape, tuple) or not all(
        isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape
    ):
        raise pickle.UnpicklingError(f"invalid array shape {shape!r}")
    return shape


class _Builder:
    """Turns the stand-ins left by the unpickler into real NumPy objects (shared references kept shared)."""

    def __init__(self) -> None:
        self._done: dict[int, object] = {}
        self._keep: list[object] = []  # keeps the ids of the inputs valid while building

    def build(self, obj: object) -> object:
        if obj is None or isinstance(obj, (bool, int, float, complex, str, bytes, np.generic)):
            return obj
        key = id(obj)
        if key in self._done:
            return self._done[key]
        self._keep.append(obj)
        if isinstance(obj, list):
            out: list = []
            self._done[key] = out
            out.extend(self.build(item) for item in obj)
            return out
        if isinstance(obj, dict):
            mapping: dict = {}
            self._done[key] = mapping
            for name, value in obj.items():
                mapping[self.build(name)] = self.build(value)
            return mapping
        if isinstance(obj, tuple):
            result: object = tuple(self.build(item) for item in obj)
        elif isinstance(obj, (set, frozenset)):
            if any(not isinstance(item, (bool, int, float, complex, str, bytes, tuple)) for item in obj):
                raise pickle.UnpicklingError("a pickled set may only hold numbers and strings")
            result = obj
        elif isinstance(obj, bytearray):
            result = bytes(obj)
        elif isinstance(obj, _PickledDType):
            result = _make_dtype(obj)
        elif isinstance(obj, _PickledArray):
            return self._array(obj, key)
        else:
            raise pickle.UnpicklingError(f"unexpected object of type {type(obj).__name__}")
        self._done[key] = result
        return result

    def _array(self, stub: _PickledArray, key: int) -> np.ndarray:
        state = getattr(stub, "state", None)
        if isinstance(state, tuple) and len(state) == 5 and state[0] == 1:
            state = state[1:]
        if not isinstance(state, tuple) or len(state) != 4:
            raise pickle.UnpicklingError("an array without a valid state (version, shape, dtype, order, data)")
        shape, dtype, is_fortran, data = _check_shape(state[0]), _make_dtype(state[1]), state[2], state[3]
        if not isinstance(is_fortran, (bool, int)):
            raise pickle.UnpicklingError(f"invalid array order flag {is_fortran!r}")
        size = math.prod(shape)
        if dtype.hasobject:
            if not isinstance(data, list) or len(data) != size:
                raise pickle.UnpicklingError(f"an object array of shape {shape} needs a list of {size} items")
            # The items come in C order whatever the layout; NumPy keeps a Fortran-ordered array Fortran-ordered.
            array = np.empty(shape, dtype=object, order="F" if is_fortran else "C")
            self._done[key] = array  # registered first: an item may refer back to its array
            items = np.empty(size, dtype=object)
            for index, item in enumerate(data):
                items[index] = self.build(item)  # one element at a time: a list item stays a list
            array[...] = items.reshape(shape)
            return array
        raw = _raw_bytes(data)
        if len(raw) != size * dtype.itemsize:
            raise pickle.UnpicklingError(
                f"a {dtype} array of shape {shape} needs {size * dtype.itemsize} bytes, got {len(raw)}"
            )
        array = np.frombuffer(raw, dtype=dtype).reshape(shape, order="F" if is_fortran else "C")
        # NumPy's own unpickling swaps non-native byte orders to native: do the same.
        array = array.astype(dtype.newbyteorder("="), order="K", copy=True)
        self._done[key] = array
        return array


def restricted_unpickle(handle: IO[bytes], path: str | Path) -> object:
    """Read one pickle allowing only NumPy arrays, numbers, strings and builtin containers (VPR-Bench's object arrays).

    Plain ``pickle.load`` runs whatever callable a file names. Here the only globals resolved are NumPy's array, dtype
    and scalar reconstruction and the builtins ``set``, ``frozenset`` and ``complex``, and even those are stand-ins
    that record their arguments; arrays are then rebuilt with ``np.frombuffer`` (plain dtypes only) or element by
    element (object arrays). Anything else raises :class:`UnsafePickleError` (a ValueError naming the file and the
    global); a truncated or malformed pickle a ValueError. The result equals ``pickle.load(handle, encoding="latin1")``.
    """
    path = Path(path)
    try:
        loaded = _RestrictedUnpickler(handle, path).load()
        return _Builder().build(loaded)
    except UnsafePickleError:
        raise
    except RecursionError:
        raise ValueError(f"{path}: the pickled data is nested too deeply to be a legacy array file") from None
    except Exception as error:  # any malformed pickle: one message naming the file
        if isinstance(error, EOFError) or "truncated" in str(error):
            raise ValueError(f"{path} is truncated: its pickled data ends early") from None
        raise ValueError(f"{path}: cannot read the pickled object array ({type(error).__name__}: {error})") from None
