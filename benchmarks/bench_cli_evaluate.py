"""`vpr-uncertainty evaluate` on a VPR-Bench matrix beside a numpy + scikit-learn script doing the same, as processes.

    python benchmarks/bench_cli_evaluate.py [--rounds 7] [--method NetVLAD]

Both read the corridor's 111 x 111 similarity matrix and its ground truth, take each query's top 20, and print
recall@{1,5,10,20} and, for RS, SD, SU, PA, L2 and BM, AUC-PR, AP, AURC, recall at 100 % precision and the
distinct values and tied share: the table `evaluate` prints by default. Each round starts one interpreter per side
(interleaved); the medians are compared. The script's AUC-PR of every method is checked against the command's
``--json`` before timing. Real data: ``$VPR_UNCERTAINTY_DATA`` (the folder with ``vprbench/``).
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

# The reference: what a researcher would write with numpy and scikit-learn alone.
REFERENCE = r"""
import sys
import numpy as np
from sklearn.metrics import auc, average_precision_score, precision_recall_curve

# VPR-Bench stores [query indices, top-1 indices, top-1 scores, similarity matrix, times] as a Python 2 pickle.
similarity = np.load(sys.argv[1], allow_pickle=True, encoding="latin1")[3].astype(np.float32)
ground_truth = np.load(sys.argv[2], allow_pickle=True)
positives = [set(np.asarray(row[1]).ravel().tolist()) for row in ground_truth]
top = np.argsort(-similarity, axis=1, kind="stable")[:, :20]
scores = np.take_along_axis(similarity, top, axis=1)
hits = np.array([[index in positives[q] for index in row] for q, row in enumerate(top)])
line = [f"{len(top)} queries,"] + [f"R@{n} {hits[:, :n].any(axis=1).mean():.3f}" for n in (1, 5, 10, 20)]
print(" ".join(line))
correct = hits[:, 0]
s = scores[:, :10]
rs = (s[:, 1:] / s[:, :1]).mean(axis=1)
sd = np.median(s, axis=1) / s[:, 0]
methods = {
    "RS": rs, "SD": sd, "SU": 0.5 * rs + 0.5 * sd, "PA": np.sqrt(2 - 2 * s[:, 0]) / np.sqrt(2 - 2 * s[:, 1]),
    "L2": np.sqrt(np.maximum(2 - 2 * s[:, 0], 0)), "BM": -s[:, 0],
}
print("method  AUC-PR      AP    AURC  R@100%P  values  tied")
for name, u in methods.items():
    precision, recall, _ = precision_recall_curve(correct, -u)
    order = np.argsort(u, kind="stable")
    accepted_correct = np.cumsum(correct[order])
    ends = np.flatnonzero(np.diff(u[order], append=np.inf) > 0)
    curve_precision = accepted_correct[ends] / (ends + 1)
    aurc = np.sum(np.diff((ends + 1) / len(u), prepend=0.0) * (1 - curve_precision))
    perfect = curve_precision >= 1
    full = (accepted_correct[ends] / len(u))[perfect].max() if perfect.any() else 0.0
    values, counts = np.unique(u, return_counts=True)
    tied = counts[counts > 1].sum() / len(u)
    print(f"{name:<6}{auc(recall, precision):>8.4f}{average_precision_score(correct, -u):>8.4f}{aurc:>8.4f}"
          f"{full:>9.3f}{len(values):>8}{tied:>6.0%}")
"""


# Bytecode caching as on a user's machine (a shell with PYTHONDONTWRITEBYTECODE=1 would recompile the package's
# modules on every start while scikit-learn's come from the .pyc files its installation wrote).
ENVIRONMENT = {name: value for name, value in os.environ.items() if name != "PYTHONDONTWRITEBYTECODE"}


def _timed(command: list[str]) -> tuple[float, str]:
    start = time.perf_counter()
    done = subprocess.run(command, check=True, capture_output=True, text=True, env=ENVIRONMENT)
    return time.perf_counter() - start, done.stdout


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--method", default="NetVLAD", help="VPR method folder under precomputed_matches/corridor")
    args = parser.parse_args()
    data = Path(os.environ.get("VPR_UNCERTAINTY_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    matrix = data / "vprbench" / "precomputed_matches" / "corridor" / args.method / "precomputed_data_corrected.npy"
    ground_truth = data / "vprbench" / "corridor" / "ground_truth_new.npy"
    if not matrix.is_file():
        sys.exit(f"no matrix at {matrix}: set VPR_UNCERTAINTY_DATA to the folder that holds vprbench/")
    folder = Path(tempfile.mkdtemp())
    script = folder / "reference.py"
    script.write_text(REFERENCE)
    # What the console script `vpr-uncertainty` runs (the package found on PYTHONPATH first, if set).
    entry = "import sys; from vpr_uncertainty.cli import main; sys.exit(main())"
    toolkit = [sys.executable, "-c", entry, "evaluate", str(matrix), "--gt", str(ground_truth)]
    reference = [sys.executable, str(script), str(matrix), str(ground_truth)]

    subprocess.run([*toolkit, "--json", str(folder / "results.json")], check=True, capture_output=True, env=ENVIRONMENT)
    expected = json.loads((folder / "results.json").read_text())["methods"]
    _, printed = _timed(reference)
    rows = {line.split()[0]: line.split() for line in printed.splitlines()[2:]}
    for name, row in rows.items():
        if abs(float(row[1]) - expected[name]["auc_pr"]) > 5e-5:
            sys.exit(
                f"the reference disagrees with the toolkit on {name}: AUC-PR {row[1]} vs {expected[name]['auc_pr']}"
            )

    times: dict[str, list[float]] = {"toolkit": [], "reference": []}
    for _ in range(args.rounds):  # interleaved, so that a noisy moment hits both alike
        times["toolkit"].append(_timed(toolkit)[0])
        times["reference"].append(_timed(reference)[0])
    shutil.rmtree(folder)
    toolkit_median, reference_median = (statistics.median(times[side]) for side in ("toolkit", "reference"))
    print(f"evaluate on the corridor's {args.method} matrix (111 x 111), {args.rounds} interleaved rounds, medians")
    print(f"{'':<36}{'median s':>9}")
    print(f"{'vpr-uncertainty evaluate':<36}{toolkit_median:>9.3f}")
    print(f"{'numpy + scikit-learn script':<36}{reference_median:>9.3f}")
    print(f"ratio {toolkit_median / reference_median:.2f} (issue-22 target <= 1.2)")


if __name__ == "__main__":
    main()
