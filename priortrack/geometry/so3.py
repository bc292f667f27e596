"""Rotations as rotation vectors: exp and log maps of SO(3), batched in torch, and the same
maps to and from unit quaternions, which compose a batch of rotations more cheaply than matrices.

exp(ω) = I + sin θ [u]× + (1 − cos θ) [u]×²,  θ = |ω|, u = ω/θ   (Rodrigues);
log(R) = θ u with cos θ = (tr R − 1)/2, taken from the skew part for θ < π/2 and from the
symmetric part R + Rᵀ = 2 cos θ I + 2 (1 − cos θ) u uᵀ near θ = π, so both ends are accurate.
Both are written entry by entry over the batch (no 3 × 3 products).
"""

from __future__ import annotations

import math

import torch

from priortrack.errors import PriortrackError


def _check(x: torch.Tensor, shape: tuple[int, ...], name: str) -> None:
    if x.shape[-len(shape):] != shape:
        raise PriortrackError(f"{name} has shape {tuple(x.shape)}; expected (..., {', '.join(map(str, shape))})")


def exp(w: torch.Tensor) -> torch.Tensor:
    """Rotation vectors (..., 3) → rotation matrices (..., 3, 3).

    Written out entry by entry, I + a [w]× + b [w]×² with [w]×² = w wᵀ − θ² I,
    a = sin θ / θ and b = (1 − cos θ) / θ² (their Taylor series below θ = 10⁻⁴), so that
    every operation runs over the batch rather than over 3 × 3 blocks.
    """
    _check(w, (3,), "rotation vector")
    x, y, z = w.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    theta_sq = xx + yy + zz
    small = theta_sq < 1e-8
    safe = torch.where(small, torch.ones_like(theta_sq), theta_sq).sqrt()
    a = torch.where(small, 1 - theta_sq / 6, torch.sin(safe) / safe)              # sin θ / θ
    b = torch.where(small, 0.5 - theta_sq / 24, (1 - torch.cos(safe)) / safe ** 2)  # (1 − cos θ) / θ²
    ax, ay, az = a * x, a * y, a * z
    bxy, bxz, byz = b * x * y, b * x * z, b * y * z
    return torch.stack([1 - b * (yy + zz), bxy - az, bxz + ay,
                        bxy + az, 1 - b * (xx + zz), byz - ax,
                        bxz - ay, byz + ax, 1 - b * (xx + yy)], -1).unflatten(-1, (3, 3))


def log(R: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) → rotation vectors (..., 3) with |ω| ∈ [0, π]."""
    _check(R, (3, 3), "rotation matrix")
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R.flatten(-2).unbind(-1)
    skew = 0.5 * torch.stack([R21 - R12, R02 - R20, R10 - R01], -1)                # sin θ · u
    cos = ((R00 + R11 + R22 - 1) / 2).clamp(-1, 1)
    sin = skew.norm(dim=-1)
    theta = torch.atan2(sin, cos)
    # Small and moderate angles: ω = θ / sin θ · (sin θ u).
    scale = torch.where(sin < 1e-12, torch.ones_like(theta), theta / sin.clamp_min(1e-300))
    scale = torch.where(theta < 1e-6, 1 + theta ** 2 / 6, scale)
    # Near π: u uᵀ = S = (R + Rᵀ − 2 cos θ I) / (2 (1 − cos θ)); take the column of S with the
    # largest diagonal entry, its sign from the skew part.
    inv = 1 / (1 - cos).clamp_min(1e-300)
    S00, S11, S22 = (R00 - cos) * inv, (R11 - cos) * inv, (R22 - cos) * inv
    S01, S02, S12 = (R01 + R10) / 2 * inv, (R02 + R20) / 2 * inv, (R12 + R21) / 2 * inv
    column = torch.stack([S00, S11, S22], -1).argmax(-1)[..., None]
    u = torch.where(column == 0, torch.stack([S00, S01, S02], -1),
                    torch.where(column == 1, torch.stack([S01, S11, S12], -1), torch.stack([S02, S12, S22], -1)))
    u = u / u.norm(dim=-1, keepdim=True).clamp_min(1e-300)
    u = torch.where((u * skew).sum(-1, keepdim=True) < 0, -u, u)
    return torch.where((cos < 0)[..., None], theta[..., None] * u, scale[..., None] * skew)


def quaternion(w: torch.Tensor) -> torch.Tensor:
    """Rotation vectors (..., 3) → unit quaternions (..., 4), q = (cos θ/2, sin(θ/2) ω/θ), θ = |ω|.

    q and −q are the same rotation; this one has a non-negative real part. The ratio
    sin(θ/2)/θ is its Taylor series 1/2 − θ²/48 below θ = 10⁻⁴.
    """
    _check(w, (3,), "rotation vector")
    x, y, z = w.unbind(-1)
    theta_sq = x * x + y * y + z * z
    small = theta_sq < 1e-8
    half = 0.5 * torch.where(small, torch.ones_like(theta_sq), theta_sq).sqrt()
    s = torch.where(small, 0.5 - theta_sq / 48, torch.sin(half) / (2 * half))     # sin(θ/2) / θ
    c = torch.where(small, 1 - theta_sq / 8, torch.cos(half))
    return torch.stack([c, s * x, s * y, s * z], -1)


def quaternion_log(q: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (..., 4) → rotation vectors (..., 3) with |ω| ∈ [0, π]:
    ω = 2 atan2(|v|, |w|) / |v| · sign(w) v for q = (w, v) (2 / |w| · sign(w) v as |v| → 0)."""
    _check(q, (4,), "quaternion")
    w, x, y, z = q.unbind(-1)
    sign = torch.where(w < 0, -1.0, 1.0).to(q.dtype)
    w = w * sign
    n_sq = x * x + y * y + z * z
    small = n_sq < 1e-16
    n = torch.where(small, torch.ones_like(n_sq), n_sq).sqrt()
    f = torch.where(small, 2 / w, 2 * torch.atan2(n, w) / n) * sign
    return torch.stack([f * x, f * y, f * z], -1)


#: The Hamilton product as a bilinear form: (q r)_k = Σ_ij q_i r_j _HAMILTON[i, j, k].
_HAMILTON = torch.zeros(4, 4, 4, dtype=torch.float64)
for _i, _j, _k, _sign in [(0, 0, 0, 1), (1, 1, 0, -1), (2, 2, 0, -1), (3, 3, 0, -1),
                          (0, 1, 1, 1), (1, 0, 1, 1), (2, 3, 1, 1), (3, 2, 1, -1),
                          (0, 2, 2, 1), (1, 3, 2, -1), (2, 0, 2, 1), (3, 1, 2, 1),
                          (0, 3, 3, 1), (1, 2, 3, 1), (2, 1, 3, -1), (3, 0, 3, 1)]:
    _HAMILTON[_i, _j, _k] = _sign


def quaternion_product(q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """The Hamilton product q r (..., 4), the rotation of q after that of r:

        q r = (a e − b f − c g − d h,  a f + b e + c h − d g,  a g − b h + c e + d f,  a h + b g − c f + d e)

    for q = (a, b, c, d), r = (e, f, g, h), as (q M)·r with M = _HAMILTON (4, 16): two batched
    products instead of some thirty elementwise operations."""
    _check(q, (4,), "quaternion")
    _check(r, (4,), "quaternion")
    q, r = torch.broadcast_tensors(q, r)
    M = _HAMILTON.to(dtype=q.dtype, device=q.device).reshape(4, 16)
    left = (q.reshape(-1, 4) @ M).view(-1, 4, 4)                                  # Σ_i q_i M[i, j, k]
    return torch.bmm(r.reshape(-1, 1, 4), left).view(q.shape)


def quaternion_conjugate(q: torch.Tensor) -> torch.Tensor:
    """q* = (w, −v) (..., 4), the inverse rotation of a unit quaternion."""
    return torch.cat([q[..., :1], -q[..., 1:]], -1)


def heading_tilt(q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit quaternions (..., 4) → heading ψ (...,) and tilt τ = (τ_x, τ_z) (..., 2), the swing–twist
    split of R about the world vertical y:

        R = exp(ψ e_y) · exp(τ_x e_x + τ_z e_z),

    the tilt (a rotation about a horizontal axis of the heading frame) applied first, then the
    heading. With q = (w, x, y, z) and n = √(w² + y²): the twist is (w, 0, y, 0)/n, so
    ψ = 2 atan2(y, w), and the swing q_ψ* q = (n, (w x − y z)/n, 0, (w z + x y)/n), whose
    logarithm is τ. ψ is defined up to 2π (q and −q give ψ and ψ ± 2π, the same rotation);
    the split is singular only where the body's y axis points straight down (n = 0).
    """
    _check(q, (4,), "quaternion")
    w, x, y, z = q.unbind(-1)
    n = torch.clamp((w * w + y * y).sqrt(), min=torch.finfo(q.dtype).tiny ** 0.5)
    swing = torch.stack([n, (w * x - y * z) / n, torch.zeros_like(n), (w * z + x * y) / n], -1)
    tau = quaternion_log(swing)
    return 2 * torch.atan2(y, w), tau[..., 0::2]


def from_heading_tilt(psi: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
    """Heading ψ (...,) and tilt τ (..., 2) → the unit quaternion of exp(ψ e_y) exp(τ_x e_x + τ_z e_z)
    (..., 4), the inverse of :func:`heading_tilt`: with (c, a) = (cos ψ/2, sin ψ/2) and the tilt's
    quaternion (d, e, 0, f), the product is (c d, c e + a f, a d, c f − a e)."""
    if tau.shape[-1:] != (2,) or psi.shape != tau.shape[:-1]:
        raise PriortrackError(f"heading {tuple(psi.shape)} and tilt {tuple(tau.shape)}: expected (...,) and (..., 2)")
    d, e, _, f = quaternion(torch.stack([tau[..., 0], torch.zeros_like(psi), tau[..., 1]], -1)).unbind(-1)
    c, a = torch.cos(psi / 2), torch.sin(psi / 2)
    return torch.stack([c * d, c * e + a * f, a * d, c * f - a * e], -1)


def wrap_angle(angle: torch.Tensor) -> torch.Tensor:
    """Angles (...) → the same angles in [−π, π)."""
    return torch.remainder(angle + math.pi, 2 * math.pi) - math.pi


def left_jacobian(w: torch.Tensor) -> torch.Tensor:
    """SO(3)'s left Jacobian J_l(ω) (..., 3, 3) at rotation vectors ω (..., 3), so that
    exp(ω + δ) = exp(J_l(ω) δ) exp(ω) to first order in δ:

        J_l(ω) = I + (1 − cos θ)/θ² [ω]× + (θ − sin θ)/θ³ [ω]×²,   θ = |ω|

    (the coefficients' Taylor series 1/2 − θ²/24 and 1/6 − θ²/120 below θ = 10⁻⁴)."""
    _check(w, (3,), "rotation vector")
    theta_sq = (w * w).sum(-1)
    small = theta_sq < 1e-8
    safe = torch.where(small, torch.ones_like(theta_sq), theta_sq).sqrt()
    b = torch.where(small, 0.5 - theta_sq / 24, (1 - torch.cos(safe)) / safe ** 2)
    c = torch.where(small, 1 / 6 - theta_sq / 120, (safe - torch.sin(safe)) / safe ** 3)
    x, y, z = w.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(w.shape + (3,))
    eye = torch.eye(3, dtype=w.dtype, device=w.device)
    return eye + b[..., None, None] * K + c[..., None, None] * (K @ K)
