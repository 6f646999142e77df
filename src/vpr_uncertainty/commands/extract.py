"""``vpr-uncertainty extract``: global descriptors of a dataset's images into a resumable HDF5 file."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from vpr_uncertainty.commands._arguments import (
    add_alias,
    add_image_options,
    add_progress_options,
    apply_threads,
    device_name,
    output_file,
    positive_int,
)
from vpr_uncertainty.commands._executor import (
    DECODING_THREADS,
    add_executor_options,
    executor_from_args,
    executor_options,
    local_workers,
)
from vpr_uncertainty.descriptors.extract import ON_ERROR
from vpr_uncertainty.descriptors.models import DEFAULT_MODEL, available_models, get_model_spec

__all__ = ["IMAGE_SUFFIXES", "SPLIT_FOLDERS", "add_parser", "dataset_images"]

#: Image files a dataset folder scan picks up (case-insensitive).
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".ppm", ".pgm", ".tif", ".tiff", ".webp")
#: (database folder, queries folder) pairs a dataset folder may have: VPR-Bench, then VPR-methods-evaluation.
SPLIT_FOLDERS = (("ref", "query"), ("database", "queries"))


def _scan(folder: Path, root: Path, unlisted: list[dict[str, str]]) -> tuple[list[Path], list[str]]:
    from vpr_uncertainty.data.images import ImageListingError, list_images

    found: list[dict[str, str]] = []
    paths = list_images(folder, problems=found)
    unlisted.extend(found)
    if not paths:
        if found:
            raise ImageListingError(folder, found)
        raise FileNotFoundError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {folder}")
    return paths, [path.relative_to(root).as_posix() for path in paths]


def _scan_dataset(folder: Path, unlisted: list[dict[str, str]]) -> dict[str, tuple[list[Path], list[str]]] | None:
    for database, queries in SPLIT_FOLDERS:
        if (folder / database).is_dir() and (folder / queries).is_dir():
            return {
                "database": _scan(folder / database, folder, unlisted),
                "queries": _scan(folder / queries, folder, unlisted),
            }
    return None


def _checked(
    scanned: dict[str, tuple[list[Path], list[str]]] | None,
    found: list[dict[str, str]],
    unlisted: list[dict[str, str]] | None,
    folder: Path,
) -> dict[str, tuple[list[Path], list[str]]] | None:
    from vpr_uncertainty.data.images import ImageListingError

    if found and unlisted is None:
        raise ImageListingError(folder, found)
    if unlisted is not None:
        unlisted.extend(found)
    return scanned


def dataset_images(
    dataset: str | Path, *, unlisted: list[dict[str, str]] | None = None
) -> dict[str, tuple[list[Path], list[str]]]:
    """Image paths and names of both splits: ``{"database": (paths, names), "queries": (paths, names)}``.

    Reads the dataset with ``vpr_uncertainty.data.load_dataset`` (any format or registered name it knows) when
    that is available; a folder it cannot read (e.g. images without ground truth) with ``ref/`` and ``query/``
    (VPR-Bench) or ``database/`` and ``queries/`` subfolders is scanned for images. Names are POSIX paths
    relative to the dataset folder, e.g. ``ref/0000000.jpg``.

    Parameters
    ----------
    dataset : str or Path
    unlisted : list, optional
        Receives ``{"path", "error"}`` of each folder or link that could not be listed (images under it are
        missing). By default such a problem raises
        :class:`~vpr_uncertainty.data.folder.ImageListingError` naming it.
    """
    try:
        from vpr_uncertainty.data import load_dataset
    except ImportError:
        load_dataset = None
    folder = Path(dataset)
    found: list[dict[str, str]] = []
    if load_dataset is not None:
        try:
            loaded = load_dataset(dataset)
        except (FileNotFoundError, ValueError):
            scanned = _scan_dataset(folder, found) if folder.is_dir() else None
            if scanned is None:
                raise
            return _checked(scanned, found, unlisted, folder)  # type: ignore[return-value]
        if loaded.database_paths is None or loaded.query_paths is None:
            raise ValueError(f"dataset {dataset} has no image files (positions only); extraction needs images")
        _checked(None, list(loaded.unlisted), unlisted, folder)
        return {
            "database": (list(loaded.database_paths), list(loaded.database_names)),
            "queries": (list(loaded.query_paths), list(loaded.query_names)),
        }
    if not folder.is_dir():
        raise FileNotFoundError(f"dataset folder not found: {folder}")
    scanned = _checked(_scan_dataset(folder, found), found, unlisted, folder)
    if scanned is None:
        expected = " or ".join(f"{d}/ and {q}/" for d, q in SPLIT_FOLDERS)
        raise FileNotFoundError(f"{folder} has no image subfolders {expected}")
    return scanned


def _model_help() -> str:
    lines = []
    for name in available_models():
        spec = get_model_spec(name)
        lines.append(f"  {name:<24}{spec.description}")
    return "\n".join(lines)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``extract`` command."""
    parser = subparsers.add_parser(
        "extract",
        help="compute global image descriptors of a dataset (HDF5, resumable)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Compute an L2-normalised global descriptor for every database and query image of a dataset and\n"
            "store them in an HDF5 file keyed by image name. A rerun resumes an interrupted extraction; a file\n"
            "made by another model or preprocessing is recomputed.\n\n"
            "Models (torch.hub models download code and weights into the torch.hub cache on first use):\n"
            + _model_help()
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
    parser.add_argument(
        "--model", default=DEFAULT_MODEL, help=f"model name (see above) or TorchScript file (default {DEFAULT_MODEL})"
    )
    parser.add_argument("--out", type=output_file, required=True, help="HDF5 file to write (resumed if it exists)")
    parser.add_argument("--device", type=device_name, default="cpu", help="cpu, cuda, cuda:N or mps (default cpu)")
    parser.add_argument("--batch-size", type=positive_int, default=16, help="images per forward pass (default 16)")
    add_alias(parser, "--batch_size", new="--batch-size", type=positive_int)
    parser.add_argument("--half", action="store_true", help="store descriptors as float16 instead of float32")
    parser.add_argument(
        "--on-error",
        choices=ON_ERROR,
        default="fail",
        help="images that cannot be used (unreadable, corrupt, broken links, over PIL's decompression-bomb limit, "
        "smaller than the model's minimum, names not valid UTF-8) and folders that cannot be listed: stop with an "
        "error naming the first, or leave them out, counted and named in a warning and in the file's 'failed' "
        "attribute (default fail)",
    )
    add_image_options(parser)
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
    parser.set_defaults(handler=_run_extract)


def _run_extract(args: argparse.Namespace) -> int:
    from vpr_uncertainty.data.images import describe_unlisted
    from vpr_uncertainty.stages.descriptors import DescriptorsConfig, extract

    executor_options(args)  # bad executor options fail before any work
    unlisted: list[dict[str, str]] | None = [] if args.on_error == "skip" else None
    splits = dataset_images(args.dataset, unlisted=unlisted)
    if unlisted:
        warnings.warn(
            f"left out the images under {len(unlisted)} path(s) that cannot be listed: {describe_unlisted(unlisted)}",
            stacklevel=2,
        )
    apply_threads(args.threads)
    conf = DescriptorsConfig(
        model=args.model,
        device=args.device,
        batch_size=args.batch_size,
        half=args.half,
        on_error=args.on_error,
        image_size=args.image_size,
        max_side=args.max_side,
        num_workers=local_workers(args),
        overwrite=args.overwrite,
        progress=getattr(args, "progress", None),
    )
    with executor_from_args(args) as executor:
        options = {} if executor.name == "local" else {"executor": executor}
        result = extract(conf, splits, args.out, **options)
    for split in ("database", "queries"):
        kept, descriptors = result.split(split)
        skipped = len(splits[split][1]) - len(kept)
        note = f", {skipped} skipped (cannot be used; listed in the file's 'failed' attribute)" if skipped else ""
        print(f"{split}: {len(kept)} descriptors of size {descriptors.shape[1]}{note}")
    print(f"wrote {args.out}")
    if args.hloc is not None:
        from vpr_uncertainty.descriptors.hloc import write_hloc_descriptors

        partial = args.hloc.with_name(args.hloc.name + ".part")  # written whole, then renamed: never half a file
        partial.unlink(missing_ok=True)
        for split in ("database", "queries"):
            write_hloc_descriptors(partial, *result.split(split))
        partial.replace(args.hloc)
        print(f"wrote {args.hloc} (hloc layout)")
    return 0
