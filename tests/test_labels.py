"""Machine labelers (``vpr_uncertainty.labels``) and the ``label`` command: agreement computed by hand (ties,
positions, no agreement), options and the registry, the command on the real corridor (the ten methods' matrices and
a few of its images), the pool fingerprint as ``calibrate`` computes it, the machine-labels file, and the attacks of
DESIGN.md on the new command and file."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty.calibration import SequentialCalibration
from vpr_uncertainty.calibration.labels_file import (
    MachineLabels,
    pool_fingerprint,
    read_labels,
    read_machine_labels,
    write_machine_labels,
)
from vpr_uncertainty.cli import main
from vpr_uncertainty.data import read_pool, read_results
from vpr_uncertainty.formats.matrix import load_vprbench_similarity
from vpr_uncertainty.labels import LABELERS, Labeler, agreement, label, label_quality
from vpr_uncertainty.retrieval import Retrieval, save_retrieval

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy")

METHODS = ("AMOSNet", "AlexNet_VPR", "CALC", "CoHOG", "HOG", "HybridNet", "NetVLAD", "RegionVLAD", "ap-gem-r101")


def _retrieval(indices, scores=None, **fields) -> Retrieval:
    indices = np.asarray(indices)
    scores = -np.sort(-np.random.default_rng(0).random(indices.shape)) if scores is None else np.asarray(scores)
    return Retrieval(scores, indices, **fields)


# --- agreement by hand ---------------------------------------------------------------------------------------------

MINE = _retrieval([[0, 1], [2, 0], [3, 2]])  # top-1: 0, 2, 3


def test_agreement_counts_the_others_returning_the_same_top1():
    others = [
        _retrieval([[0, 3], [1, 2], [1, 3]]),  # agrees on query 0 only
        _retrieval([[0, 2], [2, 1], [2, 3]]),  # 0 and 1
        _retrieval([[1, 0], [2, 3], [0, 1]]),  # 1
    ]  # votes: 2, 2, 0 (query 2: nobody returns 3 first)
    labels = agreement(MINE, others=others, min_agree=2)
    assert labels.correct.tolist() == [True, True, False]
    assert_close(labels.confidence, np.array([2, 2, 0]) / 3)
    assert agreement(MINE, others=others, min_agree=3).correct.tolist() == [False, False, False]
    assert set(labels.sources) == {"agreement:min_agree=2,others=3"}


def test_a_tied_best_score_splits_its_vote():
    tied = _retrieval([[1, 0, 2], [0, 1, 2], [3, 2, 0]], [[0.9, 0.9, 0.1], [0.5, 0.5, 0.5], [0.8, 0.7, 0.7]])
    # query 0: 1 and 0 tie -> half a vote for 0; query 1: three tie, one is 2 -> a third; query 2: 3 alone -> one
    votes = np.array([1 / 2, 1 / 3, 1.0])
    labels = agreement(MINE, others=[tied] * 3, min_agree=1)
    assert_close(labels.confidence, votes) and labels.correct.tolist() == [True, True, True]
    assert agreement(MINE, others=[tied] * 3, min_agree=2).correct.tolist() == [False, False, True]
    assert agreement(MINE, others=[tied] * 6, min_agree=3).correct.tolist() == [True, False, True]  # 6 halves = 3


def test_positions_count_a_neighbour_within_the_retrievals_radius():
    positions = np.array([[0.0, 0.0], [10.0, 0.0], [100.0, 0.0], [124.0, 0.0]])
    mine = _retrieval([[0, 1], [2, 0], [3, 2]], database_positions=positions)
    other = _retrieval([[1, 0], [0, 1], [2, 3]])  # 10 m, 100 m, 24 m from mine's top-1
    assert agreement(mine, others=[other], min_agree=1).correct.tolist() == [True, False, True]  # 25 m by default
    mine.config["radius"] = 5.0
    assert agreement(mine, others=[other], min_agree=1).correct.tolist() == [False, False, False]


def test_missing_candidates_never_agree():
    mine = _retrieval([[0, 1], [-1, -1], [3, 2]], [[0.9, 0.1], [-np.inf, -np.inf], [0.5, 0.4]])
    other = _retrieval([[0, 1], [-1, -1], [-1, -1]], [[0.9, 0.1], [-np.inf, -np.inf], [-np.inf, -np.inf]])
    labels = agreement(mine, others=[other], min_agree=1)
    assert labels.correct.tolist() == [True, False, False] and labels.confidence.tolist() == [1.0, 0.0, 0.0]


@pytest.mark.parametrize(
    ("other", "expected"),
    [
        (_retrieval([[0, 1], [2, 0]]), "holds 2 queries"),
        (
            _retrieval([[0, 1], [2, 0], [3, 2]], positives=[[0], [1], [9]]),
            "against 10 images, not this pool's 3 against 4",
        ),
        (_retrieval([[0, 1], [2, 0], [3, 2]], query_names=np.array(["a", "b", "z"])), "or other names"),
    ],
    ids=["query-count", "database-size", "query-names"],
)
def test_a_retrieval_of_other_queries_or_database_is_refused_by_name(other, expected):
    mine = _retrieval([[0, 1], [2, 0], [3, 2]], positives=[[0], [1], [3]], query_names=np.array(["a", "b", "c"]))
    with pytest.raises(ValueError, match=expected) as error:
        agreement(mine, others={"R2.npz": other}, min_agree=1)
    assert str(error.value).startswith("R2.npz holds")


@pytest.mark.parametrize("min_agree", [0, -1, 2.5, True, 4])
def test_min_agree_must_be_a_count_the_others_can_reach(min_agree):
    with pytest.raises((ValueError, TypeError), match="min_agree"):
        agreement(MINE, others=[MINE] * 3, min_agree=min_agree)


def test_agreement_on_a_million_queries_is_quick_and_small():
    rng = np.random.default_rng(1)
    indices = rng.integers(0, 1000, (1_000_000, 2))
    indices[:, 1] = (indices[:, 0] + 1) % 1000
    mine = Retrieval(np.tile(np.float32([0.9, 0.1]), (len(indices), 1)), indices)
    assert agreement(mine, others=[mine] * 3, min_agree=3).correct.all()


# --- label(): options, needs, registry -------------------------------------------------------------------------------


def test_options_come_from_the_spec_and_the_call_over_the_defaults():
    others = [_retrieval([[0, 3], [2, 1], [1, 3]])] * 3
    assert label(MINE, "agreement", others=others).sources[0] == "agreement:min_agree=3,others=3"
    assert label(MINE, "Agreement:min_agree=2", others=others).sources[0] == "agreement:min_agree=2,others=3"
    assert (
        label(MINE, "agreement:min_agree=2", options={"min_agree": 1}, others=others)
        .sources[0]
        .startswith("agreement:min_agree=1")
    )
    with pytest.raises(ValueError, match=r"has no option 'min_agre'.*min_agree"):
        label(MINE, "agreement:min_agre=2", others=others)
    with pytest.raises(ValueError, match="has no option 'radius'"):
        label(MINE, "agreement", options={"radius": 5}, others=others)
    with pytest.raises(ValueError, match="must be an integer, got 'two'"):
        label(MINE, "agreement:min_agree=two", others=others)
    with pytest.raises(ValueError, match="min_inliers must be a positive integer"):
        label(MINE, "gv-sift", options={"min_inliers": -1}, query_paths=["q"], database_paths=["d"])


def test_a_missing_need_is_named():
    with pytest.raises(ValueError, match="needs other VPR methods' retrievals of the same queries"):
        label(MINE, "agreement")
    with pytest.raises(ValueError, match="'gv-xfeat' needs the images"):
        label(MINE, "gv-xfeat", query_paths=["q.jpg"])


def test_the_registry_suggests_the_near_name_and_knows_the_presets():
    with pytest.raises(KeyError, match="did you mean 'agreement'"):
        LABELERS.get("agreemnt")
    with pytest.raises(KeyError, match="did you mean 'gv-sift'"):
        label(MINE, "gv-sfit")
    assert LABELERS.get("GV-DISK-LIGHTGLUE").name == "gv-disk-lg" and "gv-xfeat" in LABELERS
    assert {LABELERS.get(name).extra for name in ("gv-sift", "gv-xfeat")} == {"opencv", "gv"}


def test_a_labeler_that_returns_the_wrong_shape_is_named():
    def short(retrieval, **_):
        return MachineLabels(np.ones(2, bool), np.ones(2), ["short"] * 2)

    LABELERS.register(Labeler("short-test", "", short, requires=("lidar",)))
    try:  # a need not in NEEDS is the name of an input
        with pytest.raises(ValueError, match=r"'short-test' needs argument lidar"):
            label(MINE, "short-test")
        with pytest.raises(RuntimeError, match=r"'short-test' returned labels of shape \(2,\), expected \(3,\)"):
            label(MINE, "short-test", lidar="scan.bin")
    finally:
        LABELERS.unregister("short-test")


def test_label_quality_by_hand():
    quality = label_quality(np.array([1, 1, 0, 0, 1], bool), np.array([1, 0, 1, 0, 1], bool))
    assert quality == {"precision": 2 / 3, "recall": 2 / 3, "wrong": 0.4}
    assert np.isnan(label_quality(np.zeros(2, bool), np.zeros(2, bool))["precision"])


# --- the machine-labels file ----------------------------------------------------------------------------------------


def test_the_machine_labels_file_round_trip_and_its_pool(tmp_path):
    labels = MachineLabels(np.array([True, False, True]), np.array([0.1 + 0.2, np.nan, 1e-300]), ["a", "b,c", 'd"e'])
    path = write_machine_labels(tmp_path / "m.csv", labels, pool="0123456789abcdef", about="pool.npy: 3 queries")
    read = read_machine_labels(path, n_queries=3, pool="0123456789abcdef")
    assert read.correct.tolist() == [True, False, True] and read.sources == ["a", "b,c", 'd"e']
    assert read.confidence[0] == 0.1 + 0.2 and np.isnan(read.confidence[1]) and read.confidence[2] == 1e-300
    with pytest.raises(ValueError, match=r"machine labels of pool 0123456789abcdef .*not the machine labels of this"):
        read_machine_labels(path, n_queries=3, pool="fedcba9876543210")
    with pytest.raises(ValueError, match="holds machine labels"):
        read_labels(path, n_queries=3, pool="0123456789abcdef")


# --- the command on the corridor -----------------------------------------------------------------------------------


@pytest.fixture
def corridor(corridor_dir, corridor_matches_dir, tmp_path):
    """AMOSNet's matrix, the nine others' and the ground truth, as a user names them (copies in tmp_path)."""
    paths = {}
    for method in (*METHODS, "denseVLAD"):
        paths[method] = tmp_path / f"{method}.npy"
        shutil.copy(corridor_matches_dir / method / "precomputed_data_corrected.npy", paths[method])
    return paths, corridor_dir / "ground_truth_new.npy"


def _label(capsys, *arguments) -> tuple[int, str, str]:
    try:
        status = main(["label", *map(str, arguments)])
    except SystemExit as exit_info:
        status = exit_info.code
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_agreement_on_the_corridor_matches_the_api_and_the_ground_truth(corridor, tmp_path, capsys):
    paths, gt = corridor
    out = tmp_path / "machine.csv"
    others = [paths[m] for m in (*METHODS[1:], "denseVLAD")]
    status, printed, err = _label(capsys, paths["AMOSNet"], "--by", "agreement", "--with", *others, "--gt", gt,
                                  "--out", out)  # fmt: skip
    assert status == 0, err
    mine = read_results(paths["AMOSNet"], ground_truth=gt)
    expected = label(mine, "agreement", others=[read_results(p, ground_truth=gt) for p in others])
    pool = SequentialCalibration(mine.scores, target_precision=0.9).fingerprint  # as calibrate --sequential has it
    read = read_machine_labels(out, n_queries=111, pool=pool)
    assert np.array_equal(read.correct, expected.correct) and np.array_equal(read.confidence, expected.confidence)
    assert "49 of 111 queries labelled correct by agreement:min_agree=3,others=9" in printed
    assert "precision 0.980, recall 0.511, wrong 42.3%" in printed


@pytest.mark.parametrize("k", [10, 5])
def test_the_pool_fingerprint_is_calibrates(corridor, tmp_path, capsys, k):
    """The same pool line with and without --gt, for a matrix and a retrieval file, as calibrate reads each (its
    SCORES with --gt through read_results, its --unlabelled through read_pool, as label reads them)."""
    paths, gt = corridor
    npz = save_retrieval(read_results(paths["CALC"], ground_truth=gt, top_k=20), tmp_path / "calc.npz")
    for pool_file in (paths["CALC"], npz):
        expected = pool_fingerprint(read_results(pool_file, ground_truth=gt, top_k=max(50, k)).scores, k)
        assert pool_fingerprint(read_pool(pool_file, top_k=50).scores, k) == expected
        for truth in ([], ["--gt", gt]):
            out = tmp_path / f"m{len(truth)}.csv"
            assert _label(capsys, pool_file, "--by", "agreement:min_agree=1", "--with", paths["HOG"], "--k", k,
                          *truth, "--out", out)[0] == 0  # fmt: skip
            assert out.read_text().startswith(f"# vpr-uncertainty machine labels of pool {expected} (")


@pytest.fixture
def few_images(corridor_dir, tmp_path):
    """Four corridor queries and four reference images (a VPR-Bench folder), their 4 x 4 AMOSNet similarities and
    ground truth (±2 frames)."""
    queries, refs = [10, 40, 70, 100], [11, 40, 90, 99]
    folder = tmp_path / "images"
    for split, picked in (("query", queries), ("ref", refs)):
        (folder / split).mkdir(parents=True)
        for new, old in enumerate(picked):
            shutil.copy(corridor_dir / split / f"{old:07d}.jpg", folder / split / f"{new:07d}.jpg")
    similarity = load_vprbench_similarity(
        corridor_dir.parent / "precomputed_matches/corridor/AMOSNet/precomputed_data_corrected.npy"
    )
    np.save(tmp_path / "small.npy", similarity[np.ix_(queries, refs)])
    np.save(tmp_path / "gt.npy", np.abs(np.subtract.outer(queries, refs)) <= 2)
    return tmp_path / "small.npy", folder, tmp_path / "gt.npy"


def test_gv_sift_labels_a_few_corridor_images(few_images, tmp_path, capsys):
    import vpr_uncertainty.geometric  # noqa: F401
    from vpr_uncertainty.data.images import retrieval_image_paths
    from vpr_uncertainty.methods import get_method

    matrix, folder, gt = few_images
    out = tmp_path / "run" / "machine.csv"
    out.parent.mkdir()
    status, printed, err = _label(capsys, matrix, "--by", "gv-sift:min_inliers=4", "--images", folder, "--gt", gt,
                                  "--out", out)  # fmt: skip
    assert status == 0, err
    retrieval = read_pool(matrix)
    query_paths, database_paths = retrieval_image_paths(retrieval, images=folder)
    inliers = -get_method("GV-SIFT")(retrieval, query_paths=query_paths, database_paths=database_paths)
    pool = pool_fingerprint(retrieval.scores, 10)
    read = read_machine_labels(out, n_queries=4, pool=pool)
    assert np.array_equal(read.confidence, inliers) and np.array_equal(read.correct, inliers >= 4)
    assert set(read.sources) == {"gv-sift:min_inliers=4"} and "against" in printed and "precision" in printed
    assert any((out.parent / "local_features").iterdir())  # the verify stage's cache, beside OUT
    folders = ["--query-images", folder / "query", "--database-images", folder / "ref"]  # as verify takes them
    assert _label(capsys, matrix, "--by", "gv-sift", *folders, "--out", out)[0] == 0
    assert np.array_equal(read_machine_labels(out, n_queries=4, pool=pool).confidence, inliers)


def test_an_images_folder_missing_an_image_is_one_line(few_images, tmp_path, capsys):
    matrix, folder, _ = few_images
    (folder / "ref" / "0000003.jpg").unlink()
    status, _, err = _label(capsys, matrix, "--by", "gv-sift", "--images", folder, "--out", tmp_path / "m.csv")
    assert status == 2 and "3 images" in err and str(folder / "ref") in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "m.csv").exists()


# --- attacks --------------------------------------------------------------------------------------------------------


def test_an_output_that_is_an_input_is_refused_and_left_alone(corridor, tmp_path, capsys):
    paths, _ = corridor
    (tmp_path / "link.npy").symlink_to(paths["HOG"])
    os.link(paths["CALC"], tmp_path / "hard.npy")
    before = {p: p.read_bytes() for p in (paths["AMOSNet"], paths["HOG"], paths["CALC"])}
    for out in (paths["AMOSNet"], tmp_path / "link.npy", tmp_path / "hard.npy"):
        status, _, err = _label(capsys, paths["AMOSNet"], "--by", "agreement:min_agree=1", "--with", paths["HOG"],
                                paths["CALC"], "--out", out)  # fmt: skip
        assert status == 2 and "which this command never overwrites" in err
    assert all(p.read_bytes() == content for p, content in before.items())


def test_a_with_file_of_another_pool_is_refused_by_name_and_the_old_output_kept(corridor, tmp_path, capsys):
    paths, gt = corridor
    out = tmp_path / "machine.csv"
    assert (
        _label(capsys, paths["AMOSNet"], "--by", "agreement:min_agree=1", "--with", paths["HOG"], "--out", out)[0] == 0
    )
    before = out.read_bytes()
    part = save_retrieval(read_results(paths["HOG"], ground_truth=gt).subset_queries(np.arange(60)), tmp_path / "p.npz")
    status, _, err = _label(capsys, paths["AMOSNet"], "--by", "agreement:min_agree=1", "--with", part, "--out", out)
    assert status == 2 and f"{part} holds 60 queries" in err and out.read_bytes() == before


@pytest.mark.parametrize("where", ["RETRIEVAL", "--with"])
def test_nan_scores_are_refused_naming_the_file(corridor, tmp_path, capsys, where):
    paths, _ = corridor
    bad = tmp_path / "nan.npy"
    matrix = np.random.default_rng(0).random((111, 111)).astype(np.float32)
    matrix[5, 7] = np.nan
    np.save(bad, matrix)
    pool, other = (bad, paths["HOG"]) if where == "RETRIEVAL" else (paths["HOG"], bad)
    status, _, err = _label(capsys, pool, "--by", "agreement:min_agree=1", "--with", other, "--out", tmp_path / "m.csv")
    assert status == 2 and str(bad) in err and "holds nan at query 5" in err and not (tmp_path / "m.csv").exists()


def test_a_write_past_ulimit_leaves_the_previous_labels(corridor, tmp_path):
    paths, _ = corridor
    out = tmp_path / "machine.csv"
    out.write_text("# a previous, complete file\n")
    command = (
        f"ulimit -f 0; exec {sys.executable} -m vpr_uncertainty.cli label {paths['AMOSNet']} "
        f"--by agreement:min_agree=1 --with {paths['HOG']} --out {out}"
    )
    run = subprocess.run(["bash", "-c", command], capture_output=True, text=True, timeout=300)
    assert run.returncode == 1 and str(out) in run.stderr and "too large" in run.stderr, run.stderr
    assert out.read_text() == "# a previous, complete file\n"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_flags_the_labeler_does_not_read_or_needs_are_one_line(corridor, tmp_path, capsys):
    paths, _ = corridor
    out = ["--out", tmp_path / "m.csv"]
    assert "--by gv-sift needs --images" in _label(capsys, paths["HOG"], "--by", "gv-sift", *out)[2]
    assert "does not read --with" in _label(capsys, paths["HOG"], "--by", "gv-sift", "--with", paths["CALC"], *out)[2]
    assert "needs --with" in _label(capsys, paths["HOG"], "--by", "agreement", *out)[2]
    assert "standard output" in _label(capsys, paths["HOG"], "--by", "agreement", "--with", paths["CALC"],
                                       "--out", "-")[2]  # fmt: skip
