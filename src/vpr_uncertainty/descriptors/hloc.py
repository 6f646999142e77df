"""Global descriptors in hloc's HDF5 layout (``hloc.extract_features`` with a global model such as NetVLAD).

hloc writes one group per image, named by the image's path relative to its image folder (``query/0001.jpg``
makes the nested groups ``query`` and ``0001.jpg``), holding a dataset ``global_descriptor`` of shape (D,) and
one ``image_size``; ``hloc.utils.io.list_h5_names`` lists the images as the parents of the datasets. One file may
hold the queries and the database together (hloc's ``pairs_from_retrieval`` then tells them apart by a name
prefix such as ``query/`` and ``db/``).

:func:`read_hloc_descriptors` reads such a file, one split when the names carry a split prefix;
:func:`write_hloc_descriptors` writes one that hloc reads.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = [
    "DATABASE_PREFIXES",
    "HLOC_DATASET",
    "QUERY_PREFIXES",
    "is_hloc_file",
    "read_hloc_descriptors",
    "write_hloc_descriptors",
]

#: The dataset of each image's group that holds its global descriptor.
HLOC_DATASET = "global_descriptor"
#: First name components that mark a query image, and a database image.
QUERY_PREFIXES: tuple[str, ...] = ("query", "queries", "q")
DATABASE_PREFIXES: tuple[str, ...] = ("db", "database", "ref", "reference", "mapping")


def _h5py():
    try:
        import h5py
    except ImportError as error:  # pragma: no cover - h5py is a core dependency
        raise ImportError("reading hloc descriptor files needs h5py: pip install h5py") from error
    return h5py


def _names(handle) -> list[str]:
    """The images of an open file: the parents of its ``global_descriptor`` datasets, sorted."""
    h5py = _h5py()
    names: list[str] = []

    def visit(name: str, obj) -> None:
        if isinstance(obj, h5py.Dataset) and name.rsplit("/", 1)[-1] == HLOC_DATASET:
            names.append(obj.parent.name.strip("/"))

    handle.visititems(visit)
    return sorted(names)


def is_hloc_file(path: str | Path) -> bool:
    """Whether ``path`` is an HDF5 file holding at least one hloc ``global_descriptor``."""
    h5py = _h5py()
    try:
        with h5py.File(path, "r") as handle:
            found = []

            def visit(name: str, obj) -> bool | None:
                if isinstance(obj, h5py.Dataset) and name.rsplit("/", 1)[-1] == HLOC_DATASET:
                    found.append(name)
                    return True  # stop at the first
                return None

            handle.visititems(visit)
            return bool(found)
    except OSError:
        return False


def _split_of(name: str) -> str | None:
    first = name.split("/", 1)[0].lower()
    if "/" not in name:
        return None
    if first in QUERY_PREFIXES:
        return "queries"
    if first in DATABASE_PREFIXES:
        return "database"
    return None


def read_hloc_descriptors(path: str | Path, split: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read the global descriptors of an hloc HDF5 file.

    Parameters
    ----------
    path : str or Path
    split : {"database", "queries"}, optional
        When the names carry split prefixes (``query/``, ``queries/`` or ``q/``; ``db/``, ``database/``,
        ``ref/``, ``reference/`` or ``mapping/``), only that split's images; otherwise the file is taken to hold
        one split and every image is read.

    Returns
    -------
    names : ndarray of str, shape (N,)
        Sorted, as hloc lists them.
    descriptors : ndarray of shape (N, D), float32

    Raises
    ------
    ValueError
        When the file holds no global descriptors, descriptors of different sizes, or no image of ``split``
        although its names carry split prefixes.
    """
    h5py = _h5py()
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"descriptor file not found: {path}")
    with h5py.File(path, "r") as handle:
        names = _names(handle)
        if not names:
            raise ValueError(f"{path} holds no hloc global descriptors (groups with a '{HLOC_DATASET}' dataset)")
        splits = {name: _split_of(name) for name in names}
        if split is not None and any(splits.values()):
            chosen = [name for name in names if splits[name] == split]
            if not chosen:
                present = sorted(set(splits.values()) - {None})
                raise ValueError(f"{path}: no {split} images among its names (they hold {present} images)")
            names = chosen
        rows = [np.asarray(handle[name][HLOC_DATASET][()], dtype=np.float32).reshape(-1) for name in names]
    sizes = sorted({row.size for row in rows})
    if len(sizes) > 1:
        raise ValueError(f"{path}: global descriptors of different sizes {sizes}; expected one size")
    return np.asarray(names, dtype=str), np.stack(rows)


def write_hloc_descriptors(
    path: str | Path,
    names: Sequence[str],
    descriptors: np.ndarray,
    *,
    image_sizes: Sequence[tuple[int, int]] | None = None,
) -> Path:
    """Write global descriptors in hloc's layout (one group per image name, dataset ``global_descriptor``).

    Existing groups of the same names are replaced, others are kept (so the queries and the database can go
    into one file, as hloc does). ``image_sizes`` ((width, height) per image) are written as hloc's
    ``image_size`` datasets when given.

    Returns
    -------
    Path
    """
    h5py = _h5py()
    descriptors = np.asarray(descriptors, dtype=np.float32)
    names = [str(name) for name in names]
    if descriptors.ndim != 2 or len(descriptors) != len(names):
        raise ValueError(f"descriptors must have shape (len(names), D) = ({len(names)}, D), got {descriptors.shape}")
    if len(set(names)) != len(names):
        raise ValueError("image names must be unique")
    if image_sizes is not None and len(image_sizes) != len(names):
        raise ValueError(f"got {len(image_sizes)} image_sizes for {len(names)} names")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "a") as handle:
        for row, name in enumerate(names):
            if name in handle:
                del handle[name]
            group = handle.create_group(name)
            group.create_dataset(HLOC_DATASET, data=descriptors[row])
            if image_sizes is not None:
                group.create_dataset("image_size", data=np.asarray(image_sizes[row], dtype=np.int64))
    return path
