"""The SU→GV cascade on the VPR-Bench corridor: AUC-PR against the fraction verified, and its time per query.

For each of the ten real similarity matrices of the corridor (``precomputed_matches/corridor/*``, with the
corridor's images), this runs through ``vpr_uncertainty.evaluate``:

* SU, GV (``--gv``, default GV-SIFT) and the cascade ``SU+GV`` at ``--fraction`` (default 0.3), each timed with
  an empty local-feature cache (cold: every image the call verifies is extracted) — the time per query of the
  cascade counts the verification of the verified queries only;
* the AUC-PR of the cascade at every fraction of ``--sweep`` (0 = SU alone, 1 = GV on every query), from the
  inliers of one GV run on all queries (verification of a pair is deterministic, so this equals running the
  cascade at each fraction; the script checks it at ``--fraction``).

    python benchmarks/bench_cascade.py                      # GV-SIFT, all ten matrices
    python benchmarks/bench_cascade.py --gv GV-XFEAT --json cascade.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from vpr_uncertainty import evaluate, read_results
from vpr_uncertainty.data import load_vprbench_dataset
from vpr_uncertainty.evaluation import auc_pr
from vpr_uncertainty.methods.cascade import combine_cascade, most_uncertain


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=os.environ.get("VPR_UNCERTAINTY_DATA"), help="shared data folder")
    parser.add_argument("--gv", default="GV-SIFT", help="geometric-verification method (default GV-SIFT)")
    parser.add_argument("--fraction", type=float, default=0.3, help="fraction verified (default 0.3)")
    parser.add_argument("--sweep", default="0,0.1,0.2,0.3,0.4,0.5,0.7,1", help="fractions of the AUC-PR sweep")
    parser.add_argument("--workers", type=int, default=1, help="GV threads (default 1)")
    parser.add_argument("--json", type=Path, default=None, help="also write the results as JSON here")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.data is None:
        sys.exit("set VPR_UNCERTAINTY_DATA or pass --data")
    root = Path(args.data) / "vprbench"
    dataset = load_vprbench_dataset(root / "corridor")
    paths = {
        "query_paths": [str(p) for p in dataset.query_paths],
        "database_paths": [str(p) for p in dataset.database_paths],
    }
    sweep = [float(f) for f in args.sweep.split(",")]
    cascade = f"SU+{args.gv}"
    rows = []
    for folder in sorted((root / "precomputed_matches" / "corridor").iterdir()):
        retrieval = read_results(
            folder / "precomputed_data_corrected.npy", ground_truth=root / "corridor" / "ground_truth_new.npy"
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = evaluate(
                retrieval, ["SU", args.gv, cascade], verify_fraction=args.fraction, workers=args.workers, **paths
            )
        su, gv, cas = (result.methods[name] for name in ("SU", args.gv, cascade))
        curve = {}
        for fraction in sweep:
            verified = most_uncertain(su.uncertainty, fraction)
            combined = combine_cascade(su.uncertainty, verified, gv.uncertainty[verified])
            curve[fraction] = auc_pr(result.correct, combined)
        verified = most_uncertain(su.uncertainty, args.fraction)
        simulated = combine_cascade(su.uncertainty, verified, gv.uncertainty[verified])
        if not np.allclose(simulated, cas.uncertainty, rtol=1e-12, atol=0):
            raise RuntimeError(f"{folder.name}: the cascade differs from its simulation from the full GV run")
        rows.append(
            {
                "vpr_method": folder.name,
                "su": su.auc_pr,
                "gv": gv.auc_pr,
                "cascade": cas.auc_pr,
                "target": max(su.auc_pr, gv.auc_pr) - 0.01,
                "met": bool(cas.auc_pr >= max(su.auc_pr, gv.auc_pr) - 0.01),
                "ap": {"su": su.average_precision, "gv": gv.average_precision, "cascade": cas.average_precision},
                "gv_ms": gv.time_per_query_ms,
                "cascade_ms": cas.time_per_query_ms,
                "verified_fraction": cas.details["verified_fraction"],
                "curve": curve,
            }
        )
        row = rows[-1]
        print(
            f"{folder.name:<12} SU {row['su']:.3f}  {args.gv} {row['gv']:.3f}  {cascade}@{args.fraction:g} "
            f"{row['cascade']:.3f} (target {row['target']:.3f}, {'met' if row['met'] else 'MISSED'})"
            f"  ms/query {row['gv_ms']:.1f} vs {row['cascade_ms']:.1f} ({row['cascade_ms'] / row['gv_ms']:.2f}×)"
        )
    mean = {key: float(np.mean([row[key] for row in rows])) for key in ("su", "gv", "cascade", "gv_ms", "cascade_ms")}
    target = max(mean["su"], mean["gv"]) - 0.01
    met = sum(row["met"] for row in rows)
    print(
        f"{'mean':<12} SU {mean['su']:.3f}  {args.gv} {mean['gv']:.3f}  {cascade}@{args.fraction:g} "
        f"{mean['cascade']:.3f} (target {target:.3f})  ms/query {mean['gv_ms']:.1f} vs {mean['cascade_ms']:.1f} "
        f"({mean['cascade_ms'] / mean['gv_ms']:.2f}×); target met on {met}/{len(rows)} matrices"
    )
    print(
        "mean AUC-PR by fraction verified: "
        + ", ".join(f"{f:g}: {np.mean([row['curve'][f] for row in rows]):.3f}" for f in sweep)
    )
    ap = {key: float(np.mean([row["ap"][key] for row in rows])) for key in ("su", "gv", "cascade")}
    print(f"mean AP: SU {ap['su']:.3f}  {args.gv} {ap['gv']:.3f}  {cascade}@{args.fraction:g} {ap['cascade']:.3f}")
    if args.json:
        args.json.write_text(
            json.dumps({"gv": args.gv, "fraction": args.fraction, "rows": rows, "mean": mean}, indent=2)
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
