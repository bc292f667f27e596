"""World frames: the priors learned from Y-up mocap; a calibration's world may have another up.

:func:`to_y_up` gives the rotation A (3, 3) with A·up = e_y, a proper rotation, taking a world
whose up is ``up`` (an axis "x", "y", "z", "-x", "-y", "-z", or a direction vector) to the Y-up
working frame (X_work = A X); a camera X_c = R X + t becomes X_c = (R Aᵀ) X_work + t.

Where a calibration gives no vertical (anipose's, caliscope's, FreeMoCap's world is camera 1's
frame), :func:`up_from_person` finds it from the person: the robust mean direction from the ankles'
midpoint to the neck over the trial's triangulated frames,

    up = normalise(Σ_t∈S normalise(neck_t − ½ (lankle_t + rankle_t))),

S the frames within 30° of the previous estimate (three trims from the plain mean: robust to the
frames a detector puts a foot on the wrong side, and the same in any turned world); from
the pelvis (mid-hips) to the neck where the person sits (the thighs' mean direction more than
:data:`SEATED_DEGREES` from the torso's: the feet are then forward of the body, ankles to neck
leans 20–30°) or fewer than :data:`MIN_UP_FRAMES` frames have both ankles.
"""

from __future__ import annotations

import logging

import numpy as np

from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera

log = logging.getLogger(__name__)

_AXES = {"x": np.array([1.0, 0, 0]), "y": np.array([0, 1.0, 0]), "z": np.array([0, 0, 1.0])}
#: The fewest triangulated frames "up" is taken from; the robust mean's trims and their cone.
MIN_UP_FRAMES = 10
TRIM_STEPS, TRIM_DEGREES = 3, 30.0
#: A person whose thighs (knee → hip, robust mean direction) are further than this from the torso's
#: (pelvis → neck) sits or crouches: up is the torso's direction, not the ankles'.
SEATED_DEGREES = 45.0


def up_vector(up: str | np.ndarray) -> np.ndarray:
    """(3,) unit vector of an axis name or a direction ("0,0,1" as text, a sequence or an array)."""
    if isinstance(up, str) and up.strip().lstrip("-") in _AXES and up.count("-") <= 1:
        up = up.strip()
        return -_AXES[up[1:]] if up.startswith("-") else _AXES[up].copy()
    try:
        vector = np.asarray([float(v) for v in up.split(",")] if isinstance(up, str) else up,
                            dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise PriortrackError(f"up {up!r} is neither one of x, y, z, -x, -y, -z nor a vector X,Y,Z") from None
    norm = float(np.linalg.norm(vector))
    if not np.isfinite(vector).all() or norm < 1e-9:
        raise PriortrackError(f"up {vector.tolist()} is not a direction")
    return vector / norm


def nearest_axis(up: str | np.ndarray) -> str:
    """The axis name ("y", "-z", …) nearest the direction ``up`` (a viewer's up)."""
    u = up_vector(up)
    k = int(np.argmax(np.abs(u)))
    return ("-" if u[k] < 0 else "") + "xyz"[k]


def to_y_up(up: str | np.ndarray) -> np.ndarray:
    """(3, 3) rotation A with A · up = e_y (the identity for "y"; for "z", Pose2Sim's world:
    x stays, z → y, y → −z; for a vector, the smallest rotation taking it to e_y)."""
    u = up_vector(up)
    y = _AXES["y"]
    if np.allclose(u, y):
        return np.eye(3)
    if np.allclose(u, -y):
        return np.diag([1.0, -1.0, -1.0])
    axis = np.cross(u, y)                     # a turn about u × y by the angle between them takes u to y
    sin, cos = float(np.linalg.norm(axis)), float(u @ y)
    axis /= sin
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + sin * cross + (1 - cos) * cross @ cross


def _robust_direction(d: np.ndarray) -> tuple[np.ndarray | None, int]:
    """The robust mean direction of the (N, 3) directions (NaN rows skipped; module docstring): the
    normalised mean of their unit vectors, recomputed :data:`TRIM_STEPS` times over those within
    :data:`TRIM_DEGREES` of it. None where fewer than :data:`MIN_UP_FRAMES` rows are usable."""
    ok = np.isfinite(d).all(axis=1) & (np.linalg.norm(np.nan_to_num(d), axis=1) > 1e-6)
    if ok.sum() < MIN_UP_FRAMES:
        return None, int(ok.sum())
    u = d[ok] / np.linalg.norm(d[ok], axis=1, keepdims=True)
    keep = np.ones(len(u), dtype=bool)
    for _ in range(TRIM_STEPS + 1):
        m = u[keep].mean(axis=0)
        if np.linalg.norm(m) < 1e-6:
            return None, int(ok.sum())
        m /= np.linalg.norm(m)
        keep = u @ m > np.cos(np.radians(TRIM_DEGREES))
        if keep.sum() < MIN_UP_FRAMES:
            break
    return m, int(ok.sum())


def up_from_person(X: np.ndarray) -> tuple[np.ndarray, str, int]:
    """The world's up from a person's triangulated eval15 joints X (T, 15, 3), NaN where unseen
    (module docstring): the (3,) unit vector, the segment used ("ankles to neck" or "pelvis to neck")
    and the number of frames it was taken over."""
    index = {n: i for i, n in enumerate(EVAL15_NAMES)}
    neck, pelvis = X[:, index["neck"]], X[:, index["pelvis"]]
    torso, frames = _robust_direction(neck - pelvis)
    thighs = [_robust_direction(X[:, index[f"{s}hip"]] - X[:, index[f"{s}knee"]])[0] for s in "lr"]
    thighs = [t for t in thighs if t is not None]
    seated = torso is not None and thighs and np.degrees(np.arccos(np.clip(np.mean(thighs, axis=0) @ torso
                                                                            / np.linalg.norm(np.mean(thighs, axis=0)),
                                                                            -1, 1))) > SEATED_DEGREES
    if not seated:
        whole, n = _robust_direction(neck - 0.5 * (X[:, index["lankle"]] + X[:, index["rankle"]]))
        if whole is not None:
            return whole, "ankles to neck", n
    if torso is not None:
        return torso, "pelvis to neck" + (" (seated: thighs across the torso)" if seated else ""), frames
    raise PriortrackError(f"the calibration gives no vertical and too few frames show the person's ankles or "
                          f"pelvis with the neck in two cameras (fewer than {MIN_UP_FRAMES}) to find it; "
                          f"give it (--up: an axis or a vector X,Y,Z)")


def in_working_frame(camera: PinholeCamera, A: np.ndarray) -> PinholeCamera:
    """The same camera seeing the working frame X_work = A X: R → R Aᵀ."""
    return PinholeCamera(camera.K, camera.R.double().numpy() @ A.T, camera.t, camera.width, camera.height,
                         camera.dist)
