"""The typed result of one grid cell (one VPR method on one dataset) and its dictionary form.

:meth:`Cell.to_dict` is the cell's entry in ``results.json``; :meth:`Cell.arrays` holds what the JSON leaves out
(correctness, uncertainties, top-k scores and indices, hits); :meth:`Cell.from_dict` rebuilds the cell from both.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from vpr_uncertainty.evaluation import Evaluation

__all__ = ["CSV_FIELDS", "Cell"]

CSV_FIELDS = (
    "vpr_method",
    "dataset",
    "uncertainty_method",
    "auc_pr",
    "average_precision",
    "aurc",
    "time_per_query_ms",
    "recall_at_100_precision",
    "n_queries",
)
_UNCERTAINTY = "uncertainty/"
_OWN_CORRECT = "correct/"


def _float_key(value: float) -> str:
    """``f"{value:g}"`` (the key format of ``results.json``), or the exact ``repr`` when ``:g`` would round."""
    text = f"{value:g}"
    return text if float(text) == value else repr(float(value))


@dataclass
class Cell:
    """Everything the reports need from one (VPR method, dataset) cell.

    Attributes
    ----------
    vpr_method, dataset : str
        The cell's row and column.
    evaluation : Evaluation
        Every uncertainty method's numbers and uncertainties.
    scores, indices : ndarray of shape (Q, K)
        The retrieval's top-K similarities (float32) and database indices.
    ablation_alpha : dict of float to float or None
        AUC-PR of SU for each α (None when undefined).
    ablation_k : dict of str to dict of int to float or None
        AUC-PR of RS and SD for each k.
    hits : ndarray of shape (Q, H), bool, optional
        Whether each of the first H candidates is a positive.
    query_paths, database_paths : list of str, optional
        The images, when the cell has them.
    held_out : dict, optional
        The held-out evaluation of the grid's ``calibration`` option (every method's mean and std over the splits,
        CAL's calibration quality; :func:`vpr_uncertainty.study.heldout.held_out_evaluation`); None without it.
    cached : bool
        Whether the cell was read from the cache.
    stage_seconds : dict of str to float, optional
        Seconds of each stage of the run that computed the cell (``input``: reading the results file, or the
        pipeline with its own stages as ``pipeline_<stage>``; ``uncertainty_and_evaluation``; ``ablations``).
    """

    vpr_method: str
    dataset: str
    evaluation: Evaluation
    scores: np.ndarray
    indices: np.ndarray
    ablation_alpha: dict[float, float | None]
    ablation_k: dict[str, dict[int, float | None]]
    hits: np.ndarray | None = None
    query_paths: list[str] | None = None
    database_paths: list[str] | None = None
    held_out: dict[str, Any] | None = None
    cached: bool = False
    stage_seconds: dict[str, float] | None = None

    def uncertainties(self) -> dict[str, np.ndarray]:
        """Each uncertainty method's stored uncertainties, shape (Q,), by method name."""
        return {name: method.uncertainty for name, method in self.evaluation.methods.items()}

    def rows(self) -> list[dict[str, Any]]:
        """Long-format rows (the fields of ``results.csv``), one per uncertainty method."""
        recalls = {f"recall@{n}": value for n, value in self.evaluation.recall_at_n.items()}
        rows = []
        for name, method in self.evaluation.methods.items():
            metrics = method.to_dict()
            rows.append(
                {
                    "vpr_method": self.vpr_method,
                    "dataset": self.dataset,
                    "uncertainty_method": name,
                    **{key: metrics.get(key) for key in CSV_FIELDS[3:-1]},
                    "n_queries": self.evaluation.n_queries,
                    **recalls,
                }
            )
        return rows

    def to_dict(self) -> dict[str, Any]:
        """The cell's entry in ``results.json``: its names, ``Evaluation.to_dict()``, the ablations and, with the
        grid's calibration option, ``held_out``."""
        return {
            "vpr_method": self.vpr_method,
            "dataset": self.dataset,
            **self.evaluation.to_dict(),
            "ablation_alpha": {_float_key(a): v for a, v in self.ablation_alpha.items()},
            "ablation_k": {name: {str(k): v for k, v in c.items()} for name, c in self.ablation_k.items()},
            **({"held_out": self.held_out} if self.held_out is not None else {}),
            **({"stage_seconds": dict(self.stage_seconds)} if self.stage_seconds is not None else {}),
        }

    def arrays(self) -> dict[str, np.ndarray]:
        """What :meth:`to_dict` leaves out, by name (``uncertainty/NAME`` per method; ``correct/NAME`` for a
        method judged by its own retrieval)."""
        arrays = {"correct": self.evaluation.correct, "scores": self.scores, "indices": self.indices}
        if self.hits is not None:
            arrays["hits"] = self.hits
        for name, method in self.evaluation.methods.items():
            arrays[_UNCERTAINTY + name] = method.uncertainty
            if method.correct is not None:
                arrays[_OWN_CORRECT + name] = method.correct
        return arrays

    @classmethod
    def from_dict(
        cls,
        data: Mapping[str, Any],
        arrays: Mapping[str, np.ndarray],
        *,
        query_paths: list[str] | None = None,
        database_paths: list[str] | None = None,
        cached: bool = False,
    ) -> Cell:
        """The inverse of :meth:`to_dict` and :meth:`arrays`.

        Parameters
        ----------
        data : mapping
            What :meth:`to_dict` returned.
        arrays : mapping of str to ndarray
            What :meth:`arrays` returned.
        query_paths, database_paths : list of str, optional
            The cell's images.
        cached : bool, default=False
            Whether the cell comes from the cache.

        Returns
        -------
        Cell

        Raises
        ------
        KeyError
            When ``data`` or ``arrays`` lacks an entry.
        """
        evaluation = Evaluation.from_dict(
            data,
            correct=arrays["correct"],
            uncertainties={k[len(_UNCERTAINTY) :]: v for k, v in arrays.items() if k.startswith(_UNCERTAINTY)},
            own_correct={k[len(_OWN_CORRECT) :]: v for k, v in arrays.items() if k.startswith(_OWN_CORRECT)},
        )
        return cls(
            vpr_method=data["vpr_method"],
            dataset=data["dataset"],
            evaluation=evaluation,
            scores=arrays["scores"],
            indices=arrays["indices"],
            hits=arrays.get("hits"),
            ablation_alpha={float(a): v for a, v in data["ablation_alpha"].items()},
            ablation_k={name: {int(k): v for k, v in c.items()} for name, c in data["ablation_k"].items()},
            query_paths=query_paths,
            database_paths=database_paths,
            held_out=data.get("held_out"),
            cached=cached,
            stage_seconds=data.get("stage_seconds"),
        )
