"""Rotations as rotation vectors: exp and log maps of SO(3), batched in torch.

exp(ω) = I + sin θ [u]× + (1 − cos θ) [u]×²,  θ = |ω|, u = ω/θ   (Rodrigues);
log(R) = θ u with cos θ = (tr R − 1)/2, taken from the skew part for θ < π/2 and from the
symmetric part R + Rᵀ = 2 cos θ I + 2 (1 − cos θ) u uᵀ near θ = π, so both ends are accurate.
"""

from __future__ import annotations

import torch

from priortrack.errors import PriortrackError


def _check(x: torch.Tensor, shape: tuple[int, ...], name: str) -> None:
    if x.shape[-len(shape):] != shape:
        raise PriortrackError(f"{name} has shape {tuple(x.shape)}; expected (..., {', '.join(map(str, shape))})")


def hat(w: torch.Tensor) -> torch.Tensor:
    """(..., 3) → (..., 3, 3) the skew matrix [w]× with [w]× v = w × v."""
    zero = torch.zeros_like(w[..., 0])
    return torch.stack([
        torch.stack([zero, -w[..., 2], w[..., 1]], -1),
        torch.stack([w[..., 2], zero, -w[..., 0]], -1),
        torch.stack([-w[..., 1], w[..., 0], zero], -1),
    ], -2)


def exp(w: torch.Tensor) -> torch.Tensor:
    """Rotation vectors (..., 3) → rotation matrices (..., 3, 3)."""
    _check(w, (3,), "rotation vector")
    theta_sq = (w * w).sum(-1, keepdim=True)[..., None]
    theta = theta_sq.sqrt()
    small = theta_sq < 1e-8
    safe = torch.where(small, torch.ones_like(theta), theta)
    a = torch.where(small, 1 - theta_sq / 6, torch.sin(safe) / safe)              # sin θ / θ
    b = torch.where(small, 0.5 - theta_sq / 24, (1 - torch.cos(safe)) / safe ** 2)  # (1 − cos θ) / θ²
    K = hat(w)
    return torch.eye(3, dtype=w.dtype, device=w.device) + a * K + b * (K @ K)


def log(R: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) → rotation vectors (..., 3) with |ω| ∈ [0, π]."""
    _check(R, (3, 3), "rotation matrix")
    skew = 0.5 * torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                              R[..., 1, 0] - R[..., 0, 1]], -1)                  # sin θ · u
    cos = ((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)
    sin = skew.norm(dim=-1)
    theta = torch.atan2(sin, cos)
    # Small and moderate angles: ω = θ / sin θ · (sin θ u).
    scale = torch.where(sin < 1e-12, torch.ones_like(theta), theta / sin.clamp_min(1e-300))
    scale = torch.where(theta < 1e-6, 1 + theta ** 2 / 6, scale)
    near_pi = cos < 0
    # Near π: u uᵀ = (R + Rᵀ − 2 cos θ I) / (2 (1 − cos θ)); take the largest column, sign from skew.
    S = (R + R.transpose(-1, -2)) / 2 - cos[..., None, None] * torch.eye(3, dtype=R.dtype, device=R.device)
    S = S / (1 - cos).clamp_min(1e-300)[..., None, None]
    column = S.diagonal(dim1=-2, dim2=-1).argmax(-1)
    u = torch.take_along_dim(S, column[..., None, None].expand(*column.shape, 3, 1), dim=-1)[..., 0]
    u = u / u.norm(dim=-1, keepdim=True).clamp_min(1e-300)
    u = torch.where((u * skew).sum(-1, keepdim=True) < 0, -u, u)
    return torch.where(near_pi[..., None], theta[..., None] * u, scale[..., None] * skew)
