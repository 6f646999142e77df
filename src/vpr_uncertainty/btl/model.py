"""The BTL head (frozen global descriptors in, an isotropic Gaussian embedding out: L2-normalised means, one variance
per image), its file, and the Bayesian triplet loss (Warburg et al., ICCV 2021). The architecture and the loss: see
docs/explanation/btl.md; the file: docs/reference/file-formats.md. Shapes: means (B, E), variances (B,) or (B, 1),
float32 or float64.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn
from torch.nn import functional

from vpr_uncertainty._validation import check_count
from vpr_uncertainty.cache import atomic_path

#: Weight λ of the KL term (the reference implementation's default ``kl_scale_factor``).
DEFAULT_KL_WEIGHT = 1e-6

#: Threshold m of P(τ < m) (the reference implementation's default).
DEFAULT_MARGIN = 0.0

#: Variance s² of the prior N(0, s² I): a unit Gaussian.
DEFAULT_PRIOR_VARIANCE = 1.0

_TINY = 1e-12


def _variance_column(variance: torch.Tensor, mean: torch.Tensor, name: str) -> torch.Tensor:
    """Variance as shape (B,), checked against the mean's batch size."""
    if variance.ndim == 2 and variance.shape[1] == 1:
        variance = variance[:, 0]
    if variance.ndim != 1 or variance.shape[0] != mean.shape[0]:
        raise ValueError(
            f"{name} must have shape ({mean.shape[0]},) or ({mean.shape[0]}, 1): one scalar per image, "
            f"got {tuple(variance.shape)}"
        )
    return variance


def _check_means(*means: torch.Tensor) -> None:
    shape = means[0].shape
    if len(shape) != 2:
        raise ValueError(f"means must have shape (batch, dimension), got {tuple(shape)}")
    for mean in means[1:]:
        if mean.shape != shape:
            raise ValueError(f"anchor, positive and negative means must have the same shape, got {tuple(mean.shape)}")


def triplet_distance_moments(
    mean_a: torch.Tensor,
    var_a: torch.Tensor,
    mean_p: torch.Tensor,
    var_p: torch.Tensor,
    mean_n: torch.Tensor,
    var_n: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and variance of τ = ‖a − p‖² − ‖a − n‖² for independent isotropic Gaussians (docs/explanation/btl.md).

    Parameters
    ----------
    mean_a, mean_p, mean_n : Tensor of shape (B, E)
    var_a, var_p, var_n : Tensor of shape (B,) or (B, 1)
        Variance per dimension (σ², not σ), positive.

    Returns
    -------
    mean, variance : Tensor of shape (B,)

    Examples
    --------
    >>> zero, one = torch.zeros(1, 1), torch.ones(1)
    >>> triplet_distance_moments(zero, one, zero, one, zero, one)  # τ = (a−p)² − (a−n)² in 1-D
    (tensor([0.]), tensor([12.]))
    """
    _check_means(mean_a, mean_p, mean_n)
    var_a = _variance_column(var_a, mean_a, "var_a")
    var_p = _variance_column(var_p, mean_a, "var_p")
    var_n = _variance_column(var_n, mean_a, "var_n")
    dimension = mean_a.shape[1]
    d_ap = (mean_a - mean_p).square().sum(dim=1)
    d_an = (mean_a - mean_n).square().sum(dim=1)
    d_pn = (mean_p - mean_n).square().sum(dim=1)
    mean = d_ap - d_an + dimension * (var_p - var_n)
    variance = (
        2 * dimension * (var_p.square() + var_n.square())
        + 4 * (var_p * d_ap + var_n * d_an + var_a * d_pn)
        + 4 * dimension * var_a * (var_p + var_n)
    )
    return mean, variance


def triplet_probability(
    mean_a: torch.Tensor,
    var_a: torch.Tensor,
    mean_p: torch.Tensor,
    var_p: torch.Tensor,
    mean_n: torch.Tensor,
    var_n: torch.Tensor,
    *,
    margin: float = DEFAULT_MARGIN,
    log: bool = False,
) -> torch.Tensor:
    """P(‖a − p‖² < ‖a − n‖² + margin) ≈ Φ((margin − E[τ]) / √Var[τ]), per triplet; shape (B,).

    With ``log=True`` the natural logarithm, computed stably (``torch.special.log_ndtr``).

    Examples
    --------
    >>> anchor, positive, negative = torch.tensor([[0.0, 0.0]]), torch.tensor([[0.1, 0.0]]), torch.tensor([[1.0, 0.0]])
    >>> small = torch.full((1,), 1e-4)
    >>> round(float(triplet_probability(anchor, small, positive, small, negative, small)), 4)
    1.0
    >>> round(float(triplet_probability(anchor, small, negative, small, positive, small)), 4)
    0.0
    """
    mean, variance = triplet_distance_moments(mean_a, var_a, mean_p, var_p, mean_n, var_n)
    z = (margin - mean) / variance.clamp_min(_TINY).sqrt()
    return torch.special.log_ndtr(z) if log else torch.special.ndtr(z)


def kl_to_isotropic_prior(
    mean: torch.Tensor, variance: torch.Tensor, prior_variance: float = DEFAULT_PRIOR_VARIANCE
) -> torch.Tensor:
    """KL(N(mean, variance·I) ‖ N(0, prior_variance·I)) per image; shape (B,).

    Examples
    --------
    >>> kl_to_isotropic_prior(torch.zeros(1, 3), torch.ones(1))
    tensor([0.])
    """
    variance = _variance_column(variance, mean, "variance")
    if not prior_variance > 0:
        raise ValueError(f"prior_variance must be positive, got {prior_variance}")
    dimension = mean.shape[1]
    ratio = variance / prior_variance
    return 0.5 * (
        dimension * ratio + mean.square().sum(dim=1) / prior_variance - dimension - dimension * torch.log(ratio)
    )


class TripletLossTerms(NamedTuple):
    """The loss of a batch and its two parts (means over the batch)."""

    loss: torch.Tensor
    nll: torch.Tensor
    kl: torch.Tensor


def bayesian_triplet_loss(
    mean_a: torch.Tensor,
    var_a: torch.Tensor,
    mean_p: torch.Tensor,
    var_p: torch.Tensor,
    mean_n: torch.Tensor,
    var_n: torch.Tensor,
    *,
    margin: float = DEFAULT_MARGIN,
    kl_weight: float = DEFAULT_KL_WEIGHT,
    prior_variance: float = DEFAULT_PRIOR_VARIANCE,
) -> TripletLossTerms:
    """Bayesian triplet loss of a batch: mean of −log P(τ < margin) + kl_weight · (KL_a + KL_p + KL_n).

    Parameters
    ----------
    mean_a, mean_p, mean_n : Tensor of shape (B, E)
        Means of the anchor, positive and negative embeddings.
    var_a, var_p, var_n : Tensor of shape (B,) or (B, 1)
        Their variances per dimension (positive).
    margin : float, default 0
        Threshold m of P(‖a − p‖² < ‖a − n‖² + m).
    kl_weight : float, default 1e-6
        Weight λ of the KL term.
    prior_variance : float, default 1
        Variance s² of the prior N(0, s² I).

    Returns
    -------
    TripletLossTerms
        ``loss`` (scalar, to minimise), ``nll`` and ``kl`` (batch means, unweighted).
    """
    if kl_weight < 0:
        raise ValueError(f"kl_weight must be >= 0, got {kl_weight}")
    nll = -triplet_probability(mean_a, var_a, mean_p, var_p, mean_n, var_n, margin=margin, log=True).mean()
    kl = (
        kl_to_isotropic_prior(mean_a, var_a, prior_variance)
        + kl_to_isotropic_prior(mean_p, var_p, prior_variance)
        + kl_to_isotropic_prior(mean_n, var_n, prior_variance)
    ).mean()
    return TripletLossTerms(loss=nll + kl_weight * kl, nll=nll, kl=kl)


HEAD_FORMAT = "vpr-uncertainty btl-head"

HEAD_FORMAT_VERSION = 1

#: Default embedding dimension: min(input_dim, this).
DEFAULT_MAX_EMBEDDING_DIM = 2048

#: The constructor arguments of :class:`BTLHead`, stored in the head file as ``config``.
_HEAD_CONFIG = ("input_dim", "embedding_dim", "hidden_dim", "min_variance", "initial_variance")


class BTLHead(nn.Module):
    """Mean embedding and scalar variance of each image from its frozen global descriptor.

    Parameters
    ----------
    input_dim : int
        Dimension of the descriptors (e.g. 1280 for ``efficientnet-lite0-gem``).
    embedding_dim : int, optional
        Dimension E of the mean embedding; default min(input_dim, 2048).
    hidden_dim : int, default 256
        Width of the variance branch.
    min_variance : float, default 1e-6
        Added to the softplus so that no variance is zero.
    initial_variance : float, optional
        Variance of every image before training (default 0.1 / embedding_dim).
    """

    def __init__(
        self,
        input_dim: int,
        embedding_dim: int | None = None,
        hidden_dim: int = 256,
        *,
        min_variance: float = 1e-6,
        initial_variance: float | None = None,
    ) -> None:
        super().__init__()
        if embedding_dim is None and isinstance(input_dim, (int, np.integer)):
            embedding_dim = min(int(input_dim), DEFAULT_MAX_EMBEDDING_DIM)
        for name, value in (("input_dim", input_dim), ("embedding_dim", embedding_dim), ("hidden_dim", hidden_dim)):
            check_count(value, name, 1)
        if not min_variance > 0:
            raise ValueError(f"min_variance must be positive, got {min_variance}")
        initial_variance = 0.1 / embedding_dim if initial_variance is None else float(initial_variance)
        if not initial_variance > min_variance:
            raise ValueError(f"initial_variance must exceed min_variance={min_variance}, got {initial_variance}")
        self.input_dim = int(input_dim)
        self.embedding_dim = int(embedding_dim)
        self.hidden_dim = int(hidden_dim)
        self.min_variance = float(min_variance)
        self.initial_variance = initial_variance
        self._input_scale = math.sqrt(self.input_dim)
        #: Training settings and history summary read from a head file (see :func:`load_btl_head`).
        self.metadata: dict[str, Any] = {}
        self.mean = nn.Linear(self.input_dim, self.embedding_dim)
        self.variance = nn.Sequential(
            nn.Linear(self.input_dim, self.hidden_dim), nn.ReLU(), nn.Linear(self.hidden_dim, 1)
        )
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """Orthonormal mean projection, zero bias; variance branch starting at ``initial_variance``."""
        nn.init.orthogonal_(self.mean.weight)
        nn.init.zeros_(self.mean.bias)
        last = self.variance[-1]
        nn.init.normal_(last.weight, std=1e-3)
        target = self.initial_variance - self.min_variance
        with torch.no_grad():  # inverse softplus: log(exp(y) − 1), written stably for small y
            last.bias.fill_(target + math.log(-math.expm1(-target)))

    @property
    def config(self) -> dict[str, Any]:
        """Constructor arguments, stored in the head file."""
        return {key: getattr(self, key) for key in _HEAD_CONFIG}

    def forward(self, descriptors: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Descriptors (B, input_dim) -> means (B, embedding_dim), unit norm, and variances (B,), positive."""
        if descriptors.ndim != 2 or descriptors.shape[1] != self.input_dim:
            raise ValueError(
                f"the BTL head takes descriptors of shape (batch, {self.input_dim}), got {tuple(descriptors.shape)}"
            )
        x = functional.normalize(descriptors, dim=1)
        mean = functional.normalize(self.mean(x), dim=1)
        # Unit-norm rows have entries of size ~1/sqrt(dim); rescaled to unit RMS, the variance branch can move
        # the log-variance by O(1) in a few steps instead of O(1e-2).
        variance = functional.softplus(self.variance(x * self._input_scale)[:, 0]) + self.min_variance
        return mean, variance


@torch.no_grad()
def embed(head: BTLHead, descriptors: object, *, batch_size: int = 8192) -> tuple[np.ndarray, np.ndarray]:
    """Means (N, E) and variances (N,) of descriptors (N, input_dim), as float32 numpy arrays, in eval mode.

    Examples
    --------
    >>> head = BTLHead(8, embedding_dim=4)
    >>> means, variances = embed(head, np.eye(8, dtype=np.float32))
    >>> means.shape, variances.shape, bool(np.allclose(np.linalg.norm(means, axis=1), 1))
    ((8, 4), (8,), True)
    """
    array = np.asarray(descriptors, dtype=np.float32)
    if array.ndim != 2 or array.shape[1] != head.input_dim:
        raise ValueError(
            f"descriptors must have shape (n_images, {head.input_dim}) for this BTL head, got {array.shape}"
        )
    if not np.isfinite(array).all():
        raise ValueError("descriptors contain NaN or inf")
    if len(array) and (np.abs(array).sum(axis=1) == 0).any():
        raise ValueError(f"descriptors row {int(np.flatnonzero(np.abs(array).sum(axis=1) == 0)[0])} is all zeros")
    was_training = head.training
    head.eval()
    device = next(head.parameters()).device
    means, variances = [], []
    try:
        for start in range(0, len(array), batch_size):
            batch = torch.from_numpy(array[start : start + batch_size]).to(device)
            mean, variance = head(batch)
            means.append(mean.float().cpu().numpy())
            variances.append(variance.float().cpu().numpy())
    finally:
        head.train(was_training)
    if not means:
        return np.empty((0, head.embedding_dim), np.float32), np.empty(0, np.float32)
    return np.concatenate(means), np.concatenate(variances)


#: Size of an anchor's sketch, and how far (L2) a query's sketch may lie from it to be that image again.
SKETCH_DIM, SKETCH_TOLERANCE = 16, 0.005


def row_sketches(descriptors: np.ndarray) -> np.ndarray:
    """A 16-D random projection of each L2-normalised row (N, SKETCH_DIM), rounded to 4 decimals: the same image
    described again in another precision (``--half``) or on another machine lies within
    :data:`SKETCH_TOLERANCE` of it (float16 moves it by at most about 5e-4), two different images far beyond it (the
    projection keeps distances: images at cosine 0.9995 lie about 0.03 apart)."""
    rows = np.asarray(descriptors, dtype=np.float64)
    rows = rows / np.maximum(np.linalg.norm(rows, axis=1, keepdims=True), 1e-12)
    projection = np.random.default_rng(rows.shape[1]).normal(0.0, SKETCH_DIM**-0.5, (rows.shape[1], SKETCH_DIM))
    return np.round(rows @ projection, 4)


def row_digests(descriptors: np.ndarray) -> list[str]:
    """A 16-hex-digit BLAKE2b digest of each descriptor row (float32 bytes): which images a head was trained on.

    Stored in the head file (``metadata["anchors"]["digests"]``) so that evaluating the head on its own training
    queries is caught (:func:`vpr_uncertainty.btl.method.btl_uncertainty`); the same descriptors give the same
    digests on any machine.
    """
    rows = np.ascontiguousarray(np.asarray(descriptors, dtype=np.float32))
    return [hashlib.blake2b(row.tobytes(), digest_size=8).hexdigest() for row in rows]


def save_btl_head(head: BTLHead, path: str | Path, *, metadata: dict[str, Any] | None = None) -> Path:
    """Write a head file (docs/reference/file-formats.md) and return its path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {
        "format": HEAD_FORMAT,
        "format_version": HEAD_FORMAT_VERSION,
        "config": head.config,
        "state_dict": {key: value.detach().cpu() for key, value in head.state_dict().items()},
        "metadata": dict(metadata or {}),
    }
    with atomic_path(path) as temporary:
        torch.save(state, temporary)
    return path


def load_btl_head(path: str | Path, *, device: str | torch.device = "cpu") -> BTLHead:
    """Read a head file written by :func:`save_btl_head`; the head is in eval mode on ``device``.

    The file's ``metadata`` is available as ``head.metadata``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"BTL head file not found: {path} (train one with `vpr-uncertainty train-btl`)")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises several types for foreign or corrupt files
        raise ValueError(f"{path} is not a readable BTL head file: {error}") from error
    if not isinstance(state, dict) or state.get("format") != HEAD_FORMAT:
        raise ValueError(f"{path} is not a BTL head file (expected format {HEAD_FORMAT!r})")
    version = int(state.get("format_version", 0))
    if version > HEAD_FORMAT_VERSION:
        raise ValueError(
            f"{path} has BTL head format version {version}; this toolkit reads up to {HEAD_FORMAT_VERSION}. "
            "Upgrade vpr-uncertainty."
        )
    config = dict(state["config"])
    head = BTLHead(**{key: config[key] for key in _HEAD_CONFIG})
    head.load_state_dict(state["state_dict"])
    head.metadata = dict(state.get("metadata") or {})
    return head.to(device).eval()
