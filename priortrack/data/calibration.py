"""Camera calibrations: Pose2Sim's ``Calib.toml``, OpenCV-style JSON and YAML, intrinsics only.

Every reader gives a :class:`Calibration`: cameras in file order, each with

    K (3, 3) intrinsics, dist (5,) OpenCV distortion (k1, k2, p1, p2, k3), R (3, 3) world → camera
    rotation, t (3,) metres (X_c = R X + t), size (width, height) pixels,

and the world's up axis where the file says it ("z" for Pose2Sim, whose world is Z-up; "-y" for an
intrinsics-only file, whose world is the camera's own frame, y pointing down), else None (give it).

Formats:

- **Pose2Sim TOML** (``calibration.toml_write``): one table per camera with ``name``, ``size``
  (w, h), ``matrix`` (K), ``distortions`` (k1 k2 p1 p2), ``rotation`` (Rodrigues vector, world to
  camera), ``translation`` (metres), ``fisheye``; tables without ``matrix`` (``[metadata]``) are
  skipped. A fisheye camera is refused (its model is not OpenCV's pinhole one).
- **OpenCV JSON / YAML**: one camera as a mapping with ``K`` (or ``camera_matrix``), ``dist`` (or
  ``distortion_coefficients``, ``D``), ``R`` (3 × 3) or ``rvec`` (Rodrigues), ``t`` (or ``T``,
  ``tvec``), ``size`` (w, h) or ``image_width``/``image_height``, optional ``name``; several cameras
  as ``{"cameras": [...]}`` or a mapping of names to cameras; ``"up"`` optional. YAML written by
  ``cv2.FileStorage`` (``%YAML:1.0`` and ``!!opencv-matrix`` nodes) is read as well, including the
  multi-camera layout ``names: [...]`` with ``K_<name>``, ``dist_<name>``, ``R_<name>`` or
  ``Rot_<name>``, ``T_<name>``. A camera without R and t sits at the origin (intrinsics only).

Units: the translation is in metres (``translation_unit`` rescales a file in millimetres).
Every error names the file and the camera and field at fault.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from priortrack.errors import PriortrackError

UP_AXES = ("x", "y", "z", "-x", "-y", "-z")


@dataclass(frozen=True)
class CameraCalibration:
    """One camera: name, K (3, 3), dist (5,), R (3, 3), t (3,) metres, size (width, height) pixels."""

    name: str
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]


@dataclass(frozen=True)
class Calibration:
    """Cameras in file order, the world's up axis if the file says it, and the file."""

    cameras: tuple[CameraCalibration, ...]
    up: str | None
    source: str

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.cameras)


def rodrigues(rvec: np.ndarray) -> np.ndarray:
    """(3,) rotation vector ω → (3, 3) rotation exp([ω]ₓ) (Rodrigues' formula, as cv2.Rodrigues)."""
    theta = float(np.linalg.norm(rvec))
    if not np.isfinite(theta) or theta > 1e6:
        raise PriortrackError(f"rotation vector {np.asarray(rvec).tolist()} is not an angle-axis rotation")
    if theta < 1e-12:
        return np.eye(3)
    a = rvec / theta
    cross = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(theta) * cross + (1 - math.cos(theta)) * cross @ cross


def read_calibration(path: str | Path, translation_unit: float = 1.0) -> Calibration:
    """Read a calibration file (``.toml``: Pose2Sim; ``.json``; ``.yml``/``.yaml``: OpenCV)."""
    path = Path(path)
    if not path.is_file():
        raise PriortrackError(f"calibration file {path} does not exist")
    text = path.read_text(errors="replace")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        try:
            table = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise PriortrackError(f"{path}: not valid TOML ({exc})") from None
        cameras = [_pose2sim_camera(path, key, value, translation_unit) for key, value in table.items()
                   if isinstance(value, dict) and "matrix" in value]
        up = "z"
    elif suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise PriortrackError(f"{path}: not valid JSON ({exc})") from None
        cameras, up = _opencv_cameras(path, data, translation_unit)
    elif suffix in (".yml", ".yaml"):
        cameras, up = _opencv_cameras(path, _read_opencv_yaml(path, text), translation_unit)
    else:
        raise PriortrackError(f"{path}: unknown calibration format {suffix!r}; give a Pose2Sim .toml, "
                              f"an OpenCV-style .json or a .yml/.yaml")
    if not cameras:
        raise PriortrackError(f"{path}: no camera found (a camera needs its intrinsics K)")
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        raise PriortrackError(f"{path}: camera names repeat: {', '.join(names)}")
    if up is not None and up not in UP_AXES:
        raise PriortrackError(f"{path}: up axis {up!r} is not one of {', '.join(UP_AXES)}")
    return Calibration(tuple(cameras), up, str(path))


def _array(path: Path, camera: str, field: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PriortrackError(f"{path}: camera {camera!r}: {field} is not numeric ({value!r:.80})") from None
    if arr.size == int(np.prod(shape)):
        arr = arr.reshape(shape)
    if arr.shape != shape:
        raise PriortrackError(f"{path}: camera {camera!r}: {field} has shape {arr.shape}, expected {shape}")
    if not np.isfinite(arr).all():
        raise PriortrackError(f"{path}: camera {camera!r}: {field} contains NaN or inf")
    return arr


def _camera(path: Path, name: str, K, dist, R, rvec, t, size, translation_unit: float) -> CameraCalibration:
    """Checked CameraCalibration from raw fields (R or rvec; neither and no t: at the origin)."""
    K = _array(path, name, "K", K, (3, 3))
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        raise PriortrackError(f"{path}: camera {name!r}: K is not [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with "
                              f"fx, fy > 0: {K.tolist()}")
    dist = np.zeros(5) if dist is None else np.asarray(dist, dtype=np.float64).reshape(-1)
    if dist.size not in (4, 5, 8) or not np.isfinite(dist).all():
        raise PriortrackError(f"{path}: camera {name!r}: distortion must be 4 or 5 finite OpenCV coefficients "
                              f"(k1 k2 p1 p2 [k3]), got {dist.tolist()}")
    if dist.size == 8 and np.any(dist[5:]):
        raise PriortrackError(f"{path}: camera {name!r}: the rational distortion model (k4-k6) is not supported")
    dist = np.concatenate([dist[:5], np.zeros(max(0, 5 - dist.size))])
    if R is None and rvec is None and t is None:
        R, t = np.eye(3), np.zeros(3)
    elif (R is None and rvec is None) or t is None:
        raise PriortrackError(f"{path}: camera {name!r}: give both a rotation (R or rvec) and a translation t, "
                              f"or neither (intrinsics only)")
    if R is not None and np.size(R) == 3:                   # a rotation vector stored under R (EasyMocap's R_<name>)
        R, rvec = None, R
    R = rodrigues(_array(path, name, "rvec", rvec, (3,))) if R is None else _array(path, name, "R", R, (3, 3))
    if np.abs(R).max() > 1.0 + 1e-5 or np.abs(R @ R.T - np.eye(3)).max() > 1e-5 or abs(np.linalg.det(R) - 1) > 1e-5:
        raise PriortrackError(f"{path}: camera {name!r}: R is not a rotation matrix")
    t = _array(path, name, "t", t, (3,)) * translation_unit
    if size is None:
        raise PriortrackError(f"{path}: camera {name!r}: the image size (width, height) is missing")
    size_arr = _array(path, name, "size", size, (2,))
    if np.any(size_arr < 1) or np.any(size_arr != np.round(size_arr)):
        raise PriortrackError(f"{path}: camera {name!r}: size must be two positive whole numbers of pixels, "
                              f"got {size_arr.tolist()}")
    return CameraCalibration(str(name), K, dist, R, t, (int(size_arr[0]), int(size_arr[1])))


def _pose2sim_camera(path: Path, key: str, table: dict, translation_unit: float) -> CameraCalibration:
    name = str(table.get("name", key))
    if table.get("fisheye", False):
        raise PriortrackError(f"{path}: camera {name!r} is a fisheye camera; only OpenCV's pinhole model is supported")
    for field in ("rotation", "translation", "size"):
        if field not in table:
            raise PriortrackError(f"{path}: camera {name!r}: field {field!r} is missing")
    return _camera(path, name, table["matrix"], table.get("distortions"), None, table["rotation"],
                   table["translation"], table["size"], translation_unit)


_ALIASES = {"K": ("K", "camera_matrix", "matrix", "intrinsics"), "dist": ("dist", "distortion_coefficients", "D",
                                                                           "distortions"),
            "R": ("R", "Rot", "rotation_matrix"), "rvec": ("rvec", "rotation"), "t": ("t", "T", "tvec", "translation")}


def _field(camera: dict, field: str):
    return next((camera[k] for k in _ALIASES[field] if k in camera), None)


def _opencv_one(path: Path, name: str, camera: Any, translation_unit: float) -> CameraCalibration:
    if not isinstance(camera, dict):
        raise PriortrackError(f"{path}: camera {name!r} is not a mapping of fields")
    if _field(camera, "K") is None:
        raise PriortrackError(f"{path}: camera {name!r}: no intrinsics (K or camera_matrix)")
    size = camera.get("size")
    if size is None and "image_width" in camera and "image_height" in camera:
        size = (camera["image_width"], camera["image_height"])
    return _camera(path, str(camera.get("name", name)), _field(camera, "K"), _field(camera, "dist"),
                   _field(camera, "R"), _field(camera, "rvec"), _field(camera, "t"), size, translation_unit)


def _opencv_cameras(path: Path, data: Any, translation_unit: float) -> tuple[list[CameraCalibration], str | None]:
    if not isinstance(data, dict):
        raise PriortrackError(f"{path}: expected a mapping (one camera, 'cameras', or names to cameras)")
    up = data.get("up")
    if isinstance(data.get("cameras"), list):
        cameras = [_opencv_one(path, f"camera {i}", c, translation_unit) for i, c in enumerate(data["cameras"])]
    elif isinstance(data.get("names"), list):                 # the FileStorage multi-camera layout
        cameras = []
        for name in data["names"]:
            camera = {field: data[f"{key}_{name}"] for field, keys in _ALIASES.items() for key in keys
                      if f"{key}_{name}" in data}
            for key in ("size", "image_width", "image_height"):
                if f"{key}_{name}" in data:
                    camera[key] = data[f"{key}_{name}"]
            camera.setdefault("size", data.get("size"))
            cameras.append(_opencv_one(path, str(name), camera, translation_unit))
    elif _field(data, "K") is not None:
        cameras = [_opencv_one(path, str(data.get("name", "camera")), data, translation_unit)]
    else:
        cameras = [_opencv_one(path, str(name), c, translation_unit) for name, c in data.items()
                   if name != "up" and isinstance(c, dict)]
    if up is None and len(cameras) == 1 and np.array_equal(cameras[0].R, np.eye(3)) and not cameras[0].t.any():
        up = "-y"                                             # intrinsics only: the camera's own frame
    return cameras, up


def _read_opencv_yaml(path: Path, text: str) -> dict:
    """A YAML calibration, also as cv2.FileStorage writes it (``%YAML:1.0``, ``!!opencv-matrix``)."""
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    def matrix(loader, node):
        fields = loader.construct_mapping(node, deep=True)
        try:
            return np.asarray(fields["data"], dtype=np.float64).reshape(int(fields["rows"]), int(fields["cols"]))
        except (KeyError, ValueError, TypeError):
            raise PriortrackError(f"{path}: an opencv-matrix node lacks rows, cols or data") from None

    Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", matrix)
    text = re.sub(r"^%YAML:1\.0", "%YAML 1.1", text)          # FileStorage's header is not YAML 1.1 syntax
    try:
        data = yaml.load(text, Loader=Loader)
    except yaml.YAMLError as exc:
        raise PriortrackError(f"{path}: not valid YAML ({exc})") from None
    return data
