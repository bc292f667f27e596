"""Particle resampling schemes: seeded, in torch, unbiased (E[count_i] = N w_i).

Each takes normalised weights w (N,) and a torch.Generator and returns ancestor indices
(N,) int64, sorted. With W_i = Σ_{j≤i} w_j the cumulative weights, a particle i is chosen
for every point u with W_{i-1} ≤ u < W_i:

- ``systematic``: u_k = (k + U) / N, one U ~ U[0, 1); counts are ⌊N w_i⌋ or ⌈N w_i⌉;
- ``stratified``: u_k = (k + U_k) / N, U_k ~ U[0, 1) independent;
- ``multinomial``: N independent draws from w;
- ``residual``: ⌊N w_i⌋ copies of each particle, then the R = N − Σ⌊N w_i⌋ remaining
  draws multinomial from the residual weights (N w_i − ⌊N w_i⌋) / R.
  (filterpy's residual_resample omits the factor N; this one does not.)
"""

from __future__ import annotations

import torch

from priortrack.errors import PriortrackError


def _check(weights: torch.Tensor) -> torch.Tensor:
    if weights.dim() != 1 or len(weights) == 0:
        raise PriortrackError(f"weights has shape {tuple(weights.shape)}; expected (N,) with N ≥ 1")
    if not torch.isfinite(weights).all() or (weights < 0).any():
        raise PriortrackError("weights must be finite and non-negative")
    total = weights.sum()
    if total <= 0:
        raise PriortrackError("weights sum to zero: nothing to resample from")
    return weights / total


def _invert(weights: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Indices i with W_{i-1} ≤ u < W_i, u (M,) in [0, 1)."""
    cumulative = torch.cumsum(weights, dim=0)
    index = torch.searchsorted(cumulative, u, right=True)
    return index.clamp_(max=len(weights) - 1)


def systematic(weights: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    w = _check(weights)
    n = len(w)
    u = (torch.arange(n, dtype=w.dtype, device=w.device)
         + torch.rand((), generator=generator, dtype=w.dtype, device=w.device)) / n
    return _invert(w, u)


def stratified(weights: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    w = _check(weights)
    n = len(w)
    u = (torch.arange(n, dtype=w.dtype, device=w.device)
         + torch.rand(n, generator=generator, dtype=w.dtype, device=w.device)) / n
    return _invert(w, u)


def multinomial(weights: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    w = _check(weights)
    u = torch.rand(len(w), generator=generator, dtype=w.dtype, device=w.device)
    return _invert(w, u.sort().values)


def residual(weights: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    w = _check(weights)
    n = len(w)
    copies = torch.floor(n * w).long()
    deterministic = torch.repeat_interleave(torch.arange(n, device=w.device), copies)
    remaining = n - int(copies.sum())
    if remaining == 0:
        return deterministic
    residual_weights = n * w - copies.to(w.dtype)
    u = torch.rand(remaining, generator=generator, dtype=w.dtype, device=w.device)
    drawn = _invert(residual_weights / residual_weights.sum(), u)
    return torch.sort(torch.cat([deterministic, drawn])).values


RESAMPLERS = {"systematic": systematic, "stratified": stratified, "multinomial": multinomial, "residual": residual}


def resampler(name: str):
    """The resampling function called ``name`` (a clear error listing the valid ones)."""
    if name not in RESAMPLERS:
        raise PriortrackError(f"unknown resampling scheme {name!r}; schemes: {', '.join(RESAMPLERS)}")
    return RESAMPLERS[name]
