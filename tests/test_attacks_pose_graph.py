"""``loop-closures`` attacked as issue 42 lists (rows 1–7 and its clear errors): every input byte-identical after
any run, an output whole or the previous one kept, every number as the user wrote it, every line the toolkit does
not read passed through, and bad files refused naming the line. Each attack failed on 4e35eed (the refusal of a
line with a wrong number of fields held already)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from test_loop_closures import BAD10, GOOD10, gate_file  # noqa: F401 (a fixture)
from vpr_uncertainty.cli import main

pytest.importorskip("gtsam")

CLI = [sys.executable, "-m", "vpr_uncertainty.cli"]


def _graph(n: int = 20, *, x0: float = 0.0) -> list[str]:
    """A corridor of ``n`` poses 1 m apart and three closures, (0, 10), (5, 15), (2, 18): the issue's 20-pose graph."""
    lines = [f"VERTEX_SE2 {i} {x0 + i} 0 0" for i in range(n)]
    lines += [f"EDGE_SE2 {i} {i + 1} 1 0 0 100 0 0 100 0 400" for i in range(n - 1)]
    lines += [f"EDGE_SE2 {a} {b} {b - a} 0 0 100 0 0 100 0 400" for a, b in [(0, 10), (5, 15), (2, 18)]]
    return [line + "\n" for line in lines]


@pytest.fixture
def case(tmp_path, gate_file):  # noqa: F811
    """The issue's files: g.g2o, scores.npz (the closure (5, 15) rejected) and gate.json; their bytes before."""
    (tmp_path / "g.g2o").write_text("".join(_graph()))
    np.savez(tmp_path / "scores.npz", edges=[(0, 10), (5, 15), (2, 18)], scores=[GOOD10, BAD10, GOOD10])
    return tmp_path, {path: path.read_bytes() for path in tmp_path.iterdir()}


def _lc(folder: Path, graph: str, *extra: str) -> list[str]:
    return ["loop-closures", str(folder / graph), "--scores", str(folder / "scores.npz"), "--gate",
            str(folder / "gate.json"), *extra]  # fmt: skip


def _unchanged(files: dict[Path, bytes]) -> bool:
    return all(path.read_bytes() == data for path, data in files.items())


def test_a_write_past_the_file_size_limit_keeps_the_previous_output(case):  # row 1
    folder, files = case
    assert main(_lc(folder, "g.g2o", "--out", str(folder / "prev.g2o"))) == 0
    previous = (folder / "prev.g2o").read_bytes()
    (folder / "big.g2o").write_text("".join(_graph(3000)))
    command = " ".join(f"'{w}'" for w in [*CLI, *_lc(folder, "big.g2o", "--out", str(folder / "prev.g2o"))])
    result = subprocess.run(["bash", "-c", f"ulimit -f 16; exec {command}"], capture_output=True, text=True)
    assert result.returncode == 1, result.stderr
    assert "File too large (the file as it was is kept)" in result.stderr and "prev.g2o" in result.stderr
    assert (folder / "prev.g2o").read_bytes() == previous and _unchanged(files)
    assert sorted(p.name for p in folder.iterdir()) == sorted([*(p.name for p in files), "big.g2o", "prev.g2o"])


def test_two_runs_into_one_output_each_write_a_whole_graph(case):  # row 2
    folder, _ = case
    for name, x0 in (("a.g2o", 0.0), ("b.g2o", 1000.0)):
        (folder / name).write_text("".join(_graph(30000, x0=x0)))
    runs = [subprocess.Popen([*CLI, *_lc(folder, name, "--out", str(folder / "out.g2o"))], stderr=subprocess.PIPE)
            for name in ("a.g2o", "b.g2o")]  # fmt: skip
    assert [run.wait(timeout=120) for run in runs] == [0, 0], [run.stderr.read() for run in runs]
    rejected = "EDGE_SE2 5 15 10 0 0 100 0 0 100 0 400\n"
    assert (folder / "out.g2o").read_text() in {
        (folder / n).read_text().replace(rejected, "") for n in ("a.g2o", "b.g2o")
    }


@pytest.mark.parametrize(
    ("inputs", "extra", "refused"),
    [
        ({"graph": "traj.tum"}, ["--out", "traj.g2o", "--optimize"], "the poses file of --optimize traj.tum is GRAPH"),
        ({"scores": "sc.tum"}, ["--out", "sc.g2o", "--optimize"], "the poses file of --optimize sc.tum is --scores"),
        ({}, ["--out", "gate.json"], "--out gate.json is --gate"),
        ({"link": "link.g2o"}, ["--out", "link.g2o"], "--out link.g2o is GRAPH"),  # a symbolic link to the graph
        ({"hard": "hard.g2o"}, ["--out", "hard.g2o"], "--out hard.g2o is GRAPH"),  # a hard link to the graph
    ],
)
def test_an_output_that_is_an_input_is_refused(case, monkeypatch, capsys, inputs, extra, refused):  # row 3
    folder, files = case
    monkeypatch.chdir(folder)
    graph = inputs.get("graph", "g.g2o")
    if "graph" in inputs:
        shutil.copy(folder / "g.g2o", folder / graph)
    if "scores" in inputs:
        shutil.copy(folder / "scores.npz", folder / inputs["scores"])
    if "link" in inputs:
        (folder / "link.g2o").symlink_to(folder / "g.g2o")
    if "hard" in inputs:
        (folder / "hard.g2o").hardlink_to(folder / "g.g2o")
    files = {path: path.read_bytes() for path in folder.iterdir()}
    argv = ["loop-closures", graph, "--scores", inputs.get("scores", "scores.npz"), "--gate", "gate.json", *extra]
    assert main(argv) == 2
    error = capsys.readouterr().err
    assert refused in error and "never overwrites: name another file" in error and error.count("\n") == 1
    assert _unchanged(files) and sorted(folder.iterdir()) == sorted(files)


def test_an_input_named_like_a_temporary_file_survives(case, capsys):  # row 3: the fixed name "OUT.partial"
    folder, files = case
    shutil.copy(folder / "g.g2o", folder / "res.g2o.partial")
    assert main(_lc(folder, "res.g2o.partial", "--out", str(folder / "res.g2o"), "--optimize")) == 0
    assert (folder / "res.g2o.partial").read_bytes() == files[folder / "g.g2o"] and _unchanged(files)


@pytest.mark.parametrize(
    ("information", "shown"),
    [("-500 0 0 500 0 500", "-500 0 0 500 0 500"), ("1 5 0 1 0 1", "1 5 0 1 0 1"), ("0 0 0 0 0 0", "0 0 0 0 0 0")],
)
def test_an_information_matrix_that_is_not_positive_definite_is_refused(case, capsys, information, shown):  # row 4
    folder, files = case
    text = "".join(_graph()).replace("EDGE_SE2 0 10 10 0 0 100 0 0 100 0 400", f"EDGE_SE2 0 10 10 0 0 {information}")
    (folder / "bad.g2o").write_text(text)
    assert main(_lc(folder, "bad.g2o", "--out", str(folder / "o.g2o"), "--optimize")) == 2
    error = capsys.readouterr().err
    assert (
        f"bad.g2o, line 40: the information matrix of the edge is not positive definite (upper triangle {shown})"
        in (error)
    )
    assert not (folder / "o.g2o").exists() and _unchanged(files)


def test_lines_the_reader_does_not_know_are_passed_through(case, capsys):  # row 5
    folder, _ = case
    extra = ["VERTEX_XY 100 1 2\n", "EDGE_SE2_XY 3 100 1 1 10 0 10\n", "FIX 0\n", "# a comment with EDGE3 in it\n"]
    (folder / "u.g2o").write_text("".join(_graph() + extra))
    assert main(_lc(folder, "u.g2o", "--out", str(folder / "o.g2o"), "--optimize")) == 0
    out = capsys.readouterr().out
    assert "kept 2 of 3 scored loop closures and 19 odometry edges" in out
    assert "3 lines of tags not read (VERTEX_XY ×1, EDGE_SE2_XY ×1, FIX ×1) are copied to" in out
    rejected = "EDGE_SE2 5 15 10 0 0 100 0 0 100 0 400\n"
    assert (folder / "o.g2o").read_text() == (folder / "u.g2o").read_text().replace(rejected, "")
    assert len(np.loadtxt(folder / "o.tum")) == 20  # 2-D, despite the "3" in a tag and a comment


def test_a_file_mixing_2d_and_3d_tags_is_refused(case, capsys):  # row 5
    folder, _ = case
    (folder / "m.g2o").write_text("".join(_graph()) + "VERTEX_SE3:QUAT 50 0 0 0 0 0 0 1\n")
    assert main(_lc(folder, "m.g2o", "--out", str(folder / "o.g2o"))) == 2
    assert "m.g2o: line 1 is 2-D (VERTEX_SE2), line 43 is 3-D (VERTEX_SE3:QUAT)" in capsys.readouterr().err


def test_numbers_keep_every_digit(case, capsys):  # row 6
    folder, _ = case
    text = "".join(_graph(x0=512345.678901)).replace("EDGE_SE2 0 1 1 0 0", "EDGE_SE2 0 1 1.0000000001 0 0")
    (folder / "utm.g2o").write_text(text.replace(" 0 0\n", " 5412345.123456 0\n", 20))
    assert main(_lc(folder, "utm.g2o", "--out", str(folder / "o.g2o"), "--optimize")) == 0
    assert "VERTEX_SE2 0 512345.678901 5412345.123456 0\n" in (folder / "o.g2o").read_text()
    assert "EDGE_SE2 0 1 1.0000000001 0 0 " in (folder / "o.g2o").read_text()
    poses = np.loadtxt(folder / "o.tum")  # the solution is the vertices, to far below the 6 digits of %g
    np.testing.assert_allclose(poses[:, 1:3], np.c_[512345.678901 + np.arange(20), np.full(20, 5412345.123456)],
                               rtol=0, atol=1e-6)  # fmt: skip


def test_toro_information_is_read_as_information(case, capsys):  # row 7
    """Two measurements of pose 1 from pose 0, x = 1 with information 100 and x = 2 with information 1: the optimum
    is their information-weighted mean, 102 / 101 (hand-computed); read as covariances, it would be 2.01 / 1.01."""
    folder, _ = case
    toro = "VERTEX2 0 0 0 0\nVERTEX2 1 1.5 0 0\nEDGE2 0 1 1 0 0 100 0 100 100 0 0\nEDGE2 0 1 2 0 0 1 0 100 100 0 0\n"
    (folder / "t.graph").write_text(toro)
    np.savez(folder / "none.npz", edges=np.empty((0, 2), int), scores=np.empty((0, 10)))
    argv = ["loop-closures", str(folder / "t.graph"), "--scores", str(folder / "none.npz"), "--gate",
            str(folder / "gate.json"), "--out", str(folder / "o.graph"), "--optimize"]  # fmt: skip
    assert main(argv) == 0
    assert np.loadtxt(folder / "o.tum")[1, 1] == pytest.approx(102 / 101, abs=1e-9)
    assert (folder / "o.graph").read_text() == toro


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            ("VERTEX_SE2 3 3.0 0 0", "VERTEX_SE2 -3 3.0 0 0"),
            "line 4: VERTEX_SE2 ids must be integers in [0, 2^63), got '-3'",
        ),
        (("EDGE_SE2 0 10 10", "EDGE_SE2 0 10.7 10"), "line 40: EDGE_SE2 ids must be integers in [0, 2^63), got '10.7'"),
        (("EDGE_SE2 0 10 10 0", "EDGE_SE2 0 10 nan 0"), "line 40: expected a finite number, got 'nan'"),
        (("EDGE_SE2 0 1 1 0 0", "EDGE_SE2 0 1 1 0 0 inf"), "line 21: EDGE_SE2 needs 12 fields, got 13"),
    ],
)
def test_bad_numbers_are_refused_naming_the_line(case, capsys, edit, message):
    folder, files = case
    (folder / "bad.g2o").write_text("".join(_graph()).replace(*edit, 1))
    assert main(_lc(folder, "bad.g2o", "--out", str(folder / "o.g2o"))) == 2
    error = capsys.readouterr().err
    assert f"bad.g2o, {message}" in error and error.count("\n") == 1
    assert not (folder / "o.g2o").exists() and _unchanged(files)


def test_a_toro_file_without_vertices_and_a_new_folder(case, capsys):
    """No VERTEX lines: the odometry places the poses (GTSAM's reader said "key already exists"); ``--out`` in a folder
    that does not exist yet is created (the error named the internal ``.partial`` file)."""
    folder, _ = case
    (folder / "t.graph").write_text("".join(f"EDGE2 {i} {i + 1} 1 0 0 100 0 100 400 0 0\n" for i in range(19)))
    np.savez(folder / "none.npz", edges=np.empty((0, 2), int), scores=np.empty((0, 10)))
    argv = ["loop-closures", str(folder / "t.graph"), "--scores", str(folder / "none.npz"), "--gate",
            str(folder / "gate.json"), "--out", str(folder / "new" / "o.graph"), "--optimize"]  # fmt: skip
    assert main(argv) == 0
    np.testing.assert_allclose(np.loadtxt(folder / "new" / "o.tum")[:, 1], np.arange(20), atol=1e-9)


def test_counts_when_a_closure_is_in_the_graph_twice(case, capsys):
    folder, _ = case
    (folder / "d.g2o").write_text("".join(_graph()) + "EDGE_SE2 15 5 -10 0 0 100 0 0 100 0 400\n")
    assert main(_lc(folder, "d.g2o", "--out", str(folder / "o.g2o"))) == 0
    assert "kept 2 of 3 scored loop closures and 19 odometry edges" in capsys.readouterr().out
    assert "EDGE_SE2 15 5" not in (folder / "o.g2o").read_text()  # both lines of the rejected closure dropped


def test_a_long_chain_optimises_whatever_the_stack(case):
    """GTSAM's elimination recurses as deep as the chain is long: 100,000 poses overflowed the default 8 MiB stack
    (exit 139); here 20,000 poses under a 1 MiB stack, the same overflow at a fifth of the cost."""
    folder, _ = case
    rng = np.random.default_rng(0)
    n = 20000
    lines = [f"VERTEX_SE2 {i} {i + rng.normal():.6f} {rng.normal():.6f} 0\n" for i in range(n)]
    lines += [f"EDGE_SE2 {i} {i + 1} 1 0 0 100 0 0 100 0 400\n" for i in range(n - 1)]
    (folder / "chain.g2o").write_text("".join(lines))
    np.savez(folder / "none.npz", edges=np.empty((0, 2), int), scores=np.empty((0, 10)))
    argv = [*CLI, "loop-closures", str(folder / "chain.g2o"), "--scores", str(folder / "none.npz"), "--gate",
            str(folder / "gate.json"), "--out", str(folder / "o.g2o"), "--optimize"]  # fmt: skip
    command = " ".join(f"'{w}'" for w in argv)
    result = subprocess.run(["bash", "-c", f"ulimit -s 1024; exec {command}"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert len(np.loadtxt(folder / "o.tum")) == n


@pytest.mark.parametrize(
    ("edges", "message"),
    [
        ([(0, 10.7), (5, 15), (2, 18)], "edges, row 0: vertex ids must be integers >= 0, got [0.0, 10.7]"),  # truncated
        ([(0, -10), (5, 15), (2, 18)], "edges, row 0: vertex ids must be integers >= 0, got [0, -10]"),
        ([(0, 10, 1), (5, 15, 1), (2, 18, 1)], "expected edges (E, 2) and scores (E, K) of numbers, got (3, 3)"),
    ],
)
def test_score_file_edges_that_are_not_vertex_ids_are_refused(case, capsys, edges, message):
    folder, _ = case
    np.savez(folder / "bad.npz", edges=edges, scores=[GOOD10, BAD10, GOOD10])
    argv = ["loop-closures", str(folder / "g.g2o"), "--scores", str(folder / "bad.npz"), "--gate",
            str(folder / "gate.json"), "--out", str(folder / "o.g2o")]  # fmt: skip
    assert main(argv) == 2
    assert f"bad.npz: {message}" in capsys.readouterr().err and not (folder / "o.g2o").exists()
