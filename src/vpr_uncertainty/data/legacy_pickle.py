"""A restricted unpickler for the payload of NumPy *object* arrays (VPR-Bench's legacy files).

VPR-Bench saved its ground truth and precomputed matches as object arrays, whose ``.npy`` payload is a pickle.
Plain ``pickle.load`` runs whatever callable the file names, so a crafted file could run code. This reader
never calls anything the file chooses: the only globals it resolves are NumPy's array, dtype and scalar
reconstruction (``numpy.core.multiarray._reconstruct`` / ``numpy._core.multiarray._reconstruct``,
``numpy.ndarray``, ``numpy.dtype``, ``...multiarray.scalar``) and the inert builtins ``set``, ``frozenset``
and ``complex``, and even those are replaced by stand-ins that only record their arguments. Once the pickle is
read, the stand-ins are turned into real arrays with ``np.frombuffer`` (plain numeric, boolean or string dtypes)
or filled element by element (object arrays); structured, datetime and other dtypes are refused.

Lists, tuples, dicts, strings, bytes, numbers, booleans and None come from pickle opcodes, not globals, and
pass through unchanged. Anything else (``os.system``, ``builtins.eval``, ``numpy.load``, a subclass of
``ndarray``, ...) raises :class:`UnsafePickleError`, a ``ValueError`` naming the file and the global.
"""

from __future__ import annotations

import math
import pickle
import re
from pathlib import Path
from typing import IO, Any

import numpy as np

__all__ = ["UnsafePickleError", "restricted_unpickle"]

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
    """Read one pickle from ``handle`` allowing only NumPy arrays, numbers, strings and builtin containers.

    Parameters
    ----------
    handle : binary file object
        Positioned at the start of the pickle (for a ``.npy`` file: right after the header).
    path : str or Path
        The file's name, for error messages.

    Returns
    -------
    object
        What ``pickle.load(handle, encoding="latin1")`` would return for such data (NumPy arrays rebuilt,
        Python 2 strings decoded as latin-1).

    Raises
    ------
    UnsafePickleError
        When the pickle names any other global (the file's code never runs).
    ValueError
        When the pickle is truncated or malformed.
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
