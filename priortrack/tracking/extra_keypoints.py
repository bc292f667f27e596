"""The detector's keypoints beyond the 15 tracked joints (feet, face, hands), carried by the tracked body.

The filters track 15 joints; a detector gives more: BODY_25 and BODY_25B each foot's big toe, small
toe and heel and the face's nose, eyes and ears, MediaPipe its hands and mouth too. OpenSim's foot
markers need the toes and heels. Each extra keypoint k rides on a tracked joint p(k) (a foot's on its
ankle, a hand's on its wrist, the face's on the head: :func:`parent_joint`); its offset from it,

    o_t = X_{k,t} − P_{p(k),t}     (metres, world),

X_{k,t} the keypoint triangulated at frame t from the cameras that see it (Student-t robust: a
detector's outlier does not drag it), is smoothed over the frames by a Rauch–Tung–Striebel smoother
with a constant-velocity model per axis (white acceleration of spectral density q, measurement
variance σ²). In steady state that smoother is a cubic smoothing spline with response
1 / (1 + (f / f_c)⁴), f_c = (q / (σ² Δ))^{1/4} / 2π at frame interval Δ, so q = σ² Δ (2π f_c)⁴ is set
from the cut-off alone (the mean does not depend on σ): :data:`CUTOFF_HZ`, the low-pass Pose2Sim and
biomechanics apply to markers (:mod:`priortrack.tracking.lowpass`). The estimate is
X̂_{k,t} = P_{p(k),t} + ô_t; an offset over :data:`MAX_OFFSET_M` (no foot or face is that far from its
joint) is a detector's error and not measured; a frame more than :data:`MAX_GAP_S` from every measured
one has no estimate (NaN). With one camera nothing is triangulated and the extra keypoints are absent.
"""

from __future__ import annotations

import numpy as np

from priortrack.data.eval15 import EVAL15_MARKER_NAMES, EVAL15_NAMES
from priortrack.data.keypoints import EVAL15_PARTS, LAYOUTS
from priortrack.geometry.triangulation import robust_triangulate
from priortrack.tracking.resample import nearest_tick

#: The smoother's cut-off, Hz (Pose2Sim's default Butterworth cut-off for markers).
CUTOFF_HZ = 6.0
#: The farthest an extra keypoint lies from its joint, metres (a big toe from the ankle: some 0.2 m).
MAX_OFFSET_M = 0.35
#: The longest time, seconds, an offset is carried across frames that measured none.
MAX_GAP_S = 0.5
#: The smoother's starting variance, in units of the measurement variance.
DIFFUSE = 1e6
#: Keypoints that are a tracked joint's own definition in some layout (BODY_25's Neck and MidHip, BODY_25B's upper
#: neck): not extras.
_TRACKED_ALREADY = ("neck", "mid_hip", "upper_neck")


def extra_keypoints(layout: str) -> tuple[str, ...]:
    """The keypoints of ``layout`` that are none of the 15 joints' own (in the layout's order)."""
    used = {part for options in EVAL15_PARTS.values() for parts in options for part in parts if len(parts) == 1}
    return tuple(k for k in LAYOUTS[layout] if k not in used and k not in _TRACKED_ALREADY)


def parent_joint(keypoint: str) -> int:
    """The eval15 joint (index) a keypoint rides on: a foot's (toe, heel, foot index) its ankle, a hand's (pinky,
    index, thumb) its wrist, the face's (nose, eyes, ears, mouth) the head."""
    side = "l" if keypoint.startswith("left") or keypoint.endswith("left") else \
        "r" if keypoint.startswith("right") or keypoint.endswith("right") else ""
    if any(w in keypoint for w in ("toe", "heel", "foot")):
        return EVAL15_NAMES.index(f"{side}ankle")
    if any(w in keypoint for w in ("pinky", "index", "thumb")):
        return EVAL15_NAMES.index(f"{side}wrist")
    return EVAL15_NAMES.index("head")


def marker_name(keypoint: str) -> str:
    """A keypoint's marker name as Pose2Sim writes it: left_big_toe → LBigToe, right_heel → RHeel, nose → Nose."""
    words = keypoint.split("_")
    side = {"left": "L", "right": "R"}.get(words[0], "")
    return side + "".join(w.capitalize() for w in (words[1:] if side else words))


def rts_constant_velocity(measured: np.ndarray, dt: float, cutoff_hz: float = CUTOFF_HZ) -> np.ndarray:
    """Smoothed positions (T, N) of N independent coordinates measured (T, N) at interval ``dt`` (NaN: not measured)
    under a constant-velocity model (module docstring): the Kalman filter forward, the Rauch–Tung–Striebel pass
    back, σ = 1 and q = Δ (2π f_c)⁴. A coordinate starts, one step before the first frame, at its first measurement
    with velocity 0, both of variance :data:`DIFFUSE` (a diffuse start: the estimate is the data's, not the start's,
    and does not depend on σ)."""
    measured = np.asarray(measured, dtype=np.float64)
    T, N = measured.shape
    q = dt * (2 * np.pi * cutoff_hz) ** 4
    F = np.array([[1.0, dt], [0.0, 1.0]])
    Q = q * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    first = np.where(np.isfinite(measured).any(axis=0), np.argmax(np.isfinite(measured), axis=0), 0)
    x = np.stack([measured[first, np.arange(N)], np.zeros(N)], axis=1)                 # (N, 2)
    P = np.broadcast_to(np.diag([DIFFUSE, DIFFUSE]), (N, 2, 2)).copy()
    xs, Ps, xp, Pp = (np.empty((T, N, 2)), np.empty((T, N, 2, 2)), np.empty((T, N, 2)), np.empty((T, N, 2, 2)))
    for t in range(T):
        x, P = x @ F.T, F @ P @ F.T + Q                                                # predicted from t − 1 (or the start)
        xp[t], Pp[t] = x, P
        z = measured[t]
        seen = np.isfinite(z)
        if seen.any():
            S = P[seen, 0, 0] + 1.0
            K = P[seen, :, 0] / S[:, None]                                             # (n, 2)
            x[seen] = x[seen] + K * (z[seen] - x[seen, 0])[:, None]
            P[seen] = P[seen] - K[:, :, None] * P[seen, 0, :][:, None, :]
        xs[t], Ps[t] = x, P
    for t in range(T - 2, -1, -1):
        G = Ps[t] @ F.T @ np.linalg.inv(Pp[t + 1])                                     # (N, 2, 2)
        xs[t] = xs[t] + np.einsum("nij,nj->ni", G, xs[t + 1] - xp[t + 1])
        Ps[t] = Ps[t] + G @ (Ps[t + 1] - Pp[t + 1]) @ np.swapaxes(G, 1, 2)
    return xs[..., 0]


def carried(keypoints: np.ndarray, layout: str, cameras, joints: np.ndarray, fps: float, min_confidence: float,
            noise: tuple[float, float]) -> tuple[np.ndarray, tuple[str, ...]]:
    """The extra keypoints (F, E, 3) of ``layout`` at F frames (module docstring) and their marker names (E,).

    Args:
        keypoints: (C, F, K, 3) the person's detections at those frames (x, y, confidence; NaN where missing).
        cameras: the C cameras in ``joints``' world; joints (F, 15, 3) the tracked joints there (NaN: absent).
        fps: the frames' rate; min_confidence: below it a keypoint is missing; noise: (σ px, ν) of the triangulation's
            Student-t.
    """
    extras = extra_keypoints(layout)
    E, F = len(extras), len(joints)
    out = np.full((F, E, 3), np.nan)
    names = tuple(marker_name(k) for k in extras)
    if not E or len(cameras) < 2 or not F:
        return out, names
    index = [LAYOUTS[layout].index(k) for k in extras]
    kp = np.asarray(keypoints, dtype=np.float64)[:, :, index]                       # (C, F, E, 3)
    confidence = np.nan_to_num(kp[..., 2])
    seen = np.isfinite(kp[..., :2]).all(axis=-1) & (confidence >= min_confidence) & (confidence > 0)
    uv = np.where(seen[..., None], kp[..., :2], np.nan)
    X = robust_triangulate(cameras, uv, np.where(seen, confidence, 0.0), *noise)     # (F, E, 3)
    parents = joints[:, [parent_joint(k) for k in extras]]                           # (F, E, 3)
    offset = X - parents
    with np.errstate(invalid="ignore"):
        offset[np.linalg.norm(offset, axis=-1) > MAX_OFFSET_M] = np.nan
    smoothed = rts_constant_velocity(offset.reshape(F, -1), 1.0 / fps).reshape(F, E, 3)
    measured = np.isfinite(offset).all(axis=-1)                                      # (F, E)
    frames = np.arange(F)
    for e in range(E):
        hits = np.flatnonzero(measured[:, e])
        if not len(hits):
            smoothed[:, e] = np.nan
            continue
        gap = np.abs(frames - hits[nearest_tick(hits, frames)])                        # to the nearest measured
        smoothed[gap > MAX_GAP_S * fps, e] = np.nan
    out[:] = parents + smoothed
    return out, names
