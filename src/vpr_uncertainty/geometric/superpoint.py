"""SuperPoint (DeTone et al. 2018) with SuperGlue (Sarlin et al. 2020) or LightGlue: the VPR papers' strongest
geometric-verification baseline.

The two networks (:mod:`~vpr_uncertainty.geometric.superpoint_networks`) follow Magic Leap's reference
implementation, with the same parameter names, so the official checkpoints (``superpoint_v1.pth``,
``superglue_outdoor.pth``/``superglue_indoor.pth``) load unchanged; LightGlue is kornia's with
``superpoint_lightglue.pth``. No package ships these weights (Magic Leap's licence is non-commercial):
:func:`vpr_uncertainty.geometric.weights.load_official_state_dict` reads them from a local path,
``$VPR_UNCERTAINTY_WEIGHTS`` or torch's hub cache, or downloads the official files.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.geometric._torch import images_to_tensor, torch_device
from vpr_uncertainty.geometric.disk_xfeat_lightglue import build_lightglue
from vpr_uncertainty.geometric.local_features import DEFAULT_MAX_SIDE, Extractor, LocalFeatures
from vpr_uncertainty.geometric.superpoint_networks import networks
from vpr_uncertainty.geometric.weights import load_official_state_dict, state_dict_fingerprint

__all__ = [
    "SuperGlueMatcher",
    "SuperPointExtractor",
    "load_superglue",
    "load_superpoint",
    "load_superpoint_lightglue",
]


def _load_strict(model: Any, state_dict: dict[str, Any], what: str) -> Any:
    try:
        model.load_state_dict(state_dict, strict=True)
    except RuntimeError as error:
        raise ValueError(f"these weights do not fit {what}: {str(error).splitlines()[0]} ...") from error
    return model.eval()


def load_superpoint(
    weights: str | Path | dict[str, Any] | None = None, *, device: str = "cpu", download: bool = True, **conf: Any
) -> tuple[Any, str]:
    """SuperPoint with the official weights (path, state dict, or found/downloaded; see the module docstring).

    Returns the model (eval mode, on ``device``) and the weights' fingerprint.
    """
    state = weights if isinstance(weights, dict) else _cached_state("superpoint", weights, download)
    model = _load_strict(networks()["SuperPoint"](**conf), state, "SuperPoint")
    return model.to(torch_device(device)), state_dict_fingerprint(state)


def load_superglue(
    weights: str | Path | dict[str, Any] | None = None,
    *,
    variant: str = "outdoor",
    device: str = "cpu",
    download: bool = True,
    **conf: Any,
) -> tuple[Any, str]:
    """SuperGlue (``variant`` "outdoor" or "indoor" when the weights are looked up or downloaded)."""
    if variant not in ("outdoor", "indoor"):
        raise ValueError(f"variant must be 'outdoor' or 'indoor', got {variant!r}")
    state = weights if isinstance(weights, dict) else _cached_state(f"superglue_{variant}", weights, download)
    model = _load_strict(networks()["SuperGlue"](**conf), state, "SuperGlue")
    return model.to(torch_device(device)), state_dict_fingerprint(state)


def load_superpoint_lightglue(
    weights: str | Path | dict[str, Any] | None = None, *, device: str = "cpu", download: bool = True
) -> Any:
    """kornia's LightGlue for SuperPoint with ``superpoint_lightglue.pth``."""
    state = weights if isinstance(weights, dict) else _cached_state("superpoint_lightglue", weights, download)
    return build_lightglue("superpoint", dict(state)).to(torch_device(device))


@functools.lru_cache(maxsize=8)
def _cached_state_key(key: str, path: str | None, download: bool) -> dict[str, Any]:
    return load_official_state_dict(key, path, download=download)


def _cached_state(key: str, path: str | Path | None, download: bool) -> dict[str, Any]:
    return _cached_state_key(key, None if path is None else str(Path(path).absolute()), download)


class SuperPointExtractor(Extractor):
    """SuperPoint keypoints and 256-D descriptors on the grayscale image.

    Parameters
    ----------
    weights : path or state dict, optional
        ``superpoint_v1.pth``; looked up or downloaded when None.
    max_keypoints, keypoint_threshold, nms_radius
        As in the reference implementation (hloc's ``superpoint_aachen`` uses 4096, 0.005, 3; 2048 keeps the
        CPU matcher fast).
    """

    name = "superpoint"
    grayscale = True
    uses_torch = True

    def __init__(
        self,
        *,
        weights: str | Path | dict[str, Any] | None = None,
        max_keypoints: int = 2048,
        keypoint_threshold: float = 0.005,
        nms_radius: int = 4,
        max_side: int = DEFAULT_MAX_SIDE,
        device: str = "cpu",
        batch_size: int = 1,
        download: bool = True,
    ) -> None:
        super().__init__(max_side=max_side, device=device, batch_size=batch_size)
        self.model, self.fingerprint = load_superpoint(
            weights,
            device=device,
            download=download,
            max_keypoints=int(max_keypoints),
            keypoint_threshold=float(keypoint_threshold),
            nms_radius=int(nms_radius),
        )

    def config(self) -> dict[str, Any]:
        model = self.model
        return {
            **super().config(),
            "max_keypoints": model.max_keypoints,
            "keypoint_threshold": model.keypoint_threshold,
            "nms_radius": model.nms_radius,
            "weights": self.fingerprint,
        }

    def _extract_batch(self, images: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        import torch

        with torch.inference_mode():
            outputs = self.model(images_to_tensor(images, next(self.model.parameters()).device))
        return [(k.cpu().numpy(), d.float().cpu().numpy(), s.float().cpu().numpy()) for k, s, d in outputs]


class SuperGlueMatcher:
    """SuperGlue matching of SuperPoint features (outdoor weights by default: most VPR data is outdoors)."""

    name = "superglue"
    uses_torch = True

    def __init__(
        self,
        *,
        weights: str | Path | dict[str, Any] | None = None,
        variant: str = "outdoor",
        sinkhorn_iterations: int = 50,
        match_threshold: float = 0.2,
        device: str = "cpu",
        download: bool = True,
    ) -> None:
        self.model, self.fingerprint = load_superglue(
            weights,
            variant=variant,
            device=device,
            download=download,
            sinkhorn_iterations=int(sinkhorn_iterations),
            match_threshold=float(match_threshold),
        )
        self.device = next(self.model.parameters()).device
        self.thread_parallel = self.device.type == "cpu"

    def config(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "sinkhorn_iterations": self.model.sinkhorn_iterations,
            "match_threshold": self.model.match_threshold,
            "weights": self.fingerprint,
        }

    def match(self, features0: LocalFeatures, features1: LocalFeatures, *, max_side: int) -> np.ndarray:
        import torch

        if len(features0) == 0 or len(features1) == 0:
            return np.zeros((0, 2), np.int64)
        tensors = []
        sizes = []
        for features in (features0, features1):
            keypoints, size = features.at_working_resolution(max_side)
            tensors.append(
                (
                    torch.from_numpy(np.ascontiguousarray(keypoints))[None].to(self.device),
                    torch.from_numpy(np.asarray(features.descriptors, np.float32).T.copy())[None].to(self.device),
                    torch.from_numpy(features.scores)[None].to(self.device),
                )
            )
            sizes.append(size)
        (k0, d0, s0), (k1, d1, s1) = tensors
        with torch.inference_mode():
            matches0 = self.model(k0, k1, d0, d1, s0, s1, sizes[0], sizes[1])[0].cpu().numpy()
        rows = np.flatnonzero(matches0 >= 0)
        return np.stack([rows, matches0[rows]], axis=1).astype(np.int64)
