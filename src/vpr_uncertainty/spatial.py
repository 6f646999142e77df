"""SUE: spatial uncertainty from how far apart the retrieved database images were taken (Zaffar, Nan, Kooij, CVPR
2024); higher = less trustworthy. The method, why the default clip is symmetric (the published code's is one-sided),
and hard input: see docs/explanation/uncertainty-scores.md.
"""

from __future__ import annotations

import numbers
import warnings

import numpy as np

from vpr_uncertainty._validation import check_count
from vpr_uncertainty.methods import register_method
from vpr_uncertainty.retrieval import Retrieval
from vpr_uncertainty.scores import squared_distances_from_similarities

#: Slope of the weights exp(−slope · d²) in the published implementation.
DEFAULT_SLOPE = 350.0
#: Largest deviation from the mean position, in metres, that counts in full.
MAX_DEVIATION = 500.0
CLIP_MODES: tuple[str, ...] = ("symmetric", "one-sided", "none")


def _real(value: object, name: str, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {value!r}")
    value = float(value)
    if not np.isfinite(value) or value < 0 or (positive and value == 0):
        bound = "> 0" if positive else ">= 0"
        raise ValueError(f"{name} must be a finite number {bound}, got {value}")
    return value


def check_sue_options(
    *, k: int = 10, slope: float = DEFAULT_SLOPE, clip: str = "symmetric", max_deviation: float = MAX_DEVIATION
) -> tuple[float, float]:
    """Validate SUE's options (raise ValueError or TypeError naming the bad one); returns (slope, max_deviation).

    Examples
    --------
    >>> check_sue_options(clip="one-sided", slope=300)
    (300.0, 500.0)
    """
    check_count(k, "k", 1)
    if clip not in CLIP_MODES:
        raise ValueError(f"clip must be one of {', '.join(CLIP_MODES)}, got {clip!r}")
    return _real(slope, "slope"), _real(max_deviation, "max_deviation", positive=True)


def spatial_uncertainty(
    indices: object,
    distances: object,
    database_positions: object,
    k: int = 10,
    *,
    slope: float = DEFAULT_SLOPE,
    clip: str = "symmetric",
    max_deviation: float = MAX_DEVIATION,
) -> np.ndarray:
    """SUE: the weighted spatial variance of the top-k retrieved database positions.

    Parameters
    ----------
    indices : array-like of int of shape (Q, K)
        Database index of each candidate, best first; ``-1`` marks a missing candidate.
    distances : array-like of shape (Q, K)
        Squared L2 descriptor distances of the same candidates (``2 − 2·s`` for cosine similarities s of
        L2-normalised descriptors); values at missing candidates are ignored.
    database_positions : array-like of shape (D, m)
        Position of every database image, in metres (m = 2: UTM easting and northing).
    k : int, default=10
        Candidates used: the first ``min(k, K)`` columns.
    slope : float, default=350
        Sharpness of the weights exp(−slope · d²); 0 weighs all candidates equally.
    clip : {"symmetric", "one-sided", "none"}, default="symmetric"
        How deviations from the mean are clipped at ``max_deviation`` (docs/explanation/uncertainty-scores.md):
        ``"symmetric"`` |Δ| ≤ max_deviation, ``"one-sided"`` min(max_deviation, Δ) as published, ``"none"``.
    max_deviation : float, default=500
        Clipping threshold, in the unit of the positions.

    Returns
    -------
    ndarray of shape (Q,), float64
        Uncertainty (m²), higher = less trustworthy; 0 when all candidates were taken at one place.

    Examples
    --------
    >>> positions = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 2000.0]])
    >>> spatial_uncertainty([[0, 1], [0, 2]], [[0.1, 0.1], [0.1, 0.1]], positions)
    array([1.25e+01, 1.25e+05])
    >>> spatial_uncertainty([[0, 1], [0, 2]], [[0.1, 0.1], [0.1, 0.1]], positions, clip="none")
    array([1.25e+01, 5.00e+05])
    """
    slope, max_deviation = check_sue_options(k=k, slope=slope, clip=clip, max_deviation=max_deviation)
    indices, distances, positions = np.asarray(indices), np.asarray(distances), np.asarray(database_positions)
    if indices.ndim != 2 or not np.issubdtype(indices.dtype, np.integer):
        raise ValueError(f"indices must be a 2-D integer array (n_queries, k), got {indices.dtype} {indices.shape}")
    if distances.shape != indices.shape:
        raise ValueError(f"distances must have the shape of indices {indices.shape}, got {distances.shape}")
    if positions.ndim != 2 or positions.shape[1] < 1 or not np.issubdtype(positions.dtype, np.number):
        raise ValueError(f"database_positions must be a numeric array of shape (n_database, 2), got {positions.shape}")
    n_queries = indices.shape[0]
    if n_queries == 0:
        return np.empty(0, dtype=np.float64)
    n = min(k, indices.shape[1])
    if n == 0:
        raise ValueError("indices has no columns: each query needs at least one candidate")
    top = indices[:, :n]
    valid = top >= 0
    if top.max() >= len(positions):
        raise ValueError(
            f"indices refer to database image {int(top.max())} but database_positions has {len(positions)} rows"
        )
    empty = ~valid.any(axis=1)
    if empty.any():
        rows = np.flatnonzero(empty)
        raise ValueError(f"{rows.size} queries have no candidate (first: query {int(rows[0])}); SUE needs at least one")
    squared = np.where(valid, distances[:, :n].astype(np.float64, copy=False), np.inf)
    if np.isnan(squared).any() or (squared < 0).any() or np.isposinf(squared[valid]).any():
        row = int(np.flatnonzero((np.isnan(squared) | (squared < 0) | (np.isposinf(squared) & valid)).any(axis=1))[0])
        raise ValueError(
            f"distances must be finite squared L2 distances >= 0 at the candidates; query {row} has "
            f"{distances[row, :n].tolist()}"
        )
    # Stable softmax of −slope·d: the nearest candidate gets exp(0) = 1, so the sum is >= 1.
    shifted = squared - squared.min(axis=1, keepdims=True)
    with np.errstate(over="ignore", invalid="ignore"):
        weights = np.exp(-slope * shifted) if slope > 0 else valid.astype(np.float64)
    weights[~valid] = 0.0
    weights /= weights.sum(axis=1, keepdims=True)

    candidates = positions[np.where(valid, top, 0)].astype(np.float64, copy=False)  # (Q, n, m)
    if not np.isfinite(candidates[valid]).all():
        row = int(np.flatnonzero((~np.isfinite(candidates).all(axis=2) & valid).any(axis=1))[0])
        raise ValueError(f"database_positions of the candidates of query {row} are not finite")
    # Relative to the heaviest candidate: keeps UTM-sized coordinates (~1e6 m) from cancelling in the variance.
    reference = np.take_along_axis(candidates, weights.argmax(axis=1)[:, None, None], axis=1)
    relative = candidates - reference
    relative[~valid] = 0.0
    mean = np.einsum("qn,qnm->qm", weights, relative)
    deviation = relative - mean[:, None, :]
    if clip == "symmetric":
        np.clip(deviation, -max_deviation, max_deviation, out=deviation)
    elif clip == "one-sided":
        np.minimum(deviation, max_deviation, out=deviation)
    variance = np.einsum("qn,qnm->qm", weights, deviation * deviation)
    return variance.mean(axis=1)


def _position_kind(config: dict) -> str | None:
    """``config["position_kind"]``, else the dataset summary's ``config["dataset"]["position_kind"]``."""
    if config.get("position_kind") is not None:
        return config["position_kind"]
    dataset = config.get("dataset")
    return dataset.get("position_kind") if isinstance(dataset, dict) else None


def sue_from_retrieval(
    retrieval: Retrieval,
    *,
    k: int = 10,
    slope: float = DEFAULT_SLOPE,
    clip: str = "symmetric",
    max_deviation: float = MAX_DEVIATION,
) -> np.ndarray:
    """SUE of every query of a retrieval: the registry entry ``"SUE"`` (see :func:`spatial_uncertainty`).

    Uses ``retrieval.distances`` when present, else the distances 2 − 2·s of cosine similarities s, and
    ``retrieval.database_positions``, which must be present.

    Parameters
    ----------
    retrieval : Retrieval
        With ``database_positions``. A ``config["position_kind"]`` (or ``config["dataset"]["position_kind"]``,
        as written by :meth:`vpr_uncertainty.data.Dataset.retrieval_fields`) other than ``"metres"`` gives a
        :class:`~vpr_uncertainty.data.dataset.PlaceholderPositionsWarning`.
    k, slope, clip, max_deviation
        As in :func:`spatial_uncertainty`.

    Returns
    -------
    ndarray of shape (Q,)
        Uncertainty, higher = less trustworthy.
    """
    if retrieval.database_positions is None:
        raise ValueError(
            "SUE needs the positions of the database images (retrieval.database_positions); give them to "
            "retrieve (argument database_positions) or use a dataset with positions"
        )
    kind = _position_kind(retrieval.config)
    if kind is not None and kind != "metres":
        from vpr_uncertainty.data.dataset import PlaceholderPositionsWarning

        warnings.warn(
            f"SUE assumes positions in metres, but this retrieval's positions are {kind!r}: its 500 m clip and its "
            "variance have no metric meaning here",
            PlaceholderPositionsWarning,
            stacklevel=2,
        )
    if retrieval.distances is not None:
        squared = retrieval.distances
    else:
        squared = squared_distances_from_similarities(np.asarray(retrieval.scores, dtype=np.float64), method="SUE")
    return spatial_uncertainty(
        retrieval.indices, squared, retrieval.database_positions, k, slope=slope, clip=clip, max_deviation=max_deviation
    )


register_method(
    "SUE",
    sue_from_retrieval,
    description="Spatial uncertainty: weighted spread of the top-k database positions (Zaffar et al. 2024)",
    requires=("database_positions",),
    options={"k": 10, "slope": DEFAULT_SLOPE, "clip": "symmetric", "max_deviation": MAX_DEVIATION},
    validate=check_sue_options,
    kind="spatial",
    scores="cosine",  # weights from d² = 2 − 2s unless the retrieval holds its distances
)
