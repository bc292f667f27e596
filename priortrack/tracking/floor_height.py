"""A person's standing height from one camera and the floor: the size a single view cannot give, measured.

From one view a body twice the size at twice the depth projects to the same pixels, so the one-camera
tracker needs the person's height (``--height``) and, not given one, took a nominal adult's: a person 1.55 m
tall tracked as 1.70 m has every bone 10 % long, and the filter tilts each limb out of the image plane to fit
its shorter projection (on held-out walks through one camera, root-relative errors of 54–131 mm where the true
height gives 34–107). A calibration whose world has its origin on the floor (Pose2Sim's, the board laid on the
ground; ``floor`` otherwise) fixes the scale: the camera stands a known height h_c above the floor, and a
standing or walking person has a foot on it.

In the working frame (Y up, the floor at y = ``floor``), each tick's detected ankles a have rays r_a = Rᵀ (x_a,
y_a, 1) from the camera centre c (undistorted normalised points x, y), meeting the plane of a foot on the floor,
y = ``floor`` + :data:`~priortrack.body.ik.ANKLE_HEIGHT`, at

    p_a = c + d_a r_a,    d_a = (floor + ANKLE_HEIGHT − c_y) / r_a,y    (r_a,y < 0: the ray goes down);

a lifted foot's ray meets it beyond the foot. The body stands over f: the middle of the two points where they are
within :data:`FEET_APART_M` (both feet down: standing, or a short step), else the nearer (the foot on the floor).
The mid-shoulders' ray r_s is followed to the horizontal distance ρ = ‖f − c‖_h (a body is vertical; the optical
axis of a camera looking down is not, so one depth for feet and shoulders would place the shoulders too near: 0.4–0.6
m on the bench's cameras), giving their height above the floor

    Y_s = c_y − floor + (ρ / ‖r_s‖_h) r_s,y.

Over the ticks that show both shoulders and a foot, the median Y_s is the person's shoulder height, and their
standing height the one at which the template, scaled (:func:`~priortrack.body.ik.scaled_to_height`), has its
shoulders there (:func:`height_for_shoulders`): the body the filter is given. On the real-format bench's four
cameras and eight held-out walks (five CMU people), the estimate is within −0.7 to +3.6 % of the mocap skeleton's
standing height, −1.5 to +1.7 % of the height that puts the template's shoulders at the person's.

A calibration whose origin is not on the floor (a board held up, on a table) measures a wrong height; one outside
:data:`PLAUSIBLE_M` is refused (:func:`measured_height` says why and the caller takes the nominal height).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from priortrack.body.fk import ForwardKinematics
from priortrack.body.ik import ANKLE_HEIGHT, stature
from priortrack.body.layout import eval15_indices
from priortrack.data.skeleton import Skeleton
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.triangulation import undistort_normalised

#: eval15 joints: the shoulders and the ankles.
SHOULDERS, ANKLES = (3, 6), (11, 14)
#: Standing heights (metres) a measurement is taken at; outside, the floor is not where the calibration says.
PLAUSIBLE_M = (1.2, 2.2)
#: Two feet whose floor points are nearer than this (metres) both stand on the floor: the body is over their middle.
FEET_APART_M = 0.35
#: Ticks with a foot and both shoulders a measurement needs.
MIN_TICKS = 10


@dataclass(frozen=True)
class FloorHeight:
    """A standing height measured from the floor: ``height_m`` (the median tick's), ``ticks`` that measured it and
    the ticks' interquartile range ``iqr_m`` (2,), metres."""

    height_m: float
    ticks: int
    iqr_m: tuple[float, float]


def rest_heights(template: Skeleton, M: np.ndarray) -> tuple[float, float]:
    """The template's mid-shoulders' height above the floor and its standing height, metres, at rest (the detector's
    shoulders: M (15, 15) on its eval15 joints; the floor :data:`ANKLE_HEIGHT` below its lower ankle)."""
    rest = M @ ForwardKinematics(template, dtype=torch.float64)(np.zeros(template.num_channels))[
        eval15_indices(template)].numpy()
    return float(rest[list(SHOULDERS), 1].mean() - rest[list(ANKLES), 1].min() + ANKLE_HEIGHT), stature(template)


def height_for_shoulders(template: Skeleton, M: np.ndarray, shoulders: np.ndarray) -> np.ndarray:
    """The standing heights h (...) at which the template scaled to h (:func:`~priortrack.body.ik.scaled_to_height`:
    its ankle-to-head scaled, its ankle :data:`ANKLE_HEIGHT` above the floor) has its mid-shoulders ``shoulders`` (...)
    metres above the floor: h − a = (Y_s − a) (h₀ − a) / (Y₀ − a), a = ANKLE_HEIGHT, the template's own Y₀ and h₀."""
    Y0, h0 = rest_heights(template, M)
    a = ANKLE_HEIGHT
    return a + (np.asarray(shoulders, dtype=np.float64) - a) * (h0 - a) / (Y0 - a)


def shoulder_heights(camera: PinholeCamera, z: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """(T,) Y_s of the module docstring per tick of one camera's observations z (T, 15, 3) (pixels and confidence;
    0 or NaN: missing) through ``camera`` (the working frame: Y up, the floor at y = ``floor``); NaN where a tick
    shows no foot on the floor or not both shoulders, and all NaN where the camera is not above the ankles."""
    z = np.asarray(z, dtype=np.float64)
    T = len(z)
    out = np.full(T, np.nan)
    R = camera.R.double().numpy()
    c = camera.center.double().numpy()
    above = c[1] - floor - ANKLE_HEIGHT                                  # the camera over the ankles' plane
    if T == 0 or above <= 0:
        return out
    seen = np.isfinite(z).all(axis=-1) & (np.nan_to_num(z[..., 2]) > 0)
    xy = undistort_normalised(camera, z[..., :2])
    rays = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1) @ R          # (T, 15, 3) world, Rᵀ (x, y, 1)
    ankles = rays[:, list(ANKLES)]
    down = seen[:, list(ANKLES)] & (ankles[..., 1] < 0)
    depth = np.where(down, above / -np.where(down, ankles[..., 1], -1.0), np.inf)   # d of each ankle (T, 2)
    points = np.where(np.isfinite(depth)[..., None], depth[..., None] * ankles, np.nan)   # floor points − c (T, 2, 3)
    nearer = points[np.arange(T), np.argmin(depth, axis=1)]
    together = np.linalg.norm(points[:, 0, [0, 2]] - points[:, 1, [0, 2]], axis=-1) < FEET_APART_M
    foot = np.where(together[:, None], points.mean(axis=1), nearer)
    rho = np.linalg.norm(foot[:, [0, 2]], axis=-1)                       # f's horizontal distance
    r_s = rays[:, list(SHOULDERS)].mean(axis=1)
    level = np.linalg.norm(r_s[:, [0, 2]], axis=-1)
    ok = np.isfinite(depth).any(axis=1) & seen[:, list(SHOULDERS)].all(axis=1) & (level > 0)
    out[ok] = c[1] - floor + rho[ok] / level[ok] * r_s[ok, 1]
    return out


def measured_height(camera: PinholeCamera, z: np.ndarray, template: Skeleton, M: np.ndarray,
                    floor: float = 0.0) -> tuple[FloorHeight | None, str]:
    """The person's standing height (module docstring) from one camera's observations z (T, 15, 3) through
    ``camera`` (the working frame) for the ``template`` body (through the detector map M) and ""; or None and why
    not (too few ticks with a foot and both shoulders, a height outside :data:`PLAUSIBLE_M`)."""
    Y = shoulder_heights(camera, z, floor)
    Y = Y[np.isfinite(Y)]
    if len(Y) < MIN_TICKS:
        return None, (f"{len(Y)} ticks show a foot on the floor and both shoulders (the height needs "
                      f"{MIN_TICKS})")
    q1, height, q3 = height_for_shoulders(template, M, np.percentile(Y, [25, 50, 75])).tolist()
    if not PLAUSIBLE_M[0] <= height <= PLAUSIBLE_M[1]:
        return None, (f"the floor at {floor:g} m gives a standing height of {height:.2f} m, no adult's: is the "
                      f"calibration's origin on the floor (--floor)?")
    return FloorHeight(height, len(Y), (q1, q3)), ""
