"""The held-out calibration option of a grid: ``calibration = {fraction = 0.3, repeats = 20, seed = 0}``.

With the option, every cell is also evaluated on held-out queries: each of ``repeats`` random splits (seeded by
``seed``, stratified by correctness) fits ``CAL`` on a share ``fraction`` of the queries, and every uncertainty
method, CAL included, is measured on the same remaining queries
(:func:`vpr_uncertainty.calibration.quality.evaluate_held_out`). The cell stores each method's mean and standard
deviation over the splits (``held_out`` in ``results.json``); Table 1 shows the means, and the ``reliability``
report figure CAL's calibration quality. The evaluation on all queries (PR curves, heatmaps, ablations, qualitative
figures) is unchanged; a bare ``CAL`` (no ``gate=`` file) is left out of it, since it has a gate only per split.

Without the option nothing changes: no ``held_out`` entry, the same cell fingerprints and the same Table 1.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

from vpr_uncertainty.methods import get_method

if TYPE_CHECKING:
    from vpr_uncertainty.retrieval import Retrieval
    from vpr_uncertainty.study.config import GridConfig

__all__ = [
    "CALIBRATION_DEFAULTS",
    "calibration_option",
    "fitted_per_split",
    "full_query_methods",
    "held_out_evaluation",
    "runs_cal",
]

#: The keys of the ``calibration`` table, with their defaults.
CALIBRATION_DEFAULTS: dict[str, Any] = {"fraction": 0.3, "repeats": 20, "seed": 0}
_EXAMPLE = "calibration = {fraction = 0.3, repeats = 20, seed = 0}"


def fitted_per_split(spec: str) -> bool:
    """Whether ``spec`` is CAL without a gate file: a gate exists only for the splits of a held-out evaluation.

    Examples
    --------
    >>> fitted_per_split("CAL"), fitted_per_split("CAL:gate=gate.json"), fitted_per_split("SU")
    (True, False, False)
    """
    entry = get_method(spec)
    return (entry.base or entry.name) == "CAL" and not entry.bound.get("gate")


def runs_cal(methods: list[str]) -> bool:
    """Whether ``methods`` holds CAL (with or without a gate file)."""
    return any((get_method(spec).base or get_method(spec).name) == "CAL" for spec in methods)


def full_query_methods(methods: list[str], calibration: dict[str, Any] | None) -> list[str]:
    """The methods evaluated on all queries: ``methods`` less CAL without a gate file when the option is set."""
    if calibration is None:
        return list(methods)
    return [spec for spec in methods if not fitted_per_split(spec)]


def _number(table: dict, key: str, problems: list[str]) -> Any:
    value = table.get(key, CALIBRATION_DEFAULTS[key])
    if key == "fraction":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value < 1.0:
            problems.append(f"calibration.fraction must be a number strictly between 0 and 1, got {value!r}")
            return None
        return float(value)
    low = 1 if key == "repeats" else 0
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        problems.append(f"calibration.{key} must be an integer >= {low}, got {value!r}")
        return None
    return int(value)


def calibration_option(raw: Any, methods: list[str], problems: list[str]) -> dict[str, Any] | None:
    """The checked ``calibration`` table ``{fraction, repeats, seed}`` (missing keys take their defaults), or None.

    Problems (appended to ``problems``): not a table, unknown keys, values of the wrong type or range, no method
    left for the evaluation on all queries, methods the held-out splits cannot serve (a trained BTL head).

    Examples
    --------
    >>> calibration_option({"fraction": 0.5}, ["SU", "CAL"], [])
    {'fraction': 0.5, 'repeats': 20, 'seed': 0}
    >>> problems = []
    >>> calibration_option({"fraction": 1.5, "repeat": 3}, ["SU"], problems)
    >>> problems[0]
    "calibration: unknown key 'repeat' (expected fraction, repeats, seed)"
    """
    if raw is None:
        return None
    if not isinstance(raw, dict):
        problems.append(f"calibration must be a table such as {_EXAMPLE}, got {raw!r}")
        return None
    count = len(problems)
    problems += [
        f"calibration: unknown key {key!r} (expected {', '.join(CALIBRATION_DEFAULTS)})"
        for key in raw
        if key not in CALIBRATION_DEFAULTS
    ]
    option = {key: _number(raw, key, problems) for key in CALIBRATION_DEFAULTS}
    try:
        entries = [get_method(spec) for spec in methods]  # already checked by the caller; unknown ones skipped
    except (KeyError, ValueError, TypeError, ImportError):
        entries = []
    if entries and not full_query_methods(methods, option):
        problems.append("calibration: methods holds only CAL; add a method to evaluate on all queries (e.g. SU)")
    problems += [
        f"calibration: {entry.name} is not supported by the held-out evaluation (it needs "
        f"{' and '.join(entry.requires)}, which the splits do not pass on); remove it or the calibration table"
        for entry in entries
        if entry.kind == "learned"
    ]
    return option if len(problems) == count else None


def held_out_evaluation(retrieval: Retrieval, config: GridConfig, **options: Any) -> dict[str, Any]:
    """Every method of the grid on the held-out queries of the grid's splits, as JSON types.

    Parameters
    ----------
    retrieval : Retrieval
        The cell's retrieval, with its ground truth.
    config : GridConfig
        Holds ``calibration`` (fraction, repeats, seed), ``methods``, ``k`` and ``alpha``.
    **options
        Further inputs of the methods (the image paths and the local-feature cache of the cell).

    Returns
    -------
    dict
        :meth:`~vpr_uncertainty.calibration.quality.HeldOutEvaluation.to_dict`. When the splits are impossible
        (fewer than 2 correct or 2 wrong answers), every method's ``auc_pr`` is None and ``notes`` says why.
    """
    from vpr_uncertainty.calibration.quality import evaluate_held_out

    option = config.calibration
    if option is None:
        raise ValueError("the grid has no calibration option (calibration = {fraction, repeats, seed})")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the first split's notes are kept in the result
            result = evaluate_held_out(
                retrieval,
                config.methods,
                calibration_fraction=option["fraction"],
                repeats=option["repeats"],
                seed=option["seed"],
                k=config.k,
                alpha=config.alpha,
                **options,
            )
    except ValueError as error:
        if "at least 2 correct and 2 wrong" not in str(error):
            raise
        empty = {"auc_pr": None, "auc_pr_std": None, "average_precision": None, "aurc": None}
        return {
            "n_queries": retrieval.n_queries,
            "calibration": dict(option),
            "methods": {get_method(spec).name: dict(empty) for spec in config.methods},
            "notes": [f"no held-out evaluation: {error}"],
        }
    return result.to_dict()
