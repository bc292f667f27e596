"""The annealed particle filter (Deutscher & Reid, IJCV 2005): the articulated-tracking baseline.

Each frame the predicted particles s^i are refined through L annealing layers l = 1 … L:

    weight    w^i ∝ p(z | s^i)^{β_l},  β_l chosen by bisection so that the survival rate
              α = ESS / P = 1 / (P Σ (w^i)²) equals the target (default ½), β_l ≥ β_{l−1}, β_l ≤ 1
    (l < L) resample by w, then diffuse: s^i ← s^i ⊞ N(0, α^l · diag σ̂²), σ̂² the prior's own
              one-step spread per joint (in its tangent space) and the global model's σ_G² for
              the placement, so the search narrows layer by layer. (Deutscher & Reid scale the
              particle set's covariance instead; with one camera the set's spread along the
              unobserved depth grows without bound under that rule, and it diverged here.)

After the last layer the weights w^i ∝ p(z | s^i)^{β_L} define the estimate (weighted mean on the
prior's manifold) and the set is resampled. The tempered weights make it a stochastic search,
not a Bayesian posterior: it is the standard baseline, not a replacement for the particle filter.
Only the current placement g_t is diffused; g_{t−1} is the history the global model needs.
With ``translation="marginalised"`` the translation is not diffused at all: every layer scores
the predictive likelihood of each particle's Kalman filter (:mod:`priortrack.filters.marginal_translation`)
and the last layer's update is kept.
"""

from __future__ import annotations

import math

import torch

from priortrack.errors import PriortrackError
from priortrack.filters.particle import ParticleFilter
from priortrack.filters.tempering import annealing_exponent
from priortrack.models.tracking import TrackingModel
from priortrack.priors.global_motion import GlobalMotion

class AnnealedParticleFilter(ParticleFilter):
    """A particle filter whose update is L annealing layers (see the module docstring).

    Args:
        model: a :class:`TrackingModel` (the diffusion needs its prior's state space).
        particles: P.
        layers: L ≥ 1 annealing layers per frame.
        survival: the target survival rate α in (0, 1) of every layer.
        resampling: the resampling scheme between layers and at the end of a frame.
        dtype: the particles' dtype (as :class:`ParticleFilter`).
        translation: "sampled" or "marginalised" (as :class:`ParticleFilter`). Marginalised, every
            layer weighs by the predictive likelihood with t integrated out (each particle's Kalman
            filter, not committed), diffuses only the pose and the rotation, and the last layer's
            Kalman update is kept.
        seed: seeds the filter's torch.Generator.
        device: where the particles live (as :class:`ParticleFilter`).
    """

    def __init__(self, model: TrackingModel, particles: int = 1000, layers: int = 5, survival: float = 0.5,
                 resampling: str = "systematic", dtype: str = "float64", translation: str = "sampled", seed: int = 0,
                 device: str = "cpu"):
        if not isinstance(model, TrackingModel):
            raise PriortrackError("the annealed particle filter diffuses states in a prior's space: it needs a TrackingModel")
        if layers < 1:
            raise PriortrackError(f"layers must be at least 1, got {layers}")
        if not 0.0 < survival < 1.0:
            raise PriortrackError(f"survival must be in (0, 1), got {survival}")
        super().__init__(model, particles, resampling, ess_threshold=1.0, dtype=dtype, translation=translation,
                         seed=seed, device=device)
        self.layers, self.survival = int(layers), float(survival)
        self.betas: list[float] = []

    def update(self, z: torch.Tensor, flags: list[str]) -> torch.Tensor:
        """The annealing layers on the predicted particles; ``betas`` keeps this frame's β_l."""
        self.betas = []
        beta = 0.0
        std_x, std_g = self.transition_std(self.states)
        if self.marginal:
            std_g = torch.cat([torch.zeros_like(std_g[:3]), std_g[3:]])           # t is integrated, not diffused
        for layer in range(1, self.layers + 1):
            joints = self.model.observe(self.states)
            log_lik, pending = self.weigh(joints, z)
            finite = torch.isfinite(log_lik)
            if not finite.any():
                self.log_weights = self.normalised(torch.full_like(log_lik, -math.inf), flags)
                self.skip_update()
                return joints
            floor = log_lik[finite].min()
            log_lik = torch.where(finite, log_lik, floor - 1e6)      # impossible particles die first
            beta = annealing_exponent(log_lik - log_lik.max(), self.survival, lower=beta)
            self.betas.append(beta)
            self.log_weights = self.normalised(beta * log_lik, flags)
            if layer < self.layers:
                self.select(self.resample(torch.exp(self.log_weights), self.generator))
                self.states = self.diffuse(self.states, std_x, std_g, self.survival ** layer)
                self.log_weights = torch.full_like(self.log_weights, -math.log(self.P))
        return self.keep_update(pending, joints)           # the last layer's Kalman update, if any

    def transition_std(self, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The prior's one-step spread at states s: per coordinate σ̂ (S,) of the pose (equal within
        a joint group: the spread of prior.sample(x) ⊟ x about its mean) and σ_G (6,) of the placement."""
        x, _, _ = self.model.split(s)
        space = self.model.prior.space
        v = space.boxminus(self.model.prior.sample(x, self.generator), x)
        dims = torch.as_tensor(space.tangent_dims, dtype=s.dtype, device=s.device)
        group_var = space.group_norms_sq(v - v.mean(0)).mean(0) / dims
        std_x = group_var.sqrt()[torch.as_tensor(space.groups, device=s.device)]
        return std_x, self.model.global_motion.sigma.to(s)

    def diffuse(self, s: torch.Tensor, std_x: torch.Tensor, std_g: torch.Tensor, shrink: float) -> torch.Tensor:
        """s (P, S + 12) with the pose ⊞ N(0, shrink σ̂²) and g_t perturbed by N(0, shrink σ_G²)
        (translation added, heading and tilt perturbed: GlobalMotion.perturb), g_{t-1} kept."""
        x, g, g_prev = self.model.split(s)
        space = self.model.prior.space
        scale = shrink ** 0.5
        x = space.boxplus(x, space.tangent_noise(x, scale * std_x, self.generator))
        return torch.cat([x, GlobalMotion.perturb(g, scale * std_g, self.generator), g_prev], -1)

    def smooth_window(self, *_args, **_options):
        """Refused: the tempered weights p(z | s)^β of a stochastic search are not a posterior to smooth."""
        raise PriortrackError("the annealed particle filter's weights are tempered (p(z | s)^β), not a posterior: it has "
                              "no smoother; smooth the particle filter or the unscented filter")
