"""SuperPoint (DeTone et al. 2018) with SuperGlue (Sarlin et al. 2020) or LightGlue, with Magic Leap's parameter names
so that the official checkpoints load unchanged (their licence is non-commercial; where the weights are found:
see docs/explanation/geometric-verification.md).
"""

from __future__ import annotations

import copy
import functools
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.descriptors.images import torch_device
from vpr_uncertainty.geometric.lightglue import (
    LightGlueMatcher,
    TorchExtractor,
    TorchMatcher,
    build_lightglue,
    load_official_state_dict,
    state_dict_fingerprint,
    to_numpy,
)
from vpr_uncertainty.geometric.local_features import DEFAULT_MAX_SIDE, LocalFeatures, images_to_tensor


@functools.cache
def networks() -> dict[str, Any]:
    """``{"SuperPoint": class, "SuperGlue": class}``: the torch modules, defined on first use (importing this file
    does not import torch)."""
    import torch
    import torch.nn.functional as F
    from torch import nn

    def simple_nms(scores: torch.Tensor, radius: int) -> torch.Tensor:
        def max_pool(x: torch.Tensor) -> torch.Tensor:
            return F.max_pool2d(x, kernel_size=radius * 2 + 1, stride=1, padding=radius)

        zeros = torch.zeros_like(scores)
        max_mask = scores == max_pool(scores)
        for _ in range(2):
            suppressed = max_pool(max_mask.float()) > 0
            suppressed_scores = torch.where(suppressed, zeros, scores)
            new_max = suppressed_scores == max_pool(suppressed_scores)
            max_mask = max_mask | (new_max & ~suppressed)
        return torch.where(max_mask, scores, zeros)

    class SuperPoint(nn.Module):
        """SuperPoint; ``forward(image (B, 1, H, W) in [0, 1])`` -> list of (keypoints (N, 2) xy, scores (N,),
        descriptors (N, 256)) per image."""

        def __init__(
            self,
            *,
            max_keypoints: int = 2048,
            keypoint_threshold: float = 0.005,
            nms_radius: int = 4,
            remove_borders: int = 4,
        ) -> None:
            super().__init__()
            self.max_keypoints = max_keypoints
            self.keypoint_threshold = keypoint_threshold
            self.nms_radius = nms_radius
            self.remove_borders = remove_borders
            self.relu = nn.ReLU(inplace=True)
            self.pool = nn.MaxPool2d(kernel_size=2, stride=2)
            channels = (1, 64, 64, 128, 128)
            for block in range(1, 5):  # conv1a, conv1b, ..., conv4b (the reference implementation's names)
                setattr(self, f"conv{block}a", nn.Conv2d(channels[block - 1], channels[block], 3, 1, 1))
                setattr(self, f"conv{block}b", nn.Conv2d(channels[block], channels[block], 3, 1, 1))
            self.convPa = nn.Conv2d(128, 256, 3, 1, 1)
            self.convPb = nn.Conv2d(256, 65, 1, 1, 0)
            self.convDa = nn.Conv2d(128, 256, 3, 1, 1)
            self.convDb = nn.Conv2d(256, 256, 1, 1, 0)

        def forward(self, image: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
            x = image
            for block in range(1, 5):  # a max-pooling after each block but the last
                x = self.relu(getattr(self, f"conv{block}b")(self.relu(getattr(self, f"conv{block}a")(x))))
                x = self.pool(x) if block < 4 else x
            scores = self.convPb(self.relu(self.convPa(x)))
            scores = F.softmax(scores, 1)[:, :-1]
            b, _, h, w = scores.shape
            scores = scores.permute(0, 2, 3, 1).reshape(b, h, w, 8, 8).permute(0, 1, 3, 2, 4).reshape(b, h * 8, w * 8)
            scores = simple_nms(scores, self.nms_radius)
            descriptors = F.normalize(self.convDb(self.relu(self.convDa(x))), p=2, dim=1)
            outputs = []
            for i in range(b):
                ys, xs = torch.nonzero(scores[i] > self.keypoint_threshold, as_tuple=True)
                border = self.remove_borders
                inside = (ys >= border) & (ys < h * 8 - border) & (xs >= border) & (xs < w * 8 - border)
                ys, xs = ys[inside], xs[inside]
                values = scores[i, ys, xs]
                if self.max_keypoints and len(values) > self.max_keypoints:
                    values, order = torch.topk(values, self.max_keypoints)
                    ys, xs = ys[order], xs[order]
                keypoints = torch.stack([xs, ys], dim=-1).float()
                # bilinear sampling of the coarse descriptor map at the keypoints (reference implementation)
                s = 8
                grid = keypoints - s / 2 + 0.5
                grid = grid / grid.new_tensor([w * s - s / 2 - 0.5, h * s - s / 2 - 0.5])
                grid = (grid * 2 - 1).view(1, 1, -1, 2)
                sampled = F.grid_sample(descriptors[i : i + 1], grid, mode="bilinear", align_corners=True)
                sampled = F.normalize(sampled.reshape(descriptors.shape[1], -1), p=2, dim=0)
                outputs.append((keypoints, values, sampled.t()))
            return outputs

    def mlp(channels: list[int]) -> nn.Sequential:
        layers: list[nn.Module] = []
        for i in range(1, len(channels)):
            layers.append(nn.Conv1d(channels[i - 1], channels[i], kernel_size=1, bias=True))
            if i < len(channels) - 1:
                layers.append(nn.BatchNorm1d(channels[i]))
                layers.append(nn.ReLU())
        return nn.Sequential(*layers)

    class KeypointEncoder(nn.Module):
        def __init__(self, feature_dim: int, layers: list[int]) -> None:
            super().__init__()
            self.encoder = mlp([3, *layers, feature_dim])
            nn.init.constant_(self.encoder[-1].bias, 0.0)

        def forward(self, keypoints: torch.Tensor, scores: torch.Tensor) -> torch.Tensor:
            return self.encoder(torch.cat([keypoints.transpose(1, 2), scores.unsqueeze(1)], dim=1))

    class MultiHeadedAttention(nn.Module):
        def __init__(self, num_heads: int, d_model: int) -> None:
            super().__init__()
            self.dim = d_model // num_heads
            self.num_heads = num_heads
            self.merge = nn.Conv1d(d_model, d_model, kernel_size=1)
            self.proj = nn.ModuleList([copy.deepcopy(self.merge) for _ in range(3)])

        def forward(self, query: torch.Tensor, key: torch.Tensor, value: torch.Tensor) -> torch.Tensor:
            batch = query.size(0)
            q, k, v = (
                layer(x).view(batch, self.dim, self.num_heads, -1)
                for layer, x in zip(self.proj, (query, key, value), strict=True)
            )
            scores = torch.einsum("bdhn,bdhm->bhnm", q, k) / self.dim**0.5
            x = torch.einsum("bhnm,bdhm->bdhn", F.softmax(scores, dim=-1), v)
            return self.merge(x.contiguous().view(batch, self.dim * self.num_heads, -1))

    class AttentionalPropagation(nn.Module):
        def __init__(self, feature_dim: int, num_heads: int) -> None:
            super().__init__()
            self.attn = MultiHeadedAttention(num_heads, feature_dim)
            self.mlp = mlp([feature_dim * 2, feature_dim * 2, feature_dim])
            nn.init.constant_(self.mlp[-1].bias, 0.0)

        def forward(self, x: torch.Tensor, source: torch.Tensor) -> torch.Tensor:
            return self.mlp(torch.cat([x, self.attn(x, source, source)], dim=1))

    class AttentionalGNN(nn.Module):
        def __init__(self, feature_dim: int, layer_names: list[str]) -> None:
            super().__init__()
            self.layers = nn.ModuleList([AttentionalPropagation(feature_dim, 4) for _ in layer_names])
            self.names = layer_names

        def forward(self, desc0: torch.Tensor, desc1: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            for layer, name in zip(self.layers, self.names, strict=True):
                source0, source1 = (desc1, desc0) if name == "cross" else (desc0, desc1)
                delta0, delta1 = layer(desc0, source0), layer(desc1, source1)
                desc0, desc1 = desc0 + delta0, desc1 + delta1
            return desc0, desc1

    def log_optimal_transport(scores: torch.Tensor, alpha: torch.Tensor, iters: int) -> torch.Tensor:
        b, m, n = scores.shape
        one = scores.new_tensor(1)
        ms, ns = (m * one).to(scores), (n * one).to(scores)
        bins0 = alpha.expand(b, m, 1)
        bins1 = alpha.expand(b, 1, n)
        alpha = alpha.expand(b, 1, 1)
        couplings = torch.cat([torch.cat([scores, bins0], -1), torch.cat([bins1, alpha], -1)], 1)
        norm = -(ms + ns).log()
        log_mu = torch.cat([norm.expand(m), ns.log()[None] + norm])[None].expand(b, -1)
        log_nu = torch.cat([norm.expand(n), ms.log()[None] + norm])[None].expand(b, -1)
        u, v = torch.zeros_like(log_mu), torch.zeros_like(log_nu)
        for _ in range(iters):
            u = log_mu - torch.logsumexp(couplings + v.unsqueeze(1), dim=2)
            v = log_nu - torch.logsumexp(couplings + u.unsqueeze(2), dim=1)
        return couplings + u.unsqueeze(2) + v.unsqueeze(1) - norm

    class SuperGlue(nn.Module):
        """SuperGlue; ``forward(kpts0 (B, M, 2), kpts1 (B, N, 2), desc0 (B, 256, M), desc1 (B, 256, N),
        scores0 (B, M), scores1 (B, N), size0 (W, H), size1 (W, H))`` -> matches0 (B, M), -1 = unmatched."""

        def __init__(self, *, sinkhorn_iterations: int = 50, match_threshold: float = 0.2) -> None:
            super().__init__()
            self.sinkhorn_iterations = sinkhorn_iterations
            self.match_threshold = match_threshold
            self.kenc = KeypointEncoder(256, [32, 64, 128, 256])
            self.gnn = AttentionalGNN(256, ["self", "cross"] * 9)
            self.final_proj = nn.Conv1d(256, 256, kernel_size=1, bias=True)
            self.register_parameter("bin_score", nn.Parameter(torch.tensor(1.0)))

        @staticmethod
        def normalize(keypoints: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
            size_t = keypoints.new_tensor(size)[None]
            return (keypoints - size_t[:, None, :] / 2) / (size_t.max() * 0.7)

        def forward(self, kpts0, kpts1, desc0, desc1, scores0, scores1, size0, size1) -> torch.Tensor:
            desc0 = desc0 + self.kenc(self.normalize(kpts0, size0), scores0)
            desc1 = desc1 + self.kenc(self.normalize(kpts1, size1), scores1)
            desc0, desc1 = self.gnn(desc0, desc1)
            mdesc0, mdesc1 = self.final_proj(desc0), self.final_proj(desc1)
            scores = torch.einsum("bdn,bdm->bnm", mdesc0, mdesc1) / mdesc0.shape[1] ** 0.5
            scores = log_optimal_transport(scores, self.bin_score, self.sinkhorn_iterations)
            max0, max1 = scores[:, :-1, :-1].max(2), scores[:, :-1, :-1].max(1)
            indices0, indices1 = max0.indices, max1.indices
            mutual0 = torch.arange(indices0.shape[1], device=scores.device)[None] == indices1.gather(1, indices0)
            mscores0 = torch.where(mutual0, max0.values.exp(), scores.new_tensor(0))
            valid0 = mutual0 & (mscores0 > self.match_threshold)
            return torch.where(valid0, indices0, indices0.new_tensor(-1))

    return {"SuperPoint": SuperPoint, "SuperGlue": SuperGlue}


def _load_strict(model: Any, state_dict: dict[str, Any], what: str, device: str) -> tuple[Any, str]:
    """``model`` with ``state_dict`` loaded (every name must fit), in eval mode on ``device``, and the fingerprint."""
    try:
        model.load_state_dict(state_dict, strict=True)
    except RuntimeError as error:
        raise ValueError(f"these weights do not fit {what}: {str(error).splitlines()[0]} ...") from error
    return model.eval().to(torch_device(device)), state_dict_fingerprint(state_dict)


def load_superpoint(
    weights: str | Path | dict[str, Any] | None = None, *, device: str = "cpu", download: bool = True, **conf: Any
) -> tuple[Any, str]:
    """SuperPoint with the official weights (path, state dict, or found/downloaded).

    Returns the model (eval mode, on ``device``) and the weights' fingerprint.
    """
    state = _cached_state("superpoint", weights, download)
    return _load_strict(networks()["SuperPoint"](**conf), state, "SuperPoint", device)


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
    state = _cached_state(f"superglue_{variant}", weights, download)
    return _load_strict(networks()["SuperGlue"](**conf), state, "SuperGlue", device)


def load_superpoint_lightglue(
    weights: str | Path | dict[str, Any] | None = None, *, device: str = "cpu", download: bool = True
) -> Any:
    """kornia's LightGlue for SuperPoint with ``superpoint_lightglue.pth``."""
    state = _cached_state("superpoint_lightglue", weights, download)
    return build_lightglue("superpoint", dict(state)).to(torch_device(device))


@functools.lru_cache(maxsize=8)
def _cached_state_key(key: str, path: str | None, download: bool) -> dict[str, Any]:
    return load_official_state_dict(key, path, download=download)


def _cached_state(key: str, weights: str | Path | dict[str, Any] | None, download: bool) -> dict[str, Any]:
    """``weights`` when a state dict, else the official weights ``key`` (loaded once per path)."""
    if isinstance(weights, dict):
        return weights
    return _cached_state_key(key, None if weights is None else str(Path(weights).absolute()), download)


class SuperPointExtractor(TorchExtractor):
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
    settings = ("max_keypoints", "keypoint_threshold", "nms_radius")

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
        self.max_keypoints = int(max_keypoints)
        self.keypoint_threshold = float(keypoint_threshold)
        self.nms_radius = int(nms_radius)
        conf = {key: getattr(self, key) for key in self.settings}
        self.model, self.fingerprint = load_superpoint(weights, device=device, download=download, **conf)

    def _extract_batch(self, images: list[np.ndarray]) -> list[tuple[np.ndarray, ...]]:
        import torch

        with torch.inference_mode():
            outputs = self.model(images_to_tensor(images, next(self.model.parameters()).device))
        return [to_numpy(keypoints, descriptors, scores) for keypoints, scores, descriptors in outputs]


class SuperGlueMatcher(TorchMatcher):
    """SuperGlue matching of SuperPoint features (outdoor weights by default: most VPR data is outdoors)."""

    name = "superglue"
    settings = ("sinkhorn_iterations", "match_threshold")

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
        self.sinkhorn_iterations = int(sinkhorn_iterations)
        self.match_threshold = float(match_threshold)
        conf = {key: getattr(self, key) for key in self.settings}
        super().__init__(*load_superglue(weights, variant=variant, device=device, download=download, **conf))

    def match(self, features0: LocalFeatures, features1: LocalFeatures, *, max_side: int) -> np.ndarray:
        import torch

        if len(features0) == 0 or len(features1) == 0:
            return np.zeros((0, 2), np.int64)
        pair = (features0, features1)
        (k0, size0), (k1, size1) = (features.at_working_resolution(max_side) for features in pair)
        d0, d1 = (self._tensor(features.descriptors.T) for features in pair)
        s0, s1 = (self._tensor(features.scores) for features in pair)
        with torch.inference_mode():
            matches0 = self.model(self._tensor(k0), self._tensor(k1), d0, d1, s0, s1, size0, size1)[0].cpu().numpy()
        rows = np.flatnonzero(matches0 >= 0)
        return np.stack([rows, matches0[rows]], axis=1).astype(np.int64)


def superpoint_lightglue_matcher(*, weights: Any = None, device: str = "cpu", download: bool = True) -> Any:
    """LightGlue for SuperPoint: the official weights (a local path, else looked up or downloaded)."""
    model = load_superpoint_lightglue(weights, device=device, download=download)
    return LightGlueMatcher("superpoint", model=model, device=device)
