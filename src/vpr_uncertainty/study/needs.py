"""What each (cell, uncertainty method) pair of a reproduction grid needs, checked before any work.

A cell gives its retrieval's fields (the arrays of a retrieval file, the positions of a dataset), the image files
when it has images (``images`` or a model input), the descriptors for a model input, and a local-feature cache;
a method spec gives its own options (``"BTL:btl_head=head.pt"``). What a method needs is its declaration
(:attr:`vpr_uncertainty.methods.UncertaintyMethod.requires`).
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import TYPE_CHECKING

from vpr_uncertainty.methods import describe_needs, get_method

if TYPE_CHECKING:
    from vpr_uncertainty.study.config import InputEntry

__all__ = ["unmet_needs"]

#: What the grid gives every method of a cell: a local-feature cache folder; image paths when it has images.
_GRID_OPTIONS = ("cache_dir",)
_IMAGE_OPTIONS = ("query_paths", "database_paths")
#: How a config meets each need (see vpr_uncertainty.methods.NEEDS).
_HINTS = {
    "database_positions": "a retrieval .npz holding database_positions, or a dataset with positions",
    "images": 'images = "FOLDER" (with query/ and ref/) in this input, or a model input',
    "btl_head": 'the option in the method name, e.g. "BTL:btl_head=HEAD.pt"',
    "descriptors": "a model input, or BTL:query_descriptors=DESC.h5,database_descriptors=DESC.h5",
    "local_features": 'the option in the method name, e.g. "GV-H5:features_path=FEATURES.h5"',
    "gate": 'the option in the method name ("CAL:gate=GATE.json"), or calibration = {fraction = 0.3, repeats = 20, '
    "seed = 0} to fit CAL on each split of a held-out evaluation",
}


def _retrieval_fields(entry: InputEntry) -> set[str] | str:
    """Names of the fields a cell's retrieval will have, or a problem (str) when its file cannot be read."""
    if entry.model is not None:
        from vpr_uncertainty.data import load_dataset

        options = entry.run_options
        try:
            dataset = load_dataset(entry.dataset_source, root=options.get("root"), split=options.get("split"))
        except (OSError, ValueError, KeyError) as error:
            return f"dataset {entry.dataset_source!r} cannot be read: {error}"
        return {key for key, value in dataset.retrieval_fields().items() if value is not None}
    fields = {"scores", "indices", "distances", "positives"}
    is_retrieval = entry.file_format == "retrieval" or (
        entry.file_format == "auto" and entry.scores.suffix.lower() == ".npz"
    )
    if is_retrieval:
        try:
            with zipfile.ZipFile(entry.scores) as archive:
                fields = {name.removesuffix(".npy") for name in archive.namelist()}
        except (OSError, zipfile.BadZipFile) as error:
            return f"{entry.scores} is not a readable retrieval file (.npz): {error}"
    return fields


def _inputs_exist(entry: InputEntry) -> bool:
    if entry.model is None:
        return entry.scores is not None and entry.scores.is_file()
    root = entry.run_options.get("root")
    return Path(entry.dataset_source).exists() or (root is not None and (Path(root) / entry.dataset_source).exists())


def unmet_needs(entries: list[InputEntry], methods: list[str]) -> list[str]:
    """Every (cell, method) pair whose method needs what the cell's inputs do not give, one line each.

    A cell gives its retrieval's fields (a retrieval file's arrays, the positions of a dataset), the image files
    when it has images (``images`` or a model input), the descriptors for a model input, and a feature cache.
    """
    from vpr_uncertainty.pipeline import PIPELINE_OPTIONS

    found = [get_method(name) for name in methods]
    lines = []
    for entry in entries:
        if not _inputs_exist(entry):
            continue  # reported as missing by the config loader
        cell = f"cell {entry.vpr_method} / {entry.dataset}"
        given = {*_GRID_OPTIONS, *(_IMAGE_OPTIONS if entry.images is not None else ())}
        if entry.model is not None:
            given |= set(PIPELINE_OPTIONS)
        if any(method.unmet_needs(given) for method in found):  # read the inputs only when it matters
            fields = _retrieval_fields(entry)
            if isinstance(fields, str):
                lines.append(f"{cell}: {fields}")
                continue
            given |= fields
        for method in found:
            for need in method.unmet_needs(given):
                hint = f"; give {_HINTS[need]}" if need in _HINTS else ""
                lines.append(f"{cell}: {method.name} needs {describe_needs([need])}{hint}")
    return lines
