"""A defensive mixture transition: a learned prior with a fraction ε of local diffusion.

    p(x_t | x_{t−1}) = (1 − ε) p_learned(x_t | x_{t−1}) + ε p_diffusion(x_t | x_{t−1}),

both on the same state space (the learned prior's: bone directions for the Lie prior, joint angles
for a diffusion). A particle filter draws each particle's step from the learned prior with
probability 1 − ε and from the diffusion otherwise, and scores it by the mixture's density above
(``log_prob``: a log-sum-exp), so it is the transition model of the mixture, not a heuristic
jitter. (Hesterberg's defensive importance sampling; the same idea keeps a learned proposal from
losing a motion it has no component for.)

Why: the Lie prior's conditional p(v | x) is narrow in pace. A walk at 0.6× the training pace fell
outside it and the particle filter lost it (07_10: 178 mm; 35_29: 250 mm); with ε = 0.1 a tenth
of the particles can follow any small step and the ones that fit the data survive (63 and 62 mm),
while the normal pace stays where it was (43 → 38 mm on 35_29, 61 → 63 on 07_10).

An unscented filter runs the mixture as Gaussians: moment-matched to one (:meth:`DefensiveMixture.mean`,
:meth:`DefensiveMixture.transition_covariance`), the diffusion's share stays ε whatever the data say, and on a
motion the learned prior does not know the filter believes it (Shelf's actor 1, at work on the shelf, not walking:
PCP 86.5 % where ukf-real reaches 92.9 %). :class:`DefensivePair` is the mixture as two Gaussian steps, the learned
prior moment-matched and the diffusion, for the Gaussian-sum filter to weigh by their evidence each frame.
"""

from __future__ import annotations

import math

import torch

from priortrack.errors import PriortrackError
from priortrack.priors.base import BuiltOnPrior

#: The state spaces a defensive diffusion can share, by the learned prior's space class.
DEFENSIVE_SPACES = {"DirectionSpace": "directions", "AngleSpace": "angles"}


class DefensiveMixture(BuiltOnPrior):
    """(1 − ε) ``learned`` + ε ``fallback`` (module docstring). Everything but the transition
    (``space``, ``encode``, ``joints``, ``initial``, …) is the learned prior's.

    Args:
        learned: the prior (a TransitionModel).
        fallback: a diffusion on the same state space (same state width).
        epsilon: ε in (0, 1).
    """

    def __init__(self, learned, fallback, epsilon: float):
        if isinstance(epsilon, bool) or not isinstance(epsilon, (int, float)) or not 0 < epsilon < 1:
            raise PriortrackError(f"the defensive fraction must be in (0, 1), got {epsilon!r}")
        if fallback.state_dim != learned.state_dim:
            raise PriortrackError(f"the defensive diffusion's states have {fallback.state_dim} numbers, the "
                                  f"{learned.kind} prior's {learned.state_dim}: they must share a state space")
        self.learned, self.fallback, self.epsilon = learned, fallback, float(epsilon)

    #: The learned prior's are the state space and the start (``SHARED``); the transition's own methods
    #: (a mean step, a covariance) are the mixture's (:meth:`mean`, :meth:`transition_covariance`).
    BASE, WHAT = "learned", "a defensive mixture"

    def sample(self, x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """(P, S) → (P, S): each row's step from the fallback with probability ε, else from the learned prior."""
        learned, fallback = self.learned.sample(x, generator), self.fallback.sample(x, generator).to(x.dtype)
        chosen = torch.rand(len(x), generator=generator, device=x.device) < self.epsilon
        return torch.where(chosen[:, None], fallback, learned)

    def learned_step(self, x: torch.Tensor) -> torch.Tensor:
        """(P, S) → (P, n) ū, the learned prior's mean step log_x(mean(x)) in the tangent coordinates of
        ``space.local`` at each row (the diffusion's mean step is 0)."""
        return self.learned.space.local(self.learned.mean(x), x)

    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """(P, S) → (P, S) x ⊞ (1 − ε) ū: the mixture's mean step (the diffusion stays put)."""
        space = self.learned.space
        step = space.boxminus(self.learned.mean(x), x)
        return space.boxplus(x, (1 - self.epsilon) * step)

    def transition_covariance(self, x: torch.Tensor) -> torch.Tensor:
        """(P, S) → (P, n, n) the mixture's step covariance, moment-matched (what the unscented filter runs):

            (1 − ε) Σ_learned + ε Σ_diffusion + ε (1 − ε) ū ūᵀ,

        ū the learned mean step (:meth:`learned_step`); both parts' covariances in the coordinates of
        ``space.local`` (the diffusion's is isotropic per joint, the same in any orthonormal basis)."""
        u = self.learned_step(x)
        eps = self.epsilon
        return ((1 - eps) * self.learned.transition_covariance(x) + eps * self.fallback.transition_covariance(x).to(u)
                + eps * (1 - eps) * u[:, :, None] * u[:, None, :])

    def step_weights(self, x: torch.Tensor) -> torch.Tensor:
        """ln π (P, K + 1) of :meth:`step_components`: the learned prior's weights and the diffusion's, by 1 − ε and ε."""
        return torch.cat([self.learned.step_weights(x).to(torch.float64) + math.log1p(-self.epsilon),
                          self.fallback.step_weights(x).to(torch.float64) + math.log(self.epsilon)], 1)

    def step_components(self, x: torch.Tensor, covariances: bool = True, components: torch.Tensor | None = None):
        """The learned prior's K Gaussian steps weighted by 1 − ε and the diffusion's one (index K) by ε (each
        ``step_components``): ln π (P, K + 1), means (P, K + 1, n), covariances (P, K + 1, n, n) (None unless
        ``covariances``); with ``components`` (P, k) indices, those of each row only."""
        K = self.learned.step_weights(x[:1]).shape[1]
        learned = None if components is None else torch.where(components < K, components, 0)
        (log_a, mean_a, cov_a), (log_b, mean_b, cov_b) = (self.learned.step_components(x, covariances, learned),
                                                          self.fallback.step_components(x, covariances))
        log_a, log_b = log_a.to(torch.float64) + math.log1p(-self.epsilon), log_b.to(torch.float64) + math.log(self.epsilon)
        mean_b, cov_b = mean_b.to(mean_a), None if cov_b is None else cov_b.to(cov_a)
        if components is None:
            return (torch.cat([log_a, log_b], 1), torch.cat([mean_a, mean_b], 1),
                    torch.cat([cov_a, cov_b], 1) if covariances else None)
        diffusion = components == K
        return (torch.where(diffusion, log_b, log_a), torch.where(diffusion[..., None], mean_b, mean_a),
                torch.where(diffusion[..., None, None], cov_b, cov_a) if covariances else None)

    def log_prob(self, x_next: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """(P,) ln[(1 − ε) p_learned + ε p_fallback], in float64."""
        return torch.logaddexp(math.log1p(-self.epsilon) + self.learned.log_prob(x_next, x).to(torch.float64),
                               math.log(self.epsilon) + self.fallback.log_prob(x_next, x).to(torch.float64))


class DefensivePair(BuiltOnPrior):
    """A :class:`DefensiveMixture` as two Gaussian steps (k = 0, 1), in the tangent coordinates of ``space.local``:

        p(x_t | x_{t−1}) ≈ (1 − ε) N(u; ū_L(x), Σ_L(x)) + ε N(u; 0, Σ_D(x)),   u = x_t ⊟ x_{t−1},

    ū_L, Σ_L the learned prior's conditional step moment-matched to one Gaussian (its ``mean`` and
    ``transition_covariance``: the Lie prior's every component at once), Σ_D the diffusion's. The Gaussian-sum
    unscented filter on these two components (``ukf-sum`` with ``moment_matched = true``) is a two-model filter
    (the generalised pseudo-Bayesian filter of order 2; Bar-Shalom, Li & Kirubarajan, *Estimation with Applications
    to Tracking*, §11.6) whose models' weights the frames' evidence sets: the diffusion carries the estimate where
    the learned prior does not explain the data, as the defensive particles do in a particle filter. The state space
    and the start are the mixture's."""

    BASE, WHAT = "mixture", "a defensive mixture's two Gaussian steps"

    def __init__(self, mixture: DefensiveMixture):
        if not isinstance(mixture, DefensiveMixture):
            raise PriortrackError(f"two Gaussian steps are a defensive mixture's (a [prior] defensive share); the "
                                  f"{mixture.kind!r} prior has no defensive share")
        self.mixture = mixture

    def step_weights(self, x: torch.Tensor) -> torch.Tensor:
        """(P, S) → ln π (P, 2): ln(1 − ε), ln ε at every state."""
        eps = self.mixture.epsilon
        return torch.tensor([math.log1p(-eps), math.log(eps)], dtype=torch.float64, device=x.device).expand(len(x), 2)

    def step_components(self, x: torch.Tensor, covariances: bool = True, components: torch.Tensor | None = None):
        """ln π (P, 2), the mean steps (P, 2, n) (ū_L, 0) and covariances (P, 2, n, n) (Σ_L, Σ_D) (None unless
        ``covariances``); with ``components`` (P, k) indices in {0, 1}, those of each row only."""
        u = self.mixture.learned_step(x)
        log_pi, means = self.step_weights(x), torch.stack([u, torch.zeros_like(u)], 1)
        cov = (torch.stack([self.mixture.learned.transition_covariance(x).to(u),
                            self.mixture.fallback.transition_covariance(x).to(u)], 1) if covariances else None)
        if components is None:
            return log_pi, means, cov
        rows = torch.arange(len(x), device=x.device)[:, None]
        return log_pi[rows, components], means[rows, components], None if cov is None else cov[rows, components]
