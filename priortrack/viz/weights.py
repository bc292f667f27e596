"""How a particle's weight is shown: its share of the heaviest on a log scale, over a few decades.

After a sharp update (four cameras) particle weights span hundreds of decades (1e-120 to 1); on a linear scale
every particle but the heaviest shows one colour. Each weight w is shown at the level

    ℓ(w) = 1 + clip(log10(w / max w), −D, 0) / D,      D = :data:`DECADES`,

1 for the heaviest, 0 for D decades down and below (a weight of 0 too): the recordings' clouds and the
notebooks' scatter plots colour by it.
"""

from __future__ import annotations

import numpy as np

#: Decades of weight below the heaviest that the colours span.
DECADES = 4


def weight_levels(weights) -> np.ndarray:
    """ℓ (P,) in [0, 1] of weights (P,) (module docstring); a weight ≤ 0 or NaN (an unscented filter's centre point
    may weigh less than nothing) at 0; all 1 where no weight is above 0."""
    w = np.nan_to_num(np.asarray(weights, dtype=np.float64), nan=0.0)
    top = w.max() if w.size else 0.0
    if not top > 0:
        return np.ones_like(w)
    positive = w > 0
    logs = np.full_like(w, -np.inf)
    logs[positive] = np.log10(w[positive] / top)
    return 1.0 + np.clip(logs, -DECADES, 0.0) / DECADES
