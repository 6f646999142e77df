"""Files the toolkit writes and trusts: content keys, fingerprints, checksums, atomic writes, checked HDF5 reads.
What each of them hashes or checks: see docs/explanation/caches.md.

Examples
--------
>>> fingerprint("retrieval", {"k": 20}) == fingerprint("retrieval", {"k": 20})
True
>>> fingerprint("retrieval", {"k": 20}) == fingerprint("retrieval", {"k": 10})
False
"""

from __future__ import annotations

import contextlib
import errno
import glob
import hashlib
import io
import json
import os
import re
import socket
import tempfile
import warnings
import zlib
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any, TypeVar

import numpy as np

from vpr_uncertainty._files import open_regular

#: Version of this protocol; part of every fingerprint, so a change of the protocol rebuilds every cache.
PROTOCOL = 1
#: Files up to this size are hashed whole by :func:`content_key`.
FULL_HASH_BYTES = 64 * 2**20
#: Bytes hashed at each end of a larger file.
EDGE_BYTES = 2**20

_T = TypeVar("_T")


class CacheWarning(UserWarning):
    """A cache was truncated, foreign or of an older layout, and is rebuilt (the message names it and why)."""


class ChecksumError(ValueError):
    """An artefact's payload does not match the checksum stored with it (changed on disk after it was written)."""


def content_key(path: str | Path) -> str:
    """A key that changes when the content of the file changes: ``"size:mtime_ns:blake2b"``.

    A file larger than :data:`FULL_HASH_BYTES` gives ``"size:mtime_ns:ctime_ns:blake2b"`` of its two ends.
    Symbolic links are followed; a FIFO, device or socket is refused, never opened (:mod:`vpr_uncertainty._files`).

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
    with open_regular(path) as handle:
        status = os.fstat(handle.fileno())
        if status.st_size <= FULL_HASH_BYTES:
            return f"{status.st_size}:{status.st_mtime_ns}:{hashlib.file_digest(handle, _blake2b).hexdigest()}"
        hasher = _blake2b(handle.read(EDGE_BYTES))
        handle.seek(-EDGE_BYTES, os.SEEK_END)
        hasher.update(handle.read(EDGE_BYTES))
        return f"{status.st_size}:{status.st_mtime_ns}:{_change_time(status)}:{hasher.hexdigest()}"


def _blake2b(data: bytes = b"") -> Any:
    return hashlib.blake2b(data, digest_size=16)


def _change_time(stat: os.stat_result) -> int:
    return stat.st_ctime_ns


def is_partly_hashed(path: str | Path) -> bool:
    """Whether :func:`content_key` hashes only the ends of this file (larger than :data:`FULL_HASH_BYTES`)."""
    return Path(path).stat().st_size > FULL_HASH_BYTES


def file_digest(path: str | Path) -> str:
    """``"blake2b:"`` and the BLAKE2b hash of every byte of a file, whatever its size (read block by block).

    Examples
    --------
    >>> import tempfile
    >>> file = Path(tempfile.mkdtemp()) / "a.txt"
    >>> _ = file.write_text("a")
    >>> file_digest(file) == "blake2b:" + hashlib.blake2b(b"a", digest_size=16).hexdigest()
    True
    """
    with open_regular(path) as handle:
        return "blake2b:" + hashlib.file_digest(handle, _blake2b).hexdigest()


def named_files_key(values: Any) -> dict[str, str]:
    """The :func:`content_key` of every value that names an existing file (a str or path), by resolved path.

    For a stage's options (``CAL:gate=gate.json``): a file an option names enters the fingerprint by its content.
    Other values (numbers, words such as ``one-sided``) are left out; relative paths start at the working folder.

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
    method, ``shape`` and ``dtype`` (a :class:`~vpr_uncertainty.retrieval.blocks.DescriptorRows` on
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

    Examples
    --------
    >>> payload_checksum(np.arange(3), "text") == payload_checksum(np.arange(3), "text")
    True
    >>> payload_checksum(np.arange(3), "text") == payload_checksum(np.arange(3), "texT")
    False
    """
    encoded = (part.encode("utf-8") if isinstance(part, str) else part for part in parts)
    arrays = [np.frombuffer(bytes(part), dtype=np.uint8) if isinstance(part, bytes) else part for part in encoded]
    return "blake2b:" + array_digest(*arrays)


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
    """
    document = {"protocol": PROTOCOL, "stage": stage, "config": _canonical(config), "inputs": _canonical(inputs or {})}
    text = json.dumps(document, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def user_cache_dir() -> Path:
    """The toolkit's per-user cache folder: ``$XDG_CACHE_HOME/vpr-uncertainty`` (``~/.cache`` without it)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "vpr-uncertainty"


def slug(text: str) -> str:
    """``text`` as a file-name part: runs of characters other than letters, digits, ``_.-`` become ``_``."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_.") or "x"  # no hidden file: "../x" -> "x"


def stale_notice(path: str | Path, reason: str, action: str = "rebuilding it", *, stacklevel: int = 3) -> None:
    """Warn in one line that the cache at ``path`` cannot be used (``reason``) and what happens instead."""
    reason = " ".join(str(reason).split())
    warnings.warn(f"cache {path}: {reason}; {action}", CacheWarning, stacklevel=stacklevel)


def read_if_fresh(
    path: str | Path,
    expected: str,
    read: Callable[[Path], _T],
    stored: Callable[[_T], str | None],
    *,
    errors: tuple[type[BaseException], ...] = (OSError, ValueError, KeyError, EOFError),
) -> _T | None:
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


# --- atomic writes ---


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
        try:
            yield path
        except OSError as error:
            _raise_naming_target(error, path, path)
            raise
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove_orphans(path)
    owner = f"{socket.gethostname()}-{os.getpid()}"
    handle, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{owner}.", suffix=f".tmp{path.suffix}")
    os.close(handle)
    temporary = Path(name)
    os.chmod(temporary, _file_mode(path))  # mkstemp makes 0600; give the file the mode open() would have
    try:
        yield temporary
        with open(temporary, "rb+") as written:
            os.fsync(written.fileno())
        os.replace(temporary, path)
    except OSError as error:
        temporary.unlink(missing_ok=True)
        _raise_naming_target(error, temporary, path)
        raise
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    _fsync_folder(path.parent)


def _remove_orphans(path: Path) -> None:
    """Remove the temporary files of ``path`` that a process of this machine left when it was killed (its name holds
    the host and process id of its writer; a writer that still runs, or of another machine, is left alone)."""
    host = socket.gethostname()
    for orphan in path.parent.glob(f".{glob.escape(path.name)}.{glob.escape(host)}-*.tmp{glob.escape(path.suffix)}"):
        pid = orphan.name[len(f".{path.name}.{host}-") :].split(".", 1)[0]
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            orphan.unlink(missing_ok=True)
        except (ValueError, OSError):  # not our name, or a process we may not signal: alive
            continue


#: Errors of a write that say nothing of which file: named after the file being written when they carry no name.
_WRITE_ERRNOS = frozenset(
    getattr(errno, name) for name in ("ENOSPC", "EDQUOT", "EFBIG", "EIO", "EROFS") if hasattr(errno, name)
)


def _raise_naming_target(error: OSError, temporary: Path, path: Path) -> None:
    """Raise ``error`` again naming ``path`` instead of none or of its temporary file; return for an error naming
    another file (e.g. an input read within the block) or without errno, which the caller re-raises unchanged."""
    if not error.errno or error.filename2 is not None:
        return
    if error.filename is None:
        if error.errno not in _WRITE_ERRNOS:
            return
    elif str(error.filename) != str(temporary):
        return
    kept = "" if temporary == path else " (the file as it was is kept)" if path.exists() else " (nothing written)"
    raise OSError(error.errno, f"{error.strerror or os.strerror(error.errno)}{kept}", str(path)) from error


def _file_mode(path: Path) -> int:
    """The mode of the file at ``path`` when it exists, else what the process's umask gives a new file."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _fsync_folder(folder: Path) -> None:
    with contextlib.suppress(OSError):  # e.g. Windows: folders cannot be opened
        descriptor = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "w", **open_options: Any) -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path`` for writing; it replaces ``path`` when the block succeeds.

    ``mode`` is ``"w"`` (UTF-8 by default) or ``"wb"``; ``open_options`` go to :func:`open`.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    if mode == "w":
        open_options.setdefault("encoding", "utf-8")
    with atomic_path(path) as temporary, open(temporary, mode, **open_options) as handle:
        yield handle


def write_text(path: str | Path, text: str, *, keep_unchanged: bool = False) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically and return the path.

    With ``keep_unchanged``, a regular file that already holds exactly these bytes is left as it is (its
    modification time too).
    """
    if keep_unchanged:
        with contextlib.suppress(OSError):
            if Path(path).is_file() and Path(path).read_bytes() == text.encode("utf-8"):
                return Path(path)
    with atomic_write(path) as handle:
        handle.write(text)
    return Path(path)


def write_json(path: str | Path, document: Any) -> Path:
    """Write ``document`` as indented JSON (one trailing newline) to ``path`` atomically and return the path."""
    return write_text(path, json.dumps(document, indent=2, default=str) + "\n")


def write_figure(figure: Any, path: str | Path, *, inputs: str | None = None, **savefig_options: Any) -> Path:
    """Save a matplotlib ``figure`` to ``path`` atomically, in the format of its suffix (PNG without one).

    ``inputs``: a fingerprint of what the figure shows, stored in the PNG (see :func:`figure_is_current`); PNG only.
    """
    path = Path(path)
    kind = path.suffix.lstrip(".").lower() or "png"
    if inputs is not None and kind != "png":
        raise ValueError(f"only a PNG figure can store its inputs, got {path.name!r}")
    with atomic_path(path) as temporary:
        if inputs is None:
            figure.savefig(temporary, format=kind, **savefig_options)
        else:
            drawn = io.BytesIO()
            figure.savefig(drawn, format="png", **savefig_options)
            temporary.write_bytes(stamp_png(drawn.getvalue(), inputs))
    return path


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Keyword of the PNG text chunk holding a figure's inputs and checksum.
FIGURE_STAMP = b"vpr-uncertainty inputs"


def _png_chunks(data: bytes) -> list[tuple[int, bytes, bytes]] | None:
    """``(offset, type, body)`` of each chunk of a whole PNG, every CRC checked; None for anything else."""
    if not data.startswith(_PNG_SIGNATURE):
        return None
    chunks, offset = [], len(_PNG_SIGNATURE)
    while offset + 12 <= len(data):
        length = int.from_bytes(data[offset : offset + 4], "big")
        end = offset + 12 + length
        if end > len(data):
            return None
        kind, body = data[offset + 4 : offset + 8], data[offset + 8 : end - 4]
        if zlib.crc32(kind + body) != int.from_bytes(data[end - 4 : end], "big"):
            return None
        chunks.append((offset, kind, body))
        offset = end
        if kind == b"IEND":
            return chunks if offset == len(data) else None
    return None


def _head_checksum(head: bytes) -> str:
    return "blake2b:" + hashlib.blake2b(head, digest_size=16).hexdigest()


def stamp_png(data: bytes, inputs: str) -> bytes:
    """The PNG ``data`` with a text chunk before its end: ``inputs`` and the checksum of every byte before it."""
    chunks = _png_chunks(data)
    if chunks is None:
        raise ValueError("not a whole PNG file")
    head = data[: chunks[-1][0]]
    stamp = json.dumps({"inputs": str(inputs), "checksum": _head_checksum(head)}, sort_keys=True)
    chunk = b"tEXt" + FIGURE_STAMP + b"\0" + stamp.encode("latin-1")  # a PNG chunk's type and body
    return head + (len(chunk) - 4).to_bytes(4, "big") + chunk + zlib.crc32(chunk).to_bytes(4, "big") + data[len(head) :]


def figure_is_current(path: str | Path, inputs: str) -> bool:
    """Whether the PNG at ``path`` was written by :func:`write_figure` from these ``inputs`` and is intact.

    False for a missing, unreadable, truncated or corrupted file (a chunk's CRC or the stored checksum of the bytes
    before the stamp fails), one without a stamp (another writer) or one stamped with other inputs.

    Examples
    --------
    >>> import tempfile
    >>> figure = Path(tempfile.mkdtemp()) / "f.png"
    >>> figure_is_current(figure, "abc")
    False
    """
    try:
        data = Path(path).read_bytes()
    except OSError:
        return False
    chunks = _png_chunks(data)
    if chunks is None or len(chunks) < 2:
        return False
    offset, kind, body = chunks[-2]
    if kind != b"tEXt" or not body.startswith(FIGURE_STAMP + b"\0"):
        return False
    try:
        stamp = json.loads(body[len(FIGURE_STAMP) + 1 :].decode("latin-1"))
    except ValueError:
        return False
    if not isinstance(stamp, dict):
        return False
    return stamp.get("inputs") == inputs and stamp.get("checksum") == _head_checksum(data[:offset])


# --- HDF5 inputs that hold their own data ---

_REFUSED = "an input file must hold its own data; refused"


def _refuse_link(path: str | Path, name: str, link: Any) -> None:
    import h5py

    if isinstance(link, h5py.ExternalLink):
        raise ValueError(f"{path}: {name!r} is an HDF5 external link to {link.path!r} in {link.filename!r}; {_REFUSED}")
    if isinstance(link, h5py.SoftLink):
        raise ValueError(f"{path}: {name!r} is an HDF5 soft link to {link.path!r}; {_REFUSED}")


def check_dataset(dataset: Any, path: str | Path, name: str | None = None) -> None:
    """Raise a ValueError naming ``path`` and the dataset when its bytes do not live in the file itself
    (external raw storage, a virtual dataset)."""
    name = (dataset.name if name is None else name).strip("/")
    if dataset.external:
        files = ", ".join(sorted({str(entry[0]) for entry in dataset.external}))
        raise ValueError(
            f"{path}: dataset {name!r} uses HDF5 external storage (its bytes come from {files}); {_REFUSED}"
        )
    if dataset.is_virtual:
        raise ValueError(
            f"{path}: dataset {name!r} is an HDF5 virtual dataset (its bytes come from other datasets or files); "
            f"{_REFUSED}"
        )


def open_dataset(group: Any, name: str, path: str | Path) -> Any:
    """``group[name]``, checked: every link on the way a hard link, the dataset's bytes in the file itself.

    ``name`` is a path below ``group`` (``"database/descriptors"``); ``path`` the file, for the messages.

    Raises
    ------
    KeyError
        When ``name`` is missing (as ``group[name]``).
    ValueError
        For a soft or external link on the way, external storage, a virtual dataset, or a group instead of a
        dataset; the message names the file and the object.
    """
    import h5py

    prefix = group.name.strip("/")
    parts = [part for part in name.split("/") if part]
    current = group
    for depth, part in enumerate(parts):
        link = current.get(part, getlink=True)
        where = "/".join([*([prefix] if prefix else []), *parts[: depth + 1]])
        if link is None:
            raise KeyError(f"{path} has no {where!r}")
        _refuse_link(path, where, link)
        current = current[part]
    if not isinstance(current, h5py.Dataset):
        raise ValueError(f"{path}: {'/'.join([prefix, *parts]).strip('/')!r} is not a dataset")
    check_dataset(current, path, "/".join([*([prefix] if prefix else []), *parts]))
    return current


def open_present(group: Any, names: tuple[str, ...], path: str | Path) -> dict[str, Any]:
    """:func:`open_dataset` of each of ``names`` that ``group`` holds (a missing one is left out)."""
    return {name: open_dataset(group, name, path) for name in names if name in group}


def hard_links(group: Any, path: str | Path) -> Iterator[tuple[str, Any]]:
    """Every object below ``group`` by its hard-link names, refusing every other kind of link.

    Unlike ``visititems``, an object reachable by two names is yielded under both (a group entered under each), and a
    soft or external link is refused instead of being skipped (skipping it would silently leave an image out). A hard
    link back to an enclosing group is yielded, not entered (a cycle); a group reached by more names than it has hard
    links (nested hard-linked groups: names that multiply) is refused. Datasets are checked with :func:`check_dataset`.

    Yields
    ------
    name : str
        Relative to ``group``, "/"-joined.
    item : h5py.Group or h5py.Dataset
    """
    import h5py

    stack: list[tuple[str, Any, frozenset[Any]]] = [("", group, frozenset({group.id}))]
    entered: dict[Any, int] = {}
    while stack:
        prefix, current, enclosing = stack.pop()
        for key in current.keys():
            name = f"{prefix}{key}"
            _refuse_link(path, name, current.get(key, getlink=True))
            item = current[key]
            if isinstance(item, h5py.Dataset):
                check_dataset(item, path, name)
            yield name, item
            if isinstance(item, h5py.Group) and item.id not in enclosing:
                entered[item.id] = entered.get(item.id, 0) + 1
                if entered[item.id] > 1 and entered[item.id] > h5py.h5o.get_info(item.id).rc:
                    raise ValueError(
                        f"{path}: group {name!r} is reached by more names than it has hard links (hard links inside "
                        "a hard-linked group); refused: give each image one group of its own"
                    )
                stack.append((f"{name}/", item, enclosing | {item.id}))
