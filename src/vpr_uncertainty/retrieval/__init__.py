"""Retrieval results: the top-k database images of every query, how they are searched, stored and read.

Modules
    :mod:`~vpr_uncertainty.retrieval.result`        the :class:`Retrieval` type (its checks in ``_checks``);
    :mod:`~vpr_uncertainty.retrieval.file_format`   the retrieval file (``.npz``, format version 1):
                                                     :func:`save_retrieval`, :func:`load_retrieval`;
    :mod:`~vpr_uncertainty.retrieval.search`        descriptor search with Faiss: :func:`search_descriptors`,
                                                     :func:`retrieve` (the Faiss binding in ``_faiss``);
    :mod:`~vpr_uncertainty.retrieval.readers`       what a user brings: :func:`read_results` (retrieval files,
                                                     similarity matrices, VPR-Bench), :func:`top_k_from_similarity`,
                                                     :func:`read_similarity_top_k` (a matrix file, memory-mapped,
                                                     block by block), :func:`load_descriptors`;
    :mod:`~vpr_uncertainty.retrieval.descriptor_rows` descriptor files read lazily, block by block:
                                                     :func:`open_descriptors`, :class:`DescriptorRows`.

Ground truth, names and positions are attached to a search result by
:func:`vpr_uncertainty.data.attach.attach_ground_truth`.
"""

from vpr_uncertainty.data.dataset import POSITION_KINDS
from vpr_uncertainty.retrieval._faiss import faiss_gpu_available
from vpr_uncertainty.retrieval.descriptor_rows import DescriptorRows, open_descriptors
from vpr_uncertainty.retrieval.file_format import FORMAT_VERSION, load_retrieval, save_retrieval
from vpr_uncertainty.retrieval.readers import (
    INPUT_FORMATS,
    MATRIX_TOP_K,
    load_descriptors,
    load_similarity_matrix,
    read_results,
    read_similarity_top_k,
    top_k_from_similarity,
)
from vpr_uncertainty.retrieval.result import Retrieval
from vpr_uncertainty.retrieval.search import retrieve, search_descriptors

__all__ = [
    "FORMAT_VERSION",
    "INPUT_FORMATS",
    "MATRIX_TOP_K",
    "POSITION_KINDS",
    "DescriptorRows",
    "Retrieval",
    "faiss_gpu_available",
    "load_descriptors",
    "load_retrieval",
    "load_similarity_matrix",
    "open_descriptors",
    "read_results",
    "read_similarity_top_k",
    "retrieve",
    "save_retrieval",
    "search_descriptors",
    "top_k_from_similarity",
]
