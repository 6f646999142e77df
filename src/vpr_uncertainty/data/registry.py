"""The named benchmark datasets and :func:`load_dataset`, which reads any supported dataset from a path or a name.

Named datasets live under a data root, each in the layout VPR-datasets-downloader produces::

    <root>/<folder>/images/<split>/database/   and   <root>/<folder>/images/<split>/queries/

The root is the ``root`` argument (``--root`` on the command line), else the ``VPR_UNCERTAINTY_DATA``
environment variable. The downloader's own ``datasets/`` folder can serve as the root as it is; a root whose
``datasets/`` subfolder holds them works too. Nothing is downloaded at run time: a missing dataset gives an error
that says where to get it and where to put it.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_uncertainty.data.dataset import Dataset, PositionKind, _line_coordinate
from vpr_uncertainty.data.folder import DATABASE_FOLDERS, QUERY_FOLDERS, find_split_folder, load_folder_dataset
from vpr_uncertainty.data.positives import DEFAULT_RADIUS, positives_within_frames

__all__ = [
    "DATASET_FORMATS",
    "DATA_ROOT_VARIABLE",
    "NAMED_DATASETS",
    "NamedDataset",
    "data_root",
    "detect_format",
    "find_named_dataset",
    "get_named_dataset",
    "load_dataset",
]

#: Environment variable naming the data root.
DATA_ROOT_VARIABLE = "VPR_UNCERTAINTY_DATA"
#: Formats :func:`load_dataset` reads.
DATASET_FORMATS: tuple[str, ...] = ("folder", "vprbench", "table", "poses")

_DOWNLOADER = "VPR-datasets-downloader (https://github.com/gmberton/VPR-datasets-downloader)"


@dataclass(frozen=True)
class NamedDataset:
    """A benchmark dataset of the paper: where it is expected and how its positives are defined.

    Attributes
    ----------
    name : str
        Name to type (``load_dataset("st_lucia")``).
    title : str
        Usual name in papers.
    folder : str
        Folder under the data root.
    split : str
        Split read by default.
    radius : float
        Positive radius in metres, on the coordinates of the image names.
    threshold : str
        The positive threshold in words.
    position_kind : {"metres", "frames", "placeholder"}
        What the coordinates in the image names are.
    n_database, n_queries : int
        Image counts of the split in the standard version (a different count gives a warning).
    source : str
        Where to get the data and how to format it.
    citation : str
        Paper to cite.
    aliases : tuple of str
        Other accepted spellings.
    frame_tolerance : int or None
        Sequence datasets: positives are the frames at most this many frames away.
    frame_spacing : float or None
        Metres between consecutive frames in the downloader's dummy coordinates (Nordland), to recover frame
        indices from them.
    """

    name: str
    title: str
    folder: str
    split: str
    radius: float
    threshold: str
    position_kind: PositionKind
    n_database: int
    n_queries: int
    source: str
    citation: str
    aliases: tuple[str, ...] = ()
    frame_tolerance: int | None = None
    frame_spacing: float | None = None

    @property
    def relative_path(self) -> str:
        """Split folder relative to the data root, e.g. ``st_lucia/images/test``."""
        return f"{self.folder}/images/{self.split}"

    def to_dict(self) -> dict[str, object]:
        """JSON-serialisable fields."""
        return {**dataclasses.asdict(self), "aliases": list(self.aliases), "relative_path": self.relative_path}


NAMED_DATASETS: dict[str, NamedDataset] = {
    entry.name: entry
    for entry in (
        NamedDataset(
            name="pitts250k",
            title="Pittsburgh250k",
            folder="pitts250k",
            split="test",
            radius=DEFAULT_RADIUS,
            threshold="25 m",
            position_kind="metres",
            n_database=83_952,
            n_queries=8_280,
            source=f"images on request from the authors (Torii et al., NetVLAD project page); put them under "
            f"datasets/pitts250k/raw_data of {_DOWNLOADER} and run `python format_pitts250k.py`",
            citation="Torii et al., Visual Place Recognition with Repetitive Structures, TPAMI 2015",
            aliases=("pittsburgh250k", "pitts-250k", "pitts_250k"),
        ),
        NamedDataset(
            name="st_lucia",
            title="St Lucia",
            folder="st_lucia",
            split="test",
            radius=DEFAULT_RADIUS,
            threshold="25 m",
            position_kind="metres",
            n_database=1_549,
            n_queries=1_464,
            source=f"{_DOWNLOADER}: `python download_st_lucia.py`",
            citation="Milford and Wyeth, Mapping a Suburb With a Single Camera..., T-RO 2008",
            aliases=("stlucia", "st-lucia", "st lucia"),
        ),
        NamedDataset(
            name="nordland",
            title="Nordland",
            folder="nordland",
            split="test",
            radius=DEFAULT_RADIUS,
            threshold="±10 frames",
            position_kind="frames",
            n_database=27_592,
            n_queries=27_592,
            source=f"{_DOWNLOADER}: `python download_nordland.py` (the Patch-NetVLAD split, summer database, "
            "winter queries)",
            citation="Sünderhauf et al., Are we there yet? Challenging SeqSLAM on a 3000 km journey..., ICRA-W 2013",
            frame_tolerance=10,
            frame_spacing=DEFAULT_RADIUS / 10.5,
        ),
        NamedDataset(
            name="amstertime",
            title="AmsterTime",
            folder="amstertime",
            split="test",
            radius=DEFAULT_RADIUS,
            threshold="its own pair",
            position_kind="placeholder",
            n_database=1_231,
            n_queries=1_231,
            source=f"{_DOWNLOADER}: `python download_amstertime.py`",
            citation="Yildiz et al., AmsterTime: A Visual Place Recognition Benchmark Dataset..., ICPR 2022",
            aliases=("amster_time", "amster-time"),
        ),
        NamedDataset(
            name="eynsham",
            title="Eynsham",
            folder="eynsham",
            split="test",
            radius=DEFAULT_RADIUS,
            threshold="25 m",
            position_kind="metres",
            n_database=23_935,
            n_queries=23_935,
            source=f"{_DOWNLOADER}: `python download_eynsham.py`",
            citation="Cummins and Newman, Highly scalable appearance-only SLAM - FAB-MAP 2.0, RSS 2009",
        ),
        NamedDataset(
            name="tokyo247",
            title="Tokyo 24/7",
            folder="tokyo247",
            split="test",
            radius=DEFAULT_RADIUS,
            threshold="25 m",
            position_kind="metres",
            n_database=75_984,
            n_queries=315,
            source=f"database images on request from the authors (Torii et al., 24/7 Tokyo project page); put "
            f"them under datasets/tokyo247/raw_data of {_DOWNLOADER} and run `python format_tokyo247.py` "
            "(it fetches the queries)",
            citation="Torii et al., 24/7 Place Recognition by View Synthesis, TPAMI 2018",
            aliases=("tokyo", "tokyo24/7", "tokyo_247", "tokyo-247", "tokyo24_7"),
        ),
    )
}


def _normalise(name: str) -> str:
    return name.strip().lower().replace(" ", "_")


def get_named_dataset(name: str) -> NamedDataset:
    """The entry of a named dataset (case-insensitive; aliases accepted).

    Raises
    ------
    KeyError
        Listing the known names.
    """
    key = _normalise(name)
    for entry in NAMED_DATASETS.values():
        if key == entry.name or key in {_normalise(alias) for alias in entry.aliases}:
            return entry
    raise KeyError(f"unknown dataset {name!r}; named datasets: {', '.join(NAMED_DATASETS)}")


def data_root(root: str | Path | None = None) -> Path | None:
    """The data root: ``root`` when given, else ``$VPR_UNCERTAINTY_DATA``, else None."""
    if root is not None:
        return Path(root).expanduser()
    value = os.environ.get(DATA_ROOT_VARIABLE)
    return Path(value).expanduser() if value else None


def _has_split(folder: Path) -> bool:
    return any((folder / name).is_dir() for name in DATABASE_FOLDERS) and any(
        (folder / name).is_dir() for name in QUERY_FOLDERS
    )


def find_named_dataset(name: str, root: str | Path | None = None, *, split: str | None = None) -> Path | None:
    """The split folder of a named dataset under the data root, or None when it is not there."""
    entry = get_named_dataset(name)
    base = data_root(root)
    if base is None:
        return None
    for folder in (base / entry.folder, base / "datasets" / entry.folder):
        candidate = folder / "images" / (split or entry.split)
        if _has_split(candidate):
            return candidate
    return None


def _missing_message(entry: NamedDataset, root: Path | None, split: str) -> str:
    layout = f"{entry.folder}/images/{split}/database/ and {entry.folder}/images/{split}/queries/"
    if root is None:
        where = (
            f"no data root is set: pass root= (--root DIR on the command line) or set {DATA_ROOT_VARIABLE} to "
            f"the folder that holds {entry.folder}/"
        )
    else:
        where = f"looked for {root / entry.folder / 'images' / split} (and under {root / 'datasets'})"
    put = f"<root>/{entry.folder}" if root is None else str(root / entry.folder)
    return (
        f"dataset {entry.name!r} ({entry.title}) not found: {where}. Get it: {entry.source}. Put the folder it "
        f"makes (datasets/{entry.folder}) at {put}, so that {layout} exist, or use the downloader's datasets/ "
        "folder as the root."
    )


def _frames_from_dummy(dataset: Dataset, entry: NamedDataset, tolerance: float) -> Dataset:
    """Nordland as exported by the downloader: recover frame indices from the dummy coordinates.

    The downloader puts frame k at (0, k · 25/10.5 m), rounded to 0.1 m, so that 25 m means ±10 frames. Frame
    indices make the positives exact and the positions honest (``position_kind="frames"``). Positions that do not
    follow that layout are left as they are.
    """
    assert entry.frame_spacing is not None
    assert dataset.database_positions is not None and dataset.query_positions is not None
    both = np.concatenate([dataset.database_positions, dataset.query_positions])
    line = _line_coordinate(both)
    if line is None:
        return dataset
    frames = line / entry.frame_spacing
    if np.abs(frames - np.round(frames)).max() > 0.1:
        return dataset
    frames = np.round(frames)
    positions = np.column_stack([frames, np.zeros_like(frames)])
    n_database = dataset.n_database
    return dataclasses.replace(
        dataset,
        database_positions=positions[:n_database],
        query_positions=positions[n_database:],
        positives=positives_within_frames(frames[n_database:], frames[:n_database], tolerance),
        positive_radius=float(tolerance),
        position_kind="frames",
        info={
            **dataset.info,
            "positions": f"frame index, recovered from dummy UTM ({entry.frame_spacing:.4f} m/frame)",
        },
    )


def _load_named(entry: NamedDataset, root: str | Path | None, split: str | None, radius: float | None) -> Dataset:
    split = split or entry.split
    base = data_root(root)
    folder = find_named_dataset(entry.name, base, split=split)
    if folder is None:
        raise FileNotFoundError(_missing_message(entry, base, split))
    dataset = load_folder_dataset(
        folder,
        split=split,
        radius=entry.radius if radius is None or entry.frame_spacing is not None else radius,
        name=entry.name,
        position_kind=entry.position_kind,
    )
    if entry.frame_spacing is not None:
        dataset = _frames_from_dummy(dataset, entry, entry.frame_tolerance if radius is None else radius)
    if split == entry.split and (dataset.n_database, dataset.n_queries) != (entry.n_database, entry.n_queries):
        warnings.warn(
            f"{entry.title} at {folder} has {dataset.n_database} database images and {dataset.n_queries} queries; "
            f"the standard {split} split has {entry.n_database} and {entry.n_queries}: the download may be "
            "incomplete or another version",
            stacklevel=3,
        )
    return dataset


def detect_format(path: str | Path) -> str:
    """The format of a dataset path: ``"folder"``, ``"vprbench"``, ``"table"`` or ``"poses"``.

    Raises
    ------
    FileNotFoundError
        When the path does not exist.
    ValueError
        When it is none of the supported layouts (the message lists them).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no such file or folder: {path}")
    if path.is_file():
        suffix = path.suffix.lower()
        if suffix == ".npz":
            return "poses"
        if suffix in {".csv", ".tsv", ".txt"}:
            return "table"
        raise ValueError(
            f"{path}: unknown dataset file type {suffix!r}; expected .npz (utmQ, utmDb, posDistThr) or "
            ".csv/.tsv (image paths with positions)"
        )
    if (path / "ground_truth_new.npy").is_file() or ((path / "query").is_dir() and (path / "ref").is_dir()):
        return "vprbench"
    for candidate in (path, *(path / "images").glob("*"), *path.glob("*")):
        if candidate.is_dir() and _has_split(candidate):
            return "folder"
    raise ValueError(
        f"{path} is not a dataset folder: expected images/<split>/database/ and queries/ (VPR-datasets-downloader) "
        "or query/, ref/ and ground_truth_new.npy (VPR-Bench)"
    )


def load_dataset(
    path_or_name: str | Path,
    *,
    root: str | Path | None = None,
    split: str | None = None,
    radius: float | None = None,
    queries: str | Path | None = None,
    name: str | None = None,
    position_kind: PositionKind | None = None,
) -> Dataset:
    """Read a dataset from a path (format detected) or a name of :data:`NAMED_DATASETS`.

    Parameters
    ----------
    path_or_name : str or Path
        An existing file or folder (VPR-datasets-downloader folder, VPR-Bench folder, CSV/TSV table, ``.npz``
        of positions), or a dataset name such as ``"st_lucia"`` looked up under the data root. An existing path
        wins over a name.
    root : str or Path, optional
        Data root for named datasets; by default ``$VPR_UNCERTAINTY_DATA``.
    split : str, optional
        Split of a folder-format or named dataset (default: ``"test"``, or the named dataset's).
    radius : float, optional
        Positive threshold (metres; frames for frame positions); by default the dataset's own (25 m; the
        ``posDistThr`` of a position file; ±10 frames for Nordland).
    queries : str or Path, optional
        Table of query images, when ``path_or_name`` is the table of database images.
    name : str, optional
        Dataset name (paths only); by default from the path.
    position_kind : {"metres", "frames", "placeholder"}, optional
        What the positions are (paths only); detected by default.

    Returns
    -------
    Dataset

    Raises
    ------
    FileNotFoundError
        For a named dataset that is not under the root: the message says where to get it and where to put it.
        Also when the argument is neither an existing path nor a known name.
    ValueError
        When a path is in none of the supported layouts.
    """
    path = Path(path_or_name).expanduser()
    if not path.exists():
        try:
            entry = get_named_dataset(str(path_or_name))
        except KeyError:
            raise FileNotFoundError(
                f"{str(path_or_name)!r} is neither an existing file or folder nor a named dataset "
                f"({', '.join(NAMED_DATASETS)})"
            ) from None
        return _load_named(entry, root, split, radius)
    file_format = detect_format(path)
    if file_format == "vprbench":
        from vpr_uncertainty.data.vprbench import load_vprbench_dataset

        if radius is not None:
            raise ValueError(f"{path} is a VPR-Bench dataset with explicit ground truth: radius does not apply")
        return load_vprbench_dataset(path, name=name)
    if file_format == "table":
        from vpr_uncertainty.data.table import load_table_dataset

        return load_table_dataset(
            path,
            queries=queries,
            radius=DEFAULT_RADIUS if radius is None else radius,
            name=name,
            position_kind=position_kind,
        )
    if file_format == "poses":
        from vpr_uncertainty.data.poses import load_poses_dataset

        return load_poses_dataset(path, radius=radius, name=name, position_kind=position_kind)
    split_folder = find_split_folder(path, split or "test")
    return load_folder_dataset(
        split_folder,
        split=split or "test",
        radius=DEFAULT_RADIUS if radius is None else radius,
        name=name,
        position_kind=position_kind,
    )
