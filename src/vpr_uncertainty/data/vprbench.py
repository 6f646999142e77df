"""Readers for the legacy files of the VPR-Bench benchmark (Zaffar et al., IJCV 2021).

VPR-Bench stores its ground truth and its precomputed matches as NumPy *object* arrays, whose payload is a
pickle. These readers never unpickle with ``pickle.load``: they use
:func:`~vpr_uncertainty.data.legacy_pickle.restricted_unpickle`, which rebuilds NumPy arrays, numbers, strings
and lists and refuses every other global (``os.system``, ``builtins.eval``, ...) with an error naming the file, so
no code from the file can run. The results are identical to ``np.load(path, allow_pickle=True,
encoding="latin1")`` on VPR-Bench's files.

:func:`load_vprbench_dataset` reads a whole VPR-Bench image dataset (``query/``, ``ref/``, ground truth) into a
:class:`~vpr_uncertainty.data.dataset.Dataset`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import sparse

from vpr_uncertainty.data.dataset import Dataset
from vpr_uncertainty.data.ground_truth import VPRBENCH_GROUND_TRUTH, positives_from_vprbench_rows
from vpr_uncertainty.data.npy import read_npy

__all__ = [
    "PickleWarning",
    "load_vprbench_dataset",
    "load_vprbench_ground_truth",
    "load_vprbench_similarity",
]

_MATCHES = (
    "VPR-Bench precomputed matches (an object array of 6 items: query indices, top-1 indices, top-1 scores, "
    "similarity matrix, encoding time, matching time)"
)


class PickleWarning(UserWarning):
    """No longer issued: the legacy files are read with a restricted unpickler that cannot run code.

    Kept so that code filtering it keeps working.
    """


def load_vprbench_ground_truth(path: str | Path, *, n_database: int | None = None) -> sparse.csr_array:
    """Read VPR-Bench's ``ground_truth_new.npy``: rows of [query index, list of positive database indices].

    Parameters
    ----------
    path : str or Path
        The ``.npy`` file.
    n_database : int, optional
        Number of database images; by default the largest positive index + 1.

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool

    Raises
    ------
    ValueError
        When the file is not such an object array, holds anything but integer indices in range, or its pickled
        payload names a global other than NumPy array reconstruction (nothing from the file is run).
    """
    path = Path(path)
    rows = read_npy(path, what=VPRBENCH_GROUND_TRUTH, allow_objects=True)
    return positives_from_vprbench_rows(rows, path, n_database=n_database)


def load_vprbench_similarity(path: str | Path) -> np.ndarray:
    """Read the full similarity matrix from VPR-Bench's ``precomputed_data_corrected.npy``.

    The file holds [query indices, top-1 indices, top-1 scores, similarity matrix, encoding time, matching
    time]; the matrix has one row per query and one column per database image, higher = more similar.

    Returns
    -------
    ndarray of shape (Q, D), float32

    Raises
    ------
    ValueError
        When the file does not have that layout (e.g. a plain numeric matrix), or its pickled payload names a
        global other than NumPy array reconstruction (nothing from the file is run).
    """
    path = Path(path)
    content = read_npy(path, what=_MATCHES, allow_objects=True)
    if content.dtype != object:
        raise ValueError(
            f"{path} is a plain {content.dtype} array of shape {content.shape}, not {_MATCHES}; "
            "read it as a similarity matrix (format 'matrix')"
        )
    if content.shape != (6,):
        raise ValueError(f"{path}: expected {_MATCHES}, got an object array of shape {content.shape}")
    similarity = content[3]
    if not isinstance(similarity, np.ndarray) or similarity.dtype.kind not in "iuf" or similarity.ndim != 2:
        found = (
            f"a {similarity.dtype} array of shape {similarity.shape}"
            if isinstance(similarity, np.ndarray)
            else type(similarity).__name__
        )
        raise ValueError(f"{path}: item 3 should be the numeric (queries × database) similarity matrix, got {found}")
    order = content[0]
    # Some of VPR-Bench's own files (ap-gem-r101) store the query indices as floats 0.0, 1.0, ...: compared exactly.
    if not isinstance(order, np.ndarray) or order.dtype.kind not in "iuf" or order.ndim != 1:
        raise ValueError(f"{path}: item 0 should be the query indices 0..{similarity.shape[0] - 1}, got {order!r:.80}")
    if len(order) != similarity.shape[0] or not np.array_equal(order, np.arange(len(order))):
        raise ValueError(f"{path}: expected query indices 0..{similarity.shape[0] - 1} in order")
    return similarity.astype(np.float32)


def load_vprbench_dataset(root: str | Path, *, name: str | None = None, n_database: int | None = None) -> Dataset:
    """Read a VPR-Bench image dataset: ``query/``, ``ref/`` and ``ground_truth_new.npy``.

    The ground truth is an explicit list of positives per query (no positions): see
    :func:`load_vprbench_ground_truth`.

    Parameters
    ----------
    root : str or Path
        The dataset folder, e.g. ``VPR-Bench/datasets/corridor``.
    name : str, optional
        Dataset name; by default the folder name.
    n_database : int, optional
        The number of reference images the ground truth is about. By default the largest positive index + 1: the
        ground truth's own count, which ``ref/`` must match (give it only for a dataset whose last reference
        images are no query's positive).

    Returns
    -------
    Dataset
        Database = ``ref/`` images, queries = ``query/`` images, each sorted by name, hidden files (``.*``) left
        out; names relative to ``root`` (``ref/0000000.jpg``); no positions.

    Raises
    ------
    FileNotFoundError
        When a folder or the ground truth is missing.
    ValueError
        When the number of images in ``query/`` or ``ref/`` differs from the ground truth's (the message names the
        folder and both counts): one stray or missing image would shift every index after it.
    """
    from vpr_uncertainty.data.folder import list_images

    root = Path(root)
    paths = {}
    for folder in ("query", "ref"):
        if not (root / folder).is_dir():
            raise FileNotFoundError(f"{root} is not a VPR-Bench dataset: no {folder}/ folder (expected query/, ref/)")
        paths[folder] = list_images(root / folder)
        if not paths[folder]:
            raise FileNotFoundError(f"no image found under {root / folder}")
    ground_truth = root / "ground_truth_new.npy"
    if not ground_truth.is_file():
        raise FileNotFoundError(f"{root} is not a VPR-Bench dataset: no ground_truth_new.npy")
    positives = load_vprbench_ground_truth(ground_truth, n_database=n_database)
    if positives.shape[1] != len(paths["ref"]):
        covered = (
            f"is about {positives.shape[1]} database images (n_database)"
            if n_database is not None
            else f"covers {positives.shape[1]} database images (its largest positive index is {positives.shape[1] - 1})"
        )
        raise ValueError(
            f"{root / 'ref'} holds {len(paths['ref'])} images but the ground truth {ground_truth} {covered}: a stray "
            "or missing image would shift every index after it; remove the extra file (or, when the last reference "
            "images are no query's positive, give n_database)"
        )
    if positives.shape[0] != len(paths["query"]):
        raise ValueError(
            f"{ground_truth} has ground truth for {positives.shape[0]} queries but {root / 'query'} holds "
            f"{len(paths['query'])} images"
        )
    return Dataset(
        name=name or root.name,
        root=root,
        positives=positives,
        database_paths=paths["ref"],
        query_paths=paths["query"],
        source_format="vprbench",
        info={"ground_truth": ground_truth.name},
    )
