"""Forward kinematics as one fused CPU kernel (numba), for float32 and float64 channels.

:class:`priortrack.body.fk.ForwardKinematics` computes, for every joint j (parents first),

    L_j = Π_k R_{a_k}(θ_k),   G_j = G_parent · L_j,   p_j = p_parent + G_parent · (o_j + T_j),

R_a(θ) = cos θ I + sin θ [a]ₓ + (1 − cos θ) a aᵀ the right-handed rotation about the unit axis a,
T_j the joint's translation channels along the parent's axes (G and p of the root's parent: I
and 0). The torch path does this with about 50 tensor operations, level by level; here it is
one pass over the rows, in tiles of :data:`TILE` rows so that the tile's (J, 12, TILE) work set
stays in the core's cache, each joint's rows in loops that LLVM vectorises (the sines and
cosines by :func:`_sin_cos`, polynomials it can inline: the C library's sinf and cosf are scalar
calls, ten times slower).

:func:`_sin_cos` reduces θ to r = θ − q π/2 ∈ [−π/4, π/4] (q the integer nearest to 2θ/π,
π/2 split in two parts so that q π/2 is exact to float32 for |θ| < 2¹⁰) and evaluates Taylor
polynomials of sin r and cos r, whose truncation errors (r¹¹/11!, r¹²/12!) are below 1e-8 there;
the result is accurate to about 1e-7, float32's rounding. Joint angles are radians of order π.
float64 channels take the C library's sin and cos (:func:`sin_cos` picks by the angle's type when
the kernel is compiled): the unscented filter's 2n + 1 sigma points are float64, and there the
call's overhead, not the sines, is what the torch path spends (about 50 operations a level).

The torch path serves other dtypes and devices, global rotations and local rotations, and is the
reference this kernel is tested against (tests/test_fk.py). Compiled on first use (about a
second); numba caches the machine code beside this module.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types
from numba.extending import overload

#: Rows per tile of :func:`positions`.
TILE = 256
_TWO_OVER_PI = np.float32(2 / np.pi)
#: π/2 in two parts: the first has 8 significant bits, so q · _PI_2_HI is exact for |q| < 2¹⁶.
_PI_2_HI = np.float32(1.5703125)
_PI_2_LO = np.float32(np.pi / 2 - 1.5703125)


@numba.njit(inline="always", fastmath={"contract"})
def _sin_cos(theta):
    """(sin θ, cos θ) for float32 θ, |θ| < 2¹⁰, branch-free so that loops calling it vectorise."""
    half_turns = theta * _TWO_OVER_PI
    k = np.int32(half_turns + np.float32(0.5) if half_turns >= 0 else half_turns - np.float32(0.5))
    q = np.float32(k)
    r = (theta - q * _PI_2_HI) - q * _PI_2_LO
    r2 = r * r
    sin_r = r + r * r2 * (np.float32(-1 / 6) + r2 * (np.float32(1 / 120) + r2 * (
        np.float32(-1 / 5040) + r2 * np.float32(1 / 362880))))
    cos_r = np.float32(1.0) + r2 * (np.float32(-1 / 2) + r2 * (np.float32(1 / 24) + r2 * (
        np.float32(-1 / 720) + r2 * (np.float32(1 / 40320) + r2 * np.float32(-1 / 3628800)))))
    swap = (k & 1) == 1                                         # θ = r + k π/2: k odd swaps sin and cos,
    sin_t = cos_r if swap else sin_r
    cos_t = sin_r if swap else cos_r
    sin_t = -sin_t if (k & 2) == 2 else sin_t                    # and k mod 4 sets the signs
    cos_t = -cos_t if ((k + 1) & 2) == 2 else cos_t
    return sin_t, cos_t


def sin_cos(theta):
    """(sin θ, cos θ) in θ's own precision: float32 by :func:`_sin_cos`, float64 by the C library."""
    return np.sin(theta), np.cos(theta)


@overload(sin_cos, inline="always")
def _sin_cos_of_type(theta):
    if theta == types.float32:
        return lambda theta: _sin_cos(theta)
    return lambda theta: (np.sin(theta), np.cos(theta))


@numba.njit(nogil=True, cache=True, fastmath={"contract"}, error_model="numpy")
def positions(channels, parents, offsets, axes, rot_channels, trans_channels, wanted, out):
    """Joint positions of ``wanted`` joints into ``out`` (n, K, 3) for channels (n, C), float32 or
    float64 (``out``, ``offsets`` and ``axes`` of the same dtype: the kernel is compiled for each).

    Skeleton arrays (as :class:`priortrack.data.skeleton.Skeleton`): parents (J,) int64, offsets
    (J, 3) and axes (J, 3, 3), rot_channels (J, 3) and trans_channels (J, 3) int64 (−1:
    unused); wanted (K,) int64.
    """
    n, C, J = channels.shape[0], channels.shape[1], parents.shape[0]
    planar = np.empty((C, TILE), dtype=out.dtype)               # the tile's channels, rows along i
    G = np.empty((J, 9, TILE), dtype=out.dtype)                 # row-major 3 × 3 per row of the tile
    P = np.empty((J, 3, TILE), dtype=out.dtype)
    shift = np.empty((3, TILE), dtype=out.dtype)
    zero, one = np.zeros(1, dtype=out.dtype)[0], np.ones(1, dtype=out.dtype)[0]
    for start in range(0, n, TILE):
        m = min(TILE, n - start)
        for i in range(m):
            for c in range(C):
                planar[c, i] = channels[start + i, c]
        for j in range(J):
            par = parents[j]
            for a in range(3):                                  # o_j + T_j
                ch = trans_channels[j, a]
                if ch >= 0:
                    for i in range(m):
                        shift[a, i] = offsets[j, a] + planar[ch, i]
                else:
                    for i in range(m):
                        shift[a, i] = offsets[j, a]
            if par < 0:
                for e in range(9):
                    value = one if e % 4 == 0 else zero
                    for i in range(m):
                        G[j, e, i] = value
                for a in range(3):
                    for i in range(m):
                        P[j, a, i] = shift[a, i]
            else:
                for e in range(9):
                    for i in range(m):
                        G[j, e, i] = G[par, e, i]
                for a in range(3):
                    for i in range(m):
                        P[j, a, i] = (P[par, a, i] + G[par, 3 * a, i] * shift[0, i] + G[par, 3 * a + 1, i] * shift[1, i]
                                      + G[par, 3 * a + 2, i] * shift[2, i])
            for k in range(3):                                  # G_j ← G_j R_{a_k}(θ_k), slot by slot
                ch = rot_channels[j, k]
                if ch < 0:
                    continue
                x, y, z = axes[j, k, 0], axes[j, k, 1], axes[j, k, 2]
                g = G[j]
                for i in range(m):
                    s, c = sin_cos(planar[ch, i])
                    t = one - c
                    r00, r01, r02 = c + t * x * x, t * x * y - s * z, t * x * z + s * y
                    r10, r11, r12 = t * x * y + s * z, c + t * y * y, t * y * z - s * x
                    r20, r21, r22 = t * x * z - s * y, t * y * z + s * x, c + t * z * z
                    g00, g01, g02 = g[0, i], g[1, i], g[2, i]
                    g10, g11, g12 = g[3, i], g[4, i], g[5, i]
                    g20, g21, g22 = g[6, i], g[7, i], g[8, i]
                    g[0, i] = g00 * r00 + g01 * r10 + g02 * r20
                    g[1, i] = g00 * r01 + g01 * r11 + g02 * r21
                    g[2, i] = g00 * r02 + g01 * r12 + g02 * r22
                    g[3, i] = g10 * r00 + g11 * r10 + g12 * r20
                    g[4, i] = g10 * r01 + g11 * r11 + g12 * r21
                    g[5, i] = g10 * r02 + g11 * r12 + g12 * r22
                    g[6, i] = g20 * r00 + g21 * r10 + g22 * r20
                    g[7, i] = g20 * r01 + g21 * r11 + g22 * r21
                    g[8, i] = g20 * r02 + g21 * r12 + g22 * r22
        for w in range(wanted.shape[0]):
            for a in range(3):
                for i in range(m):
                    out[start + i, w, a] = P[wanted[w], a, i]
