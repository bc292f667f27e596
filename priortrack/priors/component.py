"""One component of a mixture transition, as a Gaussian transition of its own.

The Lie prior's transition is a mixture (:meth:`~priortrack.priors.lie.LiePrior.step_components`; with a defensive
share of diffusion, :class:`~priortrack.priors.defensive.DefensiveMixture`'s K + 1 components):

    p(x_t | x_{t−1}) = Σ_k π_k(x_{t−1}) N(x_t ⊟ x_{t−1}; ū_k(x_{t−1}), Q_k(x_{t−1})),

steps u = x_t ⊟ x_{t−1} in the tangent coordinates of ``space.local`` at x_{t−1}. Component k alone,

    p_k(x_t | x_{t−1}) = N(x_t ⊟ x_{t−1}; ū_k(x_{t−1}), Q_k(x_{t−1})),

mean step x ⊞ ū_k(x), noise covariance Q_k(x), is the Gaussian transition that one member of a Gaussian-sum
unscented filter runs (:mod:`priortrack.filters.gaussian_sum`). ``k`` is set by that filter before each step.
"""

from __future__ import annotations

import math

import torch

from priortrack.errors import PriortrackError
from priortrack.priors.base import BuiltOnPrior


class ComponentTransition(BuiltOnPrior):
    """Component ``k`` of ``mixture`` (a prior with ``step_weights`` and ``step_components``) as a
    :class:`~priortrack.models.protocols.GaussianTransition` on the mixture's state space. Everything but the
    transition (``space``, ``encode``, ``joints``, …) is the mixture's."""

    BASE, WHAT = "mixture", "a mixture component"

    def __init__(self, mixture, k: int = 0):
        if not (hasattr(mixture, "step_weights") and hasattr(mixture, "step_components")):
            raise PriortrackError(f"a mixture component needs a prior whose transition is a mixture of Gaussian steps "
                                  f"(step_weights, step_components); the {mixture.kind!r} prior has none")
        self.mixture, self.k = mixture, int(k)

    def _step(self, x: torch.Tensor, covariances: bool):
        """ū_k(x) (P, n) and Q_k(x) (P, n, n) (None unless ``covariances``) at states x (P, S)."""
        index = torch.full((len(x), 1), self.k, dtype=torch.long, device=x.device)
        _, mean, cov = self.mixture.step_components(x, covariances, index)
        return mean[:, 0].to(x), None if cov is None else cov[:, 0].to(x)

    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """(P, S) → (P, S) x ⊞ ū_k(x)."""
        return self.mixture.space.retract(x, self._step(x, False)[0])

    def transition_covariance(self, x: torch.Tensor) -> torch.Tensor:
        """(P, S) → (P, n, n) Q_k(x)."""
        return self._step(x, True)[1]

    def sample(self, x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """(P, S) → (P, S): x ⊞ (ū_k(x) + L ε), L Lᵀ = Q_k(x), ε ~ N(0, I)."""
        mean, cov = self._step(x, True)
        eps = torch.randn(mean.shape, generator=generator, dtype=x.dtype, device=x.device)
        return self.mixture.space.retract(x, mean + (torch.linalg.cholesky(cov) @ eps[..., None])[..., 0])

    def log_prob(self, x_next: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """(P, S), (P, S) → (P,) ln N(x_next ⊟ x; ū_k(x), Q_k(x))."""
        mean, cov = self._step(x, True)
        r = self.mixture.space.local(x_next, x) - mean
        L = torch.linalg.cholesky(cov)
        white = torch.linalg.solve_triangular(L, r[..., None], upper=False)[..., 0]
        return (-0.5 * (white * white).sum(-1) - torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
                - 0.5 * r.shape[-1] * math.log(2 * math.pi))
