"""Metropolis-adjusted Langevin moves (MALA) on a manifold, preconditioned: the resample-move step of a particle
filter that follows the gradient of its target instead of a blind random walk.

A Metropolis–Hastings move that leaves a density π(s) invariant (Roberts & Tweedie, Bernoulli 2, 1996; with a
preconditioner M, Girolami & Calderhead, JRSS B 73, 2011, §4 with a constant metric). In the tangent coordinates
at the particle s (a chart of the state's manifold: s ⊞ v, s' ⊟ s),

    g(s) = ∇_δ log π(s ⊞ δ) |_{δ=0}                                   (autograd, f coordinates)
    v    = ½ τ² M g(s) + τ L ξ,   ξ ~ N(0, I_f),  M = L Lᵀ,   s' = s ⊞ v
    log q(s' | s) = −|L⁻¹ (v − ½ τ² M g(s))|² / (2 τ²)                  (+ a constant that cancels)
    log q(s | s') = the same with v' = s ⊟ s' and g(s')
    keep s' if  log u < log π(s') − log π(s) + log q(s | s') − log q(s' | s),   u ~ U(0, 1).

The reverse step v' is taken in the chart at s' and the two charts' volumes are not compared: on the spheres
of bone directions they differ by the exponential map's Jacobian, 1 − θ²/6 per bone (1e−5 for a move of
θ = 0.01 rad), as in the guided proposal's density (:mod:`priortrack.filters.proposal`). On a Euclidean state
(⊞ = +) the moves are exact MALA: a test draws a Gaussian target through them and keeps its moments
(tests/test_langevin.py).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

#: The acceptance rates between which τ is kept (MALA's optimal rate is 0.574: Roberts & Rosenthal, JRSS B 60,
#: 1998); outside them τ is multiplied or divided by :data:`ADAPT` for the next frame (:func:`adapted`).
ACCEPTANCE = (0.4, 0.8)
ADAPT = 1.5

Target = Callable[[torch.Tensor], tuple[torch.Tensor, tuple | None]]


def _with_gradient(target: Target, retract: Callable, s: torch.Tensor, f: int):
    """log π(s) (P,) in float64, its gradient in the chart at s (P, f) and the target's companion tensors."""
    delta = torch.zeros((len(s), f), dtype=torch.float64, device=s.device, requires_grad=True)
    with torch.enable_grad():
        log_pi, aux = target(retract(s, delta))
        log_pi = log_pi.to(torch.float64)
        finite = torch.isfinite(log_pi)
        (gradient,) = torch.autograd.grad(torch.where(finite, log_pi, 0.0).sum(), delta)
    aux = None if aux is None else tuple(a.detach() for a in aux)
    return log_pi.detach(), torch.nan_to_num(gradient, nan=0.0, posinf=0.0, neginf=0.0), aux


def langevin_moves(target: Target, retract: Callable, local: Callable, s: torch.Tensor, M: torch.Tensor,
                   step: float, moves: int, generator: torch.Generator) -> tuple[torch.Tensor, tuple | None, float]:
    """``moves`` MALA moves of every particle (module docstring).

    Args:
        target: states (P, A) → log π (P,) and companion tensors (P, …) to keep with each particle's accepted
            state (the marginalised translation's Kalman update), or None.
        retract: (s (P, A), v (P, f) float64) → s ⊞ v (P, A), differentiable in v.
        local: (s' (P, A), s (P, A)) → s' ⊟ s (P, f), in the chart at s.
        s: (P, A) the particles.
        M: (f, f) the preconditioner (positive definite; the target's covariance, roughly).
        step: τ.
        moves: K ≥ 1.
        generator: the filter's random numbers.

    Returns:
        the moved particles (P, A), their companion tensors, and the acceptance rate.
    """
    f64 = torch.float64
    f = len(M)
    M = M.to(device=s.device, dtype=f64)
    L = torch.linalg.cholesky(0.5 * (M + M.T))
    log_pi, gradient, aux = _with_gradient(target, retract, s, f)
    accepted = 0
    half = 0.5 * step ** 2

    def log_q(v: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        white = torch.linalg.solve_triangular(L, (v - half * g @ M).T, upper=False).T
        return -0.5 * (white * white).sum(-1) / step ** 2

    for _ in range(moves):
        xi = torch.randn((len(s), f), generator=generator, device=s.device, dtype=f64)
        v = half * gradient @ M + step * xi @ L.T
        proposal = retract(s, v).detach()
        log_pi_new, gradient_new, aux_new = _with_gradient(target, retract, proposal, f)
        back = local(s, proposal).to(f64)
        log_ratio = log_pi_new - log_pi + log_q(back, gradient_new) - log_q(v, gradient)
        u = torch.rand(len(s), generator=generator, dtype=f64, device=s.device)
        keep = torch.log(u) < log_ratio                                                  # NaN: rejected
        s = torch.where(keep[:, None], proposal, s)
        log_pi = torch.where(keep, log_pi_new, log_pi)
        gradient = torch.where(keep[:, None], gradient_new, gradient)
        aux = kept(keep, aux_new, aux)
        accepted += int(keep.sum())
    return s, aux, accepted / (moves * len(s))


def kept(keep: torch.Tensor, new: tuple | None, old: tuple | None) -> tuple | None:
    """Per row, the accepted (``keep`` (P,) True) state's companion tensors (each (P, …)): ``new``'s, else ``old``'s
    (None: none). Shared with the random-walk move (:meth:`~priortrack.filters.particle.ParticleFilter.move`)."""
    if old is None:
        return None
    return tuple(torch.where(keep.reshape((-1,) + (1,) * (n.dim() - 1)), n, o) for n, o in zip(new, old))


def adapted(step: float, rate: float, band: tuple[float, float] = ACCEPTANCE) -> float:
    """A move's step for the next frame: × :data:`ADAPT` above the acceptance ``band``, ÷ below it, else kept (the
    Langevin moves' τ; the random walk's scale with its own band)."""
    low, high = band
    return step * ADAPT if rate > high else step / ADAPT if rate < low else step
