"""Lazy access to the optional torch dependency."""

from __future__ import annotations

from types import ModuleType

__all__ = ["TORCH_EXTRA_HINT", "require_torch"]

TORCH_EXTRA_HINT = "pip install 'vpr-uncertainty[torch]'"


def require_torch(what: str = "descriptor extraction") -> ModuleType:
    """Import and return :mod:`torch`, or raise an ImportError that names the extra to install."""
    try:
        import torch
    except ImportError as error:
        raise ImportError(
            f"{what} needs PyTorch, which is not installed; install it with {TORCH_EXTRA_HINT}"
        ) from error
    return torch
