"""Issue 28, rows 7-9 and the unclear reader messages, each written as the attack a user makes.

Row 7: an image that is a link to ``/dev/zero`` or a FIFO hung ``run`` for ever in ``cache.content_key`` (a FIFO
was silently left out of the listing). Row 8: an image of a VPR-Bench folder replaced by another of the same count
(``query/0000050.jpg`` gone, ``query/0000200.jpg`` new) shifted every later index against the ground truth, exit 0.
Row 9: an hloc file whose ``query/h.jpg`` is an HDF5 hard link to ``db/2.jpg`` lost ``db/2.jpg``. Unclear: hloc
descriptors stored as strings, complex hloc descriptors cast to real in silence, ``--gt /dev/null`` "not found".

The hang cases run in a child process (or under ``signal.alarm``) so that a regression fails instead of hanging.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from vpr_uncertainty import cache
from vpr_uncertainty.cli import main
from vpr_uncertainty.data import load_dataset, load_vprbench_dataset

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")

#: Seconds a refusal may take; the old code hung (or ran to the end) instead.
BOUND = 120


class Blocked(BaseException):
    """Raised by :func:`_deadline` (not an OSError: the code under test must not be able to catch it)."""


@contextlib.contextmanager
def _deadline(seconds: int = 20):
    """Fail with TimeoutError instead of blocking for ever (a FIFO opened for reading without a writer)."""

    def expire(signum, frame):
        raise Blocked(f"still blocked after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _cli(*arguments: str, timeout: int = BOUND) -> subprocess.CompletedProcess:
    """``vpr-uncertainty ARGUMENTS`` in a child process (this tree first on the path), killed after ``timeout`` s."""
    script = "import sys\nfrom vpr_uncertainty.cli import main\nsys.exit(main(sys.argv[1:]))"
    source = str(Path(cache.__file__).parents[1])
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([source, os.environ.get("PYTHONPATH", "")])}
    try:
        return subprocess.run(
            [sys.executable, "-c", script, *arguments], capture_output=True, text=True, timeout=timeout, env=environment
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"vpr-uncertainty {' '.join(arguments[:3])} ... still running after {timeout} s")


def _corridor_copy(corridor_dir: Path, target: Path) -> Path:
    for folder in ("query", "ref"):
        shutil.copytree(corridor_dir / folder, target / folder)
    shutil.copy(corridor_dir / "ground_truth_new.npy", target / "ground_truth_new.npy")
    return target


def _matrix(corridor_matches_dir: Path) -> Path:
    return corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"


# --- row 7: special files where a user's file is read ------------------------------------------------------------


@pytest.mark.realdata
@pytest.mark.parametrize("kind", ["link to /dev/zero", "FIFO"])
def test_row7_run_refuses_an_image_that_is_no_regular_file(tmp_path, corridor_dir, kind):
    """Before: ``run`` hung for ever hashing /dev/zero; a FIFO was left out of the listing (a misleading count)."""
    root = _corridor_copy(corridor_dir, tmp_path / "corridor")
    image = root / "query" / "0000005.jpg"
    image.unlink()
    if kind == "FIFO":
        os.mkfifo(image)
    else:
        image.symlink_to("/dev/zero")
    done = _cli("run", "--dataset", str(root), "--out", str(tmp_path / "out"), "--methods", "SU", "--no-progress")
    assert done.returncode == 2, done.stderr[-2000:]
    error = done.stderr.strip().splitlines()[-1]
    assert str(image) in error and "not a regular file" in error
    assert ("a link to /dev/zero" in error and "character device" in error) if kind != "FIFO" else "a FIFO" in error


@pytest.mark.parametrize("target", ["/dev/zero", "fifo"])
def test_row7_content_key_and_file_digest_never_block(tmp_path, target):
    """Before: both read /dev/zero for ever and blocked in open() on a FIFO without a writer."""
    if target == "fifo":
        os.mkfifo(tmp_path / "fifo")
        target = str(tmp_path / "fifo")
    (tmp_path / "image.jpg").symlink_to(target)
    for function in (cache.content_key, cache.file_digest):
        with _deadline(), pytest.raises(ValueError, match=r"image\.jpg \(a link to .*\) is a .*, not a regular file"):
            function(tmp_path / "image.jpg")


def test_row7_a_table_dataset_naming_a_device_is_refused_before_reading(tmp_path):
    """A CSV/TSV dataset names its image paths itself: the one check in content_key (extraction) refuses them."""
    from vpr_uncertainty.descriptors.extract import _content_key

    (tmp_path / "images.csv").write_text("path,role,x,y\n/dev/zero,database,0,0\nq.jpg,query,0,0\n")
    dataset = load_dataset(tmp_path / "images.csv")
    with _deadline(), pytest.raises(ValueError, match="/dev/zero is a character device, not a regular file"):
        _content_key(dataset.database_paths[0])


@pytest.mark.realdata
def test_row7_special_files_as_matrix_gate_and_config(tmp_path, corridor_dir, capsys):
    """Before: each was reported as "not found" (it exists), so the user looked for a typo."""
    from vpr_uncertainty.calibration import Gate
    from vpr_uncertainty.pipeline.grid import load_config

    for name in ("matrix.npy", "gate.json", "study.toml"):
        os.mkfifo(tmp_path / name)
    with _deadline():
        assert main(["evaluate", str(tmp_path / "matrix.npy"), "--gt", str(corridor_dir / "ground_truth_new.npy")]) == 2
        assert "matrix.npy is a FIFO, not a regular file; a similarity matrix must be" in capsys.readouterr().err
        with pytest.raises(ValueError, match=r"gate\.json is a FIFO, not a regular file; a gate file must be"):
            Gate.load(tmp_path / "gate.json")
        with pytest.raises(ValueError, match=r"study\.toml is a FIFO, not a regular file; a configuration file"):
            load_config(tmp_path / "study.toml")


@pytest.mark.realdata
def test_unclear_gt_dev_null_names_what_it_is(tmp_path, corridor_matches_dir, capsys):
    """Before: ``error: ground truth file not found: /dev/null``."""
    matrix = str(_matrix(corridor_matches_dir))
    assert main(["evaluate", matrix, "--gt", "/dev/null"]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].endswith(
        "/dev/null is a character device, not a regular file; ground truth must be a regular file"
    )
    os.mkfifo(tmp_path / "gt.npy")
    with _deadline():
        assert main(["evaluate", matrix, "--gt", str(tmp_path / "gt.npy")]) == 2
    assert "gt.npy is a FIFO, not a regular file" in capsys.readouterr().err
    (tmp_path / "gt.txt").write_text("")
    assert main(["evaluate", matrix, "--gt", str(tmp_path / "gt.txt")]) == 2
    assert "gt.txt is empty (0 bytes); expected ground truth" in capsys.readouterr().err


# --- row 8: image names that are the ground truth's indices --------------------------------------------------------


@pytest.mark.realdata
def test_row8_run_refuses_a_query_replaced_by_another_of_the_same_count(tmp_path, corridor_dir):
    """Before: accepted (exit 0, 111 queries); queries 50..110 were scored against the ground truth of 51..111."""
    root = _corridor_copy(corridor_dir, tmp_path / "corridor")
    (root / "query" / "0000050.jpg").unlink()
    shutil.copy(corridor_dir / "query" / "0000051.jpg", root / "query" / "0000200.jpg")
    done = _cli("run", "--dataset", str(root), "--out", str(tmp_path / "out"), "--methods", "SU", "--no-progress")
    assert done.returncode == 2, done.stderr[-2000:]
    error = done.stderr.strip().splitlines()[-1]
    assert str(root / "query") in error and "0000200.jpg" in error and "missing: 50;" in error
    extracted = _cli("extract", "--dataset", str(root), "--out", str(tmp_path / "d.h5"), "--no-progress")
    assert extracted.returncode == 2 and "missing: 50;" in extracted.stderr  # extract does not list the folder instead


@pytest.mark.realdata
def test_row8_the_same_for_ref_and_for_a_non_numbered_stray(tmp_path, corridor_dir):
    root = _corridor_copy(corridor_dir, tmp_path / "corridor")
    (root / "ref" / "0000050.jpg").rename(root / "ref" / "0000200.jpg")
    with pytest.raises(ValueError, match=r"ref: image names are their indices 0\.\.110 .*0000200\.jpg; missing: 50;"):
        load_dataset(root)
    (root / "ref" / "0000200.jpg").rename(root / "ref" / "extra.jpg")
    with pytest.raises(ValueError, match=r"not fitting: extra\.jpg; missing: 50;"):
        load_vprbench_dataset(root)


@pytest.mark.realdata
def test_row8_numbers_without_padding_are_mapped_by_number(tmp_path, corridor_dir):
    """Before: ``10.jpg`` sorted before ``2.jpg``: image 2 of the ground truth was read as ``10.jpg``, exit 0."""
    root = _corridor_copy(corridor_dir, tmp_path / "corridor")
    for folder in ("query", "ref"):
        for path in (root / folder).iterdir():
            path.rename(path.with_name(f"{int(path.stem)}.jpg"))
    dataset = load_vprbench_dataset(root)
    assert dataset.query_names == [f"query/{i}.jpg" for i in range(111)]
    assert dataset.database_names == [f"ref/{i}.jpg" for i in range(111)]


@pytest.mark.realdata
def test_row8_images_given_to_evaluate_are_matched_by_name(tmp_path, corridor_dir, corridor_matches_dir):
    """``evaluate MATRIX --images FOLDER``: GV verified query 50 against the picture of query 51, exit 0."""
    from vpr_uncertainty.data.images import retrieval_image_paths
    from vpr_uncertainty.formats import read_results

    images = _corridor_copy(corridor_dir, tmp_path / "images")
    (images / "query" / "0000050.jpg").rename(images / "query" / "0000200.jpg")
    retrieval = read_results(_matrix(corridor_matches_dir), ground_truth=corridor_dir / "ground_truth_new.npy")
    with pytest.raises(ValueError, match=r"query: image names are .*not fitting: 0000200\.jpg; missing: 50;"):
        retrieval_image_paths(retrieval, images=images)
    (images / "query" / "0000200.jpg").rename(images / "query" / "0000050.jpg")
    queries, database = retrieval_image_paths(retrieval, images=images)
    assert [path.name for path in queries[:2]] == ["0000000.jpg", "0000001.jpg"] and len(database) == 111


# --- row 9 and the unclear hloc messages -------------------------------------------------------------------------


def _hloc(path: Path, rows: dict[str, np.ndarray]) -> Path:
    with h5py.File(path, "a") as handle:
        for name, row in rows.items():
            handle.create_group(name).create_dataset("global_descriptor", data=row)
    return path


def test_row9_an_hloc_image_hard_linked_under_two_names_is_read_under_both(tmp_path, capsys):
    """Before: ``retrieve`` saw 4 database images: ``db/2.jpg`` was entered as ``query/h.jpg`` only."""
    pytest.importorskip("faiss")
    rng = np.random.default_rng(0)
    database = rng.standard_normal((5, 8)).astype(np.float32)
    path = _hloc(tmp_path / "feats.h5", {f"db/{i}.jpg": row for i, row in enumerate(database)})
    _hloc(path, {"query/a.jpg": database[4]})
    with h5py.File(path, "a") as handle:
        handle["query/h.jpg"] = handle["db/2.jpg"]
    out = tmp_path / "r.npz"
    argv = ["retrieve", "--database", str(path), "--queries", str(path), "--out", str(out), "--top-k", "5"]
    assert main(argv) == 0, capsys.readouterr().err
    from vpr_uncertainty.retrieval import load_retrieval

    retrieval = load_retrieval(out)
    assert retrieval.database_names.tolist() == [f"db/{i}.jpg" for i in range(5)]
    assert retrieval.query_names.tolist() == ["query/a.jpg", "query/h.jpg"]
    assert retrieval.indices[:, 0].tolist() == [4, 2]


def test_row9_hard_link_cycles_end_and_multiplying_names_are_refused(tmp_path):
    from vpr_uncertainty.formats.hloc import read_hloc_descriptors

    path = _hloc(tmp_path / "loop.h5", {"a.jpg": np.ones(4, np.float32)})
    with h5py.File(path, "a") as handle:
        handle["a.jpg/up"] = handle["/"]  # a cycle: yielded, not entered
    with _deadline():
        names, _ = read_hloc_descriptors(path)
    assert names.tolist() == ["a.jpg"]
    with h5py.File(tmp_path / "doubling.h5", "w") as handle:  # 2**40 names of one group: refused, not listed
        handle.create_group("level0")
        for level in range(40):
            handle.create_group(f"level{level + 1}").create_dataset("global_descriptor", data=np.ones(4, np.float32))
            handle[f"level{level}/a"] = handle[f"level{level}/b"] = handle[f"level{level + 1}"]
    with _deadline(), pytest.raises(ValueError, match=r"doubling\.h5: group .* is reached by more names than it has"):
        read_hloc_descriptors(tmp_path / "doubling.h5")


@pytest.mark.parametrize(
    ("row", "dtype"),
    [(np.array([b"0.1"] * 8), "|S3"), (np.ones(8, np.complex64) * (1 + 2j), "complex64")],
    ids=["strings", "complex"],
)
def test_unclear_hloc_descriptors_that_are_not_real_numbers(tmp_path, capsys, row, dtype):
    """Before: ``error: could not convert string to float: np.bytes_(b'0.1')`` (no file named); complex: exit 0,
    the imaginary part dropped with a ComplexWarning."""
    pytest.importorskip("faiss")
    database = _hloc(tmp_path / "db.h5", {f"{i}.jpg": np.eye(8, dtype=np.float32)[i] for i in range(3)})
    queries = _hloc(tmp_path / "q.h5", {"a.jpg": row})
    argv = ["retrieve", "--database", str(database), "--queries", str(queries), "--out", str(tmp_path / "r.npz")]
    assert main([*argv, "--top-k", "2"]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1
    assert f"q.h5: a.jpg/global_descriptor has shape (8,) and dtype {dtype}; expected one 1-D descriptor" in error[0]
    assert "real numbers" in error[0]


def test_listing_refuses_every_special_image_once(tmp_path):
    """One line for the whole folder: the first special file and how many there are."""
    from vpr_uncertainty.data.images import list_images

    folder = tmp_path / "ref"
    folder.mkdir()
    (folder / "0.jpg").write_bytes(b"jpeg")
    for name in ("1.jpg", "2.png"):
        os.mkfifo(folder / name)
    (folder / "3.jpg").symlink_to("/dev/null")
    os.mkfifo(folder / "notes")  # not an image: not listed, not refused
    with _deadline(), pytest.raises(ValueError) as error:
        list_images(folder)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{folder / '1.jpg'} is a FIFO, not a regular file")
    assert f"(3 such file(s) under {folder}: remove or replace them)" in message
