"""The unit-quaternion maps of :mod:`priortrack.geometry.so3` for one rotation at a time, inlined into the fused
CPU kernels (numba) that compose rotations: :func:`helpers` makes them for one float type, its constants of that
type, so that a float32 kernel computes in float32 and a float64 one in float64.

- quaternion(x, y, z): the rotation vector ω → (cos θ/2, sin(θ/2) ω/θ), θ = |ω| (the Taylor series 1/2 − θ²/48 and
  1 − θ²/8 below θ² = 1e-8), as :func:`~priortrack.geometry.so3.quaternion`;
- log(w, x, y, z): the unit quaternion → ω = 2 atan2(|v|, |w|) / |v| · sign(w) v (2 / |w| · sign(w) v as |v| → 0),
  as :func:`~priortrack.geometry.so3.quaternion_log`;
- product(a, b, c, d, e, f, g, h): the Hamilton product (a, b, c, d)(e, f, g, h), as
  :func:`~priortrack.geometry.so3.quaternion_product`.
"""

from __future__ import annotations

import math

import numba


def helpers(ftype):
    """(quaternion, log, product) for scalars of the numpy float type ``ftype`` (module docstring)."""
    zero, half, one, two = ftype(0.0), ftype(0.5), ftype(1.0), ftype(2.0)
    tiny_angle, tiny_vector, eight, forty_eight = ftype(1e-8), ftype(1e-16), ftype(8.0), ftype(48.0)

    @numba.njit(inline="always")
    def quaternion(x, y, z):
        theta_sq = x * x + y * y + z * z
        if theta_sq < tiny_angle:
            s = half - theta_sq / forty_eight
            c = one - theta_sq / eight
        else:
            angle = half * math.sqrt(theta_sq)
            s = math.sin(angle) / (two * angle)
            c = math.cos(angle)
        return c, s * x, s * y, s * z

    @numba.njit(inline="always")
    def log(w, x, y, z):
        sign = -one if w < zero else one
        w = w * sign
        n_sq = x * x + y * y + z * z
        if n_sq < tiny_vector:
            f = two / w * sign
        else:
            n = math.sqrt(n_sq)
            f = two * math.atan2(n, w) / n * sign
        return f * x, f * y, f * z

    @numba.njit(inline="always")
    def product(a, b, c, d, e, f, g, h):
        return (a * e - b * f - c * g - d * h, a * f + b * e + c * h - d * g,
                a * g - b * h + c * e + d * f, a * h + b * g - c * f + d * e)

    return quaternion, log, product
