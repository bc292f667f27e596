"""The unscented Rauch–Tung–Striebel smoother (Särkkä, IEEE TAC 53(3), 2008) on the unscented
filter's manifold states: the best Gaussian estimate of each frame given every frame.

Input: the filter's posteriors (m_k, P_k), k = 0 … T − 1, P_k in the tangent coordinates at m_k
(:class:`~priortrack.filters.snapshot.Snapshot`'s ``mean`` and ``covariance``). Backwards from
(m^s_{T−1}, P^s_{T−1}) = (m_{T−1}, P_{T−1}), with the filter's own sigma points χ_i = m_k ⊞ ξ_i,
the mean step f and the process noise Q(m_k) (its prediction, repeated):

    m⁻ = mean of f(χ_i),   P⁻ = Σ_i Wc_i (f(χ_i) ⊟ m⁻)(f(χ_i) ⊟ m⁻)ᵀ + Q(m_k),
    D  = Σ_i Wc_i (χ_i ⊟ m_k)(f(χ_i) ⊟ m⁻)ᵀ,        G = D (P⁻)⁻¹,
    m^s_k = m_k ⊞ G (m^s_{k+1} ⊟ m⁻),
    P^s_k = Γ_k (P_k + G (Γ' P^s_{k+1} Γ'ᵀ − P⁻) Gᵀ) Γ_kᵀ,

with Γ' the change of tangent coordinates from m^s_{k+1} to m⁻ and Γ_k from m_k to m^s_k (the
identity in a Euclidean space; on the spheres the parallel transport of the bases): every
covariance is combined in one chart, then moved to the point it belongs to. On a linear-Gaussian
model the unscented transform is exact and this is the Kalman RTS smoother.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from priortrack.errors import PriortrackError
from priortrack.filters.step_store import RecordArray
from priortrack.filters.ukf import ManifoldSigmaPoints, repaired_covariance


def unscented_rts(model, points: ManifoldSigmaPoints, means: Sequence[np.ndarray], covariances: Sequence[np.ndarray],
                  memory: int | None = None) -> tuple[list[np.ndarray], RecordArray]:
    """The smoothed (m^s_k (A,), P^s_k (n, n)) of the filtered ``means`` and ``covariances`` (module
    docstring), for a model in the unscented filter's form (``UNSCENTED_INTERFACE``) and its sigma points.
    The inputs are read one frame at a time, from the last (a :class:`~priortrack.filters.step_store.Column`
    of a whole run's spilled steps is not held in memory at once); the smoothed covariances are a
    :class:`~priortrack.filters.step_store.RecordArray` within ``memory`` bytes (None: in memory)."""
    if len(means) != len(covariances) or not len(means):
        raise PriortrackError(f"{len(means)} means and {len(covariances)} covariances: expected as many, at least one")
    Wm, Wc = torch.from_numpy(points.Wm), points.Wc

    def prediction(k: int):
        m, P = means[k], covariances[k]
        chi = torch.from_numpy(points.sigma_points(m, P))
        chi_next = model.mean_step(chi)
        m_pred = model.sigma_mean(chi_next, Wm)
        r_next = model.boxminus(chi_next, m_pred).numpy()
        r = model.boxminus(chi, torch.from_numpy(m)).numpy()
        P_pred = (r_next.T * Wc) @ r_next + model.process_covariance(torch.from_numpy(m)).numpy()
        return m, P, m_pred, P_pred, (r.T * Wc) @ r_next

    return rts_backwards(model, len(means), (means[-1], covariances[-1]), prediction, memory)


def rts_backwards(model, T: int, last: tuple[np.ndarray, np.ndarray], prediction,
                  memory: int | None = None) -> tuple[list[np.ndarray], RecordArray]:
    """The RTS recursion of the module docstring over T frames, from the ``last`` frame's filtered (m (A,), P (n, n)):
    ``prediction(k)``, k < T − 1, gives frame k's filtered (m_k (A,), P_k (n, n)), its prediction (m⁻ (A,) tensor,
    P⁻ (n, n)) and the cross-covariance D (n, n) (however they were computed: sigma points here, a particle cloud in
    :mod:`~priortrack.filters.cloud_smoother`). The smoothed covariances are a
    :class:`~priortrack.filters.step_store.RecordArray` within ``memory`` bytes (None: in memory)."""
    smoothed_means = [None] * T
    m_last, P_last = last
    smoothed_covariances = RecordArray(T, P_last.shape, memory)
    smoothed_means[-1], smoothed_covariances[-1] = m_last, P_last
    for k in range(T - 2, -1, -1):
        m, P, m_pred, P_pred, D = prediction(k)
        m_t = torch.from_numpy(m)
        G = np.linalg.solve(P_pred.T, D.T).T
        m_s_next = torch.from_numpy(smoothed_means[k + 1])
        into_pred = model.transport(m_s_next, m_pred).numpy()
        innovation = model.boxminus(m_s_next[None], m_pred)[0].numpy()
        m_s = model.boxplus(m_t[None], torch.from_numpy(G @ innovation)[None])[0]
        P_s = P + G @ (into_pred @ smoothed_covariances[k + 1] @ into_pred.T - P_pred) @ G.T
        onto = model.transport(m_t, m_s).numpy()
        smoothed_means[k] = m_s.numpy()
        smoothed_covariances[k] = repaired_covariance(onto @ P_s @ onto.T)[0]
    return smoothed_means, smoothed_covariances
