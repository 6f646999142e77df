"""BTL (Bayesian triplet loss) head: loss against Monte Carlo, gradients, mining, training, file, method, CLI.

Synthetic data only; the real corridor descriptors are in test_btl_corridor.py.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from conftest import assert_close

torch = pytest.importorskip("torch")

from vpr_uncertainty.btl import (  # noqa: E402
    BTLHead,
    BTLTrainingConfig,
    bayesian_triplet_loss,
    btl_retrieval,
    btl_uncertainty,
    embed,
    kl_to_isotropic_prior,
    load_btl_head,
    mine_triplets,
    save_btl_head,
    train_btl_head,
    triplet_distance_moments,
    triplet_probability,
)
from vpr_uncertainty.btl.method import resolve_btl_inputs  # noqa: E402
from vpr_uncertainty.data import positives_within_radius  # noqa: E402
from vpr_uncertainty.evaluation import evaluate  # noqa: E402
from vpr_uncertainty.methods import OwnRetrievalUncertainty, get_method  # noqa: E402
from vpr_uncertainty.retrieval import Retrieval, top_k_from_similarity  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    # Tiny matrices: a second OpenMP thread only adds contention on the shared CI cores.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _gaussians(dimension: int, seed: int, scale: float = 0.5):
    g = torch.Generator().manual_seed(seed)
    means = [torch.randn(1, dimension, dtype=torch.float64, generator=g) / dimension**0.5 for _ in range(3)]
    variances = [
        torch.rand(1, dtype=torch.float64, generator=g) * scale / dimension + 1e-3 / dimension for _ in range(3)
    ]
    return means, variances


def _monte_carlo_tau(means, variances, samples: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    a, p, n = (
        mean + variance.sqrt() * torch.randn(samples, mean.shape[1], dtype=torch.float64, generator=g)
        for mean, variance in zip(means, variances, strict=True)
    )
    return (a - p).square().sum(1) - (a - n).square().sum(1)


# --- loss -------------------------------------------------------------------------------------------------------


# Normal approximation of τ, a sum of `dimension` independent non-Gaussian terms: rough in 1 to 3 dimensions
# (measured errors in P up to 0.08 in 1-D and 0.04 in 2-D), close in 64 and more (measured < 0.004).
APPROXIMATION_ERROR = {1: 0.12, 3: 0.06, 64: 0.008}
SAMPLES = {1: 200_000, 3: 200_000, 64: 50_000}


@pytest.mark.parametrize("dimension", [1, 3, 64])
def test_moments_and_probability_against_monte_carlo(dimension):
    """Mean and variance of τ are exact (they agree with sampling up to its standard error); P(τ < m) from the
    normal approximation agrees up to the approximation error plus the sampling error."""
    for seed in range(3):
        means, variances = _gaussians(dimension, seed)
        args = (means[0], variances[0], means[1], variances[1], means[2], variances[2])
        mean, variance = triplet_distance_moments(*args)
        tau = _monte_carlo_tau(means, variances, SAMPLES[dimension], seed + 10)
        n = tau.numel()
        centred = tau - tau.mean()
        mean_error = float(centred.square().mean().sqrt()) / n**0.5
        variance_error = float(((centred**4).mean() - centred.square().mean() ** 2).sqrt()) / n**0.5
        assert abs(float(mean) - float(tau.mean())) < 5 * mean_error
        assert abs(float(variance) - float(tau.var())) < 5 * variance_error
        for margin in (0.0, 0.1, -0.1):
            expected = float((tau < margin).double().mean())
            sampling_error = max(expected * (1 - expected), 1 / n) ** 0.5 / n**0.5
            probability = float(triplet_probability(*args, margin=margin))
            assert abs(probability - expected) < APPROXIMATION_ERROR[dimension] + 5 * sampling_error


def test_loss_is_negative_log_probability_plus_weighted_kl():
    means, variances = _gaussians(8, 0)
    args = (means[0], variances[0], means[1], variances[1], means[2], variances[2])
    terms = bayesian_triplet_loss(*args, margin=0.05, kl_weight=0.5, prior_variance=2.0)
    expected_nll = -torch.log(triplet_probability(*args, margin=0.05))
    expected_kl = sum(kl_to_isotropic_prior(m, v, 2.0) for m, v in zip(means, variances, strict=True))
    assert_close(float(terms.nll), float(expected_nll.mean()), rtol=1e-12)
    assert_close(float(terms.kl), float(expected_kl.mean()), rtol=1e-12)
    assert_close(float(terms.loss), float(terms.nll + 0.5 * terms.kl), rtol=1e-12)


def test_kl_matches_torch_distributions():
    from torch.distributions import Independent, Normal, kl_divergence

    g = torch.Generator().manual_seed(0)
    mean = torch.randn(4, 6, dtype=torch.float64, generator=g)
    variance = torch.rand(4, dtype=torch.float64, generator=g) + 0.1
    for prior_variance in (1.0, 0.25):
        posterior = Independent(Normal(mean, variance.sqrt()[:, None].expand_as(mean)), 1)
        prior = Independent(Normal(torch.zeros_like(mean), torch.full_like(mean, prior_variance**0.5)), 1)
        expected = kl_divergence(posterior, prior).numpy()
        # torch.distributions sums D per-dimension terms, the library a closed form: rtol 1e-10 in float64.
        assert_close(kl_to_isotropic_prior(mean, variance, prior_variance).numpy(), expected, rtol=1e-10)


def test_loss_prefers_ordered_triplets():
    anchor = torch.tensor([[1.0, 0.0]])
    near, far = torch.tensor([[0.9, 0.1]]), torch.tensor([[0.0, 1.0]])
    variance = torch.full((1,), 0.01)
    ordered = bayesian_triplet_loss(anchor, variance, near, variance, far, variance).loss
    swapped = bayesian_triplet_loss(anchor, variance, far, variance, near, variance).loss
    assert ordered < 0.01 < 1 < swapped


def test_gradients_are_correct_and_finite():
    means, variances = _gaussians(5, 1)
    inputs = [x.clone().requires_grad_() for pair in zip(means, variances, strict=True) for x in pair]

    def loss(mean_a, var_a, mean_p, var_p, mean_n, var_n):
        return bayesian_triplet_loss(mean_a, var_a, mean_p, var_p, mean_n, var_n, margin=0.1, kl_weight=0.1).loss

    assert torch.autograd.gradcheck(loss, inputs)
    # Far in the tails (P ≈ 1e-300 and P ≈ 1): the loss and its gradients stay finite.
    for sign in (1.0, -1.0):
        anchor = torch.zeros(1, 4, requires_grad=True)
        positive = (sign * torch.tensor([[1.0, 0, 0, 0]])).requires_grad_()
        negative = torch.tensor([[0.0, 0.0, 0.0, 0.0]], requires_grad=True)
        variance = torch.full((1,), 1e-6, requires_grad=True)
        value = bayesian_triplet_loss(anchor, variance, positive * 3, variance, negative, variance).loss
        value.backward()
        assert torch.isfinite(value)
        for tensor in (anchor, positive, negative, variance):
            assert torch.isfinite(tensor.grad).all()


def test_loss_rejects_inconsistent_shapes():
    mean, variance = torch.zeros(2, 3), torch.ones(2)
    with pytest.raises(ValueError, match="one scalar per image"):
        bayesian_triplet_loss(mean, torch.ones(2, 3), mean, variance, mean, variance)
    with pytest.raises(ValueError, match="same shape"):
        bayesian_triplet_loss(mean, variance, torch.zeros(2, 4), variance, mean, variance)


# --- head -------------------------------------------------------------------------------------------------------


def test_head_outputs_unit_means_and_positive_variances_and_backpropagates():
    torch.manual_seed(0)
    head = BTLHead(12, embedding_dim=5, hidden_dim=7)
    descriptors = torch.randn(9, 12)
    mean, variance = head(descriptors)
    assert mean.shape == (9, 5) and variance.shape == (9,)
    assert_close(mean.detach().norm(dim=1).numpy(), 1.0)
    assert (variance > head.min_variance).all()
    assert_close(variance.detach().numpy(), head.initial_variance, rtol=0.05)  # random init, not rounding
    bayesian_triplet_loss(mean[:3], variance[:3], mean[3:6], variance[3:6], mean[6:], variance[6:]).loss.backward()
    for parameter in head.parameters():
        assert parameter.grad is not None and torch.isfinite(parameter.grad).all()
    with pytest.raises(ValueError, match=r"shape \(batch, 12\)"):
        head(torch.randn(2, 11))


def test_untrained_square_head_retrieves_like_the_descriptors():
    rng = np.random.default_rng(0)
    database, queries = rng.normal(size=(40, 16)).astype(np.float32), rng.normal(size=(10, 16)).astype(np.float32)
    head = BTLHead(16)  # embedding_dim defaults to 16: a rotation
    assert head.embedding_dim == 16
    unit = lambda x: x / np.linalg.norm(x, axis=1, keepdims=True)  # noqa: E731
    query_means, _ = embed(head, queries)
    database_means, _ = embed(head, database)
    assert_close(query_means @ database_means.T, unit(queries) @ unit(database).T, atol=1e-5)


# --- mining -----------------------------------------------------------------------------------------------------


def test_mining_takes_nearest_non_positives_and_most_similar_positives():
    rng = np.random.default_rng(1)
    database = rng.normal(size=(30, 8))
    queries = rng.normal(size=(6, 8))
    positives = rng.random((6, 30)) < 0.2
    positives[0] = False  # no positive: no triplet
    triplets = mine_triplets(queries, database, positives, n_negatives=4, max_positives=2)
    unit = lambda x: x / np.linalg.norm(x, axis=1, keepdims=True)  # noqa: E731
    similarity = unit(queries) @ unit(database).T
    assert 0 not in triplets.anchor
    for anchor in range(1, 6):
        rows = triplets.anchor == anchor
        own = np.flatnonzero(positives[anchor])
        expected_positives = own[np.argsort(-similarity[anchor, own])][:2]
        others = np.flatnonzero(~positives[anchor])
        expected_negatives = others[np.argsort(-similarity[anchor, others])][:4]
        assert set(triplets.positive[rows]) == set(expected_positives)
        assert set(triplets.negative[rows]) == set(expected_negatives)
        assert rows.sum() == len(expected_positives) * 4
        assert not positives[anchor, triplets.negative[rows]].any()


def test_mining_on_one_set_never_uses_the_anchor_itself():
    positions = np.arange(20, dtype=float)[:, None] * np.array([[10.0, 0.0]])
    descriptors = np.random.default_rng(2).normal(size=(20, 6))
    positives = positives_within_radius(positions, positions, 15.0)  # itself and its neighbours
    triplets = mine_triplets(descriptors, descriptors, positives, n_negatives=3, same_set=True)
    assert (triplets.anchor != triplets.positive).all() and (triplets.anchor != triplets.negative).all()
    assert (np.abs(triplets.anchor - triplets.positive) == 1).all()
    assert (np.abs(triplets.anchor - triplets.negative) > 1).all()


# --- training, file, method -------------------------------------------------------------------------------------


def _synthetic_places(seed: int = 0, n_database: int = 200, n_queries: int = 100, dimension: int = 24):
    """Places along a 1.5 km road; descriptors are smooth functions of the position plus noise that varies."""
    rng = np.random.default_rng(seed)
    frequencies = rng.uniform(0.002, 0.02, size=dimension // 2)
    phases = rng.uniform(0, 2 * np.pi, size=dimension // 2)

    def describe(x, noise):
        angle = frequencies * x[:, None] + phases
        clean = np.concatenate([np.cos(angle), np.sin(angle)], axis=1)
        return (clean + noise[:, None] * rng.normal(size=clean.shape)).astype(np.float32)

    database_x = np.sort(rng.uniform(0, 1500, n_database))
    query_x = rng.uniform(0, 1500, n_queries)
    database = describe(database_x, np.full(n_database, 0.1))
    queries = describe(query_x, rng.uniform(0.05, 0.6, n_queries))
    as_2d = lambda x: np.stack([x, np.zeros_like(x)], axis=1)  # noqa: E731
    return database, queries, as_2d(database_x), as_2d(query_x)


SMALL = {"hidden_dim": 16, "epochs": 12, "patience": 3, "n_negatives": 3, "max_positives": 5, "learning_rate": 3e-4}


@pytest.fixture(scope="module")
def trained():
    database, queries, database_positions, query_positions = _synthetic_places()
    positives = positives_within_radius(query_positions, database_positions, 25.0)
    head, history = train_btl_head(database, positives, query_descriptors=queries, progress=False, **SMALL)
    return head, history, (database, queries, positives)


def test_training_lowers_validation_loss_and_is_deterministic(trained):
    head, history, (database, queries, positives) = trained
    assert history.epoch[0] == 0 and len(history.val_loss) == len(history.epoch) >= 2
    assert history.best_val_loss < history.initial_val_loss - 0.01
    assert history.best_epoch >= 1 and np.isfinite(history.train_loss).all()
    assert history.n_val_anchors >= 1 and history.n_train_anchors > history.n_val_anchors
    assert head.metadata["training"]["seed"] == 0 and head.metadata["history"]["best_epoch"] == history.best_epoch
    _, again = train_btl_head(database, positives, query_descriptors=queries, progress=False, **{**SMALL, "epochs": 2})
    assert again.val_loss == history.val_loss[:3]  # same seed: same split, triplets, init and shuffling


def test_training_database_on_itself_from_positions():
    database, _, database_positions, _ = _synthetic_places(seed=1)
    positives = positives_within_radius(database_positions, database_positions, 25.0)
    head, history = train_btl_head(database, positives, progress=False, **{**SMALL, "epochs": 3})
    assert head.metadata["training"]["epochs"] == 3 and history.epoch[-1] <= 3


def test_training_rejects_bad_inputs():
    database, queries, database_positions, query_positions = _synthetic_places()
    positives = positives_within_radius(query_positions, database_positions, 25.0)
    with pytest.raises(ValueError, match="val_fraction"):
        BTLTrainingConfig(val_fraction=0.0)
    with pytest.raises(ValueError, match="positives must have shape"):
        train_btl_head(database, positives.T, query_descriptors=queries, progress=False)
    with pytest.raises(ValueError, match="at least 2"):
        train_btl_head(database, np.zeros((100, 200), bool), query_descriptors=queries, progress=False)
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="no CUDA GPU"):
            train_btl_head(database, positives, query_descriptors=queries, progress=False, device="cuda")


def test_head_file_round_trip(trained, tmp_path):
    head, _, (database, queries, _) = trained
    path = save_btl_head(head, tmp_path / "head.pt", metadata=head.metadata)
    loaded = load_btl_head(path)
    assert loaded.config == head.config and loaded.metadata == head.metadata
    for (mean, variance), (mean2, variance2) in [(embed(head, x), embed(loaded, x)) for x in (database, queries)]:
        np.testing.assert_array_equal(mean, mean2)  # the same weights through the same code path
        np.testing.assert_array_equal(variance, variance2)
    (tmp_path / "other.pt").write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match="not a readable BTL head"):
        load_btl_head(tmp_path / "other.pt")
    torch.save({"weights": torch.zeros(2)}, tmp_path / "foreign.pt")
    with pytest.raises(ValueError, match="not a BTL head file"):
        load_btl_head(tmp_path / "foreign.pt")
    with pytest.raises(FileNotFoundError, match="train-btl"):
        load_btl_head(tmp_path / "missing.pt")


def _shared_retrieval(database, queries, positives, k=10):
    unit = lambda x: x / np.linalg.norm(x, axis=1, keepdims=True)  # noqa: E731
    scores, indices = top_k_from_similarity(unit(queries) @ unit(database).T, k)
    return Retrieval(scores=scores, indices=indices, positives=positives)


def test_btl_method_answers_with_its_own_retrieval(trained, tmp_path):
    head, _, (database, queries, positives) = trained
    path = save_btl_head(head, tmp_path / "head.pt")
    retrieval = _shared_retrieval(database, queries, positives)
    options = {"btl_head": str(path), "query_descriptors": queries, "database_descriptors": database}
    result = get_method("BTL")(retrieval, k=10, alpha=0.5, **options)
    assert isinstance(result, OwnRetrievalUncertainty)
    _, variances = embed(head, queries)
    assert_close(result.uncertainty, variances)
    means_q, _ = embed(head, queries)
    means_d, _ = embed(head, database)
    np.testing.assert_array_equal(result.retrieval.indices[:, 0], np.argmax(means_q @ means_d.T, axis=1))
    assert (result.retrieval.positives != retrieval.positives).nnz == 0 and result.retrieval.k == retrieval.k
    assert get_method("BTL").extra == "torch"

    evaluation = evaluate(retrieval, ["BTL", "BM"], **options)
    btl = evaluation.to_dict()["methods"]["BTL"]
    assert btl["correctness_from"] == "own retrieval"
    own_correct = positives.toarray()[np.arange(len(queries)), result.retrieval.indices[:, 0]]
    answerable = positives.toarray().any(axis=1)
    assert_close(btl["own_recall@1"], own_correct[answerable].mean())
    assert any(note.startswith("BTL retrieves with its own embeddings") for note in evaluation.notes)
    assert "correctness_from" not in evaluation.to_dict()["methods"]["BM"]


def test_btl_method_errors_are_clear(trained, tmp_path):
    head, _, (database, queries, positives) = trained
    retrieval = _shared_retrieval(database, queries, positives)
    with pytest.raises(ValueError, match="needs a trained head: pass btl_head"):
        btl_uncertainty(retrieval, query_descriptors=queries, database_descriptors=database)
    with pytest.raises(FileNotFoundError, match="train-btl"):
        options = {"btl_head": tmp_path / "none.pt", "query_descriptors": queries, "database_descriptors": database}
        resolve_btl_inputs(retrieval, options)
    with pytest.raises(ValueError, match="query_descriptors="):
        btl_uncertainty(retrieval, btl_head=head, database_descriptors=database)
    with pytest.raises(ValueError, match="database_descriptors="):
        btl_uncertainty(retrieval, btl_head=head, query_descriptors=queries)
    with pytest.raises(ValueError, match="rows but the retrieval has 100 queries"):
        btl_uncertainty(retrieval, btl_head=head, query_descriptors=queries[:5], database_descriptors=database)
    with pytest.raises(ValueError, match="trained on 24-D"):
        btl_retrieval(retrieval, btl_head=head, query_descriptors=queries[:, :8], database_descriptors=database[:, :8])


# --- command line -----------------------------------------------------------------------------------------------


def _run_cli(argv: list[str]) -> int:
    from vpr_uncertainty.pipeline import train_btl

    parser = argparse.ArgumentParser(prog="vpr-uncertainty")
    train_btl.add_cli(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.handler(args)


def test_cli_trains_from_npy_and_positions(tmp_path, capsys):
    database, queries, database_positions, query_positions = _synthetic_places()
    for name, array in {
        "db.npy": database,
        "q.npy": queries,
        "db_pos.npy": database_positions,
        "q_pos.npy": query_positions,
    }.items():
        np.save(tmp_path / name, array)
    out = tmp_path / "heads" / "head.pt"
    common = ["--embedding-dim", "16", "--hidden-dim", "16", "--epochs", "3", "--negatives", "5", "--no-progress"]
    argv = ["train-btl", "--descriptors", str(tmp_path / "db.npy")]
    argv += ["--database-positions", str(tmp_path / "db_pos.npy")]
    assert _run_cli([*argv, "--query-descriptors", str(tmp_path / "q.npy"), "--query-positions",
                     str(tmp_path / "q_pos.npy"), "--out", str(out), *common]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    assert "100 queries as anchors" in printed and "validation loss" in printed
    curve = json.loads((tmp_path / "heads" / "head.curve.json").read_text())
    assert curve["epoch"][0] == 0 and len(curve["val_loss"]) == len(curve["epoch"])
    assert (tmp_path / "heads" / "head.curve.png").read_bytes()[:4] == b"\x89PNG"
    head = load_btl_head(out)
    assert head.metadata["source"]["anchors"] == "queries" and head.metadata["source"]["radius"] == 25.0

    # Without query ground truth the database trains on itself.
    assert _run_cli([*argv, "--out", str(tmp_path / "db_only.pt"), *common, "--epochs", "1"]) == 0
    assert "200 database images as anchors" in capsys.readouterr().out
    with pytest.raises(ValueError, match="--database-positions"):
        _run_cli(["train-btl", "--descriptors", str(tmp_path / "db.npy"), "--out", str(tmp_path / "x.pt")])
