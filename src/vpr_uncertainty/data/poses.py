"""Position files ``.npz`` with ``utmQ``, ``utmDb`` and ``posDistThr`` (Patch-NetVLAD's ground-truth files).

``utmQ`` (Q, 2) and ``utmDb`` (D, 2) are UTM positions in metres and ``posDistThr`` the positive radius (25 m
for Pittsburgh and Tokyo 24/7). The files carry no image names, so the dataset has positions and positives but
no image paths; its query and database indices follow the order of the arrays (Patch-NetVLAD's
``*_imageNames_query.txt`` / ``*_imageNames_index.txt`` lists).

Nordland's file stores frame i as (i, i) and ``posDistThr = 10``: the threshold is a frame tolerance. This reader
recognises frame positions (:func:`~vpr_uncertainty.data.dataset.detect_position_kind`) and takes as positives the
database frames at most ``posDistThr`` frames away (±10, the Nordland convention, same as
VPR-datasets-downloader). Patch-NetVLAD itself applied the threshold as a Euclidean radius to the (i, i)
points, i.e. ±7 frames (10 / √2); pass ``position_kind="metres"`` to reproduce that.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vpr_uncertainty.data.dataset import Dataset, PositionKind, _line_coordinate, detect_position_kind
from vpr_uncertainty.data.positives import DEFAULT_RADIUS, positives_within_frames, positives_within_radius

__all__ = ["load_poses_dataset"]


def load_poses_dataset(
    path: str | Path,
    *,
    radius: float | None = None,
    name: str | None = None,
    position_kind: PositionKind | None = None,
) -> Dataset:
    """Read query and database positions from an ``.npz`` with ``utmQ``, ``utmDb`` and ``posDistThr``.

    Parameters
    ----------
    path : str or Path
        The ``.npz`` file.
    radius : float, optional
        Positive threshold; by default ``posDistThr`` from the file (25 m when absent). In frames when the
        positions are frame indices.
    name : str, optional
        Dataset name; by default the file name without suffix.
    position_kind : {"metres", "frames", "placeholder"}, optional
        What the positions are; detected by default. ``"frames"`` computes positives by frame difference along
        the line the positions lie on; any other kind by Euclidean distance.

    Returns
    -------
    Dataset
        Positions-only (``database_paths`` and ``query_paths`` are None).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"position file not found: {path}")
    with np.load(path, allow_pickle=False) as archive:
        missing = [key for key in ("utmQ", "utmDb") if key not in archive.files]
        if missing:
            raise ValueError(
                f"{path}: expected arrays utmQ (queries × 2) and utmDb (database × 2) and optionally posDistThr, "
                f"missing {', '.join(missing)} (found {', '.join(sorted(archive.files))})"
            )
        query_positions = archive["utmQ"]
        database_positions = archive["utmDb"]
        threshold = float(archive["posDistThr"]) if "posDistThr" in archive.files else None
    for key, array in (("utmQ", query_positions), ("utmDb", database_positions)):
        if array.ndim != 2 or array.shape[1] != 2:
            raise ValueError(f"{path}: {key} must have shape (n, 2), got {array.shape}")
    if radius is None:
        radius = threshold if threshold is not None else DEFAULT_RADIUS
    if position_kind is None:
        position_kind = detect_position_kind(database_positions, query_positions)
    if position_kind == "frames":
        frames = _line_coordinate(np.concatenate([database_positions, query_positions]).astype(np.float64))
        if frames is None:
            raise ValueError(f"{path}: position_kind='frames' needs positions on a line, e.g. frame i at (i, i)")
        n_database = len(database_positions)
        positives = positives_within_frames(frames[n_database:], frames[:n_database], radius)
    else:
        positives = positives_within_radius(query_positions, database_positions, radius)
    return Dataset(
        name=name or path.stem,
        root=path.parent,
        positives=positives,
        database_positions=database_positions,
        query_positions=query_positions,
        positive_radius=radius,
        position_kind=position_kind,
        source_format="poses",
        info={"file": path.name, **({"posDistThr": threshold} if threshold is not None else {})},
    )
