"""Read a ``.npy`` file with one clear error for every way it can be wrong, and never run its code.

:func:`read_npy` checks the magic bytes, the header and the data length before reading, so an empty, truncated
or foreign file (a text file, a ``.npz`` archive renamed ``.npy``) gives a ``ValueError`` that names the file and
says what was expected, instead of an ``EOFError`` or an ``UnpicklingError``. Object arrays are refused unless
the caller allows them; then their pickled payload is read with
:func:`~vpr_uncertainty.data.legacy_pickle.restricted_unpickle`, which can rebuild arrays, numbers, strings and
lists but runs nothing the file names. A file that cannot be mapped or read for lack of memory or address space
(``ulimit -v``) raises a :class:`MemoryError` naming it and its size.
"""

from __future__ import annotations

import errno
import math
from pathlib import Path

import numpy as np
from numpy.lib import format as npy_format

from vpr_uncertainty.data.legacy_pickle import restricted_unpickle

__all__ = ["read_npy"]

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
    """Read one array from a ``.npy`` file.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What the caller expects the file to hold, for error messages (e.g. "a similarity matrix").
    allow_objects : bool
        Accept object arrays (read with the restricted unpickler); by default they are an error.
    mmap : bool
        Return a read-only :class:`numpy.memmap` of a numeric array instead of reading its data, after the same
        checks (object arrays and empty arrays are read whole).

    Returns
    -------
    ndarray
        The array, of the shape and dtype in the header.

    Raises
    ------
    FileNotFoundError
        When the file does not exist.
    ValueError
        When the file is empty, truncated, not a ``.npy`` file, an object array (unless allowed) or holds pickled
        data other than arrays, numbers, strings and builtin containers.
    MemoryError
        When the process cannot map (or read) the whole file: its address-space limit is below its size.
    """
    path = Path(path)
    if not path.is_file():
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
    """The array of the open file ``handle`` (at its start), memory-mapped whole when ``mmap``.

    Mapping needs address space for the whole file (and reading needs memory for it): when the process cannot get
    it (``ulimit -v`` below the file's size, or memory exhausted), a :class:`MemoryError` names the file, its size
    and what to do, instead of ``[Errno 12] Cannot allocate memory`` alone.
    """
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
