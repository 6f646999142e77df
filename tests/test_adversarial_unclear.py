"""The unclear cases of issue 20 that concern resources and caches: each gets one message naming the file.

* an address-space limit below the size of a similarity matrix gave ``[Errno 12] Cannot allocate memory`` and no
  file (the whole file is mapped first);
* a full disk gave ``[Errno 28] No space left on device`` and no file;
* NaN in a cached ``descriptors.h5`` was reported without the file and never rebuilt;
* ``extract --overwrite`` replaced a file that a running ``run`` held open for writing.

Every test fails on the code before the fix.
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from vpr_uncertainty.cache import CacheWarning, atomic_write, write_json
from vpr_uncertainty.cli import EXIT_RUNTIME, _message, exit_status

torch = pytest.importorskip("torch")
Image = pytest.importorskip("PIL.Image")

from vpr_uncertainty.descriptors import Preprocessing, cache_info, extract_descriptors, read_descriptors  # noqa: E402
from vpr_uncertainty.descriptors.cache import split_checksum  # noqa: E402
from vpr_uncertainty.descriptors.models import from_callable  # noqa: E402
from vpr_uncertainty.formats.matrix import open_descriptors  # noqa: E402


@pytest.fixture
def images(tmp_path: Path) -> tuple[list[Path], list[str]]:
    """Six small random RGB images."""
    rng = np.random.default_rng(0)
    folder = tmp_path / "images"
    folder.mkdir()
    paths = []
    for i in range(6):
        path = folder / f"img{i:02d}.png"
        Image.fromarray(rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)).save(path)
        paths.append(path)
    return paths, [path.name for path in paths]


class ChannelStatistics:
    """Mean and standard deviation of each channel (D = 6); counts images; NaN for the row ``nan_row`` of a batch."""

    def __init__(self, nan_row: int | None = None) -> None:
        self.images = 0
        self.nan_row = nan_row

    def __call__(self, batch: torch.Tensor) -> torch.Tensor:
        self.images += batch.shape[0]
        output = torch.cat([batch.mean(dim=(2, 3)), batch.std(dim=(2, 3))], dim=1)
        if self.nan_row is not None and self.nan_row < len(output):
            output[self.nan_row] = float("nan")
        return output


def _model(nan_row: int | None = None) -> tuple[ChannelStatistics, object]:
    network = ChannelStatistics(nan_row)
    return network, from_callable(network, name="stats", preprocessing=Preprocessing(), weights_id="v1")


# --- 1. an address-space limit below the size of a similarity matrix -------------------------------------------

_LIMITED = textwrap.dedent(
    """
    import resource, sys
    from vpr_uncertainty.cli import build_parser, main
    import vpr_uncertainty.retrieval

    build_parser()  # every module imported before the limit
    with open("/proc/self/status") as status:
        size = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize"))
    hard = resource.getrlimit(resource.RLIMIT_AS)[1]
    limit = size + (512 << 20) if hard == resource.RLIM_INFINITY else min(hard, size + (512 << 20))
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    sys.exit(main(["evaluate", sys.argv[1], "--gt", sys.argv[2]]))
    """
)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS and /proc/self/status: Linux")
def test_address_space_limit_names_the_matrix_file(tmp_path):
    """A 1.9 GiB matrix (sparse on disk) under a limit 512 MiB above the interpreter: one line naming the file."""
    from numpy.lib import format as npy_format

    matrix = tmp_path / "big matrix.npy"
    shape = (20_000, 25_000)
    with matrix.open("wb") as handle:
        npy_format.write_array_header_1_0(handle, {"descr": "<f4", "fortran_order": False, "shape": shape})
        handle.truncate(handle.tell() + shape[0] * shape[1] * 4)  # a hole: no disk space used
    ground_truth = tmp_path / "gt.npy"
    np.save(ground_truth, np.zeros((shape[0], 1), dtype=np.int64))
    result = subprocess.run(
        [sys.executable, "-c", _LIMITED, str(matrix), str(ground_truth)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == EXIT_RUNTIME, result.stderr
    assert "Traceback" not in result.stderr
    assert str(matrix) in result.stderr and "ulimit -v" in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_a_block_that_cannot_be_mapped_names_the_file_and_a_smaller_block(tmp_path, monkeypatch):
    """The streaming reader maps one block at a time: a block over the limit names the file and the remedy."""
    from vpr_uncertainty.formats.ground_truth import read_npy
    from vpr_uncertainty.retrieval.blocks import MappedRows

    path = tmp_path / "m.npy"
    np.save(path, np.ones((4, 3), dtype=np.float32))
    rows = MappedRows(read_npy(path, what="a matrix", mmap=True))

    def no_memory(*args, **kwargs):
        raise OSError(errno.ENOMEM, os.strerror(errno.ENOMEM))

    monkeypatch.setattr(np, "memmap", no_memory)
    with pytest.raises(MemoryError, match=r"m\.npy: cannot map rows 0–3 .*smaller blocks \(block_rows\)"):
        rows[0:4]


# --- 2. a full disk ---------------------------------------------------------------------------------------------


def _no_space(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _write_failing_in_block(target: Path) -> None:
    with atomic_write(target) as handle:
        handle.write('{"new": true}\n')
        _no_space()  # what a full disk raises from write() or close(): an errno and no file name


def _fsync_failing(target: Path, monkeypatch) -> None:
    monkeypatch.setattr(os, "fsync", _no_space)
    write_json(target, {"new": True})


@pytest.mark.parametrize("where", ["write", "fsync"])
def test_disk_full_names_the_file_being_written(tmp_path, monkeypatch, where):
    target = (tmp_path / "gate.json").resolve()
    target.write_text('{"old": true}\n')
    with pytest.raises(OSError) as raised:
        if where == "write":
            _write_failing_in_block(target)
        else:
            _fsync_failing(target, monkeypatch)
    monkeypatch.undo()
    error = raised.value
    assert error.errno == errno.ENOSPC and error.filename == str(target)
    assert _message(error) == f"{os.strerror(errno.ENOSPC)} (the file as it was is kept): {target}"
    assert exit_status(error) == EXIT_RUNTIME
    assert target.read_text() == '{"old": true}\n'  # nothing replaced
    assert sorted(path.name for path in tmp_path.iterdir()) == ["gate.json"]  # no temporary file left


def test_an_error_naming_another_file_is_left_as_it_is(tmp_path):
    """An input that cannot be read within the block keeps its own name (not the file being written)."""
    target = tmp_path / "out.json"
    with pytest.raises(FileNotFoundError) as raised, atomic_write(target) as handle:
        handle.write((tmp_path / "missing.txt").read_text())
    assert raised.value.filename == str(tmp_path / "missing.txt")


# --- 3. NaN in the descriptor cache -----------------------------------------------------------------------------


def test_a_model_producing_nan_names_the_image_and_the_cache(images, tmp_path):
    paths, names = images
    path = tmp_path / "d.h5"
    with pytest.raises(ValueError, match=r"NaN or infinite descriptors for 1 image\(s\): 'img01.png'") as raised:
        extract_descriptors(_model(nan_row=1)[1], paths, names, path, "database", progress=False)
    assert str(path) in str(raised.value)
    failed: list[dict[str, str]] = []
    with pytest.warns(UserWarning, match="left out 1 of 6"):
        kept, descriptors = extract_descriptors(
            _model(nan_row=1)[1], paths, names, path, "database", progress=False, on_error="skip", failed=failed
        )
    assert "img01.png" not in kept and np.isfinite(descriptors).all()
    assert [entry["name"] for entry in failed] == ["img01.png"]
    assert [entry["name"] for entry in cache_info(path)["database"]["failed"]] == ["img01.png"]


def _poison(path: Path, row: int, *, sealed: bool) -> None:
    """Write NaN into one row of the database split: sealed again (a consistent checksum) or left unsealed."""
    with h5py.File(path, "a") as handle:
        group = handle["database"]
        group["descriptors"][row] = np.nan
        if sealed:
            group.attrs["checksum"] = split_checksum(group, group["names"].shape[0])
        else:
            group.attrs["complete"] = False
            del group.attrs["checksum"]


@pytest.mark.parametrize("sealed", [False, True])
def test_nan_in_the_cache_is_recomputed_with_a_notice_naming_the_file(images, tmp_path, sealed):
    paths, names = images
    path = tmp_path / "d.h5"
    _, clean = extract_descriptors(_model()[1], paths, names, path, "database", progress=False)
    _poison(path, 2, sealed=sealed)
    network, model = _model()
    with pytest.warns(CacheWarning, match=r"1 'database' row\(s\) hold NaN") as caught:
        kept, descriptors = extract_descriptors(model, paths, names, path, "database", progress=False)
    assert any(str(path) in str(warning.message) for warning in caught)
    assert network.images == 1  # only the poisoned image recomputed
    assert list(kept) == names and np.isfinite(descriptors).all()
    np.testing.assert_allclose(descriptors, clean, rtol=1e-5)
    np.testing.assert_allclose(read_descriptors(path, "database")[1], clean, rtol=1e-5)


def test_readers_refuse_nan_naming_the_file(images, tmp_path):
    paths, names = images
    path = tmp_path / "d.h5"
    extract_descriptors(_model()[1], paths, names, path, "database", progress=False)
    _poison(path, 3, sealed=False)
    pattern = rf"{path}: the 'database' descriptors hold NaN .*image 'img03.png'"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the split is incomplete: said in a warning of its own
        with pytest.raises(ValueError, match=pattern):
            read_descriptors(path, "database")
        _, rows = open_descriptors(path, "database")
        with pytest.raises(ValueError, match=pattern):
            rows.read(0, rows.shape[0])


# --- 4. extract --overwrite while another process writes the cache ---------------------------------------------


_HOLDER = "import sys, time, h5py; h = h5py.File(sys.argv[1], 'a'); print('ready', flush=True); time.sleep(60)"


@pytest.mark.skipif(
    os.environ.get("HDF5_USE_FILE_LOCKING", "").upper() == "FALSE", reason="HDF5 file locking is switched off"
)
def test_overwrite_refuses_a_cache_another_process_writes(images, tmp_path):
    """A real second process holds the file open for writing (its HDF5 lock), as a running ``run`` does."""
    paths, names = images
    path = tmp_path / "d.h5"
    extract_descriptors(_model()[1], paths[:3], names[:3], path, "database", progress=False)
    inode = path.stat().st_ino
    holder = subprocess.Popen([sys.executable, "-c", _HOLDER, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "ready"
        with pytest.raises(ValueError, match="open for writing in another process") as raised:
            extract_descriptors(_model()[1], paths, names, path, "database", progress=False, overwrite=True)
        assert str(path) in str(raised.value)
    finally:
        holder.kill()
        holder.wait()
    assert path.stat().st_ino == inode and cache_info(path)["database"]["count"] == 3  # not replaced
    kept, _ = extract_descriptors(_model()[1], paths, names, path, "database", progress=False, overwrite=True)
    assert list(kept) == names  # once the other process is gone, --overwrite replaces it
