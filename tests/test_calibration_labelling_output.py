"""What a person labelling reads (issue 45, items 3 and 4): the query to label next named by its image pair, a
contact sheet of the next pairs, and the gate's rule in the user's terms (the uncertainty and the direction it
accepts; a fitted rule as P(correct)), on hand-made gates and on the real corridor."""

from __future__ import annotations

import math
import os
import re
import shutil

import numpy as np
import pytest

from vpr_uncertainty import Gate, calibrate
from vpr_uncertainty.calibration import AuditCalibration, SequentialCalibration
from vpr_uncertainty.calibration.calibrator import Calibrator, ranking_rule
from vpr_uncertainty.calibration.labels_file import MachineLabels, pool_fingerprint, write_machine_labels
from vpr_uncertainty.cli import main
from vpr_uncertainty.data import read_pool, read_results
from vpr_uncertainty.evaluation import correct_at_n
from vpr_uncertainty.scores import statistical_uncertainty

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy")

RS_MODEL = Calibrator("logistic", ("RS",), mean=[0.0], scale=[1.0], coef=[-20.0], intercept=15.0, ranking="RS")


def _rows(n: int = 2000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return -np.sort(-rng.uniform(0.05, 0.95, size=(n, 10)), axis=1)


# --- item 4: the rule in the user's terms ---------------------------------------------------------------------


def test_an_uncertainty_rule_reads_as_the_uncertainty_at_most_the_cut():
    scores = _rows()
    su = statistical_uncertainty(scores, k=10).astype(np.float64)
    cut = float(np.median(su))
    gate = Gate(RS_MODEL, 10, -cut, rule=ranking_rule("SU"))  # confidence −SU ≥ −cut
    assert gate.acceptance == f"accept when SU <= {cut:.4g}" and f"rule='accept when SU <= {cut:.4g}'" in repr(gate)
    clear = np.abs(su - cut) > 1e-6  # float32 SU against the gate's float64 features
    assert (gate.accept(scores) == (su <= cut))[clear].all() and clear.sum() > 1900


def test_similarity_rules_read_as_at_least_the_cut():
    scores = _rows()
    margin = Gate(RS_MODEL, 10, 0.02, rule=ranking_rule("margin"))
    assert margin.acceptance == "accept when margin >= 0.02"
    assert (margin.accept(scores) == (scores[:, 0] - scores[:, 1] >= 0.02)).all()
    best = Gate(RS_MODEL, 10, 0.9, rule=ranking_rule("BM"))
    assert best.acceptance == "accept when BM >= 0.9" and (best.accept(scores) == (scores[:, 0] >= 0.9)).all()
    assert Gate(RS_MODEL, 10, 0.0, rule=ranking_rule("margin")).acceptance == "accept when margin >= 0"


def test_a_fitted_rule_reads_as_a_probability():
    scores = _rows()
    su = statistical_uncertainty(scores, k=10).astype(np.float64)
    # the gate's own calibrator: P(correct) >= 0.5 at confidence 0
    assert Gate(RS_MODEL, 10, 0.0).acceptance == "accept when P(correct) >= 0.5"
    # a fitted model other than the calibrator: its own P at the cut, named; σ(8 − 10 SU) ≥ 0.88
    model = Calibrator("logistic", ("SU",), mean=[0.0], scale=[1.0], coef=[-10.0], intercept=8.0, ranking="CAL")
    gate = Gate(RS_MODEL, 10, math.log(0.88 / 0.12), rule=model)
    assert gate.acceptance == "accept when P(correct) >= 0.88 by the CAL model" and gate.threshold is None
    p = 1 / (1 + np.exp(-(8 - 10 * su)))
    clear = np.abs(p - 0.88) > 1e-5
    assert (gate.accept(scores) == (p >= 0.88))[clear].all()
    assert Gate(RS_MODEL, 10, math.inf).acceptance == "accept nothing"
    # an isotonic P has steps: the exact rule is the SU cut it was drawn from
    isotonic = Calibrator("isotonic", ("SU",), x=[-1.0, -0.5], y=[0.2, 0.9])
    assert Gate(isotonic, 10, -0.75).acceptance == "accept when SU <= 0.75"


def test_the_corridor_gates_print_their_rules(corridor_dir, corridor_matches_dir, tmp_path, capsys):
    matches = corridor_matches_dir / "AMOSNet" / "precomputed_data_corrected.npy"
    retrieval = read_results(matches, ground_truth=corridor_dir / "ground_truth_new.npy")
    labelled, new_run = (retrieval.subset_queries(np.arange(a, b)) for a, b in ((0, 56), (56, 111)))
    gate = calibrate(labelled, target_precision=0.8, rankings=["SU", "CAL"], unlabelled=new_run)
    assert gate.acceptance == "accept when SU <= 0.9203"  # was "accept SU >= -0.9203"
    su = statistical_uncertainty(retrieval.scores[:, :10], k=10).astype(np.float64)
    assert (gate.accept(retrieval.scores[:, :10]) == (su <= -gate.cut)).all()
    assert Gate.load(gate.save(tmp_path / "su.json")).acceptance == gate.acceptance  # the file: the same decisions
    arguments = ["calibrate", str(matches), "--gt", str(corridor_dir / "ground_truth_new.npy")]
    wide = ["--rankings", "CAL=0.9,margin=0.1"]  # the shares of 176 labels or more: a refitted CAL rule
    assert main([*arguments, "--out", str(tmp_path / "g.json"), "--target-precision", "0.9", *wide]) == 0
    printed, cal = capsys.readouterr().out, Gate.load(tmp_path / "g.json")
    p = 1 / (1 + math.exp(-cal.cut))  # the CAL model's P at its cut (the gate's P is the RS calibrator's)
    assert cal.rule.ranking == "CAL" and cal.calibrator != cal.rule and round(p, 4) == 0.8784
    assert "accept when P(correct) >= 0.8784 by the CAL model; certified precision lower bound 0.917" in printed
    assert main([*arguments, "--out", str(tmp_path / "p.json")]) == 0  # no target: P >= 0.5
    assert "accept when P(correct) >= 0.5 (no target precision: nothing certified)" in capsys.readouterr().out


# --- item 3: the pair to label, and the contact sheet -----------------------------------------------------------


@pytest.fixture
def pool(corridor_dir, corridor_matches_dir, tmp_path):
    """AMOSNet's corridor matrix (no image names), copied, and its retrieval."""
    path = shutil.copy(corridor_matches_dir / "AMOSNet" / "precomputed_data_corrected.npy", tmp_path / "amos.npy")
    return path, read_pool(path)


def _asked(out: str) -> int:
    return int(re.search(r"label next: query (\d+)", out)[1])


def _titles(monkeypatch) -> list[list[str]]:
    """The axes' titles of every figure write_figure writes (then written as usual)."""
    import vpr_uncertainty.cache as cache

    drawn, write = [], cache.write_figure
    monkeypatch.setattr(cache, "write_figure", lambda f, *a, **o: (drawn.append([x.get_title() for x in f.axes]),
                                                                    write(f, *a, **o))[1])  # fmt: skip
    return drawn


def test_sequential_names_the_pair_and_draws_the_next_pairs(pool, corridor_dir, tmp_path, capsys, monkeypatch):
    import matplotlib.pyplot as plt

    path, retrieval = pool
    labels, sheet, drawn = tmp_path / "labels.csv", tmp_path / "sheet.png", _titles(monkeypatch)
    argv = ["calibrate", str(path), "--sequential", str(labels), "--target-precision", "0.9"]
    assert main([*argv, "--images", str(corridor_dir), "--contact-sheet", str(sheet), "--sheet-size", "5"]) == 0
    out = capsys.readouterr().out
    session, expected = SequentialCalibration(retrieval.scores, target_precision=0.9), []
    for _ in range(5):  # the next five if each is labelled correct
        expected.append(session.next_query())
        session.add_label(expected[-1], True)
    query, top = expected[0], retrieval.indices[expected[0], 0]
    assert f"label next: query {query} (query/{query:07d}.jpg -> ref/{top:07d}.jpg)" in out
    assert f"wrote {sheet}: the next 5 queries to label" in out and "note:" not in out
    titles = drawn[0]
    assert [int(t.split()[1]) for t in titles[::2]] == expected
    assert all(f"ref/{retrieval.indices[q, 0]:07d}.jpg" in t for q, t in zip(expected, titles[1::2], strict=True))
    assert f"similarity {retrieval.scores[query, 0]:.3f}" in titles[1]
    image = plt.imread(sheet)
    assert image.shape[:2] == (5 * 2.4 * 150, 6 * 150) and image[..., :3].std() > 0.1  # 5 rows of photographs
    before = labels.read_text()  # drawing the sheet labelled nothing: the same query is asked again
    assert main(argv) == 0 and _asked(capsys.readouterr().out) == query and labels.read_text() == before


def test_without_images_the_index_and_one_line_saying_so(pool, tmp_path, capsys):
    path, _ = pool
    assert main(["calibrate", str(path), "--sequential", str(tmp_path / "l.csv"), "--target-precision", "0.9"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"label next: query \d+ \(append '\d+,1'", out)
    assert [line for line in out.splitlines() if line.startswith("note:")] == [
        "note: the results name no image files: --images DIR (the dataset folder) shows the pair to label"
    ]


def test_the_audit_names_the_pair_and_draws_its_next_draws(pool, corridor_dir, tmp_path, capsys, monkeypatch):
    path, retrieval = pool
    labelled = read_results(path, ground_truth=corridor_dir / "ground_truth_new.npy")
    truth = correct_at_n(labelled.indices, labelled.positives, 1)
    machine = tmp_path / "machine.csv"
    labels = MachineLabels(truth, np.full(111, np.nan), ["ground truth"] * 111)
    write_machine_labels(machine, labels, pool=pool_fingerprint(retrieval.scores, 10))
    audit, sheet, drawn = tmp_path / "audit.csv", tmp_path / "audit.png", _titles(monkeypatch)
    argv = ["calibrate", str(path), "--machine-labels", str(machine), "--audit", str(audit), "--target-precision",
            "0.9", "--images", str(corridor_dir), "--contact-sheet", str(sheet)]  # fmt: skip
    assert main(argv) == 0
    out = capsys.readouterr().out
    session, expected = AuditCalibration(retrieval.scores, truth, target_precision=0.9), []
    while len(expected) < 8 and (query := session.next_query()) is not None:
        expected.append(query)
        session.add_label(query, True)
    top = retrieval.indices[expected[0], 0]
    assert f"label next: query {expected[0]} (query/{expected[0]:07d}.jpg -> ref/{top:07d}.jpg)" in out
    assert [int(t.split()[1]) for t in drawn[0][::2]] == expected and sheet.stat().st_size > 100_000
    assert not re.search(r"^\d+,", audit.read_text(), re.MULTILINE)  # drawing the sheet gave no label


def test_nothing_left_to_label_writes_no_sheet(pool, corridor_dir, tmp_path, capsys):
    path, _ = pool
    sheet = tmp_path / "sheet.png"
    argv = ["calibrate", str(path), "--gt", str(corridor_dir / "ground_truth_new.npy"), "--sequential",
            str(tmp_path / "l.csv"), "--target-precision", "0.9", "--images", str(corridor_dir), "--contact-sheet",
            str(sheet)]  # fmt: skip
    assert main(argv) == 0
    assert f"no query is left to label: {sheet} not written" in capsys.readouterr().out and not sheet.exists()


def test_a_sheet_that_is_an_input_or_the_labels_and_misused_options_are_refused(pool, corridor_dir, tmp_path, capsys):
    path, _ = pool
    labels = tmp_path / "labels.csv"
    base = ["calibrate", str(path), "--sequential", str(labels), "--target-precision", "0.9"]
    matrix = path.read_bytes()
    os.link(path, tmp_path / "linked.npy")
    for sheet, role in ((path, "SCORES"), (tmp_path / "linked.npy", "SCORES"), (labels, "--sequential")):
        assert main([*base, "--images", str(corridor_dir), "--contact-sheet", str(sheet)]) == 2
        assert f"--contact-sheet {sheet} is {role}" in capsys.readouterr().err
    assert path.read_bytes() == matrix and not labels.exists()
    gate = tmp_path / "gate.json"  # two outputs that collide
    assert main([*base, "--out", str(gate), "--images", str(corridor_dir), "--contact-sheet", str(gate)]) == 2
    assert f"--contact-sheet {gate} is --out {gate}, which this command also writes" in capsys.readouterr().err
    assert main([*base, "--contact-sheet", str(tmp_path / "s.png")]) == 2
    assert "--contact-sheet needs --images" in capsys.readouterr().err
    plain = ["calibrate", str(path), "--gt", str(corridor_dir / "ground_truth_new.npy"), "--out", str(tmp_path / "g")]
    assert main([*plain, "--images", str(corridor_dir)]) == 2
    assert "show the queries to label (--sequential, --audit)" in capsys.readouterr().err
    few = tmp_path / "few"
    for split in ("query", "ref"):
        (few / split).mkdir(parents=True)
        shutil.copy(corridor_dir / split / "0000000.jpg", few / split / "0000000.jpg")
    assert main([*base, "--images", str(few)]) == 2  # refused before the labels file is started
    assert "holds 1 images but the results have 111 queries" in capsys.readouterr().err and not labels.exists()


def test_a_sheet_write_that_fails_half_way_leaves_the_previous_sheet(pool, corridor_dir, tmp_path, capsys, monkeypatch):
    from matplotlib.figure import Figure

    def full_disk(self, target, **options):
        target.write_bytes(b"partial")
        raise OSError(28, "No space left on device")

    path, _ = pool
    sheet = tmp_path / "sheet.png"
    sheet.write_bytes(b"the previous sheet")
    monkeypatch.setattr(Figure, "savefig", full_disk)
    argv = ["calibrate", str(path), "--sequential", str(tmp_path / "l.csv"), "--target-precision", "0.9", "--images",
            str(corridor_dir), "--contact-sheet", str(sheet)]  # fmt: skip
    assert main(argv) != 0 and "No space left on device" in capsys.readouterr().err
    assert sheet.read_bytes() == b"the previous sheet" and [
        p.name for p in tmp_path.iterdir() if "sheet" in p.name
    ] == ["sheet.png"]


@pytest.mark.parametrize(
    ("text", "expected"),
    [("SU, CAL", ("SU", "CAL")), ("CAL=0.9,margin=0.1", {"CAL": 0.9, "margin": 0.1}), ("SU=1", {"SU": 1.0})],
)
def test_rankings_option_takes_names_or_shares(text, expected):
    from vpr_uncertainty.pipeline.calibrate import _rankings

    assert _rankings(text) == expected


@pytest.mark.parametrize("text", ["CAL=0.9,margin", "CAL=x", "CAL=0.5=0.5", ",", "SU=1,SU=0.5"])
def test_a_rankings_option_mixing_names_and_shares_is_one_line_exit_2(text, capsys, tmp_path):
    scores = tmp_path / "s.npy"
    np.save(scores, np.eye(4, dtype=np.float32))
    with pytest.raises(SystemExit) as stopped:
        main(["calibrate", str(scores), "--out", str(tmp_path / "g.json"), "--rankings", text])
    assert stopped.value.code == 2 and "--rankings" in capsys.readouterr().err


def test_an_unknown_ranking_gets_the_near_name():
    from vpr_uncertainty.calibration.guarantee import check_rankings

    with pytest.raises(ValueError, match="unknown ranking\\(s\\) \\['su'\\]; did you mean 'SU'\\?"):
        check_rankings({"su": 1.0}, {"SU": np.zeros(3)})
    with pytest.raises(ValueError, match="did you mean 'margin'"):
        check_rankings(["margn"], {"gap": np.zeros(3)})
