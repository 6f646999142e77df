"""The Faiss binding of the descriptor search: importing Faiss, detecting GPUs, and building and querying an index.

:class:`Searcher` answers ``search(queries, k) -> (scores, indices)`` with Faiss's raw output (unordered ties,
``-1`` for missing candidates); :mod:`vpr_uncertainty.retrieval.search` orders, pads and settles ties on top of
it. Faiss is imported only when a search runs, with an ImportError that names the package to install.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["GPU_MAX_K", "Searcher", "faiss_gpu_available", "import_faiss"]

#: Largest k that GPU Faiss can return.
GPU_MAX_K = 2048


def faiss_gpu_available() -> bool:
    """Whether the installed Faiss has GPU support and sees at least one GPU."""
    try:
        faiss = import_faiss()
    except ImportError:
        return False
    return hasattr(faiss, "StandardGpuResources") and faiss.get_num_gpus() > 0


def import_faiss() -> Any:
    try:
        import faiss
    except ImportError as error:
        raise ImportError(
            "descriptor retrieval needs Faiss; install it with: pip install faiss-cpu (or faiss-gpu to search on a "
            "CUDA device)"
        ) from error
    return faiss


class Searcher:
    """``search(queries, k) -> (scores, indices)`` over one database, exact or through a Faiss index."""

    def __init__(
        self,
        database: np.ndarray,
        index: str,
        device: str,
        search_params: str | None,
        faiss: Any,
        *,
        progress: bool | None = None,
    ) -> None:
        self.database = database
        self.faiss = faiss
        self.max_k = GPU_MAX_K if device == "cuda" else None
        self.index = None
        self._resources = None
        exact = index.replace(" ", "").lower() == "flat"
        if device == "cpu" and exact:
            if search_params:
                raise ValueError(f"search_params {search_params!r} need an approximate index; exact search has none")
            return  # faiss.knn_inner_product on the array itself: no copy of the database into an index
        if device == "cuda":
            if not hasattr(faiss, "StandardGpuResources") or faiss.get_num_gpus() < 1:
                if hasattr(faiss, "StandardGpuResources"):
                    reason = "has GPU support but sees no GPU"
                else:
                    reason = "is built without GPU support"
                raise ValueError(
                    f"device='cuda' needs GPU Faiss and a visible GPU, but this Faiss ({faiss.__version__}) {reason}; "
                    "install faiss-gpu and check CUDA_VISIBLE_DEVICES, or use device='cpu'"
                )
        dimension = database.shape[1]
        try:
            built = faiss.index_factory(dimension, index, faiss.METRIC_INNER_PRODUCT)
        except RuntimeError as error:
            raise ValueError(f"invalid Faiss index-factory string {index!r}: {faiss_message(error)}") from None
        if device == "cuda":
            self._resources = faiss.StandardGpuResources()
            try:
                built = faiss.index_cpu_to_gpu(self._resources, 0, built)
            except RuntimeError as error:
                raise ValueError(f"Faiss index {index!r} cannot run on the GPU: {faiss_message(error)}") from None
        from vpr_uncertainty.progress import progress_status

        try:
            if not built.is_trained:  # IVF/PQ training can take minutes: say so while it runs
                with progress_status(f"train Faiss {index} on {len(database):,} vectors", enabled=progress):
                    built.train(database)
            built.add(database)
        except RuntimeError as error:
            raise ValueError(f"cannot build the Faiss index {index!r}: {faiss_message(error)}") from None
        if search_params:
            space = faiss.GpuParameterSpace() if device == "cuda" else faiss.ParameterSpace()
            try:
                space.set_index_parameters(built, search_params)
            except RuntimeError as error:
                raise ValueError(
                    f"invalid search_params {search_params!r} for index {index!r}: {faiss_message(error)}"
                ) from None
        self.index = built

    def search(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        scores = np.empty((len(queries), k), dtype=np.float32)
        indices = np.empty((len(queries), k), dtype=np.int64)
        if len(queries) == 0:
            return scores, indices
        faiss = self.faiss
        if self.index is None:
            faiss.knn_inner_product(
                faiss.swig_ptr(queries),
                faiss.swig_ptr(self.database),
                self.database.shape[1],
                len(queries),
                len(self.database),
                k,
                faiss.swig_ptr(scores),
                faiss.swig_ptr(indices),
            )
        else:
            self.index.search(queries, k, D=scores, I=indices)
        return scores, indices


def faiss_message(error: BaseException) -> str:
    """The useful last part of a Faiss C++ error message."""
    text = str(error).strip()
    return text.rsplit(": ", 1)[-1] if ": " in text else text
