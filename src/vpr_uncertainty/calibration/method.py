"""The uncertainty method ``CAL``: 1 − P(correct top-1) of a fitted :class:`~vpr_uncertainty.calibration.Gate`.

CAL needs a gate: option ``gate`` (a gate file written by ``vpr-uncertainty calibrate``, or a :class:`Gate`), e.g.
``--methods SU,CAL:gate=gate.json``. The held-out evaluation (``evaluate --calibration-fraction``) fits one gate
per split on the calibration queries and hands it to CAL for the held-out ones.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import numpy as np

from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.methods import register_method
from vpr_uncertainty.retrieval import Retrieval

__all__ = ["cal_uncertainty", "resolve_gate"]


def resolve_gate(retrieval: Retrieval, options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` with ``gate`` read from its file (the method's ``resolve`` hook)."""
    resolved = dict(options)
    value = resolved.get("gate")
    if value in (None, ""):
        resolved["gate"] = None
    elif isinstance(value, (str, os.PathLike)):
        resolved["gate"] = Gate.load(value)
    elif not isinstance(value, Gate):
        raise TypeError(f"option gate must be the path of a gate file or a Gate, got {type(value).__name__}")
    return resolved


def cal_uncertainty(retrieval: Retrieval, *, gate: Gate | None = None) -> np.ndarray:
    """1 − P(correct top-1) for every query, shape (Q,): higher = less trustworthy."""
    if gate is None:
        raise ValueError(
            "uncertainty method 'CAL' needs a fitted gate (option gate=GATE.json, written by "
            "`vpr-uncertainty calibrate`), or a held-out evaluation that fits one per split"
        )
    return 1.0 - gate.probability_correct(retrieval.scores)


register_method(
    "CAL",
    cal_uncertainty,
    description="1 − calibrated P(correct) of a fitted gate (calibrate; fitted per split in held-out evaluate)",
    requires=("gate",),
    options={"gate": ""},
    kind="calibrated",
    resolve=resolve_gate,
)
