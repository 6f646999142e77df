"""Stage 3, uncertainties and their evaluation: a retrieval → ``uncertainties.npz`` and an :class:`Evaluation`.

``uncertainties.npz`` holds one (Q,) array per uncertainty method (higher = less trustworthy), ``correct`` (Q,)
bool, and ``fingerprint``: the :func:`~vpr_uncertainty.cache.fingerprint` of the methods and options and of the
retrieval's fingerprint, so the file says what produced it. The evaluation measures the time per query of each
method, so it always runs (the slow inputs, local features for geometric verification, have their own cache).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty import cache

__all__ = ["UncertaintyConfig", "UncertaintyResult", "evaluate"]

STAGE = "uncertainty"


@dataclass(frozen=True)
class UncertaintyConfig:
    """Which uncertainties :func:`evaluate` computes.

    Attributes
    ----------
    methods : sequence of str
        Uncertainty methods (names with optional options, as :func:`vpr_uncertainty.evaluation.evaluate` takes).
    k, alpha : int, float
        Options of RS, SD and SU.
    options : mapping
        Further method options (e.g. ``btl_head``).
    bootstrap, seed, reference : int, int, str or None
        Paired bootstrap of the evaluation (0 resamples: none); see :func:`vpr_uncertainty.evaluate`.
    """

    methods: Sequence[str]
    k: int = 10
    alpha: float = 0.5
    options: Mapping[str, Any] = field(default_factory=dict)
    bootstrap: int = 0
    seed: int = 0
    reference: str | None = None


@dataclass
class UncertaintyResult:
    """What :func:`evaluate` produced: the file and the evaluation in memory."""

    path: Path
    evaluation: Any
    fingerprint: str


def evaluate(
    conf: UncertaintyConfig,
    retrieval: Any,
    path: str | Path,
    *,
    inputs: Mapping[str, Any] | None = None,
    retrieval_fingerprint: str | None = None,
) -> UncertaintyResult:
    """Every uncertainty of ``conf`` on ``retrieval``, evaluated, with the uncertainties written to ``path``.

    Parameters
    ----------
    conf : UncertaintyConfig
    retrieval : Retrieval
        With its ground truth.
    path : str or Path
        ``uncertainties.npz``.
    inputs : mapping, optional
        What image-based methods need (``query_paths``, ``database_paths``, descriptors, ``cache_dir``,
        ``device``) and where geometric verification runs (``executor``); not part of the fingerprint (the
        retrieval's fingerprint covers their content, and every executor gives the same results).
    retrieval_fingerprint : str, optional
        The fingerprint of the retrieval file.

    Returns
    -------
    UncertaintyResult
    """
    from vpr_uncertainty.evaluation import evaluate as evaluate_methods

    path = Path(path)
    options = {**dict(inputs or {}), **dict(conf.options)}
    evaluation = evaluate_methods(
        retrieval,
        list(conf.methods),
        k=conf.k,
        alpha=conf.alpha,
        bootstrap=conf.bootstrap,
        seed=conf.seed,
        reference=conf.reference,
        **options,
    )
    described = {"methods": list(conf.methods), "k": conf.k, "alpha": conf.alpha, "options": dict(conf.options)}
    fingerprint = cache.fingerprint(STAGE, described, {"retrieval": retrieval_fingerprint})
    arrays = {name: method.uncertainty for name, method in evaluation.methods.items()}
    with cache.atomic_write(path, "wb") as handle:
        np.savez_compressed(handle, correct=evaluation.correct, fingerprint=np.array(fingerprint), **arrays)
    return UncertaintyResult(path=path, evaluation=evaluation, fingerprint=fingerprint)
