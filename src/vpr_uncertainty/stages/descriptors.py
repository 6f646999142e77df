"""Stage 1, global descriptors: the images of both splits → ``descriptors.h5``.

The artefact follows :mod:`vpr_uncertainty.cache`: the file stores the fingerprint of the model and its
preprocessing and, per image, the content key of the file it was computed from, so a rerun computes exactly the
images that are new or changed (see :mod:`vpr_uncertainty.descriptors.cache`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.descriptors.models import DEFAULT_MODEL

__all__ = ["DescriptorsConfig", "DescriptorsResult", "extract", "model_of"]

_SPLITS = ("database", "queries")


@dataclass(frozen=True)
class DescriptorsConfig:
    """How :func:`extract` computes descriptors.

    Attributes
    ----------
    model : str or Path
        A registered descriptor model or a TorchScript file.
    device : str
        ``"cpu"``, ``"cuda"``, ``"cuda:N"`` or ``"mps"``.
    batch_size : int
        Images per forward pass (and per flush of the file).
    half : bool
        Store float16 instead of float32.
    on_error : {"fail", "skip"}
        What to do with an image that cannot be used.
    image_size, max_side : int, optional
        Overrides of the model's preprocessing.
    num_workers : int, optional
        Image decoding threads.
    overwrite : bool
        Recompute every image, ignoring the file.
    progress : bool, optional
        Show progress bars (default: when stderr is a terminal; see :mod:`vpr_uncertainty.progress`).
    """

    model: str | Path = DEFAULT_MODEL
    device: str = "cpu"
    batch_size: int = 16
    half: bool = False
    on_error: str = "fail"
    image_size: int | None = None
    max_side: int | None = None
    num_workers: int | None = None
    overwrite: bool = False
    progress: bool | None = None


@dataclass
class DescriptorsResult:
    """What :func:`extract` produced: the file, and the descriptors and names of each split in memory.

    Attributes
    ----------
    path : Path
        ``descriptors.h5``.
    model_name : str
    names : dict of str to ndarray of str
        Per split, the images that have a descriptor, in the requested order.
    descriptors : dict of str to ndarray of shape (N, D), float32
    failed : dict of str to list of dict
        Per split, the images left out (``{"name", "path", "error"}``), with ``on_error="skip"``.
    """

    path: Path
    model_name: str
    names: dict[str, np.ndarray]
    descriptors: dict[str, np.ndarray]
    failed: dict[str, list[dict[str, str]]] = field(default_factory=dict)

    def split(self, split: str) -> tuple[np.ndarray, np.ndarray]:
        """``(names, descriptors)`` of one split."""
        return self.names[split], self.descriptors[split]


def model_of(conf: DescriptorsConfig) -> Any:
    """The descriptor model of ``conf``, with its preprocessing overrides applied."""
    from vpr_uncertainty.descriptors.models import load_model

    model = load_model(conf.model, device=conf.device)
    changes = {
        key: value for key, value in (("image_size", conf.image_size), ("max_side", conf.max_side)) if value is not None
    }
    if changes:
        model.preprocessing = model.preprocessing.replace(**changes)
    return model


def extract(
    conf: DescriptorsConfig,
    images: Mapping[str, tuple[Sequence[str | Path], Sequence[str]]],
    path: str | Path,
    *,
    model: Any = None,
    executor: Any = None,
) -> DescriptorsResult:
    """Descriptors of the images of each split, written to (and resumed from) ``path``.

    Parameters
    ----------
    conf : DescriptorsConfig
    images : mapping
        ``{"database": (paths, names), "queries": (paths, names)}`` (either split may be absent).
    path : str or Path
        The HDF5 file.
    model : DescriptorModel, optional
        An already loaded model (default: :func:`model_of` of ``conf``).
    executor : LocalExecutor or RayExecutor, optional
        Where the model runs (default: in this process); with Ray, each actor loads the model of ``conf`` once
        (or receives ``model`` when one is given) and this process writes the same file as a local run.

    Returns
    -------
    DescriptorsResult
    """
    from vpr_uncertainty.descriptors.extract import extract_descriptors

    unknown = set(images) - set(_SPLITS)
    if unknown:
        raise ValueError(f"images must be keyed by {_SPLITS}, got {sorted(unknown)}")
    factory = None
    if model is None and executor is not None and executor.name != "local":
        from functools import partial

        factory = partial(model_of, conf)
    model = model_of(conf) if model is None else model
    path = Path(path)
    result = DescriptorsResult(path=path, model_name=model.name, names={}, descriptors={})
    for split in _SPLITS:
        if split not in images:
            continue
        paths, names = images[split]
        failed: list[dict[str, str]] = []
        result.names[split], result.descriptors[split] = extract_descriptors(
            model,
            paths,
            names,
            path,
            split,
            batch_size=conf.batch_size,
            device=conf.device,
            half=conf.half,
            on_error=conf.on_error,
            workers=conf.num_workers,
            overwrite=conf.overwrite and split == next(s for s in _SPLITS if s in images),
            progress=conf.progress,
            failed=failed,
            executor=executor,
            model_factory=factory,
        )
        result.failed[split] = failed
    return result
