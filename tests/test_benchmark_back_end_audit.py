"""benchmarks/back_end_audit.py: the population ceiling and the shifted cut, against counting on replicated rows."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import load_benchmark

pytest.importorskip("gtsam")


@pytest.fixture(scope="module")
def audit(corridor_matches_dir):
    return load_benchmark("back_end_audit")


@pytest.fixture(scope="module")
def amosnet(audit):
    return audit.slam.population("AMOSNet")  # 94 correct rows, 17 wrong


# AMOSNet's 94 correct and 17 wrong rows, each repeated so that the wrong share is exactly w:
# 94·a·w = 17·b·(1 − w) with integers a, b
REPEATS = {0.3: (119, 282), 0.5: (17, 94)}


@pytest.mark.parametrize("wrong_rate", sorted(REPEATS))
@pytest.mark.parametrize("target", [0.7, 0.9])
def test_population_ceiling_is_the_hindsight_ceiling_of_rows_repeated_to_that_mix(audit, amosnet, wrong_rate, target):
    """The ceiling's formula with F the rows' SU distributions is the most lenient cut's true share when the rows
    themselves are repeated to make the mix (oracle_kept counts accepted rows one by one, tied SU values together)."""
    per_true, per_wrong = REPEATS[wrong_rate]
    rows = np.r_[
        np.repeat(amosnet.scores[amosnet.correct], per_true, 0),
        np.repeat(amosnet.scores[~amosnet.correct], per_wrong, 0),
    ]
    is_true = np.r_[np.ones(94 * per_true, bool), np.zeros(17 * per_wrong, bool)]
    assert abs((~is_true).mean() - wrong_rate) < 1e-12
    assert audit.population_ceiling(amosnet, wrong_rate, target) == pytest.approx(
        audit.oracle_kept(rows, is_true, target), abs=1e-12
    )


def test_the_ceiling_falls_with_the_wrong_rate_and_the_target(audit, amosnet):
    ceilings = np.array([[audit.population_ceiling(amosnet, w, t) for t in (0.5, 0.7, 0.9)] for w in (0.3, 0.5, 0.7)])
    assert (np.diff(ceilings, axis=0) <= 0).all() and (np.diff(ceilings, axis=1) <= 0).all()
    assert ceilings[0, 0] == 1.0 and ceilings[-1, -1] < 0.5  # everything at 30 % and p* 0.5; little at 70 % and 0.9


def test_shifted_cut_reads_the_wrong_rate_of_the_recent_closures_only(audit, amosnet):
    """With exact labels, the cut chosen for the wrong share of the `recent` rows keeps the population ceiling's
    share of the correct rows at that share; a wrong-free recent stretch accepts every row."""
    rows, correct = amosnet.scores, amosnet.correct
    recent = np.r_[np.flatnonzero(correct)[:17], np.flatnonzero(~correct)]  # 17 correct, 17 wrong: w = 0.5
    for target in (0.7, 0.9):
        accepted = audit.ShiftedCut(rows, correct, recent, target).accept(rows)
        assert accepted[correct].mean() == pytest.approx(audit.population_ceiling(amosnet, 0.5, target), abs=1e-12)
    clean = np.flatnonzero(correct)[:20]
    assert audit.ShiftedCut(rows, correct, clean, 0.9).accept(rows).all()
    assert not audit.ShiftedCut(rows, np.zeros(len(rows), bool), recent, 0.5).accept(rows).any()  # nothing true
