"""Descriptor models, batched extraction and the HDF5 descriptor cache (the ``[torch]`` extra).

Descriptors are L2-normalised float32 rows, one per image name; higher dot product = more similar images.
Importing this package does not import torch; loading a model does, and says which extra to install when
torch is missing.

>>> from vpr_uncertainty.descriptors import available_models
>>> available_models()[:3]
['efficientnet-lite0-gem', 'eigenplaces', 'cosplace']

Typical use::

    from vpr_uncertainty.descriptors import extract_descriptors, read_descriptors
    extract_descriptors("efficientnet-lite0-gem", database_paths, database_names, "descriptors.h5", "database")
    names, descriptors = read_descriptors("descriptors.h5", "database")
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
