"""``vpr-uncertainty datasets``: the named benchmark datasets, where they go, and which are present."""

from __future__ import annotations

import argparse
from pathlib import Path

from vpr_uncertainty.pipeline.options import add_json_option, write_json


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``datasets`` command."""
    parser = subparsers.add_parser(
        "datasets",
        help="list the named benchmark datasets and which are present under the data root",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "List the benchmark datasets that can be read by name (e.g. 'st_lucia'): the folder each is expected\n"
            "in under the data root, the split, the positive threshold, the image counts, where to get it, and\n"
            "whether it is present. The data root is --root, else the VPR_UNCERTAINTY_DATA environment variable.\n"
            "Nothing is downloaded: each dataset is fetched and formatted with the tool named in its entry."
        ),
        epilog="example:\n  vpr-uncertainty datasets --root ~/VPR-datasets-downloader/datasets",
    )
    parser.add_argument("names", nargs="*", metavar="NAME", help="only these datasets (default: all)")
    parser.add_argument("--root", type=Path, help="data root (default: $VPR_UNCERTAINTY_DATA)")
    add_json_option(parser, "the list")
    parser.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    from vpr_uncertainty.data.named_datasets import (
        DATA_ROOT_VARIABLE,
        NAMED_DATASET_REGISTRY,
        data_root,
        find_named_dataset,
        get_named_dataset,
    )

    entries = [get_named_dataset(name) for name in args.names] if args.names else list(NAMED_DATASET_REGISTRY)
    root = data_root(args.root)
    found = {entry.name: find_named_dataset(entry.name, root) if root is not None else None for entry in entries}
    if args.json:
        records = [
            {**entry.to_dict(), "found": None if root is None else found[entry.name] is not None}
            | ({"path": str(found[entry.name])} if found[entry.name] is not None else {})
            for entry in entries
        ]
        write_json(args.json, {"root": None if root is None else str(root), "datasets": records})
        return 0
    header = ("name", "dataset", "folder under the root", "positives", "database", "queries", "present")
    rows = [
        (
            entry.name,
            entry.title,
            entry.relative_path,
            entry.threshold,
            f"{entry.n_database:,}",
            f"{entry.n_queries:,}",
            "-" if root is None else ("yes" if found[entry.name] is not None else "no"),
        )
        for entry in entries
    ]
    widths = [max(len(row[column]) for row in (header, *rows)) for column in range(len(header))]
    for row in (header, *rows):
        print("  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True)).rstrip())
    print()
    if root is None:
        print(f"data root: not set (pass --root DIR or set {DATA_ROOT_VARIABLE}); presence not checked")
    else:
        print(f"data root: {root}")
    print("\nwhere to get them (then put <folder> under the data root):")
    for entry in entries:
        print(f"  {entry.name}: {entry.source}")
    return 0
