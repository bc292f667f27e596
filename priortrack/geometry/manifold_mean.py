"""The weighted mean of points on a manifold for weights of any sign (the unscented transform's).

For weights w (N,) summing to 1 and points x_i, the mean is the fixed point of

    m ← m ⊞ Σ_i w_i (x_i ⊟ m),

one step where ⊞ = + (it is then Σ_i w_i x_i), the Karcher iteration with signed weights on a
manifold. (For non-negative weights on spheres, :func:`priortrack.geometry.sphere.karcher_mean`
is the faster, specialised form.)
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import torch

log = logging.getLogger(__name__)

#: The iteration stops when its step is below this (largest |coordinate|: metres, radians; the
#: iterate is then within about twice that of the fixed point) …
MEAN_TOL = 1e-10
#: … or after this many steps (logged). With the unscented weights' large negative W_0 the
#: rotations' iteration contracts slowly (by about 0.65 per step seen on walks with spread
#: sigma points): 45 steps from 1e-2 to MEAN_TOL.
MEAN_MAX_STEPS = 100


def signed_mean(start: torch.Tensor, w: torch.Tensor, minus: Callable[[torch.Tensor], torch.Tensor],
                plus: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]) -> torch.Tensor:
    """The fixed point of m ← m ⊞ Σ_i w_i (x_i ⊟ m) from ``start``, with minus(m) = (x_i ⊟ m)_i (N, k),
    plus(m, v) = m ⊞ v and w (N,). Stops once the step's largest entry is below MEAN_TOL (after
    MEAN_MAX_STEPS steps, logged)."""
    mean = start
    for _ in range(MEAN_MAX_STEPS):
        step = w @ minus(mean)
        mean = plus(mean, step)
        if float(step.abs().max()) < MEAN_TOL:
            return mean
    log.warning("signed mean: no convergence in %d steps (last step %.3g)", MEAN_MAX_STEPS, float(step.abs().max()))
    return mean
