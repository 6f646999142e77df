"""The executors (executors.py) and the reproduce grid run as Ray tasks (study/runner.py run_grid).

One local Ray cluster (2 CPUs) for the module. Real inputs: the corridor's NetVLAD and HOG similarity matrices.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import results_numbers
from vpr_uncertainty.executors import LocalExecutor, get_executor, import_ray
from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_results

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")


def test_local_executor_maps_in_order():
    seen = []
    assert LocalExecutor().map(abs, [-3, 1, -2], on_result=seen.append) == [3, 1, 2]
    assert seen == [3, 1, 2]


@pytest.mark.parametrize(
    ("name", "options", "message"),
    [
        ("dask", {}, "executor must be one of local, ray"),
        ("local", {"address": "auto"}, "ray executor only"),
        ("local", {"workers": 0}, "workers must be a positive integer"),
        ("ray", {"gpus_per_worker": -1}, "gpus_per_worker must be a number >= 0"),
    ],
)
def test_bad_executor_options_are_refused(name, options, message):
    with pytest.raises(ValueError, match=message):
        get_executor(name, **options)


def test_missing_ray_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ImportError, match=r"vpr-uncertainty\[ray\]"):
        import_ray()


def test_ray_map_keeps_the_order_and_raises_the_task_error(ray_cluster):
    executor = get_executor("ray", workers=2)
    # builtins: the workers cannot import this test module (functions are pickled by reference)
    assert executor.map(abs, range(0, -7, -1)) == list(range(7))
    with pytest.raises(ValueError, match="invalid literal"):
        executor.map(int, ["1", "x"])
    executor.close()
    assert ray_cluster.is_initialized()  # a cluster it did not start is left running


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
    path.write_text('out = "out"\nmethods = ["RS", "SD", "SU", "BM"]\n' + inputs)
    return path


def _results(config_path: Path, out: str, executor=None) -> tuple[dict, list]:
    config = load_config(config_path, out=config_path.parent / out)
    cells = run_grid(config, progress=False, executor=executor)
    paths = write_results(cells, config)
    return json.loads(paths["results_json"].read_text()), cells


def test_grid_on_ray_equals_the_local_grid_and_shares_the_cell_cache(ray_cluster, grid):
    local, _ = _results(grid, "local")
    with get_executor("ray", workers=2) as executor:
        remote, cells = _results(grid, "ray", executor)
    assert results_numbers(remote) == results_numbers(local)
    assert [cell.vpr_method for cell in cells] == ["NetVLAD", "HOG"]
    assert not any(cell.cached for cell in cells)
    _, again = _results(grid, "ray")  # the local executor reads the cells the Ray tasks wrote
    assert all(cell.cached for cell in again)
    np.testing.assert_array_equal(again[0].indices, cells[0].indices)


def test_reproduce_command_on_ray_reads_the_cells_of_a_local_run(ray_cluster, grid, capsys):
    from vpr_uncertainty.cli import main

    assert main(["reproduce", str(grid), "--no-report"]) == 0
    assert main(["reproduce", str(grid), "--no-report", "--executor", "ray", "--workers", "2"]) == 0
    assert "2 of 2 cells read from the cache" in capsys.readouterr().out


def test_ray_only_options_are_refused_with_the_local_executor(grid, capsys):
    from vpr_uncertainty.cli import main

    assert main(["reproduce", str(grid), "--gpus-per-worker", "1"]) != 0
    assert "--gpus-per-worker: only with --executor ray" in capsys.readouterr().err


def _closed_port() -> int:
    """A loopback port with nothing listening (bound, then released)."""
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_an_address_where_nothing_listens_fails_within_the_timeout():
    import time

    from vpr_uncertainty.executors import RayExecutor, wait_for_address

    port = _closed_port()
    started = time.monotonic()
    with pytest.raises(ConnectionError, match=f"no Ray cluster answers at 127.0.0.1:{port} within 1 s"):
        RayExecutor(address=f"127.0.0.1:{port}", connect_timeout=1.0)
    assert time.monotonic() - started < 10  # Ray alone waited for more than 5 minutes
    with pytest.raises(ConnectionError, match=r"ray://127\.0\.0\.1"):
        wait_for_address(f"ray://127.0.0.1:{port}", 0.5)
    wait_for_address("auto", 0.5)  # no port to probe: Ray answers "auto" itself
    with pytest.raises(ValueError, match="connect_timeout must be a positive number"):
        RayExecutor(address="auto", connect_timeout=0)


def test_reproduce_with_an_unreachable_address_is_one_line(grid, capsys):
    from vpr_uncertainty.cli import main

    port = _closed_port()
    argv = ["reproduce", str(grid), "--executor", "ray", "--address", f"127.0.0.1:{port}", "--connect-timeout", "1"]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"no Ray cluster answers at 127.0.0.1:{port} within 1 s" in err[0]
    with pytest.raises(SystemExit) as refused:  # argparse: usage error
        main(["reproduce", str(grid), "--executor", "ray", "--connect-timeout", "0"])
    assert refused.value.code == 2 and "must be a number of seconds > 0" in capsys.readouterr().err


class _StallingRay:
    """A stand-in for the ray module whose init never returns (as when a worker dies during start-up)."""

    def __init__(self, error: type[BaseException] | None = None) -> None:
        self.error, self.shutdowns = error, 0

    def init(self, **options):
        import time

        if self.error is not None:
            raise self.error()
        while True:
            time.sleep(0.05)

    def is_initialized(self) -> bool:
        return True

    def shutdown(self) -> None:
        self.shutdowns += 1


def test_ray_start_up_is_bounded_and_leaves_nothing_behind():
    import time

    from vpr_uncertainty.executors import start_ray

    stalling = _StallingRay()
    started = time.monotonic()
    with pytest.raises(TimeoutError, match=r"Ray did not start within 0\.5 s"):
        start_ray(stalling, {"address": "local"}, 0.5)
    assert time.monotonic() - started < 5 and stalling.shutdowns == 1
    interrupted = _StallingRay(KeyboardInterrupt)  # Ctrl-C during start-up: honoured, and cleaned up
    with pytest.raises(KeyboardInterrupt):
        start_ray(interrupted, {"address": "local"}, 30)
    assert interrupted.shutdowns == 1
    import signal

    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)  # no alarm left armed


def test_the_command_line_unwinds_on_sigterm(monkeypatch):
    import signal

    from vpr_uncertainty import cli

    seen = {}

    def handler(args):
        seen["handler"] = signal.getsignal(signal.SIGTERM)
        return 0

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda plugins=(), command=None: parser)
    monkeypatch.setattr(parser, "parse_args", lambda argv: argparse.Namespace(command="x", handler=handler))
    before = signal.getsignal(signal.SIGTERM)
    assert cli.main(["x"]) == 0
    assert seen["handler"] is cli._terminated and signal.getsignal(signal.SIGTERM) == before
    with pytest.raises(SystemExit) as stopped:
        cli._terminated(signal.SIGTERM, None)
    assert stopped.value.code == 128 + signal.SIGTERM


def test_sigterm_shuts_down_the_cluster_the_executor_started(tmp_path):
    """SIGTERM left Ray's processes running; now the executor's context closes and they stop."""
    import signal
    import subprocess
    import sys
    import time

    pytest.importorskip("ray")
    script = tmp_path / "hold.py"
    script.write_text(
        "import signal, time\n"
        "import ray\n"
        "from vpr_uncertainty import cli\n"
        "from vpr_uncertainty.executors import RayExecutor\n"
        "signal.signal(signal.SIGTERM, cli._terminated)\n"
        "with RayExecutor(workers=1):\n"
        "    print(ray._private.worker._global_node.get_session_dir_path(), flush=True)\n"
        "    time.sleep(300)\n"
    )
    process = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        session = process.stdout.readline().strip()
        assert session, "the cluster did not start"
        assert _processes_of(session), "no Ray process names the session"
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=60) == 128 + signal.SIGTERM
        deadline = time.monotonic() + 30
        while _processes_of(session) and time.monotonic() < deadline:
            time.sleep(0.5)
        assert not _processes_of(session)
    finally:
        if process.poll() is None:
            process.kill()


def _processes_of(session: str) -> list[int]:
    """PIDs of the processes whose command line names a Ray session folder."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if session.encode() in (entry / "cmdline").read_bytes():
                    found.append(int(entry.name))
            except OSError:
                continue
    return found


def _descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (from /proc's parent links)."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parents[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
    found, frontier = [], [pid]
    while frontier:
        children = [child for child, parent in parents.items() if parent in frontier]
        found += children
        frontier = children
    return found


def test_workers_killed_while_the_local_cluster_starts_give_a_timeout_not_a_hang():
    """Real Ray: every worker SIGKILLed as it appears during start-up hung ray.init for up to 13 minutes."""
    import os
    import signal
    import subprocess
    import sys
    import time

    pytest.importorskip("ray")
    code = (
        "from vpr_uncertainty.executors import RayExecutor\n"
        "try:\n"
        "    with RayExecutor(workers=1, start_timeout=4) as executor:\n"
        "        print('started', executor.map(abs, [-1]), flush=True)\n"
        "except TimeoutError as error:\n"
        "    print('timeout', error, flush=True)\n"
    )
    process = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True
    )
    started, killed = time.monotonic(), 0
    try:
        while process.poll() is None and time.monotonic() - started < 120:
            for pid in _descendants(process.pid):
                try:
                    command = Path(f"/proc/{pid}/cmdline").read_bytes()
                except OSError:
                    continue
                if b"default_worker.py" in command or command.startswith(b"ray::"):
                    with contextlib.suppress(OSError):
                        os.kill(pid, signal.SIGKILL)
                        killed += 1
            time.sleep(0.05)
        assert process.poll() is not None, "still starting after 120 s"
        output = process.stdout.read()
        # a timeout (what start-up with its workers killed gives here), or a start that recovered: never a hang
        assert "timeout Ray did not start within 4 s" in output or output.startswith("started"), (killed, output)
        assert not [pid for pid in _descendants(process.pid)]  # nothing left running
    finally:
        if process.poll() is None:
            process.kill()


_RAY_IN_A_CHILD = """
import sys
from vpr_uncertainty.executors import RayExecutor
log_file = sys.argv[1] or None
with RayExecutor(workers=1, log_file=log_file) as executor:
    print(executor.map(abs, [-3]))
import logging
print(all(not isinstance(h, logging.FileHandler) for h in logging.getLogger("ray").handlers))
"""


@pytest.mark.parametrize("quiet", [True, False], ids=["log_file", "ray_default"])
def test_ray_log_lines_go_to_the_log_file_not_the_terminal(tmp_path, quiet):
    """Ray's start-up notice (and its token-auth warning, where Ray gives one) reaches stderr only without a log
    file; with one, they are in the file, and Ray's own handlers are back once the executor closes."""
    import os
    import subprocess

    pytest.importorskip("ray")
    log_file = tmp_path / "logs" / "ray.log"
    environment = {key: value for key, value in os.environ.items() if key != "RAY_AUTH_MODE"}
    done = subprocess.run(
        [sys.executable, "-c", _RAY_IN_A_CHILD, str(log_file) if quiet else ""],
        capture_output=True,
        text=True,
        env=environment,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["[3]", "True"]
    if quiet:
        assert "Ray" not in done.stderr, done.stderr
        assert "Started a local Ray instance" in log_file.read_text()
    else:
        assert "Started a local Ray instance" in done.stderr and not log_file.exists()


def test_verbose_keeps_ray_logs_on_the_terminal(monkeypatch, tmp_path):
    from vpr_uncertainty.pipeline.options import add_executor_options, executor_options

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    parser = argparse.ArgumentParser()
    add_executor_options(parser)
    quiet = executor_options(parser.parse_args(["--executor", "ray"]))
    assert quiet["log_file"] == tmp_path / "vpr-uncertainty" / "logs" / "ray.log"
    assert executor_options(parser.parse_args(["--executor", "ray", "--verbose"]))["log_file"] is None
