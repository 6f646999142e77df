""":func:`evaluate`: run each uncertainty method on a retrieval, time it (throughput, batch-1 latency, cold and warm
geometric verification), measure it, and note where the input bends a convention."""

from __future__ import annotations

import functools
import statistics
import tempfile
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.evaluation.bootstrap import add_bootstrap, check_bootstrap, resolve_reference
from vpr_uncertainty.evaluation.metrics import (
    RECALL_NS,
    FewerCandidatesWarning,
    answerable_queries,
    candidate_hits,
    check_recall_ns,
    correct_at_n,
    first_positive_rank,
    positives_against_mean,
    precision_at_recall,
    rank_queries,
    recall_at_full_precision,
    recall_at_n,
    recall_candidates_note,
)
from vpr_uncertainty.evaluation.results import Evaluation, MethodEvaluation
from vpr_uncertainty.methods import (
    DetailedUncertainty,
    OwnRetrievalUncertainty,
    UncertaintyMethod,
    check_options,
    default_method_names,
    get_method,
)
from vpr_uncertainty.retrieval import Retrieval
from vpr_uncertainty.retrieval.result import distance_kind_hint

RECALL_LEVELS: tuple[float, ...] = (0.25, 0.5, 0.75)
#: Seconds of calls after which the timings stop repeating a call.
_TIMING_BUDGET_S = 0.5


def time_per_query(compute: Callable[[], Any], n_queries: int, *, repeats: int = 5) -> tuple[Any, float]:
    """``(first result, median seconds of a call / n_queries)``: ``compute`` run once, then again while the calls
    took under half a second (at most ``repeats`` in all)."""
    result, first = _timed(compute)
    durations = [first]
    while len(durations) < repeats and sum(durations) < _TIMING_BUDGET_S:
        durations.append(_timed(compute)[1])
    return result, statistics.median(durations) / max(n_queries, 1)


def _timed(call: Callable[[], Any]) -> tuple[Any, float]:
    """``call()``'s result and the seconds it took."""
    start = time.perf_counter()
    result = call()
    return result, time.perf_counter() - start


def evaluate(
    retrieval: Retrieval,
    methods: Sequence[str] | None = None,
    *,
    k: int = 10,
    alpha: float = 0.5,
    recall_levels: Sequence[float] = RECALL_LEVELS,
    recall_at: Sequence[int] | None = None,
    timing_repeats: int = 5,
    bootstrap: int = 0,
    seed: int = 0,
    reference: str | None = None,
    latency: bool = False,
    **options: Any,
) -> Evaluation:
    """Compute every requested uncertainty on a retrieval and measure how well it predicts correct answers.

    Parameters
    ----------
    retrieval : Retrieval
        Top-k retrieval with its ground truth (``retrieval.positives``).
    methods : sequence of str, optional
        Registered method names (see :func:`vpr_uncertainty.available_methods`); by default the registry's default
        entries at call time (:func:`~vpr_uncertainty.methods.default_method_names`), plugins included, less
        those that do not suit the retrieval's scores (with a warning naming them: e.g. RS, SD, SU on distances).
    k, alpha : int, float
        Options of the score-based methods (k candidates, weight α of SU). When the retrieval holds fewer than
        k candidates per query, the methods use those it has: a :class:`FewerCandidatesWarning` and a note say
        so, and ``Evaluation.k`` records the k used.
    recall_levels : sequence of float
        Recall levels at which the end-to-end precision is reported.
    recall_at : sequence of int, optional
        The N of the retrieval's recall@N (``Evaluation.recall_at_n``), any N >= 1. An N above the candidates per
        query is unknown unless they cover the whole database: it is reported as None, with a
        :class:`FewerCandidatesWarning` and a note ("recall@100 needs 100 candidates per query, the retrieval holds
        20: reported as None; ..."), never capped under its name. By default, those of
        :data:`~vpr_uncertainty.evaluation.metrics.RECALL_NS` (1, 5, 10, 20) that the retrieval can answer.
    timing_repeats : int
        Calls per method for the time per query (median; fewer when a call is slow). A geometric method's
        ``time_per_query_ms`` is its cold figure (every local feature extracted); its ``timings`` hold
        ``time_per_query_ms_cold`` and ``time_per_query_ms_warm`` (features read from the cache in
        ``cache_dir``; absent without one), see :func:`time_geometric`.
    bootstrap : int, default=0
        Paired bootstrap resamples over queries (0: none, else >= 40): 95 % intervals of AUC-PR, AP and AURC, a
        paired test of each method's AUC-PR against ``reference`` (Holm-corrected), and the leaders of each metric;
        see :func:`vpr_uncertainty.evaluation.bootstrap.add_bootstrap`.
    seed : int, default=0
        Seed of the bootstrap resamples.
    reference : str, optional
        The method of the paired tests; default SU when evaluated, else the first method.
    latency : bool, default=False
        Also measure each score-based method's latency at batch size 1 (``timings["latency_ms_batch1"]``: the
        median over 3 runs of 200 single-query calls of its registered function on a (1, K) row).
    **options
        Further options passed to the methods that accept them; an option that no selected method takes
        (besides the inputs of :data:`~vpr_uncertainty.methods.STAGE_INPUTS`) is a ValueError. Files the
        options name (e.g. BTL's head) are read once, before the timing.
    """
    if retrieval.positives is None:
        raise ValueError(
            "the retrieval has no ground truth (positives); read it with one (argument ground_truth) or from a file "
            "that holds it"
        )
    if retrieval.n_queries == 0:
        raise ValueError("the retrieval has no queries")
    if methods is None:
        methods = default_method_names(retrieval=retrieval)
    if not methods:
        raise ValueError("no uncertainty method requested")
    entries = [get_method(name) for name in methods]  # unknown names fail before any work
    check_options(entries, options)  # and so do options that no selected method takes
    ranked = int(retrieval.config.get("ranked_candidates", retrieval.k))  # a per-query table names the top-1 only
    if recall_at is None:  # every N is known when the candidates cover the database
        recall_at = [n for n in RECALL_NS if n <= ranked or ranked >= retrieval.positives.shape[1]] or [1]
    recall_at = check_recall_ns(recall_at)
    check_bootstrap(bootstrap, seed)
    if bootstrap:
        resolve_reference(reference, [entry.name for entry in entries])
    positives = retrieval.positives
    answerable = answerable_queries(positives)
    first_rank = first_positive_rank(retrieval.indices, positives)  # one look-up for correct and every recall@N
    correct = first_rank < 1
    recall_note = recall_candidates_note(recall_at, ranked, positives.shape[1])
    with warnings.catch_warnings():  # the note below says it once, pointing at the caller
        warnings.simplefilter("ignore", FewerCandidatesWarning)
        recalls = recall_at_n(
            retrieval.indices[:, :ranked], positives, recall_at, first_rank=first_rank, answerable=answerable
        )
    evaluation = Evaluation(
        n_queries=retrieval.n_queries,
        n_answerable=int(answerable.sum()),
        correct=correct,
        recall_at_n=recalls,
        k=min(int(k), retrieval.k),
        k_requested=int(k),
        retrieval=retrieval,
    )

    def note(text: str | None, warning: type[Warning] | None = None) -> None:
        if text:
            evaluation.notes.append(text)
            if warning is not None:
                warnings.warn(text, warning, stacklevel=3)

    note(recall_note, FewerCandidatesWarning)
    if (~answerable).any():
        note(
            f"{int((~answerable).sum())} queries have no positive in the database; they count as wrong answers "
            "and are left out of the recall denominators"
        )
    if correct.all() or not correct.any():
        note("AUC-PR and AP are undefined: every top-1 answer is correct, or none is", RuntimeWarning)
    note(_candidates_note(k, retrieval.k, entries, retrieval.config.get("source")), FewerCandidatesWarning)
    note(_nonpositive_note(retrieval.scores, entries))
    replaced = [f"{entry.name} is {entry.function.__module__}'s" for entry in entries if entry.replaces]
    if replaced:
        note(f"{', '.join(replaced)} method, a plugin's in place of the built-in of that name")
    note(_direction_note(retrieval, float(correct.mean())), UserWarning)
    for entry in entries:
        inputs = entry.resolve_inputs(retrieval, {"k": k, "alpha": alpha, **options})  # files read once
        timings: dict[str, float] = {}
        if entry.kind == "geometric":
            result, cold, warm = time_geometric(
                lambda given, entry=entry: entry(retrieval, **given), inputs, repeats=timing_repeats
            )
            seconds = cold / retrieval.n_queries
            timings["time_per_query_ms_cold"] = seconds * 1e3
            if warm is not None:
                timings["time_per_query_ms_warm"] = warm / retrieval.n_queries * 1e3
        else:
            call = entry.bind(retrieval, inputs)  # needs checked once; the timed call is the method's own function
            with entry.naming_errors():
                result, seconds = time_per_query(call, retrieval.n_queries, repeats=timing_repeats)
            entry.check_result(result, retrieval)
        if latency and entry.kind in LATENCY_KINDS:
            timings["latency_ms_batch1"] = latency_batch1(functools.partial(entry, **inputs), retrieval) * 1e3
        method_correct, own_recall, details = correct, None, {}
        if isinstance(result, DetailedUncertainty):
            result, details = result.uncertainty, dict(result.details)
        uncertainty = result
        if isinstance(result, OwnRetrievalUncertainty):
            uncertainty, own, details = result.uncertainty, result.retrieval, dict(result.details)
            if details.get("trained_on_queries"):
                evaluation.notes.append(
                    f"{entry.name} was trained on {details['trained_on_queries']} of these {retrieval.n_queries} "
                    "queries (allow_train_queries): its figures are optimistic, and it is marked ‡ and never best"
                )
            note(f"{entry.name}: {details.pop('note')}" if "note" in details else None)  # e.g. BTL's unverified leakage
            method_correct = correct_at_n(own.indices, own.positives if own.positives is not None else positives, 1)
            own_recall = float(method_correct[answerable].mean())
            evaluation.notes.append(
                f"{entry.name} retrieves with its own embeddings: its correctness labels come from its own top-1 "
                f"(recall@1 {own_recall:.3f})"
            )
        ranking = rank_queries(method_correct, uncertainty)  # one sort for every metric of this method
        both = 0 < ranking.n_correct < ranking.n_queries  # AUC-PR and AP need both correct and wrong answers
        curve = ranking.rejection_curve(n_answerable=evaluation.n_answerable)
        evaluation.methods[entry.name] = MethodEvaluation(
            name=entry.name,
            uncertainty=uncertainty,
            auc_pr=ranking.auc_pr() if both else None,
            average_precision=ranking.average_precision() if both else None,
            aurc=ranking.aurc(),
            time_per_query_ms=seconds * 1e3,
            curve=curve,
            recall_at_full_precision=recall_at_full_precision(curve),
            precision_at_recall={level: precision_at_recall(curve, level) for level in recall_levels},
            own_recall_at_1=own_recall,
            correct=None if own_recall is None else method_correct,
            timings=timings,
            details=details,
            n_distinct=ranking.n_distinct,
            tied_share=ranking.tied_share,
        )
    tied = [method.name for method in evaluation.methods.values() if not method.informative]  # one value for all
    if tied:
        note(
            f"{', '.join(tied)}: the same uncertainty for all {evaluation.n_queries} queries, so no ranking; their "
            "AUC-PR and AP are chance level (marked uninformative) and they are never declared best"
        )
    if bootstrap:
        add_bootstrap(evaluation, n_resamples=bootstrap, seed=seed, reference=reference)
    return evaluation


#: Where the s_1 <= 0 rule is written down.
_NONPOSITIVE_RULE_DOCS = "docs/explanation/conventions.md; vpr_uncertainty.scores"


def _candidates_note(k: int, available: int, entries: Sequence[UncertaintyMethod], source: object) -> str | None:
    """A note when k exceeds the candidates per query, for the methods whose result depends on k (ratio, spatial)."""
    using_k = [entry.name for entry in entries if entry.scores == "similarity" or entry.kind == "spatial"]
    if int(k) <= available or not using_k:
        return None
    where = f" ({source})" if source else ""
    return (
        f"k = {int(k)} was asked but the retrieval{where} holds {available} candidates per query: "
        f"{', '.join(using_k)} used k = {available}; retrieve at least {int(k)} candidates for k = {int(k)}"
    )


def _nonpositive_note(scores: np.ndarray, entries: Sequence[UncertaintyMethod]) -> str | None:
    """A note counting the queries whose best similarity s_1 <= 0, when a ratio method (RS, SD, SU, ...) is asked."""
    ratio = [entry.name for entry in entries if entry.scores == "similarity"]  # divide by s_1: RS, SD, SU, ...
    if not ratio or scores.shape[0] == 0 or scores.shape[1] == 0:
        return None
    best = np.asarray(scores)[:, 0]
    count = int((best <= 0).sum())
    if not count:
        return None
    return (
        f"{count} of {len(best)} queries have a best similarity s_1 <= 0: {', '.join(ratio)} rank them as the most "
        f"uncertain (uncertainty 1 - s_1 >= 1), the rule for s_1 <= 0 in {_NONPOSITIVE_RULE_DOCS}"
    )


def _direction_note(retrieval: Retrieval, top_1_correct: float) -> str | None:
    """A note when the scores order the ground truth last (distances read as similarities, or the reverse): when the
    queries whose positives score below the mean of their row (the matrix's, as the reader counted them in
    ``config["positives_vs_mean"]``, else the candidates') outnumber those above by 3 standard deviations of a fair
    coin's count (one-sided p ≈ 0.001 for scores unrelated to the ground truth; any better ones score them above)."""
    counts = retrieval.config.get("positives_vs_mean")
    if counts is None:
        rows, columns = np.nonzero(candidate_hits(retrieval.indices, retrieval.positives))
        counts = positives_against_mean(retrieval.scores, rows, columns)
    above, below = (int(count) for count in counts)
    if below - above < 3 * np.sqrt(above + below) or below == 0:
        return None
    reading, advice = "similarities", "if lower means more similar, read them as distances (--scores, or score_kind "
    advice += f"in a reproduce config): {distance_kind_hint(retrieval.scores)}"
    if retrieval.score_kind == "distance" or "score_conversion" in retrieval.config:
        reading, advice = "distances (--scores)", "if higher means more similar, drop --scores"
    return (
        f"the scores rank the ground truth backwards: read as {reading}, {below} of {above + below} queries score "
        f"their positives below the mean of their row (top-1 correct: {top_1_correct:.3f}); {advice}"
    )


#: Kinds of method whose batch-1 latency is measured (the others need images or a model per call).
LATENCY_KINDS: frozenset[str] = frozenset({"score", "spatial", "calibrated"})


def single_query_retrievals(retrieval: Any, n: int) -> list[Any]:
    """``n`` (>= 1) one-query retrievals: the first ``n`` queries (cycled when there are fewer), each (1, K)."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if retrieval.n_queries == 0:
        raise ValueError("the retrieval has no queries")
    rows = [retrieval.subset_queries(np.array([index])) for index in range(min(n, retrieval.n_queries))]
    return [rows[i % len(rows)] for i in range(n)]


def latency_batch1(call: Callable[[Any], Any], retrieval: Any, *, n_calls: int = 200, runs: int = 3) -> float:
    """Seconds (> 0) per ``call(one_query_retrieval)``: the median over ``runs`` (>= 3) runs of ``n_calls`` calls on
    :func:`single_query_retrievals` of ``retrieval``, built before timing.

    A latency, as a robot sees it (the paper's "0.03 ms per query" for SU, a median over repeated runs), where
    ``time_per_query_ms`` is a throughput (one call on every query, divided by their number).
    """
    if runs < 3:
        raise ValueError(f"runs must be >= 3 (a median over repeated runs), got {runs}")
    queries = single_query_retrievals(retrieval, n_calls)
    call(queries[0])  # warm-up: imports, caches
    per_call = []
    for _ in range(runs):
        start = time.perf_counter()
        for query in queries:
            call(query)
        per_call.append((time.perf_counter() - start) / len(queries))
    return max(statistics.median(per_call), 1e-12)


def _snapshot(folder: Path) -> set[str]:
    """Names of the files directly in ``folder`` (empty when it is missing)."""
    return {path.name for path in folder.iterdir() if path.is_file()} if folder.is_dir() else set()


def time_geometric(
    call: Callable[[Mapping[str, Any]], Any], options: Mapping[str, Any], *, repeats: int = 3
) -> tuple[Any, float, float | None]:
    """``(first result, cold seconds, warm seconds)`` of ``call(options)``, a geometric method on every query.

    Cold: one call that extracts every local feature it needs (with a fresh temporary cache when
    ``options["cache_dir"]`` already held features); warm: the median of at most ``repeats`` calls (at least one, more
    while they take under half a second in all) that read every feature from the cache (matching and RANSAC only);
    None without ``cache_dir``.
    """
    if options.get("cache_dir") is None:
        result, seconds = _timed(lambda: call(options))
        return result, seconds, None
    cache_dir = Path(options["cache_dir"])
    before = _snapshot(cache_dir)
    result, cold = _timed(lambda: call(options))
    created = bool(_snapshot(cache_dir) - before)  # a new cache file: nothing of this extractor was cached
    warm: list[float] = [] if created else [cold]
    while len(warm) < max(repeats, 1) and (not warm or sum(warm) < _TIMING_BUDGET_S):
        warm.append(_timed(lambda: call(options))[1])
    if not created:  # the first call read the cache: time a cold one in a fresh cache
        with tempfile.TemporaryDirectory(prefix="vpr-uncertainty-cold-") as scratch:
            cold = _timed(lambda: call({**options, "cache_dir": Path(scratch)}))[1]
    return result, cold, statistics.median(warm)
