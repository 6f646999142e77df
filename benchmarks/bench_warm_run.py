"""A warm rerun of ``vpr-uncertainty run`` beside a cold run on the real corridor dataset (issue 22: warm <= 0.5x cold).

    VPR_UNCERTAINTY_DATA=../shared/data python benchmarks/bench_warm_run.py [--rounds 3] [--data DIR]

Each round runs, in fresh interpreters, a cold ``run`` (a new run directory: descriptors computed, figures drawn)
and then a warm rerun into the same directory (everything cached); rounds interleave the two, so a noisy moment
of a shared machine hits both alike. Printed: medians over the rounds of the wall time of each interpreter, and
its breakdown: importing the CLI, the time ``run`` records per stage in results.json (dataset, extraction = the
descriptor cache check when warm, retrieval, uncertainty and evaluation, reports) and the rest (the CLI's parser
and plugins, interpreter start and exit); the ratio warm / cold of each; and which heavy modules the warm rerun
imported.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: One ``run`` in this interpreter: times the import of the CLI and the command, lists the heavy modules.
SCRIPT = """
import json, sys, time
start = time.perf_counter()
from vpr_uncertainty.cli import main
imported = time.perf_counter()
status = main(["run", "--dataset", sys.argv[1], "--out", sys.argv[2]])
done = time.perf_counter()
heavy = sorted(name for name in ("torch", "matplotlib", "faiss", "h5py", "sklearn", "scipy") if name in sys.modules)
print(json.dumps({"status": status, "import": imported - start, "command": done - imported, "heavy": heavy}))
"""

STAGES = ("dataset", "extraction", "retrieval", "uncertainty_and_evaluation", "reports")


def run_once(corridor: Path, out: Path) -> dict[str, float | list[str]]:
    """Wall seconds of one ``run`` in a fresh interpreter, with its import time and stage times."""
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(corridor), str(out)], capture_output=True, text=True, check=True
    )
    wall = time.perf_counter() - start
    printed = json.loads(done.stdout.strip().splitlines()[-1])
    stages = json.loads((out / "results.json").read_text())["stage_seconds"]
    row: dict[str, float | list[str]] = {"wall": wall, "import": printed["import"]}
    row.update({stage: float(stages.get(stage, 0.0)) for stage in STAGES})
    row["rest"] = wall - printed["import"] - sum(float(stages.get(stage, 0.0)) for stage in STAGES)
    row["heavy"] = printed["heavy"]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--data", type=Path, default=os.environ.get("VPR_UNCERTAINTY_DATA"))
    args = parser.parse_args()
    if args.data is None:
        parser.error("give --data or set VPR_UNCERTAINTY_DATA (the folder holding vprbench/corridor)")
    corridor = Path(args.data) / "vprbench" / "corridor"
    folder = Path(tempfile.mkdtemp(prefix="bench-warm-run-"))
    rows: dict[str, list[dict]] = {"cold": [], "warm": []}
    try:
        for round_ in range(args.rounds):
            out = folder / f"round{round_}"
            rows["cold"].append(run_once(corridor, out))  # a new directory: nothing cached
            rows["warm"].append(run_once(corridor, out))  # the same directory: everything cached
    finally:
        shutil.rmtree(folder, ignore_errors=True)

    def median(kind: str, key: str) -> float:
        return statistics.median(float(row[key]) for row in rows[kind])

    print(f"corridor (111 queries, 111 database images), default model and methods; medians of {args.rounds} rounds")
    print(f"{'seconds':<28}{'cold':>9}{'warm':>9}{'warm/cold':>11}")
    labels = {
        "wall": "wall (fresh interpreter)",
        "import": "import vpr_uncertainty.cli",
        "dataset": "dataset",
        "extraction": "extraction (warm: check)",
        "retrieval": "retrieval",
        "uncertainty_and_evaluation": "uncertainty + evaluation",
        "reports": "reports",
        "rest": "rest (parser, plugins, exit)",
    }
    for key, label in labels.items():
        cold, warm = median("cold", key), median("warm", key)
        ratio = f"{warm / cold:.2f}x" if cold > 0 else "-"
        print(f"{label:<28}{cold:>9.3f}{warm:>9.3f}{ratio:>11}")
    per_round = [w["wall"] / c["wall"] for c, w in zip(rows["cold"], rows["warm"], strict=True)]
    print(f"warm/cold wall per round: {', '.join(f'{ratio:.2f}x' for ratio in per_round)} (target <= 0.5x)")
    print(f"heavy modules imported by the warm rerun: {', '.join(rows['warm'][-1]['heavy']) or 'none'}")
    print(f"heavy modules imported by the cold run: {', '.join(rows['cold'][-1]['heavy']) or 'none'}")


if __name__ == "__main__":
    main()
