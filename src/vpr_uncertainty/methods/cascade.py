"""Cascades ``SCORE+GV`` (e.g. ``SU+GV-SIFT``): cheap doubt first, geometric verification only on the
``verify_fraction`` of the queries the score method doubts most. Why this combination, and what its time per query
counts: see docs/explanation/uncertainty-scores.md.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from vpr_uncertainty._validation import check_fraction
from vpr_uncertainty.methods.entries import (
    METHODS,
    DetailedUncertainty,
    OwnRetrievalUncertainty,
    UncertaintyMethod,
    register_composer,
)
from vpr_uncertainty.retrieval import Retrieval

DEFAULT_VERIFY_FRACTION = 0.3
_GEOMETRIC = "geometric"


def most_uncertain(uncertainty: np.ndarray, fraction: float) -> np.ndarray:
    """Indices of the ``round(fraction · Q)`` most uncertain queries (ties broken by query order), ascending.

    Examples
    --------
    >>> most_uncertain(np.array([0.1, 0.9, 0.5, 0.9]), 0.5)
    array([1, 3])
    """
    uncertainty = np.asarray(uncertainty, dtype=np.float64)
    count = round(check_fraction(fraction, "verify_fraction") * uncertainty.size)
    order = np.argsort(-uncertainty, kind="stable")
    return np.sort(order[:count])


def combine_cascade(score_uncertainty: np.ndarray, verified: np.ndarray, gv_uncertainty: np.ndarray) -> np.ndarray:
    """One uncertainty from the score method's (all queries) and geometric verification's (the verified ones).

    Parameters
    ----------
    score_uncertainty : ndarray of shape (Q,)
        The score method's uncertainties.
    verified : ndarray of int, shape (V,)
        The verified queries.
    gv_uncertainty : ndarray of shape (V,)
        Geometric verification's uncertainties (−inliers) of the verified queries, in the order of ``verified``.

    Returns
    -------
    ndarray of shape (Q,), float64
        Unverified queries: their score uncertainty; verified ones: ``max(unverified) + 1 + (gv − min gv)``, so
        every verified query ranks as less trustworthy than every unverified one, in the order of ``gv``.

    Examples
    --------
    >>> combine_cascade(np.array([0.2, 0.9, 0.5]), np.array([1]), np.array([-40.0]))
    array([0.2, 1.5, 0.5])
    """
    combined = np.asarray(score_uncertainty, dtype=np.float64).copy()
    verified = np.asarray(verified, dtype=np.int64)
    gv = np.asarray(gv_uncertainty, dtype=np.float64)
    if gv.shape != verified.shape:
        raise ValueError(f"gv_uncertainty has shape {gv.shape}, expected one value per verified query {verified.shape}")
    if not verified.size:
        return combined
    unverified = np.ones(combined.size, dtype=bool)
    unverified[verified] = False
    top = float(combined[unverified].max()) if unverified.any() else 0.0
    combined[verified] = top + 1.0 + (gv - gv.min())
    return combined


def run_cascade(
    retrieval: Retrieval,
    *,
    score: UncertaintyMethod,
    gv: UncertaintyMethod,
    verify_fraction: float = DEFAULT_VERIFY_FRACTION,
    **options: Any,
) -> DetailedUncertainty:
    """The cascade ``score+gv`` on ``retrieval`` (docs/explanation/uncertainty-scores.md); ``options`` go to both.

    Returns
    -------
    DetailedUncertainty
        The combined uncertainties, with ``details`` ``verified_fraction`` (verified queries / Q) and
        ``verified_queries``.
    """
    fraction = check_fraction(verify_fraction, "verify_fraction")
    score_result = score(retrieval, **options)
    if isinstance(score_result, (OwnRetrievalUncertainty, DetailedUncertainty)):
        raise ValueError(f"cascade {score.name}+{gv.name}: {score.name} does not give one uncertainty per query")
    score_uncertainty = np.asarray(score_result, dtype=np.float64)
    verified = most_uncertain(score_uncertainty, fraction)
    gv_uncertainty = np.zeros(0)
    if verified.size:
        sub_options = dict(options)
        if sub_options.get("query_paths") is not None:
            paths = list(sub_options["query_paths"])
            sub_options["query_paths"] = [paths[row] for row in verified]
        gv_result = gv(retrieval.subset_queries(verified), **sub_options)
        gv_uncertainty = np.asarray(getattr(gv_result, "uncertainty", gv_result), dtype=np.float64)
    combined = combine_cascade(score_uncertainty, verified, gv_uncertainty)
    n_queries = max(retrieval.n_queries, 1)
    details = {"verified_fraction": verified.size / n_queries, "verified_queries": int(verified.size)}
    return DetailedUncertainty(uncertainty=combined, details=details)


def split_cascade_name(name: str) -> tuple[str, str] | None:
    """``("SU", "GV-SIFT")`` for ``"SU+GV-SIFT"``; None for a name without ``+``."""
    if "+" not in name:
        return None
    first, _, second = (part.strip() for part in name.partition("+"))
    if not first or not second or "+" in second:
        raise ValueError(f"a cascade is named SCORE+GV (e.g. SU+GV-SIFT), got {name!r}")
    return first, second


def cascade_entry(name: str) -> UncertaintyMethod:
    """The entry of the cascade ``name`` (``"SCORE+GV"``): any non-geometric method, then a ``GV-*`` method.

    Its options are ``verify_fraction`` and those of both methods (given to both; each takes its own).

    Examples
    --------
    >>> cascade_entry("SU+GV-SIFT").option_defaults()["verify_fraction"]
    0.3
    """
    parts = split_cascade_name(name)
    if parts is None:
        raise ValueError(f"{name!r} is not a cascade (SCORE+GV, e.g. SU+GV-SIFT)")
    score, gv = METHODS.get(parts[0]), METHODS.get(parts[1])
    if score.kind == _GEOMETRIC or gv.kind != _GEOMETRIC:
        geometric = ", ".join(METHODS.names(kind=_GEOMETRIC))
        raise ValueError(
            f"cascade {name!r}: expected a score method before '+' and a geometric-verification method after it "
            f"({geometric}), got {score.name} ({score.kind}) and {gv.name} ({gv.kind})"
        )

    def cascade(retrieval: Retrieval, **options: Any) -> DetailedUncertainty:
        return run_cascade(retrieval, score=score, gv=gv, **options)

    def resolve(retrieval: Retrieval, options: dict[str, Any]) -> dict[str, Any]:
        return gv.resolve_inputs(retrieval, score.resolve_inputs(retrieval, options))

    defaults = {**score.option_defaults(), **gv.option_defaults(), "verify_fraction": DEFAULT_VERIFY_FRACTION}
    return dataclasses.replace(
        gv,
        name=f"{score.name}+{gv.name}",
        description=f"{score.name}, then {gv.name} on the verify_fraction most uncertain queries (cascade)",
        target=cascade,
        requires=tuple(dict.fromkeys((*score.requires, *gv.requires))),
        extra=gv.extra or score.extra,
        options=defaults,
        validate=lambda **given: check_fraction(
            given.get("verify_fraction", DEFAULT_VERIFY_FRACTION), "verify_fraction"
        ),
        kind="cascade",
        default=False,
        resolve=resolve,
        bound={},
        base=None,
        reads=(),
    )


register_composer("+", cascade_entry)
