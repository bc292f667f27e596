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

**The branch no body takes.** An elbow seen by one camera whose view runs across the body (a camera at the
person's side) has one branch out from the shoulder and one through the chest, and a filter drifting along the
ray it cannot see may settle on the second: on Shelf, cameras 0, 1, 4, actor 2's right elbow (akimbo, seen by
camera 4 at their right only) sat 0.17 m inside the shoulder, on the trunk's axis, 0.35–0.5 m from the truth for 3 s,
reprojecting within 12 px. An elbow is *inside the trunk* where its distance to the trunk's axis (the segment
from the mid-hips to the mid-shoulders, the elbow's foot strictly between) is under :data:`TRUNK_FRACTION` of the
shoulder width; :func:`trunk_repairs` gives, for such an elbow seen by exactly one camera, its reflection about the
shoulder (the other branch, the same pixel and upper-arm length) where that one is outside, and its wrist moved
as little as the forearm's length from there allows.
"""

from __future__ import annotations

import numpy as np

#: The limbs as (root, mid, end) eval15 indices: left arm, right arm, left leg, right leg.
LIMBS = ((3, 4, 5), (6, 7, 8), (9, 10, 11), (12, 13, 14))
#: An elbow nearer the trunk's axis than this fraction of the shoulder width is inside the trunk (module
#: docstring): a trunk's half-depth is about 0.3 of the shoulder width (0.10–0.12 m against 0.33–0.40 m). Never
#: so in the 66 bundled CMU clips (walks, runs, jumps, dance: 0.42 at the least) nor in Shelf's annotations (0.24).
TRUNK_FRACTION = 0.2
#: eval15's elbows, the mid joints of the arms: what :func:`trunk_repairs` repairs.
ELBOWS = tuple(mid for _, mid, _ in LIMBS[:2])
#: eval15's shoulders and hips.
_SHOULDERS, _HIPS = (3, 6), (9, 12)
#: The trunk's joints a repair keeps in place: pelvis, neck, shoulders, hips.
_HELD = (0, 1, 3, 6, 9, 12)


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


def inside_trunk(J: np.ndarray, joint: int) -> np.ndarray:
    """(...) whether ``joint`` of joints J (..., 15, 3) is inside the trunk (module docstring):
    nearer the segment from the mid-hips to the mid-shoulders than :data:`TRUNK_FRACTION` of the shoulder width, its
    foot on the segment strictly between them. False where a joint is not finite."""
    shoulders = J[..., list(_SHOULDERS), :]
    base = J[..., list(_HIPS), :].mean(-2)
    axis = shoulders.mean(-2) - base
    p = J[..., joint, :] - base
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (p * axis).sum(-1) / (axis * axis).sum(-1)
        off = p - t[..., None] * axis
        width = shoulders[..., 0, :] - shoulders[..., 1, :]
        return (t > 0) & (t < 1) & ((off * off).sum(-1) < TRUNK_FRACTION ** 2 * (width * width).sum(-1))


def trunk_repairs(J: np.ndarray, seen: np.ndarray, centres: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """The joints of J (15, 3) to move off the branch no body takes, as (joint, target (3,)) pairs: each elbow
    inside the trunk that exactly one camera sees (``seen`` (C, 15) bool, the cameras' centres (C, 3)) goes to its
    reflection about its shoulder along that camera's ray (:func:`reflected`), where that one is outside; and its
    wrist as little as the forearm's length from the moved elbow allows (the forearm swung with the upper arm would
    throw it off): where exactly one camera sees it, to the point of that camera's ray at that length nearer to where
    it was (:func:`on_ray`), else to the point at that length towards where it was. With any of these, the trunk's
    joints (:data:`_HELD`) where they are: the arm is what moves, not the body."""
    repairs = []
    for shoulder, elbow, wrist in LIMBS[:2]:
        cameras = np.flatnonzero(seen[:, elbow])
        if len(cameras) != 1 or not inside_trunk(J, elbow):
            continue
        moved = J.copy()
        moved[elbow] = reflected(J[elbow], centres[cameras[0]], J[shoulder])
        if inside_trunk(moved, elbow):
            continue
        repairs.append((elbow, moved[elbow]))
        forearm = np.linalg.norm(J[wrist] - J[elbow])
        cameras = np.flatnonzero(seen[:, wrist])
        if len(cameras) == 1:
            points = [on_ray(J[wrist], centres[cameras[0]], moved[elbow], forearm, sign) for sign in (1.0, -1.0)]
            repairs.append((wrist, min(points, key=lambda point: np.linalg.norm(point - J[wrist]))))
        else:
            repairs.append((wrist, moved[elbow] + forearm * _unit(J[wrist] - moved[elbow])))
    if repairs:
        repairs += [(joint, J[joint]) for joint in _HELD]
    return repairs
