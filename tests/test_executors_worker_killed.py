"""A ``reproduce`` cell whose Ray worker process is killed mid-run: Ray reruns the task and the grid completes with
the numbers of the local run; a stopped grid resumes from the cells already written.

The worker is killed from outside, as an out-of-memory killer or a lost node would: the test watches ``/proc``
for the process whose title Ray sets to ``ray::_apply`` while it runs a task of
:class:`~vpr_uncertainty.executors.RayExecutor` and sends it SIGKILL. Real inputs: the corridor's NetVLAD and HOG
similarity matrices, with a bootstrap so that a cell runs long enough (about a second) to be caught.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

import pytest

from conftest import results_numbers
from vpr_uncertainty.executors import get_executor
from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_results

pytestmark = [
    pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file"),
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds the worker through /proc"),
]

TASK_TITLE = "ray::_apply"


@pytest.fixture
def grid(tmp_path: Path, corridor_dir: Path, corridor_matches_dir: Path) -> Path:
    inputs = ""
    for method in ("NetVLAD", "HOG"):
        shutil.copy(corridor_matches_dir / method / "precomputed_data_corrected.npy", tmp_path / f"{method}.npy")
        inputs += (
            f'[[inputs]]\nvpr_method = "{method}"\ndataset = "corridor"\nscores = "{method}.npy"\n'
            f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"\n'
        )
    path = tmp_path / "grid.toml"
    path.write_text('out = "out"\nmethods = ["RS", "SD", "SU", "BM"]\nbootstrap = 400\n' + inputs)
    return path


def _parent(pid: int) -> int:
    """The parent's pid (0 when the process is gone); /proc/PID/stat's 4th field, after the parenthesised name."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0
    return int(stat.rsplit(")", 1)[1].split()[1])


def _descends_from_this_process(pid: int) -> bool:
    """Whether ``pid`` runs under this test process (its own local cluster, not another test session's)."""
    while pid > 1:
        pid = _parent(pid)
        if pid == os.getpid():
            return True
    return False


def _task_processes() -> list[int]:
    """The pids of this test's Ray workers running a task of RayExecutor.map right now."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                title = (entry / "cmdline").read_bytes().split(b"\0")[0].decode(errors="replace").strip()
            except OSError:  # the process ended while we looked
                continue
            if title == TASK_TITLE and _descends_from_this_process(int(entry.name)):
                pids.append(int(entry.name))
    return pids


def _kill_first_task_worker(stop: threading.Event, killed: list[int], timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not stop.is_set() and time.monotonic() < deadline:
        pids = _task_processes()
        if pids:
            os.kill(pids[0], signal.SIGKILL)
            killed.append(pids[0])
            return
        time.sleep(0.01)


def _results(config_path: Path, out: str, executor=None):
    config = load_config(config_path, out=config_path.parent / out)
    cells = run_grid(config, progress=False, executor=executor)
    return json.loads(write_results(cells, config)["results_json"].read_text()), cells


def test_a_cell_whose_worker_is_killed_is_rerun_and_the_grid_equals_the_local_one(ray_cluster, grid):
    local, _ = _results(grid, "local")
    stop, killed = threading.Event(), []
    killer = threading.Thread(target=_kill_first_task_worker, args=(stop, killed), daemon=True)
    killer.start()
    try:
        with get_executor("ray", workers=2) as executor:
            remote, cells = _results(grid, "ray", executor)
    finally:
        stop.set()
        killer.join()
    assert killed, "no Ray task process was seen running: the cells finished before the killer looked"
    with pytest.raises(ProcessLookupError):
        os.kill(killed[0], 0)  # the worker really is gone
    assert results_numbers(remote) == results_numbers(local)
    assert [cell.vpr_method for cell in cells] == ["NetVLAD", "HOG"]
    assert len(list((grid.parent / "ray" / "cells").glob("*.json"))) == 2  # both cells written once


def test_a_stopped_grid_resumes_from_the_cells_already_written(ray_cluster, grid):
    """The driver stops after the first cell (as on Ctrl-C or a lost head node); the rerun computes only the rest."""
    config = load_config(grid, out=grid.parent / "ray")
    first_only = dataclasses.replace(config, inputs=config.inputs[:1])
    with get_executor("ray", workers=2) as executor:
        (first,) = run_grid(first_only, progress=False, executor=executor)
        cells = run_grid(config, progress=False, executor=executor)
    assert not first.cached
    assert [cell.cached for cell in cells] == [True, False]
    local, _ = _results(grid, "local")
    assert results_numbers(json.loads(write_results(cells, config)["results_json"].read_text())) == results_numbers(
        local
    )
