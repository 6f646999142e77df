"""Issue 42, rows 12 and 13, tried as a user would: ``--executor ray --address`` in a form the GCS probe did not
read, or at an HTTP/2 server that is not Ray's GCS.

Before: ``--address "127.0.0.1:6399 "`` (a trailing space; ``127.0.0.1:+6399`` and ``localhost: 1`` alike) skipped
the probe, as the port was not all digits, and ``ray.init`` waited for ever; an HTTP/2 server that closed the call
without a ``grpc-status`` was taken for a GCS that wants a token, one that sent any body for a GCS's reply, and
``ray.init`` hung there too. Target: any malformed or wrong address ends within ``--connect-timeout`` + 10 s, in
one line naming the address and the fix.
"""

from __future__ import annotations

import contextlib
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

pytest.importorskip("ray")

import vpr_uncertainty
from vpr_uncertainty.executors import _frame, wait_for_address

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")

#: The package the child process runs: the one this process imports (a checkout under test may sit elsewhere).
SRC = str(Path(vpr_uncertainty.__file__).resolve().parents[1])
TIMEOUT = 2

#: What a Ray 2.60 GCS sends on stream 1 for the probe's GetClusterId, recorded: without authentication (headers,
#: the reply with its 28-byte cluster id, trailers), and with token authentication (trailers only, status 16).
GCS_HEADERS = _frame(1, 4, 1, b"\x88@\x0ccontent-type\x10application/grpc")
GCS_TRAILERS = _frame(1, 5, 1, b"@\x0bgrpc-status\x010")
GCS_REPLY = GCS_HEADERS + _frame(0, 0, 1, b"\0\0\0\0\x20\n\0\x12\x1c" + bytes(range(28))) + GCS_TRAILERS
GCS_WANTS_A_TOKEN = _frame(
    1,
    5,
    1,
    b"\x88@\x0ccontent-type\x10application/grpc\x00\x0bgrpc-status\x0216\x00\x0cgrpc-message>InvalidAuthToken: "
    b"Authentication token is missing or incorrect",
)
#: What other HTTP/2 servers answer: status 200 and nothing else (row 13), a page, an empty gRPC message (a gRPC
#: server that answers every call), a page that holds the bytes of a status 16 (not in the trailers).
NOT_RAY = {
    "200 without grpc-status": _frame(1, 5, 1, b"\x88"),
    "200 with a page": _frame(1, 4, 1, b"\x88") + _frame(0, 1, 1, b"<html>hello</html>"),
    "an empty gRPC message": GCS_HEADERS + _frame(0, 0, 1, bytes(5)) + GCS_TRAILERS,
    "a status 16 in a page": _frame(1, 4, 1, b"\x88") + _frame(0, 1, 1, b"\x00\x0bgrpc-status\x0216"),
}


def _http2_server(reply: bytes) -> tuple[int, Callable[[], None]]:
    """A loopback port where an HTTP/2 server answers the first call of every connection with ``reply`` (frames,
    after its SETTINGS and the acknowledgement of the client's), then holds the connection open."""
    server = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []

    def serve(connection: socket.socket) -> None:
        with contextlib.suppress(OSError):  # the client, or close() below, ended the connection
            connection.recv(65536)  # the preface, SETTINGS and the call
            connection.sendall(_frame(4, 0, 0) + _frame(4, 1, 0) + reply)
            while connection.recv(65536):
                pass

    def accept() -> None:
        while True:
            try:
                connection = server.accept()[0]
            except OSError:
                return
            held.append(connection)
            threading.Thread(target=serve, args=(connection,), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()

    def close() -> None:
        server.close()
        for connection in held:
            with contextlib.suppress(OSError):
                connection.shutdown(socket.SHUT_RDWR)
            connection.close()

    return server.getsockname()[1], close


def _closed_port() -> int:
    """A loopback port with nothing listening (bound, then released)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _grid(folder: Path, corridor_dir: Path, corridor_matches_dir: Path) -> Path:
    """A one-cell study (NetVLAD on the corridor, SU)."""
    matrix = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    (folder / "grid.toml").write_text(
        f'out = "out"\nmethods = ["SU"]\nalphas = []\nks = []\n[[inputs]]\nvpr_method = "NetVLAD"\n'
        f'dataset = "corridor"\nscores = "{matrix}"\nground_truth = "{corridor_dir / "ground_truth_new.npy"}"\n'
    )
    return folder / "grid.toml"


def _reproduce_on_ray(
    grid: Path, address: str, *, timeout: float = TIMEOUT + 20
) -> tuple[subprocess.CompletedProcess, float]:
    """``vpr-uncertainty reproduce grid --executor ray --address address --connect-timeout TIMEOUT`` in a child
    process (Ray's C++ wait cannot be interrupted in this one); its result and wall-clock seconds. A command still
    running after ``timeout`` seconds fails the test."""
    argv = ["reproduce", str(grid), "--no-report", "--executor", "ray", "--address", address]
    argv += ["--connect-timeout", str(TIMEOUT)]
    environment = {**os.environ, "PYTHONPATH": SRC, "RAY_AUTH_MODE": "disabled"}
    environment.pop("RAY_ADDRESS", None)
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
        pytest.fail(f"--address {address!r} still running after {timeout} s")
    return subprocess.CompletedProcess(argv, process.returncode, out, err), time.monotonic() - started


@pytest.mark.parametrize("form", ["127.0.0.1:{} ", "127.0.0.1:+{}", "localhost: {}"])
def test_a_port_that_is_not_plain_digits_is_refused_in_one_line(form, tmp_path, corridor_dir, corridor_matches_dir):
    """Row 12. Before: the probe was skipped and ``ray.init`` hung past 230 s."""
    address = form.format(_closed_port())
    done, seconds = _reproduce_on_ray(_grid(tmp_path, corridor_dir, corridor_matches_dir), address)
    assert seconds < TIMEOUT + 10, seconds
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert f"Ray address {address!r} is not host:port" in lines[0], lines[0]
    assert "no spaces" in lines[0] and "ray start --head" in lines[0], lines[0]
    assert not (tmp_path / "out" / "results.json").exists()


@pytest.mark.parametrize("reply", list(NOT_RAY.values()), ids=list(NOT_RAY))
def test_an_http2_server_that_is_not_a_gcs_is_refused_in_one_line(reply, tmp_path, corridor_dir, corridor_matches_dir):
    """Row 13 and its variations. Before: taken for a GCS (one that wants a token, or one that replied), and
    ``ray.init`` hung past 60 s."""
    port, close = _http2_server(reply)
    try:
        done, seconds = _reproduce_on_ray(_grid(tmp_path, corridor_dir, corridor_matches_dir), f"127.0.0.1:{port}")
    finally:
        close()
    assert seconds < TIMEOUT + 10, seconds
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(lines) == 1, done.stderr
    assert f"127.0.0.1:{port} is not a Ray GCS: " in lines[0], lines[0]
    assert "ray start --head" in lines[0] and "6379" in lines[0], lines[0]


@pytest.mark.parametrize(
    "address",
    [
        "127.0.0.1:6399\n",
        " 127.0.0.1:6399",
        "127.0.0.1:6399/",
        "127.0.0.1:\u0663\u0663",  # Arabic-Indic digits: str.isdigit says yes, int() reads 33
        "127.0.0.1:99999",  # read as 99999 % 65536 by the socket, refused by Ray
        "127.0.0.1:0",
        "127.0.0.1:06379",  # a leading zero
        "127.0.0.1:",
        ":6379",
        "::1:6379",  # an IPv6 address without brackets
        "host name:6379",
        "ray://127.0.0.1:10001 ",
        "ray://",
        "6379",
    ],
)
def test_every_other_malformed_form_is_refused_before_any_wait(address):
    started = time.monotonic()
    with pytest.raises(ValueError, match=r"is not host:port \(a port of digits, 1-65535, no spaces\)"):
        wait_for_address(address, 30)
    assert time.monotonic() - started < 1


def test_auto_reads_ray_address_as_ray_init_does(monkeypatch):
    """``ray.init(address="auto")`` connects to ``RAY_ADDRESS``: the probe asks that address."""
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:6399 ")
    with pytest.raises(ValueError, match=r"RAY_ADDRESS \(what 'auto' reads\) '127.0.0.1:6399 ' is not host:port"):
        wait_for_address("auto", 30)
    port = _closed_port()
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{port}")
    with pytest.raises(ConnectionError, match=f"no Ray cluster answers at 127.0.0.1:{port} within 0.5 s"):
        wait_for_address("auto", 0.5)
    monkeypatch.setenv("RAY_ADDRESS", "")
    wait_for_address("auto", 0.5)  # Ray finds the cluster itself, or says at once that it found none


@pytest.mark.parametrize("reply", [GCS_REPLY, GCS_WANTS_A_TOKEN], ids=["reply", "token"])
def test_what_a_real_gcs_answers_still_passes(reply):
    """The two answers a Ray GCS gives the probe (recorded from Ray 2.60); well-formed addresses of every form."""
    port, close = _http2_server(reply)
    try:
        for address in (f"127.0.0.1:{port}", f"localhost:{port}", f"[::ffff:127.0.0.1]:{port}"):
            wait_for_address(address, 5)
    finally:
        close()
