"""Stage 1, ``extract``: the images of both splits -> ``descriptors.h5`` (global descriptors, resumed per image: a rerun
computes exactly the images that are new or changed; what the file stores: see docs/explanation/caches.md).
"""

from __future__ import annotations

import argparse
import contextlib
import shutil
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty import cache
from vpr_uncertainty._repr import compact_repr
from vpr_uncertainty.data import load_dataset
from vpr_uncertainty.data.images import IMAGE_SPLIT_FOLDERS, ImageListingError, MalformedImageNameError, list_images
from vpr_uncertainty.descriptors import DEFAULT_MODEL, available_models, get_model_spec
from vpr_uncertainty.formats.hloc import write_hloc_descriptors
from vpr_uncertainty.pipeline.options import (
    DECODING_THREADS,
    add_executor_options,
    add_options,
    add_progress_options,
    apply_threads,
    conf_from_args,
    device_name,
    executor_from_args,
    executor_options,
    integer_at_least,
    local_workers,
    option,
    output_file,
    positive_int,
)

__all__ = [
    "Descriptors",
    "ExtractConf",
    "add_cli",
    "cached",
    "compute",
    "default_conf",
    "fingerprint_of",
    "main",
    "model_of",
]

SPLITS = ("database", "queries")
#: Image files a dataset folder scan picks up (case-insensitive).
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".ppm", ".pgm", ".tif", ".tiff", ".webp")


@dataclass(frozen=True)
class ExtractConf:
    """How descriptors are computed; each field is also the command-line option of the same name."""

    model: str = option(
        DEFAULT_MODEL, "descriptor model: a registered name (see `extract --help`) or a TorchScript file"
    )
    device: str = option("cpu", "cpu, cuda, cuda:N or mps (extraction and Faiss search)", type=device_name)
    batch_size: int = option(16, "images per forward pass", type=positive_int)
    half: bool = option(False, "store descriptors as float16 instead of float32")
    on_error: str = option(
        "fail",
        "images that cannot be used (unreadable, corrupt, broken links, over PIL's decompression-bomb limit, smaller "
        "than the model's minimum, names not valid UTF-8) and folders that cannot be listed: stop with an error "
        "naming the first, or leave them out, counted and named in a warning, in the file's 'failed' attribute and "
        "in results.json",
        choices=("fail", "skip"),
    )
    image_size: int | None = option(
        None,
        "resize so that the shorter image side has this many pixels (default: the model's own setting)",
        type=positive_int,
    )
    max_side: int | None = option(
        None,
        "cap on the longer side of the model input, in pixels (default 640); larger images are shrunk keeping their "
        "aspect ratio, so memory per batch is bounded: about 235 bytes per pixel for the default model on CPU, i.e. "
        "about 2 GB for 16 images of 640 x 640",
        type=integer_at_least(32),
    )
    workers: int | None = field(default=None)  # image decoding threads: the executor option --workers
    overwrite: bool = field(default=False)
    progress: bool | None = field(default=None)


#: The configuration of the stage when none is given (hloc's ``default_conf``).
default_conf = ExtractConf()


@dataclass
class Descriptors:
    """What :func:`compute` produced: the file, and the descriptors and names of each split in memory.

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

    __repr__ = compact_repr

    path: Path
    model_name: str
    names: dict[str, np.ndarray]
    descriptors: dict[str, np.ndarray]
    failed: dict[str, list[dict[str, str]]] = field(default_factory=dict)

    def split(self, split: str) -> tuple[np.ndarray, np.ndarray]:
        """``(names, descriptors)`` of one split."""
        return self.names[split], self.descriptors[split]


def _preprocessing_changes(conf: ExtractConf) -> dict[str, Any]:
    return {
        key: value for key, value in (("image_size", conf.image_size), ("max_side", conf.max_side)) if value is not None
    }


def model_of(conf: ExtractConf) -> Any:
    """The descriptor model of ``conf``, with its preprocessing overrides applied."""
    from vpr_uncertainty.descriptors.models import load_model

    model = load_model(conf.model, device=conf.device)
    changes = _preprocessing_changes(conf)
    if changes:
        model.preprocessing = model.preprocessing.replace(**changes)
    return model


def fingerprint_of(conf: ExtractConf) -> dict[str, Any] | None:
    """``model_of(conf).fingerprint``, found without loading the model (no torch); None when only loading it can
    tell (:func:`~vpr_uncertainty.descriptors.models.model_identity`)."""
    from vpr_uncertainty.descriptors.models import fingerprint_of as model_fingerprint
    from vpr_uncertainty.descriptors.models import model_identity

    identity = model_identity(conf.model)
    if identity is None:
        return None
    name, weights_id, preprocessing, code = identity
    changes = _preprocessing_changes(conf)
    return model_fingerprint(name, weights_id, preprocessing.replace(**changes) if changes else preprocessing, code)


def cached(
    conf: ExtractConf, images: Mapping[str, tuple[Sequence[str | Path], Sequence[str]]], path: str | Path
) -> Descriptors | None:
    """The :class:`Descriptors` that :func:`compute` would return when ``path`` already holds every image of
    ``images`` for the model and preprocessing of ``conf``, found without loading the model; None when anything
    must be computed, repaired or rebuilt, or when the model cannot be identified without loading it."""
    from vpr_uncertainty.descriptors.extract import cached_descriptors

    path = Path(path)
    config = fingerprint_of(conf) if path.is_file() and not conf.overwrite else None
    if config is None:
        return None
    result = Descriptors(path=path, model_name=config["model"], names={}, descriptors={})
    for split in (split for split in SPLITS if split in images):
        found = cached_descriptors(config, *images[split], path, split, half=conf.half)
        if found is None:
            return None
        result.names[split], result.descriptors[split] = found
        result.failed[split] = []
    return result


def compute(
    conf: ExtractConf,
    images: Mapping[str, tuple[Sequence[str | Path], Sequence[str]]],
    path: str | Path,
    *,
    model: Any = None,
    executor: Any = None,
) -> Descriptors:
    """Descriptors of the images of each split, written to (and resumed from) ``path``.

    Parameters
    ----------
    conf : ExtractConf
    images : mapping
        ``{"database": (paths, names), "queries": (paths, names)}`` (either split may be absent).
    path : str or Path
        The HDF5 file.
    model : DescriptorModel, optional
        An already loaded model (default: :func:`model_of` of ``conf``, loaded only when a descriptor must be
        computed: when ``path`` holds them all, :func:`cached` returns them without importing torch).
    executor : LocalExecutor or RayExecutor, optional
        Where the model runs (default: in this process); with Ray, each actor loads the model of ``conf`` once
        and this process writes the same file as a local run.
    """
    from vpr_uncertainty.descriptors.extract import extract_descriptors

    unknown = set(images) - set(SPLITS)
    if unknown:
        raise ValueError(f"images must be keyed by {SPLITS}, got {sorted(unknown)}")
    if model is None:
        # a warm rerun: every descriptor cached for this model and preprocessing; the model is not loaded
        found = cached(conf, images, path)
        if found is not None:
            return found
    factory = None
    if model is None and executor is not None and executor.name != "local":
        factory = partial(model_of, conf)
    model = model_of(conf) if model is None else model
    path = Path(path)
    result = Descriptors(path=path, model_name=model.name, names={}, descriptors={})
    with _whole_file_kept(path) as working:
        for split in (split for split in SPLITS if split in images):
            result.failed[split] = []
            result.names[split], result.descriptors[split] = extract_descriptors(
                model,
                *images[split],
                working,
                split,
                batch_size=conf.batch_size,
                device=conf.device,
                half=conf.half,
                on_error=conf.on_error,
                workers=conf.workers,
                overwrite=conf.overwrite and split == next(s for s in SPLITS if s in images),
                progress=conf.progress,
                failed=result.failed[split],
                executor=executor,
                model_factory=factory,
            )
    return result


@contextlib.contextmanager
def _whole_file_kept(path: Path) -> Iterator[Path]:
    """``path``, or when it holds a whole descriptor file (every split complete), a copy of it that replaces it once
    every split is written: a failed update or rebuild (disk full, a file size limit, an error) leaves it as it was.
    A file still being extracted is resumed in place, so that an interrupted first extraction keeps its rows."""
    from vpr_uncertainty.descriptors.cache import is_whole

    if not path.is_file() or not is_whole(path):
        yield path
        return
    with cache.atomic_path(path) as temporary:
        shutil.copyfile(path, temporary)
        yield temporary


def main(conf: ExtractConf, dataset: str | Path, out: str | Path, *, executor: Any = None) -> Path:
    """Descriptors of every image of ``dataset`` (a folder or a registered name) in the HDF5 file ``out``."""
    return compute(conf, dataset_images(dataset), out, executor=executor).path


# --- reading a dataset's images ------------------------------------------------------------------------------


def _scan(folder: Path, root: Path, unlisted: list[dict[str, str]]) -> tuple[list[Path], list[str]]:
    found: list[dict[str, str]] = []
    paths = list_images(folder, problems=found)
    unlisted.extend(found)
    if not paths:
        if found:
            raise ImageListingError(folder, found)
        raise FileNotFoundError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {folder}")
    return paths, [path.relative_to(root).as_posix() for path in paths]


def _scan_dataset(folder: Path, unlisted: list[dict[str, str]]) -> dict[str, tuple[list[Path], list[str]]] | None:
    for queries, database in IMAGE_SPLIT_FOLDERS:  # VPR-Bench, then VPR-methods-evaluation
        if (folder / database).is_dir() and (folder / queries).is_dir():
            return {
                "database": _scan(folder / database, folder, unlisted),
                "queries": _scan(folder / queries, folder, unlisted),
            }
    return None


def dataset_images(
    dataset: str | Path, *, unlisted: list[dict[str, str]] | None = None
) -> dict[str, tuple[list[Path], list[str]]]:
    """Image paths and names of both splits: ``{"database": (paths, names), "queries": (paths, names)}``.

    Reads the dataset with :func:`vpr_uncertainty.data.load_dataset` (any format or registered name); a folder it
    cannot read (images without ground truth) with ``ref/`` and ``query/`` (VPR-Bench) or ``database/`` and
    ``queries/`` subfolders is scanned for images, named by their POSIX path relative to the folder. ``unlisted``
    receives ``{"path", "error"}`` of each folder or link that could not be listed; without it, such a problem raises
    :class:`~vpr_uncertainty.data.images.ImageListingError` naming it.
    """
    folder = Path(dataset)
    found: list[dict[str, str]] = []
    try:
        loaded = load_dataset(dataset)
    except (FileNotFoundError, MalformedImageNameError):  # no ground truth, names without positions; not a dataset
        # that is there but wrong (images that do not match its ground truth): that is refused
        scanned = _scan_dataset(folder, found) if folder.is_dir() else None
        if scanned is None:
            raise
    else:
        if loaded.database_paths is None or loaded.query_paths is None:
            raise ValueError(f"dataset {dataset} has no image files (positions only); extraction needs images")
        found = list(loaded.unlisted)
        scanned = {
            "database": (list(loaded.database_paths), list(loaded.database_names)),
            "queries": (list(loaded.query_paths), list(loaded.query_names)),
        }
    if found and unlisted is None:
        raise ImageListingError(folder, found)
    if unlisted is not None:
        unlisted.extend(found)
    return scanned


# --- command line --------------------------------------------------------------------------------------------


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """The ``extract`` command."""
    parser = subparsers.add_parser(
        "extract",
        help="compute global image descriptors of a dataset (HDF5, resumable)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Compute an L2-normalised global descriptor for every database and query image of a dataset and\n"
            "store them in an HDF5 file keyed by image name. A rerun resumes an interrupted extraction; a file\n"
            "made by another model or preprocessing is recomputed.\n\n"
            "Models (torch.hub models download code and weights into the torch.hub cache on first use):\n"
            + "\n".join(f"  {name:<24}{get_model_spec(name).description}" for name in available_models())
            + f"\n  {'FILE.pt':<24}your own TorchScript model: normalised images (B, 3, H, W) -> (B, D)"
        ),
        epilog=(
            "example:\n  vpr-uncertainty extract --dataset corridor/ --model efficientnet-lite0-gem "
            "--out runs/corridor/descriptors.h5"
        ),
    )
    parser.add_argument(
        "--dataset",
        required=True,
        help="dataset path or registered name (any format of vpr_uncertainty.data), or a folder with ref/ and "
        "query/ (VPR-Bench) or database/ and queries/ image subfolders",
    )
    parser.add_argument("--out", type=output_file, required=True, help="HDF5 file to write (resumed if it exists)")
    add_options(parser, ExtractConf)
    add_threads_option(parser)
    parser.add_argument(
        "--hloc",
        type=output_file,
        metavar="FILE",
        help="also write the descriptors in hloc's global-feature layout (one group per image name with a "
        "'global_descriptor'), for hloc.pairs_from_retrieval",
    )
    parser.add_argument("--overwrite", action="store_true", help="recompute everything, ignoring the file")
    add_progress_options(parser)
    add_executor_options(
        parser,
        local_workers=DECODING_THREADS,
        ray_workers="the Ray actors, each loading the model once and decoding its own images "
        "(default: the cluster's CPUs)",
    )
    parser.set_defaults(handler=_handle)


def add_threads_option(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--threads``: CPU threads of the model (``run`` and ``extract``)."""
    parser.add_argument(
        "--threads",
        type=positive_int,
        help="CPU threads of the model (torch.set_num_threads; default torch's choice). On a CPU shared with "
        "other jobs, 1 can be several times faster",
    )


def _handle(args: argparse.Namespace) -> int:
    from vpr_uncertainty.data.images import describe_unlisted

    executor_options(args)  # bad executor options fail before any work
    unlisted: list[dict[str, str]] | None = [] if args.on_error == "skip" else None
    splits = dataset_images(args.dataset, unlisted=unlisted)
    if unlisted:
        warnings.warn(
            f"left out the images under {len(unlisted)} path(s) that cannot be listed: {describe_unlisted(unlisted)}",
            stacklevel=2,
        )
    apply_threads(args.threads)
    conf = conf_from_args(
        ExtractConf,
        args,
        workers=local_workers(args),
        overwrite=args.overwrite,
        progress=getattr(args, "progress", None),
    )
    with executor_from_args(args) as executor:
        result = compute(conf, splits, args.out, executor=None if executor.name == "local" else executor)
    for split in SPLITS:
        kept, descriptors = result.split(split)
        skipped = len(splits[split][1]) - len(kept)
        note = f", {skipped} skipped (cannot be used; listed in the file's 'failed' attribute)" if skipped else ""
        print(f"{split}: {len(kept)} descriptors of size {descriptors.shape[1]}{note}")
    print(f"wrote {args.out}")
    if args.hloc is not None:
        partial_file = args.hloc.with_name(args.hloc.name + ".part")  # written whole, then renamed
        partial_file.unlink(missing_ok=True)
        for split in SPLITS:
            write_hloc_descriptors(partial_file, *result.split(split))
        partial_file.replace(args.hloc)
        print(f"wrote {args.hloc} (hloc layout)")
    return 0
