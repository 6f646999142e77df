"""The GV-* uncertainty methods: −(RANSAC inliers between each query and its top-1), shape (Q,).

Higher = less trustworthy, as for every method of the toolkit; a query without a top-1 candidate (index -1)
gets 0 inliers. ``GV-SIFT``, ``GV-DISK-LG``, ``GV-XFEAT``, ``GV-SP-SG`` and ``GV-SP-LG`` run the presets of
:mod:`vpr_uncertainty.geometric.presets`; ``GV-H5`` verifies precomputed local features (hloc HDF5).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from vpr_uncertainty.data.images import check_image_counts
from vpr_uncertainty.geometric.local_features import DEFAULT_MAX_SIDE
from vpr_uncertainty.geometric.matching import NearestNeighborMatcher
from vpr_uncertainty.geometric.presets import H5_MODULES, require_modules
from vpr_uncertainty.geometric.verify import GeometricVerifier, verify_retrieval
from vpr_uncertainty.retrieval import Retrieval

__all__ = [
    "gv_disk_lightglue",
    "gv_h5",
    "gv_sift",
    "gv_superpoint_lightglue",
    "gv_superpoint_superglue",
    "gv_xfeat",
]


def _check_paths(
    retrieval: Retrieval,
    query_paths: Sequence[str | Path] | None,
    database_paths: Sequence[str | Path] | None,
    method: str,
) -> None:
    if query_paths is None or database_paths is None:
        raise ValueError(
            f"{method} verifies images: it needs the query and database image files "
            "(options query_paths=..., database_paths=..., indexed like the retrieval)"
        )
    check_image_counts(
        retrieval,
        len(query_paths),
        len(database_paths),
        queries=f"{method}: query_paths{_folder_of(query_paths)}",
        database=f"{method}: database_paths{_folder_of(database_paths)}",
    )


def _folder_of(paths: Sequence[str | Path]) -> str:
    """`` (under FOLDER)``: the deepest folder holding every path, for messages; empty when there is none."""
    try:
        folder = os.path.commonpath([os.path.dirname(os.fspath(path)) for path in paths])
    except (TypeError, ValueError):  # no paths, or absolute and relative paths mixed
        return ""
    return f" (under {folder})" if folder else ""


def _preset_method(name: str, function_name: str) -> Callable[..., np.ndarray]:
    """The uncertainty-method function of the GV preset ``name``, called ``function_name``."""

    def method(
        retrieval: Retrieval,
        *,
        query_paths: Sequence[str | Path] | None = None,
        database_paths: Sequence[str | Path] | None = None,
        cache_dir: str | Path | None = None,
        max_side: int = DEFAULT_MAX_SIDE,
        workers: int | None = None,
        device: str = "cpu",
        seed: int = 0,
        superpoint_weights: str | Path | None = None,
        matcher_weights: str | Path | None = None,
        executor: Any = None,
    ) -> np.ndarray:
        _check_paths(retrieval, query_paths, database_paths, name)
        verifier = GeometricVerifier.from_preset(
            name,
            max_side=max_side,
            device=device,
            cache_dir=cache_dir,
            workers=workers,
            seed=seed,
            superpoint_weights=superpoint_weights,
            matcher_weights=matcher_weights,
            executor=executor,
        )
        result = verify_retrieval(retrieval, verifier, query_paths=query_paths, database_paths=database_paths)
        return -result.inliers[:, 0].astype(np.float64)

    method.__name__ = method.__qualname__ = function_name
    method.__doc__ = f"""{name}: −(RANSAC inliers between each query and its top-1), shape (Q,); higher = doubt more.

    Options: ``query_paths``, ``database_paths`` (image files indexed like the retrieval; required),
    ``cache_dir`` (HDF5 feature caches; none by default), ``max_side`` (working resolution, default
    {DEFAULT_MAX_SIDE}), ``workers`` (threads; default the CPU cores up to 8), ``device`` ("cpu" or "cuda"),
    ``seed`` (RANSAC), ``superpoint_weights`` / ``matcher_weights`` (local weight files, GV-SP-* only),
    ``executor`` (where the pairs are matched and verified: a
    :func:`~vpr_uncertainty.executors.get_executor` executor; default this process; the local features are
    extracted and cached once per image in this process either way; the inliers are the same).
    """
    return method


gv_sift = _preset_method("GV-SIFT", "gv_sift")
gv_disk_lightglue = _preset_method("GV-DISK-LG", "gv_disk_lightglue")
gv_xfeat = _preset_method("GV-XFEAT", "gv_xfeat")
gv_superpoint_superglue = _preset_method("GV-SP-SG", "gv_superpoint_superglue")
gv_superpoint_lightglue = _preset_method("GV-SP-LG", "gv_superpoint_lightglue")


def gv_h5(
    retrieval: Retrieval,
    *,
    features_path: str | Path | None = None,
    query_paths: Sequence[str | Path] | None = None,
    database_paths: Sequence[str | Path] | None = None,
    ratio: float | None = 0.8,
    mutual: bool = True,
    model: Literal["homography", "fundamental"] = "homography",
    ransac_threshold: float = 3.0,
    max_side: int = DEFAULT_MAX_SIDE,
    workers: int | None = None,
    seed: int = 0,
    executor: Any = None,
) -> np.ndarray:
    """GV-H5: −inliers of the top-1 from precomputed local features in an hloc-layout HDF5 file.

    Any local feature (DELF, R2D2, ALIKED, hloc's SuperPoint, ...) extracted by another tool is verified with
    mutual nearest-neighbour matching, Lowe's ratio test (``ratio``, None to skip) and USAC/MAGSAC++.

    Images are looked up by name: their path relative to the deepest folder holding all ``query_paths`` and
    ``database_paths`` (hloc's naming, e.g. ``query/0001.jpg``), else their file name; without paths, by the
    retrieval's ``query_names`` and ``database_names``. Keypoints are in original-image pixels (hloc) and
    ``ransac_threshold`` is in pixels at ``max_side``, as for the other GV methods. ``executor``: where the
    pairs are matched and verified (as for the other GV methods).
    """
    if features_path is None:
        raise ValueError("GV-H5 needs features_path: an HDF5 file of local features in hloc's layout")
    if query_paths is not None or database_paths is not None:
        _check_paths(retrieval, query_paths, database_paths, "GV-H5")
    require_modules("uncertainty method 'GV-H5'", H5_MODULES)
    verifier = GeometricVerifier(
        None,
        NearestNeighborMatcher(ratio=ratio, mutual=mutual),
        model=model,
        ransac_threshold=ransac_threshold,
        max_side=max_side,
        features_path=features_path,
        workers=workers,
        seed=seed,
        executor=executor,
    )
    result = verify_retrieval(retrieval, verifier, query_paths=query_paths, database_paths=database_paths)
    return -result.inliers[:, 0].astype(np.float64)
