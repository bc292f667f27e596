"""The depth branches of a limb seen by one camera.

A pixel fixes its joint to the ray from the camera's centre c through it, not to a point. A limb is a
chain root → mid → end (shoulder → elbow → wrist, hip → knee → ankle) of known bone lengths: with the root
placed, the mid joint lies where its ray meets the sphere of the upper bone's length about the root (two
points, a limb tilted towards the camera or away from it), and the end where its ray meets the sphere of
the lower bone's length about the mid (two again). Along the ray through p (unit u = (p − c) / ‖p − c‖) the
two points at distance ℓ from an anchor a are c + (s₀ ± √(s₀² − ‖a − c‖² + ℓ²)) u, s₀ = (a − c)·u; the one
that is not p itself is its reflection

    p' = p + 2 ((a − p)·u) u,

which keeps both p's pixel and its distance to a. A fit from one view lands on one branch of each by where
it starts; :func:`limb_branches` gives the other three of a limb, as 3D targets to start a fit from.
"""

from __future__ import annotations

import numpy as np

#: The limbs as (root, mid, end) eval15 indices: left arm, right arm, left leg, right leg.
LIMBS = ((3, 4, 5), (6, 7, 8), (9, 10, 11), (12, 13, 14))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def reflected(p: np.ndarray, centre: np.ndarray, anchor: np.ndarray) -> np.ndarray:
    """p' (..., 3): the other point of the ray from ``centre`` (3,) through p (..., 3) at p's distance from
    ``anchor`` (..., 3) (module docstring)."""
    u = _unit(p - centre)
    return p + 2 * ((anchor - p) * u).sum(-1, keepdims=True) * u


def on_ray(p: np.ndarray, centre: np.ndarray, anchor: np.ndarray, length: np.ndarray, sign: float) -> np.ndarray:
    """(..., 3) the point of the ray from ``centre`` (3,) through p (..., 3) at ``length`` (...) from ``anchor``
    (..., 3): the farther of the two (``sign`` +1) or the nearer (−1); where the ray passes farther than
    ``length`` from the anchor, its closest point to it."""
    u = _unit(p - centre)
    a = anchor - centre
    s0 = (a * u).sum(-1, keepdims=True)
    discriminant = s0 ** 2 - (a * a).sum(-1, keepdims=True) + np.asarray(length)[..., None] ** 2
    return centre + (s0 + sign * np.sqrt(np.maximum(discriminant, 0.0))) * u


def limb_branches(J: np.ndarray, centre: np.ndarray, limb: tuple[int, int, int]) -> list[np.ndarray]:
    """The limb's other three branches of joints J (T, 15, 3) seen from a camera at ``centre`` (3,), each
    (T, 15, 3) with every pixel and bone length of the limb kept: the end reflected about the mid; the mid
    reflected about the root with the end on its ray at the lower bone's length, farther or nearer."""
    root, mid, end = limb
    lower = np.linalg.norm(J[:, end] - J[:, mid], axis=-1)
    end_flipped = J.copy()
    end_flipped[:, end] = reflected(J[:, end], centre, J[:, mid])
    out = [end_flipped]
    moved = reflected(J[:, mid], centre, J[:, root])
    for sign in (1.0, -1.0):
        branch = J.copy()
        branch[:, mid] = moved
        branch[:, end] = on_ray(J[:, end], centre, moved, lower, sign)
        out.append(branch)
    return out
