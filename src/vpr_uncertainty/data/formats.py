"""Dataset formats: how :func:`~vpr_uncertainty.data.load_dataset` recognises and reads a dataset path.

Each :class:`DatasetFormat` in :data:`DATASET_FORMAT_REGISTRY` declares the file suffixes it reads (file
formats) or a ``detect(folder) -> bool`` test (folder formats), and a reader given as a lazy dotted target,
called as ``reader(path, split=, radius=, queries=, name=, position_kind=)``. Detection tries the entries in
registration order; a new format is one :func:`register_format` call.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vpr_uncertainty.data.dataset import Dataset, PositionKind
from vpr_uncertainty.data.folder import DATABASE_FOLDERS, QUERY_FOLDERS
from vpr_uncertainty.data.positives import DEFAULT_RADIUS
from vpr_uncertainty.plugins import Registry, load_target

__all__ = ["DATASET_FORMAT_REGISTRY", "DatasetFormat", "detect_format", "has_split", "read_format", "register_format"]


@dataclass(frozen=True)
class DatasetFormat:
    """One dataset format.

    Attributes
    ----------
    name, description : str
    expects : str
        What a path of this format holds, in words (for the error of an unrecognised path).
    reader : callable or str
        ``reader(path, *, split, radius, queries, name, position_kind) -> Dataset`` or its dotted path.
    suffixes : tuple of str
        File suffixes (lower case) of a file format; empty for a folder format.
    detect : callable or None
        ``detect(folder) -> bool`` of a folder format.
    requires : tuple of str
        What the format provides the stages (images, positions or explicit positives).
    extra : str or None
        The pip extra its reader needs.
    """

    name: str
    description: str
    expects: str
    reader: Callable[..., Dataset] | str
    suffixes: tuple[str, ...] = ()
    detect: Callable[[Path], bool] | None = None
    requires: tuple[str, ...] = ()
    extra: str | None = None


#: The registered dataset formats, in detection order.
DATASET_FORMAT_REGISTRY: Registry[DatasetFormat] = Registry("dataset format", label="formats")


def register_format(entry: DatasetFormat, *, overwrite: bool = False) -> DatasetFormat:
    """Add a dataset format (tried after the ones registered before it)."""
    if bool(entry.suffixes) == (entry.detect is not None):
        raise ValueError(f"dataset format {entry.name!r}: give either suffixes (a file format) or detect (a folder)")
    return DATASET_FORMAT_REGISTRY.register(entry, overwrite=overwrite)


def has_split(folder: Path) -> bool:
    """Whether ``folder`` holds a database and a queries folder (VPR-datasets-downloader split layout)."""
    return any((folder / name).is_dir() for name in DATABASE_FOLDERS) and any(
        (folder / name).is_dir() for name in QUERY_FOLDERS
    )


def detect_format(path: str | Path) -> str:
    """The name of the format of a dataset path (e.g. ``"folder"``, ``"vprbench"``, ``"table"``, ``"poses"``).

    Raises
    ------
    FileNotFoundError
        When the path does not exist.
    ValueError
        When it is none of the registered layouts (the message lists what each expects).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no such file or folder: {path}")
    if path.is_file():
        suffix = path.suffix.lower()
        files = DATASET_FORMAT_REGISTRY.entries()
        for entry in files:
            if suffix in entry.suffixes:
                return entry.name
        expected = " or ".join(entry.expects for entry in files if entry.suffixes)
        raise ValueError(f"{path}: unknown dataset file type {suffix!r}; expected {expected}")
    for entry in DATASET_FORMAT_REGISTRY:
        if entry.detect is not None and entry.detect(path):
            return entry.name
    expected = " or ".join(entry.expects for entry in DATASET_FORMAT_REGISTRY if entry.detect is not None)
    raise ValueError(f"{path} is not a dataset folder: expected {expected}")


def read_format(file_format: str, path: Path, **arguments: Any) -> Dataset:
    """Read ``path`` with the reader of the registered format ``file_format``."""
    entry = DATASET_FORMAT_REGISTRY.get(file_format)
    reader = load_target(entry.reader, what=f"dataset format {entry.name!r}", extra=entry.extra)
    return reader(path, **arguments)


# --- the built-in formats ------------------------------------------------------------------------------------


def _is_vprbench(path: Path) -> bool:
    return (path / "ground_truth_new.npy").is_file() or ((path / "query").is_dir() and (path / "ref").is_dir())


def _is_downloader_folder(path: Path) -> bool:
    return any(
        candidate.is_dir() and has_split(candidate)
        for candidate in (path, *(path / "images").glob("*"), *path.glob("*"))
    )


def read_poses(path: Path, *, radius: float | None, name: str | None, position_kind: PositionKind | None, **_: Any):
    from vpr_uncertainty.data.poses import load_poses_dataset

    return load_poses_dataset(path, radius=radius, name=name, position_kind=position_kind)


def read_table(path: Path, *, queries: Any, radius: float | None, name: str | None, position_kind: Any, **_: Any):
    from vpr_uncertainty.data.table import load_table_dataset

    radius = DEFAULT_RADIUS if radius is None else radius
    return load_table_dataset(path, queries=queries, radius=radius, name=name, position_kind=position_kind)


def read_vprbench(path: Path, *, radius: float | None, name: str | None, **_: Any) -> Dataset:
    from vpr_uncertainty.data.vprbench import load_vprbench_dataset

    if radius is not None:
        raise ValueError(f"{path} is a VPR-Bench dataset with explicit ground truth: radius does not apply")
    return load_vprbench_dataset(path, name=name)


def read_folder(path: Path, *, split: str | None, radius: float | None, name: str | None, position_kind: Any, **_: Any):
    from vpr_uncertainty.data.folder import find_split_folder, load_folder_dataset

    split = split or "test"
    radius = DEFAULT_RADIUS if radius is None else radius
    return load_folder_dataset(
        find_split_folder(path, split), split=split, radius=radius, name=name, position_kind=position_kind
    )


_HERE = "vpr_uncertainty.data.formats:"
register_format(
    DatasetFormat(
        "poses",
        "positions of database and queries (utmQ, utmDb, posDistThr), as in the published .npz files",
        ".npz (utmQ, utmDb, posDistThr)",
        _HERE + "read_poses",
        suffixes=(".npz",),
        requires=("positions",),
    )
)
register_format(
    DatasetFormat(
        "table",
        "a CSV/TSV table of image paths with positions (and an optional second table of queries)",
        ".csv/.tsv (image paths with positions)",
        _HERE + "read_table",
        suffixes=(".csv", ".tsv", ".txt"),
        requires=("images", "positions"),
    )
)
register_format(
    DatasetFormat(
        "vprbench",
        "a VPR-Bench folder: query/, ref/ and ground_truth_new.npy (explicit positives)",
        "query/, ref/ and ground_truth_new.npy (VPR-Bench)",
        _HERE + "read_vprbench",
        detect=_is_vprbench,
        requires=("images", "positives"),
    )
)
register_format(
    DatasetFormat(
        "folder",
        "a VPR-datasets-downloader folder: images/<split>/database/ and queries/, positions in the image names",
        "images/<split>/database/ and queries/ (VPR-datasets-downloader)",
        _HERE + "read_folder",
        detect=_is_downloader_folder,
        requires=("images", "positions"),
    )
)
