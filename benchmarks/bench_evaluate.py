"""In-process ``evaluate(retrieval, ["SU", "BM"])`` + ``format_table`` beside plain numpy + scikit-learn doing the same
work on the same arrays, in one run (rounds interleaved, medians).

    python benchmarks/bench_evaluate.py                         # Q = 1e4, 1e5, 1e6; 3 rounds
    python benchmarks/bench_evaluate.py --sizes 10000 --rounds 5

The synthetic retrieval is realistic in shape: Q queries, top-10 cosine-like similarities sorted descending, one
positive per query: among the top-1 for ~60 % of them, at ranks 2-10 for ~25 %, outside the top 10 for ~13 %, and
none in the database for ~2 % (left out of the recall denominators). A correct top-1 tends to stand further above
its runners-up, so SU is informative.

The reference computes what ``evaluate`` computes by default: SU and BM (once each; ``evaluate`` also times them,
calling each up to 5 times within 0.5 s, which it counts), top-1 correctness, recall@N for N in (1, 5, 10, 20) that
fit in K, and per method AUC-PR (``sklearn.metrics.precision_recall_curve`` + ``auc``), AP
(``average_precision_score``), the rejection curve (precision, recall, coverage at each distinct uncertainty), AURC,
recall at 100 % precision, precision at recall 0.25/0.5/0.75 and the number of distinct / tied uncertainty values.
The two agree to the tolerance policy (float32 scores: 1e-5 relative) or the run stops.
Targets: toolkit / reference <= 1.5 at Q = 1e6 (issue 22), <= 1.0 (issue 45).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from scipy import sparse
from sklearn.metrics import auc, average_precision_score, precision_recall_curve

from vpr_uncertainty import Retrieval, evaluate
from vpr_uncertainty.reports.tables import format_table

K = 10
RECALL_NS = (1, 5, 10, 20)
RECALL_LEVELS = (0.25, 0.5, 0.75)


def synthetic_retrieval(n_queries: int, seed: int = 0) -> Retrieval:
    """Q queries against a database of Q images, top-10 candidates each (see the module docstring)."""
    rng = np.random.default_rng(seed)
    n_database = max(n_queries, 2 * K)
    start = rng.integers(0, n_database, n_queries)
    indices = (start[:, None] + np.arange(K)) % n_database  # K distinct database images per query
    kind = rng.random(n_queries)
    top1 = kind < 0.60
    in_top = (kind >= 0.60) & (kind < 0.85)
    outside = (kind >= 0.85) & (kind < 0.98)
    rank = np.where(top1, 0, rng.integers(1, K, n_queries))
    positive = np.where(outside, (start + n_database // 2) % n_database, indices[np.arange(n_queries), rank])
    has = top1 | in_top | outside
    rows = np.flatnonzero(has)
    positives = sparse.csr_array(
        (np.ones(rows.size, dtype=bool), (rows, positive[rows])), shape=(n_queries, n_database)
    )
    best = rng.uniform(0.55, 0.95, n_queries)
    gaps = rng.exponential(0.015, (n_queries, K))
    gaps[:, 0] = 0.0
    gaps[:, 1] += np.where(top1, rng.exponential(0.04, n_queries), 0.0)  # a correct top-1 stands out
    scores = (best[:, None] - np.cumsum(gaps, axis=1)).astype(np.float32)
    return Retrieval(scores=scores, indices=indices.astype(np.int64), positives=positives)


def toolkit(retrieval: Retrieval) -> tuple[object, str]:
    evaluation = evaluate(retrieval, ["SU", "BM"])
    return evaluation, format_table(evaluation)


def _curve(correct: np.ndarray, uncertainty: np.ndarray, n_answerable: int) -> dict[str, object]:
    order = np.argsort(uncertainty, kind="stable")
    ordered = uncertainty[order]
    hits = np.cumsum(correct[order])
    ends = np.flatnonzero(np.diff(ordered, append=np.inf) > 0)
    accepted = ends + 1
    precision = hits[ends] / accepted
    recall = hits[ends] / n_answerable
    coverage = accepted / correct.size
    reached = [np.flatnonzero(recall >= level) for level in RECALL_LEVELS]
    _, counts = np.unique(uncertainty, return_counts=True)
    pr_precision, pr_recall, _ = precision_recall_curve(correct, -uncertainty)
    return {
        "auc_pr": float(auc(pr_recall, pr_precision)),
        "average_precision": float(average_precision_score(correct, -uncertainty)),
        "aurc": float(np.sum(np.diff(coverage, prepend=0.0) * (1.0 - precision))),
        "recall_at_100_precision": float(recall[precision >= 1.0].max()) if (precision >= 1.0).any() else 0.0,
        "precision_at_recall": [float(precision[r[0]]) if r.size else None for r in reached],
        "distinct": int(counts.size),
        "tied_share": float(counts[counts > 1].sum() / uncertainty.size),
        "curve": (precision, recall, coverage),
    }


def reference(retrieval: Retrieval) -> dict[str, object]:
    """The same numbers with numpy and scikit-learn, written directly."""
    scores, indices, positives = retrieval.scores, retrieval.indices, retrieval.positives
    top = scores[:, :K]
    n = top.shape[1]
    # SU = (0.5 mean(s_2..s_n) + 0.5 median) / s_1 in the toolkit's arithmetic (float64, s_2 + s_3 + ... left to
    # right, then the weights, then / s_1, rounded to the scores' dtype), so float32 rounds alike and the tie groups
    # of the curves match.
    columns = top.T.astype(np.float64)
    total = columns[1].copy()
    for j in range(2, n):
        total += columns[j]
    su = (0.5 / (n - 1) * total + 0.25 * (columns[(n - 1) // 2] + columns[n // 2])) / columns[0]
    uncertainties = {"SU": su.astype(top.dtype), "BM": -top[:, 0]}
    answerable = np.diff(positives.indptr) > 0
    n_answerable = int(answerable.sum())
    hits = np.asarray(positives[np.repeat(np.arange(len(indices)), n), indices[:, :n].ravel()]).reshape(-1, n)
    first = np.where(hits.any(axis=1), hits.argmax(axis=1), n)  # rank of the first positive, n when none
    correct = first == 0
    recall = {m: float((first[answerable] < m).mean()) for m in RECALL_NS if m <= n}
    methods = {name: _curve(correct, u.astype(np.float64), n_answerable) for name, u in uncertainties.items()}
    return {"correct": correct, "recall": recall, "methods": methods, "uncertainties": uncertainties}


def check_agree(evaluation: object, ref: dict[str, object]) -> None:
    assert np.array_equal(evaluation.correct, ref["correct"])
    assert evaluation.recall_at_n == ref["recall"], (evaluation.recall_at_n, ref["recall"])
    for name, expected in ref["methods"].items():
        method = evaluation.methods[name]
        np.testing.assert_allclose(method.uncertainty, ref["uncertainties"][name], rtol=1e-5, err_msg=name)
        for key in ("auc_pr", "average_precision", "aurc", "recall_at_100_precision"):
            got = {"recall_at_100_precision": method.recall_at_full_precision}.get(key, getattr(method, key, None))
            np.testing.assert_allclose(got, expected[key], rtol=1e-5, err_msg=f"{name} {key}")
        for level, want in zip(RECALL_LEVELS, expected["precision_at_recall"], strict=True):
            got = method.precision_at_recall[level]
            assert (got is None) == (want is None), (name, level, got, want)
            if want is not None:
                np.testing.assert_allclose(got, want, rtol=1e-5, err_msg=f"{name} precision at recall {level}")
        curve = method.curve
        for got, want in zip((curve.precision, curve.recall, curve.coverage), expected["curve"], strict=True):
            np.testing.assert_allclose(got, want, rtol=1e-5, err_msg=f"{name} rejection curve")
        assert method.n_distinct == expected["distinct"]
        np.testing.assert_allclose(method.tied_share, expected["tied_share"], rtol=1e-12)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    rows = []
    for size in args.sizes:
        retrieval = synthetic_retrieval(size)
        evaluation, _ = toolkit(retrieval)  # warm-up, and the numbers to compare
        check_agree(evaluation, reference(retrieval))
        times: dict[str, list[float]] = {"toolkit": [], "reference": []}
        for _ in range(args.rounds):  # interleaved, so that a noisy moment hits both alike
            for name, function in (("toolkit", toolkit), ("reference", reference)):
                start = time.perf_counter()
                function(retrieval)
                times[name].append(time.perf_counter() - start)
        ours, theirs = statistics.median(times["toolkit"]), statistics.median(times["reference"])
        rows.append((size, ours, theirs))
        ratios = [a / b for a, b in zip(times["toolkit"], times["reference"], strict=True)]
        print(
            f"Q={size:,}: numbers agree (recall@1 {evaluation.recall_at_n[1]:.3f}, SU AUC-PR "
            f"{evaluation.methods['SU'].auc_pr:.4f}); paired ratios {', '.join(f'{r:.2f}' for r in ratios)}",
            flush=True,
        )
    print(f"{'Q':>10}{'toolkit s':>12}{'reference s':>13}{'ratio':>8}")
    for size, ours, theirs in rows:
        print(f"{size:>10,}{ours:>12.3f}{theirs:>13.3f}{ours / theirs:>8.2f}")


if __name__ == "__main__":
    main()
