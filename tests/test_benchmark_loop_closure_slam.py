"""``benchmarks/loop_closure_slam.py``'s own machinery: the fill-in measure of ``--fill-in`` against hand-counted
graphs and the mode on the four-lap graph; an optimiser's child process that raises."""

from __future__ import annotations

import itertools
import json
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


def test_sphere2500_has_its_poses_and_a_fitted_noise_model(bench):
    """Neither Sphere2500 file has vertices: the initial guess and the ground truth are their odometry composed
    (GTSAM's readG2o returned no poses there, so every Sphere2500 run failed in the APE); the fitted variant's σ are
    the RMS errors of the edges at the ground truth, so each component's mean squared whitened error is 1."""
    problem = bench.sphere2500()
    assert problem.truth.shape == (2500, 8) and problem.initial.size() == 2500
    start, end = problem.truth[[0, -1], 1:4]
    assert np.allclose(start, 0) and np.linalg.norm(end) > 10  # the truth is a sphere, not the origin repeated
    fitted = bench.sphere2500_fitted()
    _, truth = bench.read_graph(bench.GTSAM_DATA / "sphere2500_groundtruth.txt")
    np.testing.assert_array_equal(bench.pose_rows(truth), problem.truth)
    whitened = np.array([fitted.graph.at(i).whitenedError(truth) for i in range(fitted.graph.size())])
    np.testing.assert_allclose(np.mean(whitened**2, axis=0), 1.0, rtol=1e-6)
    sigmas = fitted.graph.at(0).noiseModel().sigmas()
    assert sigmas[:3].max() < 0.05 < 0.09 < sigmas[3:].min()  # rotation about 0.01-0.04 rad, translation 0.1 m


def _raises() -> None:
    raise ValueError("boom")


def test_an_optimiser_that_raises_is_reported_at_once(bench):
    """The child's error comes back as soon as it happens (the parent used to wait out the whole time limit)."""
    start = time.perf_counter()
    with pytest.raises(RuntimeError, match="raised ValueError: boom"):
        bench.in_child(_raises, timeout=60)
    assert time.perf_counter() - start < 10
    assert bench.in_child(lambda: 42, timeout=60) == 42


def test_grouped_wrong_closures_are_mutually_consistent_runs(bench):
    """Sünderhauf's grouped policy: runs of 5-20 closures (a + t, b + t), one measurement per run, none an edge."""
    problem = bench.four_lap(0)
    graph, closures, is_true = bench.with_wrong_closures(problem, 0.5, np.random.default_rng(3), "grouped")
    wrong = closures[~is_true]
    assert is_true.sum() == 60 and len(wrong) == 60  # 50 %: as many wrong as true
    factors = {tuple(sorted(graph.at(i).keys())): graph.at(i) for i in range(graph.size())}
    starts = [0] + [k for k in range(1, len(wrong)) if tuple(wrong[k] - wrong[k - 1]) != (1, 1)] + [len(wrong)]
    lengths = np.diff(starts)
    assert (lengths <= 20).all() and (lengths[:-1] >= 5).all()  # the last run is cut to the count
    for begin, end in itertools.pairwise(starts):
        run = [factors[tuple(pair)].measured() for pair in wrong[begin:end].tolist()]
        assert all(m.equals(run[0], 0.0) for m in run)  # one claim: the two stretches are one place
    assert (wrong[:, 1] - wrong[:, 0] > 20).all()
    assert len({tuple(p) for p in closures.tolist()}) == len(closures)


def test_p_star_runs_the_gate_once_per_target_on_the_same_labels(bench, corridor_dir, tmp_path):
    out = tmp_path / "r.jsonl"
    only = "true only, LM (floor);gate p*=0.5, LM;gate p*=0.9, LM;gate p*=0.9 + GNC"
    argv = ["--graphs", "fourlap", "--rates", "0.5", "--p-star", "0.5,0.9", "--only", only, "--json", str(out)]
    assert bench.main(argv) == 0
    records = {r["config"]: r for r in map(json.loads, out.read_text().splitlines())}
    assert list(records) == only.split(";")
    assert records["gate p*=0.5, LM"]["p_star"] == 0.5 and records["gate p*=0.9 + GNC"]["p_star"] == 0.9
    assert records["true only, LM (floor)"]["p_star"] is None
    # the same 200 labels: the looser target certifies a lower bound and passes at least as many wrong closures
    assert records["gate p*=0.5, LM"]["gate_lower_bound"] < records["gate p*=0.9, LM"]["gate_lower_bound"]
    assert records["gate p*=0.5, LM"]["wrong_passed"] >= records["gate p*=0.9, LM"]["wrong_passed"]
    with pytest.raises(SystemExit):
        bench.main(["--graphs", "fourlap", "--p-star", "0.9,1.5"])


def test_p_star_summary_against_a_hand_made_results_file(bench, tmp_path):
    """Two seeds: ratios to each seed's own floor, a run that did not finish counted apart, medians by hand."""

    def record(seed: int, config: str, ate: float | None, seconds: float, passed: tuple) -> dict:
        return {
            "graph": "g", "method": "M", "rate": 0.7, "seed": seed, "config": config, "ate_rmse": ate,
            "wrong_passed": passed[0], "true_passed": passed[1], "seconds": seconds,
        }  # fmt: skip

    records = [
        record(0, "true only, LM (floor)", 0.1, 1.0, (0, 60)),
        record(1, "true only, LM (floor)", 0.2, 3.0, (0, 60)),
        record(0, "all, GNC (TLS)", 0.1, 10.0, (140, 60)),
        record(1, "all, GNC (TLS)", None, 180.0, (140, 60)),  # stopped at the time limit
        record(0, "gate p*=0.7 + GNC", 0.105, 2.0, (3, 50)),
        record(1, "gate p*=0.7 + GNC", 0.4, 4.0, (5, 40)),
    ]
    path = tmp_path / "r.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    accuracy, cost = (part.split(":\n\n")[1].splitlines() for part in bench.p_star_summary(path).split("\n\nClosures"))
    assert accuracy[0].split(" | ")[5:] == ["all closures, LM", "all, GNC (TLS)", "gate p*=0.7 + GNC |"]
    # floor median 0.15 m; GNC alone: 1.0 on seed 0, seed 1 stopped; the gate: ratios 1.05 and 2.0 (median 1.525)
    row = accuracy[2].split(" | ")
    assert row[:5] == ["| g", "random, native, 200", "70%", "2", "0.150"]
    assert row[5] == "–" and row[6] == "1.00 [1.00, 1.00] 1/2 (1 not finished)"
    assert row[7] in ("1.52 [1.05, 2.00] 1/2 |", "1.53 [1.05, 2.00] 1/2 |")
    # medians of (3, 5) wrong and (50, 40) true passed; of 2 s and 4 s; a stopped run counts its limit
    assert cost[2].split(" | ")[6:] == ["140 / 60, 95.00 s", "4 / 45, 3.00 s |"]
