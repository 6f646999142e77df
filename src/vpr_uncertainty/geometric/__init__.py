"""Geometric verification: local features, matching and RANSAC turned into inlier counts (uncertainty = −inliers),
hloc-layout feature caches, re-ranking by inliers, and the GV-* methods (registered on import). OpenCV, torch and
kornia (extras ``opencv`` and ``gv``) load when a method first runs."""

from vpr_uncertainty.geometric.cache import extract_features, image_names, read_features, write_features
from vpr_uncertainty.geometric.local_features import (
    DEFAULT_MAX_SIDE,
    Extractor,
    LocalFeatures,
    NearestNeighborMatcher,
    count_inliers,
    load_image,
    match_nearest_neighbors,
)
from vpr_uncertainty.geometric.methods import (
    gv_disk_lightglue,
    gv_h5,
    gv_sift,
    gv_superpoint_lightglue,
    gv_superpoint_superglue,
    gv_xfeat,
)
from vpr_uncertainty.geometric.verify import (
    GV_PRESETS,
    GeometricVerifier,
    GVPreset,
    Reranking,
    VerificationResult,
    preset_names,
    register_preset,
    rerank,
    rerank_by_inliers,
    verify_retrieval,
)

__all__ = [
    "DEFAULT_MAX_SIDE",
    "GV_PRESETS",
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
    "preset_names",
    "read_features",
    "register_preset",
    "rerank",
    "rerank_by_inliers",
    "verify_retrieval",
    "write_features",
]
