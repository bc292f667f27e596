"""World frames: the priors learned from Y-up mocap; a calibration's world may have another up axis.

:func:`to_y_up` gives the rotation A (3, 3) with A·up = e_y, a proper rotation, taking a world
whose up axis is ``up`` ("x", "y", "z", "-x", "-y", "-z") to the Y-up working frame
(X_work = A X); a camera X_c = R X + t becomes X_c = (R Aᵀ) X_work + t.
"""

from __future__ import annotations

import numpy as np

from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera

_AXES = {"x": np.array([1.0, 0, 0]), "y": np.array([0, 1.0, 0]), "z": np.array([0, 0, 1.0])}


def to_y_up(up: str) -> np.ndarray:
    """(3, 3) rotation A with A · up = e_y (the identity for "y"; for "z", Pose2Sim's world:
    x stays, z → y, y → −z)."""
    if not isinstance(up, str) or up.lstrip("-") not in _AXES or up.count("-") > 1:
        raise PriortrackError(f"up axis {up!r} is not one of x, y, z, -x, -y, -z")
    u = -_AXES[up[1:]] if up.startswith("-") else _AXES[up]
    y = _AXES["y"]
    if np.allclose(u, y):
        return np.eye(3)
    if np.allclose(u, -y):
        return np.diag([1.0, -1.0, -1.0])
    axis = np.cross(u, y)                     # a quarter turn about u × y takes u to y
    axis /= np.linalg.norm(axis)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + cross + cross @ cross


def in_working_frame(camera: PinholeCamera, A: np.ndarray) -> PinholeCamera:
    """The same camera seeing the working frame X_work = A X: R → R Aᵀ."""
    return PinholeCamera(camera.K, camera.R.double().numpy() @ A.T, camera.t, camera.width, camera.height,
                         camera.dist)
