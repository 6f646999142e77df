"""Geometric verification: local features + matching + RANSAC -> inlier counts; the GV-* uncertainty methods.

Uncertainty = −(number of RANSAC inliers between a query and its top-1 database image): higher = less
trustworthy, as for every method of the toolkit. A query without a top-1 candidate (index -1) gets 0 inliers.

Pipeline of one call
--------------------
1. The images that appear in a pair are extracted once each (database images shared by several queries
   included), read from the HDF5 cache in ``cache_dir`` when they are there (see
   :mod:`vpr_uncertainty.geometric.cache`). Images are shrunk to ``max_side`` (default 640, see
   :mod:`vpr_uncertainty.geometric.local_features`).
2. Pairs are matched in ``workers`` threads at once (numpy and torch release the GIL; a torch matcher then
   runs on one torch thread per pair); on CUDA, torch matchers take the pairs one after another.
3. RANSAC (USAC/MAGSAC++, :mod:`vpr_uncertainty.geometric.ransac`) in ``workers`` threads.

Presets (the method names) are the entries of :data:`~vpr_uncertainty.geometric.presets.GV_PRESETS`
(``GV-SIFT``, ``GV-DISK-LG``, ``GV-XFEAT``, ``GV-SP-SG``, ``GV-SP-LG``); ``GV-H5`` verifies precomputed local
features in an hloc HDF5 file with mutual NN ratio matching. RANSAC: homography MAGSAC++, 3 px.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from vpr_uncertainty.geometric.cache import ExtractionStats, extract_features, image_names, read_features
from vpr_uncertainty.geometric.local_features import (
    DEFAULT_MAX_SIDE,
    Extractor,
    LocalFeatures,
    check_max_side,
    default_workers,
    single_blas_thread,
    single_torch_thread,
)
from vpr_uncertainty.geometric.matching import Matcher
from vpr_uncertainty.geometric.presets import GV_PRESETS, PRESETS, build_components
from vpr_uncertainty.geometric.ransac import MIN_MATCHES, count_inliers
from vpr_uncertainty.progress import progress_bar
from vpr_uncertainty.retrieval import Retrieval

__all__ = [
    "PRESETS",
    "GeometricVerifier",
    "VerificationResult",
    "verify_retrieval",
]


@dataclass
class VerificationResult:
    """Inliers of each verified pair and where the time went.

    Attributes
    ----------
    inliers : ndarray of shape (P,), int64
        RANSAC inliers per pair (0 for a missing candidate, too few matches, or no model).
    matches : ndarray of shape (P,), int64
        Tentative matches per pair before RANSAC.
    extraction : ExtractionStats
        Images extracted and read from the cache, and the seconds spent.
    matching_seconds, ransac_seconds : float
    """

    inliers: np.ndarray
    matches: np.ndarray
    extraction: ExtractionStats = field(default_factory=ExtractionStats)
    matching_seconds: float = 0.0
    ransac_seconds: float = 0.0


class GeometricVerifier:
    """An extractor, a matcher and a RANSAC configuration, applied to image pairs.

    Parameters
    ----------
    extractor : Extractor or None
        None when the features come from a file (``features_path``).
    matcher : Matcher
    model : {"homography", "fundamental"}
        Model fitted by RANSAC (see :mod:`vpr_uncertainty.geometric.ransac` for the choice of the defaults).
    ransac_threshold : float
        Pixels at the working resolution.
    max_side : int
        Working resolution: longer image side in pixels (never enlarged).
    cache_dir : path, optional
        Folder of the feature caches (HDF5, hloc layout, one file per extractor configuration).
    features_path : path, optional
        An hloc-layout HDF5 file that already holds the features of every image (instead of ``extractor``).
    workers : int, optional
        Threads for image reading, OpenCV extraction, NN matching and RANSAC; torch threads on CPU.
    seed : int
        Seed of RANSAC's sampler.
    executor : LocalExecutor or RayExecutor, optional
        Where the local features are extracted and the pairs matched and verified: in this process (default), or
        in chunks as Ray tasks (:mod:`vpr_uncertainty.geometric.distributed`); the features are cached once per
        image by this process either way.

    Examples
    --------
    >>> from vpr_uncertainty.geometric import GeometricVerifier
    >>> verifier = GeometricVerifier.from_preset("GV-SIFT", cache_dir="runs/corridor/local_features")  # doctest: +SKIP
    >>> verifier.verify(["q.jpg"], ["d0.jpg", "d1.jpg"], [(0, 1)]).inliers  # doctest: +SKIP
    array([57])
    """

    def __init__(
        self,
        extractor: Extractor | None,
        matcher: Matcher,
        *,
        model: Literal["homography", "fundamental"] = "homography",
        ransac_threshold: float = 3.0,
        max_side: int = DEFAULT_MAX_SIDE,
        cache_dir: str | Path | None = None,
        features_path: str | Path | None = None,
        workers: int | None = None,
        seed: int = 0,
        executor: Any = None,
    ) -> None:
        if (extractor is None) == (features_path is None):
            raise ValueError("give either an extractor or features_path (precomputed features), not both or neither")
        if model not in MIN_MATCHES:
            raise ValueError(f"model must be one of {sorted(MIN_MATCHES)}, got {model!r}")
        if not ransac_threshold > 0:
            raise ValueError(f"ransac_threshold must be > 0 pixels, got {ransac_threshold!r}")
        self.extractor = extractor
        self.matcher = matcher
        self.model = model
        self.ransac_threshold = float(ransac_threshold)
        self.max_side = check_max_side(max_side)
        self.cache_dir = None if cache_dir is None else Path(cache_dir)
        self.features_path = None if features_path is None else Path(features_path)
        if self.features_path is not None and not self.features_path.is_file():
            raise FileNotFoundError(f"features file {self.features_path} does not exist")
        self.workers = default_workers() if workers is None else max(1, int(workers))
        self.seed = int(seed)
        if executor is not None and not (callable(getattr(executor, "map", None)) and hasattr(executor, "name")):
            raise ValueError(
                "executor must be an executor of vpr_uncertainty.executors.get_executor (local or ray), "
                f"got {executor!r}"
            )
        self.executor = executor

    @classmethod
    def from_preset(
        cls,
        name: str,
        *,
        max_side: int = DEFAULT_MAX_SIDE,
        device: str = "cpu",
        max_keypoints: int | None = None,
        superpoint_weights: str | Path | None = None,
        matcher_weights: str | Path | None = None,
        download: bool = True,
        **options: Any,
    ) -> GeometricVerifier:
        """A verifier for a registered preset (:data:`~vpr_uncertainty.geometric.presets.GV_PRESETS`); ``options``
        go to :class:`GeometricVerifier`.

        ``superpoint_weights`` / ``matcher_weights`` are local paths of the official SuperPoint and SuperGlue /
        LightGlue weights (GV-SP-SG, GV-SP-LG); without them the files are looked up or downloaded.
        """
        max_side = check_max_side(max_side)
        try:
            preset = GV_PRESETS.get(name)
        except KeyError as error:
            raise ValueError(error.args[0]) from None
        on_cuda = str(device).startswith("cuda")
        runtime = {"max_side": max_side, "device": device, "batch_size": 8 if on_cuda else 1, "download": download}
        extractor, matcher = build_components(
            preset,
            options=None if max_keypoints is None else {"extractor": {"max_keypoints": int(max_keypoints)}},
            runtime={**runtime, "weights": superpoint_weights},
            matcher_runtime={**runtime, "weights": matcher_weights},
        )
        return cls(extractor, matcher, max_side=max_side, **options)

    # --- running -------------------------------------------------------------------------------------------

    def _features(self, paths: list[Path], names: list[str]) -> tuple[dict[str, LocalFeatures], ExtractionStats]:
        if self.extractor is not None:
            options = {"cache_dir": self.cache_dir, "workers": self.workers, "executor": self.executor}
            return extract_features(paths, self.extractor, names=names, **options)
        start = time.perf_counter()
        import h5py

        with h5py.File(self.features_path, "r") as handle:
            features = {name: read_features(handle, _h5_key(handle, name)) for name in dict.fromkeys(names)}
        return features, ExtractionStats(cached=len(features), seconds=time.perf_counter() - start)

    def verify_names(
        self,
        pairs: Sequence[tuple[str, str]],
        paths: dict[str, Path] | None = None,
    ) -> VerificationResult:
        """Inliers of pairs of image names (``paths`` maps names to files; not needed with ``features_path``)."""
        needed = list(dict.fromkeys(name for pair in pairs for name in pair))
        if self.extractor is not None:
            if paths is None:
                raise ValueError("the images' paths are needed to extract their features")
            features, stats = self._features([paths[name] for name in needed], needed)
        else:
            features, stats = self._features([], needed)
        if self.executor is not None and self.executor.name != "local" and len(pairs) > 1:
            from vpr_uncertainty.geometric.distributed import verify_on_executor

            all_matches, inliers, matching, ransac = verify_on_executor(self, features, list(pairs))
        else:
            all_matches, inliers, matching, ransac = self._match_and_count(features, list(pairs))
        return VerificationResult(
            inliers=np.asarray(inliers, np.int64).reshape(-1),
            matches=np.asarray(all_matches, np.int64).reshape(-1),
            extraction=stats,
            matching_seconds=matching,
            ransac_seconds=ransac,
        )

    def _match_and_count(
        self, features: dict[str, LocalFeatures], pairs: list[tuple[str, str]]
    ) -> tuple[list[int], list[int], float, float]:
        """Matches and RANSAC inliers of each pair, with the matching and RANSAC seconds, in this process."""
        matching_start = time.perf_counter()

        def match(pair: tuple[str, str]) -> np.ndarray:
            return self.matcher.match(features[pair[0]], features[pair[1]], max_side=self.max_side)

        uses_torch = getattr(self.matcher, "uses_torch", False)
        blas = contextlib.nullcontext() if uses_torch else single_blas_thread()
        if self.matcher.thread_parallel and self.workers > 1 and len(pairs) > 1:
            with blas, single_torch_thread(uses_torch), ThreadPoolExecutor(self.workers) as pool:
                all_matches = list(progress_bar(pool.map(match, pairs), total=len(pairs), desc="matching", unit="pair"))
        else:
            with blas, single_torch_thread(uses_torch and self.matcher.thread_parallel):
                all_matches = [match(pair) for pair in progress_bar(pairs, desc="matching", unit="pair")]
        ransac_start = time.perf_counter()

        def ransac(item: tuple[tuple[str, str], np.ndarray]) -> int:
            (name0, name1), matches = item
            if len(matches) < MIN_MATCHES[self.model]:
                return 0
            points0, _ = features[name0].at_working_resolution(self.max_side)
            points1, _ = features[name1].at_working_resolution(self.max_side)
            return count_inliers(
                points0[matches[:, 0]],
                points1[matches[:, 1]],
                model=self.model,
                threshold=self.ransac_threshold,
                seed=self.seed,
            )

        items = list(zip(pairs, all_matches, strict=True))
        if self.workers > 1 and len(items) > 1:
            with ThreadPoolExecutor(self.workers) as pool:
                inliers = list(progress_bar(pool.map(ransac, items), total=len(items), desc="RANSAC", unit="pair"))
        else:
            inliers = [ransac(item) for item in progress_bar(items, desc="RANSAC", unit="pair")]
        end = time.perf_counter()
        return [len(m) for m in all_matches], inliers, ransac_start - matching_start, end - ransac_start

    def verify(
        self,
        query_paths: Sequence[str | Path] | None,
        database_paths: Sequence[str | Path] | None,
        pairs: object,
        *,
        query_names: Sequence[str] | None = None,
        database_names: Sequence[str] | None = None,
    ) -> VerificationResult:
        """Inliers of (query index, database index) pairs; a database index of -1 gives 0 inliers.

        Parameters
        ----------
        query_paths, database_paths : sequence of path
            Image files, indexed like the retrieval's rows and ``indices``. Their names (cache keys) are the
            paths relative to the deepest folder that holds all of them, as hloc names images.
        pairs : array-like of shape (P, 2), int
        query_names, database_names : sequence of str, optional
            Names to use instead (required with ``features_path`` when no paths are given).
        """
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        query_paths = None if query_paths is None else [Path(p) for p in query_paths]
        database_paths = None if database_paths is None else [Path(p) for p in database_paths]
        if query_names is None or database_names is None:
            if query_paths is None or database_paths is None:
                raise ValueError("give query_paths and database_paths (or query_names and database_names)")
            names = image_names([*query_paths, *database_paths])
            query_names = names[: len(query_paths)] if query_names is None else query_names
            database_names = names[len(query_paths) :] if database_names is None else database_names
        n_queries, n_database = len(query_names), len(database_names)
        if pairs.size and (pairs[:, 0].min() < 0 or pairs[:, 0].max() >= n_queries):
            raise ValueError(f"pairs refer to query {int(pairs[:, 0].max())} but there are {n_queries} query images")
        if pairs.size and pairs[:, 1].max() >= n_database:
            raise ValueError(
                f"pairs refer to database image {int(pairs[:, 1].max())} but there are {n_database} database images"
            )
        valid = pairs[:, 1] >= 0
        named = [(str(query_names[q]), str(database_names[d])) for q, d in pairs[valid]]
        paths = None
        if query_paths is not None and database_paths is not None:
            paths = dict(zip(map(str, query_names), query_paths, strict=True))
            paths.update(zip(map(str, database_names), database_paths, strict=True))
        result = self.verify_names(named, paths)
        inliers = np.zeros(len(pairs), np.int64)
        matches = np.zeros(len(pairs), np.int64)
        inliers[valid], matches[valid] = result.inliers, result.matches
        result.inliers, result.matches = inliers, matches
        return result


def _h5_key(handle: Any, name: str) -> str:
    """The group of ``name`` in an hloc file: the name itself, else the one group with the same file name."""
    if name in handle:
        return name
    base = Path(name).name
    if base in handle:
        return base
    return name  # read_features raises a KeyError that shows what the file's names look like


def verify_retrieval(
    retrieval: Retrieval,
    verifier: GeometricVerifier,
    *,
    query_paths: Sequence[str | Path] | None = None,
    database_paths: Sequence[str | Path] | None = None,
    top_k: int = 1,
) -> VerificationResult:
    """Inliers between every query and each of its first ``top_k`` candidates; ``inliers`` has shape (Q, top_k)."""
    k = min(int(top_k), retrieval.k)
    if k < 1:
        raise ValueError(f"top_k must be >= 1, got {top_k}")
    pairs = np.stack([np.repeat(np.arange(retrieval.n_queries), k), retrieval.indices[:, :k].reshape(-1)], axis=1)
    names: dict[str, Any] = {}
    if verifier.features_path is not None and (query_paths is None or database_paths is None):
        if retrieval.query_names is None or retrieval.database_names is None:
            raise ValueError("GV-H5 needs image names: give query_paths/database_paths or a retrieval with names")
        names = {"query_names": list(retrieval.query_names), "database_names": list(retrieval.database_names)}
    result = verifier.verify(query_paths, database_paths, pairs, **names)
    result.inliers = result.inliers.reshape(retrieval.n_queries, k)
    result.matches = result.matches.reshape(retrieval.n_queries, k)
    return result
