"""Points seen by several calibrated cameras: undistortion and confidence-weighted DLT triangulation.

**Undistortion.** A pixel u = K (x_d, y_d, 1) is taken back to the normalised point (x, y) whose
distortion (:mod:`priortrack.geometry.camera`) gives (x_d, y_d), by the fixed-point iteration
OpenCV's ``undistortPoints`` uses,

    x ← (x_d − Δx(x, y)) / ρ(r²),   y ← (y_d − Δy(x, y)) / ρ(r²),

ρ = 1 + k1 r² + k2 r⁴ + k3 r⁶ the radial factor and Δ the tangential terms, from (x_d, y_d).

**DLT.** Each camera c that sees the point, with weight w_c (its detection confidence), adds the
rows w_c (x P_3 − P_1) and w_c (y P_3 − P_2), P = [R | t] (3 × 4) acting on the homogeneous
point; the point is the right singular vector of the smallest singular value of the stacked
(2C × 4) matrix (Hartley & Zisserman, Multiple View Geometry, §12.2). A point seen by fewer than
two cameras is NaN.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera

#: Fixed-point iterations of the undistortion (the residual falls by about |k1| r² per step).
UNDISTORT_STEPS = 20


def undistort_normalised(camera: PinholeCamera, uv: np.ndarray) -> np.ndarray:
    """(..., 2) pixels → (..., 2) normalised camera coordinates (x, y) = (X_c/Z_c, Y_c/Z_c), NaN stays NaN."""
    uv = np.asarray(uv, dtype=np.float64)
    K = camera.K.double().numpy()
    yd = (uv[..., 1] - K[1, 2]) / K[1, 1]
    xd = (uv[..., 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    if not camera.distorted:
        return np.stack([xd, yd], axis=-1)
    k1, k2, p1, p2, k3 = camera.dist.tolist()
    x, y = xd.copy(), yd.copy()
    for _ in range(UNDISTORT_STEPS):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        x = (xd - 2 * p1 * x * y - p2 * (r2 + 2 * x * x)) / radial
        y = (yd - p1 * (r2 + 2 * y * y) - 2 * p2 * x * y) / radial
    return np.stack([x, y], axis=-1)


#: Points triangulated together at most: a long recording's systems (2C × 4 each, and the SVD's work) in
#: pieces, so that memory does not grow with it (36,000 frames × 15 joints at once held 285 MB more).
CHUNK = 30_000


def _dlt(cameras: Sequence[PinholeCamera], uv: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(N, 3) points from uv (C, N, 2) and weights w (C, N) (:func:`triangulate`)."""
    return dlt_normalised(cameras, np.stack([undistort_normalised(c, uv[i]) for i, c in enumerate(cameras)]), w)


def dlt_normalised(cameras: Sequence[PinholeCamera], xy: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(N, 3) points from undistorted normalised coordinates xy (C, N, 2) (:func:`undistort_normalised`)
    and weights w (C, N): the DLT of the module docstring, NaN where fewer than two cameras see a point. A camera is
    anything with its world → camera R (3, 3) and t (3,), torch or numpy."""
    seen = np.isfinite(xy).all(axis=-1) & (w > 0)                                   # (C, N)
    w = np.where(seen, w, 0.0)
    xy = np.where(seen[..., None], xy, 0.0)
    rows = []
    for i, c in enumerate(cameras):
        R, t = (np.asarray(v.double().numpy() if hasattr(v, "double") else v, dtype=np.float64) for v in (c.R, c.t))
        P = np.concatenate([R, t[:, None]], axis=1)                                  # (3, 4)
        rows.append(w[i, :, None] * (xy[i, :, 0:1] * P[2] - P[0]))
        rows.append(w[i, :, None] * (xy[i, :, 1:2] * P[2] - P[1]))
    A = np.stack(rows, axis=1)                                                      # (N, 2C, 4)
    A = A / np.maximum(np.linalg.norm(A, axis=(1, 2), keepdims=True), 1e-300)      # conditioning
    _, _, Vt = np.linalg.svd(A)
    h = Vt[:, -1]                                                                   # (N, 4)
    with np.errstate(divide="ignore", invalid="ignore"):
        points = h[:, :3] / h[:, 3:4]
    points[seen.sum(axis=0) < 2] = np.nan
    return points


def triangulate(cameras: Sequence[PinholeCamera], uv: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Confidence-weighted DLT (module docstring).

    Args:
        cameras: C calibrated cameras.
        uv: (C, ..., 2) pixels, NaN where a camera does not see the point.
        weights: (C, ...) non-negative weights (confidences); None for equal weights.

    Returns:
        (..., 3) world points, NaN where fewer than two cameras see a point with weight > 0.
    """
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim < 2 or uv.shape[0] != len(cameras) or uv.shape[-1] != 2:
        raise PriortrackError(f"uv has shape {uv.shape}; expected ({len(cameras)}, ..., 2) for {len(cameras)} cameras")
    weights = np.ones(uv.shape[:-1]) if weights is None else np.asarray(weights, dtype=np.float64)
    if weights.shape != uv.shape[:-1] or not np.isfinite(weights).all() or (weights < 0).any():
        raise PriortrackError(f"weights must be finite, non-negative and of shape {uv.shape[:-1]}")
    shape = uv.shape[1:-1]
    uv, weights = uv.reshape(len(cameras), -1, 2), weights.reshape(len(cameras), -1)
    N = uv.shape[1]
    points = np.concatenate([_dlt(cameras, uv[:, s:s + CHUNK], weights[:, s:s + CHUNK])
                             for s in range(0, N, CHUNK)]) if N else np.zeros((0, 3))
    return points.reshape(shape + (3,))


#: Gauss–Newton rounds of :func:`robust_triangulate` after its start, and the central difference's step (metres) of
#: the projection's Jacobian in them.
ROBUST_ROUNDS, JACOBIAN_STEP = 6, 1e-6


def robust_triangulate(cameras: Sequence[PinholeCamera], uv: np.ndarray, weights: np.ndarray | None,
                       sigma_px: float, nu: float) -> np.ndarray:
    """:func:`triangulate` under the trackers' Student-t pixel noise (scale ``sigma_px``, ``nu`` degrees of freedom):
    a detection thrown far off (a detector's outlier) no longer drags the point towards its ray.

    Each point X minimises the Student-t's negative log-likelihood

        E(X) = Σ_c w_c ln(1 + d_c² / (ν σ²)),   d_c = ‖u_c − π_c(X)‖ (pixels, through camera c's distortion),

    w_c the detection's confidence. The start is the best, by E, of the DLT by every camera and, where three or more
    see the point, of each DLT leaving one camera out (a single outlier's camera is one of them); then
    :data:`ROBUST_ROUNDS` rounds of iteratively reweighted Gauss–Newton, each solving
    (Σ_c ρ_c J_cᵀ J_c) δ = Σ_c ρ_c J_cᵀ r_c with ρ_c = w_c / (ν σ² + d_c²) the Student-t's weight (Lange, Little &
    Taylor, JASA 84, 1989) and J_c = ∂π_c/∂X, a step kept only where it lowers E. Shapes as :func:`triangulate`."""
    uv = np.asarray(uv, dtype=np.float64)
    C = len(cameras)
    weights = np.ones(uv.shape[:-1]) if weights is None else np.asarray(weights, dtype=np.float64)
    if not (sigma_px > 0 and nu > 0):
        raise PriortrackError(f"robust triangulation needs sigma_px > 0 and nu > 0, got {sigma_px} and {nu}")
    points = triangulate(cameras, uv, weights)                                     # checks the shapes
    seen = np.isfinite(uv).all(axis=-1) & (weights > 0)                             # (C, ...)
    w = np.where(seen, weights, 0.0)
    scale = nu * sigma_px ** 2

    def projected(X: np.ndarray) -> np.ndarray:                                    # (C, ..., 2), NaN behind
        return np.stack([camera.project(np.nan_to_num(X)[..., None, :])[0][..., 0, :] for camera in cameras])

    def residuals(X: np.ndarray) -> np.ndarray:                                    # (C, ..., 2), 0 where unseen
        return np.where(seen[..., None], uv - projected(X), 0.0)

    def cost(X: np.ndarray) -> np.ndarray:
        d2 = np.nan_to_num((residuals(X) ** 2).sum(-1), nan=np.inf)
        return np.where(np.isfinite(X).all(-1), (w * np.log1p(d2 / scale)).sum(0), np.inf)

    best = cost(points)
    if C >= 3:
        for c in range(C):
            others = [k for k in range(C) if k != c]
            X = triangulate([cameras[k] for k in others], uv[others], weights[others])
            trial = cost(X)
            better = trial < best
            points[better], best[better] = X[better], trial[better]
    steps = np.eye(3) * JACOBIAN_STEP
    for _ in range(ROBUST_ROUNDS):
        r = residuals(points)
        rho = np.nan_to_num(w / (scale + (r ** 2).sum(-1)))                          # (C, ...)
        J = np.stack([(projected(points + e) - projected(points - e)) / (2 * JACOBIAN_STEP) for e in steps], -1)
        J, r = np.nan_to_num(J), np.nan_to_num(r)                                  # behind a camera: no pull
        A = np.einsum("c...,c...ki,c...kj->...ij", rho, J, J)
        b = np.einsum("c...,c...ki,c...k->...i", rho, J, r)
        solvable = np.isfinite(points).all(-1) & (np.linalg.det(A) > 1e-12 * np.abs(A).max(axis=(-1, -2)) ** 3)
        delta = np.zeros_like(points)
        delta[solvable] = np.linalg.solve(A[solvable], b[solvable][..., None])[..., 0]
        X = points + delta
        trial = cost(X)
        better = trial < best
        points[better], best[better] = X[better], trial[better]
    return points
