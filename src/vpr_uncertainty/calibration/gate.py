"""The gate: P(correct top-1) and an accept/reject decision, for many queries or one at a time, saved as JSON.

A :class:`Gate` is made by :func:`vpr_uncertainty.calibrate` (or read back with :meth:`Gate.load`). It holds two
maps of the features: the calibrator, which gives P(correct), and the rule, a linear confidence (the certified
ranking: the margin, −SU, the fitted model, …; without a certificate the calibrator's own order) that it accepts
at or above the cut. ``gate(row)`` decides one query in pure Python, with everything it needs folded into a few
precomputed numbers: a couple of microseconds, like :class:`~vpr_uncertainty.StatisticalUncertainty`.

The JSON file holds numbers only (no pickle): the calibrator and the rule (features, scaling, coefficients), k,
the cut and the threshold, the certificate, the toolkit version, the calibration set's size and a fingerprint of
its scores and labels; and a ``digest``, SHA-256 of each field (``cut``, ``calibrator.coef``, ``rule.coef``, …, each
named by its path, one name per field), by which :meth:`Gate.load` refuses and names a field edited, added or written
twice (against edits, not forgery). The gate refuses a row unlike its calibration rows: other than k scores, or fewer
of them finite (not ``-inf``) than any calibration row held.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty._validation import check_k, check_top_k_scores
from vpr_uncertainty.cache import write_text
from vpr_uncertainty.calibration.calibrator import (
    FEATURES,
    RANKINGS,
    Calibrator,
    aliasing_ratio,
    feature_matrix,
    ranking_rule,
    row_features,
)
from vpr_uncertainty.scores import one_row, row_statistics

__all__ = ["FORMAT", "Gate"]

#: The ``format`` field of a gate file.
FORMAT = "vpr-uncertainty gate"
_FORMAT_VERSION = 3  # 2: the digest; 3: the rule apart from the calibrator
_FIX = "; write the gate again with `vpr-uncertainty calibrate`"


class Gate:
    """Calibrated P(correct top-1) and an acceptance rule with (optionally) a certified precision.

    Parameters
    ----------
    calibrator : Calibrator
        The fitted map from features to P(correct).
    k : int
        Candidates per query the features read.
    cut : float
        Accept a query when the rule's confidence is ≥ ``cut``; ``inf`` accepts none.
    info : dict, optional
        What :func:`~vpr_uncertainty.calibrate` recorded: ``target_precision``, ``delta``,
        ``precision_lower_bound``, ``expected_recall``, ``expected_coverage``, ``certificate``, ``calibration``
        (size, fingerprint, seed, ``min_candidates``: the fewest finite scores of a calibration row, default k)
        and ``toolkit_version``.
    rule : Calibrator, optional
        A linear map whose confidence the gate cuts (default: the calibrator's order; −SU for an isotonic one).

    Attributes
    ----------
    threshold : float or None
        P(correct) at the cut when the rule is the calibrator's own confidence, so that the gate accepts P ≥
        threshold (1.0 when it accepts nothing); None when the rule is another ranking.
    precision_lower_bound : float or None
        The certified lower bound of the precision of accepted answers (None without a target or certificate).
    expected_recall : float or None
        Share of answerable test queries accepted and correct at the cut (None without a target).
    """

    __slots__ = (
        "_bias",
        "_cut",
        "_k",
        "_least",
        "_w_aliasing",
        "_w_best",
        "_w_median",
        "_w_nonpositive",
        "_w_ratio",
        "_w_runners",
        "_w_second",
        "_w_spread",
        "calibrator",
        "cut",
        "info",
        "k",
        "rule",
    )

    def __init__(
        self,
        calibrator: Calibrator,
        k: int,
        cut: float,
        info: dict[str, Any] | None = None,
        rule: Calibrator | None = None,
    ) -> None:
        rule = rule or (ranking_rule("SU") if getattr(calibrator, "model", None) == "isotonic" else calibrator)
        for name, value in (("calibrator", calibrator), ("rule", rule)):
            if not isinstance(value, Calibrator):
                raise TypeError(f"{name} must be a Calibrator, got {type(value).__name__}")
        if rule.model != "logistic":
            raise ValueError("the rule must be a linear (logistic) map of the features")
        self.calibrator, self.rule = calibrator, rule
        self.k = check_k(k)
        cut = float(cut)
        if math.isnan(cut):
            raise ValueError("cut must be a number or inf, got nan")
        self.cut = cut
        self.info = dict(info or {})
        least = (self.info.get("calibration") or {}).get("min_candidates", self.k)
        if isinstance(least, bool) or not isinstance(least, int) or not 2 <= least <= self.k:
            raise ValueError(f"calibration.min_candidates must be an integer in [2, k={self.k}], got {least!r}")
        self._least = least
        self._prepare()

    # --- the one-query fast path --------------------------------------------------------------------------------

    def _prepare(self) -> None:
        """Fold the rule's features, scaling and coefficients into the weights of the row statistics."""
        self._k, self._cut = self.k, self.cut
        bias, raw = self.rule.raw_weights()
        w = dict.fromkeys(FEATURES, 0.0)
        # plain floats: numpy scalars make every operation of the one-query path slower
        w.update(zip(self.rule.features, (float(value) for value in raw), strict=True))
        self._bias = float(bias)
        self._w_aliasing = w["PA"]
        self._w_best = w["s1"] + w["gap"]
        self._w_second = -w["gap"]
        self._w_spread = w["zscore"]
        # Ratio features divided by s_1: s_2 (ratio), mean of the runners-up (RS, ½ of SU), median (SD, ½ of SU).
        self._w_runners = w["RS"] + 0.5 * w["SU"]
        self._w_median = w["SD"] + 0.5 * w["SU"]
        self._w_nonpositive = w["ratio"] + w["RS"] + w["SD"] + w["SU"]
        self._w_ratio = w["ratio"]

    def __call__(self, scores: Sequence[float] | np.ndarray) -> bool:
        """Accept one query? ``scores``: its top-K similarities, sorted descending (a list, a (K,) or (1, K) array).

        A malformed row (not numbers, NaN or ±inf at the top, unsorted, overflowing, another shape, other than k
        scores, fewer finite ones than the calibration rows held) raises, as :meth:`accept` does: a robot that
        catches the error rejects the query.
        """
        return self._confidence_of(one_row(scores, shapes="(K,) or (1, K)")) >= self._cut

    def _confidence_of(self, values: list[float]) -> float:
        if len(values) != self._k:
            self._refuse(f"a row of {len(values)} scores")
        best, second, runners, median, last, n = row_statistics(values, self._k)
        if n < self._least:
            self._refuse(f"a row of {n} finite scores", finite=True)
        if best > 0:
            ratios = (self._w_ratio * second + self._w_runners * runners + self._w_median * median) / best
        else:
            ratios = self._w_nonpositive * (1.0 - best)
        z = self._bias + self._w_best * best + self._w_second * second + ratios
        if self._w_spread:
            spread = best - last
            z += self._w_spread * ((best - runners) / spread if spread > 0 else 0.0)
        if self._w_aliasing:
            z += self._w_aliasing * aliasing_ratio(best, second)
        if not -math.inf < z < math.inf:  # huge scores: each feature on its own (ratios before sums), as in batch
            z = self._confidence_by_features(values, self.rule)
        return z

    def _confidence_by_features(self, values: list[float], calibrator: Calibrator) -> float:
        """``calibrator``'s confidence from :func:`row_features` and the raw weights: slower, but overflows only
        where the features themselves do (the same numbers as the batch path)."""
        features = row_features(values, k=self._k, features=calibrator.features)
        if calibrator.model == "isotonic":
            z = -features[0]
        else:
            bias, weights = calibrator.raw_weights()
            z = bias + sum(weight * value for weight, value in zip(weights, features, strict=True))
        if not -math.inf < z < math.inf:
            raise ValueError(f"scores are too large: the gate's confidence overflows float64 ({values})")
        return z

    def probability_one(self, scores: Sequence[float] | np.ndarray) -> float:
        """P(correct) of one query (same input as ``gate(scores)``)."""
        values = one_row(scores, shapes="(K,) or (1, K)")
        self._confidence_of(values)  # the same refusals as gate(row)
        confidence = self._confidence_by_features(values, self.calibrator)
        return float(self.calibrator.probability_from_confidence(np.array([confidence]))[0])

    def _refuse(self, got: str, *, finite: bool = False) -> None:
        """Raise: the gate's guarantee covers the top k scores, at least ``min_candidates`` of them finite."""
        k = self._k
        need = f"rows of at least {self._least} finite scores" if finite else f"each query's top {k} scores"
        hint = " (as calibrated)" if finite else f" (scores[:, :{k}] of a longer retrieval)"
        raise ValueError(f"the gate was calibrated at k={k}: its guarantee covers {need}{hint}, got {got}")

    # --- many queries -------------------------------------------------------------------------------------------

    def confidence(self, scores: object, *, of: str = "calibrator") -> np.ndarray:
        """The confidence of shape (Q,) (higher = more likely correct) of the calibrator (``of="calibrator"``) or
        of the rule (``of="rule"``), from scores of shape (Q, k)."""
        calibrator = self.rule if of == "rule" else self.calibrator
        scores = check_top_k_scores(scores)
        if scores.shape[1] != self.k:
            self._refuse(f"scores of shape {scores.shape}")
        short = np.flatnonzero(np.isfinite(scores).sum(axis=1) < self._least)
        if short.size:
            self._refuse(f"fewer in {short.size} scores rows ({short[:10].tolist()} first)", finite=True)
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is checked below
            confidence = calibrator.confidence(feature_matrix(scores, k=self.k, features=calibrator.features))
        if not np.isfinite(confidence).all():
            row = int(np.flatnonzero(~np.isfinite(confidence))[0])
            raise ValueError(f"scores row {row} is too large: the gate's confidence overflows float64")
        return confidence

    def probability_correct(self, scores: object) -> np.ndarray:
        """P(correct top-1) of shape (Q,), in [0, 1], from top-K similarities of shape (Q, K) sorted descending."""
        if self.rule is not self.calibrator:  # the rows the rule refuses (it may read other features) have no P
            self.confidence(scores, of="rule")
        return self.calibrator.probability_from_confidence(self.confidence(scores))

    def accept(self, scores: object) -> np.ndarray:
        """Whether each query is accepted, shape (Q,), bool."""
        return self.confidence(scores, of="rule") >= self.cut

    # --- what calibrate recorded --------------------------------------------------------------------------------

    @property
    def threshold(self) -> float | None:
        if math.isinf(self.cut):
            return 1.0 if self.cut > 0 else 0.0
        same = self.rule == (ranking_rule("SU") if self.calibrator.model == "isotonic" else self.calibrator)
        return float(self.calibrator.probability_from_confidence(np.array([self.cut]))[0]) if same else None

    @property
    def acceptance(self) -> str:
        """The rule in the user's terms: an uncertainty and the direction it accepts (``accept when SU <= 0.9203``:
        higher = more doubt), a similarity (BM: the top-1 score, the margin s1 - s2) or P(correct) (a fitted rule's
        own model's at the cut, named when it is not the calibrator)."""
        if math.isinf(self.cut):
            return "accept nothing" if self.cut > 0 else "accept every query"
        if (name := self.rule.ranking) in RANKINGS and self.rule == ranking_rule(name):  # exact: isotonic P has steps
            sign = RANKINGS[name][1]
            return f"accept when {name} {'<=' if sign < 0 else '>='} {sign * self.cut + 0.0:.4g}"
        by = "" if self.threshold is not None else f" by the {name or 'rule'} model"
        return f"accept when P(correct) >= {self.rule.probability_from_confidence(np.array([self.cut]))[0]:.4g}{by}"

    @property
    def precision_lower_bound(self) -> float | None:
        return self.info.get("precision_lower_bound")

    @property
    def expected_recall(self) -> float | None:
        return self.info.get("expected_recall")

    @property
    def expected_coverage(self) -> float | None:
        return self.info.get("expected_coverage")

    def __repr__(self) -> str:
        bound = self.precision_lower_bound
        return (
            f"Gate(model={self.calibrator.model!r}, features={list(self.calibrator.features)}, k={self.k}, "
            f"rule={self.acceptance!r}, precision_lower_bound={None if bound is None else round(bound, 4)})"
        )

    # --- JSON -----------------------------------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The gate as JSON types (the content of :meth:`save`), with its ``digest``."""
        data = {
            "format": FORMAT,
            "format_version": _FORMAT_VERSION,
            "k": self.k,
            "cut": None if math.isinf(self.cut) else self.cut,
            "threshold": self.threshold,
            "calibrator": self.calibrator.to_dict(),
            "rule": self.rule.to_dict(),
            **{key: value for key, value in self.info.items() if key not in {"k", "cut", "threshold", "digest"}},
        }
        data = json.loads(json.dumps(data))  # as load reads it back (lists, string keys): the digest is of that
        data["digest"] = _digest(data)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, where: str = "gate") -> Gate:
        """The inverse of :meth:`to_dict`; a ValueError names the field that is malformed or was edited (by its
        digest). A dict without a digest is refused: build a gate in Python with ``Gate(calibrator, k, cut)``."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise ValueError(f'{where}: not a gate file (expected "format": "{FORMAT}")')
        version, digest = data.get("format_version"), data.get("digest")
        if version != _FORMAT_VERSION or not isinstance(digest, dict):
            problem = "no digest" if version == _FORMAT_VERSION else f"format_version {version!r}"
            raise ValueError(
                f"{where}: {problem} (this toolkit reads gate files of format_version {_FORMAT_VERSION}, with a digest)"
                f"{_FIX}"
            )
        found = _digest(data)
        edited = ", ".join(
            sorted(_shown(name) for name in found.keys() | digest if found.get(name) != digest.get(name))
        )
        edited = f"{edited} changed since calibrate (the digest differs)" if edited else ""
        try:
            k, cut = check_k(data.get("k")), data.get("cut")
            if cut is not None and (not isinstance(cut, (int, float)) or not math.isfinite(cut)):
                raise ValueError(f"cut must be a finite number or null (accept nothing), got {cut!r}")
            calibrator = Calibrator.from_dict(data.get("calibrator"))
            rule = Calibrator.from_dict(data.get("rule"), where="rule")
            info = {k: v for k, v in data.items() if k not in {"format", "format_version", "calibrator", "rule"}}
            gate = cls(calibrator, k, math.inf if cut is None else float(cut), info, rule)
        # with the edited fields, which may be the cause (k edited: then min_candidates > k)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{where}: {error}{f'; {edited}' if edited else ''}{_FIX}") from None
        if edited:
            raise ValueError(f"{where}: {edited}{_FIX}")
        return gate

    def save(self, path: str | os.PathLike) -> Path:
        """Write the gate as JSON (atomically: a temporary file, then a rename) and return the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        return write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> Gate:
        """Read a gate written by :meth:`save`."""
        path = Path(path)
        if not is_regular_file(path, "a gate file"):
            raise FileNotFoundError(f"gate file not found: {path} (write one with `vpr-uncertainty calibrate`)")
        try:
            data = json.loads(path.read_text(), object_pairs_hook=_unique)
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise ValueError(f"{path}: not a JSON gate file: {error}") from None
        except ValueError as error:  # a repeated field
            raise ValueError(f"{path}: {error}{_FIX}") from None
        return cls.from_dict(data, where=str(path))


def _digest(data: dict[str, Any]) -> dict[str, str]:
    """SHA-256 (16 hex digits) of the canonical JSON of each field but ``digest``, an object's fields one by one,
    each named by its path (``cut``, ``rule.coef``): a ``~`` or ``.`` within a key is written ``~0`` or ``~1`` (as
    in a JSON pointer), so that no two fields share a name (a top-level ``"rule.coef"`` is ``rule~1coef``)."""
    fields: dict[str, Any] = {}
    for key, value in data.items():
        if key != "digest":
            nested = isinstance(value, dict) and value
            fields.update({_name(key, name): item for name, item in value.items()} if nested else {_name(key): value})
    return {
        name: hashlib.sha256(json.dumps(value, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:16]
        for name, value in sorted(fields.items())
    }


def _name(*keys: object) -> str:
    return ".".join(str(key).replace("~", "~0").replace(".", "~1") for key in keys)


def _shown(name: str) -> str:
    """A digest name as the user reads it: a key holding ``.`` or ``~`` in quotes (``"rule.coef"``, top level)."""
    parts = (part.replace("~1", ".").replace("~0", "~") for part in str(name).split("."))
    return ".".join(json.dumps(part) if "." in part or "~" in part else part for part in parts)


def _unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object's fields as a dict; a ValueError names a field written twice (JSON would keep the last)."""
    data = dict(pairs)
    if len(data) < len(pairs):
        repeated = next(key for index, (key, _) in enumerate(pairs) if key in dict(pairs[:index]))
        raise ValueError(f'field "{repeated}" is written twice')
    return data
