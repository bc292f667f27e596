"""Pinhole camera with OpenCV axes (x right, y down, z forward).

World coordinates are metres with Y up; image coordinates are pixels with the
origin at the top-left corner, u to the right and v down.

A world point X (3,) maps to camera coordinates and pixels as

    X_c = R X + t                      (R world->camera rotation, t (3,) metres)
    [u', v', w']^T = K X_c,  u = u'/w', v = v'/w'

With K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]] this is the familiar
u = fx X_c/Z_c + s Y_c/Z_c + cx, v = fy Y_c/Z_c + cy, and w' = Z_c (the depth).

A camera with lens distortion (OpenCV's model, coefficients (k1, k2, p1, p2, k3)) distorts the
normalised point (x, y) = (X_c/Z_c, Y_c/Z_c) before K, with r² = x² + y²:

    x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)
    y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y
    u = fx x_d + s y_d + cx,  v = fy y_d + cy          (as cv2.projectPoints).
"""

from __future__ import annotations

import logging
import math
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from priortrack.data.calibration import CameraCalibration
from priortrack.errors import PriortrackError
from priortrack.kernels import cpu_kernel_applies

__all__ = ["PinholeCamera", "MIN_DEPTH"]

logger = logging.getLogger(__name__)

#: A point is "in front" of the camera when its depth Z_c exceeds this (metres).
MIN_DEPTH = 1e-6

_ROTATION_TOL = 1e-6


def _to_float64_numpy(value: Any, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """Convert ``value`` to a float64 numpy array of exactly ``shape`` or raise."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PriortrackError(
            f"{name}: expected a numeric array of shape {shape}, could not convert ({exc})"
        ) from None
    if arr.shape != shape:
        raise PriortrackError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise PriortrackError(f"{name}: expected finite values of shape {shape}, found NaN or inf")
    return arr


def _positive_int(value: Any, name: str) -> int:
    """Return ``value`` as a positive ``int`` or raise naming ``name``."""
    if isinstance(value, bool):
        raise PriortrackError(f"{name}: expected a positive integer number of pixels, got {value!r}")
    try:
        as_float = float(value)
    except (TypeError, ValueError):
        raise PriortrackError(
            f"{name}: expected a positive integer number of pixels, got {value!r}"
        ) from None
    if not math.isfinite(as_float) or as_float != int(as_float) or as_float <= 0:
        raise PriortrackError(f"{name}: expected a positive integer number of pixels, got {value!r}")
    return int(as_float)


class PinholeCamera:
    """A calibrated pinhole camera, X_c = R X + t, pixels = dehomogenise(K X_c).

    Attributes (torch tensors, float64 on CPU unless moved with :meth:`to`):
        K: (3, 3) intrinsics, upper triangular with K[2] = (0, 0, 1), fx, fy > 0.
        R: (3, 3) world->camera rotation (orthonormal, det +1).
        t: (3,) translation in metres, so that X_c = R X + t.
        width, height: image size in pixels (ints).

    Camera axes follow OpenCV: x right, y down, z forward (optical axis).

    Args:
        K, R, t: array-likes (numpy, torch, nested lists) of the shapes above.
        width, height: positive integers.

    Raises:
        PriortrackError: a wrong shape, non-finite entries, an invalid K
            (K[2] != (0, 0, 1), non-positive focal length, non-zero K[1, 0])
            or an R that is not a rotation to 1e-6 (||R R^T - I||_max, |det R - 1|).
    """

    __slots__ = ("K", "R", "t", "width", "height", "dist", "_P", "_p", "_cache")

    def __init__(self, K: Any, R: Any, t: Any, width: int = 1000, height: int = 1000, dist: Any = None) -> None:
        dist_np = np.zeros(5) if dist is None else np.asarray(dist, dtype=np.float64).reshape(-1)
        if len(dist_np) not in (4, 5):
            raise PriortrackError(f"dist: expected (k1, k2, p1, p2) or (k1, k2, p1, p2, k3), got {len(dist_np)} values")
        dist_np = _to_float64_numpy(np.concatenate([dist_np, np.zeros(5 - len(dist_np))]), "dist", (5,))
        K_np = _to_float64_numpy(K, "K", (3, 3))
        R_np = _to_float64_numpy(R, "R", (3, 3))
        t_np = _to_float64_numpy(t, "t", (3,))
        if not np.array_equal(K_np[2], [0.0, 0.0, 1.0]) or K_np[1, 0] != 0.0:
            raise PriortrackError(
                "K: expected (3, 3) intrinsics [[fx, s, cx], [0, fy, cy], [0, 0, 1]], "
                f"got {K_np.tolist()}"
            )
        if K_np[0, 0] <= 0 or K_np[1, 1] <= 0:
            raise PriortrackError(
                f"K: expected positive focal lengths fx = K[0,0], fy = K[1,1], got "
                f"{K_np[0, 0]}, {K_np[1, 1]}"
            )
        orth_err = float(np.max(np.abs(R_np @ R_np.T - np.eye(3))))
        det = float(np.linalg.det(R_np))
        if orth_err > _ROTATION_TOL or abs(det - 1.0) > _ROTATION_TOL:
            raise PriortrackError(
                "R: expected a (3, 3) rotation matrix (R R^T = I and det R = +1 to 1e-6), "
                f"got max|R R^T - I| = {orth_err:.3g}, det R = {det:.6g}"
            )
        self._set(
            torch.from_numpy(K_np),
            torch.from_numpy(R_np),
            torch.from_numpy(t_np),
            _positive_int(width, "width"),
            _positive_int(height, "height"),
            torch.from_numpy(dist_np),
        )

    def _set(self, K: torch.Tensor, R: torch.Tensor, t: torch.Tensor, width: int, height: int,
             dist: torch.Tensor) -> None:
        self.K = K
        self.R = R
        self.t = t
        self.width = width
        self.height = height
        #: (5,) OpenCV distortion (k1, k2, p1, p2, k3), float64; zeros for an ideal pinhole.
        self.dist = dist.double().cpu()
        # Full projection P = K R (3, 3) and p = K t (3,): homogeneous pixels = P X + p.
        # Computed in float64 whatever the storage dtype.
        K64, R64, t64 = K.double(), R.double(), t.double()
        self._P = (K64 @ R64).cpu()
        self._p = (K64 @ t64).cpu()
        #: (device, dtype) → P, p there (:meth:`projection`); ("kernel", dtype) → R, t, K, dist as numpy arrays.
        self._cache: dict[tuple[Any, Any], tuple] = {}

    # ------------------------------------------------------------------ constructors
    @classmethod
    def look_at(
        cls,
        eye: Sequence[float] | np.ndarray | torch.Tensor,
        target: Sequence[float] | np.ndarray | torch.Tensor,
        up: Sequence[float] | np.ndarray | torch.Tensor = (0.0, 1.0, 0.0),
        focal_px: float = 1000.0,
        width: int = 1000,
        height: int = 1000,
    ) -> "PinholeCamera":
        """A camera at ``eye`` (3,) looking at ``target`` (3,), world ``up`` (3,) shown up.

        The rows of R are the camera axes expressed in world coordinates:

            z_c = (target - eye) / |target - eye|         (forward)
            x_c = (z_c x up) / |z_c x up|                 (right)
            y_c = z_c x x_c                               (down; image v grows downwards)
            R = [x_c; y_c; z_c],  t = -R eye,
            K = [[f, 0, W/2], [0, f, H/2], [0, 0, 1]]      (principal point at the image centre)

        so the target projects to (W/2, H/2) and a point displaced along ``up``
        projects to a smaller v.

        Raises:
            PriortrackError: eye == target, ``up`` parallel to the viewing direction,
                non-positive ``focal_px``/``width``/``height`` or wrong shapes.
        """
        eye_np = _to_float64_numpy(eye, "eye", (3,))
        target_np = _to_float64_numpy(target, "target", (3,))
        up_np = _to_float64_numpy(up, "up", (3,))
        forward = target_np - eye_np
        dist = float(np.linalg.norm(forward))
        if dist < 1e-12:
            raise PriortrackError(f"eye, target: must differ, both are {eye_np.tolist()}")
        z_c = forward / dist
        right = np.cross(z_c, up_np)
        right_norm = float(np.linalg.norm(right))
        if right_norm < 1e-9 * max(1.0, float(np.linalg.norm(up_np))):
            raise PriortrackError(
                f"up: must not be parallel to the viewing direction target - eye = {forward.tolist()}, "
                f"got up = {up_np.tolist()}"
            )
        x_c = right / right_norm
        y_c = np.cross(z_c, x_c)
        R = np.stack([x_c, y_c, z_c])
        t = -R @ eye_np
        try:
            f = float(focal_px)
        except (TypeError, ValueError):
            raise PriortrackError(f"focal_px: expected a positive number, got {focal_px!r}") from None
        if not math.isfinite(f) or f <= 0:
            raise PriortrackError(f"focal_px: expected a positive number, got {focal_px!r}")
        w = _positive_int(width, "width")
        h = _positive_int(height, "height")
        K = np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])
        return cls(K, R, t, w, h)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "PinholeCamera":
        """Inverse of :meth:`to_dict`: keys K (3x3 lists), R (3x3), t (3), width, height, and
        optionally dist (k1, k2, p1, p2[, k3]).

        Raises:
            PriortrackError: ``data`` is not a mapping, a key is missing, or a value is invalid.
        """
        if not isinstance(data, Mapping):
            raise PriortrackError(
                f"data: expected a mapping with keys K, R, t, width, height, got {type(data).__name__}"
            )
        for key in ("K", "R", "t", "width", "height"):
            if key not in data:
                raise PriortrackError(
                    f"data: camera dictionary is missing key {key!r} (expected K, R, t, width, height)"
                )
        return cls(data["K"], data["R"], data["t"], data["width"], data["height"], data.get("dist"))

    @classmethod
    def from_calibration(cls, camera: "CameraCalibration") -> "PinholeCamera":
        """The camera of a calibration file (:mod:`priortrack.data.calibration`), distortion included."""
        return cls(camera.K, camera.R, camera.t, camera.size[0], camera.size[1], camera.dist)

    # ------------------------------------------------------------------ conversions
    def to_dict(self) -> dict[str, Any]:
        """Plain-Python form for JSON / npz metadata: lists of floats and ints.

        Returns ``{"K": 3x3 list, "R": 3x3 list, "t": 3-list, "width": int, "height": int,
        "dist": 5-list}``; values are exact float64 (``json`` round-trips them bit for bit).
        """
        return {
            "K": self.K.detach().double().cpu().tolist(),
            "R": self.R.detach().double().cpu().tolist(),
            "t": self.t.detach().double().cpu().tolist(),
            "width": int(self.width),
            "height": int(self.height),
            "dist": self.dist.tolist(),
        }

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> "PinholeCamera":
        """A copy with K, R, t on ``device`` and of ``dtype`` (None keeps the current one).

        The rotation check is not repeated (a float32 R need not pass 1e-6);
        projection always uses P = K R and p = K t computed in float64.
        """
        new = object.__new__(type(self))
        new._set(
            self.K.to(device=device, dtype=dtype),
            self.R.to(device=device, dtype=dtype),
            self.t.to(device=device, dtype=dtype),
            self.width,
            self.height,
            self.dist,
        )
        # Keep the float64 projection of the original (more precise than re-deriving it).
        new._P, new._p = self._P, self._p
        return new

    # ------------------------------------------------------------------ properties
    @property
    def center(self) -> torch.Tensor:
        """Camera centre in world coordinates, (3,): C = -R^T t (the point with X_c = 0)."""
        return -(self.R.transpose(0, 1) @ self.t)

    @property
    def fx(self) -> float:
        """Horizontal focal length K[0, 0] in pixels."""
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        """Vertical focal length K[1, 1] in pixels."""
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        """Principal point u coordinate K[0, 2] in pixels."""
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        """Principal point v coordinate K[1, 2] in pixels."""
        return float(self.K[1, 2])

    @property
    def distorted(self) -> bool:
        """Whether the camera has lens distortion (any coefficient non-zero)."""
        return bool(self.dist.any())

    # ------------------------------------------------------------------ projection
    def projection(self, device: torch.device, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
        """P = K R (3, 3) and p = K t (3,) (homogeneous pixels = P X + p) on ``device`` in ``dtype``."""
        key = (device, dtype)
        hit = self._cache.get(key)
        if hit is None:
            hit = (self._P.to(device=device, dtype=dtype), self._p.to(device=device, dtype=dtype))
            self._cache[key] = hit
        return hit

    def project(self, points: np.ndarray | torch.Tensor) -> tuple[np.ndarray | torch.Tensor, np.ndarray | torch.Tensor]:
        """Project world points to pixels.

        Args:
            points: (..., J, 3) world points in metres, numpy array or torch tensor
                (any leading batch dims; NaN allowed for missing points).

        Returns:
            uv: (..., J, 2) pixels, u = (P X + p)_0 / Z_c, v = (P X + p)_1 / Z_c with
                P = K R, p = K t and Z_c = (P X + p)_2 = (R X + t)_z the depth.
            in_front: (..., J) bool, Z_c > 1e-6.  Where False (behind the camera, on
                its plane, or a NaN input) uv is NaN.

        A numpy input gives numpy outputs (float32 stays float32, other dtypes give
        float64, computed in float64); a torch input gives torch outputs on the same
        device with the same floating dtype (integer tensors give float64).  The torch
        path is differentiable where in_front holds (no inf/NaN gradients leak from
        points behind the camera).

        Raises:
            PriortrackError: ``points`` does not have shape (..., J, 3).
        """
        if isinstance(points, torch.Tensor):
            return self._project_torch(points)[:2]
        try:
            arr = np.asarray(points)
        except (TypeError, ValueError) as exc:
            raise PriortrackError(f"points: expected a (..., J, 3) array, could not convert ({exc})") from None
        self._check_points_shape(arr.shape)
        out_dtype = np.float32 if arr.dtype == np.float32 else np.float64
        x = arr.astype(np.float64, copy=False)
        if self.distorted:
            uv, in_front, _ = self._project_torch(torch.from_numpy(np.ascontiguousarray(x)))
            return uv.numpy().astype(out_dtype, copy=False), in_front.numpy()
        P = self._P.numpy()
        p = self._p.numpy()
        h = x @ P.T + p  # (..., J, 3) homogeneous pixels
        z = h[..., 2]
        in_front = z > MIN_DEPTH
        z_safe = np.where(in_front, z, 1.0)
        uv = h[..., :2] / z_safe[..., None]
        uv = np.where(in_front[..., None], uv, np.nan)
        return uv.astype(out_dtype, copy=False), in_front

    def _project_torch(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`project` of a tensor, with the depth h_2 it divided by (1 where not in front)."""
        self._check_points_shape(tuple(points.shape))
        if not points.is_floating_point():
            points = points.to(torch.float64)
        if self.distorted and points.dtype in (torch.float32, torch.float64) and cpu_kernel_applies(points):
            return self._project_in_kernel(points)
        if self.distorted:
            uv, in_front, z_safe, _ = self._project_distorted(points, jacobian=False)
            return uv, in_front, z_safe
        P, p = self.projection(points.device, points.dtype)
        h = torch.addmm(p, points.reshape(-1, 3), P.transpose(0, 1)).view(points.shape)
        z = h[..., 2]
        in_front = z > MIN_DEPTH
        z_safe = torch.where(in_front, z, 1.0)
        uv = h[..., :2] / z_safe.unsqueeze(-1)
        uv = torch.where(in_front.unsqueeze(-1), uv, float("nan"))
        return uv, in_front, z_safe

    def _project_in_kernel(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`_project_distorted`'s projection of CPU float32/float64 points without gradients, by the fused
        kernel of :mod:`priortrack.geometry.projection_kernel`."""
        from priortrack.geometry.projection_kernel import project_distorted

        key = ("kernel", points.dtype)
        arrays = self._cache.get(key)
        if arrays is None:
            arrays = tuple(a.to(points.dtype).numpy().copy() for a in (self.R, self.t, self.K, self.dist))
            self._cache[key] = arrays
        flat = points.reshape(-1, 3).contiguous().numpy()
        uv = np.empty((len(flat), 2), dtype=flat.dtype)
        in_front, z_safe = np.empty(len(flat), dtype=np.bool_), np.empty(len(flat), dtype=flat.dtype)
        project_distorted(flat, *arrays, MIN_DEPTH, uv, in_front, z_safe)
        shape = points.shape[:-1]
        return (torch.from_numpy(uv).view(shape + (2,)), torch.from_numpy(in_front).view(shape),
                torch.from_numpy(z_safe).view(shape))

    def _project_distorted(self, points: torch.Tensor, jacobian: bool = True):
        """Pixels through the distortion model (module docstring), with the depth and the Jacobian
        ∂uv/∂X (..., J, 2, 3) = K₂ · ∂(x_d, y_d)/∂(x, y) · ∂(x, y)/∂X_c · R, K₂ = K[:2, :2] (None unless
        ``jacobian``: a projection alone skips it, about half the work)."""
        dtype, device = points.dtype, points.device
        R, t = self.R.to(device=device, dtype=dtype), self.t.to(device=device, dtype=dtype)
        K = self.K.to(device=device, dtype=dtype)
        k1, k2, p1, p2, k3 = self.dist.to(dtype).tolist()
        Xc = points @ R.T + t
        z = Xc[..., 2]
        in_front = z > MIN_DEPTH
        z_safe = torch.where(in_front, z, 1.0)
        x, y = Xc[..., 0] / z_safe, Xc[..., 1] / z_safe
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        uv = torch.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], dim=-1)
        uv = torch.where(in_front.unsqueeze(-1), uv, float("nan"))
        if not jacobian:
            return uv, in_front, z_safe, None
        g = k1 + r2 * (2 * k2 + 3 * k3 * r2)                                   # d radial / d r²
        D = torch.stack([torch.stack([radial + 2 * x * x * g + 2 * p1 * y + 6 * p2 * x,
                                      2 * x * y * g + 2 * p1 * x + 2 * p2 * y], -1),
                         torch.stack([2 * x * y * g + 2 * p1 * x + 2 * p2 * y,
                                      radial + 2 * y * y * g + 6 * p1 * y + 2 * p2 * x], -1)], -2)   # (..., 2, 2)
        zero = torch.zeros_like(x)
        inv_z = 1 / z_safe
        N = torch.stack([torch.stack([inv_z, zero, -x * inv_z], -1),
                         torch.stack([zero, inv_z, -y * inv_z], -1)], -2)                           # (..., 2, 3)
        return uv, in_front, z_safe, K[:2, :2] @ D @ N @ R

    def project_jacobian(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Pixels and their Jacobian with respect to the world point.

        For h = P X + p (P = K R, p = K t) and u = h_{0,1} / h_2:

            ∂u/∂X = (P_{0,1} − u P_2) / h_2   (2 × 3 per point).

        Args:
            points: (..., J, 3) world points, an array-like or torch tensor (integers as float64).

        Returns:
            uv (..., J, 2), jacobian (..., J, 2, 3) and in_front (..., J), torch tensors as
            :meth:`project` gives them (NaN where a point is not in front of the camera), in the
            points' floating dtype and on their device.

        Raises:
            PriortrackError: ``points`` does not have shape (..., J, 3).
        """
        points = torch.as_tensor(points)
        if self.distorted:
            self._check_points_shape(tuple(points.shape))
            uv, in_front, _, jacobian = self._project_distorted(
                points if points.is_floating_point() else points.to(torch.float64))
            return uv, jacobian, in_front
        uv, in_front, depth = self._project_torch(points)
        P, _ = self.projection(uv.device, uv.dtype)
        jacobian = (P[:2] - uv[..., :, None] * P[2]) / depth[..., None, None]
        return uv, jacobian, in_front

    @staticmethod
    def _check_points_shape(shape: tuple[int, ...]) -> None:
        if len(shape) < 2 or shape[-1] != 3:
            raise PriortrackError(f"points: expected shape (..., J, 3), got {tuple(shape)}")

    # ------------------------------------------------------------------ misc
    def __eq__(self, other: object) -> bool:
        """Exact equality of K, R, t (compared in float64 on CPU), width and height."""
        if not isinstance(other, PinholeCamera):
            return NotImplemented
        return (
            self.width == other.width
            and self.height == other.height
            and all(
                torch.equal(a.detach().double().cpu(), b.detach().double().cpu())
                for a, b in ((self.K, other.K), (self.R, other.R), (self.t, other.t), (self.dist, other.dist))
            )
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        c = self.center.detach().double().cpu().tolist()
        return (
            f"PinholeCamera(fx={self.fx:.6g}, fy={self.fy:.6g}, cx={self.cx:.6g}, cy={self.cy:.6g}, "
            f"center=({c[0]:.4g}, {c[1]:.4g}, {c[2]:.4g}), width={self.width}, height={self.height}, "
            f"dtype={self.K.dtype}, device={self.K.device})"
        )


def pixel_errors(camera: PinholeCamera, joints: np.ndarray, uv: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """(T, J) pixel distance between the projected joints (T, J, 3) and the detections (T, J, 2), NaN
    where a detection is not seen (confidence 0, NaN) or a joint is missing."""
    projected, _ = camera.project(np.nan_to_num(joints))
    seen = (confidence > 0) & np.isfinite(uv).all(axis=-1) & np.isfinite(joints).all(axis=-1)
    return np.where(seen, np.linalg.norm(projected - uv, axis=-1), np.nan)
