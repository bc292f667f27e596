"""The iterated posterior-linearisation smoother (García-Fernández, Svensson & Särkkä, IEEE TAC
62(4), 2017) on the unscented filter's manifold states.

The unscented RTS smoother (:mod:`priortrack.filters.unscented_rts`) linearises the dynamics f about
the *filtered* Gaussians. Through a long gap in the data these are wide and far from where the
smoothed trajectory ends up, and a nonlinear f (the GPDM's periodic orbit) is then linearised where
the motion is not. Posterior linearisation relinearises f and h about the current *smoothed*
Gaussians N(μ_k, Σ_k) and smooths the linearised model again, ``iterations`` times.

One iteration, in the tangent coordinates δ_k at each μ_k (x_k = μ_k ⊞ δ_k), with the sigma
points χ_i = μ_k ⊞ ξ_i of N(μ_k, Σ_k) (the filter's weights Wm, Wc; Σ_i Wm_i ξ_i = 0):

- statistical linear regression of f (eq. 9–11 of the paper): y_i = f(χ_i) ⊟ μ_{k+1},
  ȳ = Σ Wm_i y_i, Ψ = Σ Wc_i ξ_i (y_i − ȳ)ᵀ, Φ = Σ Wc_i (y_i − ȳ)(y_i − ȳ)ᵀ, A_k = Ψᵀ Σ_k⁻¹,
  b_k = ȳ, Ω_k = Φ − A_k Σ_k A_kᵀ, so δ_{k+1} = A_k δ_k + b_k + q, q ~ N(0, Q(μ_k) + Ω_k);
- the same of h on the pixels the filter updated with (below): z_k = H_k δ_k + ẑ_k + r,
  r ~ N(0, R_k + Λ_k);
- the Kalman filter and RTS smoother of that linear-Gaussian model, started from the filter's own
  first posterior (which holds the first frame's data); then μ_k ← μ_k ⊞ δ^s_k and Σ_k ← Γ P^s_k Γᵀ
  (Γ the change of tangent coordinates from the old μ_k to the new).

The first linearisation is the unscented RTS smoother's output. On a linear-Gaussian model the
regressions are exact (Ω = Λ = 0) and every iteration returns the RTS smoother's estimates.

**The spread of the sigma points.** Both the first pass and the regressions place their sigma points
at α = ``SMOOTHER_ALPHA`` (0.1), not at the filter's α (0.5 in the presets): through a blackout the
heading's variance reaches 2–12 rad², points 1.9 σ out (α = 0.5, n = 15) pass π, the rotation chart
wraps, and the regression of f (and the RTS gain) is then of the wrapped points: walkjog 35_29's
smoothed heading swung by 2.8 rad and its blackout error doubled (122 → 255 mm). With α = 0.1 the
regressions are local (α = 0.001 gives the same figures to 1 mm). α and ``ITERATIONS`` were chosen
on walks outside every accuracy table (walkjog 35_02, 35_05, CMU 07_02, 07_09): α = 0.3 already
wraps on 07_09; a second and third iteration changed the GPDM's errors by under 5 mm and made the
local diffusion UKF's worse.

**The data it smooths are the filter's.** The relinearised filter updates with the pixels the unscented
filter updated with: the filter's exchanges of a detector's left/right swaps made again, the points its
validation gate held out left out (its steps' ``swapped`` and ``held_out``), so the smoother conditions on
the same data as the filter it smooths. Gating again, against the smoothed Gaussian's own predicted pixels,
held out far more: on caliscope's webcams (MediaPipe's errors beyond the presets' 5 px) 10–12 points a frame
against the filter's 1–3, the right arm's in two of the three cameras, and the smoothed right wrist went
150–160 mm from the cameras' triangulation for 8 ticks while the filtered stayed within 40 mm
(``compare --detections`` without cam_0). Gating against the relinearised filter's prediction (H P⁻ Hᵀ + Λ + R)
let in a shoulder the filter had rightly held out (left-out camera 45–64 px against the filtered 29–37).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from priortrack.errors import PriortrackError
from priortrack.filters.step_store import RecordArray
from priortrack.filters.ukf import ManifoldSigmaPoints, exchange, repaired_covariance
from priortrack.filters.unscented_rts import unscented_rts

#: Relinearisations after the unscented RTS smoother's pass, by default.
ITERATIONS = 1
#: Van der Merwe's α of the smoother's sigma points (module docstring).
SMOOTHER_ALPHA = 0.1
#: Frames whose sigma points are propagated in one batch (bounds the smoother's memory on long runs).
FRAMES_AT_ONCE = 256


def _regression(xi: np.ndarray, y: np.ndarray, Sigma: np.ndarray, Wm: np.ndarray, Wc: np.ndarray):
    """Statistical linear regression of y (N, d) on offsets ξ (N, n) with covariance Σ (n, n):
    (A (d, n), b = ȳ (d,), Ω (d, d), Φ (d, d))."""
    y_bar = Wm @ y
    r = y - y_bar
    Psi = (xi.T * Wc) @ r
    Phi = (r.T * Wc) @ r
    A = np.linalg.solve(Sigma, Psi).T
    return A, y_bar, Phi - A @ Sigma @ A.T, Phi


def _observed(model, z: np.ndarray, h: np.ndarray, xi: np.ndarray, Sigma: np.ndarray, Wm, Wc,
              held_out: np.ndarray | None, swapped: np.ndarray | None):
    """The linearised measurement of one frame: (H (k, n), ẑ (k,), R + Λ (k, k), z (k,)) on the pixels
    the filter updated with, or None where there are none: the observed and predictable points, with the
    filter's exchanges of a detector's left/right swaps (``swapped`` (2p,) points, :func:`exchange`) made
    and the points its validation gate held out (``held_out`` (K,) bool) left out; None: none."""
    gated, _ = model.gate(z)
    values, R = model.measurement(torch.as_tensor(gated, dtype=torch.float64))
    values, R = values.numpy(), R.numpy()
    b = model.measurement_block
    if swapped is not None:
        values, R = exchange(values, R, swapped, b)
    usable = np.isfinite(values) & np.isfinite(h).all(axis=0)
    if held_out is not None:
        usable &= ~np.repeat(held_out, b)
    if not usable.any():
        return None
    H, z_hat, Lam, _ = _regression(xi, h[:, usable], Sigma, Wm, Wc)
    return H, z_hat, R[np.ix_(usable, usable)] + Lam, values[usable]


def _sigma_frames(model, points: ManifoldSigmaPoints, mu: list[np.ndarray], Sigma: RecordArray):
    """Per frame k in order: the sigma points' offsets ξ (N, n) of N(μ_k, Σ_k), their images under the
    dynamics f(χ_i) (N, A) and the measurement h(χ_i) (N, m), computed ``FRAMES_AT_ONCE`` frames at a
    time (a whole recording's sigma points at once would not fit: 18,000 frames × 125 points)."""
    for start in range(0, len(mu), FRAMES_AT_ONCE):
        xi = [points.offsets_at(P) for P in Sigma[start:start + FRAMES_AT_ONCE]]          # (2n + 1, n) each
        N = len(xi[0])
        chi = model.boxplus(torch.from_numpy(np.repeat(np.stack(mu[start:start + FRAMES_AT_ONCE]), N, axis=0)),
                            torch.from_numpy(np.concatenate(xi)))
        moved = model.mean_step(chi).split(N)
        h = model.measure(chi).numpy().reshape(len(xi), N, -1)
        yield from zip(xi, moved, h)


def posterior_linearisation(model, points: ManifoldSigmaPoints, means: Sequence[np.ndarray],
                            covariances: Sequence[np.ndarray], data: np.ndarray, iterations: int = ITERATIONS,
                            held_out: Sequence[np.ndarray | None] | None = None,
                            swapped: Sequence[np.ndarray | None] | None = None,
                            memory: int | None = None) -> tuple[list[np.ndarray], RecordArray]:
    """Smoothed (μ_k (A,), Σ_k (n, n)) of the filtered ``means`` and ``covariances`` (module
    docstring) given each frame's ``data`` (T, *observation_shape), for a model in the unscented
    filter's form and its sigma points (the filtered inputs read a frame at a time, as
    :func:`~priortrack.filters.unscented_rts.unscented_rts` reads them). ``iterations`` = 0 is the
    unscented RTS smoother. ``held_out`` (per frame (K,) bool or None) and ``swapped`` (per frame (2p,)
    points or None) are the filter's own validation-gate and swap decisions (its steps' fields): the
    smoother conditions on the pixels the filter updated with (None: every observed pixel). The
    per-frame matrices (the smoothed Σ_k, and an iteration's M_k and G_k) are
    :class:`~priortrack.filters.step_store.RecordArray` s of a third of ``memory`` bytes each (None: in
    memory), so a run's length alone does not exhaust the memory."""
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 0:
        raise PriortrackError(f"iterations must be a whole number ≥ 0, got {iterations!r}")
    if len(data) != len(means):
        raise PriortrackError(f"{len(data)} frames of data for {len(means)} filtered frames")
    share = None if memory is None else memory // 3
    mu, Sigma = unscented_rts(model, points, means, covariances, share)
    Wm, Wc = points.Wm, points.Wc
    T, n = len(mu), len(Sigma[0])
    for _ in range(iterations):
        frames = _sigma_frames(model, points, mu, Sigma)
        previous = next(frames)
        # the filter, in the tangent coordinates at each μ_k
        gamma = model.transport(torch.from_numpy(means[0]), torch.from_numpy(mu[0])).numpy()
        d = model.boxminus(torch.from_numpy(means[0])[None], torch.from_numpy(mu[0]))[0].numpy()
        P = gamma @ covariances[0] @ gamma.T
        # per frame k < T − 1, what the RTS smoother of the linearised model needs of it, kept from the
        # forward pass: G_k = P_k A_kᵀ (P⁻_{k+1})⁻¹, c_k = d_k − G_k d⁻_{k+1}, M_k = P_k − G_k P⁻_{k+1} G_kᵀ
        # (two matrices a frame, not the filtered, predicted and dynamics three)
        c, M, G = [None] * (T - 1), RecordArray(T - 1, (n, n), share), RecordArray(T - 1, (n, n), share)
        for k in range(1, T):
            current = next(frames)
            (xi_prev, moved_prev, _), (xi, _, h) = previous, current
            previous = current
            y = model.boxminus(moved_prev, torch.from_numpy(mu[k])).numpy()
            A, b, Omega, _ = _regression(xi_prev, y, Sigma[k - 1], Wm, Wc)
            Q = model.process_covariance(torch.from_numpy(mu[k - 1])).numpy() + Omega
            d_pred, P_pred = A @ d + b, A @ P @ A.T + Q
            P_pred = (P_pred + P_pred.T) / 2
            gain = np.linalg.solve(P_pred, A @ P).T
            c[k - 1], M[k - 1], G[k - 1] = d - gain @ d_pred, P - gain @ P_pred @ gain.T, gain
            d, P = d_pred, P_pred
            obs = _observed(model, data[k], h, xi, Sigma[k], Wm, Wc, None if held_out is None else held_out[k],
                            None if swapped is None else swapped[k])
            if obs is not None:
                H, z_hat, R, z = obs
                S = H @ P @ H.T + R
                K = np.linalg.solve(S, H @ P).T
                d = d + K @ (z - z_hat - H @ d)
                I_KH = np.eye(n) - K @ H
                P = I_KH @ P @ I_KH.T + K @ R @ K.T
        # the RTS smoother backwards, d^s_k = c_k + G_k d^s_{k+1}, P^s_k = M_k + G_k P^s_{k+1} G_kᵀ, with μ_k
        # and Σ_k replaced in place
        for k in range(T - 1, -1, -1):
            if k < T - 1:
                gain = G[k]
                d, P = c[k] + gain @ d, M[k] + gain @ P @ gain.T
            m_t = torch.from_numpy(mu[k])
            m_new = model.boxplus(m_t[None], torch.from_numpy(d)[None])[0]
            onto = model.transport(m_t, m_new).numpy()
            mu[k], Sigma[k] = m_new.numpy(), repaired_covariance(onto @ P @ onto.T)[0]
        M.close()
        G.close()
    return mu, Sigma
