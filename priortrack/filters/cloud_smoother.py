"""The Gaussian smoother of a particle filter's run: the RTS recursion with each frame's moments from its cloud.

Backward simulation (:mod:`~priortrack.filters.backward_simulation`) draws whole trajectories through the
stored particles with weights w_t^i p(s_{t+1} | s_t^i). Where the transition is narrow next to the cloud (a
learned prior under several sharp cameras) every trajectory keeps its genealogy's ancestor, the 100 of them
pass through one particle a frame, and the smoothed joints are one particle's where the filter averaged the
cloud: on four cameras worse than the filter in 8 of 15 runs (issue 45). Here each frame's weighted cloud
{s_i, w_i} gives the moments that the RTS recursion (:func:`~priortrack.filters.unscented_rts.rts_backwards`)
needs, in the unscented form's tangent coordinates (:class:`~priortrack.filters.ukf.UnscentedTracking`), its
particles carried through the prior's mean step f (an ensemble RTS smoother: Raanes, QJRMS 142, 2016):

    m_t = the weighted mean state (the filter's estimate's, ``mean``),   r_i = s_i ⊟ m_t,
    P_t = Σ_i w_i r_i r_iᵀ + C̄,
    f_i = f(s_i),   m⁻ = their weighted mean,   r⁻_i = f_i ⊟ m⁻,
    P⁻ = Σ_i w_i r⁻_i r⁻_iᵀ + J C̄ Jᵀ + Q(m_t),   D = Σ_i w_i r_i r⁻_iᵀ + C̄ Jᵀ,

where the filter integrates the translation out, C̄ = Σ_i w_i C_i its particles' Kalman covariances of
(t_t, t_{t−1}) in the translation coordinates (the law of total covariance; 0 otherwise) and J the mean step's
Jacobian in those coordinates (the translation's step is linear: central differences are exact to rounding);
Q(m) is the prior's moment-matched transition covariance, as the unscented filters run. No sigma points: with
the smoother's small α their signed mean (W₀ ≈ −100) diverged on clouds spread through a blackout (steps of
0.7–5 rad after 100 iterations; a pf-lie run smoothed 1.48× its filter's error).

It keeps of a cloud its mean and covariance only: where the filtering distribution has two modes (one camera, a
limb's two depth branches) it smooths their mean, and backward simulation, which keeps them, remains
(``method="backward"``). On a linear-Gaussian model whose clouds have the Kalman filter's moments it is the
Kalman RTS smoother.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from priortrack.filters.step_store import RecordArray
from priortrack.filters.ukf import repaired_covariance
from priortrack.filters.unscented_rts import rts_backwards
from priortrack.models.tracking import GLOBAL_DIM

#: The central difference's step (metres) of the mean step's Jacobian in the translation coordinates.
TRANSLATION_STEP = 1e-3


def _translation_coordinates(form) -> torch.Tensor:
    """(6,) the tangent coordinates of the translations t_t and t_{t−1} (the placements' first three each)."""
    n_x = form.tangent_dim - 2 * GLOBAL_DIM
    return torch.tensor([*range(n_x, n_x + 3), *range(n_x + GLOBAL_DIM, n_x + GLOBAL_DIM + 3)])


class _Cloud:
    """One frame's cloud on the CPU in float64 (wherever the particles live: the recursion runs there, as the
    unscented filter does): the states s (N, A), normalised weights w (N,), the mean m (A,), the residuals
    r = s ⊟ m (N, n) and C̄ (6, 6) (None where the translation is drawn)."""

    def __init__(self, form, particles: torch.Tensor, weights: torch.Tensor, translation_covariance, mean):
        self.s = particles.detach().cpu().to(torch.float64)
        w = weights.detach().cpu().to(torch.float64)
        self.w = w / w.sum()
        #: The weighted mean of states (N, A) under these weights: ``mean``, else the form's ``sigma_mean``.
        self.average = form.sigma_mean if mean is None else mean
        self.m = self.average(self.s, self.w)
        self.r = form.boxminus(self.s, self.m)
        self.C = (None if translation_covariance is None else
                  torch.einsum("p,pij->ij", self.w, translation_covariance.detach().cpu().to(torch.float64)))

    def covariance(self, form) -> torch.Tensor:
        """P (n, n) = Σ_i w_i r_i r_iᵀ + C̄ (unrepaired)."""
        P = (self.r.T * self.w) @ self.r
        if self.C is not None:
            rows = _translation_coordinates(form)
            P[rows[:, None], rows[None]] += self.C
        return P


def cloud_gaussian(form, particles: torch.Tensor, weights: torch.Tensor,
                   translation_covariance: torch.Tensor | None = None, mean=None) -> tuple[np.ndarray, np.ndarray]:
    """(m_t (A,), P_t (n, n)) of a weighted cloud (module docstring): particles (N, A), weights (N,) (any positive
    scale), where the translation is integrated out each particle's Kalman covariance (N, 6, 6) of (t_t, t_{t−1});
    m_t = ``mean``(particles, weights) (a TrackingModel's ``mean``; None: the form's ``sigma_mean``). P is repaired
    to positive definite (:func:`~priortrack.filters.ukf.repaired_covariance`: a cloud of fewer distinct particles
    than dimensions has a singular one)."""
    cloud = _Cloud(form, particles, weights, translation_covariance, mean)
    return cloud.m.numpy(), repaired_covariance(cloud.covariance(form).numpy())[0]


def _prediction(form, cloud: _Cloud):
    """(m_t, P_t, m⁻, P⁻, D) of the module docstring for one frame's cloud."""
    f = form.mean_step(cloud.s)
    m_pred = cloud.average(f, cloud.w)
    r_next = form.boxminus(f, m_pred)
    P = cloud.covariance(form)
    P_pred = (r_next.T * cloud.w) @ r_next + form.process_covariance(cloud.m)
    D = (cloud.r.T * cloud.w) @ r_next
    if cloud.C is not None:
        rows = _translation_coordinates(form)
        steps = torch.zeros((12, form.tangent_dim), dtype=torch.float64)
        steps[torch.arange(6), rows] = TRANSLATION_STEP
        steps[torch.arange(6, 12), rows] = -TRANSLATION_STEP
        moved = form.boxminus(form.mean_step(form.boxplus(cloud.m.expand(12, -1), steps)), m_pred)
        J = ((moved[:6] - moved[6:]) / (2 * TRANSLATION_STEP)).T                     # (n, 6)
        P_pred = P_pred + J @ cloud.C @ J.T
        D[rows] += cloud.C @ J.T
    return (cloud.m.numpy(), repaired_covariance(P.numpy())[0], m_pred, P_pred.numpy(), D.numpy())


def cloud_rts(form, particles: Sequence[torch.Tensor], weights: Sequence[torch.Tensor],
              translation_covariances: Sequence[torch.Tensor | None], memory: int | None = None,
              mean=None) -> tuple[list[np.ndarray], RecordArray]:
    """The smoothed means (W, A) and covariances (a :class:`~priortrack.filters.step_store.RecordArray` of (n, n)
    within ``memory`` bytes) of W frames' clouds (module docstring; ``mean`` as :func:`cloud_gaussian`'s), each
    frame read once, from the last (a spilled run's steps come from disk one at a time)."""
    def prediction(k: int):
        return _prediction(form, _Cloud(form, particles[k], weights[k], translation_covariances[k], mean))

    T = len(particles)
    last = cloud_gaussian(form, particles[T - 1], weights[T - 1], translation_covariances[T - 1], mean)
    return rts_backwards(form, T, last, prediction, memory)
