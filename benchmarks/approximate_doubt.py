"""Doubt scores on approximate top-k (IVF-PQ, HNSW) vs exact top-k of the same descriptors: AUC-PR difference.

A city-scale deployment retrieves with an approximate Faiss index, so RS, SD and SU see approximate similarities
(PQ-compressed scores, candidates an index may miss). This study runs the same queries through exact search
(``Flat``) and through approximate indexes (Faiss factory strings, as ``retrieve --index`` accepts), and reports
each method's AUC-PR (uncertainty predicting a wrong top-1), recall@1 and the top-1 agreement with exact search.

Data: 100,000 × 256 clustered unit descriptors (1,000 clusters of 100 "places"; each place close to its cluster
centre, so that neighbours are confusable) and 2,000 queries, each a noisy copy of one place (its only positive);
the noise varies per query, so some top-1 answers are wrong. (The corridor's 111 × 111 descriptors are too few for
an IVF or HNSW index to differ from exact search.)

    python benchmarks/approximate_doubt.py                          # synthetic, Flat vs IVF1024,PQ32 vs HNSW32
    python benchmarks/approximate_doubt.py --database 20000 --indexes IVF256,PQ32   # quick check
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

from vpr_uncertainty import evaluate
from vpr_uncertainty.formats.ground_truth import positives_from_lists
from vpr_uncertainty.retrieval import retrieve

METHODS = ("RS", "SD", "SU")


def unit(rows: np.ndarray) -> np.ndarray:
    return (rows / np.linalg.norm(rows, axis=1, keepdims=True)).astype(np.float32)


def synthetic(n_database: int, n_queries: int, dimension: int, seed: int = 0):
    """Clustered database, noisy-copy queries; returns (database, queries, positives as lists)."""
    rng = np.random.default_rng(seed)
    n_clusters = max(1, n_database // 100)
    centres = unit(rng.standard_normal((n_clusters, dimension)))
    database = unit(
        centres[np.arange(n_database) % n_clusters] + 0.6 * unit(rng.standard_normal((n_database, dimension)))
    )
    places = rng.choice(n_database, size=n_queries, replace=False)
    noise = rng.uniform(1.0, 3.0, size=(n_queries, 1))  # easy to hard queries
    queries = unit(database[places] + noise * unit(rng.standard_normal((n_queries, dimension))))
    return database, queries, [[int(p)] for p in places]


def run(database, queries, positives, indexes, k, search_params):
    rows = []
    exact_top1 = None
    for index in ["Flat", *indexes]:
        start = time.perf_counter()
        params = search_params.get(index)
        retrieval = retrieve(database, queries, k, index=index, search_params=params, progress=False)
        seconds = time.perf_counter() - start
        retrieval.positives = positives_from_lists(positives, n_database=len(database))
        retrieval.__post_init__()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = evaluate(retrieval, METHODS, k=k, timing_repeats=1)
        top1 = retrieval.indices[:, 0]
        exact_top1 = top1 if exact_top1 is None else exact_top1
        row = {
            "index": index,
            "search_params": params,
            "seconds": round(seconds, 2),
            "recall@1": float(np.mean([top1[q] in positives[q] for q in range(len(top1))])),
            "top1_agrees_with_exact": float(np.mean(top1 == exact_top1)),
            **{name: float(result.methods[name].auc_pr) for name in METHODS},
        }
        rows.append(row)
    for row in rows:
        row.update({f"{name}_minus_exact": row[name] - rows[0][name] for name in METHODS})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--database", type=int, default=100_000)
    parser.add_argument("--queries", type=int, default=2000)
    parser.add_argument("--dimension", type=int, default=256)
    parser.add_argument("--k", type=int, default=10)
    parser.add_argument("--indexes", default="IVF1024,PQ32;HNSW32", help="';'-separated Faiss factory strings")
    parser.add_argument("--nprobe", type=int, default=16, help="nprobe of IVF indexes (default 16)")
    parser.add_argument("--ef-search", type=int, default=64, help="efSearch of HNSW indexes (default 64)")
    parser.add_argument("--json", type=Path, help="write the rows as JSON")
    args = parser.parse_args()
    indexes = [index for index in args.indexes.split(";") if index]
    search_params = {
        index: (f"nprobe={args.nprobe}" if index.startswith("IVF") else f"efSearch={args.ef_search}")
        for index in indexes
        if index.startswith(("IVF", "HNSW"))
    }
    database, queries, positives = synthetic(args.database, args.queries, args.dimension)
    rows = run(database, queries, positives, indexes, args.k, search_params)
    print(f"{args.database} x {args.dimension} database, {args.queries} queries, k={args.k}")
    print(f"{'index':<16}{'params':<14}{'s':>7}{'R@1':>7}{'top1=':>7}" + "".join(f"{m:>8}{'Δ':>8}" for m in METHODS))
    for row in rows:
        print(
            f"{row['index']:<16}{row['search_params'] or '':<14}{row['seconds']:>7.1f}{row['recall@1']:>7.3f}"
            f"{row['top1_agrees_with_exact']:>7.3f}"
            + "".join(f"{row[m]:>8.3f}{row[m + '_minus_exact']:>+8.3f}" for m in METHODS)
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
