"""The Lie prior's conditional sampler as one fused CPU kernel (numba), for float32 poses.

:meth:`priortrack.priors.lie.GeodesicMixture.sample_next` computes, per row of poses x and given
one uniform u and normals z (B, 2) per row (see :mod:`priortrack.priors.lie` for the notation):

    ln π̃_k(x) = ln α_k − ½ Σ_b ln det Sxx_kb − B ln 2π − ½ Σ_b (θ_kb / sin θ_kb)² |G_kb x_b|²,
    k = the inverse-CDF draw of u under π(x),
    V_b = Eᵀ(m + L_c z_b)/s + (θ_kb / sin θ_kb) (Eᵀ R E / s) x_b,      (component k)
    u_b = V_b − (x_b·V_b) / (1 + c_kb) (x_b + μ_kb),   x_next,b = exp_{x_b}(u_b), renormalised,

with c_kb = μ_kb·x_b clamped to [−c_max, c_max] and θ_kb = arccos c_kb. The torch path evaluates
this with some 150 tensor operations per block, each a pass over memory; here it is one pass.
The responsibilities (K·B arccosines a row, most of the work) run as loops over the rows that
LLVM vectorises, with :func:`_arccos`, a polynomial arccosine that it can inline (the C library's
acosf is a scalar call, some 30 times slower); the draw and the step (B bones of one component a
row) run row by row with the C library's sqrt, sin and cos.

:func:`_arccos` is Cephes' asinf polynomial (relative error below 3e-7 on [0, ½]) with the
half-angle reduction arccos c = 2 arcsin √((1 − c)/2) for |c| > ½, so it is accurate to a few
float32 ulps on all of [−1, 1], as the torch path's arccos.

The torch path stays the implementation for other devices and dtypes, and the reference this
kernel is tested against (tests/test_lie.py). Compiled on first use (about a second; numba
caches the machine code beside this module).
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: Cephes asinf coefficients: arcsin s = s + s z P(z), z = s², for 0 ≤ s ≤ ½.
_P4, _P3, _P2, _P1, _P0 = 4.2163199048e-2, 2.4181311049e-2, 4.5470025998e-2, 7.4953002686e-2, 1.6666752422e-1


@numba.njit(inline="always", fastmath=False)
def _arccos(c):
    """arccos c for c ∈ [−1, 1] (float32), branch-free so that loops calling it vectorise."""
    a = abs(c)
    half = a > np.float32(0.5)
    z = np.float32(0.5) * (np.float32(1.0) - a) if half else a * a
    s = math.sqrt(z) if half else a
    p = ((((np.float32(_P4) * z + np.float32(_P3)) * z + np.float32(_P2)) * z + np.float32(_P1)) * z
         + np.float32(_P0))
    r = s + s * z * p                                                        # arcsin s
    t = np.float32(2.0) * r if half else np.float32(math.pi / 2) - r          # arccos |c|
    return np.float32(math.pi) - t if c < 0 else t


@numba.njit(inline="always", fastmath=False)
def _cos_sinc(t):
    """(cos t, sin t / t) for t ≥ 0 (float32): Taylor polynomials up to t ≤ π/4, where their
    truncation errors (t¹⁰/11!, t¹²/12!) are below 1e-8, and the C library's cos and sin beyond."""
    if t > np.float32(math.pi / 4):
        return math.cos(t), math.sin(t) / t
    q = t * t
    cos_t = np.float32(1.0) + q * (np.float32(-1 / 2) + q * (np.float32(1 / 24) + q * (
        np.float32(-1 / 720) + q * (np.float32(1 / 40320) + q * np.float32(-1 / 3628800)))))
    sinc_t = np.float32(1.0) + q * (np.float32(-1 / 6) + q * (np.float32(1 / 120) + q * (
        np.float32(-1 / 5040) + q * np.float32(1 / 362880))))
    return cos_t, sinc_t


@numba.njit(nogil=True, cache=True, fastmath={"contract"}, error_model="numpy")
def sample_block(x, u, z, mu, g, log_norm, cond, noise_w, noise_b, c_max, log_floor, out, planar, logits):
    """x_next into ``out`` (n, 3B) for poses x (n, 3B), uniforms u (n,) and normals z (B, 2, n).

    Component constants (float32, C-contiguous): mu (K, B, 3) μ; g (K, B, 2, 3) G = L_xx⁻¹ E;
    log_norm (K,) ln α_k − ½ Σ_b ln det Sxx_kb − B ln 2π; cond (K, B, 3, 3) Eᵀ R E / s;
    noise_w (K, B, 3, 2) Eᵀ L_c / s; noise_b (K, B, 3) Eᵀ m / s. c_max: the cosine clamp;
    log_floor: the floor on ln(π_k / max_j π_j) (:data:`priortrack.priors.lie.LOG_WEIGHT_FLOOR`).
    Scratch: planar (3B, n) and logits (K, n), float32.
    """
    n = x.shape[0]
    K, B = mu.shape[0], mu.shape[1]
    one = np.float32(1.0)
    for j in range(3 * B):                                                  # planar copy: rows along i
        for i in range(n):
            planar[j, i] = x[i, j]
    for k in range(K):
        for i in range(n):
            logits[k, i] = log_norm[k]
        for b in range(B):
            m0, m1, m2 = mu[k, b, 0], mu[k, b, 1], mu[k, b, 2]
            a0, a1, a2 = g[k, b, 0, 0], g[k, b, 0, 1], g[k, b, 0, 2]
            b0, b1, b2 = g[k, b, 1, 0], g[k, b, 1, 1], g[k, b, 1, 2]
            for i in range(n):
                x0, x1, x2 = planar[3 * b, i], planar[3 * b + 1, i], planar[3 * b + 2, i]
                c = min(max(m0 * x0 + m1 * x1 + m2 * x2, -c_max), c_max)
                g1 = a0 * x0 + a1 * x1 + a2 * x2
                g2 = b0 * x0 + b1 * x1 + b2 * x2
                theta = _arccos(c)
                logits[k, i] -= np.float32(0.5) * theta * theta / ((one - c) * (one + c)) * (g1 * g1 + g2 * g2)
    comp = np.empty(n, dtype=np.int64)
    first = np.zeros(K + 1, dtype=np.int64)                                 # counting sort of the rows by k
    for i in range(n):
        top = logits[0, i]
        for k in range(1, K):
            top = max(top, logits[k, i])
        total = np.float32(0.0)
        for k in range(K):                                                  # w_k, then W_k, in place
            total += math.exp(max(logits[k, i] - top, log_floor))
            logits[k, i] = total
        threshold = (one - u[i]) * total
        k = 0
        for j in range(K):                                                  # the number of j with W_j < threshold
            k += logits[j, i] < threshold
        comp[i] = k
        first[k + 1] += 1
    for k in range(K):
        first[k + 1] += first[k]
    for i in range(n):
        k = comp[i]
        column = first[k]                                                   # row i's rank in the stable sort by k
        first[k] += 1
        for b in range(B):
            x0, x1, x2 = x[i, 3 * b], x[i, 3 * b + 1], x[i, 3 * b + 2]
            m0, m1, m2 = mu[k, b, 0], mu[k, b, 1], mu[k, b, 2]
            c = min(max(m0 * x0 + m1 * x1 + m2 * x2, -c_max), c_max)
            ratio = _arccos(c) / math.sqrt((one - c) * (one + c))          # θ / sin θ
            z0, z1 = z[b, 0, column], z[b, 1, column]
            w, a = noise_w[k, b], cond[k, b]
            v0 = noise_b[k, b, 0] + w[0, 0] * z0 + w[0, 1] * z1 + ratio * (a[0, 0] * x0 + a[0, 1] * x1 + a[0, 2] * x2)
            v1 = noise_b[k, b, 1] + w[1, 0] * z0 + w[1, 1] * z1 + ratio * (a[1, 0] * x0 + a[1, 1] * x1 + a[1, 2] * x2)
            v2 = noise_b[k, b, 2] + w[2, 0] * z0 + w[2, 1] * z1 + ratio * (a[2, 0] * x0 + a[2, 1] * x1 + a[2, 2] * x2)
            along = (x0 * v0 + x1 * v1 + x2 * v2) / (one + c)
            s0, s1, s2 = v0 - along * (x0 + m0), v1 - along * (x1 + m1), v2 - along * (x2 + m2)
            t = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            cos_t, sinc_t = _cos_sinc(t)
            y0, y1, y2 = cos_t * x0 + sinc_t * s0, cos_t * x1 + sinc_t * s1, cos_t * x2 + sinc_t * s2
            norm = one / math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
            out[i, 3 * b], out[i, 3 * b + 1], out[i, 3 * b + 2] = y0 * norm, y1 * norm, y2 * norm
