"""The command line under user mistakes and faults: one line on stderr, never a traceback, the right exit status.

Exit statuses (``vpr-uncertainty --help``): 2 usage or input error, 1 runtime failure (disk full...), 130 Ctrl-C.
"""

from __future__ import annotations

import errno
import json
import os
import re
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from vpr_uncertainty import cli
from vpr_uncertainty.cli import main

SRC = Path(__file__).resolve().parents[1] / "src"


def run_cli(*args: str, env: dict[str, str] | None = None, **options) -> subprocess.CompletedProcess:
    """``vpr-uncertainty ARGS`` in a fresh interpreter (this checkout's sources first on the path)."""
    return subprocess.run(
        [sys.executable, "-m", "vpr_uncertainty.cli", *args],
        capture_output=True,
        text=True,
        env=_environment(env),
        timeout=300,
        **options,
    )


def _environment(extra: dict[str, str] | None = None) -> dict[str, str]:
    environment = dict(os.environ)
    environment["PYTHONPATH"] = os.pathsep.join(filter(None, [str(SRC), environment.get("PYTHONPATH")]))
    environment.pop(cli.DEBUG_VARIABLE, None)
    environment.update(extra or {})
    return environment


_PROGRESS_BAR = re.compile(r"\d+/\d+ \[")


def error_lines(stderr: str) -> list[str]:
    """stderr without warnings, progress bars and blank lines: what the user reads as the error."""
    return [
        line
        for line in re.split(r"[\r\n]", stderr)
        if line.strip() and not line.startswith("warning:") and not _PROGRESS_BAR.search(line)
    ]


def assert_one_line(stderr: str, *fragments: str) -> str:
    lines = error_lines(stderr)
    assert "Traceback" not in stderr
    assert len(lines) == 1, stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def usage_error(capsys, argv: list[str], *fragments: str) -> str:
    """Run main(argv), expect argparse's exit status 2 and one line naming ``fragments``."""
    with pytest.raises(SystemExit) as raised:
        main(argv)
    assert raised.value.code == 2
    return assert_one_line(capsys.readouterr().err, *fragments)


@pytest.fixture
def similarity_files(tmp_path: Path) -> tuple[Path, Path]:
    rng = np.random.default_rng(0)
    similarity = rng.uniform(size=(12, 20)).astype(np.float32)
    np.save(tmp_path / "sim.npy", similarity)
    top1 = [str(int(np.argmax(row)) if q % 3 else 0) for q, row in enumerate(similarity)]  # some right, some wrong
    (tmp_path / "gt.txt").write_text("\n".join(top1) + "\n")
    return tmp_path / "sim.npy", tmp_path / "gt.txt"


# --- the mapping from exceptions to exit statuses ---------------------------------------------------------------


@pytest.mark.parametrize(
    ("error", "status"),
    [
        (ValueError("bad value in x.npy"), 2),
        (TypeError("bad type"), 2),
        (KeyError("no 'queries' descriptors in d.h5"), 2),
        (ImportError("pip install vpr-uncertainty[torch]"), 2),
        (FileNotFoundError(errno.ENOENT, "No such file or directory", "x.npy"), 2),
        (IsADirectoryError(errno.EISDIR, "Is a directory", "out"), 2),
        (NotADirectoryError(errno.ENOTDIR, "Not a directory", "file/x"), 2),
        (PermissionError(errno.EACCES, "Permission denied", "/root/x"), 2),
        (EOFError("No data left in file"), 2),
        (OSError(errno.ENOSPC, "No space left on device", "d.h5"), 1),
        (OSError(errno.EIO, "Input/output error"), 1),
        (RuntimeError("Unable to synchronously flush file (file write failed:\n, errno = 28)"), 1),
        (MemoryError(), 1),
        (KeyboardInterrupt(), 130),
    ],
)
def test_exceptions_map_to_one_line_and_exit_status(monkeypatch, capsys, error, status):
    def handler(args):
        raise error

    from vpr_uncertainty.pipeline import datasets

    monkeypatch.setattr(datasets, "_handle", handler)
    assert main(["datasets"]) == status
    err = capsys.readouterr().err
    line = assert_one_line(err, "vpr-uncertainty datasets: ")
    if status == 130:
        assert line.endswith("interrupted")
    elif isinstance(error, OSError) and error.filename:
        assert line.endswith(f"{error.strerror}: {error.filename}")
    elif isinstance(error, KeyError):
        assert line.endswith(str(error.args[0]))  # not the repr with quotes


def test_unexpected_error_is_a_bug_with_its_traceback(monkeypatch, capsys):
    from vpr_uncertainty.pipeline import datasets

    monkeypatch.setattr(datasets, "_handle", lambda args: None.shape)
    assert main(["datasets"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and err.strip().splitlines()[-1].startswith("vpr-uncertainty datasets: internal error")


@pytest.mark.parametrize("how", ["flag", "environment"])
def test_debug_shows_the_traceback_and_keeps_the_status(monkeypatch, capsys, how):
    from vpr_uncertainty.pipeline import datasets

    def handler(args):
        raise ValueError("bad value")

    monkeypatch.setattr(datasets, "_handle", handler)
    argv = ["datasets"]
    if how == "flag":
        argv.insert(0, "--debug")
    else:
        monkeypatch.setenv(cli.DEBUG_VARIABLE, "1")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and "ValueError: bad value" in err
    assert err.strip().splitlines()[-1] == "vpr-uncertainty datasets: error: bad value"


def test_help_documents_exit_statuses_and_debug(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "--debug" in out and cli.DEBUG_VARIABLE in out
    assert all(code in out for code in ("130", "usage or input error", "runtime failure"))


# --- output paths -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "--dataset", "corridor"],
        ["demo", "--no-download"],
        ["reproduce", "grid.toml"],
    ],
)
def test_out_folder_that_is_a_file(tmp_path, capsys, argv):
    (tmp_path / "afile").write_text("x")
    usage_error(capsys, [*argv, "--out", str(tmp_path / "afile")], "--out", "afile exists and is not a folder")


def test_out_file_under_a_file_or_that_is_a_folder(tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    under = str(tmp_path / "afile" / "d.h5")
    usage_error(capsys, ["extract", "--dataset", "corridor", "--out", under], "--out", "is a file, so")
    usage_error(capsys, ["extract", "--dataset", "corridor", "--out", str(tmp_path)], "--out", "is a folder")
    usage_error(capsys, ["retrieve", "--database", "d.npy", "--queries", "q.npy", "--out", under], "--out")
    usage_error(capsys, ["train-btl", "--descriptors", "d.npy", "--out", under], "--out")


def test_unwritable_json(tmp_path, capsys, similarity_files):
    scores, gt = similarity_files
    (tmp_path / "afile").write_text("x")
    for target, fragment in [(tmp_path / "afile" / "r.json", "is a file, so"), (tmp_path, "is a folder")]:
        usage_error(capsys, ["evaluate", str(scores), "--gt", str(gt), "--json", str(target)], "--json", fragment)
    if Path("/proc/self").exists():  # a folder in which nothing can be created, even by root
        usage_error(capsys, ["evaluate", str(scores), "--gt", str(gt), "--json", "/proc/r.json"], "cannot write in")


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_json_on_a_full_disk(capsys, similarity_files):
    scores, gt = similarity_files
    assert main(["evaluate", str(scores), "--gt", str(gt), "--json", "/dev/full"]) == 1
    assert_one_line(capsys.readouterr().err, "No space left on device: /dev/full")


@pytest.mark.parametrize("command", ["run", "demo", "extract", "train-btl"])
def test_bogus_device_is_a_usage_error(capsys, command):
    required = {
        "run": ["--dataset", "x", "--out", "runs/x"],
        "demo": [],
        "extract": ["--dataset", "x", "--out", "d.h5"],
        "train-btl": ["--descriptors", "d.npy", "--out", "head.pt"],
    }[command]
    usage_error(capsys, [command, *required, "--device", "bogus"], "--device", "expected cpu, cuda, cuda:N or mps")


@pytest.mark.parametrize("device", ["cpu", "cuda", "cuda:1", "mps"])
def test_device_names_accepted(device):
    from vpr_uncertainty.pipeline.options import device_name

    assert device_name(device) == device


def test_library_rejects_a_bogus_device_with_a_value_error():
    pytest.importorskip("torch")
    from vpr_uncertainty.descriptors.models import from_callable

    with pytest.raises(ValueError, match="invalid device 'bogus'"):
        from_callable(lambda images: images.mean(dim=(2, 3)), device="bogus")


# --- extraction: disk full and Ctrl-C ---------------------------------------------------------------------------


def write_table_dataset(folder: Path, n: int = 24) -> Path:
    """``n`` database and ``n`` query images (8 x 8 PNG) 10 m apart, and a CSV table naming them."""
    from PIL import Image

    rng = np.random.default_rng(0)
    rows = ["path,role,x,y"]
    for role in ("database", "query"):
        (folder / role).mkdir(parents=True)
        for i in range(n):
            Image.fromarray(rng.integers(0, 256, (8, 8, 3), dtype=np.uint8)).save(folder / role / f"{i:03d}.png")
            rows.append(f"{role}/{i:03d}.png,{role},{10.0 * i},0")
    (folder / "places.csv").write_text("\n".join(rows) + "\n")
    return folder / "places.csv"


def write_model(path: Path, repeat: int = 1) -> Path:
    """A TorchScript model: channel means through a fixed projection, repeated to ``3 * repeat`` dimensions."""
    torch = pytest.importorskip("torch")

    class Pool(torch.nn.Module):
        def __init__(self, repeat: int) -> None:
            super().__init__()
            self.repeat = repeat
            self.weight = torch.nn.Parameter(torch.tensor([[1.0, 0.2, -0.3], [0.1, 1.0, 0.4], [-0.2, 0.3, 1.0]]))

        def forward(self, images: torch.Tensor) -> torch.Tensor:
            return (images.mean(dim=(2, 3)) @ self.weight).repeat(1, self.repeat)

    torch.jit.script(Pool(repeat)).save(str(path))
    return path


@pytest.fixture
def tiny_dataset(tmp_path: Path) -> tuple[Path, Path]:
    return write_table_dataset(tmp_path / "data"), write_model(tmp_path / "pool.pt")


@pytest.fixture
def small_disk(tmp_path: Path):
    """A 256 KiB tmpfs: skipped where mounting is not permitted (not root, no CAP_SYS_ADMIN, not Linux)."""
    mount_point = tmp_path / "small"
    mount_point.mkdir()
    try:
        mounted = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount_point)], capture_output=True, timeout=30
        )
    except (OSError, subprocess.SubprocessError) as error:
        pytest.skip(f"cannot mount a small tmpfs here: {error}")
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {mounted.stderr.decode(errors='replace').strip()}")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", str(mount_point)], capture_output=True, timeout=30)


def test_extraction_on_a_full_disk_is_one_line_and_exit_1(tmp_path, tiny_dataset, small_disk):
    """h5py used to raise a RuntimeError on flush and close, then the interpreter crashed at exit (status 139)."""
    table, _ = tiny_dataset
    wide = write_model(tmp_path / "wide.pt", repeat=2048)  # 6144 floats a row: the first chunk (6 MiB) cannot fit
    out = small_disk / "descriptors.h5"
    result = run_cli("extract", "--dataset", str(table), "--model", str(wide), "--out", str(out), "--no-progress")
    assert result.returncode == 1, result.stderr  # not -11 / 139 (segmentation fault)
    assert_one_line(result.stderr, "vpr-uncertainty extract: error: No space left on device", str(out))


# A subprocess whose model stops in the middle of its third batch and says so on stdout, so that the test sends
# SIGINT exactly there (a real signal, from outside, at a known point).
_PAUSING = textwrap.dedent(
    """
    import sys, time
    from vpr_uncertainty.cli import main
    from vpr_uncertainty.descriptors import extract

    original, calls = extract._forward, []

    def forward(model, images):
        calls.append(len(images))
        if len(calls) == 3:
            print("PAUSED", flush=True)
            time.sleep(120)
        return original(model, images)

    extract._forward = forward
    sys.exit(main(sys.argv[1:]))
    """
)


def interrupt_in_third_batch(*args: str) -> subprocess.CompletedProcess:
    process = subprocess.Popen(
        [sys.executable, "-c", _PAUSING, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_environment(),
        # as from a terminal: a test run started in the background (`make test &` in a script) hands its children
        # SIGINT ignored, and Python then installs no KeyboardInterrupt handler
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        for line in process.stdout:
            if line.strip() == "PAUSED":
                process.send_signal(signal.SIGINT)
                break
        stdout, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    return subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)


def count_forwarded_images(monkeypatch) -> list[int]:
    from vpr_uncertainty.descriptors import extract

    counted: list[int] = []
    original = extract._forward
    monkeypatch.setattr(
        extract, "_forward", lambda model, images: counted.append(len(images)) or original(model, images)
    )
    return counted


def test_ctrl_c_during_extract_exits_130_and_the_rerun_resumes(tmp_path, tiny_dataset, monkeypatch, capsys):
    from vpr_uncertainty.descriptors import cache_info, read_descriptors

    table, model = tiny_dataset
    out = tmp_path / "descriptors.h5"
    argv = ["extract", "--dataset", str(table), "--model", str(model), "--out", str(out), "--batch-size", "4"]
    interrupted = interrupt_in_third_batch(*argv, "--no-progress", "--workers", "0")
    assert interrupted.returncode == 130, interrupted.stderr
    assert_one_line(interrupted.stderr, "vpr-uncertainty extract: interrupted")
    info = cache_info(out)  # the file is closed and readable: two batches of the database are in it
    assert info["database"]["count"] == 8 and not info["database"]["complete"]

    counted = count_forwarded_images(monkeypatch)
    assert main([*argv, "--no-progress"]) == 0
    assert "recomputing" not in capsys.readouterr().err
    assert sum(counted) == 48 - 8  # resumed: only the images not yet in the cache went through the model
    fresh = tmp_path / "fresh.h5"
    assert main(["extract", "--dataset", str(table), "--model", str(model), "--out", str(fresh), "--no-progress"]) == 0
    for split in ("database", "queries"):
        names, descriptors = read_descriptors(out, split)
        fresh_names, fresh_descriptors = read_descriptors(fresh, split)
        np.testing.assert_array_equal(names, fresh_names)
        # Same model, images and batch shapes (8 x 8 each): the very same code path, bitwise.
        np.testing.assert_array_equal(descriptors, fresh_descriptors)


def test_ctrl_c_during_run_exits_130_and_the_rerun_resumes(tmp_path, tiny_dataset, monkeypatch, capsys):
    pytest.importorskip("faiss")
    table, model = tiny_dataset
    out = tmp_path / "run"
    argv = ["run", "--dataset", str(table), "--model", str(model), "--out", str(out), "--batch-size", "4"]
    interrupted = interrupt_in_third_batch(*argv, "--methods", "SU,BM")
    assert interrupted.returncode == 130, interrupted.stderr
    assert_one_line(interrupted.stderr, "vpr-uncertainty run: interrupted")
    assert not (out / "results.json").exists()

    counted = count_forwarded_images(monkeypatch)
    assert main([*argv, "--methods", "SU,BM"]) == 0
    capsys.readouterr()
    assert sum(counted) == 48 - 8
    results = json.loads((out / "results.json").read_text())
    assert results["n_queries"] == 24 and set(results["methods"]) == {"SU", "BM"}


# --- other caches stay consistent when a write is cut short ------------------------------------------------------


def test_interrupted_retrieval_write_keeps_the_previous_file(tmp_path, monkeypatch):
    from vpr_uncertainty.retrieval import Retrieval, load_retrieval, result, save_retrieval

    first = Retrieval(scores=np.array([[0.9, 0.5]]), indices=np.array([[0, 1]]))
    path = save_retrieval(first, tmp_path / "retrieval.npz")

    def cut_short(handle, **arrays):
        handle.write(b"PK\x03\x04 half an archive")
        raise KeyboardInterrupt

    monkeypatch.setattr(result.np, "savez_compressed", cut_short)
    with pytest.raises(KeyboardInterrupt):
        save_retrieval(Retrieval(scores=np.array([[0.8, 0.1]]), indices=np.array([[1, 0]])), path)
    np.testing.assert_array_equal(load_retrieval(path).indices, first.indices)  # the rerun reads a whole file
    assert sorted(p.name for p in tmp_path.iterdir()) == ["retrieval.npz"]


def test_reproduce_recomputes_a_cell_whose_arrays_were_cut_short(tmp_path):
    from vpr_uncertainty.pipeline.grid import load_cell

    json_path, npz_path = tmp_path / "cell.json", tmp_path / "cell.npz"
    json_path.write_text(json.dumps({"fingerprint": "abc"}))
    np.savez_compressed(npz_path, correct=np.ones(1000, bool))
    npz_path.write_bytes(npz_path.read_bytes()[:100])  # interrupted while rewriting (--force)
    assert load_cell(json_path, npz_path, "abc") is None
