"""Import cost of the package beside that of numpy, measured in the same run (fresh interpreters, medians).

    python benchmarks/bench_import.py [--rounds 7]

Each round starts one interpreter per statement and reads its wall time and peak resident memory (the child's
VmHWM); rounds interleave the statements. Bytecode is cached as on a user's machine (PYTHONDONTWRITEBYTECODE
is dropped from the children's environment).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

STATEMENTS = {
    "import numpy": "import numpy",
    "import vpr_uncertainty": "import vpr_uncertainty",
    "import vpr_uncertainty + SU of one row": (
        "import numpy as np, vpr_uncertainty as v; v.statistical_uncertainty(np.array([[0.9, 0.5, 0.4]]), k=3)"
    ),
}


def _gate_file(folder: Path) -> Path:
    """A gate calibrated on synthetic scores (a higher score is more often right), saved to ``folder``."""
    import numpy as np

    from vpr_uncertainty import Retrieval, calibrate

    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((300, 10)), axis=1)
    retrieval = Retrieval(
        scores=scores, indices=np.tile(np.arange(10), (300, 1)), positives=rng.random((300, 10)) < scores
    )
    return calibrate(retrieval).save(folder / "gate.json")


ENVIRONMENT = {name: value for name, value in os.environ.items() if name != "PYTHONDONTWRITEBYTECODE"}
# Printed by each child at exit: its peak resident memory in KiB (Linux's VmHWM; ru_maxrss would carry over the
# parent's peak across fork and exec).
PEAK_MEMORY = "; print(next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')))"


def measure(statement: str) -> tuple[float, float]:
    """Wall seconds and peak resident MiB of a fresh interpreter that runs ``statement``."""
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", statement + PEAK_MEMORY], check=True, capture_output=True, text=True, env=ENVIRONMENT
    )
    elapsed = time.perf_counter() - start
    return elapsed, int(done.stdout.split()[-1]) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp())
    row = "[0.9, 0.5, 0.4, 0.3, 0.3, 0.2, 0.2, 0.1, 0.1, 0.1]"
    STATEMENTS["import vpr_uncertainty + Gate.load + one call"] = (
        f"import vpr_uncertainty as v; v.Gate.load({str(_gate_file(folder))!r})({row})"
    )
    times: dict[str, list[float]] = {name: [] for name in STATEMENTS}
    memory: dict[str, list[float]] = {name: [] for name in STATEMENTS}
    for statement in STATEMENTS.values():  # writes the bytecode caches, as a user's first import does
        measure(statement)
    for _ in range(args.rounds):  # interleaved, so that a noisy moment hits every statement alike
        for name, statement in STATEMENTS.items():
            elapsed, peak = measure(statement)
            times[name].append(elapsed)
            memory[name].append(peak)
    reference = statistics.median(times["import numpy"])
    print(f"{'statement':<48}{'median ms':>10}{'x numpy':>9}{'peak RSS MiB':>14}")
    for name, values in times.items():
        median = statistics.median(values)
        print(f"{name:<48}{median * 1e3:>10.0f}{median / reference:>9.2f}{statistics.median(memory[name]):>14.1f}")
    print("issue-22 targets: import + Gate.load + one call <= 2.5x import numpy, <= 50 MiB")


if __name__ == "__main__":
    main()
