"""Time of ``vpr-uncertainty loop-closures`` on City10000, next to reading the same graph in the same run.

Target (issue 31): the command filters City10000 (10,000 poses) in under a second. The graph is the standard one
GTSAM ships (``T1_city10000_04.txt``, 10,688 true closures) with random wrong closures added at ``--rates``, each
closure carrying a real AMOSNet corridor score row, the gate calibrated on 200 of those rows (seed 0), exactly as
``loop_closure_slam.py`` builds its cases; all three are written to a temporary folder as the files a user passes
(g2o graph, score file, gate file). The command's own report gives the filtering time (the gate on every row, the
matching of closures to edges, the filtered graph built); beside it, the time to read the graph file
(``read_graph_file``, what any run of the command pays first) and the whole command. Medians of ``--repeats`` runs.

    VPR_UNCERTAINTY_DATA=... python benchmarks/bench_loop_closures.py [--rates 0.3,0.85] [--repeats 5]
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from vpr_uncertainty.pipeline.loop_closures import LoopClosureConf, main
from vpr_uncertainty.slam.graph_file import read_graph_file

sys.path.insert(0, str(Path(__file__).resolve().parent))  # its sibling script builds the cases

import loop_closure_slam as slam


def measure(rate: float, repeats: int, folder: Path) -> str:
    problem = slam.city10000()
    graph, closures, _, rows, gate = slam.drawn_case(problem, rate, slam.population("AMOSNet"), seed=0)
    paths = {name: folder / name for name in ("graph.g2o", "closures.npz", "gate.json", "filtered.g2o")}
    slam.gtsam.writeG2o(graph, problem.initial, str(paths["graph.g2o"]))
    np.savez(paths["closures.npz"], edges=closures, scores=rows)
    gate.save(paths["gate.json"])
    reading, filtering, whole, said = [], [], [], []
    for _ in range(repeats):
        start = time.perf_counter()
        read_graph_file(paths["graph.g2o"])
        reading.append(time.perf_counter() - start)
        start = time.perf_counter()
        main(LoopClosureConf(), *(paths[n] for n in ("graph.g2o", "closures.npz", "gate.json", "filtered.g2o")),
             log=said.append)  # fmt: skip
        whole.append(time.perf_counter() - start)
        filtering.append(float(re.search(r"\(([\d.]+) s\)", said[-1]).group(1)))
    return (
        f"City10000, {rate:.0%} wrong closures ({len(closures):,} scored, {graph.size():,} edges): {said[-1]}\n"
        f"  filtering (the command's report) {statistics.median(filtering):.3f} s | reading the graph "
        f"{statistics.median(reading):.3f} s | whole command {statistics.median(whole):.3f} s "
        f"(medians of {repeats})"
    )


def run(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rates", default="0.3,0.85", help="fractions of wrong closures (default 0.3,0.85)")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        for rate in (float(r) for r in args.rates.split(",")):
            print(measure(rate, args.repeats, Path(folder)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(run())
