"""OpenCV SIFT (optionally RootSIFT) local features."""

from __future__ import annotations

from typing import Any

import numpy as np

from vpr_uncertainty.geometric.local_features import DEFAULT_MAX_SIDE, Extractor

__all__ = ["SIFTExtractor"]


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
        return {
            **super().config(),
            "max_keypoints": self.max_keypoints,
            "root_sift": self.root_sift,
            "contrast_threshold": self.contrast_threshold,
            "opencv": self._cv2.__version__,
        }

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
