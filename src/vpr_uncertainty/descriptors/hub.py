"""The nine VPR methods of the benchmark, loaded through ``torch.hub`` and its cache.

Each entry records the torch.hub entry point, its default backbone and descriptor size, and the input
resolution and normalisation with which gmberton's VPR-methods-evaluation feeds the model (ImageNet mean and
standard deviation at native resolution unless said otherwise; DINOv2 models round height and width to a
multiple of 14; Conv-AP and MixVPR take 320 x 320; CricaVPR 224 x 224).

Loading calls ``torch.hub.load(repo, entrypoint, trust_repo=True, **kwargs)``: with internet it downloads the
code and the weights into the torch.hub cache (``torch.hub.get_dir()``, by default ``~/.cache/torch/hub``), and
afterwards works offline from that cache. When neither the cache nor the network has them, one
:class:`~vpr_uncertainty.descriptors.models.ModelUnavailableError` names the model and the folder to fill. The
hub code of these repositories needs torchvision (and AnyLoc also ``einops`` and ``fast_pytorch_kmeans``).

Entry points, from the authors unless noted:

=============  =======================================  ===========================  ======  ================
name           torch.hub repo : entry point             backbone                     D       input
=============  =======================================  ===========================  ======  ================
eigenplaces    gmberton/eigenplaces : get_trained_model ResNet-50                    512     native
cosplace       gmberton/cosplace : get_trained_model    ResNet-50                    512     native
convap         (none published: TorchScript in cache)   ResNet-50                    512     320 x 320
mixvpr         jarvisyjw/MixVPR : get_trained_model     ResNet-50                    4096    320 x 320
apgem          (none published: TorchScript in cache)   ResNet-101                   2048    native
salad          serizba/salad : dinov2_salad             DINOv2 ViT-B/14              8448    multiple of 14
anyloc         AnyLoc/DINO : get_vlad_model             DINOv2 ViT-G/14 (urban VLAD) 49152   multiple of 14
cricavpr       Lu-Feng/CricaVPR : trained_model         DINOv2 ViT-B/14              10752   224 x 224
netvlad        yxgeee/OpenIBL : vgg16_netvlad           VGG-16 + PCA                 4096    native
=============  =======================================  ===========================  ======  ================

* MixVPR: the authors publish no torch.hub entry point; ``jarvisyjw/MixVPR`` is the community fork that
  VPR-methods-evaluation's author endorsed (amaralibey/MixVPR#33). It serves the 4096-D model only;
  VPR-methods-evaluation's default is the 512-D one from Google Drive.
* NetVLAD: the only published torch.hub NetVLAD is OpenIBL's VGG16-NetVLAD with PCA whitening (4096-D),
  trained with SFRS; VPR-methods-evaluation loads it as ``sfrs`` and its ``netvlad`` from the original MATLAB
  Pitts30k weights, which have no hub entry point. Input: 0-255 pixels minus the OpenIBL mean.
* Conv-AP and AP-GeM have no torch.hub entry point (their weights are on Google Drive; AP-GeM also needs the
  ``dirtorch`` code). Loading them looks for a TorchScript export at ``<torch.hub dir>/vpr_uncertainty/
  <name>.pt`` and otherwise says where to put one.
* CricaVPR's descriptors depend on the other images of the batch (cross-image encoder).
"""

from __future__ import annotations

import json
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from vpr_uncertainty.descriptors._torch import require_torch
from vpr_uncertainty.descriptors.images import DEFAULT_MIN_SIDE, Preprocessing
from vpr_uncertainty.descriptors.wrapper import DescriptorModel, ModelSpec, ModelUnavailableError, from_torchscript

__all__ = ["HUB_MODELS", "HUB_TIMEOUT_S", "hub_cache_dir", "load_hub_model", "torchscript_cache_path"]

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


def _hub_weights_id(spec: ModelSpec, kwargs: dict[str, Any]) -> str:
    return f"torch.hub:{spec.hub_repo}:{spec.hub_entrypoint}:{json.dumps(kwargs, sort_keys=True)}"


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


def load_hub_model(spec: ModelSpec, *, device: Any = "cpu", **options: Any) -> DescriptorModel:
    """Load a hub model; ``options`` override the entry point's keyword arguments (e.g. ``fc_output_dim``)."""
    torch = require_torch(f"the model {spec.name!r}")
    kwargs = {**spec.hub_kwargs, **options}
    descriptor_dim: int | None = spec.descriptor_dim
    if options:
        descriptor_dim = int(kwargs["fc_output_dim"]) if "fc_output_dim" in kwargs else None
    if spec.hub_repo is None:
        return _load_torchscript_export(spec, device=device, descriptor_dim=descriptor_dim, options=options)
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
    model = DescriptorModel(
        spec.name,
        network,
        spec.preprocessing,
        weights_id=_hub_weights_id(spec, kwargs),
        descriptor_dim=descriptor_dim,
    )
    return model.to(device)


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


def _spec(
    name: str,
    description: str,
    descriptor_dim: int,
    backbone: str,
    preprocessing: Preprocessing,
    repo: str | None,
    entrypoint: str | None,
    kwargs: dict[str, Any],
    source: str,
    notes: str = "",
) -> ModelSpec:
    return ModelSpec(
        name=name,
        description=description,
        descriptor_dim=descriptor_dim,
        backbone=backbone,
        preprocessing=preprocessing,
        loader=load_hub_model,
        source=source,
        hub_repo=repo,
        hub_entrypoint=entrypoint,
        hub_kwargs=kwargs,
        notes=notes,
    )


_NATIVE = Preprocessing(min_side=DEFAULT_MIN_SIDE)
_DINO = Preprocessing(multiple_of=14, min_side=DEFAULT_MIN_SIDE)

#: The nine methods of the benchmark, in the order of the paper's tables.
HUB_MODELS: tuple[ModelSpec, ...] = (
    _spec(
        "eigenplaces",
        "EigenPlaces (ICCV 2023), ResNet-50, 512-D",
        512,
        "ResNet-50",
        _NATIVE,
        "gmberton/eigenplaces",
        "get_trained_model",
        {"backbone": "ResNet50", "fc_output_dim": 512},
        "torch.hub (authors)",
    ),
    _spec(
        "cosplace",
        "CosPlace (CVPR 2022), ResNet-50, 512-D",
        512,
        "ResNet-50",
        _NATIVE,
        "gmberton/cosplace",
        "get_trained_model",
        {"backbone": "ResNet50", "fc_output_dim": 512},
        "torch.hub (authors)",
    ),
    _spec(
        "convap",
        "Conv-AP (GSV-Cities, Neurocomputing 2022), ResNet-50, 512-D, 320x320",
        512,
        "ResNet-50",
        Preprocessing(image_size=(320, 320)),
        None,
        None,
        {},
        "TorchScript export in the torch.hub cache",
        "weights resnet50_ConvAP_128_2x2.ckpt: https://drive.google.com/drive/folders/1VYPw9uGD11NgiGFgfWueLt3noJYOIuhL",
    ),
    _spec(
        "mixvpr",
        "MixVPR (WACV 2023), ResNet-50, 4096-D, 320x320",
        4096,
        "ResNet-50",
        Preprocessing(image_size=(320, 320)),
        "jarvisyjw/MixVPR",
        "get_trained_model",
        {"pretrained": True},
        "torch.hub (community fork, endorsed in amaralibey/MixVPR#33)",
        "the hub serves the 4096-D model only",
    ),
    _spec(
        "apgem",
        "AP-GeM (ICCV 2019), ResNet-101, 2048-D",
        2048,
        "ResNet-101",
        _NATIVE,
        None,
        None,
        {},
        "TorchScript export in the torch.hub cache",
        "weights Resnet-101-AP-GeM.pt of naver/deep-image-retrieval (dirtorch): "
        "https://docs.google.com/uc?export=download&id=1UWJGDuHtzaQdFhSMojoYVQjmCXhIwVvy",
    ),
    _spec(
        "salad",
        "SALAD (CVPR 2024), DINOv2 ViT-B/14, 8448-D",
        8448,
        "DINOv2 ViT-B/14",
        _DINO,
        "serizba/salad",
        "dinov2_salad",
        {},
        "torch.hub (authors)",
    ),
    _spec(
        "anyloc",
        "AnyLoc-VLAD-DINOv2 (RA-L 2023), ViT-G/14, urban vocabulary, 49152-D",
        49152,
        "DINOv2 ViT-G/14",
        _DINO,
        "AnyLoc/DINO",
        "get_vlad_model",
        {"backbone": "DINOv2", "domain": "urban"},
        "torch.hub (authors)",
        "domain= selects the VLAD vocabulary: urban, indoor, aerial, structured, unstructured, global",
    ),
    _spec(
        "cricavpr",
        "CricaVPR (CVPR 2024), DINOv2 ViT-B/14, 10752-D, 224x224",
        10752,
        "DINOv2 ViT-B/14",
        Preprocessing(image_size=(224, 224)),
        "Lu-Feng/CricaVPR",
        "trained_model",
        {},
        "torch.hub (authors)",
        "descriptors depend on the other images of the batch (cross-image encoder)",
    ),
    _spec(
        "netvlad",
        "NetVLAD (CVPR 2016), VGG-16 + PCA whitening, 4096-D (OpenIBL weights)",
        4096,
        "VGG-16",
        _OPENIBL,
        "yxgeee/OpenIBL",
        "vgg16_netvlad",
        {"pretrained": True},
        "torch.hub (OpenIBL, SFRS-trained weights)",
        "the original MATLAB Pitts30k weights have no torch.hub entry point",
    ),
)
