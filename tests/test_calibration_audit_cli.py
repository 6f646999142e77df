"""`calibrate --machine-labels --audit` on the real corridor: the loop a person runs (and --gt, which runs it from
the ground truth), and the attacks on its files (DESIGN.md, "Attack your own edges")."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from vpr_uncertainty.calibration import Gate
from vpr_uncertainty.calibration.labels_file import MachineLabels, pool_fingerprint, write_machine_labels
from vpr_uncertainty.cli import main
from vpr_uncertainty.data import read_pool, read_results
from vpr_uncertainty.evaluation import correct_at_n
from vpr_uncertainty.retrieval import save_retrieval

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy")

METHODS = ("AMOSNet", "AlexNet_VPR", "CALC", "CoHOG", "HOG", "HybridNet", "NetVLAD", "RegionVLAD", "ap-gem-r101",
           "denseVLAD")  # fmt: skip


@pytest.fixture
def corridor(corridor_dir, corridor_matches_dir, tmp_path):
    """CoHOG's and AMOSNet's pools, each with machine labels (3 of the 9 other methods' top-1 within ±2 frames)
    written under its pool's fingerprint, and the ground truth."""
    gt = corridor_dir / "ground_truth_new.npy"
    tops = {m: read_pool(corridor_matches_dir / m / "precomputed_data_corrected.npy").indices[:, 0] for m in METHODS}
    found = {}
    for method in ("CoHOG", "AMOSNet"):
        pool = shutil.copy(corridor_matches_dir / method / "precomputed_data_corrected.npy", tmp_path / f"{method}.npy")
        others = np.stack([top for name, top in tops.items() if name != method])
        correct = (np.abs(others - tops[method]) <= 2).sum(axis=0) >= 3
        labels = MachineLabels(correct, np.full(111, np.nan), ["agreement:frames=2"] * 111)
        scores = read_pool(pool).scores
        write_machine_labels(tmp_path / f"{method}-machine.csv", labels, pool=pool_fingerprint(scores, 10))
        found[method] = tmp_path / f"{method}.npy", tmp_path / f"{method}-machine.csv"
    return found, gt


def _run(capsys, *arguments) -> tuple[int, str, str]:
    status = main(["calibrate", *map(str, arguments), "--target-precision", "0.9"])
    captured = capsys.readouterr()
    return status, captured.out, "\n".join(x for x in captured.err.splitlines() if not x.startswith("warning:"))


def test_labelling_by_hand_reaches_what_gt_reaches(corridor, tmp_path, capsys):
    (pool, machine), gt = corridor[0]["CoHOG"], corridor[1]
    truth = correct_at_n(*(lambda r: (r.indices, r.positives))(read_results(pool, ground_truth=gt)), 1)
    by_gt, by_hand = tmp_path / "gt.csv", tmp_path / "hand.csv"
    status, out, err = _run(capsys, pool, "--machine-labels", machine, "--audit", by_gt, "--gt", gt, "--out",
                            tmp_path / "gt.json")  # fmt: skip
    assert status == 0 and "a simulation" in out and "certified (probability >= 0.9)" in out, err
    # the person's loop: no label yet, a machine-labelled gate; then one label per run, as asked
    status, out, _ = _run(capsys, pool, "--machine-labels", machine, "--audit", by_hand, "--out", tmp_path / "m.json")
    assert status == 0 and "machine-labelled, not certified" in out and "certified (probability" not in out
    machine_gate = Gate.load(tmp_path / "m.json")
    assert machine_gate.precision_lower_bound is None and machine_gate.info["certificate"]["machine_labelled"]
    runs = 0
    while asked := re.search(r"label next: query (\d+)", out):
        query = int(asked[1])
        with open(by_hand, "a") as handle:
            handle.write(f"{query},{int(truth[query])}\n")
        status, out, err = _run(capsys, pool, "--machine-labels", machine, "--audit", by_hand, "--out",
                                tmp_path / "hand.json")  # fmt: skip
        assert status == 0, err
        runs += 1
    assert runs >= 10 and "done: no further label" in out
    rows = [line for line in by_hand.read_text().splitlines() if not line.startswith("#")]
    assert rows == [line for line in by_gt.read_text().splitlines() if not line.startswith("#")]
    hand, simulated = Gate.load(tmp_path / "hand.json"), Gate.load(tmp_path / "gt.json")
    assert hand.cut == simulated.cut and hand.precision_lower_bound == simulated.precision_lower_bound >= 0.9
    assert hand.info["audit"]["labelled"] == runs and hand.info["calibration"]["pool"] in by_hand.read_text()


def test_the_query_to_label_names_its_image_pair(corridor, tmp_path, capsys):
    (pool, machine), gt = corridor[0]["CoHOG"], corridor[1]
    retrieval = read_results(pool, ground_truth=gt)
    retrieval.query_names = np.array([f"query/{i:07d}.jpg" for i in range(111)])
    retrieval.database_names = np.array([f"ref/{i:07d}.jpg" for i in range(111)])
    named = save_retrieval(retrieval, tmp_path / "named.npz")
    status, out, err = _run(capsys, named, "--machine-labels", machine, "--audit", tmp_path / "a.csv")
    query = int(re.search(r"label next: query (\d+)", out)[1])
    top = retrieval.indices[query, 0]
    assert status == 0 and f"(query/{query:07d}.jpg -> ref/{top:07d}.jpg)" in out, err


def test_an_audit_of_another_pool_and_machine_labels_of_another_pool_are_refused(corridor, tmp_path, capsys):
    (cohog, cohog_machine), (amosnet, amosnet_machine) = corridor[0]["CoHOG"], corridor[0]["AMOSNet"]
    audit = tmp_path / "audit.csv"
    assert _run(capsys, cohog, "--machine-labels", cohog_machine, "--audit", audit, "--gt", corridor[1])[0] == 0
    before = audit.read_bytes()
    status, _, err = _run(capsys, amosnet, "--machine-labels", amosnet_machine, "--audit", audit)
    assert status == 2 and "not of this pool" in err and audit.read_bytes() == before
    fresh = tmp_path / "fresh.csv"
    status, _, err = _run(capsys, cohog, "--machine-labels", amosnet_machine, "--audit", fresh)
    assert status == 2 and "AMOSNet-machine.csv" in err and not fresh.exists(), err


def test_an_audit_that_is_the_machine_labels_is_refused(corridor, tmp_path, capsys):
    pool, machine = corridor[0]["CoHOG"]
    before = machine.read_bytes()
    link = tmp_path / "link.csv"
    link.symlink_to(machine)
    for audit in (machine, link):
        status, _, err = _run(capsys, pool, "--machine-labels", machine, "--audit", audit, "--gt", corridor[1])
        assert status == 2 and "--audit" in err and "--machine-labels" in err and machine.read_bytes() == before
    copy = shutil.copy(machine, tmp_path / "copy.csv")  # a machine-labels file given as the audit
    status, _, err = _run(capsys, pool, "--machine-labels", machine, "--audit", copy, "--gt", corridor[1])
    assert status == 2 and "holds machine labels" in err and copy.read_bytes() == before
    status, _, err = _run(capsys, pool, "--machine-labels", machine, "--audit", tmp_path / "a.csv", "--out",
                          tmp_path / "a.csv")  # fmt: skip
    assert status == 2 and "never overwrites" in err and not (tmp_path / "a.csv").exists()


def test_drawing_again_after_labelling_is_refused(corridor, tmp_path, capsys):
    pool, machine = corridor[0]["CoHOG"]
    audit = tmp_path / "audit.csv"
    assert _run(capsys, pool, "--machine-labels", machine, "--audit", audit, "--gt", corridor[1])[0] == 0
    before = audit.read_bytes()
    for change in (["--seed", "1"], ["--audit-size", "60"], ["--delta", "0.2"], ["--rankings", "SU"]):
        status, _, err = _run(capsys, pool, "--machine-labels", machine, "--audit", audit, *change)
        assert (
            status == 2 and "drawing again after labelling voids the guarantee" in err and audit.read_bytes() == before
        )
    other = tmp_path / "other-machine.csv"  # the labeler rerun after the audit was seen: other machine labels
    text = machine.read_text().splitlines()
    text[2] = text[2].replace(",1,", ",0,") if ",1," in text[2] else text[2].replace(",0,", ",1,")
    other.write_text("\n".join(text) + "\n")
    status, _, err = _run(capsys, pool, "--machine-labels", other, "--audit", audit)
    assert status == 2 and "machine labels" in err and audit.read_bytes() == before


def test_a_write_past_ulimit_leaves_the_audit_file_as_it_was(corridor, tmp_path):
    (pool, machine), gt = corridor[0]["CoHOG"], corridor[1]
    audit = tmp_path / "audit.csv"
    audit.write_text("query,correct\n")
    before = audit.read_bytes()
    command = f"ulimit -f 0; exec {sys.executable} -m vpr_uncertainty.cli calibrate {pool} --gt {gt} "
    run = subprocess.run(
        ["bash", "-c", command + f"--machine-labels {machine} --audit {audit} --target-precision 0.9"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
        timeout=300,
    )
    assert run.returncode == 1 and str(audit) in run.stderr and "too large" in run.stderr, run.stderr
    assert audit.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary file left
