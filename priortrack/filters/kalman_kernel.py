"""The per-particle Kalman update of :mod:`priortrack.filters.marginal_translation` as one fused
CPU kernel (numba), for CPU tensors of either float dtype.

In torch the prediction and update are a dozen batched products of
10⁴ tiny matrices (about 10 ms a step at 10⁴ particles); here each particle is one short loop,
in the same order as the module's equations: C⁻ = F C Fᵀ + Q, the projection h = P X + p of each
observed joint, its Jacobian J_j = (P_{0,1} − u_j P_2) / h_2 and residual r_j = z_j − u_j (and
Σ_j |r_j|², for the likelihood at t̂), the sums A and b, then

    N = I + A P,  y = N⁻¹ b,  M = N⁻¹ A  (N⁻¹ by the adjugate),
    shift = C[:, :3] y,   C⁺ = C − C[:, :3] M C[:3, :],   correction = ½ bᵀ P y − ½ log det N.

The torch path serves other devices and gradients, and is the reference this kernel is tested
against (tests/test_marginal_translation.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(nogil=True, cache=True, fastmath={"contract"}, error_model="numpy")
def update(joints, z, Pm, p, inv_var, min_depth, miss_sq, C_prev, sigma_sq, velocity, shift, C_out, correction, d_sq):
    """Kalman prediction and update of every particle.

    joints (P, n, 3) observed joints at t̂; z (n, 2) their pixels; Pm (3, 3), p (3,) the camera's
    K R and K t; C_prev (P, 6, 6) the previous frame's covariance, sigma_sq (3,) σ_t² and velocity (3,)
    the velocity's decay v (F's V = diag v). Writes
    shift (P, 6), C_out (P, 6, 6) and correction (P,). Joints with depth ≤ min_depth are left
    out. Everything is computed in the arrays' dtype, in scalars (the 3 × 3 algebra written out).
    """
    n_particles, n = joints.shape[0], joints.shape[1]
    zero, one, half = C_prev.dtype.type(0.0), C_prev.dtype.type(1.0), C_prev.dtype.type(0.5)
    w = C_prev.dtype.type(inv_var)
    K = np.empty((6, 3), dtype=C_prev.dtype)
    FC = np.empty((6, 6), dtype=C_prev.dtype)
    C = np.empty((6, 6), dtype=C_prev.dtype)
    for i in range(n_particles):
        # C⁻ = F C Fᵀ + Q, F = [[I + V, −V], [I, 0]]
        for r in range(3):
            for c in range(6):
                FC[r, c] = C_prev[i, r, c] + velocity[r] * (C_prev[i, r, c] - C_prev[i, r + 3, c])
                FC[r + 3, c] = C_prev[i, r, c]
        for r in range(6):
            for c in range(3):
                C[r, c] = FC[r, c] + velocity[c] * (FC[r, c] - FC[r, c + 3])
                C[r, c + 3] = FC[r, c]
        for r in range(3):
            C[r, r] += sigma_sq[r]
        a00 = a01 = a02 = a11 = a12 = a22 = zero
        b0 = b1 = b2 = zero
        miss = zero
        for j in range(n):
            X0, X1, X2 = joints[i, j, 0], joints[i, j, 1], joints[i, j, 2]
            h2 = Pm[2, 0] * X0 + Pm[2, 1] * X1 + Pm[2, 2] * X2 + p[2]
            if not h2 > min_depth:
                miss += miss_sq
                continue
            inv_h = one / h2
            u = (Pm[0, 0] * X0 + Pm[0, 1] * X1 + Pm[0, 2] * X2 + p[0]) * inv_h
            v = (Pm[1, 0] * X0 + Pm[1, 1] * X1 + Pm[1, 2] * X2 + p[1]) * inv_h
            ru, rv = z[j, 0] - u, z[j, 1] - v
            miss += ru * ru + rv * rv
            j0, j1, j2 = (Pm[0, 0] - u * Pm[2, 0]) * inv_h, (Pm[0, 1] - u * Pm[2, 1]) * inv_h, (Pm[0, 2] - u * Pm[2, 2]) * inv_h
            k0, k1, k2 = (Pm[1, 0] - v * Pm[2, 0]) * inv_h, (Pm[1, 1] - v * Pm[2, 1]) * inv_h, (Pm[1, 2] - v * Pm[2, 2]) * inv_h
            a00 += j0 * j0 + k0 * k0
            a01 += j0 * j1 + k0 * k1
            a02 += j0 * j2 + k0 * k2
            a11 += j1 * j1 + k1 * k1
            a12 += j1 * j2 + k1 * k2
            a22 += j2 * j2 + k2 * k2
            b0 += j0 * ru + k0 * rv
            b1 += j1 * ru + k1 * rv
            b2 += j2 * ru + k2 * rv
        a00, a01, a02, a11, a12, a22 = a00 * w, a01 * w, a02 * w, a11 * w, a12 * w, a22 * w
        b0, b1, b2 = b0 * w, b1 * w, b2 * w
        p00, p01, p02 = C[0, 0], C[0, 1], C[0, 2]
        p11, p12, p22 = C[1, 1], C[1, 2], C[2, 2]
        # N = I + A P
        n00, n01, n02 = one + a00 * p00 + a01 * p01 + a02 * p02, a00 * p01 + a01 * p11 + a02 * p12, a00 * p02 + a01 * p12 + a02 * p22
        n10, n11, n12 = a01 * p00 + a11 * p01 + a12 * p02, one + a01 * p01 + a11 * p11 + a12 * p12, a01 * p02 + a11 * p12 + a12 * p22
        n20, n21, n22 = a02 * p00 + a12 * p01 + a22 * p02, a02 * p01 + a12 * p11 + a22 * p12, one + a02 * p02 + a12 * p12 + a22 * p22
        # N⁻¹ = adj(N) / det N
        c00, c01, c02 = n11 * n22 - n12 * n21, n02 * n21 - n01 * n22, n01 * n12 - n02 * n11
        c10, c11, c12 = n12 * n20 - n10 * n22, n00 * n22 - n02 * n20, n02 * n10 - n00 * n12
        c20, c21, c22 = n10 * n21 - n11 * n20, n01 * n20 - n00 * n21, n00 * n11 - n01 * n10
        det = n00 * c00 + n01 * c10 + n02 * c20
        inv_det = one / det
        y0 = (c00 * b0 + c01 * b1 + c02 * b2) * inv_det
        y1 = (c10 * b0 + c11 * b1 + c12 * b2) * inv_det
        y2 = (c20 * b0 + c21 * b1 + c22 * b2) * inv_det
        # M = N⁻¹ A
        m00, m01, m02 = (c00 * a00 + c01 * a01 + c02 * a02) * inv_det, (c00 * a01 + c01 * a11 + c02 * a12) * inv_det, (c00 * a02 + c01 * a12 + c02 * a22) * inv_det
        m10, m11, m12 = (c10 * a00 + c11 * a01 + c12 * a02) * inv_det, (c10 * a01 + c11 * a11 + c12 * a12) * inv_det, (c10 * a02 + c11 * a12 + c12 * a22) * inv_det
        m20, m21, m22 = (c20 * a00 + c21 * a01 + c22 * a02) * inv_det, (c20 * a01 + c21 * a11 + c22 * a12) * inv_det, (c20 * a02 + c21 * a12 + c22 * a22) * inv_det
        quadratic = (b0 * (p00 * y0 + p01 * y1 + p02 * y2) + b1 * (p01 * y0 + p11 * y1 + p12 * y2)
                     + b2 * (p02 * y0 + p12 * y1 + p22 * y2))
        correction[i] = half * quadratic - half * math.log(det)
        d_sq[i] = miss
        for r in range(6):
            g0, g1, g2 = C[r, 0], C[r, 1], C[r, 2]
            shift[i, r] = g0 * y0 + g1 * y1 + g2 * y2
            K[r, 0] = g0 * m00 + g1 * m10 + g2 * m20
            K[r, 1] = g0 * m01 + g1 * m11 + g2 * m21
            K[r, 2] = g0 * m02 + g1 * m12 + g2 * m22
        for r in range(6):
            for c in range(r, 6):
                value = C[r, c] - (K[r, 0] * C[c, 0] + K[r, 1] * C[c, 1] + K[r, 2] * C[c, 2])
                C_out[i, r, c] = value
                C_out[i, c, r] = value
