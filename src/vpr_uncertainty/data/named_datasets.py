"""The named benchmark datasets under a data root, the corridor download, and load_dataset."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import urllib.error
import urllib.request
import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from vpr_uncertainty.cache import atomic_write, user_cache_dir
from vpr_uncertainty.data.dataset import Dataset
from vpr_uncertainty.data.formats import (
    DATASET_FORMAT_REGISTRY,
    detect_format,
    is_vprbench_folder,
    load_vprbench_dataset,
)
from vpr_uncertainty.data.images import has_split, load_folder_dataset
from vpr_uncertainty.plugins import Registry, load_target
from vpr_uncertainty.progress import progress_bar
from vpr_uncertainty.retrieval.ground_truth import PositionKind, line_coordinate, positives_within_frames

# --- the corridor download ---

#: The pinned commit of the VPR-Bench repository the corridor files are fetched from.
CORRIDOR_COMMIT = "1f78cf83661886840ba4ef9ac3d66a01db2f1458"
#: Base address of the corridor files at that commit: each file is ``CORRIDOR_URL/<relative path>`` (a folder
#: address itself is not downloadable; the relative paths are the keys of ``corridor_sha256.json``).
CORRIDOR_URL = f"https://raw.githubusercontent.com/MubarizZaffar/VPR-Bench/{CORRIDOR_COMMIT}/datasets/corridor"


def corridor_archive_url() -> str:
    """The archive of the VPR-Bench repository at the pinned commit (the corridor is its ``datasets/corridor``)."""
    return f"https://github.com/MubarizZaffar/VPR-Bench/archive/{CORRIDOR_COMMIT}.zip"


def default_data_root() -> Path:
    """``$VPR_UNCERTAINTY_DATA`` (:func:`data_root`) if set, else :func:`~vpr_uncertainty.cache.user_cache_dir`."""
    return data_root() or user_cache_dir()


def corridor_files() -> dict[str, str]:
    """Relative path → SHA-256 of every corridor file."""
    text = resources.files("vpr_uncertainty.data").joinpath("corridor_sha256.json").read_text()
    return json.loads(text)


def verify_corridor(folder: str | Path) -> list[str]:
    """Relative paths of the corridor files that are missing or whose checksum differs (empty when complete)."""
    folder = Path(folder)
    return [
        name
        for name, digest in corridor_files().items()
        if not (folder / name).is_file() or hashlib.sha256((folder / name).read_bytes()).hexdigest() != digest
    ]


def ensure_corridor(root: str | Path | None = None, *, download: bool = True, timeout: float = 20.0) -> Path:
    """The VPR-Bench corridor folder (the demo's data) ``root/vprbench/corridor``, fetching missing files if allowed.

    ``root`` defaults to :func:`default_data_root`. With ``download``, missing or corrupt files are fetched from
    :data:`CORRIDOR_URL` (``timeout`` seconds each), checked against ``corridor_sha256.json`` and only then moved into
    place. Raises FileNotFoundError, saying which files and where to put them, when they cannot be had.
    """
    folder = Path(root or default_data_root()) / "vprbench" / "corridor"
    missing = verify_corridor(folder) if folder.is_dir() else list(corridor_files())
    if not missing:
        return folder
    where = (
        f"Put the VPR-Bench corridor dataset into {folder}: download each file from {CORRIDOR_URL}/<file> "
        f"(e.g. {CORRIDOR_URL}/ground_truth_new.npy, {CORRIDOR_URL}/query/0000000.jpg; the {len(corridor_files())} "
        "files and their SHA-256 are listed in the package's vpr_uncertainty/data/corridor_sha256.json, and "
        f"ensure_corridor(root) fetches and checks them when online), or unpack datasets/corridor of "
        f"{corridor_archive_url()} there; or point VPR_UNCERTAINTY_DATA at a data root that holds vprbench/corridor."
    )
    if not download:
        raise FileNotFoundError(f"{len(missing)} corridor files are missing or corrupt (first: {missing[0]}). {where}")
    digests = corridor_files()
    try:
        for name in progress_bar(missing, desc="downloading corridor", unit="file"):
            target = folder / name
            target.parent.mkdir(parents=True, exist_ok=True)
            with urllib.request.urlopen(f"{CORRIDOR_URL}/{name}", timeout=timeout) as response:
                content = response.read()
            if hashlib.sha256(content).hexdigest() != digests[name]:
                raise OSError(f"checksum mismatch for {name} downloaded from {CORRIDOR_URL}")
            with atomic_write(target, "wb") as handle:  # a full disk names the file; nothing half-written kept
                handle.write(content)
    except (urllib.error.URLError, OSError, TimeoutError) as error:
        raise FileNotFoundError(
            f"cannot download the corridor dataset ({error}); this machine may be offline. {where}"
        ) from error
    return folder


#: Environment variable naming the data root.
DATA_ROOT_VARIABLE = "VPR_UNCERTAINTY_DATA"


@dataclass(frozen=True)
class NamedDataset:
    """A benchmark dataset (a record of ``named_datasets.json``): where it is expected, how its positives are made.

    Attributes
    ----------
    name, title : str
        The name to type (``load_dataset("st_lucia")``) and the usual name in papers; ``aliases`` other spellings.
    folder, split, path : str
        Folder under the data root, the default split, and the split folder when not ``<folder>/images/<split>``.
    radius : float
        Positive radius in metres on the coordinates of the image names (``threshold``: the same in words).
    position_kind : {"metres", "frames", "placeholder"}
        What the coordinates in the image names are.
    n_database, n_queries : int
        Image counts of the standard split (another count gives a warning).
    source, citation : str
        Where to get the data and how to format it; the paper to cite.
    frame_tolerance, frame_spacing : int and float, or None
        Sequence datasets: positives are the frames at most ``frame_tolerance`` apart; ``frame_spacing`` metres
        between frames in the downloader's dummy coordinates (Nordland) recovers the frame indices.
    layout : {"downloader", "vprbench"}
        VPR-datasets-downloader's folders (positions in the names) or VPR-Bench's (``query/``, ``ref/``, positives).
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
    layout: str = "downloader"
    path: str | None = None

    @property
    def relative_path(self) -> str:
        """Split folder relative to the data root, e.g. ``st_lucia/images/test``."""
        return self.path if self.path is not None else f"{self.folder}/images/{self.split}"

    def to_dict(self) -> dict[str, object]:
        """JSON-serialisable fields."""
        return {**dataclasses.asdict(self), "aliases": list(self.aliases), "relative_path": self.relative_path}


def _normalise(name: str) -> str:
    return name.strip().lower().replace(" ", "_")


def read_named_datasets(text: str | None = None) -> list[NamedDataset]:
    """The records of ``named_datasets.json`` (or of the JSON ``text``), checked field by field."""
    if text is None:
        text = resources.files("vpr_uncertainty.data").joinpath("named_datasets.json").read_text(encoding="utf-8")
    document = json.loads(text)
    downloader = str(document.get("downloader", ""))
    fields = {item.name for item in dataclasses.fields(NamedDataset)}
    records = []
    for number, record in enumerate(document["datasets"]):
        unknown = sorted(set(record) - fields)
        if unknown:
            raise ValueError(
                f"named_datasets.json, record {number}: unknown fields {unknown} (valid: {sorted(fields)})"
            )
        source = record["source"].replace("{downloader}", downloader).replace("{corridor_url}", CORRIDOR_URL)
        record = {**record, "source": source.replace("{corridor_archive}", corridor_archive_url())}
        records.append(NamedDataset(**{**record, "aliases": tuple(record.get("aliases", ()))}))
    return records


#: The named datasets: records read from the package's ``named_datasets.json`` (names and aliases).
NAMED_DATASET_REGISTRY: Registry[NamedDataset] = Registry("dataset", normalise=_normalise, label="named datasets")


for _record in read_named_datasets():
    NAMED_DATASET_REGISTRY.register(_record, aliases=_record.aliases)


def get_named_dataset(name: str) -> NamedDataset:
    """The entry of a named dataset (case-insensitive; aliases accepted).

    Raises
    ------
    KeyError
        Listing the known names.
    """
    return NAMED_DATASET_REGISTRY.get(name)


def data_root(root: str | Path | None = None) -> Path | None:
    """The data root: ``root`` when given, else ``$VPR_UNCERTAINTY_DATA``, else None."""
    if root is not None:
        return Path(root).expanduser()
    value = os.environ.get(DATA_ROOT_VARIABLE)
    return Path(value).expanduser() if value else None


def find_named_dataset(name: str, root: str | Path | None = None, *, split: str | None = None) -> Path | None:
    """The split folder of a named dataset under the data root, or None when it is not there."""
    entry = get_named_dataset(name)
    base = data_root(root)
    if base is None:
        return None
    if entry.layout == "vprbench":
        candidate = base / entry.relative_path
        return candidate if is_vprbench_folder(candidate) else None
    split = split or entry.split
    candidates = [base / entry.path] if entry.path is not None and split == entry.split else []
    for folder in (base / entry.folder, base / "datasets" / entry.folder):
        candidates += [folder / "images" / split, folder / split]  # some downloader versions omit images/
    return next((candidate for candidate in candidates if has_split(candidate)), None)


def _missing_message(entry: NamedDataset, root: Path | None, split: str) -> str:
    if entry.layout == "vprbench":
        where = (
            f"looked for {root / entry.relative_path}"
            if root is not None
            else f"no data root is set (--root DIR or {DATA_ROOT_VARIABLE}: the folder holding {entry.relative_path})"
        )
        return f"dataset {entry.name!r} ({entry.title}) not found: {where}. Get it: {entry.source}."
    layout = f"{entry.folder}/images/{split}/database/ and {entry.folder}/images/{split}/queries/"
    if root is None:
        where = (
            f"no data root is set: pass root= (the data root) or set {DATA_ROOT_VARIABLE} to "
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
    """Nordland as the downloader exports it (frame k at (0, k · 25/10.5 m)): frame indices and exact positives."""
    assert entry.frame_spacing is not None
    assert dataset.database_positions is not None and dataset.query_positions is not None
    both = np.concatenate([dataset.database_positions, dataset.query_positions])
    line = line_coordinate(both)
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
        info=dict(dataset.info, positions=f"frame index, recovered from dummy UTM ({entry.frame_spacing:.4f} m/frame)"),
    )


def _load_named(entry: NamedDataset, root: str | Path | None, split: str | None, radius: float | None) -> Dataset:
    split = split or entry.split
    base = data_root(root)
    folder = find_named_dataset(entry.name, base, split=split)
    if folder is None:
        raise FileNotFoundError(_missing_message(entry, base, split))
    if entry.layout == "vprbench":
        return load_vprbench_dataset(folder, name=entry.name)
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
    """Read a dataset from a path (format detected) or a name of :data:`NAMED_DATASET_REGISTRY`.

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
                f"({', '.join(NAMED_DATASET_REGISTRY.names())})"
            ) from None
        return _load_named(entry, root, split, radius)
    entry = DATASET_FORMAT_REGISTRY.get(detect_format(path))
    reader = load_target(entry.reader, what=f"dataset format {entry.name!r}", extra=entry.extra)
    return reader(path, split=split, radius=radius, queries=queries, name=name, position_kind=position_kind)
