"""What ``evaluate`` reads besides SCORES: image folders for the ``GV-*`` methods, other tools' outputs, and
the default method list (the registry's, shared with ``run`` and ``demo``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from vpr_uncertainty.commands._arguments import add_alias, non_negative_float

__all__ = ["add_input_options", "read_inputs"]

_IMAGES_HINT = (
    "give --images DIR (a dataset folder with query/ and ref/, or queries/ and database/) or --query-images and "
    "--database-images"
)


def add_input_options(parser: argparse.ArgumentParser) -> None:
    """``--images``, ``--query-images``, ``--database-images`` and ``--radius`` (with the field's aliases)."""
    group = parser.add_argument_group(
        "images, for the methods that verify them (GV-*): query i and database image j are the i-th and j-th "
        "images of their folder, sorted by path (VPR-Bench, VPR-datasets-downloader), or the names a retrieval "
        "file holds"
    )
    group.add_argument(
        "--images",
        type=Path,
        metavar="DIR",
        help="dataset folder with query/ and ref/ (VPR-Bench) or queries/ and database/ image subfolders",
    )
    group.add_argument("--query-images", type=Path, metavar="DIR", help="folder of the query images")
    group.add_argument("--database-images", type=Path, metavar="DIR", help="folder of the database images")
    add_alias(group, "--queries_folder", new="--query-images", type=Path)
    add_alias(group, "--database_folder", new="--database-images", type=Path)
    parser.add_argument(
        "--radius",
        type=non_negative_float,
        help="VPR-methods-evaluation log folders: positives within this many metres (default: the run's "
        "positive_dist_threshold, else 25)",
    )
    add_alias(parser, "--positive_dist_threshold", new="--radius", type=non_negative_float)


def _needs_images(methods: list[str]) -> list[str]:
    from vpr_uncertainty.methods import get_method

    def verifies(name: str) -> bool:
        entry = get_method(name)
        accepted = entry.accepted_options()
        if accepted is None:  # takes any option (a cascade SCORE+GV, a plugin): what it requires says
            return "images" in entry.requires
        return "query_paths" in accepted

    return [name for name in methods if verifies(name)]


def read_inputs(args: argparse.Namespace, *, top_k: int) -> tuple[Any, list[str], dict[str, Any], list[str]]:
    """Read SCORES and the image folders of ``evaluate``'s arguments.

    Returns
    -------
    retrieval : Retrieval
    methods : list of str
        ``--methods``, else the default list (with SUE when the results hold metric positions, as ``run``).
    options : dict
        ``query_paths`` / ``database_paths`` for the methods that verify images.
    notes : list of str
        What was derived (ground truth of a log folder, predictions checked).
    """
    from vpr_uncertainty.data import read_results
    from vpr_uncertainty.data.results import read_vpr_methods_evaluation
    from vpr_uncertainty.methods import default_method_names

    notes: list[str] = []
    log_paths: tuple[Any, Any] = (None, None)
    if Path(args.scores).is_dir() and args.format == "auto":
        log = read_vpr_methods_evaluation(args.scores, ground_truth=args.gt, radius=args.radius, top_k=top_k)
        retrieval, notes, log_paths = log.retrieval, log.notes, (log.query_paths, log.database_paths)
    else:
        if args.radius is not None:
            raise ValueError(
                "--radius applies to VPR-methods-evaluation log folders; a results file holds or is given (--gt) "
                "its ground truth"
            )
        retrieval = read_results(args.scores, ground_truth=args.gt, file_format=args.format, top_k=top_k)
    methods = args.methods
    if methods is None:
        kind = retrieval.config.get("position_kind")
        methods = default_method_names(
            metric_positions=retrieval.database_positions is not None and kind in (None, "metres")
        )
    verifying = _needs_images(methods)
    folders = {"images": args.images, "query_images": args.query_images, "database_images": args.database_images}
    given = any(value is not None for value in folders.values())
    if given and not verifying:
        raise ValueError(
            "--images, --query-images and --database-images feed the methods that verify images (GV-*); "
            "none is in --methods"
        )
    options: dict[str, Any] = {}
    if verifying:
        if given:
            from vpr_uncertainty.data.images import retrieval_image_paths

            query_paths, database_paths = retrieval_image_paths(retrieval, **folders)
        elif log_paths[0] is not None:
            query_paths, database_paths = log_paths
            notes.append("images: the folders named in the log folder's info.log")
        else:
            raise ValueError(
                f"{', '.join(verifying)} verif{'ies' if len(verifying) == 1 else 'y'} images: {_IMAGES_HINT}"
            )
        options = {"query_paths": [str(p) for p in query_paths], "database_paths": [str(p) for p in database_paths]}
    return retrieval, methods, options, notes
