"""Joint angles a biomechanist reads, from tracked 3D joints and the detector's foot keypoints (degrees).

Geometric, from the points themselves, as markerless pipelines compute them (Sports2D's joint angles), not an
OpenSim model's inverse kinematics: no model, no markers placed on one. Frames, for joints (F, 15, 3) in any
world (metres):

- the pelvis frame: r̂ the right hip from the left hip, û the mid-shoulders from the mid-hips made orthogonal to
  r̂, f̂ = û × r̂ forward (a person facing −z with y up and x to their right: f̂ = −z); the trunk frame the same with
  r̂ the right shoulder from the left.
- ``hip_flexion`` = atan2(d·f̂, −d·û) of the thigh d = knee − hip in the pelvis frame (0 hanging, + knee forward);
  ``hip_adduction`` = atan2(∓d·r̂, −d·û) (+ towards the midline: − for the right side, + for the left).
- ``knee_flexion`` = 180° − ∠(hip − knee, ankle − knee), 0 straight: on a one-axis knee it is the joint's own angle
  (CMU's ASF tibia rx, exactly); ``elbow_flexion`` = 180° − ∠(shoulder − elbow, wrist − elbow) likewise.
- ``ankle_dorsiflexion`` = 90° − ∠(knee − ankle, big toe − heel): 0 foot square to the shank, + toes up; NaN
  without the foot's keypoints.
- ``shoulder_flexion`` = atan2(a·f̂, −a·û), ``shoulder_abduction`` = atan2(±a·r̂, −a·û) of the upper arm
  a = elbow − shoulder in the trunk frame (+ away from the body).

Each is given for the right (``_r``) and the left (``_l``) side, NaN where a point it needs is missing, and a
planar angle NaN where the segment lies within ``OUT_OF_PLANE_DEG`` of that plane's normal (an arm straight out to
the side has no flexion: the decomposition's gimbal).
"""

from __future__ import annotations

import numpy as np

from priortrack.data.eval15 import EVAL15_NAMES

_J = {n: i for i, n in enumerate(EVAL15_NAMES)}
#: A segment within this many degrees of a plane's normal has no angle in that plane (NaN).
OUT_OF_PLANE_DEG = 10.0
#: The angles, in the order they are returned (each then suffixed _r and _l).
ANGLES = ("hip_flexion", "hip_adduction", "knee_flexion", "ankle_dorsiflexion", "shoulder_flexion",
          "shoulder_abduction", "elbow_flexion")


def _unit(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame(left: np.ndarray, right: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, ...]:
    """(r̂, û, f̂), each (F, 3): right from ``left`` to ``right``, up from ``low`` to ``high`` orthogonal to it."""
    r = _unit(right - left)
    up = high - low
    u = _unit(up - np.sum(up * r, axis=-1, keepdims=True) * r)
    return r, u, np.cross(u, r)


def _between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angle (F,) between vectors a and b (F, 3), degrees."""
    return np.degrees(np.arccos(np.clip(np.sum(_unit(a) * _unit(b), axis=-1), -1.0, 1.0)))


def _in_plane(d: np.ndarray, along: np.ndarray, down: np.ndarray) -> np.ndarray:
    """atan2(d·along, d·down) in degrees, NaN where d lies within :data:`OUT_OF_PLANE_DEG` of the plane's normal
    (an arm held straight out to the side has no flexion)."""
    a, b = np.sum(d * along, axis=-1), np.sum(d * down, axis=-1)
    with np.errstate(invalid="ignore"):
        shown = np.hypot(a, b) >= np.sin(np.radians(OUT_OF_PLANE_DEG)) * np.linalg.norm(d, axis=-1)
    return np.where(shown, np.degrees(np.arctan2(a, b)), np.nan)


def joint_angles(joints: np.ndarray, heels: np.ndarray | None = None, toes: np.ndarray | None = None) -> dict:
    """{name_side: (F,) degrees} (module docstring) of eval15 ``joints`` (F, 15, 3); ``heels`` and ``toes`` (F, 2, 3)
    the left and right heel and big toe (NaN where missing; None: no ankle angle)."""
    X = np.asarray(joints, dtype=np.float64)
    pelvis = _frame(X[:, _J["lhip"]], X[:, _J["rhip"]], X[:, _J["pelvis"]], X[:, _J["neck"]])
    trunk = _frame(X[:, _J["lshoulder"]], X[:, _J["rshoulder"]], X[:, _J["pelvis"]], X[:, _J["neck"]])
    out = {}
    for name in ANGLES:
        for side, s, sign in (("r", "r", -1.0), ("l", "l", 1.0)):
            hip, knee, ankle = (X[:, _J[s + j]] for j in ("hip", "knee", "ankle"))
            shoulder, elbow, wrist = (X[:, _J[s + j]] for j in ("shoulder", "elbow", "wrist"))
            if name == "hip_flexion":
                value = _in_plane(knee - hip, pelvis[2], -pelvis[1])
            elif name == "hip_adduction":
                value = _in_plane(knee - hip, sign * pelvis[0], -pelvis[1])
            elif name == "knee_flexion":
                value = 180.0 - _between(hip - knee, ankle - knee)
            elif name == "ankle_dorsiflexion":
                k = 0 if s == "l" else 1
                value = (np.full(len(X), np.nan) if heels is None or toes is None else
                         90.0 - _between(knee - ankle, toes[:, k] - heels[:, k]))
            elif name == "shoulder_flexion":
                value = _in_plane(elbow - shoulder, trunk[2], -trunk[1])
            elif name == "shoulder_abduction":
                value = _in_plane(elbow - shoulder, -sign * trunk[0], -trunk[1])
            else:
                value = 180.0 - _between(shoulder - elbow, wrist - elbow)
            out[f"{name}_{side}"] = value
    return out
