"""Local features, the working resolution, the extractor base class and OpenCV SIFT; matchers and RANSAC (OpenCV's
USAC with MAGSAC++). Importing this module imports neither torch nor OpenCV. Keypoint conventions, the working
resolution and why the RANSAC defaults are what they are: see docs/explanation/geometric-verification.md.
"""

from __future__ import annotations

import contextlib
import os
from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np


@contextlib.contextmanager
def single_torch_thread(active: bool) -> Iterator[None]:
    """When ``active``, run torch's CPU operators on one thread inside the block, then restore the previous setting."""
    if not active:
        yield
        return
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def images_to_tensor(images: list[np.ndarray], device: Any) -> Any:
    """A float32 (B, C, H, W) tensor in [0, 1] on ``device`` from equal-sized uint8 images ((H, W) or (H, W, C))."""
    import torch

    array = np.stack(images)
    if array.ndim == 3:
        array = array[..., None]
    return torch.from_numpy(array).permute(0, 3, 1, 2).to(device=device, dtype=torch.float32).div_(255.0)


DEFAULT_MAX_SIDE = 640


def default_workers() -> int:
    """Worker threads when none are given: the CPU cores, at most 8."""
    return max(1, min(8, os.cpu_count() or 1))


def check_max_side(max_side: object) -> int:
    if isinstance(max_side, bool) or not isinstance(max_side, (int, np.integer)) or max_side < 16:
        raise ValueError(f"max_side must be an integer >= 16 (pixels of the longer image side), got {max_side!r}")
    return int(max_side)


def working_scale(image_size: Sequence[int], max_side: int) -> float:
    """Factor from original pixels to working pixels: ``min(1, max_side / max(W, H))``."""
    longer = max(int(image_size[0]), int(image_size[1]))
    return 1.0 if longer <= max_side else max_side / longer


@dataclass
class LocalFeatures:
    """Keypoints and descriptors of one image (hloc's layout).

    Attributes
    ----------
    keypoints : ndarray of shape (N, 2), float32
        ``(x, y)`` in pixels of the original image.
    descriptors : ndarray of shape (N, D)
        One row per keypoint (hloc stores the transpose on disk).
    scores : ndarray of shape (N,), float32
        Detection scores (ones when the extractor gives none).
    image_size : ndarray of shape (2,), int64
        ``(width, height)`` of the original image.
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    scores: np.ndarray
    image_size: np.ndarray

    def __post_init__(self) -> None:
        self.keypoints = np.asarray(self.keypoints, dtype=np.float32).reshape(-1, 2)
        n = len(self.keypoints)
        self.descriptors = np.asarray(self.descriptors)
        if self.descriptors.ndim != 2 or self.descriptors.shape[0] != n:
            raise ValueError(f"descriptors must have shape ({n}, D) for {n} keypoints, got {self.descriptors.shape}")
        self.scores = np.ones(n, np.float32) if self.scores is None else np.asarray(self.scores, np.float32)
        if self.scores.shape != (n,):
            raise ValueError(f"scores must have shape ({n},), got {self.scores.shape}")
        self.image_size = np.asarray(self.image_size, dtype=np.int64).reshape(2)

    def __len__(self) -> int:
        return len(self.keypoints)

    @classmethod
    def empty(cls, image_size: Sequence[int], descriptor_dim: int, dtype: Any = np.float32) -> LocalFeatures:
        return cls(np.zeros((0, 2), np.float32), np.zeros((0, descriptor_dim), dtype), None, image_size)

    @classmethod
    def from_working(
        cls,
        keypoints: np.ndarray,
        descriptors: np.ndarray,
        scores: np.ndarray | None,
        *,
        original_size: Sequence[int],
        working_size: Sequence[int],
    ) -> LocalFeatures:
        """Features detected on a resized image, with their keypoints mapped back to the original image."""
        factor = np.asarray(original_size, np.float64) / np.asarray(working_size, np.float64)
        keypoints = (np.asarray(keypoints, np.float64).reshape(-1, 2) + 0.5) * factor - 0.5
        return cls(keypoints.astype(np.float32), descriptors, scores, original_size)

    def at_working_resolution(self, max_side: int) -> tuple[np.ndarray, tuple[int, int]]:
        """Keypoints in pixels of the image resized to ``max_side``, and that size ``(W, H)``."""
        scale = working_scale(self.image_size, max_side)
        size = (max(1, round(self.image_size[0] * scale)), max(1, round(self.image_size[1] * scale)))
        if scale == 1.0:
            return self.keypoints, size
        factor = np.asarray(size, np.float64) / self.image_size
        return ((self.keypoints + 0.5) * factor - 0.5).astype(np.float32), size


def load_image(path: str | Path, *, max_side: int, grayscale: bool) -> tuple[np.ndarray, tuple[int, int]]:
    """Read an image and shrink it so its longer side is at most ``max_side`` (area interpolation).

    The header is checked first with the loader of the global descriptors
    (:func:`~vpr_uncertainty.descriptors.images.read_image_size`): broken links, files that are not images and images
    over PIL's decompression-bomb limit (``PIL.Image.MAX_IMAGE_PIXELS``) are refused before OpenCV allocates
    anything, so decoding needs at most that many pixels. OpenCV then decodes the bytes (``cv2.imdecode``, which
    accepts any file name, including names that are not valid UTF-8).

    Returns
    -------
    image : ndarray of shape (H', W') uint8 when ``grayscale``, else (H', W', 3) RGB uint8
    original_size : (W, H) of the file

    Raises
    ------
    ValueError
        ``cannot read image <path>: <reason>``.
    """
    import cv2

    from vpr_uncertainty.descriptors.images import ImageDecodeError, printable, read_image_size

    path = Path(path)
    if not path.is_file() and not path.is_symlink():
        raise ValueError(f"cannot read image {printable(path)}: it does not exist")
    try:
        read_image_size(path)
    except ImageDecodeError as error:
        raise ValueError(f"cannot read image {printable(path)}: {error.reason}") from None
    flag = cv2.IMREAD_GRAYSCALE if grayscale else cv2.IMREAD_COLOR
    try:
        image = cv2.imdecode(np.fromfile(path, dtype=np.uint8), flag)
    except (OSError, cv2.error) as error:
        raise ValueError(f"cannot read image {printable(path)}: {error}") from None
    if image is None:
        raise ValueError(f"cannot read image {printable(path)}: OpenCV cannot decode it")
    if not grayscale:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    height, width = image.shape[:2]
    scale = working_scale((width, height), max_side)
    if scale < 1.0:
        size = (max(1, round(width * scale)), max(1, round(height * scale)))
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return image, (width, height)


def single_blas_thread() -> contextlib.AbstractContextManager[Any]:
    """NumPy's BLAS limited to one thread: the matrix products of one pair are small and the pairs run in parallel
    (threads here, processes under Ray), so BLAS threads only contend (20-30x slower matching on 2 busy cores)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


class Extractor(ABC):
    """Detects and describes local features; subclasses set ``name``, ``grayscale`` and ``_extract_batch``.

    Parameters
    ----------
    max_side : int
        Images are shrunk so their longer side is at most this many pixels before extraction.
    device : {"cpu", "cuda"}
        Where a torch model runs (ignored by OpenCV extractors).
    batch_size : int
        Images of the same size extracted together (useful on a GPU).
    """

    name: str = "extractor"
    grayscale: bool = True
    #: extraction releases the GIL (OpenCV), so images are processed by ``workers`` threads at once
    thread_parallel: bool = False
    #: a torch model: on CPU, ``workers`` threads with one torch thread each; on CUDA, batches in one thread
    uses_torch: bool = False
    #: the attributes (options) that :meth:`config` adds to the base configuration
    settings: tuple[str, ...] = ()

    def __init__(self, *, max_side: int = DEFAULT_MAX_SIDE, device: str = "cpu", batch_size: int = 1) -> None:
        self.max_side = check_max_side(max_side)
        self.device = device
        self.batch_size = max(1, int(batch_size))

    def config(self) -> dict[str, Any]:
        """Everything that changes the output; the feature cache is keyed by it."""
        base = {"name": self.name, "max_side": self.max_side, "grayscale": self.grayscale}
        return {**base, **{key: getattr(self, key) for key in self.settings}}

    @abstractmethod
    def _extract_batch(self, images: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
        """Keypoints (N, 2) in pixels of the given images, descriptors (N, D), scores (N,) or None, per image."""

    def extract(
        self, paths: Sequence[str | Path], *, workers: int | None = None
    ) -> Iterator[tuple[int, LocalFeatures]]:
        """Yield ``(position in paths, features)`` for every image, in an order that may differ from ``paths``."""
        workers = default_workers() if workers is None else max(1, int(workers))

        def load(path: str | Path) -> tuple[np.ndarray, tuple[int, int]]:
            return load_image(path, max_side=self.max_side, grayscale=self.grayscale)

        def finish(item: tuple[np.ndarray, tuple[int, int]], result: tuple) -> LocalFeatures:
            (image, original), (keypoints, descriptors, scores) = item, result
            size = (image.shape[1], image.shape[0])
            return LocalFeatures.from_working(keypoints, descriptors, scores, original_size=original, working_size=size)

        if self.thread_parallel or (self.uses_torch and not str(self.device).startswith("cuda")):
            # OpenCV, or a torch model on CPU: one image per thread, each on one torch thread (inter-op
            # parallelism beats intra-op on small images and on a busy machine)
            with single_torch_thread(self.uses_torch), ThreadPoolExecutor(workers) as pool:

                def one(path: str | Path) -> LocalFeatures:
                    item = load(path)
                    return finish(item, self._extract_batch([item[0]])[0])

                yield from enumerate(pool.map(one, paths))
            return
        # torch models on a GPU: images read by threads, the model runs in this thread on batches of equal size
        with ThreadPoolExecutor(workers) as pool:
            pending: list[tuple[int, tuple[np.ndarray, tuple[int, int]]]] = []
            for position, item in enumerate(pool.map(load, paths)):
                if pending and (len(pending) >= self.batch_size or pending[0][1][0].shape != item[0].shape):
                    yield from self._run(pending, finish)
                    pending = []
                pending.append((position, item))
            if pending:
                yield from self._run(pending, finish)

    def _run(self, pending: list, finish: Any) -> Iterator[tuple[int, LocalFeatures]]:
        results = self._extract_batch([item[0] for _, item in pending])
        for (position, item), result in zip(pending, results, strict=True):
            yield position, finish(item, result)


class SIFTExtractor(Extractor):
    """OpenCV's SIFT detector and descriptor on the grayscale image.

    Parameters
    ----------
    max_keypoints : int
        The strongest keypoints kept per image (OpenCV's ``nfeatures``).
    root_sift : bool
        Map descriptors to RootSIFT (L1-normalise, square root), which matches better under Euclidean distance.
    contrast_threshold : float
        OpenCV's ``contrastThreshold`` (its default, 0.04).
    max_side, device, batch_size
        See :class:`~vpr_uncertainty.geometric.local_features.Extractor`.
    """

    name = "sift"
    grayscale = True
    thread_parallel = True
    settings = ("max_keypoints", "root_sift", "contrast_threshold")

    def __init__(
        self,
        *,
        max_keypoints: int = 4096,
        root_sift: bool = False,
        contrast_threshold: float = 0.04,
        max_side: int = DEFAULT_MAX_SIDE,
        device: str = "cpu",
        batch_size: int = 1,
    ) -> None:
        super().__init__(max_side=max_side, device=device, batch_size=batch_size)
        import cv2

        self.max_keypoints = int(max_keypoints)
        self.root_sift = bool(root_sift)
        self.contrast_threshold = float(contrast_threshold)
        self._cv2 = cv2

    def config(self) -> dict[str, Any]:
        return {**super().config(), "opencv": self._cv2.__version__}

    def _extract_batch(self, images: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        # one detector per call: cv2.SIFT objects are not documented as thread-safe
        sift = self._cv2.SIFT_create(nfeatures=self.max_keypoints, contrastThreshold=self.contrast_threshold)
        results = []
        for image in images:
            keypoints, descriptors = sift.detectAndCompute(image, None)
            if descriptors is None or not keypoints:
                results.append((np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32), np.zeros(0, np.float32)))
                continue
            points = np.array([keypoint.pt for keypoint in keypoints], np.float32)
            scores = np.array([keypoint.response for keypoint in keypoints], np.float32)
            descriptors = descriptors.astype(np.float32)
            if self.root_sift:
                descriptors /= np.maximum(descriptors.sum(axis=1, keepdims=True), 1e-8)
                descriptors = np.sqrt(descriptors)
            results.append((points, descriptors, scores))
        return results


class Matcher(Protocol):
    name: str
    #: whether ``match`` may run in several threads at once (numpy and torch on CPU release the GIL)
    thread_parallel: bool
    #: a torch model: parallel threads then run with one torch thread each
    uses_torch: bool

    def config(self) -> dict[str, Any]: ...

    def match(self, features0: LocalFeatures, features1: LocalFeatures, *, max_side: int) -> np.ndarray: ...


def match_nearest_neighbors(
    descriptors0: np.ndarray, descriptors1: np.ndarray, *, ratio: float | None = 0.8, mutual: bool = True
) -> np.ndarray:
    """Nearest-neighbour matches under Euclidean distance, filtered by Lowe's ratio test and a mutual check.

    Parameters
    ----------
    descriptors0, descriptors1 : ndarray of shape (N0, D) and (N1, D)
    ratio : float or None
        Keep a match when its distance is below ``ratio`` times the distance to the second-nearest neighbour
        (Lowe 2004 uses 0.8); None skips the test.
    mutual : bool
        Keep only matches that are also the nearest neighbour in the other direction.

    Returns
    -------
    ndarray of shape (M, 2), int64

    Examples
    --------
    >>> a = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    >>> b = np.array([[0.0, 0.05], [1.0, 0.1], [0.6, 0.6]])
    >>> match_nearest_neighbors(a, b, ratio=0.8)
    array([[0, 0],
           [1, 1]])
    """
    d0 = np.asarray(descriptors0, np.float32)
    d1 = np.asarray(descriptors1, np.float32)
    if d0.ndim != 2 or d1.ndim != 2 or d0.shape[1] != d1.shape[1]:
        raise ValueError(f"descriptors must be (N0, D) and (N1, D) with the same D, got {d0.shape} and {d1.shape}")
    need = 2 if ratio is not None else 1
    if len(d0) == 0 or len(d1) < need:
        return np.zeros((0, 2), np.int64)
    squared = (
        np.einsum("ij,ij->i", d0, d0)[:, None] + np.einsum("ij,ij->i", d1, d1)[None, :] - 2.0 * (d0 @ d1.T)
    ).astype(np.float64)
    np.maximum(squared, 0.0, out=squared)
    nearest = np.argmin(squared, axis=1)
    rows = np.arange(len(d0))
    keep = np.ones(len(d0), bool)
    if ratio is not None:
        best = squared[rows, nearest]
        squared[rows, nearest] = np.inf
        second = squared.min(axis=1)
        squared[rows, nearest] = best
        keep &= best < (ratio**2) * second
    if mutual:
        keep &= np.argmin(squared, axis=0)[nearest] == rows
    return np.stack([rows[keep], nearest[keep]], axis=1).astype(np.int64)


class NearestNeighborMatcher:
    """Mutual nearest neighbours with Lowe's ratio test (any float descriptor: SIFT, hloc files, DELF, ...)."""

    name = "nn-ratio"
    thread_parallel = True
    uses_torch = False

    def __init__(self, *, ratio: float | None = 0.8, mutual: bool = True) -> None:
        if ratio is not None and not 0.0 < ratio <= 1.0:
            raise ValueError(f"ratio must lie in (0, 1] or be None, got {ratio!r}")
        self.ratio = ratio
        self.mutual = bool(mutual)

    def config(self) -> dict[str, Any]:
        return {"name": self.name, "ratio": self.ratio, "mutual": self.mutual}

    def match(self, features0: LocalFeatures, features1: LocalFeatures, *, max_side: int) -> np.ndarray:
        return match_nearest_neighbors(
            features0.descriptors, features1.descriptors, ratio=self.ratio, mutual=self.mutual
        )


#: fewest matches a model can be fitted to; below it the count is 0
MIN_MATCHES = {"homography": 4, "fundamental": 8}


def count_inliers(
    points0: np.ndarray,
    points1: np.ndarray,
    *,
    model: Literal["homography", "fundamental"] = "homography",
    threshold: float = 3.0,
    confidence: float = 0.999,
    max_iterations: int = 10_000,
    seed: int = 0,
) -> int:
    """Number of matches consistent with the model found by USAC/MAGSAC++.

    Parameters
    ----------
    points0, points1 : ndarray of shape (M, 2)
        Matched keypoints, ``(x, y)`` pixels at the working resolution.
    model : {"homography", "fundamental"}
    threshold : float
        Largest residual (pixels) of an inlier; MAGSAC++'s maximum noise scale.
    confidence : float
    max_iterations : int
    seed : int
        State of OpenCV's sampling generator.

    Returns
    -------
    int
        0 when there are fewer than ``MIN_MATCHES[model]`` matches or no model is found.
    """
    import cv2

    if model not in MIN_MATCHES:
        raise ValueError(f"model must be one of {sorted(MIN_MATCHES)}, got {model!r}")
    points0 = np.ascontiguousarray(points0, np.float64).reshape(-1, 2)
    points1 = np.ascontiguousarray(points1, np.float64).reshape(-1, 2)
    if points0.shape != points1.shape:
        raise ValueError(f"points0 and points1 must have the same shape, got {points0.shape} and {points1.shape}")
    if len(points0) < MIN_MATCHES[model]:
        return 0
    params = cv2.UsacParams()
    params.threshold = float(threshold)
    params.confidence = float(confidence)
    params.maxIterations = int(max_iterations)
    params.randomGeneratorState = int(seed) & 0x7FFFFFFF
    params.sampler = cv2.SAMPLING_UNIFORM
    params.score = cv2.SCORE_METHOD_MAGSAC
    params.loMethod = cv2.LOCAL_OPTIM_SIGMA
    params.loIterations = 10
    params.loSampleSize = 14 if model == "homography" else 20
    params.neighborsSearch = cv2.NEIGH_GRID
    params.final_polisher = cv2.MAGSAC
    params.final_polisher_iterations = 10
    params.isParallel = False
    try:
        if model == "homography":
            _, mask = cv2.findHomography(points0, points1, params)
        else:
            _, mask = cv2.findFundamentalMat(points0, points1, params)
    except cv2.error:  # degenerate configurations (e.g. all points on a line) raise instead of returning None
        return 0
    return 0 if mask is None else int(np.count_nonzero(mask))
