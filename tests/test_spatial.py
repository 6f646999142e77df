"""SUE against a loop reference in the style of the published code, its limiting cases and its registry entry."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty import get_method
from vpr_uncertainty.retrieval import Retrieval
from vpr_uncertainty.spatial import spatial_uncertainty, sue_from_retrieval


def loop_reference(indices, distances, positions, k=10, slope=350.0, clip="symmetric", max_deviation=500.0):
    """One query at a time, as in sue.py of Zaffar et al. (with the softmax shifted by the smallest distance)."""
    result = np.zeros(len(indices))
    for q in range(len(indices)):
        chosen = [(int(i), float(d)) for i, d in zip(indices[q][:k], distances[q][:k], strict=True) if i >= 0]
        nearest = min(d for _, d in chosen)
        weights = [math.exp(-slope * (d - nearest)) for _, d in chosen]
        total = sum(weights)
        weights = [w / total for w in weights]
        poses = [positions[i] for i, _ in chosen]
        mean = [sum(w * p[c] for w, p in zip(weights, poses, strict=True)) for c in range(len(poses[0]))]
        variances = []
        for c in range(len(mean)):
            variance = 0.0
            for w, p in zip(weights, poses, strict=True):
                delta = p[c] - mean[c]
                if clip == "symmetric":
                    delta = max(-max_deviation, min(max_deviation, delta))
                elif clip == "one-sided":
                    delta = min(max_deviation, delta)
                variance += w * delta**2
            variances.append(variance)
        result[q] = sum(variances) / len(variances)
    return result


def published(indices, distances, positions, num_nn=10, slope=350):
    """The SUE loop of the published sue.py, unshifted weights and one-sided clip (distances must be small)."""
    scores = np.zeros(len(indices))
    for itr in range(len(indices)):
        nn_poses = positions[indices[itr][:num_nn]]
        weights = np.array([math.e ** ((-1 * abs(distances[itr][j])) * slope) for j in range(num_nn)])
        weights = weights / sum(abs(weights))
        mean_pose = [np.average(nn_poses[:, 0], weights=weights), np.average(nn_poses[:, 1], weights=weights)]
        var_x = sum(weights[j] * min(500, nn_poses[j, 0] - mean_pose[0]) ** 2 for j in range(num_nn))
        var_y = sum(weights[j] * min(500, nn_poses[j, 1] - mean_pose[1]) ** 2 for j in range(num_nn))
        scores[itr] = (var_x + var_y) / 2
    return scores


def random_problem(seed=0, n_queries=50, n_database=300, k=10, spread=2000.0):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(0, spread, size=(n_database, 2)) + np.array([584000.0, 4477000.0])  # UTM-sized
    indices = np.stack([rng.choice(n_database, size=k, replace=False) for _ in range(n_queries)])
    distances = np.sort(rng.uniform(0.2, 1.4, size=(n_queries, k)), axis=1)
    return indices, distances, positions


@pytest.mark.parametrize("clip", ["symmetric", "one-sided", "none"])
@pytest.mark.parametrize("slope", [0.0, 3.5, 350.0])
def test_matches_loop_reference(clip, slope):
    indices, distances, positions = random_problem(seed=int(slope))
    expected = loop_reference(indices, distances, positions, slope=slope, clip=clip)
    result = spatial_uncertainty(indices, distances, positions, slope=slope, clip=clip)
    # float64, but the loop sums the weighted variance in another order over UTM-sized coordinates (~5e6 m):
    # cancellation in x - mean costs ~6 digits, hence rtol 1e-9 and an atol (m²) for variances near 0.
    assert_close(result, expected, rtol=1e-9, atol=1e-6)


def test_one_sided_clip_reproduces_the_published_code():
    indices, distances, positions = random_problem(seed=1)
    distances = distances * 0.01  # small enough that the unshifted exp of the published code does not underflow
    expected = published(indices, distances, positions)
    result = spatial_uncertainty(indices, distances, positions, clip="one-sided")
    assert_close(result, expected, rtol=1e-8)  # the published code's unshifted exp and UTM-sized sums: ~6 digits lost


def test_all_neighbours_at_one_place_give_zero():
    positions = np.tile([[584744.9, 4476709.9]], (20, 1))
    indices = np.arange(20).reshape(2, 10)
    distances = np.linspace(0.1, 1.5, 20).reshape(2, 10)
    for clip in ("symmetric", "one-sided", "none"):
        np.testing.assert_array_equal(spatial_uncertainty(indices, distances, positions, clip=clip), [0.0, 0.0])


def test_one_candidate_or_one_dominant_candidate_gives_zero():
    positions = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0]])
    assert spatial_uncertainty([[1]], [[0.5]], positions).tolist() == [0.0]
    # exp(−350 · 1) underflows next to exp(0): the nearest candidate takes all the weight.
    assert spatial_uncertainty([[0, 1, 2]], [[0.0, 1.0, 1.0]], positions)[0] < 1e-100


@pytest.mark.parametrize("scale", [1e3, 1e100, 1e300])
def test_huge_distances_stay_finite(scale):
    indices, distances, positions = random_problem(seed=2)
    result = spatial_uncertainty(indices, distances * scale, positions)
    assert np.isfinite(result).all() and (result >= 0).all()
    # All weight on the nearest candidate (huge gaps), unless the distances tie.
    assert_close(result, 0.0, atol=1e-6)


def test_huge_but_close_distances_keep_their_relative_weights():
    indices, distances, positions = random_problem(seed=3)
    shifted = spatial_uncertainty(indices, distances + 1e6, positions)
    # distances + 1e6 keep only ~10 of their 16 digits, and exp(-slope * d) amplifies the loss: rtol 1e-6.
    assert_close(shifted, spatial_uncertainty(indices, distances, positions), rtol=1e-6)


def test_equal_distances_give_the_plain_variance():
    indices, _, positions = random_problem(seed=4, spread=300.0)  # within 500 m: no clipping
    result = spatial_uncertainty(indices, np.full(indices.shape, 0.7), positions)
    # numpy's var subtracts the mean first, the method weights by exp: other sums over UTM-sized coordinates.
    assert_close(result, positions[indices].var(axis=1).mean(axis=1), rtol=1e-9)


def test_clip_variants():
    positions = np.array([[0.0, 0.0], [-3000.0, 0.0], [3000.0, 0.0]])
    west = ([[0, 1]], [[0.5, 0.5]])
    east = ([[0, 2]], [[0.5, 0.5]])
    symmetric = [spatial_uncertainty(*case, positions)[0] for case in (west, east)]
    one_sided = [spatial_uncertainty(*case, positions, clip="one-sided")[0] for case in (west, east)]
    unclipped = spatial_uncertainty(*west, positions, clip="none")[0]
    # Two points, equal weights, round coordinates: every step is exact in binary, so == is meant.
    assert symmetric[0] == symmetric[1] == 500.0**2 / 2  # mirror images agree
    assert one_sided[0] == one_sided[1]  # two points: one deviation of each sign, so still symmetric
    assert unclipped == 1500.0**2 / 2
    # Three points: the one-sided clip depends on which way the axis points, the symmetric one does not.
    lopsided = np.array([[0.0, 0.0], [0.0, 0.0], [3000.0, 0.0]])  # mean x = 1000: deviations −1000, −1000, 2000
    three = ([[0, 1, 2]], [[0.5, 0.5, 0.5]])
    mirrored = lopsided * [-1, 1]
    assert_close(spatial_uncertainty(*three, lopsided)[0], 500.0**2 / 2)
    assert_close(spatial_uncertainty(*three, mirrored)[0], 500.0**2 / 2)
    assert_close(spatial_uncertainty(*three, lopsided, clip="one-sided")[0], (2 * 1000.0**2 + 500.0**2) / 6)
    assert_close(spatial_uncertainty(*three, mirrored, clip="one-sided")[0], (2 * 500.0**2 + 2000.0**2) / 6)
    assert spatial_uncertainty(*west, positions, max_deviation=100.0)[0] == 100.0**2 / 2


def test_missing_candidates_are_left_out():
    indices, distances, positions = random_problem(seed=5)
    padded_indices = indices.copy()
    padded_indices[:, 6:] = -1
    padded_distances = distances.copy()
    padded_distances[:, 6:] = np.inf
    assert_close(
        spatial_uncertainty(padded_indices, padded_distances, positions),
        spatial_uncertainty(indices[:, :6], distances[:, :6], positions),
    )
    padded_indices[0] = -1
    with pytest.raises(ValueError, match="no candidate"):
        spatial_uncertainty(padded_indices, padded_distances, positions)


def test_k_uses_the_first_columns():
    indices, distances, positions = random_problem(seed=6, k=20)
    assert_close(
        spatial_uncertainty(indices, distances, positions, k=10),
        spatial_uncertainty(indices[:, :10], distances[:, :10], positions),
    )


def test_one_dimensional_positions():
    positions = np.array([[0.0], [10.0]])
    assert spatial_uncertainty([[0, 1]], [[0.1, 0.1]], positions).tolist() == [25.0]


@pytest.mark.parametrize(
    ("arguments", "options", "message"),
    [
        (([[0, 5]], [[0.1, 0.2]], np.zeros((3, 2))), {}, "database_positions has 3 rows"),
        (([[0, 1]], [[0.1]], np.zeros((3, 2))), {}, "shape of indices"),
        (([[0, 1]], [[0.1, np.nan]], np.zeros((3, 2))), {}, "finite squared L2"),
        (([[0, 1]], [[-0.1, 0.1]], np.zeros((3, 2))), {}, "finite squared L2"),
        (([[0, 1]], [[0.1, np.inf]], np.zeros((3, 2))), {}, "finite squared L2"),
        (([[0, 1]], [[0.1, 0.2]], np.zeros(3)), {}, "database_positions"),
        (([[0, 1]], [[0.1, 0.2]], [[0.0, 0.0], [np.nan, 0.0]]), {}, "not finite"),
        (([[0, 1]], [[0.1, 0.2]], np.zeros((3, 2))), {"clip": "both"}, "clip must be one of"),
        (([[0, 1]], [[0.1, 0.2]], np.zeros((3, 2))), {"slope": -1.0}, "slope"),
        (([[0, 1]], [[0.1, 0.2]], np.zeros((3, 2))), {"max_deviation": 0.0}, "max_deviation"),
        (([[0, 1]], [[0.1, 0.2]], np.zeros((3, 2))), {"k": 0}, "k must be"),
    ],
)
def test_invalid_input(arguments, options, message):
    with pytest.raises(ValueError, match=message):
        spatial_uncertainty(*arguments, **options)


def test_no_queries():
    assert spatial_uncertainty(np.zeros((0, 10), int), np.zeros((0, 10)), np.zeros((3, 2))).shape == (0,)


# --- the registry entry -------------------------------------------------------------------------------------


def retrieval_of(indices, squared, positions, **extra) -> Retrieval:
    return Retrieval(scores=1 - squared / 2, indices=indices, database_positions=positions, **extra)


def test_registry_entry_uses_the_distances_or_the_scores():
    indices, distances, positions = random_problem(seed=7)
    expected = spatial_uncertainty(indices, distances, positions)
    with_distances = retrieval_of(indices, distances, positions, distances=distances)
    without = retrieval_of(indices, distances, positions)
    assert_close(get_method("SUE")(with_distances, k=10, alpha=0.3), expected)
    # Distances rebuilt from the scores (d² = 2 − 2s of s = 1 − d²/2) differ in the last bits, amplified by exp.
    assert_close(get_method("SUE")(without), expected, rtol=1e-9)
    assert_close(
        sue_from_retrieval(with_distances, clip="none"), spatial_uncertainty(indices, distances, positions, clip="none")
    )


def test_registry_entry_without_positions_is_a_clear_error():
    retrieval = Retrieval(scores=np.array([[0.9, 0.5]]), indices=np.array([[0, 1]]))
    with pytest.raises(ValueError, match="needs database_positions"):
        get_method("SUE")(retrieval)
    with pytest.raises(ValueError, match="positions of the database images"):
        sue_from_retrieval(retrieval)


@pytest.mark.parametrize("kind", ["frames", "placeholder"])
@pytest.mark.parametrize("nested", [False, True])
def test_warns_when_positions_are_not_metres(kind, nested):
    from vpr_uncertainty.data.dataset import PlaceholderPositionsWarning

    indices, distances, positions = random_problem(seed=8)
    config = {"dataset": {"name": "toy", "position_kind": kind}} if nested else {"position_kind": kind}
    retrieval = retrieval_of(indices, distances, positions, config=config)
    with pytest.warns(PlaceholderPositionsWarning, match=f"positions are '{kind}'"):
        sue_from_retrieval(retrieval)


def test_no_warning_for_metres():
    indices, distances, positions = random_problem(seed=9)
    retrieval = retrieval_of(indices, distances, positions, config={"position_kind": "metres"})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sue_from_retrieval(retrieval)
