"""The Gaussian smoother of a particle filter's run: the unscented RTS smoother over its moment-matched clouds.

Backward simulation (:mod:`~priortrack.filters.backward_simulation`) draws whole trajectories through the
stored particles with weights w_t^i p(s_{t+1} | s_t^i). Where the transition is narrow next to the cloud (a
learned prior under several sharp cameras) every trajectory keeps its genealogy's ancestor, the 100 of them
pass through one particle a frame, and the smoothed joints are one particle's where the filter averaged the
cloud: on four cameras worse than the filter in 8 of 15 runs (issue 45). Here each frame's weighted cloud
{s_t^i, w_t^i} is summarised by its first two moments in the unscented form's tangent coordinates
(:class:`~priortrack.filters.ukf.UnscentedTracking`),

    m_t = the weighted mean state (the form's ``sigma_mean``: the pose on the prior's manifold, the placements'
          translations averaged and rotations by their mean),
    P_t = Σ_i w_t^i (s_t^i ⊟ m_t)(s_t^i ⊟ m_t)ᵀ  (+ Σ_i w_t^i C_t^i on the translations (t_t, t_{t−1}) where the
          filter integrates them out, C_t^i a particle's Kalman covariance: the law of total covariance),

and (m_t, P_t) are smoothed by the unscented RTS smoother (:func:`~priortrack.filters.unscented_rts.unscented_rts`)
under the prior's Gaussian transition, its mean step and moment-matched covariance Q(m) (what the unscented
filters run). It keeps of a cloud its mean and covariance only: where the filtering distribution has two modes
(one camera, a limb's two depth branches) it smooths their mean, and backward simulation, which keeps them,
remains (``method="backward"``). On a linear-Gaussian model with the Kalman filter's Gaussians as clouds it is
the Kalman RTS smoother.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from priortrack.filters.ukf import ManifoldSigmaPoints, repaired_covariance
from priortrack.filters.unscented_rts import unscented_rts
from priortrack.models.tracking import GLOBAL_DIM


def cloud_gaussian(form, particles: torch.Tensor, weights: torch.Tensor,
                   translation_covariance: torch.Tensor | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(m (A,), P (n, n)) of a weighted cloud: particles (N, A), weights (N,) (any positive scale), and, where the
    translation is integrated out, each particle's Kalman covariance (N, 6, 6) of (t_t, t_{t−1}) (module
    docstring), in float64; P is repaired to positive definite (:func:`~priortrack.filters.ukf.repaired_covariance`:
    a cloud of fewer distinct particles than dimensions has a singular one). On the CPU, wherever the particles live
    (the unscented RTS that follows runs there, as the unscented filter does)."""
    s = particles.detach().cpu().to(torch.float64)
    w = weights.detach().cpu().to(torch.float64)
    w = w / w.sum()
    m = form.sigma_mean(s, w)
    r = form.boxminus(s, m)
    P = (r.T * w) @ r
    if translation_covariance is not None:
        n_x = form.tangent_dim - 2 * GLOBAL_DIM
        rows = torch.tensor([*range(n_x, n_x + 3), *range(n_x + GLOBAL_DIM, n_x + GLOBAL_DIM + 3)])
        C = translation_covariance.detach().cpu().to(torch.float64)
        P[rows[:, None], rows[None]] += torch.einsum("p,pij->ij", w, C)
    return m.numpy(), repaired_covariance(P.numpy())[0]


def cloud_rts(form, points: ManifoldSigmaPoints, particles: Sequence[torch.Tensor], weights: Sequence[torch.Tensor],
              translation_covariances: Sequence[torch.Tensor | None], memory: int | None = None):
    """The smoothed means (W, A) and covariances (a :class:`~priortrack.filters.step_store.RecordArray` of (n, n))
    of W frames' clouds (each read once, in order: a spilled run's steps come from disk one at a time), by the
    unscented RTS smoother with sigma points ``points`` (module docstring)."""
    gaussians = [cloud_gaussian(form, s, w, C) for s, w, C in zip(particles, weights, translation_covariances)]
    means, covariances = zip(*gaussians)
    return unscented_rts(form, points, list(means), list(covariances), memory)
