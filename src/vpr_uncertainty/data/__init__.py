"""Dataset readers and ground truth.

Every reader returns a :class:`Dataset` (image paths and names, positions when known, positives of each query);
:func:`load_dataset` reads any supported format from a path, or a named benchmark from the data root; a new
format is one :func:`register_format` call (see :mod:`vpr_uncertainty.data.formats`).
"""

from vpr_uncertainty.data.dataset import (
    POSITION_KINDS,
    Dataset,
    PlaceholderPositionsWarning,
    detect_position_kind,
)
from vpr_uncertainty.data.folder import MalformedImageNameError, load_folder_dataset, parse_image_name
from vpr_uncertainty.data.formats import DATASET_FORMAT_REGISTRY, DatasetFormat, register_format
from vpr_uncertainty.data.geo import latlon_to_utm
from vpr_uncertainty.data.ground_truth import (
    load_ground_truth,
    positives_from_lists,
    positives_from_mask,
    positives_to_lists,
)
from vpr_uncertainty.data.named_datasets import (
    DATA_ROOT_VARIABLE,
    NAMED_DATASETS,
    NamedDataset,
    data_root,
    detect_format,
    find_named_dataset,
    get_named_dataset,
    load_dataset,
)
from vpr_uncertainty.data.poses import load_poses_dataset
from vpr_uncertainty.data.positives import DEFAULT_RADIUS, positives_within_frames, positives_within_radius
from vpr_uncertainty.data.table import load_table_dataset
from vpr_uncertainty.data.vprbench import load_vprbench_dataset

__all__ = [
    "DATASET_FORMAT_REGISTRY",
    "DATA_ROOT_VARIABLE",
    "DEFAULT_RADIUS",
    "NAMED_DATASETS",
    "POSITION_KINDS",
    "Dataset",
    "DatasetFormat",
    "MalformedImageNameError",
    "NamedDataset",
    "PlaceholderPositionsWarning",
    "data_root",
    "detect_format",
    "detect_position_kind",
    "find_named_dataset",
    "get_named_dataset",
    "latlon_to_utm",
    "load_dataset",
    "load_folder_dataset",
    "load_ground_truth",
    "load_poses_dataset",
    "load_table_dataset",
    "load_vprbench_dataset",
    "parse_image_name",
    "positives_from_lists",
    "positives_from_mask",
    "positives_to_lists",
    "positives_within_frames",
    "positives_within_radius",
    "register_format",
]
