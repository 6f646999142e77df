"""Local-feature files in hloc's HDF5 layout, and the cache that extracts each image once (one file per extractor
configuration; inside :func:`deferred_writes` only the driver writes). The layout: see docs/reference/file-formats.md;
who writes and when an image is extracted again: see docs/explanation/caches.md.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vpr_uncertainty import cache
from vpr_uncertainty.cache import open_present
from vpr_uncertainty.geometric.local_features import Extractor, LocalFeatures
from vpr_uncertainty.identity import target_identity
from vpr_uncertainty.progress import progress_bar

if TYPE_CHECKING:
    import h5py


@dataclass
class PendingFeatures:
    """Local features extracted inside :func:`deferred_writes` for one cache file (``path``, with the extractor's
    JSON ``config``), for the driver to write: image name -> (features, content key of its file when extracted)."""

    path: Path
    config: str
    features: dict[str, tuple[LocalFeatures, str]] = field(default_factory=dict)


#: Set inside :func:`deferred_writes`: cache file -> what was extracted for it and is not written yet.
_store: dict[Path, PendingFeatures] | None = None


@contextmanager
def deferred_writes() -> Iterator[list[PendingFeatures]]:
    """Within the context, :func:`extract_features` reads the caches and never writes them: what it extracts is
    kept in memory (reused by later calls) and, on exit, fills the yielded list (one :class:`PendingFeatures` per
    cache file that got new features) for the driver's :func:`store_features`."""
    global _store  # one store per process: a task runs alone in its worker
    previous, _store = _store, {}
    pending: list[PendingFeatures] = []
    try:
        yield pending
        pending.extend(entry for entry in _store.values() if entry.features)
    finally:
        _store = previous


def deferring_writes(function: Callable[[Any], Any], item: Any) -> tuple[Any, list[PendingFeatures]]:
    """``(function(item), pending)``: ``function`` (module-level, or a partial of one) run inside
    :func:`deferred_writes`, with the local features it extracted for the driver's :func:`store_features`."""
    with deferred_writes() as pending:
        result = function(item)
    return result, pending


#: Chunks per worker: several, so that a slow chunk does not hold the others back.
CHUNKS_PER_WORKER = 4


def split_chunks(items: list, executor: Any) -> list[list]:
    """``items`` in consecutive chunks of equal size (the last may be shorter), one executor task each:
    :data:`CHUNKS_PER_WORKER` chunks per worker."""
    size = max(1, math.ceil(len(items) / (CHUNKS_PER_WORKER * max(1, executor.workers or 1))))
    return [items[start : start + size] for start in range(0, len(items), size)]


def _extract_chunk(paths: list[Path], extractor: Any) -> list[Any]:
    """The local features of each image of one chunk, in order (one thread: the task has one CPU)."""
    features: list[Any] = [None] * len(paths)
    for position, result in extractor.extract(paths, workers=1):
        features[position] = result
    return features


def extract_on_executor(extractor: Any, paths: Sequence[Path], executor: Any) -> Iterator[tuple[int, Any]]:
    """Yield ``(position in paths, LocalFeatures)`` for every image, extracted in chunks on ``executor``.

    Chunks come back in completion order; within one they are in order. The caller writes them to the cache.
    """
    chunks = split_chunks(list(paths), executor)
    for chunk, features in executor.imap(partial(_extract_chunk, extractor=extractor), chunks):
        for offset, result in enumerate(features):
            yield chunk * len(chunks[0]) + offset, result


CACHE_FORMAT_VERSION = 2

_FEATURE_DATASETS = ("keypoints", "descriptors", "scores", "image_size")

STAGE = "local features"


def image_names(paths: Sequence[str | Path], root: str | Path | None = None) -> list[str]:
    """hloc-style names: each path relative to ``root`` (default: the deepest folder holding all paths), "/"-joined.

    Examples
    --------
    >>> image_names(["/d/query/0.jpg", "/d/ref/0.jpg"])
    ['query/0.jpg', 'ref/0.jpg']
    """
    resolved = [Path(path).absolute() for path in paths]
    if not resolved:
        return []
    if root is None:
        root = os.path.commonpath([path.parent for path in resolved])
    root = Path(root).absolute()
    return [path.relative_to(root).as_posix() for path in resolved]


def config_fingerprint(config: Mapping[str, Any]) -> str:
    """The :func:`~vpr_uncertainty.cache.fingerprint` of an extractor configuration."""
    return cache.fingerprint(STAGE, {"cache_format": CACHE_FORMAT_VERSION, **config})


def extractor_config(extractor: Extractor) -> dict[str, Any]:
    """What determines an extractor's features: its configuration and the code of its class."""
    return {**extractor.config(), "code": target_identity(type(extractor))}


def cache_path(cache_dir: str | Path, extractor: Extractor) -> Path:
    """The cache file of an extractor's configuration inside ``cache_dir``."""
    return Path(cache_dir) / f"{extractor.name}-{config_fingerprint(extractor_config(extractor))[:16]}.h5"


def read_features(file: h5py.File | str | Path, name: str, *, verify: bool = False) -> LocalFeatures:
    """Read one image's features from an hloc-layout HDF5 file (an open file or its path).

    ``descriptors`` stored as (D, N), hloc's layout, are transposed to (N, D) (also when D == N: a square array
    is taken to be hloc's); (N, D) is read as it is. float16 is widened to float32.
    A file without ``image_size`` gets the extent of the keypoints. A soft or external link, external storage or
    a virtual dataset on the way is refused with a ValueError (:mod:`vpr_uncertainty.cache`). With ``verify``,
    features whose bytes do not match the checksum the cache stored with them raise
    :class:`~vpr_uncertainty.cache.ChecksumError` (each dataset is read once, for both).
    """
    import h5py

    if not isinstance(file, h5py.File):
        with h5py.File(file, "r") as handle:
            return read_features(handle, name, verify=verify)
    if name not in file:
        example = next(iter(_group_names(file)), None)
        raise KeyError(
            f"{file.filename} has no features for image {name!r}"
            + (f" (its names look like {example!r})" if example else " (it holds no image)")
        )
    group = file[name]
    if "keypoints" not in group or "descriptors" not in group:
        raise KeyError(f"{file.filename}:{name} lacks 'keypoints' or 'descriptors' (not hloc's local-feature layout)")
    # Each dataset checked (no soft or external link, external storage or virtual dataset): bytes of this file only.
    opened = open_present(file, tuple(f"{name}/{key}" for key in _FEATURE_DATASETS), file.filename)
    raw = {path.rsplit("/", 1)[1]: dataset[()] for path, dataset in opened.items()}  # each dataset read once
    if verify and group.attrs.get("checksum") != _checksum(raw):
        raise cache.ChecksumError(f"{file.filename}:{name}: the features do not match their checksum")
    keypoints = np.asarray(raw["keypoints"], np.float32).reshape(-1, 2)
    descriptors = np.asarray(raw["descriptors"])
    n = len(keypoints)
    if descriptors.ndim != 2:
        raise ValueError(f"{file.filename}:{name}/descriptors must be 2-D, got shape {descriptors.shape}")
    if descriptors.shape[1] == n:
        descriptors = descriptors.T  # hloc's (D, N); a square array (D == N) is read as hloc's too
    elif descriptors.shape[0] != n:
        raise ValueError(f"{file.filename}:{name}: {n} keypoints but descriptors of shape {descriptors.shape}")
    if descriptors.dtype == np.float16:
        descriptors = descriptors.astype(np.float32)
    scores = np.asarray(raw["scores"], np.float32).reshape(-1) if "scores" in raw else None
    if "image_size" in group:
        image_size = np.asarray(raw["image_size"]).reshape(2)
    else:
        image_size = np.ceil(keypoints.max(axis=0) + 1) if n else np.ones(2)
    return LocalFeatures(keypoints, np.ascontiguousarray(descriptors), scores, image_size)


def write_features(
    file: h5py.File,
    name: str,
    features: LocalFeatures,
    *,
    source: str | Path | None = None,
    content_key: str | None = None,
) -> None:
    """Write one image's features in hloc's layout, replacing an existing group of that name.

    The group records ``content_key`` (the :func:`~vpr_uncertainty.cache.content_key` of the image file, taken when
    it was extracted), else the content key of ``source`` now, else none.
    """
    if name in file:
        del file[name]
    group = file.create_group(name)
    group.create_dataset("keypoints", data=features.keypoints)
    group.create_dataset("descriptors", data=np.ascontiguousarray(features.descriptors.T))
    group.create_dataset("scores", data=features.scores)
    group.create_dataset("image_size", data=features.image_size)
    if content_key is None and source is not None:
        content_key = cache.content_key(source)
    if content_key is not None:
        group.attrs["content_key"] = content_key
    group.attrs["checksum"] = _checksum({key: group[key][()] for key in _FEATURE_DATASETS})  # as stored


def _checksum(raw: Mapping[str, Any]) -> str:
    return cache.payload_checksum(*(part for key in sorted(raw) for part in (key, raw[key])))


def _group_names(file: h5py.File) -> list[str]:
    import h5py

    names: list[str] = []

    def visit(name: str, item: Any) -> None:
        if isinstance(item, h5py.Group) and "keypoints" in item:
            names.append(name)

    file.visititems(visit)
    return names


def _stored_key(handle: h5py.File, name: str) -> str | None:
    """The content key stored with the features of ``name``; None when they are missing or incomplete."""
    import h5py

    group = handle.get(name)
    return group.attrs.get("content_key") if isinstance(group, h5py.Group) and "image_size" in group else None


def _open_cache(path: Path, config: str, *, write: bool = True) -> h5py.File | None:
    """The cache file for appending: created whole when missing; rebuilt (one-line notice) when unusable. With
    ``write=False``, for reading, or None when it is missing, unreadable or of another configuration (the driver
    rebuilds it, with the notice, when it writes)."""
    import h5py

    if path.exists() if write else path.is_file():
        try:
            handle = h5py.File(path, "a" if write else "r")
        except OSError as error:  # e.g. a run killed while writing
            stale = f"unreadable (truncated or foreign: {str(error).splitlines()[0]})" if write else ""
        else:
            if handle.attrs.get("fingerprint") == config_fingerprint(json.loads(config)):
                return handle
            handle.close()
            stale = "made by another configuration or an earlier version"
        if write:
            cache.stale_notice(path, stale)
    if not write:
        return None
    with cache.atomic_path(path) as temporary, h5py.File(temporary, "w") as handle:
        handle.attrs["config"] = config
        handle.attrs["fingerprint"] = config_fingerprint(json.loads(config))
    return h5py.File(path, "a")


def store_features(pending: Iterable[Iterable[PendingFeatures]]) -> int:
    """Write what the tasks returned (``pending``: one list of :class:`PendingFeatures` per task) to the caches;
    return the number of images written.

    Called by the driver once no task is running: it is the one writer of the files. An image extracted by several
    tasks is written once; one already stored with the same content key is kept. A missing, unreadable or foreign
    file is created (or rebuilt, with the one-line notice) first; a file that cannot be written (locked, disk full)
    is reported in one line (:class:`~vpr_uncertainty.cache.CacheWarning`) and left as is.
    """
    merged: dict[Path, PendingFeatures] = {}
    for entries in pending:
        for entry in entries:
            target = merged.setdefault(Path(entry.path), PendingFeatures(Path(entry.path), entry.config))
            target.features.update(entry.features)
    written = 0
    for path, entry in merged.items():
        try:
            with _open_cache(path, entry.config) as handle:
                for name, (features, key) in entry.features.items():
                    if _stored_key(handle, name) != key:
                        write_features(handle, name, features, content_key=key)
                        written += 1
        except OSError as error:  # e.g. locked by another run: the results are computed, only the cache is missed
            cache.stale_notice(path, f"not written ({error})", "a rerun extracts these images again")
    return written


def _deferred_features(entry: PendingFeatures, unique: Mapping[str, str | Path]) -> dict[str, LocalFeatures]:
    """The features that an earlier call of the same task kept in memory, of the images unchanged since."""
    found = {}
    for name, path in unique.items():
        if name in entry.features and Path(path).is_file():
            features, key = entry.features[name]
            if key == cache.content_key(path):
                found[name] = features
    return found


@dataclass
class ExtractionStats:
    """What :func:`extract_features` did: images extracted, images read from the cache, seconds spent."""

    extracted: int = 0
    cached: int = 0
    seconds: float = 0.0


def extract_features(
    paths: Sequence[str | Path],
    extractor: Extractor,
    *,
    names: Sequence[str] | None = None,
    cache_dir: str | Path | None = None,
    workers: int | None = None,
    executor: Any = None,
) -> tuple[dict[str, LocalFeatures], ExtractionStats]:
    """Features of every image, extracted once: read from the cache when there, else extracted and written.

    Parameters
    ----------
    paths : sequence of path
        Image files; duplicates are extracted once.
    extractor : Extractor
    names : sequence of str, optional
        Cache keys (hloc names) of the images; by default :func:`image_names` of ``paths``.
    cache_dir : path, optional
        Folder of the HDF5 caches; without it nothing is written and everything is extracted.
    workers : int, optional
        Threads that read images (and run OpenCV extractors).
    executor : LocalExecutor or RayExecutor, optional
        With Ray, the images to extract go in chunks to Ray tasks; this process still writes the cache, each chunk
        as it comes back (inside :func:`deferred_writes` the cache is read, never written).

    Returns
    -------
    features : dict
        Image name -> :class:`LocalFeatures`.
    stats : ExtractionStats
    """
    start = time.perf_counter()
    names = image_names(paths) if names is None else [str(name) for name in names]
    if len(names) != len(paths):
        raise ValueError(f"got {len(names)} names for {len(paths)} images")
    unique = dict(zip(names, paths, strict=True))
    features: dict[str, LocalFeatures] = {}
    stats = ExtractionStats()
    handle: h5py.File | None = None
    deferred: PendingFeatures | None = None
    try:
        if cache_dir is not None:
            file_path = cache_path(cache_dir, extractor)
            config = json.dumps(extractor_config(extractor), sort_keys=True, default=str)
            if _store is None:
                handle = _open_cache(file_path, config)
            else:  # a task: read the shared file, keep what is extracted for the driver
                deferred = _store.setdefault(file_path, PendingFeatures(file_path, config))
                features.update(_deferred_features(deferred, unique))
                handle = _open_cache(file_path, config, write=False)
            if handle is not None:
                changed = []
                for name, path in unique.items():
                    stored = None if name in features else _stored_key(handle, name)
                    if stored is not None and Path(path).is_file() and stored == cache.content_key(path):
                        try:
                            features[name] = read_features(handle, name, verify=True)
                        except cache.ChecksumError:
                            changed.append(name)
                if changed:  # one line for all: edited on disk, or written before features carried a checksum
                    cache.stale_notice(
                        file_path,
                        f"the features of {len(changed)} image(s) do not match their checksum (first: {changed[0]!r}; "
                        "changed on disk, or written by an earlier version)",
                        "extracting them again",
                    )
            if deferred is not None and handle is not None:
                handle.close()
                handle = None
        todo = [name for name in unique if name not in features]
        stats.cached = len(features)
        if executor is not None and executor.name != "local" and len(todo) > 1:
            extracted = extract_on_executor(extractor, [Path(unique[name]) for name in todo], executor)
        else:
            extracted = extractor.extract([unique[name] for name in todo], workers=workers)
        bar = progress_bar(extracted, total=len(todo), desc=f"{extractor.name} local features", unit="img")
        for position, result in bar:
            name = todo[position]
            features[name] = result
            if deferred is not None:
                deferred.features[name] = (result, cache.content_key(unique[name]))
            elif handle is not None:
                write_features(handle, name, result, source=unique[name])
                if (position + 1) % 32 == 0:
                    handle.flush()  # an interrupted run keeps (and a rerun resumes from) what was extracted
        stats.extracted = len(todo)
    finally:
        if handle is not None:
            handle.close()
    stats.seconds = time.perf_counter() - start
    return features, stats
