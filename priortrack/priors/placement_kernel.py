"""World placement X = exp(ω) · B + t as one fused CPU kernel (numba), for float32 joints.

:func:`priortrack.priors.global_motion.to_world` places body-frame joints B (P, J, 3) by
placements g = (t, ω) (P, 6). In torch that is a rotation-vector exponential over the batch
(some 40 elementwise operations) and one batched 3 × 3 product, which the BLAS runs as 10⁴ tiny
products; here each row is one short loop: Rodrigues' formula

    exp(ω) = I + a [ω]ₓ + b [ω]ₓ²,   a = sin θ / θ,   b = (1 − cos θ) / θ² = ½ (sin(θ/2) / (θ/2))²,

(b in the half-angle form, free of the cancellation in 1 − cos θ; both by their Taylor series
1 − θ²/6 and ½ − θ²/24 below θ² = 1e-8, as :func:`priortrack.geometry.so3.exp`), then the
product and the shift for every joint of the row.

The torch path serves other dtypes and devices and gradients, and is the reference this kernel
is tested against (tests/test_global_motion.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(nogil=True, cache=True, fastmath={"contract"}, error_model="numpy")
def place(body, g, out):
    """out (P, J, 3) ← exp(ω) · body + t for body joints (P, J, 3) and placements g (P, 6), float32."""
    P, J = body.shape[0], body.shape[1]
    for i in range(P):
        x, y, z = g[i, 3], g[i, 4], g[i, 5]
        xx, yy, zz = x * x, y * y, z * z
        theta_sq = xx + yy + zz
        if theta_sq < np.float32(1e-8):
            a = np.float32(1.0) - theta_sq / np.float32(6.0)
            b = np.float32(0.5) - theta_sq / np.float32(24.0)
        else:
            theta = math.sqrt(theta_sq)
            a = math.sin(theta) / theta
            half = math.sin(np.float32(0.5) * theta) / (np.float32(0.5) * theta)
            b = np.float32(0.5) * half * half
        ax, ay, az = a * x, a * y, a * z
        bxy, bxz, byz = b * x * y, b * x * z, b * y * z
        r00, r01, r02 = np.float32(1.0) - b * (yy + zz), bxy - az, bxz + ay
        r10, r11, r12 = bxy + az, np.float32(1.0) - b * (xx + zz), byz - ax
        r20, r21, r22 = bxz - ay, byz + ax, np.float32(1.0) - b * (xx + yy)
        t0, t1, t2 = g[i, 0], g[i, 1], g[i, 2]
        for j in range(J):
            b0, b1, b2 = body[i, j, 0], body[i, j, 1], body[i, j, 2]
            out[i, j, 0] = r00 * b0 + r01 * b1 + r02 * b2 + t0
            out[i, j, 1] = r10 * b0 + r11 * b1 + r12 * b2 + t1
            out[i, j, 2] = r20 * b0 + r21 * b1 + r22 * b2 + t2
