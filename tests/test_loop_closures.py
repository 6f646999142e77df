"""``loop-closures``: the gate's decisions applied to a pose graph, and GTSAM on the result (hand-made small graphs)."""

from __future__ import annotations

import numpy as np
import pytest

from vpr_uncertainty.pipeline.loop_closures import LoopClosureConf
from vpr_uncertainty.slam.pose_graph import closure_mask


class FirstScoreGate:
    """Accepts a row when its top score is above 0.5 (a stand-in for a calibrated gate)."""

    k = 3

    def accept(self, scores):
        scores = np.asarray(scores)
        if scores.shape[1] != self.k:
            raise ValueError(f"the gate was calibrated at k={self.k}, got scores of shape {scores.shape}")
        return scores[:, 0] > 0.5


GOOD, BAD = [0.9, 0.2, 0.1], [0.3, 0.29, 0.28]

# a square of 4 poses a side walked twice: 8 poses, odometry (i, i+1), closures (4, 0) and (7, 3)
EDGES = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 7), (4, 0), (7, 3)]


def test_keeps_odometry_and_the_accepted_closures():
    keep = closure_mask(EDGES, [(0, 4), (7, 3)], [GOOD, BAD], FirstScoreGate())  # either direction matches
    assert keep.tolist() == [True] * 7 + [True, False]
    keep = closure_mask([*EDGES, (-1, -1)], [(4, 0), (3, 7)], [BAD, GOOD], FirstScoreGate())  # (-1, -1): a prior
    assert keep.tolist() == [True] * 7 + [False, True, True]


def test_scored_odometry_is_gated_too():
    assert closure_mask(EDGES, [(4, 0), (7, 3), (1, 2)], [GOOD, GOOD, BAD], FirstScoreGate())[1] == np.False_


@pytest.mark.parametrize(
    ("closures", "rows", "message"),
    [
        ([(4, 0), (7, 3), (2, 6)], [GOOD, GOOD, GOOD], r"1 edges of the score file are not in the graph: \(2, 6\)"),
        ([(4, 0)], [GOOD], r"1 loop closures of the graph have no score row: \(3, 7\)"),
        ([(4, 0), (7, 3), (0, 4)], [GOOD, GOOD, GOOD], r"edges listed twice in the score file: \(0, 4\)"),
        ([(4, 0), (7, 3)], [GOOD], r"scores must have shape \(E, K\) with E = 2"),
        ([(4, 0), (7, 3)], [[0.9, 0.1], [0.8, 0.1]], "calibrated at k=3"),
    ],
)
def test_errors_name_the_edges(closures, rows, message):
    with pytest.raises(ValueError, match=message):
        closure_mask(EDGES, closures, rows, FirstScoreGate())


# --- with GTSAM --------------------------------------------------------------------------------------------------


def _square(gtsam, *, drift=0.0):
    """Ground truth of the 8 poses, and a g2o text of the graph: exact measurements, drifting vertices."""
    truth = [gtsam.Pose2(*xy, np.pi / 2 * (i % 4)) for i, xy in enumerate([(0, 0), (2, 0), (2, 2), (0, 2)] * 2)]
    lines = [f"VERTEX_SE2 {i} {p.x() + drift * i} {p.y()} {p.theta()}" for i, p in enumerate(truth)]
    for a, b in EDGES:
        d = truth[a].between(truth[b])
        lines.append(f"EDGE_SE2 {a} {b} {d.x()} {d.y()} {d.theta()} 100 0 0 100 0 400")
    return truth, "\n".join(lines) + "\n"


@pytest.fixture
def gtsam():
    return pytest.importorskip("gtsam")


@pytest.fixture
def gate_file(tmp_path):
    """A gate calibrated on synthetic rows: correct answers stand out of their runners-up, wrong ones do not."""
    from vpr_uncertainty.calibration import calibrate_arrays

    rng = np.random.default_rng(0)
    correct = rng.random(300) < 0.7
    top = np.where(correct, rng.uniform(0.7, 0.9, 300), rng.uniform(0.3, 0.5, 300))
    scores = np.sort(np.c_[top, rng.uniform(0.2, 0.3, (300, 9))], axis=1)[:, ::-1]
    gate = calibrate_arrays(scores, correct, target_precision=0.9, delta=0.1)
    assert gate.accept(np.array([[0.8, *[0.25] * 9]]))[0] and not gate.accept(np.array([[0.4, *[0.3] * 9]]))[0]
    return gate.save(tmp_path / "gate.json")


GOOD10, BAD10 = [0.8, *[0.25] * 9], [0.4, *[0.3] * 9]


def test_command_filters_a_g2o_graph_and_round_trips(gtsam, gate_file, tmp_path, capsys):
    from vpr_uncertainty.cli import main
    from vpr_uncertainty.slam.pose_graph import read_graph

    _, text = _square(gtsam)
    (tmp_path / "graph.g2o").write_text(text)
    np.savez(tmp_path / "closures.npz", edges=[(0, 4), (3, 7)], scores=[GOOD10, BAD10])
    argv = ["loop-closures", str(tmp_path / "graph.g2o"), "--scores", str(tmp_path / "closures.npz")]
    assert main([*argv, "--gate", str(gate_file), "--out", str(tmp_path / "filtered.g2o")]) == 0
    out = capsys.readouterr().out  # the gate's rule in the user's terms (issue 45, item 4)
    assert "kept 1 of 2 scored loop closures and 7 odometry edges" in out and "; the gate: accept when " in out
    assert (tmp_path / "graph.g2o").read_text() == text  # the input is never modified
    graph, initial = read_graph(tmp_path / "filtered.g2o")
    assert sorted(tuple(graph.at(i).keys()) for i in range(graph.size())) == sorted(EDGES[:8])
    assert initial.size() == 8 and graph.at(7).measured().equals(
        read_graph(tmp_path / "graph.g2o")[0].at(7).measured(), 1e-9
    )

    np.savez(tmp_path / "short.npz", edges=[(0, 4), (3, 7)], scores=[GOOD10[:5], BAD10[:5]])
    assert (
        main(
            [
                *argv[:2],
                "--scores",
                str(tmp_path / "short.npz"),
                "--gate",
                str(gate_file),
                "--out",
                str(tmp_path / "x.g2o"),
            ]
        )
        == 2
    )
    assert "calibrated at k=10" in capsys.readouterr().err
    for extra in (["--robust", "gnc"], ["--verbose"], ["--optimize", "--inlier-probability", "1.5"]):  # ignored or NaN
        assert main([*argv, "--gate", str(gate_file), "--out", str(tmp_path / "y.g2o"), *extra]) == 2
        assert "need --optimize; --inlier-probability must lie in (0, 1)" in capsys.readouterr().err
        assert not (tmp_path / "y.g2o").exists()


def test_an_edge_to_an_undefined_vertex_is_an_error(gtsam, tmp_path):
    from vpr_uncertainty.slam.pose_graph import read_graph

    _, text = _square(gtsam)
    (tmp_path / "graph.g2o").write_text(text + "EDGE_SE2 2 9 0 0 0 100 0 0 100 0 400\n")
    with pytest.raises(ValueError, match=r"edges name vertices the file does not define: \[9\]"):
        read_graph(tmp_path / "graph.g2o")


def test_optimisation_reaches_the_ground_truth_and_gnc_rejects_an_outlier(gtsam, tmp_path, capfd):
    from vpr_uncertainty.slam.pose_graph import optimize, read_graph

    truth, text = _square(gtsam, drift=0.3)  # the vertices drift 0.3 m a pose; the measurements are exact
    (tmp_path / "graph.g2o").write_text(text)
    graph, initial = read_graph(tmp_path / "graph.g2o")

    def error(values):
        return max(np.linalg.norm(values.atPose2(i).translation() - truth[i].translation()) for i in range(8))

    assert error(initial) > 1 and error(optimize(graph, initial)) < 1e-6
    graph.add(gtsam.BetweenFactorPose2(1, 6, gtsam.Pose2(5, -3, 1), graph.at(0).noiseModel()))  # a wrong closure
    assert error(optimize(graph, initial)) > 0.1
    assert error(optimize(graph, initial, robust="gnc")) < 1e-6
    assert capfd.readouterr().out == ""
    # verbose: GTSAM prints GNC's λ and every LM iteration (its own C++ output, hence capfd), the result unchanged
    assert error(optimize(graph, initial, robust="gnc", verbose=True)) < 1e-6
    printed = capfd.readouterr().out
    assert "iter: 0" in printed and "lambda:" in printed and "cost_change" in printed and "total_time" in printed
    assert error(optimize(graph, initial, robust="cauchy")) < error(optimize(graph, initial))
    # the same GNC with Gauss-Newton inner solves; verbose shows GN's errors, not LM's lines
    assert error(optimize(graph, initial, robust="gnc-gn")) < 1e-6 and capfd.readouterr().out == ""
    assert error(optimize(graph, initial, robust="gnc-gn", verbose=True)) < 1e-6
    printed = capfd.readouterr().out
    assert "newError" in printed and "lambda:" in printed and "cost_change" not in printed


def test_reads_the_city10000_layout_and_3d_g2o(gtsam, tmp_path):
    from vpr_uncertainty.slam.pose_graph import optimize, read_graph

    city = "EDGE2 0 1 1 0 1 1.0 0.0 0.0\nEDGE2 1 1 2 0 2 1.0 0.0 1.5707963 7 7 7\nEDGE2 2 1 0 0 1 -1 1 -1.5707963\n"
    (tmp_path / "city.txt").write_text(city)
    graph, initial = read_graph(tmp_path / "city.txt")
    assert graph.size() == 3 and initial.atPose2(2).equals(gtsam.Pose2(2, 0, np.pi / 2), 1e-6)  # the first candidate
    (tmp_path / "bad.txt").write_text(city + "EDGE2 2 1 3 0 2 1.0 0.0\n")
    with pytest.raises(ValueError, match=r"bad.txt, line 4: EDGE2 i 1 j 0 N x y θ … \(N measurements\) needs 12"):
        read_graph(tmp_path / "bad.txt")

    info = " ".join(["100 0 0 0 0 0", "100 0 0 0 0", "100 0 0 0", "400 0 0", "400 0", "400"])
    se3 = "".join(f"EDGE_SE3:QUAT {i} {i + 1} 1 0 0 0 0 0 1 {info}\n" for i in range(3))
    (tmp_path / "line.g2o").write_text(se3 + f"EDGE_SE3:QUAT 0 3 3 0 0 0 0 0 1 {info}\n")
    graph, initial = read_graph(tmp_path / "line.g2o")
    assert graph.size() == 4 and np.allclose(optimize(graph, initial).atPose3(3).translation(), [3, 0, 0])
    (tmp_path / "cut.g2o").write_text(se3 + "EDGE_SE3:QUAT 0 3 3 0 0\n")
    with pytest.raises(ValueError, match=r"cut\.g2o, line 4: EDGE_SE3:QUAT needs 31 fields, got 6"):
        read_graph(tmp_path / "cut.g2o")


def test_conf_defaults():
    assert LoopClosureConf() == LoopClosureConf(optimize=False, robust="none", inlier_probability=0.99, verbose=False)


def test_without_gtsam_the_error_names_the_extra(monkeypatch):
    from vpr_uncertainty.slam.pose_graph import gtsam_module

    monkeypatch.setitem(__import__("sys").modules, "gtsam", None)
    with pytest.raises(ImportError, match=r"pip install 'vpr-uncertainty\[slam\]'"):
        gtsam_module()


def test_pose_rows_are_tum_rows(gtsam):
    """2-D and 3-D poses as ``id x y z qx qy qz qw`` (hand-computed: a quarter turn about z is (0, 0, √½, √½))."""
    from vpr_uncertainty.slam.pose_graph import pose_rows

    planar, spatial, half = gtsam.Values(), gtsam.Values(), np.sqrt(0.5)
    planar.insert(3, gtsam.Pose2(1.0, 2.0, np.pi / 2))
    spatial.insert(5, gtsam.Pose3(gtsam.Rot3.Rz(np.pi / 2), np.array([1.0, 2.0, 3.0])))
    np.testing.assert_allclose(pose_rows(planar), [[3, 1, 2, 0, 0, 0, half, half]], atol=1e-12)
    np.testing.assert_allclose(pose_rows(spatial), [[5, 1, 2, 3, 0, 0, half, half]], atol=1e-12)


# --- what the command shows, and graphs as real systems write them (issue 44, items 3 and 4) -----------------


def _square_files(gtsam, folder, *, ids=range(8), wrong=False):
    """The square walked twice with vertex ids ``ids``, a ground truth of them, and a score file of its closures
    (the first closure's row accepted, the second's rejected); ``wrong`` adds a wrong closure (1, 6) with a row the
    gate accepts."""
    truth, text = _square(gtsam, drift=0.3)
    rename = dict(enumerate(ids))
    lines = [" ".join([w[0], *(str(rename[int(x)]) for x in w[1:3 if w[0] == "EDGE_SE2" else 2]),
                       *w[3 if w[0] == "EDGE_SE2" else 2:]]) for w in map(str.split, text.splitlines())]  # fmt: skip
    if wrong:
        lines.append(f"EDGE_SE2 {rename[1]} {rename[6]} 5 -3 1 100 0 0 100 0 400")
    (folder / "g.g2o").write_text("\n".join(lines) + "\n")
    half = np.sqrt(0.5)
    rows = [
        [rename[i], p.x(), p.y(), 0, 0, 0, np.sin(p.theta() / 2), np.cos(p.theta() / 2)] for i, p in enumerate(truth)
    ]
    np.savetxt(folder / "truth.tum", rows)
    closures = [(rename[4], rename[0]), (rename[7], rename[3])] + ([(rename[1], rename[6])] if wrong else [])
    np.savez(folder / "c.npz", edges=closures, scores=[GOOD10, BAD10] + ([GOOD10] if wrong else []))
    return half


def test_decisions_ground_truth_and_plot(gtsam, gate_file, tmp_path, capsys):
    from vpr_uncertainty.cli import main

    _square_files(gtsam, tmp_path, wrong=True)
    argv = ["loop-closures", str(tmp_path / "g.g2o"), "--scores", str(tmp_path / "c.npz"), "--out",
            str(tmp_path / "o.g2o"), "--optimize", "--ground-truth", str(tmp_path / "truth.tum")]  # fmt: skip
    assert main([*argv, "--gate", str(gate_file), "--robust", "gnc", "--decisions", str(tmp_path / "d.csv"),
                 "--plot", str(tmp_path / "p.png")]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "kept 2 of 3 scored loop closures and 7 odometry edges" in out and "wrote" in out
    rmse = float(out.split("APE of the result ")[1].split(" m")[0])
    assert rmse < 1e-6  # GNC rejects the wrong closure the gate let through: the exact measurements are met
    rows = [line.split(",") for line in (tmp_path / "d.csv").read_text().splitlines()]
    assert rows[0] == ["row", "i", "j", "p_correct", "accepted", "weight"]
    assert [[*r[:3], r[4]] for r in rows[1:]] == [["0", "4", "0", "1"], ["1", "7", "3", "0"], ["2", "1", "6", "1"]]
    assert float(rows[1][5]) == pytest.approx(1.0) and rows[2][5] == "" and float(rows[3][5]) < 0.5  # GNC's weights
    assert 0 < float(rows[1][3]) <= 1 and (tmp_path / "p.png").stat().st_size > 10_000
    assert main([*argv, "--gate", "none"]) == 0  # the baseline: every closure kept, least squares pulled away
    out = capsys.readouterr().out
    assert "kept 3 of 3 scored loop closures" in out and float(out.split("APE of the result ")[1].split(" m")[0]) > 0.1


def test_keyframe_ids_that_skip_and_unscored_closures(gtsam, gate_file, tmp_path, capsys):
    from vpr_uncertainty.cli import main

    _square_files(gtsam, tmp_path, ids=range(0, 16, 2))  # keyframes 0, 2, 4, ...: every edge differs by 2
    base = ["loop-closures", str(tmp_path / "g.g2o"), "--gate", str(gate_file), "--out", str(tmp_path / "o.g2o")]
    assert main([*base, "--scores", str(tmp_path / "c.npz")]) == 2  # ids rule: the odometry looks like closures
    error = capsys.readouterr().err
    assert "loop closures of the graph have no score row" in error and "--unscored" in error and "--odometry" in error
    assert main([*base, "--scores", str(tmp_path / "c.npz"), "--odometry", "consecutive"]) == 0
    assert "kept 1 of 2 scored loop closures and 7 odometry edges" in capsys.readouterr().out
    np.savez(tmp_path / "one.npz", edges=[(8, 0)], scores=[BAD10])  # the closure (14, 6) has no row
    for policy, kept in (("keep", True), ("drop", False)):
        argv = [*base, "--scores", str(tmp_path / "one.npz"), "--odometry", "consecutive", "--unscored", policy]
        assert main(argv) == 0
        assert f"{'kept' if kept else 'dropped'} 1 loop closures without a score row" in capsys.readouterr().out
        assert ("EDGE_SE2 14 6" in (tmp_path / "o.g2o").read_text()) == kept
    assert main([*base, "--scores", str(tmp_path / "one.npz"), "--odometry", "tag:EDGE_X"]) == 2
    assert "the odometry rule (--odometry) must be ids, consecutive or tag:TAG" in capsys.readouterr().err


def test_a_ground_truth_of_other_ids_is_refused(gtsam, gate_file, tmp_path, capsys):
    from vpr_uncertainty.cli import main

    _square_files(gtsam, tmp_path)
    (tmp_path / "other.tum").write_text("100 0 0 0 0 0 0 1\n101 1 0 0 0 0 0 1\n")
    argv = ["loop-closures", str(tmp_path / "g.g2o"), "--scores", str(tmp_path / "c.npz"), "--gate", str(gate_file),
            "--out", str(tmp_path / "o.g2o"), "--optimize", "--ground-truth", str(tmp_path / "other.tum")]  # fmt: skip
    assert main(argv) == 2
    assert "the ground truth has no pose of 8 vertices of the graph, e.g. [0, 1, 2, 3, 4]" in capsys.readouterr().err
    (tmp_path / "bad.tum").write_text("0 0 0 0 0 0 1\n")
    assert main([*argv[:-1], str(tmp_path / "bad.tum")]) == 2
    assert "bad.tum: expected finite rows of 'id x y z qx qy qz qw'" in capsys.readouterr().err
    assert main([*argv[:-3], "--plot", str(tmp_path / "p.png")]) == 2  # a figure of a result needs --optimize
    assert "--plot need --optimize" in capsys.readouterr().err


def test_trajectory_error_is_the_benchmarks_ate(gtsam):
    """APE after SE(3) alignment: a trajectory shifted and turned as a whole has none; one pose 1 m off of n gives
    an RMSE of about √(1/n) m (the alignment spreads a little of it)."""
    from vpr_uncertainty.slam.pose_graph import trajectory_error

    rng = np.random.default_rng(0)
    truth = np.c_[np.arange(50), rng.normal(size=(50, 3)), np.zeros((50, 3)), np.ones(50)]
    moved = truth.copy()
    moved[:, 1:4] = truth[:, 1:4] @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]]).T + [5, -2, 1]
    moved[:, 4:] = [0, 0, np.sqrt(0.5), np.sqrt(0.5)]
    assert trajectory_error(moved, truth)["rmse"] < 1e-9
    off = truth.copy()
    off[7, 1] += 1.0
    assert trajectory_error(off, truth)["rmse"] == pytest.approx(np.sqrt(1 / 50), rel=0.05)


def test_the_online_graph_gates_each_closure_and_matches_the_batch(gtsam, gate_file):
    """The square walked twice, keyframe by keyframe: the gate keeps the closure with a good row and rejects the
    wrong one with a bad row; iSAM2's estimate equals LM's on the same factors (exact measurements: the truth)."""
    from vpr_uncertainty import Gate
    from vpr_uncertainty.slam.online import OnlineGraph
    from vpr_uncertainty.slam.pose_graph import optimize

    truth, _ = _square(gtsam)
    information = np.diag([100.0, 100.0, 400.0])
    online = OnlineGraph(Gate.load(gate_file))
    for j in range(1, 8):
        d = truth[j - 1].between(truth[j])
        online.add_odometry(j - 1, j, [d.x(), d.y(), d.theta()], information)
        if j == 4:
            assert online.add_closure(4, 0, [0.0, 0.0, 0.0], information, scores=GOOD10)
        if j == 6:
            assert not online.add_closure(1, 6, [5.0, -3.0, 1.0], information, scores=BAD10)
        online.update()
    estimate = online.estimate()
    assert [(i, j, accepted) for i, j, accepted, _ in online.decisions] == [(4, 0, True), (1, 6, False)]
    assert (
        0 < online.decisions[0][3] <= 1
        and max(np.linalg.norm(estimate.atPose2(i).translation() - truth[i].translation()) for i in range(8)) < 1e-6
    )
    batch = optimize(online.batch(), estimate)
    assert all(batch.atPose2(i).equals(estimate.atPose2(i), 1e-6) for i in range(8))
    with pytest.raises(ValueError, match="a 2-D pose is x y θ"):
        online.add_odometry(7, 8, [1.0, np.nan, 0.0], information)


def test_the_back_end_labels_its_closures(gtsam, gate_file, tmp_path, capsys):
    """label --by back-end: GNC on every scored closure keeps the two true ones (weight 1) and rejects the wrong
    one; the machine labels are of the closures file's pool, as calibrate reads it."""
    from vpr_uncertainty.calibration.labels_file import pool_fingerprint, read_machine_labels
    from vpr_uncertainty.cli import main
    from vpr_uncertainty.formats import read_pool

    _square_files(gtsam, tmp_path, wrong=True)
    argv = ["label", str(tmp_path / "c.npz"), "--by", "back-end", "--graph", str(tmp_path / "g.g2o")]
    assert main([*argv, "--out", str(tmp_path / "m.csv")]) == 0
    assert "2 of 3 queries labelled correct by back-end:robust=gnc" in capsys.readouterr().out
    pool = read_pool(tmp_path / "c.npz")
    assert pool.config["edges"] == [[4, 0], [7, 3], [1, 6]]
    labels = read_machine_labels(tmp_path / "m.csv", n_queries=3, pool=pool_fingerprint(pool.scores, 10))
    assert labels.correct.tolist() == [True, True, False] and labels.confidence[2] < 0.5
    assert main(["label", str(tmp_path / "c.npz"), "--by", "back-end", "--out", str(tmp_path / "n.csv")]) == 2
    assert "--by back-end needs --graph" in capsys.readouterr().err
