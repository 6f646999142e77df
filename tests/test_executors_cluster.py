"""The Ray executor on a two-node cluster started on this machine (``ray start --head`` plus ``ray start --address``).

Both nodes (1 CPU each) are started by the module fixture, as processes of their own sessions, and stopped by it
(their process groups are terminated; ``ray stop`` would stop every Ray process on the machine). The reproduce grid
on the corridor's NetVLAD and HOG matrices, run across both nodes, gives the local ``results.json``.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import results_numbers
from test_executors import _results, grid  # noqa: F401  (the grid fixture)
from vpr_uncertainty.executors import get_executor

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")

PORT = 26479


def _start(*arguments: str, log: Path) -> subprocess.Popen:
    command = [str(Path(sys.executable).with_name("ray")), "start", *arguments, "--num-cpus=1", "--block"]
    with open(log, "w") as file:
        return subprocess.Popen(command, stdout=file, stderr=subprocess.STDOUT, start_new_session=True)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    if shutil.which("ray", path=str(Path(sys.executable).parent)) is None:
        pytest.skip("the ray command is not installed next to this Python")
    logs = tmp_path_factory.mktemp("ray_logs")
    # with Ray 2.60's token authentication this driver was refused (InvalidAuthToken) by nodes of `ray start`;
    # the other Ray test modules use the same mode (mixing modes in one process breaks ray.init)
    os.environ["RAY_AUTH_MODE"] = "disabled"
    processes = [
        _start("--head", f"--port={PORT}", "--include-dashboard=false", "--disable-usage-stats", log=logs / "head")
    ]
    try:
        for _ in range(60):
            try:
                ray.init(address=f"127.0.0.1:{PORT}", log_to_driver=False)
                break
            except ConnectionError:
                time.sleep(1)
        address = f"{ray.util.get_node_ip_address()}:{PORT}"
        processes.append(_start(f"--address={address}", "--disable-usage-stats", log=logs / "worker"))
        for _ in range(60):
            if sum(node["Alive"] for node in ray.nodes()) == 2:
                break
            time.sleep(1)
        assert sum(node["Alive"] for node in ray.nodes()) == 2, (logs / "worker").read_text()[-2000:]
        ray.shutdown()
        yield address
    finally:
        ray.shutdown()
        for process in processes[::-1]:
            os.killpg(process.pid, signal.SIGTERM)
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
        Path("/tmp/ray/ray_current_cluster").unlink(missing_ok=True)  # the address file this head wrote


def test_grid_across_two_nodes_equals_the_local_grid(cluster, grid):  # noqa: F811
    local, _ = _results(grid, "local")
    with get_executor("ray", address=cluster, workers=2) as executor:
        nodes = {node["NodeID"] for node in executor.ray.nodes() if node["Alive"]}
        remote, cells = _results(grid, "ray", executor)
    assert len(nodes) == 2
    assert results_numbers(remote) == results_numbers(local)
    assert not any(cell.cached for cell in cells)
