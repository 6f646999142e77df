"""Dataset and ground-truth readers."""

from vpr_uncertainty.data.ground_truth import (
    load_ground_truth,
    positives_from_lists,
    positives_from_mask,
    positives_to_lists,
)

__all__ = ["load_ground_truth", "positives_from_lists", "positives_from_mask", "positives_to_lists"]
