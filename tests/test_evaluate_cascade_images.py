"""``evaluate --images DIR`` feeds the cascades SCORE+GV (e.g. SU+GV-SIFT), not only the GV-* methods."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("cv2")
pytestmark = [pytest.mark.realdata, pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")]


def test_evaluate_verifies_the_images_of_a_cascade(corridor_dir, corridor_matches_dir, tmp_path, capsys):
    from vpr_uncertainty.cli import main

    matrix = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    argv = ["evaluate", str(matrix), "--gt", str(corridor_dir / "ground_truth_new.npy"), "--images", str(corridor_dir)]
    argv += ["--methods", "SU,SU+GV-SIFT", "--verify-fraction", "0.05", "--json", str(tmp_path / "r.json")]
    assert main(argv) == 0  # before: "argument of type 'NoneType' is not iterable" (a cascade takes **options)
    capsys.readouterr()
    cascade = json.loads((tmp_path / "r.json").read_text())["methods"]["SU+GV-SIFT"]
    assert cascade["verified_queries"] == round(0.05 * 111)
