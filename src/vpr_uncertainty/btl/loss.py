r"""The Bayesian triplet loss (Warburg et al., "Bayesian Triplet Loss: Uncertainty Quantification in Image
Retrieval", ICCV 2021) for isotropic Gaussian embeddings.

Every image is an isotropic Gaussian in R^E: a mean μ (E,) and one scalar variance σ² (per dimension). For an
anchor a ~ N(μa, σa² I), a positive p ~ N(μp, σp² I) and a negative n ~ N(μn, σn² I), independent, let

    τ = ‖a − p‖² − ‖a − n‖² = Σ_d τ_d,     τ_d = p_d² − n_d² − 2 a_d (p_d − n_d).

The loss is the negative log-probability that the triplet is ordered, up to a margin m:

    −log P(‖a − p‖² < ‖a − n‖² + m) = −log P(τ < m).

**Moments of τ (exact).** The dimensions are independent, so the means and the variances of the τ_d add up.
With E[x²] = μ² + σ², Var[x²] = 4μ²σ² + 2σ⁴, Cov(x², a x) = 2 μa μx σx² and
Var[a(p − n)] = μa²(σp² + σn²) + σa²(μp − μn)² + σa²(σp² + σn²), collecting the terms per dimension gives

    E[τ]   = ‖μa − μp‖² − ‖μa − μn‖² + E (σp² − σn²)

    Var[τ] = 2E (σp⁴ + σn⁴)
             + 4 σp² ‖μp − μa‖² + 4 σn² ‖μn − μa‖² + 4 σa² ‖μp − μn‖²
             + 4E σa² (σp² + σn²)

(expanding the squares gives exactly the sums ``2·T1 + 2·T2 − 2·T3`` of the authors' reference implementation).

**Normal approximation (the paper's).** τ is a sum of E independent non-Gaussian terms; the paper approximates
it by N(E[τ], Var[τ]), so that

    P(τ < m) ≈ Φ((m − E[τ]) / √Var[τ]).

The approximation is good when E is large (central limit over the dimensions) and poorest in low dimension
with variances comparable to the distances between the means; the tests measure it against Monte Carlo.
−log Φ is computed with ``torch.special.log_ndtr``, which stays finite and keeps its gradient where Φ underflows
(the reference code computes log(Φ + 1e-8) instead, whose gradient vanishes there).

**Margin.** The threshold m enters as P(τ < m): m = 0 (the reference implementation's default) asks that the
positive is nearer than the negative; a negative m asks for a classic margin, ‖a − p‖² + |m| < ‖a − n‖².

**KL regulariser.** Each embedding is pulled towards the prior N(0, s² I) (unit Gaussian: s² = 1) by

    KL(N(μ, σ² I) ‖ N(0, s² I)) = ½ [E σ²/s² + ‖μ‖²/s² − E + E log(s²/σ²)],

summed over the anchor, the positive and the negative and weighted by λ = 1e-6 (``kl_weight``; the default
``kl_scale_factor`` of the reference implementation). With L2-normalised means ‖μ‖² = 1 and the KL acts on the
variances only, keeping them from collapsing to zero.

Loss of a batch of B triplets: mean over the batch of −log Φ(...) + λ (KL_a + KL_p + KL_n).

Shapes: means (B, E), variances (B,) or (B, 1) (one scalar per image), float32 or float64.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

__all__ = [
    "DEFAULT_KL_WEIGHT",
    "DEFAULT_MARGIN",
    "DEFAULT_PRIOR_VARIANCE",
    "BayesianTripletLoss",
    "TripletLossTerms",
    "bayesian_triplet_loss",
    "kl_to_isotropic_prior",
    "triplet_distance_moments",
    "triplet_probability",
]

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
    """Mean and variance of τ = ‖a − p‖² − ‖a − n‖² for independent isotropic Gaussians (module docstring).

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


class BayesianTripletLoss(nn.Module):
    """:func:`bayesian_triplet_loss` as a module; ``forward`` returns :class:`TripletLossTerms`."""

    def __init__(
        self,
        margin: float = DEFAULT_MARGIN,
        kl_weight: float = DEFAULT_KL_WEIGHT,
        prior_variance: float = DEFAULT_PRIOR_VARIANCE,
    ) -> None:
        super().__init__()
        self.margin = float(margin)
        self.kl_weight = float(kl_weight)
        self.prior_variance = float(prior_variance)

    def forward(
        self,
        mean_a: torch.Tensor,
        var_a: torch.Tensor,
        mean_p: torch.Tensor,
        var_p: torch.Tensor,
        mean_n: torch.Tensor,
        var_n: torch.Tensor,
    ) -> TripletLossTerms:
        """Means (B, E) and variances (B,) of anchors, positives and negatives -> loss terms."""
        return bayesian_triplet_loss(
            mean_a,
            var_a,
            mean_p,
            var_p,
            mean_n,
            var_n,
            margin=self.margin,
            kl_weight=self.kl_weight,
            prior_variance=self.prior_variance,
        )

    def extra_repr(self) -> str:
        return f"margin={self.margin}, kl_weight={self.kl_weight}, prior_variance={self.prior_variance}"
