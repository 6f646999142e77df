"""``benchmarks/loop_closure_slam.py``'s own machinery: the fill-in measure of ``--fill-in`` against hand-counted
graphs and the mode on the four-lap graph; an optimiser's child process that raises."""

from __future__ import annotations

import time

import numpy as np
import pytest

from conftest import load_benchmark

gtsam = pytest.importorskip("gtsam")


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("loop_closure_slam")


def test_a_chain_has_no_fill_and_a_ring_one_block_per_elimination(bench):
    chain = np.array([(k, k + 1) for k in range(9)])
    # chain of 10 poses: each pose but the last has its one neighbour as separator: 9 blocks, work 9·2² + 1
    assert bench.elimination_fill(chain) == (9, 37)
    # closing it into a ring: every elimination joins the two neighbours until three poses remain (8 separators of
    # two), then 1 and 0: 17 blocks, work 8·3² + 2² + 1
    assert bench.elimination_fill(np.r_[chain, [(0, 9)]]) == (17, 77)


def test_fill_in_mode_on_the_four_lap_graph(bench, capsys, corridor_dir):
    assert bench.main(["--fill-in", "--graphs", "fourlap", "--rates", "0.85"]) == 0
    rows = [line.split("|")[1:-1] for line in capsys.readouterr().out.splitlines()[2:]]
    by_name = {row[2].strip(): row for row in rows}
    assert list(by_name) == ["true only", "gate p*=0.9", "all"]
    assert by_name["true only"][3].strip() == "0 / 60" and by_name["all"][3].strip() == "340 / 60"
    blocks = {name: int(row[4].replace(",", "")) for name, row in by_name.items()}
    # random wrong closures join far-apart poses: the factor fills in
    assert blocks["true only"] == 708 and blocks["all"] > 5 * blocks["true only"]


def _raises() -> None:
    raise ValueError("boom")


def test_an_optimiser_that_raises_is_reported_at_once(bench):
    """The child's error comes back as soon as it happens (the parent used to wait out the whole time limit)."""
    start = time.perf_counter()
    with pytest.raises(RuntimeError, match="raised ValueError: boom"):
        bench.in_child(_raises, timeout=60)
    assert time.perf_counter() - start < 10
    assert bench.in_child(lambda: 42, timeout=60) == 42
