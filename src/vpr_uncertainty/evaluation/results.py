"""What :func:`vpr_uncertainty.evaluate` returns (:class:`Evaluation`, a :class:`MethodEvaluation` per method), as
JSON numbers (``to_dict``/``from_dict``; the arrays are stored beside them), a pandas table and a compact text."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from vpr_uncertainty.evaluation.metrics import RejectionCurve, answerable_queries, rank_queries
from vpr_uncertainty.plugins import import_or_explain

if TYPE_CHECKING:  # pragma: no cover
    import pandas


#: Optional time figures of a method (see :func:`vpr_uncertainty.evaluate`), in ms.
TIMING_KEYS = ("latency_ms_batch1", "time_per_query_ms_cold", "time_per_query_ms_warm")
#: Numbers a method reports about its own run (:class:`~vpr_uncertainty.methods.DetailedUncertainty`), written
#: beside its metrics and read back by :meth:`MethodEvaluation.from_dict`.
DETAIL_KEYS: tuple[str, ...] = ("verified_fraction", "verified_queries", "trained_on_queries", "training_unverified")
_NEEDS_PANDAS = "{} needs pandas, which the core install leaves out: pip install 'vpr-uncertainty[pandas]'"
#: The metrics with a bootstrap interval (``<metric>_ci``).
_INTERVALS = ("auc_pr", "average_precision", "aurc")


@dataclass(repr=False)
class MethodEvaluation:
    """Everything measured for one uncertainty method.

    ``correct`` is set only for a method that retrieves with its own embeddings: its own top-1 correctness, the
    labels its metrics were measured against (otherwise those of :attr:`Evaluation.correct`). ``details`` holds
    what the method reported about its run (a cascade's ``verified_fraction`` and ``verified_queries``). Its
    ``repr`` shows the numbers, not the arrays. ``n_distinct`` and ``tied_share`` are counted once, when it is built
    (:func:`~vpr_uncertainty.evaluate` gives them from its one sort of the uncertainties).
    """

    name: str
    uncertainty: np.ndarray
    auc_pr: float | None
    average_precision: float | None
    aurc: float
    time_per_query_ms: float
    curve: RejectionCurve
    recall_at_full_precision: float
    precision_at_recall: dict[float, float | None]
    own_recall_at_1: float | None = None
    correct: np.ndarray | None = None
    auc_pr_ci: tuple[float, float] | None = None
    average_precision_ci: tuple[float, float] | None = None
    aurc_ci: tuple[float, float] | None = None
    vs_reference: dict[str, Any] | None = None
    #: Time figures beside ``time_per_query_ms`` (:data:`TIMING_KEYS`), written as keys of :meth:`to_dict`.
    timings: dict[str, float] = field(default_factory=dict)
    #: Numbers the method reported about its own run (:data:`DETAIL_KEYS`), written as keys of :meth:`to_dict`.
    details: dict[str, Any] = field(default_factory=dict)

    #: Number of distinct uncertainty values (1: every query tied); counted from ``uncertainty`` when not given.
    n_distinct: int | None = None
    #: Share of the queries whose uncertainty equals that of at least one other query (0: no ties); counted from
    #: ``uncertainty`` when not given.
    tied_share: float | None = None

    def __post_init__(self) -> None:
        if self.n_distinct is None or self.tied_share is None:
            _, counts = np.unique(self.uncertainty, return_counts=True)
            if self.n_distinct is None:
                self.n_distinct = int(counts.size)
            if self.tied_share is None:
                size = np.size(self.uncertainty)
                self.tied_share = float(counts[counts > 1].sum() / size) if size else 0.0

    def __repr__(self) -> str:
        return method_summary(self)

    @property
    def informative(self) -> bool:
        """False when every query has the same uncertainty: the ranking is arbitrary, AUC-PR and AP at chance."""
        return self.n_distinct > 1

    @property
    def trained_on_queries(self) -> int:
        """How many of the evaluated queries the method was trained on (0: none, or a training-free method)."""
        return int(self.details.get("trained_on_queries") or 0)

    @property
    def never_best(self) -> bool:
        """Trained on these queries, or unable to say it was not (a BTL head that records no anchors): never starred."""
        return bool(self.trained_on_queries or self.details.get("training_unverified"))

    def to_dict(self) -> dict[str, Any]:
        """The numbers of this method as JSON types (the uncertainties and the curve are left out)."""
        return {
            "informative": self.informative,
            "distinct_values": self.n_distinct,
            "tied_share": self.tied_share,
            "auc_pr": self.auc_pr,
            "average_precision": self.average_precision,
            "aurc": self.aurc,
            "time_per_query_ms": self.time_per_query_ms,
            **{key: self.timings[key] for key in TIMING_KEYS if key in self.timings},
            "recall_at_100_precision": self.recall_at_full_precision,
            "precision_at_recall": {f"{level:g}": value for level, value in self.precision_at_recall.items()},
            **(
                {"correctness_from": "own retrieval", "own_recall@1": self.own_recall_at_1}
                if self.own_recall_at_1 is not None
                else {}
            ),
            **{
                f"{metric}_ci": list(getattr(self, f"{metric}_ci"))
                for metric in _INTERVALS
                if getattr(self, f"{metric}_ci") is not None
            },
            **({"vs_reference": dict(self.vs_reference)} if self.vs_reference is not None else {}),
            **self.details,
        }

    @classmethod
    def from_dict(
        cls,
        name: str,
        data: Mapping[str, Any],
        *,
        uncertainty: np.ndarray,
        correct: np.ndarray,
        n_answerable: int,
        own_correct: np.ndarray | None = None,
    ) -> MethodEvaluation:
        """The inverse of :meth:`to_dict`, given the arrays it leaves out (see :meth:`Evaluation.from_dict`).

        ``correct`` is the evaluation's top-1 correctness, shape (Q,); ``own_correct`` the method's own labels when it
        retrieves with its own embeddings; ``n_answerable`` the recall denominator of the rejection curve.
        """
        uncertainty = np.asarray(uncertainty)
        labels = correct if own_correct is None else np.asarray(own_correct, dtype=bool)
        ranking = rank_queries(labels, uncertainty)  # one sort: the curve and the ties
        return cls(
            name=name,
            uncertainty=uncertainty,
            auc_pr=data["auc_pr"],
            average_precision=data["average_precision"],
            aurc=data["aurc"],
            time_per_query_ms=data["time_per_query_ms"],
            curve=ranking.rejection_curve(n_answerable=n_answerable),
            recall_at_full_precision=data["recall_at_100_precision"],
            precision_at_recall={float(level): value for level, value in data["precision_at_recall"].items()},
            own_recall_at_1=data.get("own_recall@1"),
            correct=None if own_correct is None else labels,
            **{f"{metric}_ci": _interval(data.get(f"{metric}_ci")) for metric in _INTERVALS},
            vs_reference=dict(data["vs_reference"]) if data.get("vs_reference") is not None else None,
            timings={key: data[key] for key in TIMING_KEYS if data.get(key) is not None},
            details={key: data[key] for key in DETAIL_KEYS if key in data},
            n_distinct=ranking.n_distinct,
            tied_share=ranking.tied_share,
        )


def _interval(value: Any) -> tuple[float, float] | None:
    return None if value is None else (float(value[0]), float(value[1]))


@dataclass(repr=False)
class Evaluation:
    """Result of :func:`vpr_uncertainty.evaluate`: retrieval quality and one :class:`MethodEvaluation` per method.

    ``repr`` is a compact summary (one line per method); :meth:`to_frame` gives a pandas DataFrame and
    :meth:`to_dict` the JSON document of ``evaluate --json``.
    """

    n_queries: int
    n_answerable: int
    correct: np.ndarray
    recall_at_n: dict[int, float | None]
    methods: dict[str, MethodEvaluation] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    k: int | None = None
    k_requested: int | None = None
    bootstrap: dict[str, Any] | None = None
    #: The retrieval evaluated (set by :func:`~vpr_uncertainty.evaluate`, None when read back): the names and scores
    #: of :meth:`per_query_columns`.
    retrieval: Any = field(default=None, compare=False)

    def __repr__(self) -> str:
        return evaluation_summary(self)

    def per_query_columns(self, retrieval: Any = None) -> dict[str, np.ndarray]:
        """One row per query, as columns of shape (Q,) (no pandas needed): ``query_index``, ``query``,
        ``top1_index``, ``top1`` (names; empty where the retrieval has none), ``answerable``, ``correct`` (0/1),
        ``s_1`` ... ``s_k`` (the k scores the methods used), then each method's uncertainty under its name, in the
        order evaluated. ``retrieval``: the one evaluated, for an evaluation read back (:meth:`from_dict`).
        """
        retrieval = self.retrieval if retrieval is None else retrieval
        if retrieval is None or retrieval.n_queries != self.n_queries:
            raise ValueError(
                f"the per-query table needs the retrieval of these {self.n_queries} queries (argument retrieval)"
            )
        top1, names = retrieval.indices[:, 0], retrieval.database_names
        columns = {
            "query_index": np.arange(self.n_queries),
            "query": np.full(self.n_queries, "") if retrieval.query_names is None else retrieval.query_names,
            "top1_index": top1,
            "top1": np.full(self.n_queries, "") if names is None else np.append(names, "")[top1],  # -1: none
            "answerable": answerable_queries(retrieval.positives).astype(np.int8),
            "correct": self.correct.astype(np.int8),
        }
        scores = retrieval.scores[:, : self.k or retrieval.k]
        columns.update({f"s_{rank + 1}": scores[:, rank] for rank in range(scores.shape[1])})
        return {**columns, **{name: method.uncertainty for name, method in self.methods.items()}}

    def per_query_frame(self, retrieval: Any = None) -> pandas.DataFrame:
        """:meth:`per_query_columns` as a DataFrame (the table of ``evaluate --per-query``); needs pandas."""
        pandas = import_or_explain("pandas", _NEEDS_PANDAS.format("Evaluation.per_query_frame()"))
        return pandas.DataFrame(self.per_query_columns(retrieval))

    def to_frame(self) -> pandas.DataFrame:
        """One row per method, indexed by its name, in the order evaluated; needs pandas (the ``pandas`` extra).

        Columns, named as in ``results.json``: ``auc_pr``, ``average_precision`` (NaN when every answer is correct,
        or none is), ``aurc`` (lower is better), ``recall_at_100_precision``, ``time_per_query_ms``,
        ``informative``, ``tied_share``, ``precision_at_recall_<level>``; with a bootstrap
        ``<metric>_ci_low``/``_high`` and ``delta_auc_pr``, ``p_value_holm``, ``significant``; ``own_recall@1`` for a
        method with its own retrieval; and the method's optional timings and details (a cascade's
        ``verified_fraction``). The frame's ``attrs`` hold ``n_queries``, ``n_answerable``, ``k`` and the recall@N.

        Examples
        --------
        >>> import numpy as np
        >>> from vpr_uncertainty import Retrieval, evaluate
        >>> retrieval = Retrieval(scores=np.array([[0.9, 0.2], [0.6, 0.5], [0.8, 0.1]]),
        ...                       indices=np.array([[0, 1], [0, 1], [1, 0]]), positives=[[0], [1], [1]])
        >>> frame = evaluate(retrieval, ["SU", "BM"], k=2).to_frame()
        >>> list(frame.index), frame.loc["SU", ["auc_pr", "aurc"]].round(3).tolist()
        (['SU', 'BM'], [1.0, 0.111])
        """
        pandas = import_or_explain("pandas", _NEEDS_PANDAS.format("Evaluation.to_frame()"))
        rows = [method_row(method) for method in self.methods.values()]
        columns = list(dict.fromkeys(key for row in rows for key in row))
        frame = pandas.DataFrame(rows, index=pandas.Index(list(self.methods), name="method"), columns=columns)
        floats = [name for name in columns if name not in ("informative", "significant")]
        frame[floats] = frame[floats].astype(float)  # None (an undefined AUC-PR) becomes NaN, not an object column
        frame.attrs.update(
            n_queries=self.n_queries,
            n_answerable=self.n_answerable,
            k=self.k,
            **{f"recall@{n}": value for n, value in self.recall_at_n.items()},
        )
        return frame

    def to_dict(self) -> dict[str, Any]:
        """The JSON schema of ``evaluate --json``."""
        return {
            "n_queries": self.n_queries,
            **({"k": self.k} if self.k is not None else {}),
            **({"k_requested": self.k_requested} if self.k_requested not in (None, self.k) else {}),
            "recall@1": self.recall_at_n.get(1),
            **{f"recall@{n}": value for n, value in self.recall_at_n.items() if n != 1},
            "n_queries_without_positives": self.n_queries - self.n_answerable,
            "methods": {name: method.to_dict() for name, method in self.methods.items()},
            **({"bootstrap": dict(self.bootstrap)} if self.bootstrap is not None else {}),
            **({"notes": list(self.notes)} if self.notes else {}),
        }

    @classmethod
    def from_dict(
        cls,
        data: Mapping[str, Any],
        *,
        correct: np.ndarray,
        uncertainties: Mapping[str, np.ndarray],
        own_correct: Mapping[str, np.ndarray] | None = None,
    ) -> Evaluation:
        """The inverse of :meth:`to_dict`, given the arrays it leaves out.

        Parameters
        ----------
        data : mapping
            What :meth:`to_dict` returned (extra keys are ignored).
        correct : ndarray of shape (Q,), bool
            Whether each query's top-1 answer is correct.
        uncertainties : mapping of str to ndarray of shape (Q,)
            Every method's uncertainties, by the names of ``data["methods"]``.
        own_correct : mapping of str to ndarray of shape (Q,), optional
            The own correctness labels of the methods that retrieve with their own embeddings.

        Raises
        ------
        ValueError
            When ``correct`` does not have ``data["n_queries"]`` entries or a method's uncertainties are missing.
        """
        correct = np.asarray(correct).astype(bool)
        n_queries = int(data["n_queries"])
        if correct.shape != (n_queries,):
            raise ValueError(f"correct must have shape ({n_queries},) as n_queries says, got {correct.shape}")
        missing = [name for name in data["methods"] if name not in uncertainties]
        if missing:
            raise ValueError(f"uncertainties of {', '.join(missing)} are missing")
        n_answerable = n_queries - int(data["n_queries_without_positives"])
        own_correct = own_correct or {}
        methods = {
            name: MethodEvaluation.from_dict(
                name,
                metrics,
                uncertainty=uncertainties[name],
                correct=correct,
                n_answerable=n_answerable,
                own_correct=own_correct.get(name),
            )
            for name, metrics in data["methods"].items()
        }
        recalls = {
            int(key[len("recall@") :]): value
            for key, value in data.items()
            if key.startswith("recall@") and (value is not None or key != "recall@1")  # None: N > the candidates
        }
        return cls(
            n_queries=n_queries,
            n_answerable=n_answerable,
            correct=correct,
            recall_at_n=recalls,
            methods=methods,
            notes=list(data.get("notes", [])),
            k=data.get("k"),
            k_requested=data.get("k_requested", data.get("k")),
            bootstrap=dict(data["bootstrap"]) if data.get("bootstrap") is not None else None,
        )


_VS_REFERENCE = ("delta_auc_pr", "p_value_holm", "significant")


def method_row(method: MethodEvaluation) -> dict[str, Any]:
    """The numbers of one method as a flat dict (the columns of :func:`evaluation_frame`)."""
    row: dict[str, Any] = {
        "auc_pr": method.auc_pr,
        "average_precision": method.average_precision,
        "aurc": method.aurc,
        "recall_at_100_precision": method.recall_at_full_precision,
        "time_per_query_ms": method.time_per_query_ms,
        "informative": method.informative,
        "tied_share": method.tied_share,
    }
    row.update({f"precision_at_recall_{level:g}": value for level, value in method.precision_at_recall.items()})
    for metric in _INTERVALS:
        interval = getattr(method, f"{metric}_ci")
        if interval is not None:
            row[f"{metric}_ci_low"], row[f"{metric}_ci_high"] = interval
    if method.vs_reference is not None:
        row.update({key: method.vs_reference.get(key) for key in _VS_REFERENCE})
    if method.own_recall_at_1 is not None:
        row["own_recall@1"] = method.own_recall_at_1
    row.update(method.timings)
    row.update(method.details)
    return row


def _number(value: float | None, digits: int = 4) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def method_summary(method: MethodEvaluation) -> str:
    """``MethodEvaluation('SU', auc_pr=0.8277, ..., n_queries=111)``: the numbers, not the arrays."""
    parts = [
        f"auc_pr={_number(method.auc_pr)}",
        f"average_precision={_number(method.average_precision)}",
        f"aurc={_number(method.aurc)}",
        f"recall_at_100_precision={_number(method.recall_at_full_precision, 3)}",
        f"time_per_query_ms={method.time_per_query_ms:.3g}",
    ]
    if method.auc_pr_ci is not None:
        parts.append(f"auc_pr_ci=({method.auc_pr_ci[0]:.3f}, {method.auc_pr_ci[1]:.3f})")
    if not method.informative:
        parts.append("informative=False")
    parts.append(f"n_queries={method.uncertainty.size}")
    return f"MethodEvaluation({method.name!r}, {', '.join(parts)})"


def evaluation_summary(evaluation: Evaluation) -> str:
    """A few lines: the retrieval's size and recall@N, then one line per method (AUC-PR, AP, AURC, R@100%P, ms)."""
    recalls = ", ".join(f"recall@{n}={_number(value, 3)}" for n, value in evaluation.recall_at_n.items())
    head = f"Evaluation(n_queries={evaluation.n_queries}, n_answerable={evaluation.n_answerable}, k={evaluation.k}"
    lines = [f"{head}{', ' + recalls if recalls else ''}, methods=["]
    width = max((len(name) for name in evaluation.methods), default=0)
    for name, method in evaluation.methods.items():
        interval = "" if method.auc_pr_ci is None else f" [{method.auc_pr_ci[0]:.3f}, {method.auc_pr_ci[1]:.3f}]"
        lines.append(
            f"  {name:<{width}}  AUC-PR {_number(method.auc_pr)}{interval}  AP {_number(method.average_precision)}  "
            f"AURC {_number(method.aurc)}  R@100%P {_number(method.recall_at_full_precision, 3)}  "
            f"{method.time_per_query_ms:.3g} ms/query{'' if method.informative else '  (uninformative)'}"
        )
    count = len(evaluation.notes)
    notes = f", {count} note{'s' if count > 1 else ''} (.notes)" if count else ""
    lines.append(f"]{notes})")
    return "\n".join(lines)
