"""Image decoding and preprocessing for descriptor models, with PIL and numpy only (no torchvision).

An image goes through two steps:

1. :func:`load_image` decodes the file with PIL, converts it to RGB and resizes it as the model's
   :class:`Preprocessing` says; the result is a ``uint8`` array of shape (H, W, 3). This runs in worker threads.
2. :func:`to_model_input` stacks a list of such arrays into a float tensor of shape (B, 3, H, W) on the model's
   device, scaled to [0, 1] and normalised with the model's mean and standard deviation.

Resizing happens on the PIL image (antialiased ``Image.resize``), like torchvision's ``Resize`` on PIL images.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "IMAGENET_MEAN",
    "IMAGENET_STD",
    "ImageDecodeError",
    "Preprocessing",
    "load_image",
    "to_model_input",
]

IMAGENET_MEAN: tuple[float, float, float] = (0.485, 0.456, 0.406)
IMAGENET_STD: tuple[float, float, float] = (0.229, 0.224, 0.225)

_INTERPOLATIONS = ("bilinear", "bicubic", "nearest")


class ImageDecodeError(ValueError):
    """An image file could not be read or decoded; the message names the image."""

    def __init__(self, name: str, path: str | Path, reason: str) -> None:
        super().__init__(f"cannot decode image {name!r} ({path}): {reason}")
        self.name = name
        self.path = Path(path)
        self.reason = reason


@dataclass(frozen=True)
class Preprocessing:
    """How images are resized and normalised before a model sees them.

    Parameters
    ----------
    image_size : None, int or (int, int)
        ``None`` keeps the native resolution; an int resizes so that the *shorter* side has this length,
        keeping the aspect ratio; ``(height, width)`` resizes to exactly that size.
    multiple_of : int
        After resizing, round height and width to the nearest multiple of this (14 for DINOv2 backbones), with
        Python's ``round`` like VPR-methods-evaluation.
    mean, std : tuple of 3 floats
        Per-channel normalisation of pixel values in [0, 1]: ``(x - mean) / std``.
    interpolation : {"bilinear", "bicubic", "nearest"}
        PIL resampling filter.

    Examples
    --------
    >>> Preprocessing(image_size=224).output_size(width=160, height=120)
    (299, 224)
    >>> Preprocessing(multiple_of=14).output_size(width=160, height=120)
    (154, 126)
    """

    image_size: int | tuple[int, int] | None = None
    multiple_of: int = 1
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD
    interpolation: str = "bilinear"

    def __post_init__(self) -> None:
        size = self.image_size
        if isinstance(size, list):
            object.__setattr__(self, "image_size", size := tuple(size))
        if size is not None:
            values = (size,) if isinstance(size, (int, np.integer)) else size
            if (
                not isinstance(values, tuple)
                or len(values) not in (1, 2)
                or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 0 for v in values)
            ):
                raise ValueError(f"image_size must be None, a positive int or (height, width), got {size!r}")
            if isinstance(size, tuple):
                object.__setattr__(self, "image_size", tuple(int(v) for v in size))
            else:
                object.__setattr__(self, "image_size", int(size))
        if isinstance(self.multiple_of, bool) or not isinstance(self.multiple_of, (int, np.integer)):
            raise ValueError(f"multiple_of must be a positive int, got {self.multiple_of!r}")
        if self.multiple_of < 1:
            raise ValueError(f"multiple_of must be a positive int, got {self.multiple_of!r}")
        for field in ("mean", "std"):
            value = tuple(float(v) for v in getattr(self, field))
            if len(value) != 3:
                raise ValueError(f"{field} must have 3 values (R, G, B), got {getattr(self, field)!r}")
            object.__setattr__(self, field, value)
        if any(v <= 0 for v in self.std):
            raise ValueError(f"std must be positive, got {self.std!r}")
        if self.interpolation not in _INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {_INTERPOLATIONS}, got {self.interpolation!r}")

    def output_size(self, width: int, height: int) -> tuple[int, int]:
        """Size ``(width, height)`` of an image of the given size after resizing."""
        if self.image_size is None:
            new_w, new_h = width, height
        elif isinstance(self.image_size, tuple):
            new_h, new_w = self.image_size
        else:
            scale = self.image_size / min(width, height)
            new_w, new_h = round(width * scale), round(height * scale)
        if self.multiple_of > 1:
            m = self.multiple_of
            new_w = max(m, round(new_w / m) * m)
            new_h = max(m, round(new_h / m) * m)
        return new_w, new_h

    def replace(self, **changes: Any) -> Preprocessing:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable description (part of the cache fingerprint)."""
        size = self.image_size
        return {
            "image_size": list(size) if isinstance(size, tuple) else size,
            "multiple_of": self.multiple_of,
            "mean": list(self.mean),
            "std": list(self.std),
            "interpolation": self.interpolation,
        }


def load_image(path: str | Path, preprocessing: Preprocessing, *, name: str | None = None) -> np.ndarray:
    """Decode an image file to an RGB ``uint8`` array of shape (H, W, 3), resized as ``preprocessing`` says.

    Raises
    ------
    ImageDecodeError
        If the file is missing, is not an image, or is truncated; the message names the image.
    """
    from PIL import Image, UnidentifiedImageError

    name = str(path) if name is None else name
    try:
        with Image.open(path) as image:
            image.load()
            rgb = image.convert("RGB")
    except FileNotFoundError:
        raise ImageDecodeError(name, path, "file not found") from None
    except UnidentifiedImageError:
        raise ImageDecodeError(name, path, "not a recognised image format") from None
    except (OSError, ValueError, SyntaxError) as error:  # truncated or corrupt data
        raise ImageDecodeError(name, path, str(error) or type(error).__name__) from None
    size = preprocessing.output_size(*rgb.size)
    if size != rgb.size:
        resample = {
            "bilinear": Image.Resampling.BILINEAR,
            "bicubic": Image.Resampling.BICUBIC,
            "nearest": Image.Resampling.NEAREST,
        }[preprocessing.interpolation]
        rgb = rgb.resize(size, resample=resample)
    return np.asarray(rgb, dtype=np.uint8)


def to_model_input(images: Sequence[np.ndarray], preprocessing: Preprocessing, device: Any) -> Any:
    """Stack equally sized ``uint8`` (H, W, 3) arrays into a normalised float tensor (B, 3, H, W) on ``device``."""
    from vpr_uncertainty.features._torch import require_torch

    torch = require_torch()
    batch = torch.from_numpy(np.stack(images)).to(device)
    batch = batch.permute(0, 3, 1, 2).float().div_(255.0)
    mean = torch.tensor(preprocessing.mean, dtype=batch.dtype, device=batch.device).view(1, 3, 1, 1)
    std = torch.tensor(preprocessing.std, dtype=batch.dtype, device=batch.device).view(1, 3, 1, 1)
    return batch.sub_(mean).div_(std)
