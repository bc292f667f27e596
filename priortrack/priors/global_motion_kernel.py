"""The global motion's draw g_t ~ p(g_t | g_{t-1}, g_{t-2}) as one fused CPU kernel (numba), for
float32 placements.

:meth:`priortrack.priors.global_motion.GlobalMotion.sample` predicts t̂ = 2 t_1 − t_2 and
R̂ = R_1 R_2ᵀ R_1 (as unit quaternions, q̂ = q_1 q_2* q_1), then perturbs: t = t̂ + ε,
q = exp(η) q̂, ω = log q. In torch that is three rotation-vector-to-quaternion conversions,
three batched Hamilton products and a quaternion logarithm over 10⁴ rows (some 3 ms); here each
row is one short loop with the same formulas as :mod:`priortrack.geometry.so3` (their Taylor
branches included), from the same normal variates.

The torch path serves other dtypes and devices and gradients, and is the reference this kernel
is tested against (tests/test_global_motion.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(inline="always")
def _quaternion(x, y, z):
    """so3.quaternion of one rotation vector: (cos θ/2, sin(θ/2) ω/θ)."""
    theta_sq = x * x + y * y + z * z
    if theta_sq < np.float32(1e-8):
        s = np.float32(0.5) - theta_sq / np.float32(48.0)
        c = np.float32(1.0) - theta_sq / np.float32(8.0)
    else:
        half = np.float32(0.5) * math.sqrt(theta_sq)
        s = math.sin(half) / (np.float32(2.0) * half)
        c = math.cos(half)
    return c, s * x, s * y, s * z


@numba.njit(inline="always")
def _product(a, b, c, d, e, f, g, h):
    """The Hamilton product (a, b, c, d)(e, f, g, h)."""
    return (a * e - b * f - c * g - d * h, a * f + b * e + c * h - d * g,
            a * g - b * h + c * e + d * f, a * h + b * g - c * f + d * e)


@numba.njit(nogil=True, cache=True, fastmath={"contract"}, error_model="numpy")
def sample(g1, g2, noise, sigma, out):
    """out (P, 6) ← one draw of g_t per row of g_{t-1} = g1, g_{t-2} = g2 (P, 6), from the standard
    normal variates ``noise`` (P, 6) scaled by ``sigma`` (6,) (translation, then rotation), float32."""
    for i in range(g1.shape[0]):
        for a in range(3):
            out[i, a] = np.float32(2.0) * g1[i, a] - g2[i, a] + noise[i, a] * sigma[a]
        w1, x1, y1, z1 = _quaternion(g1[i, 3], g1[i, 4], g1[i, 5])
        w2, x2, y2, z2 = _quaternion(g2[i, 3], g2[i, 4], g2[i, 5])
        w, x, y, z = _product(w1, x1, y1, z1, w2, -x2, -y2, -z2)
        w, x, y, z = _product(w, x, y, z, w1, x1, y1, z1)                                    # q̂ = q_1 q_2* q_1
        we, xe, ye, ze = _quaternion(noise[i, 3] * sigma[3], noise[i, 4] * sigma[4], noise[i, 5] * sigma[5])
        w, x, y, z = _product(we, xe, ye, ze, w, x, y, z)                                    # exp(η) q̂
        # so3.quaternion_log: ω = 2 atan2(|v|, |w|) / |v| · sign(w) v
        sign = np.float32(-1.0) if w < 0 else np.float32(1.0)
        w = w * sign
        n_sq = x * x + y * y + z * z
        if n_sq < np.float32(1e-16):
            f = np.float32(2.0) / w * sign
        else:
            n = math.sqrt(n_sq)
            f = np.float32(2.0) * math.atan2(n, w) / n * sign
        out[i, 3], out[i, 4], out[i, 5] = f * x, f * y, f * z
