"""Fetch the VPR-Bench corridor dataset (the demo's data) with checksums, or say where to put it.

The corridor dataset (Milford, IJRR 2013) is distributed inside the VPR-Bench repository (Zaffar et al., IJCV 2021,
MIT licence): 111 query and 111 reference images of 160 × 120 pixels and ``ground_truth_new.npy``. Files are
fetched from a pinned commit and each is checked against the SHA-256 listed in ``corridor_sha256.json``; a file
is only moved into place once its checksum matches.
"""

from __future__ import annotations

import hashlib
import json
import os
import urllib.error
import urllib.request
from importlib import resources
from pathlib import Path

__all__ = [
    "CORRIDOR_COMMIT",
    "CORRIDOR_URL",
    "corridor_archive_url",
    "corridor_files",
    "default_data_root",
    "ensure_corridor",
    "verify_corridor",
]

#: The pinned commit of the VPR-Bench repository the corridor files are fetched from.
CORRIDOR_COMMIT = "1f78cf83661886840ba4ef9ac3d66a01db2f1458"
#: Base address of the corridor files at that commit: each file is ``CORRIDOR_URL/<relative path>`` (a folder
#: address itself is not downloadable; the relative paths are the keys of ``corridor_sha256.json``).
CORRIDOR_URL = f"https://raw.githubusercontent.com/MubarizZaffar/VPR-Bench/{CORRIDOR_COMMIT}/datasets/corridor"


def corridor_archive_url() -> str:
    """The downloadable archive of the VPR-Bench repository at the pinned commit (the corridor is its
    ``datasets/corridor`` folder)."""
    return f"https://github.com/MubarizZaffar/VPR-Bench/archive/{CORRIDOR_COMMIT}.zip"


def default_data_root() -> Path:
    """``VPR_UNCERTAINTY_DATA`` if set, else a per-user cache directory (``$XDG_CACHE_HOME/vpr-uncertainty``)."""
    if os.environ.get("VPR_UNCERTAINTY_DATA"):
        return Path(os.environ["VPR_UNCERTAINTY_DATA"])
    cache = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(cache) / "vpr-uncertainty"


def corridor_files() -> dict[str, str]:
    """Relative path → SHA-256 of every corridor file."""
    text = resources.files("vpr_uncertainty.data").joinpath("corridor_sha256.json").read_text()
    return json.loads(text)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def verify_corridor(folder: str | Path) -> list[str]:
    """Relative paths of the corridor files that are missing or whose checksum differs (empty when complete)."""
    folder = Path(folder)
    return [
        name
        for name, digest in corridor_files().items()
        if not (folder / name).is_file() or _sha256(folder / name) != digest
    ]


def ensure_corridor(root: str | Path | None = None, *, download: bool = True, timeout: float = 20.0) -> Path:
    """Return the corridor folder under ``root/vprbench/corridor``, downloading missing files if allowed.

    Parameters
    ----------
    root : str or Path, optional
        The data root; by default :func:`default_data_root`.
    download : bool
        Fetch missing or corrupt files from :data:`CORRIDOR_URL`.
    timeout : float
        Seconds to wait for each file.

    Raises
    ------
    FileNotFoundError
        When files are missing and cannot be downloaded (offline, or ``download=False``); the message says which
        files and where to put them.
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
        from vpr_uncertainty.cache import atomic_write
        from vpr_uncertainty.progress import progress_bar

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
