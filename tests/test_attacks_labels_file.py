"""Issue 42, rows 8, 9 and 11 and the labels file's clear errors, written as the attacks: labels made for one pool
used on another, a labels file emptied by a failed write, a gate file whose digest two fields share, a labels file
saved by a spreadsheet (byte-order mark) or not text at all. Then the labels file's own edges: a query labelled both
ways, a FIFO, a huge index, and what a user wrote in the file that the reader does not interpret."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from vpr_uncertainty.calibration import Gate
from vpr_uncertainty.calibration.fit import calibrate_arrays
from vpr_uncertainty.cli import main

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy")

TARGET = ["--target-precision", "0.9"]


@pytest.fixture
def pools(corridor_matches_dir, tmp_path):
    """AMOSNet's and CoHOG's corridor matrices, as a user names them."""
    for method in ("AMOSNet", "CoHOG"):
        shutil.copy(corridor_matches_dir / method / "precomputed_data_corrected.npy", tmp_path / f"{method}.npy")
    return tmp_path / "AMOSNet.npy", tmp_path / "CoHOG.npy"


def _errors(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.strip() and not line.startswith("warning:")]


def _hand_made(path, rows: str = "") -> None:
    """A labels file a person started: AMOSNet's first 40 labels in the order the tool asks (its ground truth)."""
    path.write_text(
        "query,correct\n69,1\n70,1\n58,1\n63,1\n75,1\n62,1\n56,1\n55,1\n68,1\n65,1\n67,1\n57,1\n66,1\n73,1\n60,1\n"
        "64,1\n74,1\n71,1\n59,1\n61,1\n72,1\n54,1\n53,1\n76,1\n52,1\n51,1\n49,1\n50,1\n48,1\n77,1\n" + rows  # 30 labels
    )


# --- row 8: labels for another pool ---------------------------------------------------------------------------------


def test_labels_the_tool_wrote_for_amosnet_are_refused_for_cohog(pools, corridor_dir, tmp_path, capsys):
    amosnet, cohog = pools
    labels = tmp_path / "labels.csv"
    gt = ["--gt", str(corridor_dir / "ground_truth_new.npy")]
    assert main(["calibrate", str(amosnet), *gt, "--sequential", str(labels), *TARGET]) == 0
    capsys.readouterr()
    before = labels.read_bytes()
    assert main(["calibrate", str(cohog), "--sequential", str(labels), *TARGET, "--out", str(tmp_path / "g.json")]) == 2
    (error,) = _errors(capsys.readouterr().err)
    fingerprints = re.findall(r"pool ([0-9a-f]{16})", error)
    assert len(set(fingerprints)) == 2 and "AMOSNet.npy" in error and "CoHOG.npy" in error, error
    assert labels.read_bytes() == before and not (tmp_path / "g.json").exists()


def test_a_hand_made_file_is_adopted_by_its_first_pool_then_refused_for_another(pools, tmp_path, capsys):
    amosnet, cohog = pools
    labels = tmp_path / "labels.csv"
    _hand_made(labels)
    hand = labels.read_text()
    assert main(["calibrate", str(amosnet), "--sequential", str(labels), *TARGET]) == 0
    out = capsys.readouterr().out
    assert "carried no pool fingerprint: adopted for pool" in out and "30 of 111 queries labelled" in out
    first, rest = labels.read_text().split("\n", 1)
    assert first.startswith("# vpr-uncertainty labels of pool ") and "AMOSNet.npy" in first and rest == hand
    assert main(["calibrate", str(amosnet), "--sequential", str(labels), *TARGET]) == 0
    assert "adopted" not in capsys.readouterr().out  # once
    assert main(["calibrate", str(cohog), "--sequential", str(labels), *TARGET]) == 2
    assert "not of this pool" in capsys.readouterr().err


def test_the_pool_fingerprint_is_of_the_values_and_k_not_of_the_file(pools, corridor_dir, tmp_path, capsys):
    """The same scores read from a VPR-Bench matrix and from a retrieval file (float32 or float64) are one pool; k
    is part of it."""
    from vpr_uncertainty.calibration.labels_file import pool_fingerprint

    amosnet, _ = pools
    scores = -np.sort(-np.random.default_rng(0).random((50, 20)), axis=1).astype(np.float32)
    assert pool_fingerprint(scores, 10) == pool_fingerprint(scores.astype(np.float64), 10)
    assert pool_fingerprint(scores, 10) == pool_fingerprint(scores[:, :10].copy(), 10)
    assert pool_fingerprint(scores, 10) != pool_fingerprint(scores, 5)
    labels = tmp_path / "labels.csv"
    assert main(["calibrate", str(amosnet), "--sequential", str(labels), *TARGET]) == 0
    gt = ["--gt", str(corridor_dir / "ground_truth_new.npy")]
    assert main(["subset", str(amosnet), *gt, "--out", str(tmp_path / "pool.npz")]) == 0
    assert main(["calibrate", str(tmp_path / "pool.npz"), "--sequential", str(labels), *TARGET]) == 0
    assert main(["calibrate", str(amosnet), "--sequential", str(labels), *TARGET, "--k", "5"]) == 2
    assert "k=10), not of this pool" in capsys.readouterr().err


# --- row 9: a write that fails ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("with_truth", [True, False], ids=["labels-from-gt", "adopting-a-hand-made-file"])
def test_a_write_past_ulimit_leaves_the_labels_file_as_it_was(pools, corridor_dir, tmp_path, with_truth):
    """Row 9 (--gt appends the labels it gives), and the new write of the pool line (an own edge: without --gt
    nothing was written before)."""
    amosnet, _ = pools
    labels = tmp_path / "mylabels.csv"
    _hand_made(labels)
    before = labels.read_bytes()
    gt = f"--gt {corridor_dir / 'ground_truth_new.npy'}" if with_truth else ""
    command = f"ulimit -f 0; exec {sys.executable} -m vpr_uncertainty.cli calibrate {amosnet} {gt} "
    run = subprocess.run(
        ["bash", "-c", command + f"--sequential {labels} --target-precision 0.9"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
        timeout=300,
    )
    assert labels.read_bytes() == before
    (error,) = _errors(run.stderr)
    assert run.returncode == 1 and str(labels) in error and "too large" in error, run.stderr
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary file left


# --- row 11: two fields of a gate file that share a digest name -------------------------------------------------------


@pytest.fixture
def gate_file(tmp_path):
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((300, 10)), axis=1).astype(np.float32)
    correct = scores[:, 0] - scores[:, 1] + rng.normal(0, 0.05, 300) > 0.05
    return calibrate_arrays(scores, correct, k=10, target_precision=0.8, rankings=["margin"]).save(tmp_path / "g.json")


@pytest.mark.parametrize(("field", "key"), [("rule", "coef"), ("rule", "intercept"), ("calibrator", "coef")])
def test_an_edited_field_with_its_old_value_under_a_dotted_top_level_name_is_refused(gate_file, field, key):
    data = json.loads(gate_file.read_text())
    old = data[field][key]
    data[field][key] = [-c for c in old] if isinstance(old, list) else old + 5
    data[f"{field}.{key}"] = old  # flattened, this name was the edited field's: the digest matched
    gate_file.write_text(json.dumps(data, indent=2))
    with pytest.raises(ValueError) as error:
        Gate.load(gate_file)
    message = str(error.value)
    assert f'"{field}.{key}", {field}.{key} changed since calibrate' in message and "\n" not in message, message


def test_gate_files_written_before_keep_their_digest(gate_file):
    """The names of fields without '.' or '~' (every field the toolkit writes) are as before: old files load."""
    import hashlib

    data = json.loads(gate_file.read_text())
    flat = {}
    for key, value in data.items():  # the digest as format_version 3 computed it until now
        if key != "digest":
            flat.update(
                {f"{key}.{n}": v for n, v in value.items()} if isinstance(value, dict) and value else {key: value}
            )
    canonical = {n: json.dumps(v, sort_keys=True, separators=(",", ":")).encode() for n, v in flat.items()}
    assert data["digest"] == {n: hashlib.sha256(c).hexdigest()[:16] for n, c in sorted(canonical.items())}
    assert Gate.load(gate_file).to_dict() == data


# --- clear errors: what spreadsheets save, and what is not a labels file ----------------------------------------------


@pytest.mark.parametrize(("newline", "quote"), [("\n", ""), ("\r\n", ""), ("\r\n", '"')])
def test_a_labels_file_with_a_byte_order_mark_is_read(pools, tmp_path, capsys, newline, quote):
    amosnet, _ = pools
    labels = tmp_path / "labels.csv"
    rows = [f"{quote}{a}{quote},{quote}{b}{quote}" for a, b in [("query", "correct"), ("69", "1"), ("70", "yes")]]
    labels.write_bytes(("\ufeff" + newline.join([*rows, ""])).encode("utf-8"))
    assert main(["calibrate", str(amosnet), "--sequential", str(labels), *TARGET]) == 0
    assert "2 of 111 queries labelled" in capsys.readouterr().out


@pytest.mark.parametrize(
    "content", [b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", b"\x00" * 64, "query,correct\n69,1\n".encode("utf-16")]
)
def test_a_binary_labels_file_is_one_line_naming_it(pools, tmp_path, capsys, content):
    amosnet, _ = pools
    labels = tmp_path / "labels.csv"
    labels.write_bytes(content)
    assert main(["calibrate", str(amosnet), "--sequential", str(labels), *TARGET]) == 2
    (error,) = _errors(capsys.readouterr().err)
    assert f"{labels}: not a labels file" in error and "expected UTF-8 text" in error, error
    assert labels.read_bytes() == content


# --- the labels file's own edges --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("rows", "expected"),
    [
        ("5,1\n5,0\n", "line 33: query 5 is labelled otherwise on line 32"),
        ("1" * 5000 + ",1\n", "line 32: query must be a pool index in [0, 111)"),
        (",1\n", "line 32: query must be a pool index"),
    ],
)
def test_malformed_rows_are_refused_naming_the_line(pools, tmp_path, capsys, rows, expected):
    amosnet, _ = pools
    labels = tmp_path / "labels.csv"
    _hand_made(labels, rows)
    before = labels.read_bytes()
    assert main(["calibrate", str(amosnet), "--sequential", str(labels), *TARGET]) == 2
    (error,) = _errors(capsys.readouterr().err)
    assert f"{labels}, {expected}" in error, error
    assert labels.read_bytes() == before


def test_comments_and_extra_columns_are_kept_when_labels_are_appended(pools, corridor_dir, tmp_path, capsys):
    amosnet, _ = pools
    labels = tmp_path / "labels.csv"
    mine = "# labelled by A. on the lab screen\nquery,correct,who\n69,1,anna\n70,1,anna\n\n# day two\n58,1,ben"
    labels.write_text(mine)
    gt = ["--gt", str(corridor_dir / "ground_truth_new.npy")]
    assert main(["calibrate", str(amosnet), *gt, "--sequential", str(labels), *TARGET]) == 0
    first, rest = labels.read_text().split("\n", 1)
    assert first.startswith("# vpr-uncertainty labels of pool ") and rest.startswith(mine + "\n")
    assert "labelled 72 of 111 queries" in capsys.readouterr().out
    appended = rest[len(mine) + 1 :].splitlines()
    assert len(appended) == 69 and all(re.fullmatch(r"\d+,[01]", row) for row in appended)


def test_a_fifo_named_as_labels_file_is_refused_not_read(pools, tmp_path):
    amosnet, _ = pools
    fifo = tmp_path / "labels.csv"
    os.mkfifo(fifo)
    command = [sys.executable, "-m", "vpr_uncertainty.cli", "calibrate", str(amosnet), "--sequential", str(fifo)]
    run = subprocess.run([*command, *TARGET], capture_output=True, text=True, timeout=60)  # blocked for ever
    assert run.returncode == 2 and "is a FIFO, not a regular file" in run.stderr, run.stderr


def test_the_gate_of_a_sequential_session_names_its_pool(pools, corridor_dir, tmp_path):
    amosnet, _ = pools
    gt, gate = ["--gt", str(corridor_dir / "ground_truth_new.npy")], tmp_path / "gate.json"
    argv = ["calibrate", str(amosnet), *gt, "--sequential", str(tmp_path / "l.csv"), *TARGET, "--out", str(gate)]
    assert main(argv) == 0
    pool = re.search(r"pool ([0-9a-f]{16})", (tmp_path / "l.csv").read_text())[1]
    assert Gate.load(gate).info["calibration"]["pool"] == pool
