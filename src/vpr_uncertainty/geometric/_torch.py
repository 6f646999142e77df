"""The torch helpers the local-feature models share: the device, the CPU thread count, images as a tensor.

Importing this module does not import torch; calling a helper does.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np

__all__ = ["images_to_tensor", "torch_device", "torch_threads"]


def torch_device(device: str | None) -> Any:
    """A torch device from ``"cpu"``/``"cuda"``/``"cuda:1"`` (None = cpu), with a clear error without CUDA."""
    import torch

    device = "cpu" if device is None else str(device)
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"device={device!r} was requested but torch sees no CUDA device; use device='cpu'")
    try:
        return torch.device(device)
    except RuntimeError as error:
        raise ValueError(f"device must be 'cpu' or 'cuda', got {device!r}") from error


@contextlib.contextmanager
def torch_threads(workers: int | None) -> Iterator[None]:
    """Run torch's CPU operators on ``workers`` threads inside the block, then restore the previous setting."""
    import torch

    if workers is None:
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(max(1, int(workers)))
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def images_to_tensor(images: list[np.ndarray], device: Any) -> Any:
    """A float32 (B, C, H, W) tensor in [0, 1] on ``device`` from equal-sized uint8 images ((H, W) or (H, W, C))."""
    import torch

    array = np.stack(images)
    if array.ndim == 3:
        array = array[..., None]
    return torch.from_numpy(array).permute(0, 3, 1, 2).to(device=device, dtype=torch.float32).div_(255.0)
