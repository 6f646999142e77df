"""Datasets and their ground truth; the readers of what a user brings live in :mod:`vpr_uncertainty.formats` (their
public names are importable from here too)."""

from vpr_uncertainty.data.dataset import Dataset, PlaceholderPositionsWarning, latlon_to_utm
from vpr_uncertainty.data.formats import (
    DATASET_FORMAT_REGISTRY,
    DatasetFormat,
    detect_format,
    load_poses_dataset,
    load_table_dataset,
    load_vprbench_dataset,
    register_format,
)
from vpr_uncertainty.data.images import MalformedImageNameError, load_folder_dataset, parse_image_name
from vpr_uncertainty.data.named_datasets import (
    DATA_ROOT_VARIABLE,
    NAMED_DATASET_REGISTRY,
    NamedDataset,
    data_root,
    find_named_dataset,
    get_named_dataset,
    load_dataset,
)
from vpr_uncertainty.formats import (
    DEFAULT_TOP_K,
    RESULTS_FORMAT_REGISTRY,
    ResultsFormat,
    input_formats,
    read_pool,
    read_results,
    register_results_format,
)
from vpr_uncertainty.formats.ground_truth import (
    load_ground_truth,
    positives_from_lists,
    positives_from_mask,
    positives_to_lists,
)
from vpr_uncertainty.formats.matrix import (
    load_descriptors,
    load_similarity_matrix,
    open_descriptors,
    read_similarity_top_k,
)
from vpr_uncertainty.retrieval.ground_truth import (
    DEFAULT_RADIUS,
    POSITION_KINDS,
    attach_ground_truth,
    detect_position_kind,
    ground_truth_fields,
    positives_within_frames,
    positives_within_radius,
)

__all__ = [
    "DATASET_FORMAT_REGISTRY",
    "DATA_ROOT_VARIABLE",
    "DEFAULT_RADIUS",
    "DEFAULT_TOP_K",
    "NAMED_DATASET_REGISTRY",
    "POSITION_KINDS",
    "RESULTS_FORMAT_REGISTRY",
    "Dataset",
    "DatasetFormat",
    "MalformedImageNameError",
    "NamedDataset",
    "PlaceholderPositionsWarning",
    "ResultsFormat",
    "attach_ground_truth",
    "data_root",
    "detect_format",
    "detect_position_kind",
    "find_named_dataset",
    "get_named_dataset",
    "ground_truth_fields",
    "input_formats",
    "latlon_to_utm",
    "load_dataset",
    "load_descriptors",
    "load_folder_dataset",
    "load_ground_truth",
    "load_poses_dataset",
    "load_similarity_matrix",
    "load_table_dataset",
    "load_vprbench_dataset",
    "open_descriptors",
    "parse_image_name",
    "positives_from_lists",
    "positives_from_mask",
    "positives_to_lists",
    "positives_within_frames",
    "positives_within_radius",
    "read_pool",
    "read_results",
    "read_similarity_top_k",
    "register_format",
    "register_results_format",
]
