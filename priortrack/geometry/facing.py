"""Which way a person seen by one camera faces: the trunk's depth reversal, told by their feet and face.

One camera fixes each of the hips and shoulders to its ray. Reflect the line across the body, l = (left hip −
right hip) + (left shoulder − right shoulder) made horizontal, across the vertical plane that holds the camera's
horizontal ray r to the mid-hips,

    l' = l − 2 (l·r) r,

and every point of the trunk keeps its pixel to first order (what moves is its depth), while the body turns about
the vertical through the mid-hips by the angle from l to l'. It then faces f' = l' × up where it faced f = l × up:
the two facings' images point to opposite sides of the picture, and nothing in the hips and shoulders tells them
apart (the Necker cube's reversal). A filter that meets a person side-on to its only camera follows one and may keep
the wrong one for seconds: on Shelf, each camera alone, ukf-real's trunk was more than 90° from the truth's in 0–132
frames of an actor (every one of them this reflection: l·r of the opposite sign, the same size), 325–417 mm off
root-relative there against 105–287 elsewhere.

A detector tells the two apart where it gives the feet and the face: a foot points the way its person faces
(heel → toes), the nose is in front of the ears. :func:`image_forward` sums those keypoints' image directions
(unit vectors weighted by the lesser confidence of each pair); :func:`facing_turns` compares them with the images of
f and f' at the mid-hips and gives the turn to f' where the detections' direction is nearer f''s by more than
:data:`MARGIN` in cosine. Measured on Shelf's annotated actors (every camera, the detections given to each actor by
the truth's projection): side-on (|l·r| > 0.7), the feet and the nose prefer the truth's facing over its reflection
in 99–100 % of frames; otherwise in 76–88 %, where the two facings' images are near each other anyway.
"""

from __future__ import annotations

import numpy as np
import torch

from priortrack.geometry import so3

#: The working frame's up: every filter's world is Y-up (:func:`~priortrack.geometry.frames.to_y_up`).
UP = np.array([0.0, 1.0, 0.0])
#: (base, tip) keypoint names whose image direction base → tip is the person's forward (the mean of those of each
#: the layout has and the detector saw): each foot's heel → its toes; the ears → the nose.
FORWARD_CUES = ((("left_heel",), ("left_big_toe", "left_small_toe", "left_foot_index")),
                (("right_heel",), ("right_big_toe", "right_small_toe", "right_foot_index")),
                (("left_ear", "right_ear"), ("nose",)))
#: How much nearer (in cosine) the detections' forward must be to the reflected facing's image than to the
#: current one's for :func:`facing_turns` to turn the body (set once from the cosines' range [−2, 2], not varied).
MARGIN = 0.5
#: The trunk's predicted pixels must be within this fraction of its image height (mid-shoulders to mid-hips) of
#: its detections for :func:`facing_turns` to turn it (set once, not varied: a tracked trunk is within 0.1, a filter
#: following no one or someone else is off by more than the trunk's height).
FIT_FRACTION = 0.25
#: eval15's hips and shoulders (left, right).
_HIPS, _SHOULDERS = (9, 12), (3, 6)
#: A direction shorter than this (pixels) says nothing.
_SHORTEST_PX = 1.0


def image_forward(keypoints: np.ndarray, names: tuple[str, ...], min_confidence: float) -> np.ndarray:
    """(..., 3) the image's forward direction of each detection of keypoints (..., K, 3) (x, y, confidence; NaN
    missing) of the layout ``names``: Σ w_i u_i over :data:`FORWARD_CUES` (u_i the unit image vector from the mean of
    a cue's base keypoints to the mean of its tips, w_i the least confidence among them; pairs below
    ``min_confidence`` or shorter than a pixel left out) in the first two, Σ w_i in the third (0: no cue)."""
    index = {name: i for i, name in enumerate(names)}
    out = np.zeros(keypoints.shape[:-2] + (3,))
    for base, tip in FORWARD_CUES:
        base, tip = [index[n] for n in base if n in index], [index[n] for n in tip if n in index]
        if not base or not tip:
            continue
        (b, b_weight), (t, t_weight) = _mean_point(keypoints[..., base, :], min_confidence), \
            _mean_point(keypoints[..., tip, :], min_confidence)
        v = t - b
        length = np.linalg.norm(v, axis=-1)
        weight = np.minimum(b_weight, t_weight)
        weight = np.where(np.isfinite(length) & (length > _SHORTEST_PX), weight, 0.0)
        out[..., :2] += weight[..., None] * np.divide(v, length[..., None], out=np.zeros_like(v),
                                                      where=weight[..., None] > 0)
        out[..., 2] += weight
    return out


def _mean_point(points: np.ndarray, min_confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """The mean (..., 2) of points (..., n, 3) at or above ``min_confidence`` (NaN where none) and their least
    confidence (..., ) (0 where none)."""
    confidence = np.nan_to_num(points[..., 2].astype(float), nan=0.0)
    kept = confidence >= max(min_confidence, np.finfo(float).tiny)
    count = kept.sum(-1)
    total = np.where(kept[..., None], np.nan_to_num(points[..., :2].astype(float)), 0.0).sum(-2)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count[..., None] > 0, total / count[..., None], np.nan)
    least = np.where(count > 0, np.where(kept, confidence, np.inf).min(-1), 0.0)
    return mean, least


def alone(z: np.ndarray) -> int | None:
    """The camera that alone sees a person in one frame's observation z (C, 15, ·) (eval15; NaN missing): the only
    camera with any joint, three of the four hips and shoulders among them; None otherwise. Where a second camera
    sees any joint it holds a depth a turn would contradict (Shelf's cameras 0, 4: turning wherever one camera alone
    saw the trunk cost actor 1 6 points of PCP)."""
    seen = np.isfinite(z[..., 0])
    cameras = np.flatnonzero(seen.any(axis=1))
    if len(cameras) != 1 or seen[cameras[0], list(_HIPS + _SHOULDERS)].sum() < 3:
        return None
    return int(cameras[0])


def facing_turns(J: np.ndarray, camera, forward: np.ndarray, detected: np.ndarray) -> np.ndarray:
    """(N,) the turn (radians, about :data:`UP`) that takes each body of joints J (N, 15, 3) from its facing to the
    reflected one (module docstring, :func:`reflection_turns`) where the detections' forward direction in
    ``camera``'s image, ``forward`` (3,) of :func:`image_forward`, is nearer the reflected facing's image than the
    body's own by more than :data:`MARGIN` in cosine, and the body's trunk fits its detected pixels there (``detected``
    (15, ≥ 2): the camera's eval15 detections, u and v first; NaN missing) within :data:`FIT_FRACTION` of the
    trunk's image height (the reversal keeps the trunk's pixels, so it is the question only where they fit: a
    filter off its person, given someone else's feet, is not turned); 0 elsewhere (no cue, no trunk, the camera on
    the trunk's line)."""
    out = np.zeros(len(J))
    if not forward[2] > 0:
        return out
    mid, across, reflected = _reflection(J, torch.as_tensor(camera.center).double().cpu().numpy())
    angles = _turns(across, reflected)
    cue = forward[:2] / max(np.linalg.norm(forward[:2]), np.finfo(float).tiny)
    own, other = (_image_directions(camera, mid, np.cross(line, UP)) @ cue for line in (across, reflected))
    turned = (other - own > MARGIN) & (angles != 0) & _fits(J, camera, detected[list(_HIPS + _SHOULDERS), :2])
    out[turned] = angles[turned]
    return out


def reflection_turns(J: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(...) the turn (radians, about :data:`UP`) of each body of joints J (..., 15, 3) from its line across the body
    l to that line reflected across the vertical plane through the camera's centre (3,) and the body's mid-hips,
    l' = l − 2 (l·r) r (module docstring); 0 where either is not defined."""
    return _turns(*_reflection(J, centre)[1:])


def _reflection(J: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mid-hips (..., 3) of joints J (..., 15, 3), their horizontal unit line across the body l and its reflection
    l' = l − 2 (l·r) r across the vertical plane through the camera's centre (3,) (r the horizontal unit ray to the
    mid-hips), NaN where not defined."""
    mid = J[..., list(_HIPS), :].mean(-2)
    across = (J[..., _HIPS[0], :] - J[..., _HIPS[1], :]) + (J[..., _SHOULDERS[0], :] - J[..., _SHOULDERS[1], :])
    across, ray = _flat(across), _flat(mid - centre)
    return mid, across, across - 2 * (across * ray).sum(-1, keepdims=True) * ray


def _turns(across: np.ndarray, reflected: np.ndarray) -> np.ndarray:
    """(...) the angle about :data:`UP` from each line to its reflection; 0 where not defined."""
    angle = np.arctan2((np.cross(across, reflected) * UP).sum(-1), (across * reflected).sum(-1))
    return np.where(np.isfinite(angle), angle, 0.0)


def _fits(J: np.ndarray, camera, trunk_px: np.ndarray) -> np.ndarray:
    """(N,) whether each body's hips and shoulders of J (N, 15, 3) project within :data:`FIT_FRACTION` of the
    detected trunk's image height (mid-shoulders to mid-hips) of their detections ``trunk_px`` (4, 2), on average
    over those detected."""
    detected = np.asarray(trunk_px, dtype=float)
    seen = np.isfinite(detected).all(-1)
    hips, shoulders = seen[:2], seen[2:]
    if not (hips.any() and shoulders.any()):
        return np.zeros(len(J), dtype=bool)
    height = np.linalg.norm(detected[2:][shoulders].mean(0) - detected[:2][hips].mean(0))
    points = torch.as_tensor(J[:, list(_HIPS + _SHOULDERS)], dtype=torch.float64)
    predicted = camera.project(points)[0].cpu().numpy()
    error = np.linalg.norm(predicted[:, seen] - detected[seen], axis=-1)
    return np.isfinite(error).all(-1) & (error.mean(-1) <= FIT_FRACTION * height)


def turned_placements(g: torch.Tensor, angles: torch.Tensor, pivots: torch.Tensor) -> torch.Tensor:
    """Placements g = (t, ω) (N, 6) (world = exp(ω) · body + t) each turned by its angle (N,) about :data:`UP`
    through its pivot (N, 3): exp(ω') = R exp(ω), t' = pivot + R (t − pivot), R = exp(angle · up); in g's dtype and
    on its device."""
    up = torch.as_tensor(UP, dtype=g.dtype, device=g.device)
    R = so3.exp(angles.to(g)[:, None] * up)
    pivots = pivots.to(g)
    t = pivots + ((g[:, :3] - pivots)[:, None, :] @ R.transpose(-1, -2))[:, 0]
    return torch.cat([t, so3.log(R @ so3.exp(g[:, 3:]))], -1)


def _flat(v: np.ndarray) -> np.ndarray:
    """v (..., 3) made horizontal and unit (NaN where it has no horizontal part)."""
    v = v - (v * UP).sum(-1, keepdims=True) * UP
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.linalg.norm(v, axis=-1, keepdims=True)
        return np.where(norm > 1e-9, v / norm, np.nan)


def _image_directions(camera, points: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(N, 2) the unit image direction of a short step from each of ``points`` (N, 3) along its direction (N, 3)
    through ``camera`` (NaN where either end is behind it)."""
    ends = torch.as_tensor(np.stack([points, points + 0.3 * directions], 1), dtype=torch.float64)
    uv = camera.project(ends)[0].cpu().numpy()
    d = uv[:, 1] - uv[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        return d / np.linalg.norm(d, axis=-1, keepdims=True)
