"""Cholesky factors with a jitter that grows on failure (DESIGN.md: Cholesky solves, never inverses), and the
whitening L⁻¹ of a factor for batches whose right-hand sides are too many for a solve each."""

from __future__ import annotations

import logging

import torch

from priortrack.errors import PriortrackError

log = logging.getLogger(__name__)


def jittered_cholesky(K: torch.Tensor, what: str, start: float, stop: float) -> torch.Tensor:
    """Lower Cholesky factors L (..., n, n), L Lᵀ = K + ε I, of symmetric matrices K (..., n, n).

    ε = 0 first; while a factorisation fails, ε = j · |mean diagonal of K| for j = start, 10 start,
    100 start, … up to ``stop``; past that a PriortrackError names ``what``.
    """
    L, info = torch.linalg.cholesky_ex(K)
    if not bool((info > 0).any()):
        return L
    eye = torch.eye(K.shape[-1], dtype=K.dtype, device=K.device)
    scale = K.diagonal(dim1=-2, dim2=-1).mean().detach().abs().clamp(min=torch.finfo(K.dtype).tiny)
    jitter = start
    while jitter <= stop * (1 + 1e-9):
        L, info = torch.linalg.cholesky_ex(K + (jitter * scale) * eye)
        if not bool((info > 0).any()):
            log.debug("cholesky of %s needed a jitter of %.1e", what, jitter)
            return L
        jitter *= 10
    raise PriortrackError(f"{what} is not positive definite (Cholesky fails even with a jitter of {stop:g} × its "
                          f"mean diagonal)")


def whitening(factor: torch.Tensor) -> torch.Tensor:
    """L⁻¹ (..., n, n) of lower Cholesky factors L (..., n, n), a triangular solve against I: |L⁻¹ d|² = dᵀ Σ⁻¹ d.

    For many residuals d under one factor, d @ L⁻ᵀ is a plain product; a triangular solve with that many
    right-hand sides is not always one (on CUDA, cuBLAS's solve against 10⁶ columns took 40 s where the
    product takes milliseconds)."""
    eye = torch.eye(factor.shape[-1], dtype=factor.dtype, device=factor.device)
    return torch.linalg.solve_triangular(factor, eye.expand_as(factor), upper=False)
