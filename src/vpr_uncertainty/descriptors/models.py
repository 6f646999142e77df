"""Descriptor models: a registry of named models, loaded lazily (the wrapper lives in :mod:`.wrapper`).

A :class:`DescriptorModel` maps a batch of normalised images, a float tensor of shape (B, 3, H, W), to
L2-normalised global descriptors of shape (B, D), float32. It carries the :class:`Preprocessing` its network
expects and a fingerprint (model name, weights identity, preprocessing) that the HDF5 cache stores, so that a
cache made by another model or another preprocessing is never reused.

Models come from:

* the registry (:func:`available_models`): the offline default ``efficientnet-lite0-gem`` and the nine VPR
  methods of the benchmark, loaded through ``torch.hub`` (see :mod:`vpr_uncertainty.descriptors.hub`);
* a TorchScript file (``.pt``, ``.pth``, ``.ts``, ``.torchscript``) holding a module that maps images to
  descriptors;
* a Python callable or ``torch.nn.Module`` with the same contract.

Importing this module does not import torch; loading a model does.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from vpr_uncertainty.descriptors import efficientnet, hub
from vpr_uncertainty.descriptors.images import Preprocessing
from vpr_uncertainty.descriptors.wrapper import (
    DEFAULT_MODEL,
    TORCHSCRIPT_SUFFIXES,
    DescriptorModel,
    ModelSpec,
    ModelUnavailableError,
    from_callable,
    from_torchscript,
)
from vpr_uncertainty.plugins import Registry

__all__ = [
    "DEFAULT_MODEL",
    "MODELS",
    "TORCHSCRIPT_SUFFIXES",
    "DescriptorModel",
    "ModelSpec",
    "ModelUnavailableError",
    "available_models",
    "get_model_spec",
    "load_model",
    "register_model",
]


def _key(name: str) -> str:
    return re.sub(r"[\s_\-]", "", name.lower())


#: The registered descriptor models (names matched ignoring case, ``-`` and ``_``).
MODELS: Registry[ModelSpec] = Registry("model", normalise=_key, label="available")
for _spec in (efficientnet.SPEC, *hub.HUB_MODELS):
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
