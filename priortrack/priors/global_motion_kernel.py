"""The global motion's draw g_t ~ p(g_t | g_{t-1}, g_{t-2}) as one fused CPU kernel (numba), for
float32 placements.

:meth:`priortrack.priors.global_motion.GlobalMotion.sample` splits each rotation into heading and
tilt (:func:`priortrack.geometry.so3.heading_tilt`), predicts t̂ = t_1 + v ⊙ (t_1 − t_2), ψ̂ = ψ_1 + wrap(ψ_1 − ψ_2)
and τ̂ = μ + a (τ_1 − μ), perturbs the three, and joins them back into a rotation vector
(:func:`~priortrack.geometry.so3.from_heading_tilt`, then the quaternion logarithm). In torch that
is some forty elementwise passes over 10⁴ rows; here each row is one short loop with the same
formulas as :mod:`priortrack.geometry.so3` (their Taylor branches included), from the same normal
variates.

The torch path serves other dtypes and devices and gradients, and is the reference this kernel
is tested against (tests/test_global_motion.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from priortrack.geometry.so3_kernel import helpers


#: :mod:`priortrack.geometry.so3`'s quaternion and logarithm for one float32 rotation.
_quaternion, _log, _ = helpers(np.float32)


@numba.njit(inline="always")
def _heading_tilt(x, y, z):
    """so3.heading_tilt of the rotation vector (x, y, z): ψ, τ_x, τ_z."""
    w, x, y, z = _quaternion(x, y, z)
    n = max(math.sqrt(w * w + y * y), np.float32(1e-19))
    tx, _, tz = _log(n, (w * x - y * z) / n, np.float32(0.0), (w * z + x * y) / n)
    return np.float32(2.0) * math.atan2(y, w), tx, tz


@numba.njit(nogil=True, cache=True, fastmath={"contract"}, error_model="numpy")
def sample(g1, g2, noise, sigma, tilt, velocity, out):
    """out (P, 6) ← one draw of g_t per row of g_{t-1} = g1, g_{t-2} = g2 (P, 6), from the standard
    normal variates ``noise`` (P, 6) scaled by ``sigma`` (6,) (translation; tilt x, heading, tilt z),
    with the tilt's mean μ = tilt[0] and decay a = tilt[1] (2, 2) and the translation velocity's
    decay v = ``velocity`` (3,), float32."""
    two_pi, pi = np.float32(2.0 * math.pi), np.float32(math.pi)
    for i in range(g1.shape[0]):
        for a in range(3):
            out[i, a] = g1[i, a] + velocity[a] * (g1[i, a] - g2[i, a]) + noise[i, a] * sigma[a]
        psi1, tx1, tz1 = _heading_tilt(g1[i, 3], g1[i, 4], g1[i, 5])
        psi2, _, _ = _heading_tilt(g2[i, 3], g2[i, 4], g2[i, 5])
        step = psi1 - psi2 + pi
        step = step - two_pi * math.floor(step / two_pi) - pi                            # wrap to [−π, π)
        psi = psi1 + step + noise[i, 4] * sigma[4]
        tx = tilt[0, 0] + tilt[1, 0] * (tx1 - tilt[0, 0]) + noise[i, 3] * sigma[3]
        tz = tilt[0, 1] + tilt[1, 1] * (tz1 - tilt[0, 1]) + noise[i, 5] * sigma[5]
        d, e, _, f = _quaternion(tx, np.float32(0.0), tz)
        c, s = math.cos(np.float32(0.5) * psi), math.sin(np.float32(0.5) * psi)
        out[i, 3], out[i, 4], out[i, 5] = _log(c * d, c * e + s * f, s * d, c * f - s * e)
