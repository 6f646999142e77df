"""An :class:`~vpr_uncertainty.evaluation.results.Evaluation` as a table: a pandas DataFrame and a compact text.

pandas is an optional dependency (the ``pandas`` extra, also in ``all``): the core install stays small for the
robots and SLAM pipelines that only gate answers, and a notebook has pandas already. It is imported only when
:func:`evaluation_frame` is called; without it the ImportError says what to install.

Columns of the frame (one row per method, indexed by the method's name, in the order evaluated), named as in
``results.json``:

* ``auc_pr``, ``average_precision`` (None/NaN when every answer is correct, or none is), ``aurc`` (lower is better),
  ``recall_at_100_precision``, ``time_per_query_ms``, ``informative`` (False: every query has the same uncertainty),
  ``tied_share``;
* ``precision_at_recall_<level>`` for each recall level evaluated (``precision_at_recall_0.5``);
* with a bootstrap: ``auc_pr_ci_low``, ``auc_pr_ci_high``, ``average_precision_ci_low``/``_high``,
  ``aurc_ci_low``/``_high`` (95 % percentile intervals), and ``delta_auc_pr``, ``p_value_holm``, ``significant``
  against the reference method;
* for a method that retrieves with its own embeddings: ``own_recall@1``;
* the optional time figures it measured (``latency_ms_batch1``, ``time_per_query_ms_cold``/``_warm``) and the
  numbers it reported about its run (a cascade's ``verified_fraction``, ``verified_queries``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    import pandas

    from vpr_uncertainty.evaluation.results import Evaluation, MethodEvaluation

__all__ = ["evaluation_frame", "evaluation_summary", "method_row", "method_summary"]

_INTERVALS = ("auc_pr", "average_precision", "aurc")
_VS_REFERENCE = ("delta_auc_pr", "p_value_holm", "significant")


def _import_pandas() -> Any:
    try:
        import pandas
    except ImportError as error:
        raise ImportError(
            "Evaluation.to_frame() needs pandas, which the core install leaves out: "
            "pip install 'vpr-uncertainty[pandas]' (or pip install pandas)"
        ) from error
    return pandas


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


def evaluation_frame(evaluation: Evaluation) -> pandas.DataFrame:
    """One row per method, indexed by its name (see the module docstring for the columns).

    Parameters
    ----------
    evaluation : Evaluation
        The result of :func:`vpr_uncertainty.evaluate`.

    Returns
    -------
    pandas.DataFrame
        The frame's ``attrs`` hold ``n_queries``, ``n_answerable``, ``k`` and the recall@N of the retrieval.

    Raises
    ------
    ImportError
        When pandas is not installed (it names the extra to install).
    """
    pandas = _import_pandas()
    rows = [method_row(method) for method in evaluation.methods.values()]
    columns: dict[str, None] = {}
    for row in rows:
        columns.update(dict.fromkeys(row))
    frame = pandas.DataFrame(rows, index=pandas.Index(list(evaluation.methods), name="method"), columns=list(columns))
    floats = [name for name in columns if name not in ("informative", "significant")]
    frame[floats] = frame[floats].astype(float)  # None (an undefined AUC-PR) becomes NaN, not an object column
    frame.attrs.update(
        n_queries=evaluation.n_queries,
        n_answerable=evaluation.n_answerable,
        k=evaluation.k,
        **{f"recall@{n}": value for n, value in evaluation.recall_at_n.items()},
    )
    return frame


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
    recalls = ", ".join(f"recall@{n}={value:.3f}" for n, value in evaluation.recall_at_n.items())
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
