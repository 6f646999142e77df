"""Descriptor models, batched extraction and the HDF5 descriptor cache (the ``[torch]`` extra): L2-normalised
float32 rows, one per image name, higher dot product = more similar. Importing the package does not import torch.
"""

from vpr_uncertainty.descriptors.cache import SPLITS, cache_info, read_descriptors
from vpr_uncertainty.descriptors.extract import extract_descriptors
from vpr_uncertainty.descriptors.images import ImageDecodeError, Preprocessing, load_image
from vpr_uncertainty.descriptors.models import (
    DEFAULT_MODEL,
    DescriptorModel,
    ModelSpec,
    ModelUnavailableError,
    available_models,
    get_model_spec,
    load_model,
    register_model,
)

__all__ = [
    "DEFAULT_MODEL",
    "SPLITS",
    "DescriptorModel",
    "ImageDecodeError",
    "ModelSpec",
    "ModelUnavailableError",
    "Preprocessing",
    "available_models",
    "cache_info",
    "extract_descriptors",
    "get_model_spec",
    "load_image",
    "load_model",
    "read_descriptors",
    "register_model",
]
