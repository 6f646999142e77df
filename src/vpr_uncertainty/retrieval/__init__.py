"""Retrieval results: the top-k database images of every query, their file, and the search that finds them."""

from vpr_uncertainty.retrieval.blocks import DescriptorRows, top_k_from_similarity
from vpr_uncertainty.retrieval.result import (
    FORMAT_VERSION,
    Retrieval,
    load_retrieval,
    positives_from_lists,
    positives_from_mask,
    save_retrieval,
)
from vpr_uncertainty.retrieval.search import faiss_gpu_available, retrieve, search_descriptors

__all__ = [
    "FORMAT_VERSION",
    "DescriptorRows",
    "Retrieval",
    "faiss_gpu_available",
    "load_retrieval",
    "positives_from_lists",
    "positives_from_mask",
    "retrieve",
    "save_retrieval",
    "search_descriptors",
    "top_k_from_similarity",
]
