"""`vpr-uncertainty calibrate` and the held-out `evaluate --calibration-fraction` on the real corridor."""

from __future__ import annotations

import json

import pytest

from vpr_uncertainty.cli import main


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_calibrate_command(corridor_dir, corridor_matches_dir, tmp_path, capsys):
    matches = corridor_matches_dir / "AMOSNet" / "precomputed_data_corrected.npy"
    gate, plot = tmp_path / "gate.json", tmp_path / "reliability.png"
    arguments = ["calibrate", str(matches), "--gt", str(corridor_dir / "ground_truth_new.npy"), "--out", str(gate)]
    assert main([*arguments, "--target-precision", "0.9", "--plot", str(plot)]) == 0
    printed = capsys.readouterr().out
    assert "certified precision lower bound" in printed and "expected recall" in printed and "ECE" in printed
    assert json.loads(gate.read_text())["format"] == "vpr-uncertainty gate" and plot.stat().st_size > 10_000
    with pytest.raises(SystemExit) as exit_info:
        main([*arguments, "--target-precision", "1.5"])
    assert exit_info.value.code == 2 and "strictly between 0 and 1" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_held_out_evaluate_json(corridor_dir, corridor_matches_dir, tmp_path, capsys, monkeypatch):
    """One ECE, named: the terminal and the JSON gave the mean over the splits (0.105), the diagram's legend the
    ECE of the pooled bins (0.056), neither saying which."""
    from vpr_uncertainty.reports.display import ReliabilityDisplay

    legends, plot = [], ReliabilityDisplay.plot
    monkeypatch.setattr(ReliabilityDisplay, "plot", lambda self, *a, **k: legends.append(plot(self, *a, **k)) or self)
    matches = corridor_matches_dir / "CALC" / "precomputed_data_corrected.npy"
    out = tmp_path / "held_out.json"
    status = main(
        ["evaluate", str(matches), "--gt", str(corridor_dir / "ground_truth_new.npy"), "--methods", "SU,margin,CAL",
         "--calibration-fraction", "0.3", "--repeats", "5", "--seed", "0", "--json", str(out),
         "--plot", str(tmp_path / "rel.png")]
    )  # fmt: skip
    assert status == 0
    data = json.loads(out.read_text())
    assert data["calibration"]["fraction"] == 0.3 and data["calibration"]["repeats"] == 5
    assert data["calibration"]["seed"] == 0
    assert data["calibration"]["n_calibration"] + data["calibration"]["n_held_out"] == 111
    for name in ("SU", "margin", "CAL"):
        per_repeat = data["methods"][name]["auc_pr_per_repeat"]
        assert len(per_repeat) == 5 and data["methods"][name]["auc_pr"] == pytest.approx(sum(per_repeat) / 5)
    assert sum(data["calibration_quality"]["CAL"]["reliability"]["counts"]) == 5 * data["calibration"]["n_held_out"]
    ece = f"ECE {data['calibration_quality']['CAL']['ece']:.3f}, mean over the 5 splits"
    assert f"CAL calibration on held-out queries: {ece}; Brier" in capsys.readouterr().out
    assert [drawn.line_.get_label() for drawn in legends] == [f"CAL ({ece})"]


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_cal_without_gate_is_an_input_error(corridor_dir, corridor_matches_dir, capsys):
    matches = corridor_matches_dir / "CALC" / "precomputed_data_corrected.npy"
    assert main(["evaluate", str(matches), "--gt", str(corridor_dir / "ground_truth_new.npy"), "--methods", "CAL"]) == 2
    assert "needs a fitted gate" in capsys.readouterr().err
