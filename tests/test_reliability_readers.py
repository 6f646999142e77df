"""Issue 10: the .npy, ground-truth and similarity-matrix readers run no code from a file and give one clear error.

* Item 2: VPR-Bench's object arrays are read with a restricted unpickler; a malicious payload in any reader raises
  an error naming the file and the global, and its side effect never happens.
* Item 3: ground truth with floats, booleans, negative or out-of-range indices, a mask of the wrong width or the
  wrong number of queries is an error naming the file, the query and the value, never silently coerced.
* Item 5: empty, truncated or foreign ``.npy`` files, a format that does not match the file, and similarity
  matrices that are non-numeric, empty or hold NaN/+inf are ValueErrors naming the file.
"""

from __future__ import annotations

import io
import json
import os
import pickle
import warnings
from pathlib import Path

import numpy as np
import pytest
from numpy.lib import format as npy_format

from vpr_uncertainty import read_results
from vpr_uncertainty.cli import main as cli_main
from vpr_uncertainty.data import load_ground_truth, load_similarity_matrix, load_vprbench_dataset, positives_from_lists
from vpr_uncertainty.formats.ground_truth import UnsafePickleError, load_vprbench_ground_truth, read_npy
from vpr_uncertainty.formats.matrix import load_vprbench_similarity

# --------------------------------------------------------------------------------------------------------------
# Helpers: legacy-looking files and malicious payloads


def _write_object_npy(path: Path, payload: bytes, shape: tuple[int, ...]) -> Path:
    """A .npy file with an object-array header followed by an arbitrary pickle (what an attacker can write)."""
    with path.open("wb") as handle:
        npy_format.write_array_header_1_0(handle, {"descr": "|O", "fortran_order": False, "shape": shape})
        handle.write(payload)
    return path


def _object_array(items: list) -> np.ndarray:
    array = np.empty(len(items), dtype=object)
    for index, item in enumerate(items):
        array[index] = item
    return array


def _ground_truth_rows(n_queries: int) -> np.ndarray:
    rows = np.empty((n_queries, 2), dtype=object)
    for query in range(n_queries):
        rows[query] = [query, [query]]
    return rows


def _precomputed(similarity: np.ndarray) -> np.ndarray:
    n_queries = similarity.shape[0]
    return _object_array(
        [np.arange(n_queries), similarity.argmax(axis=1), similarity.max(axis=1), similarity, 0.1, 0.2]
    )


class _Payload:
    """Unpickling it calls ``function(*arguments)``."""

    def __init__(self, function, *arguments) -> None:
        self.function, self.arguments = function, arguments

    def __reduce__(self):
        return self.function, self.arguments


class _SneakyArray(np.ndarray):
    """An ndarray subclass: its pickle names this module, which the restricted unpickler must refuse."""


def _payloads(marker: Path) -> dict[str, bytes]:
    """Pickles whose loading would create ``marker`` (or call a forbidden NumPy function)."""
    touch = f"touch {marker}"
    create = f"open({str(marker)!r}, 'w').close()"
    return {
        "os.system": pickle.dumps(_Payload(os.system, touch), protocol=2),
        "builtins.eval": pickle.dumps(_Payload(eval, create), protocol=3),
        "builtins.exec": pickle.dumps(_Payload(exec, create), protocol=4),
        "protocol 0 INST": f"(S'{touch}'\nios\nsystem\n.".encode(),
        "inside a list": pickle.dumps([1, [2, _Payload(os.system, touch)]], protocol=2),
        "numpy.testing.runstring": pickle.dumps(_Payload(np.testing.runstring, create, {}), protocol=2),
        "numpy.load": pickle.dumps(_Payload(np.load, str(marker)), protocol=2),
        "ndarray subclass": pickle.dumps(np.arange(3).view(_SneakyArray), protocol=2),
        "numpy.rec.recarray": pickle.dumps(np.rec.fromrecords([(1, 2.0)]), protocol=2),
    }


def _assert_refused(call, path: Path, marker: Path) -> None:
    with pytest.raises(ValueError, match=str(path.name)) as caught:
        call(path)
    assert not marker.exists(), "the payload ran"
    assert str(path) in str(caught.value)


READERS = {
    "load_vprbench_ground_truth": lambda path: load_vprbench_ground_truth(path),
    "load_ground_truth": lambda path: load_ground_truth(path),
    "load_vprbench_similarity": load_vprbench_similarity,
    "load_similarity_matrix(auto)": lambda path: load_similarity_matrix(path),
    "load_similarity_matrix(vprbench)": lambda path: load_similarity_matrix(path, file_format="vprbench"),
    "read_npy": lambda path: read_npy(path, what="anything", allow_objects=True),
}


# --------------------------------------------------------------------------------------------------------------
# Item 2: no code execution


@pytest.mark.parametrize("reader", sorted(READERS))
def test_malicious_payload_never_runs(tmp_path, reader):
    """Before: np.load(allow_pickle=True) ran the payload (the marker file appeared)."""
    marker = tmp_path / "pwned"
    for name, payload in _payloads(marker).items():
        path = _write_object_npy(tmp_path / f"{name}.npy", payload, (1,))
        _assert_refused(READERS[reader], path, marker)


@pytest.mark.parametrize("reader", sorted(READERS))
def test_payload_inside_a_legacy_array_is_refused_by_name(tmp_path, reader):
    """A real VPR-Bench-shaped object array whose item is an os.system payload: the error names the global."""
    marker = tmp_path / "pwned"
    rows = _ground_truth_rows(3)
    rows[1, 1] = _Payload(os.system, f"touch {marker}")
    path = tmp_path / "ground_truth_new.npy"
    np.save(path, rows, allow_pickle=True)
    with pytest.raises(UnsafePickleError, match=r"ground_truth_new\.npy: refusing .*'posix\.system'|'nt\.system'"):
        READERS[reader](path)
    assert not marker.exists()


def test_vprbench_dataset_refuses_payload(tmp_path):
    marker = tmp_path / "pwned"
    for folder in ("query", "ref"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "0000000.jpg").write_bytes(b"")
    _write_object_npy(tmp_path / "ground_truth_new.npy", _payloads(marker)["os.system"], (1, 2))
    with pytest.raises(UnsafePickleError, match=r"ground_truth_new\.npy"):
        load_vprbench_dataset(tmp_path)
    assert not marker.exists()


def test_cli_refuses_payload_with_exit_2(tmp_path, capsys):
    marker = tmp_path / "pwned"
    matrix = tmp_path / "sim.npy"
    np.save(matrix, np.eye(3, dtype=np.float32))
    gt = _write_object_npy(tmp_path / "gt.npy", _payloads(marker)["os.system"], (3, 2))
    assert cli_main(["evaluate", str(matrix), "--gt", str(gt)]) == 2
    assert not marker.exists()
    error = capsys.readouterr().err
    assert "gt.npy: refusing" in error and "system" in error and "Traceback" not in error


@pytest.mark.parametrize(
    "payload",
    [
        # _reconstruct with a subtype that is not numpy.ndarray (here: numpy.dtype)
        b"\x80\x02cnumpy.core.multiarray\n_reconstruct\ncnumpy\ndtype\nK\x00\x85U\x01b\x87R.",
        # calling the ndarray marker
        b"\x80\x02cnumpy\nndarray\nK\x03\x85R.",
        # a structured dtype (object fields could alias raw bytes)
        b"\x80\x02cnumpy\ndtype\nU\x02V8\x89\x88\x87R.",
        # a scalar of object dtype
        b"\x80\x02cnumpy.core.multiarray\nscalar\ncnumpy\ndtype\nU\x02O8\x89\x88\x87RU\x08AAAAAAAA\x86R.",
        # an object array whose data is raw bytes instead of a list
        b"\x80\x02cnumpy.core.multiarray\n_reconstruct\ncnumpy\nndarray\nK\x00\x85U\x01b\x87R(K\x01K\x01\x85"
        b"cnumpy\ndtype\nU\x02O8\x89\x88\x87R(K\x03U\x01|NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK?tb\x89U\x08AAAAAAAAtb.",
        # a float array announcing more bytes than it has
        b"\x80\x02cnumpy.core.multiarray\n_reconstruct\ncnumpy\nndarray\nK\x00\x85U\x01b\x87R(K\x01K\x10\x85"
        b"cnumpy\ndtype\nU\x02f8\x89\x88\x87R(K\x03U\x01<NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK\x00tb\x89U\x08AAAAAAAAtb.",
    ],
    ids=["reconstruct-subtype", "call-ndarray", "structured-dtype", "object-scalar", "object-raw-bytes", "short-data"],
)
def test_numpy_tricks_are_refused(tmp_path, payload):
    path = _write_object_npy(tmp_path / "tricky.npy", payload, (1,))
    with pytest.raises(ValueError, match=r"tricky\.npy"):
        read_npy(path, what="anything", allow_objects=True)


def test_restricted_reader_matches_np_load(tmp_path):
    """Synthetic object arrays with every allowed ingredient read exactly as np.load reads them."""
    fortran = np.empty((2, 3), dtype=object, order="F")
    for index in range(6):
        fortran.flat[index] = [index, float(index)]
    items = [
        np.arange(3),
        [np.int64(4), 5, 2**70, np.float32(1.5), True, None, "text", b"bytes", {"k": (1, 2.5)}],
        np.asfortranarray(np.arange(6.0).reshape(2, 3)).astype(">f4"),
        np.array(["ab", "c"]),
        np.zeros((0, 3), dtype=np.complex64),
        fortran,
        {1, 2},
        complex(1, 2),
    ]
    path = tmp_path / "mixed.npy"
    np.save(path, _object_array(items), allow_pickle=True)
    expected = np.load(path, allow_pickle=True)
    got = read_npy(path, what="anything", allow_objects=True)
    assert got.shape == expected.shape and got.dtype == object
    for mine, theirs in zip(got, expected, strict=True):
        assert type(mine) is type(theirs)
        if isinstance(theirs, np.ndarray):
            assert mine.dtype == theirs.dtype and mine.shape == theirs.shape
            assert mine.flags.f_contiguous == theirs.flags.f_contiguous
            assert mine.tolist() == theirs.tolist()
        else:
            assert mine == theirs


@pytest.mark.realdata
def test_real_legacy_files_identical_to_np_load(corridor_dir, corridor_matches_dir):
    """Every legacy file of the shared data: same structure, dtypes and bytes as the old np.load path."""
    paths = [corridor_dir / "ground_truth_new.npy", *sorted(corridor_matches_dir.glob("*/precomputed_data*.npy"))]
    assert len(paths) == 11
    for path in paths:
        expected = np.load(path, allow_pickle=True, encoding="latin1")
        got = read_npy(path, what="a legacy file", allow_objects=True)
        assert got.shape == expected.shape and got.dtype == expected.dtype == object
        for mine, theirs in zip(got.ravel(), expected.ravel(), strict=True):
            assert type(mine) is type(theirs), path
            if isinstance(theirs, np.ndarray):
                assert mine.dtype == theirs.dtype and mine.shape == theirs.shape, path
                assert mine.tobytes() == theirs.tobytes(), path  # exact: the same bytes, no arithmetic
            else:
                assert mine == theirs, path
        if path.name.startswith("precomputed"):
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # no pickle warning any more: nothing unsafe happens
                matrix = load_vprbench_similarity(path)
            np.testing.assert_array_equal(matrix, np.asarray(expected[3], dtype=np.float32))


# --------------------------------------------------------------------------------------------------------------
# Item 3: ground truth is never silently coerced


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ([[1.7, 2], [0]], r"query 0: 1\.7 is not a database index"),
        ([[2.0], [0]], r"query 0: 2\.0 is not a database index"),
        ([[True, False], [0]], r"query 0: True is not a database index"),
        ([[0], ["1"]], r"query 1: '1' is not a database index"),
        ([[0], [-1]], r"query 1 must be database indices .* got -1"),
        ([[0], [4]], r"query 1 must be database indices \(an integer in \[0, 4\)\), got 4"),
        ([[0], [2**70]], r"query 1 must be database indices .* got 1180591620717411303424"),
    ],
)
def test_json_ground_truth_rejects_non_indices(tmp_path, content, match):
    path = tmp_path / "gt.json"
    path.write_text(json.dumps(content))
    with pytest.raises(ValueError, match=rf"gt\.json: positives of {match}"):
        load_ground_truth(path, n_database=4)


def test_json_ground_truth_errors_name_the_file(tmp_path):
    path = tmp_path / "gt.json"
    path.write_text("[[1],")
    with pytest.raises(ValueError, match=r"gt\.json is not valid JSON"):
        load_ground_truth(path)
    path.write_text(json.dumps({"positives": [[0], 1]}))
    with pytest.raises(ValueError, match=r"gt\.json: expected a JSON list of lists"):
        load_ground_truth(path)
    path.write_bytes(b"\xff\xfe[[0]]")
    with pytest.raises(ValueError, match=r"gt\.json is not a UTF-8 text file"):
        load_ground_truth(path)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("0\n-1\n", r"gt\.txt: positives of query 1 must be database indices .* got -1"),
        ("0\n1.5\n", r"gt\.txt:2: .*query 1\), got '1\.5'"),
        ("0\n1_0\n", r"gt\.txt:2: .*got '1_0'"),
        ("0\n9\n", r"gt\.txt: positives of query 1 must be database indices \(an integer in \[0, 4\)\), got 9"),
    ],
)
def test_text_ground_truth_rejects_non_indices(tmp_path, text, match):
    path = tmp_path / "gt.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        load_ground_truth(path, n_database=4)


def test_positives_from_lists_rejects_floats_and_booleans():
    with pytest.raises(ValueError, match=r"query 0: 1\.7 is not a database index"):
        positives_from_lists([[1.7]], n_database=3)
    with pytest.raises(ValueError, match=r"query 1: True is not a database index"):
        positives_from_lists([[0], [True]], n_database=3)
    with pytest.raises(ValueError, match=r"query 0: 1\.0 is not a database index"):
        positives_from_lists([np.array([1.0])], n_database=3)
    assert positives_from_lists([np.array([2, 0], dtype=np.uint8), (1,)], n_database=3).nnz == 3


def test_mask_ground_truth(tmp_path):
    path = tmp_path / "mask.npy"
    np.save(path, np.eye(3, 5) * 2)
    with pytest.raises(ValueError, match=r"mask\.npy: .*boolean \(or 0/1\).* 2\.0 at query 0, database image 0"):
        load_ground_truth(path)
    np.save(path, np.eye(3, 4, dtype=bool))  # narrower than the 5 database images
    with pytest.raises(ValueError, match=r"mask\.npy covers 4 database images, expected 5"):
        load_ground_truth(path, n_database=5)
    with pytest.raises(ValueError, match=r"mask\.npy has 3 queries, expected 2"):
        load_ground_truth(path, n_queries=2)


def _save_npz(path: Path, indptr, indices, **extra) -> Path:
    np.savez(path, positives_indptr=np.asarray(indptr), positives_indices=np.asarray(indices), **extra)
    return path


@pytest.mark.parametrize(
    ("indptr", "indices", "extra", "match"),
    [
        (
            [0, 1, 2],
            [0, -5],
            {"n_database": 4},
            r"gt\.npz: positives_indices holds -5, outside the database of n_database = 4",
        ),
        ([0, 1, 2], [0, 7], {"n_database": 4}, r"gt\.npz: positives_indices holds 7"),
        ([0, 1, 2], [0.0, 2.5], {}, r"gt\.npz: positives_indices must hold integers, got dtype float"),
        ([0, 1, 2], [True, False], {}, r"positives_indices must hold integers, got dtype bool"),
        ([0, 1, 2], np.array([0, 2**64 - 1], np.uint64), {}, r"positives_indices holds 18446744073709551615"),
        ([0, 2, 1], [0, 1], {}, r"positives_indptr must rise from 0 .* \(it decreases\)"),
        ([0, 1, 3], [0, 1], {}, r"positives_indptr must rise from 0 to the 2 entries"),
        ([0, 1, 2], [0, 1], {"n_database": -3}, r"n_database must be a non-negative integer, got -3"),
        ([0, 1, 2], [0, 1], {"n_database": 9}, r"gt\.npz: the ground truth covers 9 database images, expected 4"),
    ],
)
def test_npz_ground_truth_is_validated(tmp_path, indptr, indices, extra, match):
    path = _save_npz(tmp_path / "gt.npz", indptr, indices, **extra)
    with pytest.raises(ValueError, match=match):
        load_ground_truth(path, n_database=4 if "n_database" in extra else None)


def test_npz_ground_truth_file_errors(tmp_path):
    path = tmp_path / "gt.npz"
    path.write_bytes(b"")
    with pytest.raises(ValueError, match=r"gt\.npz is empty"):
        load_ground_truth(path)
    np.save(tmp_path / "array.npy", np.zeros(3))
    path.write_bytes((tmp_path / "array.npy").read_bytes())
    with pytest.raises(ValueError, match=r"gt\.npz is a \.npy array"):
        load_ground_truth(path)
    _save_npz(path, [0, 1], [0])
    path.write_bytes(path.read_bytes()[:40])
    with pytest.raises(ValueError, match=r"gt\.npz is not a readable \.npz archive"):
        load_ground_truth(path)


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda rows: rows.__setitem__((1, 1), [1.0]), r"positives of query 1: 1\.0 is not a database index"),
        (lambda rows: rows.__setitem__((1, 1), [True]), r"positives of query 1: True is not a database index"),
        (lambda rows: rows.__setitem__((1, 1), [-2]), r"positives of query 1 must be database indices .* got -2"),
        (lambda rows: rows.__setitem__((1, 1), [3]), r"positives of query 1 .*\[0, 3\)\), got 3"),
        (lambda rows: rows.__setitem__((1, 1), "1"), r"positives of query 1 must be a list of database indices"),
        (
            lambda rows: rows.__setitem__((2, 0), 2.0),
            r"row 2: the query index must be an integer in \[0, 3\), got 2\.0",
        ),
        (lambda rows: rows.__setitem__((2, 0), 5), r"row 2: the query index must be an integer in \[0, 3\), got 5"),
        (lambda rows: rows.__setitem__((2, 0), 1), r"row 2: query 1 appears twice"),
    ],
)
def test_vprbench_ground_truth_is_validated(tmp_path, edit, match):
    rows = _ground_truth_rows(3)
    edit(rows)
    path = tmp_path / "ground_truth_new.npy"
    np.save(path, rows, allow_pickle=True)
    with pytest.raises(ValueError, match=rf"ground_truth_new\.npy: {match}"):
        load_ground_truth(path, n_database=3)


def test_vprbench_ground_truth_shapes(tmp_path):
    rows = _ground_truth_rows(3)
    rows[1, 1] = np.array([0, 2])  # an array of positives, and a single int, are lists of indices too
    rows[2, 1] = 1
    path = tmp_path / "ground_truth_new.npy"
    np.save(path, rows, allow_pickle=True)
    positives = load_vprbench_ground_truth(path, n_database=3)
    assert positives.toarray().tolist() == [[True, False, False], [True, False, True], [False, True, False]]
    np.save(path, _object_array([1, 2, 3]), allow_pickle=True)
    with pytest.raises(ValueError, match=r"ground_truth_new\.npy: expected VPR-Bench ground truth .* shape \(3,\)"):
        load_vprbench_ground_truth(path)


def test_matrix_with_narrow_mask_or_out_of_range_gt_is_an_error(tmp_path):
    """Before: a mask narrower than the matrix was padded, and the message then blamed 'no positive'."""
    np.save(tmp_path / "sim.npy", np.random.default_rng(0).uniform(size=(3, 5)).astype(np.float32))
    np.save(tmp_path / "mask.npy", np.eye(3, 4, dtype=bool))
    with pytest.raises(ValueError, match=r"mask\.npy covers 4 database images, expected 5"):
        read_results(tmp_path / "sim.npy", ground_truth=tmp_path / "mask.npy")
    (tmp_path / "gt.json").write_text("[[1.7, 2], [0], [1]]")
    with pytest.raises(ValueError, match=r"gt\.json: positives of query 0: 1\.7"):
        read_results(tmp_path / "sim.npy", ground_truth=tmp_path / "gt.json")
    (tmp_path / "gt.txt").write_text("0\n1\n5\n")
    with pytest.raises(ValueError, match=r"gt\.txt: positives of query 2 .*\[0, 5\)\), got 5"):
        read_results(tmp_path / "sim.npy", ground_truth=tmp_path / "gt.txt")
    (tmp_path / "gt.txt").write_text("0\n1\n")
    with pytest.raises(ValueError, match=r"gt\.txt has 2 queries, expected 3"):
        read_results(tmp_path / "sim.npy", ground_truth=tmp_path / "gt.txt")


# --------------------------------------------------------------------------------------------------------------
# Item 5: .npy reading errors and the similarity matrix itself


def _gt_for(tmp_path: Path, n_queries: int) -> Path:
    path = tmp_path / "gt.txt"
    path.write_text("\n".join("0" for _ in range(n_queries)) + "\n")
    return path


def _npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=True)
    return buffer.getvalue()


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"", r"bad\.npy is empty \(0 bytes\); expected .*similarity matrix"),
        (b"\x93NUM", r"bad\.npy is truncated \(4 bytes, not even a \.npy header\)"),
        (b"0.1 0.2\n0.3 0.4\n", r"bad\.npy is not a NumPy \.npy file \(it holds text\); expected .*similarity matrix"),
        (b"PK\x03\x04rest", r"bad\.npy is not a NumPy \.npy file \(it holds a zip archive"),
        (_npy_bytes(np.ones((4, 5), np.float32))[:60], r"bad\.npy is truncated: its \.npy header is incomplete"),
        (_npy_bytes(np.ones((4, 5), np.float32))[:140], r"bad\.npy is truncated: .*\(4, 5\) \(80 bytes of data\)"),
        (_npy_bytes(_precomputed(np.eye(3)))[:300], r"bad\.npy is truncated: its pickled data ends early"),
        (b"\x93NUMPY\x01\x00\x10\x00{'descr': 'xy'}\n", r"bad\.npy has an invalid \.npy header"),
    ],
    ids=["empty", "magic-only", "text", "zip", "header-cut", "data-cut", "pickle-cut", "bad-header"],
)
def test_broken_npy_similarity_is_one_clear_error(tmp_path, content, match):
    path = tmp_path / "bad.npy"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=match):
        read_results(path, ground_truth=_gt_for(tmp_path, 4))


@pytest.mark.parametrize(
    "content", [b"", b"not numpy\n", _npy_bytes(np.eye(2, dtype=bool))[:100]], ids=["empty", "text", "truncated"]
)
def test_broken_npy_ground_truth_is_one_clear_error(tmp_path, content):
    np.save(tmp_path / "sim.npy", np.eye(2, dtype=np.float32))
    path = tmp_path / "gt.npy"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=r"gt\.npy (is empty|is not a NumPy|is truncated).*expected ground truth"):
        read_results(tmp_path / "sim.npy", ground_truth=path)


def test_format_that_does_not_match_the_file(tmp_path):
    np.save(tmp_path / "sim.npy", np.eye(3, dtype=np.float32))
    gt = _gt_for(tmp_path, 3)
    with pytest.raises(ValueError, match=r"sim\.npy is a \.npy array, not a retrieval file"):
        read_results(tmp_path / "sim.npy", ground_truth=gt, file_format="retrieval")
    with pytest.raises(ValueError, match=r"sim\.npy is a plain float32 array of shape \(3, 3\), not VPR-Bench"):
        read_results(tmp_path / "sim.npy", ground_truth=gt, file_format="vprbench")
    np.save(tmp_path / "matches.npy", _precomputed(np.eye(3)), allow_pickle=True)
    with pytest.raises(ValueError, match=r"matches\.npy holds Python objects .*format 'vprbench' or 'auto'"):
        read_results(tmp_path / "matches.npy", ground_truth=gt, file_format="matrix")
    np.save(tmp_path / "objects.npy", _object_array([1, "a"]), allow_pickle=True)
    with pytest.raises(ValueError, match=r"objects\.npy holds Python objects .*shape \(2,\)"):
        read_results(tmp_path / "objects.npy", ground_truth=gt)


def test_vprbench_matches_in_any_file_name_are_read_safely(tmp_path):
    """The restricted reader makes 'auto' safe on any name: no more 'pass --format vprbench' dead end."""
    similarity = np.random.default_rng(2).uniform(size=(4, 6))
    np.save(tmp_path / "renamed.npy", _precomputed(similarity), allow_pickle=True)
    retrieval = read_results(tmp_path / "renamed.npy", ground_truth=_gt_for(tmp_path, 4))
    np.testing.assert_array_equal(retrieval.indices[:, 0], similarity.argmax(axis=1))
    np.testing.assert_allclose(retrieval.scores[:, 0], similarity.max(axis=1).astype(np.float32), rtol=1e-6)


@pytest.mark.parametrize(
    ("matrix", "match"),
    [
        (
            np.array([["a", "b"], ["c", "d"]]),
            r"sim\.npy: a similarity matrix must hold integers or floats, got dtype <U1",
        ),
        (np.eye(2, dtype=bool), r"must hold integers or floats, got dtype bool"),
        (np.eye(2, dtype=complex), r"must hold integers or floats, got dtype complex128"),
        (np.ones(3, np.float32), r"sim\.npy: a similarity matrix must be 2-D"),
        (np.zeros((0, 3), np.float32), r"sim\.npy: the similarity matrix is empty \(shape \(0, 3\)\)"),
        (np.zeros((2, 0), np.float32), r"sim\.npy: the similarity matrix is empty \(shape \(2, 0\)\)"),
        (np.array([[0.1, 0.2], [0.3, np.nan]]), r"sim\.npy: .*holds nan at query 1, database image 1 \(1 such"),
        (np.array([[0.1, np.inf], [np.inf, 0.2]]), r"sim\.npy: .*holds inf at query 0, database image 1 \(2 such"),
    ],
    ids=["str", "bool", "complex", "1-D", "no-queries", "no-database", "nan", "inf"],
)
def test_bad_similarity_matrix_is_named(tmp_path, matrix, match):
    np.save(tmp_path / "sim.npy", matrix)
    with pytest.raises(ValueError, match=match):
        load_similarity_matrix(tmp_path / "sim.npy")


def test_bad_vprbench_matrix_is_named(tmp_path):
    similarity = np.eye(3)
    similarity[1, 2] = np.nan
    np.save(tmp_path / "precomputed_data_corrected.npy", _precomputed(similarity), allow_pickle=True)
    with pytest.raises(ValueError, match=r"precomputed_data_corrected\.npy: .*nan at query 1, database image 2"):
        load_similarity_matrix(tmp_path / "precomputed_data_corrected.npy")
    content = _precomputed(np.eye(3))
    content[3] = np.array([["a"] * 3] * 3)
    np.save(tmp_path / "precomputed_data_corrected.npy", content, allow_pickle=True)
    with pytest.raises(ValueError, match=r"item 3 should be the numeric .* got a <U1 array"):
        load_vprbench_similarity(tmp_path / "precomputed_data_corrected.npy")
    content = _precomputed(np.eye(3))
    content[0] = np.array([0.0, 1.5, 2.0])  # whole floats are VPR-Bench's own (ap-gem-r101); 1.5 is no index
    np.save(tmp_path / "precomputed_data_corrected.npy", content, allow_pickle=True)
    with pytest.raises(ValueError, match=r"expected query indices 0\.\.2 in order"):
        load_vprbench_similarity(tmp_path / "precomputed_data_corrected.npy")
    content[0] = np.array(["0", "1", "2"])
    np.save(tmp_path / "precomputed_data_corrected.npy", content, allow_pickle=True)
    with pytest.raises(ValueError, match=r"item 0 should be the query indices 0\.\.2"):
        load_vprbench_similarity(tmp_path / "precomputed_data_corrected.npy")


def test_minus_inf_keeps_its_meaning(tmp_path):
    """-inf = this database image is no candidate (the retrieval convention): accepted, ranked last, index -1."""
    matrix = np.array([[0.9, -np.inf, 0.5], [0.1, 0.8, 0.7]], dtype=np.float32)
    np.save(tmp_path / "sim.npy", matrix)
    retrieval = read_results(tmp_path / "sim.npy", ground_truth=_gt_for(tmp_path, 2))
    assert retrieval.indices[0].tolist() == [0, 2, -1]
    assert retrieval.indices[1].tolist() == [1, 2, 0]


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["{tmp}/empty.npy"], "empty.npy is empty (0 bytes)"),
        (["{tmp}/text.npy"], "text.npy is not a NumPy .npy file (it holds text)"),
        (["{tmp}/sim.npy", "--format", "retrieval"], "sim.npy is a .npy array, not a retrieval file"),
        (["{tmp}/sim.npy", "--format", "vprbench"], "sim.npy is a plain float32 array of shape (3, 3)"),
        (["{tmp}/sim.npy", "--gt", "{tmp}/float.json"], "float.json: positives of query 0: 1.7 is not a database"),
    ],
    ids=["empty", "text", "retrieval-on-npy", "vprbench-on-matrix", "float-gt"],
)
def test_cli_one_line_error(tmp_path, capsys, args, expected):
    np.save(tmp_path / "sim.npy", np.eye(3, dtype=np.float32))
    (tmp_path / "empty.npy").write_bytes(b"")
    (tmp_path / "text.npy").write_text("1 2 3\n")
    (tmp_path / "float.json").write_text("[[1.7, 2], [0], [1]]")
    gt = ["--gt", str(_gt_for(tmp_path, 3))] if "--gt" not in args else []
    assert cli_main(["evaluate", *[arg.format(tmp=tmp_path) for arg in args], *gt]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "Traceback" not in error
    assert str(tmp_path / expected.split(" ")[0]) in error and expected in error
