"""Global descriptors in hloc's HDF5 layout (``hloc.extract_features`` with a global model such as NetVLAD):
:func:`read_hloc_descriptors` reads such a file, one split when the names carry a split prefix;
:func:`write_hloc_descriptors` writes one that hloc reads. The layout: see docs/reference/file-formats.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty.cache import hard_links, open_dataset

#: The dataset of each image's group that holds its global descriptor.
HLOC_DATASET = "global_descriptor"
#: First name components that mark a query image, and a database image.
QUERY_PREFIXES: tuple[str, ...] = ("query", "queries", "q")
DATABASE_PREFIXES: tuple[str, ...] = ("db", "database", "ref", "reference", "mapping")


def _descriptor_datasets(handle, path: str | Path):
    """``(name, dataset)`` of every ``global_descriptor`` of an open file, refusing links and storage that reach
    outside it (:func:`vpr_uncertainty.cache.hard_links`)."""
    import h5py

    for name, item in hard_links(handle, path):
        if isinstance(item, h5py.Dataset) and name.rsplit("/", 1)[-1] == HLOC_DATASET:
            yield name, item


def is_hloc_file(path: str | Path) -> bool:
    """Whether ``path`` is an HDF5 file holding at least one hloc ``global_descriptor``.

    Raises
    ------
    ValueError
        When a link or a dataset met before the first descriptor reaches outside the file (see
        :mod:`vpr_uncertainty.cache`).
    """
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            return next(_descriptor_datasets(handle, path), None) is not None
    except OSError:
        return False


def _split_of(name: str) -> str | None:
    first = name.split("/", 1)[0].lower() if "/" in name else ""
    return "queries" if first in QUERY_PREFIXES else "database" if first in DATABASE_PREFIXES else None


def _row(handle, name: str, path: Path) -> np.ndarray:
    """The global descriptor of image ``name``: a 1-D dataset of real numbers of the file itself, as float32
    (strings, complex numbers or records would be garbled by the cast)."""
    dataset = open_dataset(handle, f"{name}/{HLOC_DATASET}", path)
    if dataset.ndim != 1 or dataset.dtype.kind not in "biuf":
        raise ValueError(
            f"{path}: {name}/{HLOC_DATASET} has shape {dataset.shape} and dtype {dataset.dtype}; expected one 1-D "
            "descriptor (D,) of real numbers per image"
        )
    return np.asarray(dataset[()], dtype=np.float32)


def read_hloc_descriptors(path: str | Path, split: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read the global descriptors of an hloc HDF5 file.

    Parameters
    ----------
    path : str or Path
    split : {"database", "queries"}, optional
        When the names carry split prefixes (``query/``, ``queries/`` or ``q/``; ``db/``, ``database/``,
        ``ref/``, ``reference/`` or ``mapping/``), only that split's images; otherwise the file is taken to hold
        one split and every image is read; a file mixing prefixed and unprefixed names is refused.

    Returns
    -------
    names : ndarray of str, shape (N,)
        Sorted, as hloc lists them.
    descriptors : ndarray of shape (N, D), float32

    Raises
    ------
    ValueError
        When the file holds no global descriptors, a descriptor that is not 1-D real numbers, descriptors of different
        sizes, no image of ``split`` although its names carry split prefixes, a name without a split prefix beside
        names with one (it belongs to neither split: hloc's ``pairs_from_retrieval`` would skip it), or a soft or
        external link, external storage or a virtual dataset (:mod:`vpr_uncertainty.cache`: bytes from outside the
        file are refused).
    """
    import h5py

    path = Path(path)
    if not is_regular_file(path, "a descriptor file"):
        raise FileNotFoundError(f"descriptor file not found: {path}")
    with h5py.File(path, "r") as handle:
        names = sorted(name.rpartition("/")[0] for name, _ in _descriptor_datasets(handle, path))  # their images
        if not names:
            raise ValueError(f"{path} holds no hloc global descriptors (groups with a '{HLOC_DATASET}' dataset)")
        splits = {name: _split_of(name) for name in names}
        if split is not None and any(splits.values()):
            if loose := [name for name in names if splits[name] is None]:
                raise ValueError(
                    f"{path}: image {loose[0]!r} ({len(loose)} such) has no split prefix while others have one; "
                    f"expected every name under {'/, '.join(QUERY_PREFIXES)}/ or {'/, '.join(DATABASE_PREFIXES)}/"
                )
            chosen = [name for name in names if splits[name] == split]
            if not chosen:
                present = sorted(set(splits.values()) - {None})
                raise ValueError(f"{path}: no {split} images among its names (they hold {present} images)")
            names = chosen
        rows = [_row(handle, name, path) for name in names]
    sizes = sorted({row.size for row in rows})
    if len(sizes) > 1:
        raise ValueError(f"{path}: global descriptors of different sizes {sizes}; expected one size")
    return np.asarray(names, dtype=str), np.stack(rows)


def write_hloc_descriptors(path: str | Path, names: Sequence[str], descriptors: np.ndarray) -> Path:
    """Write global descriptors in hloc's layout (one group per image name, dataset ``global_descriptor``).

    Existing groups of the same names are replaced, others are kept (so the queries and the database can go
    into one file, as hloc does).

    Returns
    -------
    Path
    """
    import h5py

    descriptors = np.asarray(descriptors, dtype=np.float32)
    names = [str(name) for name in names]
    if descriptors.ndim != 2 or len(descriptors) != len(names):
        raise ValueError(f"descriptors must have shape (len(names), D) = ({len(names)}, D), got {descriptors.shape}")
    if len(set(names)) != len(names):
        raise ValueError("image names must be unique")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "a") as handle:
        try:
            for row, name in enumerate(names):
                if name in handle:
                    del handle[name]
                group = handle.create_group(name)
                group.create_dataset(HLOC_DATASET, data=descriptors[row])
            handle.flush()
        except (OSError, RuntimeError) as error:  # disk full, I/O error: an OSError naming this file
            from vpr_uncertainty.descriptors.cache import write_error

            raise write_error(path, error, "hloc global features") from error
    return path
