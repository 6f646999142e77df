"""Progress bars: on stderr, quiet when it is not a terminal unless asked (--progress), everywhere a stage is long."""

from __future__ import annotations

import io

import numpy as np
import pytest

from vpr_uncertainty.cli import main
from vpr_uncertainty.progress import progress_bar, progress_default, progress_enabled, progress_status


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_not_a_terminal_means_no_bar(capsys):
    assert list(progress_bar(range(3), desc="work")) == [0, 1, 2]
    assert capsys.readouterr().err == ""


def test_a_terminal_gets_a_bar(monkeypatch):
    terminal = _Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    assert progress_enabled() is True
    list(progress_bar(range(3), desc="work"))
    assert "work" in terminal.getvalue()


def test_the_call_and_the_process_default_decide_before_the_terminal(capsys, monkeypatch):
    with progress_default(True):
        list(progress_bar(range(2), desc="asked"))
        list(progress_bar(range(2), desc="refused", enabled=False))
    err = capsys.readouterr().err
    assert "asked" in err and "refused" not in err
    monkeypatch.setattr("sys.stderr", _Terminal())
    with progress_default(False):
        assert progress_enabled() is False
    assert progress_enabled() is True  # the default is restored after the block


def test_status_bar_of_a_long_call_shows_its_label(capsys):
    with progress_default(True), progress_status("train Faiss IVF4,Flat on 10 vectors", interval=0.01):
        pass
    assert "train Faiss IVF4,Flat" in capsys.readouterr().err


def test_faiss_training_is_not_silent(capsys):
    pytest.importorskip("faiss")
    from vpr_uncertainty.retrieval import search_descriptors

    rng = np.random.default_rng(0)
    database = rng.standard_normal((400, 16)).astype(np.float32)
    with progress_default(True):
        search_descriptors(database, database[:5], 3, index="IVF4,Flat")
    err = capsys.readouterr().err
    assert "train Faiss IVF4,Flat on 400 vectors" in err
    assert "retrieval" in err  # --progress shows even a short search


def test_geometric_verification_shows_its_stages(capsys, corridor_dir):
    pytest.importorskip("cv2")
    from vpr_uncertainty.geometric.verify import GeometricVerifier

    verifier = GeometricVerifier.from_preset("GV-SIFT", workers=1)
    paths = {name: corridor_dir / name for name in ("query/0000000.jpg", "ref/0000000.jpg", "ref/0000001.jpg")}
    pairs = [("query/0000000.jpg", "ref/0000000.jpg"), ("query/0000000.jpg", "ref/0000001.jpg")]
    with progress_default(True):
        verifier.verify_names(pairs, paths)
    err = capsys.readouterr().err
    assert "local features" in err and "matching" in err and "RANSAC" in err


def _paths(tmp_path):
    rng = np.random.default_rng(1)
    np.save(tmp_path / "db.npy", rng.standard_normal((50, 8)).astype(np.float32))
    np.save(tmp_path / "q.npy", rng.standard_normal((5, 8)).astype(np.float32))
    out = str(tmp_path / "r.npz")
    return ["--database", str(tmp_path / "db.npy"), "--queries", str(tmp_path / "q.npy"), "--out", out]


@pytest.mark.parametrize(
    ("before", "after", "shown"),
    [
        ([], [], False),
        (["--progress"], [], True),
        ([], ["--progress"], True),
        (["--progress"], ["--no-progress"], False),
    ],
)
def test_progress_flags_before_or_after_the_command(tmp_path, capsys, before, after, shown):
    pytest.importorskip("faiss")
    assert main([*before, "retrieve", *_paths(tmp_path), *after]) == 0
    assert ("retrieval" in capsys.readouterr().err) is shown


def test_every_command_takes_the_progress_flags():
    from vpr_uncertainty.cli import build_parser, command_names

    parser = build_parser()
    commands = next(action for action in parser._actions if action.dest == "command").choices
    for name in command_names():
        assert {"--progress", "--no-progress"} <= set(commands[name]._option_string_actions), name
