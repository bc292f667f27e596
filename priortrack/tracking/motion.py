"""A person's joints as independent constant-velocity points: the scene tracker's motion model for
association (which detection is whose), before each person's own filter tracks their body.

Each joint j has the state x_j = (p_j, v_j) ∈ R⁶ (position, metres; velocity, m/s), moved by white-noise
acceleration of standard deviation σ_a (Bar-Shalom's discrete white-noise acceleration model):

    x_j ← F x_j,   F = [[I, Δt I], [0, I]],   P_j ← F P_j Fᵀ + Q,   Q = σ_a² [[Δt⁴/4 I, Δt³/2 I], [Δt³/2 I, Δt² I]].

A detection of joint j in camera c, y (its undistorted normalised image point, (x, y) = (X_c/Z_c, Y_c/Z_c):
the lens's distortion is taken out once, :func:`~priortrack.geometry.triangulation.undistort_normalised`),
updates it by the extended Kalman filter: h(p) = ((R p + t)_x, (R p + t)_y) / (R p + t)_z,
H = [∂h/∂p, 0] (2 × 6) with ∂h/∂p = (R_{x,y} − h R_z) / (R p + t)_z, R = (σ_px / (f · confidence))² I₂
(f = √(fx fy), pixels to normalised units),

    S = H P Hᵀ + R,   K = P Hᵀ S⁻¹,   x ← x + K (y − h(p)),   P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ

(Joseph's form), with every camera's rows stacked (one linearisation at the prediction). The predicted
points and S of every joint in every camera are what the association cost reads
(:meth:`JointKalman.predicted`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from priortrack.geometry.camera import PinholeCamera

#: σ_a, m/s²: the joints' acceleration spread (a wrist in a brisk walk swings at about 10 m/s²).
ACCELERATION_STD = 10.0
#: A detection's pixel noise at confidence 1.
SIGMA_PX = 8.0
#: The starting spread of a joint's velocity, m/s.
START_VELOCITY_STD = 1.0


@dataclass(frozen=True)
class View:
    """A camera as the motion model reads it: R (3, 3), t (3,) (X_c = R X + t) and f = √(fx fy) pixels."""

    R: np.ndarray
    t: np.ndarray
    f: float

    @classmethod
    def of(cls, camera: PinholeCamera) -> "View":
        return cls(camera.R.double().numpy(), camera.t.double().numpy(), float(np.sqrt(camera.fx * camera.fy)))

    @property
    def centre(self) -> np.ndarray:
        """(3,) the camera's centre in the world, −Rᵀ t."""
        return -self.R.T @ self.t

    def rays(self, xy: np.ndarray) -> np.ndarray:
        """Unit world directions Rᵀ (x, y, 1) (..., 3) of normalised image points xy (..., 2) (NaN stays NaN)."""
        d = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1) @ self.R
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


class JointKalman:
    """The motion model of the module docstring for one person's J joints.

    Attributes:
        x: (J, 6) positions and velocities; P: (J, 6, 6) their covariances.
    """

    def __init__(self, joints: np.ndarray, velocity: np.ndarray | None = None, position_std: float = 0.05,
                 acceleration_std: float = ACCELERATION_STD, sigma_px: float = SIGMA_PX):
        joints = np.asarray(joints, dtype=np.float64)
        J = len(joints)
        velocity = np.zeros((J, 3)) if velocity is None else np.nan_to_num(np.asarray(velocity, dtype=np.float64))
        centre = np.nanmedian(joints, axis=0) if np.isfinite(joints).any() else np.zeros(3)
        unseen = ~np.isfinite(joints).all(axis=1)
        self.x = np.concatenate([np.where(unseen[:, None], centre, joints), velocity], axis=1)
        # a joint no view triangulated starts at the body's centre with a body-sized spread
        std = np.where(unseen, 0.5, position_std)
        self.P = np.zeros((J, 6, 6))
        self.P[:, :3, :3] = (std ** 2)[:, None, None] * np.eye(3)
        self.P[:, 3:, 3:] = START_VELOCITY_STD ** 2 * np.eye(3)
        self.acceleration_std, self.sigma_px = acceleration_std, sigma_px

    @property
    def joints(self) -> np.ndarray:
        """(J, 3) the joints' positions."""
        return self.x[:, :3]

    def predict(self, dt: float) -> None:
        """x ← F x, P ← F P Fᵀ + Q over dt seconds."""
        F = np.eye(6)
        F[:3, 3:] = dt * np.eye(3)
        q = self.acceleration_std ** 2
        Q = np.block([[dt ** 4 / 4 * np.eye(3), dt ** 3 / 2 * np.eye(3)], [dt ** 3 / 2 * np.eye(3), dt ** 2 * np.eye(3)]])
        self.x = self.x @ F.T
        self.P = F @ self.P @ F.T + q * Q

    def predicted(self, view: View) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The joints' normalised image points h(p) (J, 2), ∂h/∂p (J, 2, 3) and H P Hᵀ (J, 2, 2) in ``view``
        (NaN where a joint is not in front of it)."""
        Xc = self.joints @ view.R.T + view.t
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(Xc[:, 2] > 1e-6, Xc[:, 2], np.nan)
            h = Xc[:, :2] / z[:, None]
            H = (view.R[None, :2] - h[:, :, None] * view.R[2]) / z[:, None, None]
        return h, H, H @ self.P[:, :3, :3] @ np.swapaxes(H, 1, 2)

    def update(self, views: list[View], xy: list[np.ndarray], confidence: list[np.ndarray]) -> None:
        """The EKF update (module docstring) with the detections of several cameras: per view, xy (J, 2)
        normalised points (NaN where missing) and confidence (J,) (0 where missing). A joint a view does
        not show gets a zero row of H there (no information: its gain column is zero)."""
        if not views:
            return
        J = len(self.x)
        e, H, r2 = np.zeros((J, 2 * len(views))), np.zeros((J, 2 * len(views), 6)), np.ones((J, 2 * len(views)))
        for v, (view, y, c) in enumerate(zip(views, xy, confidence)):
            h, Hp, _ = self.predicted(view)
            seen = np.isfinite(y).all(axis=1) & (c > 0) & np.isfinite(h).all(axis=1)
            rows = slice(2 * v, 2 * v + 2)
            e[seen, rows] = (y - h)[seen]
            H[seen, rows, :3] = Hp[seen]
            r2[seen, rows] = ((self.sigma_px / (view.f * c[seen])) ** 2)[:, None]
        R = r2[..., None] * np.eye(2 * len(views))
        Ht = np.swapaxes(H, 1, 2)
        S = H @ self.P @ Ht + R
        K = np.swapaxes(np.linalg.solve(S, H @ self.P), 1, 2)             # P Hᵀ S⁻¹ (S, P symmetric), (J, 6, 2V)
        self.x = self.x + (K @ e[..., None])[..., 0]
        A = np.eye(6) - K @ H
        self.P = A @ self.P @ np.swapaxes(A, 1, 2) + K @ R @ np.swapaxes(K, 1, 2)
