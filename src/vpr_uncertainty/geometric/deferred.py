"""Local features kept in memory instead of written: what a grid cell extracts when it runs as an executor task.

Several tasks writing one HDF5 file at once fail (``BlockingIOError: unable to lock file``) or, worse, interleave.
So a task never writes the shared local-feature caches: inside :func:`deferred_writes`,
:func:`~vpr_uncertainty.geometric.cache.extract_features` reads them, keeps what it extracts here (reused by later
calls in the same task), and the task returns it (:func:`deferring_writes`); the driver writes it with
:func:`~vpr_uncertainty.geometric.cache.store_features` once no task is running.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vpr_uncertainty.geometric.local_features import LocalFeatures

__all__ = ["PendingFeatures", "active_store", "deferred_writes", "deferring_writes"]


@dataclass
class PendingFeatures:
    """Local features extracted inside :func:`deferred_writes` for one cache file, for the driver to write.

    Attributes
    ----------
    path : Path
        The cache file (:func:`~vpr_uncertainty.geometric.cache.cache_path`).
    config : str
        The extractor's configuration (JSON), stored in the file when the driver creates it.
    features : dict of str to (LocalFeatures, str)
        Image name -> its features and the :func:`~vpr_uncertainty.cache.content_key` of its file when extracted.
    """

    path: Path
    config: str
    features: dict[str, tuple[LocalFeatures, str]] = field(default_factory=dict)


#: Set inside :func:`deferred_writes`: cache file -> what was extracted for it and is not written yet.
_store: dict[Path, PendingFeatures] | None = None


def active_store() -> dict[Path, PendingFeatures] | None:
    """The in-memory store of the enclosing :func:`deferred_writes` (cache file -> features), or None outside one."""
    return _store


@contextmanager
def deferred_writes() -> Iterator[list[PendingFeatures]]:
    """Within the context, :func:`~vpr_uncertainty.geometric.cache.extract_features` reads the caches, never writes.

    What it extracts is kept in memory (and reused by later calls in the context); the list the context yields is
    filled with it on exit, for the driver to write with :func:`~vpr_uncertainty.geometric.cache.store_features`.

    Yields
    ------
    list of PendingFeatures
        Empty inside the context; one entry per cache file that got new features, on exit.
    """
    global _store  # one store per process: a task runs alone in its worker
    previous, _store = _store, {}
    pending: list[PendingFeatures] = []
    try:
        yield pending
        pending.extend(entry for entry in _store.values() if entry.features)
    finally:
        _store = previous


def deferring_writes(function: Callable[[Any], Any], item: Any) -> tuple[Any, list[PendingFeatures]]:
    """``function(item)`` inside :func:`deferred_writes`, with the local features it extracted (an executor task).

    Parameters
    ----------
    function : callable
        A module-level function or a partial of one.
    item : object

    Returns
    -------
    result : object
        ``function(item)``.
    pending : list of PendingFeatures
        The local features it extracted, for :func:`~vpr_uncertainty.geometric.cache.store_features` in the driver.
    """
    with deferred_writes() as pending:
        result = function(item)
    return result, pending
