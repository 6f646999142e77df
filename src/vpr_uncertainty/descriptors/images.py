"""Image decoding and preprocessing for descriptor models, with PIL and numpy only (no torchvision): :func:`load_image`
(a file to an RGB ``uint8`` (H, W, 3) array, resized as :class:`Preprocessing` says) and :func:`to_model_input` (a
normalised float tensor (B, 3, H, W)). How memory is bounded and which images cannot be used
(:class:`ImageDecodeError`): see docs/explanation/descriptors.md.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import os
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty._validation import check_count
from vpr_uncertainty.data.images import printable
from vpr_uncertainty.plugins import import_or_explain

IMAGENET_MEAN: tuple[float, float, float] = (0.485, 0.456, 0.406)
IMAGENET_STD: tuple[float, float, float] = (0.229, 0.224, 0.225)

_INTERPOLATIONS = ("bilinear", "bicubic", "nearest")
#: Longest side, in pixels, of the image a model sees (unless a model's preprocessing says otherwise).
DEFAULT_MAX_SIDE = 640
#: Shortest side, in pixels, the registered models accept (EfficientNet-Lite0 fails below 32: it downsamples 32
#: times). Models given as a callable or a TorchScript file accept any size unless their preprocessing says so.
DEFAULT_MIN_SIDE = 32

TORCH_EXTRA_HINT = "pip install 'vpr-uncertainty[torch]'"


def require_torch(what: str = "descriptor extraction") -> Any:
    """Import and return :mod:`torch`, or raise an ImportError that names the extra to install."""
    return import_or_explain(
        "torch", f"{what} needs PyTorch, which is not installed; install it with {TORCH_EXTRA_HINT}"
    )


def torch_device(device: Any = None, *, types: tuple[str, ...] | None = None) -> Any:
    """``device`` (``"cpu"``, ``"cuda:1"``, ``"mps"``, a ``torch.device``; None: the CPU) as a torch device, or a
    ValueError naming an unknown device, a type not in ``types`` (any by default), or a missing GPU or Metal backend."""
    torch = require_torch("a torch device")
    kinds = types or ("cpu", "cuda", "mps")
    expected = "expected " + ", ".join(map(repr, kinds)) + (" or 'cuda:N'" if "cuda" in kinds else "")
    try:
        resolved = torch.device("cpu" if device is None else device)
    except (RuntimeError, TypeError) as error:
        raise ValueError(f"invalid device {device!r}: {expected}") from error
    if types is not None and resolved.type not in types:
        raise ValueError(f"unsupported device {device!r}: {expected}")
    if resolved.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {str(resolved)!r} was requested but CUDA is not available (no CUDA GPU); use 'cpu'")
    if resolved.type == "cuda" and (resolved.index or 0) >= torch.cuda.device_count():
        raise ValueError(f"device {str(resolved)!r} was requested but only {torch.cuda.device_count()} GPU(s) exist")
    if resolved.type == "mps" and not torch.backends.mps.is_available():
        raise ValueError("device 'mps' was requested but the Metal backend is not available; use device='cpu'")
    return resolved


class ImageDecodeError(ValueError):
    """An image cannot be used (unreadable, corrupt, too large, too small...); the message names the image."""

    def __init__(self, name: str, path: str | Path, reason: str) -> None:
        where = "" if str(name) == str(path) else f" ({printable(path)})"
        super().__init__(f"cannot use image '{printable(name)}'{where}: {reason}")
        self.name = name
        self.path = Path(path)
        self.reason = reason


def image_pixel_limit() -> int | None:
    """Most pixels an image may have: ``PIL.Image.MAX_IMAGE_PIXELS`` (None: no limit)."""
    from PIL import Image

    return Image.MAX_IMAGE_PIXELS


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
    max_side : int or None
        Cap on the longer side of the model input, in pixels (default 640); larger outputs are shrunk, keeping
        the aspect ratio, so memory per batch is bounded. ``image_size`` may not exceed it. None: no cap.
        Part of the cache fingerprint.
    min_side : int
        Images whose model input would have a side shorter than this cannot be used (default 1; the registered
        models use :data:`DEFAULT_MIN_SIDE` = 32).

    Examples
    --------
    >>> Preprocessing(image_size=224).output_size(width=160, height=120)
    (299, 224)
    >>> Preprocessing(multiple_of=14).output_size(width=160, height=120)
    (154, 126)
    >>> Preprocessing().output_size(width=4032, height=3024)   # capped at max_side = 640
    (640, 480)
    """

    image_size: int | tuple[int, int] | None = None
    multiple_of: int = 1
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD
    interpolation: str = "bilinear"
    max_side: int | None = DEFAULT_MAX_SIDE
    min_side: int = 1

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
            object.__setattr__(self, "image_size", tuple(map(int, size)) if isinstance(size, tuple) else int(size))
        multiple = self.multiple_of
        if isinstance(multiple, bool) or not isinstance(multiple, (int, np.integer)) or multiple < 1:
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
        object.__setattr__(self, "min_side", check_count(self.min_side, "min_side", 1))
        if self.max_side is not None:
            floor = max(self.min_side, self.multiple_of)
            object.__setattr__(self, "max_side", check_count(self.max_side, "max_side", floor))
            sides = self.image_size if isinstance(self.image_size, tuple) else (self.image_size or 0,)
            if max(sides) > self.max_side:
                raise ValueError(
                    f"image_size {self.image_size!r} exceeds max_side {self.max_side}; raise max_side to use it"
                )

    def output_size(self, width: int, height: int) -> tuple[int, int]:
        """Size ``(width, height)`` of an image of the given size after resizing (both sides <= ``max_side``)."""
        if self.image_size is None:
            new_w, new_h = width, height
        elif isinstance(self.image_size, tuple):
            new_h, new_w = self.image_size
        else:
            scale = self.image_size / min(width, height)
            new_w, new_h = round(width * scale), round(height * scale)
        cap = self.max_side
        if cap is not None and max(new_w, new_h) > cap:
            scale = cap / max(new_w, new_h)
            new_w, new_h = min(cap, max(1, round(new_w * scale))), min(cap, max(1, round(new_h * scale)))
        if self.multiple_of > 1:
            m = self.multiple_of
            new_w = max(m, round(new_w / m) * m)
            new_h = max(m, round(new_h / m) * m)
            if cap is not None:  # rounding up may pass the cap: take the multiple below it
                new_w, new_h = (side - m if side > cap else side for side in (new_w, new_h))
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
            "max_side": self.max_side,
        }


def _link_problem(path: Path) -> str | None:
    """Why a symbolic link cannot be followed, or None when ``path`` is not a broken link."""
    if not os.path.islink(path):
        return None
    target = printable(os.readlink(path))
    try:
        os.stat(path)
    except OSError as error:
        if error.errno == errno.ELOOP:
            return f"symbolic link to '{target}' that loops back on itself"
        return f"broken symbolic link to '{target}' ({error.strerror or error})"
    return None


class _Unusable(ValueError):
    """Raised inside the loaders for an image whose size rules it out; the message is the reason."""


def _too_many(pixels: str) -> str:
    return (
        f"{pixels}, more than the limit of {image_pixel_limit() or 0:,} (PIL.Image.MAX_IMAGE_PIXELS, protection "
        "against decompression bombs)"
    )


def _check_pixels(width: int, height: int) -> None:
    limit = image_pixel_limit()
    if limit is not None and width * height > limit:
        raise _Unusable(_too_many(f"{width} x {height} pixels"))


@contextlib.contextmanager
def _opened(path: str | Path, name: str | None, reading: str) -> Iterator[Any]:
    """``PIL.Image.open(path)``; what makes the image unusable, there or in the block, raises an ImageDecodeError
    naming it (``reading``: what an unreadable file could not be read for)."""
    from PIL import Image, UnidentifiedImageError

    name = str(path) if name is None else name
    path = Path(path)
    link = _link_problem(path)
    if link is not None:
        raise ImageDecodeError(name, path, link)
    try:
        with Image.open(path) as image:
            yield image
    except _Unusable as error:
        raise ImageDecodeError(name, path, str(error)) from None
    except FileNotFoundError:
        raise ImageDecodeError(name, path, "file not found") from None
    except UnidentifiedImageError:
        reason = "not a recognised image format"
        with contextlib.suppress(OSError):
            reason = "empty file (0 bytes)" if path.stat().st_size == 0 else reason
        raise ImageDecodeError(name, path, reason) from None
    except Image.DecompressionBombError as error:
        claimed = re.search(r"\((\d+) pixels\)", str(error))
        pixels = f"{int(claimed.group(1)):,} pixels" if claimed else "too many pixels"
        raise ImageDecodeError(name, path, _too_many(pixels)) from None
    except MemoryError:
        raise ImageDecodeError(name, path, "not enough memory to decode it") from None
    except (OSError, ValueError, SyntaxError) as error:  # unreadable, truncated or corrupt data
        raise ImageDecodeError(name, path, f"cannot {reading}: {error or type(error).__name__}") from None
    except Exception as error:  # PIL's decoders raise many kinds of errors on corrupt data
        raise ImageDecodeError(name, path, f"corrupt image data ({type(error).__name__}: {error})") from None


def read_image_size(path: str | Path, *, name: str | None = None) -> tuple[int, int]:
    """``(width, height)`` of an image file from its header, checked against the decompression-bomb limit.

    Reads only the header; used by loaders that decode with another library (OpenCV for local features).

    Raises
    ------
    ImageDecodeError
        Naming the image, when it is missing, a broken link, not an image, or over ``PIL.Image.MAX_IMAGE_PIXELS``.
    """
    with _opened(path, name, "read its header") as image:
        width, height = image.size
        _check_pixels(width, height)
    return width, height


def _check_size(width: int, height: int, preprocessing: Preprocessing) -> tuple[int, int]:
    """The output size of an image of ``width`` x ``height`` pixels; ValueError when it cannot be used."""
    _check_pixels(width, height)
    size = preprocessing.output_size(width, height)
    if min(size) < preprocessing.min_side:
        resized = "" if size == (width, height) else f", {size[0]} x {size[1]} after resizing"
        need = f"the model needs at least {preprocessing.min_side} pixels on each side"
        raise _Unusable(f"{width} x {height} pixels{resized}: {need}")
    return size


def load_image(path: str | Path, preprocessing: Preprocessing, *, name: str | None = None) -> np.ndarray:
    """Decode an image file to an RGB ``uint8`` array of shape (H, W, 3), resized as ``preprocessing`` says.

    Both sides of the result are at most ``preprocessing.max_side``; a large JPEG is decoded at reduced size.

    Raises
    ------
    ImageDecodeError
        If the image cannot be used (docs/explanation/descriptors.md): missing, unreadable, broken symbolic link, not
        an image, truncated, over the decompression-bomb limit, or smaller than ``preprocessing.min_side``. The
        message names the image and the reason.
    """
    from PIL import Image

    with _opened(path, name, "decode it") as image:
        width, height = image.size
        size = _check_size(width, height, preprocessing)
        box = None
        if min(width // (2 * size[0]), height // (2 * size[1])) >= 2:
            # JPEG: decode at 1/2, 1/4 or 1/8 scale, still at least twice the target size (as thumbnail())
            drafted = image.draft("RGB", (2 * size[0], 2 * size[1]))
            box = None if drafted is None else drafted[1]
        image.load()
        rgb = image.convert("RGB")
    if size != rgb.size or box is not None:
        rgb = rgb.resize(size, resample=Image.Resampling[preprocessing.interpolation.upper()], box=box)
    return np.asarray(rgb, dtype=np.uint8)


def to_model_input(images: Sequence[np.ndarray], preprocessing: Preprocessing, device: Any) -> Any:
    """Stack equally sized ``uint8`` (H, W, 3) arrays into a normalised float tensor (B, 3, H, W) on ``device``."""
    torch = require_torch()
    batch = torch.from_numpy(np.stack(images)).to(device)
    batch = batch.permute(0, 3, 1, 2).float().div_(255.0)
    mean = torch.tensor(preprocessing.mean, dtype=batch.dtype, device=batch.device).view(1, 3, 1, 1)
    std = torch.tensor(preprocessing.std, dtype=batch.dtype, device=batch.device).view(1, 3, 1, 1)
    return batch.sub_(mean).div_(std)
