"""Issue 28, rows 12 and 13 and an unclear message, tried as a user would: ``--executor ray --address`` at a port
where something else listens; a ``--plugin`` that overrides SU or adds a method, under ``--executor ray``; a plugin
that the workers cannot import, or import as other code; an installed plugin that fails to load.

Before: a silent listener or an HTTP server at ``--address`` hung ``reproduce`` for minutes whatever
``--connect-timeout`` said (Ray's C++ waits for the GCS, printing "Failed to connect to GCS" lines); the workers
used the built-in SU and did not know a plugin's method ("unknown uncertainty method 'ENT'"); a plugin file removed
or edited after the run loaded it went unnoticed; a broken entry point printed a raw Python warning.
"""

from __future__ import annotations

import http.server
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from conftest import assert_close

ray = pytest.importorskip("ray")

from vpr_uncertainty import plugins  # noqa: E402
from vpr_uncertainty.cli import main  # noqa: E402
from vpr_uncertainty.executors import wait_for_address  # noqa: E402
from vpr_uncertainty.methods import METHODS  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")

SRC = str(Path(__file__).resolve().parents[1] / "src")
TIMEOUT = 2


def _grid(folder: Path, corridor_dir: Path, corridor_matches_dir: Path, methods: list[str]) -> Path:
    """A one-cell study (NetVLAD on the corridor) with ``methods``."""
    matrix = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "grid.toml").write_text(
        f'out = "out"\nmethods = {json.dumps(methods)}\nalphas = []\nks = []\n[[inputs]]\nvpr_method = "NetVLAD"\n'
        f'dataset = "corridor"\nscores = "{matrix}"\nground_truth = "{corridor_dir / "ground_truth_new.npy"}"\n'
    )
    return folder / "grid.toml"


def _auc_pr(grid: Path) -> dict[str, float]:
    (cell,) = json.loads((grid.parent / "out" / "results.json").read_text())["cells"]
    return {method: numbers["auc_pr"] for method, numbers in cell["methods"].items()}


def _command(
    *argv: str, timeout: float, env: dict[str, str] | None = None
) -> tuple[subprocess.CompletedProcess, float]:
    """``vpr-uncertainty argv`` in a child process (Ray's C++ wait cannot be interrupted in this one); its result
    and wall-clock seconds. A command still running after ``timeout`` seconds fails the test."""
    environment = {**os.environ, "PYTHONPATH": SRC, "RAY_AUTH_MODE": "disabled", **(env or {})}
    started = time.monotonic()
    process = subprocess.Popen(
        [sys.executable, "-m", "vpr_uncertainty.cli", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=environment,
        start_new_session=True,
    )
    try:
        out, err = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.communicate()
        pytest.fail(f"vpr-uncertainty {' '.join(argv)} still running after {timeout} s")
    return subprocess.CompletedProcess(argv, process.returncode, out, err), time.monotonic() - started


def _silent_listener() -> tuple[int, Callable[[], None]]:
    """A port where connections are accepted and never answered."""
    server = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []

    def accept() -> None:
        while True:
            try:
                held.append(server.accept()[0])
            except OSError:
                return

    threading.Thread(target=accept, daemon=True).start()

    def close() -> None:
        server.close()
        for connection in held:
            connection.close()

    return server.getsockname()[1], close


def _http_server() -> tuple[int, Callable[[], None]]:
    """A port where an HTTP server answers (as Ray's dashboard does at 8265)."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    server.RequestHandlerClass.log_message = lambda *args: None
    threading.Thread(target=server.serve_forever, daemon=True).start()

    def close() -> None:
        server.shutdown()
        server.server_close()

    return server.server_address[1], close


@pytest.mark.parametrize(
    ("listener", "what"),
    [(_silent_listener, "accepts connections there but does not answer"), (_http_server, "an HTTP server answers")],
    ids=["silent", "http"],
)
def test_an_address_where_something_else_listens_ends_within_the_connect_timeout(
    listener, what, tmp_path, corridor_dir, corridor_matches_dir
):
    """Before: > 200 s (silent listener), 580 s (HTTP server), with Ray's C++ lines on the terminal."""
    grid = _grid(tmp_path, corridor_dir, corridor_matches_dir, ["SU"])
    port, close = listener()
    try:
        argv = ["reproduce", str(grid), "--no-report", "--executor", "ray", "--address", f"127.0.0.1:{port}"]
        done, seconds = _command(*argv, "--connect-timeout", str(TIMEOUT), timeout=60)
    finally:
        close()
    assert seconds < TIMEOUT + 10, seconds
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(lines) == 1, done.stderr
    assert f"127.0.0.1:{port} is not a Ray GCS: " in lines[0] and what in lines[0], lines[0]
    assert "ray start --head" in lines[0] and "6379" in lines[0]


def test_a_gcs_with_token_authentication_is_recognised(tmp_path):
    """The probe sends no token: a GCS that wants one refuses the call as UNAUTHENTICATED, and ray.init (which
    reads the token) is left to connect; Ray 2.61 turns token authentication on for every cluster."""
    ray_command = Path(sys.executable).with_name("ray")
    if not ray_command.exists():
        pytest.skip("the ray command is not installed next to this Python")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    environment = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": "0123456789abcdef" * 2}
    head = subprocess.Popen(
        [
            str(ray_command),
            "start",
            "--head",
            f"--port={port}",
            "--num-cpus=0",
            "--include-dashboard=false",
            "--disable-usage-stats",
            "--block",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=environment,
        start_new_session=True,
    )
    try:
        wait_for_address(f"127.0.0.1:{port}", 60)
    finally:
        os.killpg(head.pid, signal.SIGTERM)
        try:
            head.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(head.pid, signal.SIGKILL)
        Path("/tmp/ray/ray_current_cluster").unlink(missing_ok=True)


def test_a_port_of_a_ray_node_that_is_not_its_gcs_is_refused(ray_cluster):
    """The raylet's and the object manager's ports speak gRPC too, but not the GCS's calls."""
    wait_for_address(ray_cluster.get_runtime_context().gcs_address, 10)  # the GCS itself passes
    node = ray_cluster.nodes()[0]
    for port in (node["NodeManagerPort"], node["ObjectManagerPort"]):
        address = f"{node['NodeManagerAddress']}:{port}"
        with pytest.raises(ConnectionError, match=f"{address} is not a Ray GCS: a gRPC server there refuses"):
            wait_for_address(address, TIMEOUT)


@pytest.fixture
def plugin_folder(tmp_path, monkeypatch):
    """A folder on this process's Python path for plugin modules; what they register and load is undone after."""
    plugins.load_plugins()  # the entry points first, so that the snapshot holds them
    monkeypatch.setattr(plugins, "_loaded", dict(getattr(plugins, "_loaded", {})), raising=False)
    monkeypatch.setattr(METHODS, "_entries", dict(METHODS._entries))
    monkeypatch.setattr(METHODS, "_aliases", dict(METHODS._aliases))
    folder = tmp_path / "plugins"
    folder.mkdir()
    monkeypatch.syspath_prepend(str(folder))
    before = set(sys.modules)
    yield folder
    for name in set(sys.modules) - before:
        if sys.modules[name] is not None and str(getattr(sys.modules[name], "__file__", "")).startswith(str(folder)):
            del sys.modules[name]


_PLUGIN = """
import numpy as np
from vpr_uncertainty.methods import register_method

def gap(retrieval, *, k=10):
    scores = np.asarray(retrieval.scores, dtype=np.float64)
    return scores[:, 1] - scores[:, 0]          # a plugin's SU: the gap between the two best, not the built-in

def entropy(retrieval, *, k=10):
    scores = np.asarray(retrieval.scores, dtype=np.float64)[:, :k] * 10
    p = np.exp(scores - scores.max(axis=1, keepdims=True))
    p /= p.sum(axis=1, keepdims=True)
    return -(p * np.log(p)).sum(axis=1)

register_method({name!r}, {function}, description="a plugin", overwrite=True)
"""


@pytest.mark.parametrize(("name", "function"), [("SU", "gap"), ("ENT", "entropy")], ids=["overrides_SU", "adds_ENT"])
def test_a_plugin_method_on_ray_gives_the_numbers_of_the_local_run(
    name, function, ray_cluster, plugin_folder, tmp_path, corridor_dir, corridor_matches_dir
):
    """Before: the workers used the built-in SU (0.9686 against the plugin's 0.9048 in the issue) without a notice,
    and a method only a plugin registers was "unknown uncertainty method 'ENT'"."""
    builtin = _auc_pr(_ran(_grid(tmp_path / "builtin", corridor_dir, corridor_matches_dir, ["SU"])))["SU"]
    module = f"attack_plugin_{name.lower()}"
    (plugin_folder / f"{module}.py").write_text(_PLUGIN.format(name=name, function=function))
    local = _auc_pr(_ran(_grid(tmp_path / "local", corridor_dir, corridor_matches_dir, [name]), "--plugin", module))
    on_ray = _grid(tmp_path / "ray", corridor_dir, corridor_matches_dir, [name])
    remote = _auc_pr(_ran(on_ray, "--plugin", module, executor=("--executor", "ray", "--workers", "2")))
    assert_close(remote[name], local[name], dtype="float64")
    if name == "SU":
        assert abs(local["SU"] - builtin) > 0.01  # the plugin's SU, not the built-in one


def test_a_plugin_file_reaches_the_workers_by_its_path(
    ray_cluster, plugin_folder, tmp_path, corridor_dir, corridor_matches_dir, monkeypatch
):
    """Before: ``--plugin ./file.py`` failed ("the 'package' argument is required to perform a relative import");
    the file, in a folder on no Python path, is imported on the workers by its absolute path."""
    folder = plugin_folder / "not_on_the_path"
    folder.mkdir()
    (folder / "attack_plugin_file.py").write_text(_PLUGIN.format(name="ENT", function="entropy"))
    monkeypatch.chdir(folder)
    local = _auc_pr(
        _ran(
            _grid(tmp_path / "local", corridor_dir, corridor_matches_dir, ["ENT"]),
            "--plugin",
            "./attack_plugin_file.py",
        )
    )
    on_ray = _grid(tmp_path / "ray", corridor_dir, corridor_matches_dir, ["ENT"])
    remote = _auc_pr(
        _ran(on_ray, "--plugin", "./attack_plugin_file.py", executor=("--executor", "ray", "--workers", "2"))
    )
    assert_close(remote["ENT"], local["ENT"], dtype="float64")


def _ran(grid: Path, *plugin: str, executor: tuple[str, ...] = ()) -> Path:
    assert main([*plugin, "reproduce", str(grid), "--no-report", *executor]) == 0
    return grid


@pytest.mark.parametrize("change", ["removed", "edited"])
def test_a_plugin_the_workers_cannot_load_as_this_run_did_fails_in_one_line(
    change, ray_cluster, plugin_folder, tmp_path, corridor_dir, corridor_matches_dir, capsys
):
    """Before: exit 0 with the built-in SU's numbers: the workers never imported the plugin."""
    module = f"attack_plugin_{change}"
    path = plugin_folder / f"{module}.py"
    path.write_text(_PLUGIN.format(name="SU", function="gap"))
    plugins.load_plugins([module])  # the run loads it ...
    if change == "removed":  # ... and then the file goes, or changes, before a worker imports it
        path.unlink()
    else:
        path.write_text(_PLUGIN.format(name="SU", function="entropy"))
    grid = _grid(tmp_path, corridor_dir, corridor_matches_dir, ["SU"])
    capsys.readouterr()
    assert main(["--plugin", module, "reproduce", str(grid), "--no-report", "--executor", "ray", "--workers", "2"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vpr-uncertainty reproduce: error: plugin ")
    expected = "cannot be imported on a Ray worker" if change == "removed" else "is not the code this run loaded"
    assert f"'{module}'" in lines[0] and expected in lines[0] and str(plugin_folder) in lines[0], lines[0]


_MODEL_PLUGIN = """
from vpr_uncertainty.descriptors import DescriptorModel, ModelSpec, Preprocessing, register_model

def load(spec, *, device="cpu"):
    network = lambda images: images.mean(dim=(2, 3))          # (B, 3, H, W) -> (B, 3)
    return DescriptorModel(spec.name, network, spec.preprocessing, weights_id="v1", descriptor_dim=3).to(device)

register_model(ModelSpec(name="attack-colour", description="mean colour", descriptor_dim=3, backbone="none",
                         preprocessing=Preprocessing(image_size=32), loader=load))
"""


def test_a_plugin_model_extracts_on_ray_as_locally(ray_cluster, plugin_folder, monkeypatch, tmp_path, corridor_dir):
    """Before: every Ray Data actor failed with "unknown model", reported as "a batch of images killed its Ray
    worker 4 times"."""
    pytest.importorskip("torch")
    from vpr_uncertainty.descriptors.models import MODELS
    from vpr_uncertainty.executors import get_executor
    from vpr_uncertainty.pipeline.extract import ExtractConf, compute

    monkeypatch.setattr(MODELS, "_entries", dict(MODELS._entries))
    monkeypatch.setattr(MODELS, "_aliases", dict(MODELS._aliases))
    (plugin_folder / "attack_model_plugin.py").write_text(_MODEL_PLUGIN)
    plugins.load_plugins(["attack_model_plugin"])
    paths = sorted((corridor_dir / "ref").glob("*.jpg"))[:6]
    images = {"database": (paths, [path.name for path in paths])}
    conf = ExtractConf(model="attack-colour", batch_size=3, progress=False)
    local = compute(conf, images, tmp_path / "local.h5").descriptors["database"]
    with get_executor("ray", workers=1) as executor:
        remote = compute(conf, images, tmp_path / "ray.h5", executor=executor).descriptors["database"]
    assert remote.shape == (6, 3)
    assert_close(remote, local)


def test_an_installed_plugin_that_fails_to_load_is_one_line_naming_it_and_the_fix(tmp_path):
    """Before: ``.../cli.py:91: UserWarning: plugin 'broken' of broken-vpr-plugin could not be loaded ...`` and the
    source line, on two lines, with no fix."""
    info = tmp_path / "broken_vpr_plugin-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-vpr-plugin\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[vpr_uncertainty.plugins]\nbroken = broken_vpr_plugin_module\n")
    done, _ = _command("--help", timeout=120, env={"PYTHONPATH": f"{SRC}{os.pathsep}{tmp_path}"})
    assert done.returncode == 0
    assert done.stderr.splitlines() == [
        "warning: plugin 'broken' (broken_vpr_plugin_module) of the package broken-vpr-plugin could not be loaded "
        "and is left out (ModuleNotFoundError: No module named 'broken_vpr_plugin_module'); repair or uninstall that "
        "package (pip uninstall broken-vpr-plugin)"
    ]


class _NoisyRay:
    """A stand-in for the ray module whose start-up writes to the standard error as Ray's C++ core does."""

    def init(self, **options) -> None:
        os.write(2, b"[2026-12-03 09:31:25,598 W 8212 8212] rpc_client.h:153: Failed to connect to GCS\n")

    def is_initialized(self) -> bool:
        return False

    def cluster_resources(self) -> dict:
        return {"CPU": 1}


def test_what_ray_writes_to_the_standard_error_while_it_starts_goes_to_the_log_file(monkeypatch, tmp_path, capfd):
    """Before: Ray's C++ lines ("Failed to connect to GCS", every 40 s while it waited) reached the terminal."""
    from vpr_uncertainty import executors

    monkeypatch.setattr(executors, "import_ray", _NoisyRay)
    log_file = tmp_path / "logs" / "ray.log"
    executors.RayExecutor(log_file=log_file, start_timeout=30)._put_logs_back()
    assert "Failed to connect to GCS" not in capfd.readouterr().err
    assert "Failed to connect to GCS" in log_file.read_text()
