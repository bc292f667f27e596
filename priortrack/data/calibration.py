"""Camera calibrations as the tools our users come from write them, recognised from the content.

Every reader gives a :class:`Calibration`: cameras in file order, each with

    K (3, 3) intrinsics, dist (5,) OpenCV distortion (k1, k2, p1, p2, k3), R (3, 3) world → camera
    rotation, t (3,) metres (X_c = R X + t), size (width, height) pixels,

the world's up direction where the file gives one ("z" for Pose2Sim, whose world is Z-up; "-y" for
an intrinsics-only file, whose world is the camera's own frame, y pointing down; a (3,) vector where
it is measured, as mmhuman3d's floor), else None (found from the person, or given), the format's
name, and the unit the translations were read in.

Formats (:mod:`priortrack.data.calibration_formats` has the table): Pose2Sim, anipose/FreeMoCap,
caliscope (``camera_array.toml`` and ``config.toml``), mmhuman3d, CMU Panoptic, VoxelPose, 4D Association
(``K``, ``RT``, ``imgSize``), Qualisys ``.qca.txt`` (as Pose2Sim reads it), and OpenCV-style JSON / YAML: one camera as a mapping with ``K`` (or ``camera_matrix``), ``dist`` (or
``distortion_coefficients``, ``D``), ``R`` (3 × 3) or ``rvec`` (Rodrigues), ``t`` (or ``T``,
``tvec``), ``size`` (w, h) or ``image_width``/``image_height``, optional ``name``; several cameras
as ``{"cameras": [...]}`` or a mapping of names to cameras; ``"up"`` and ``"units"`` optional. YAML
written by ``cv2.FileStorage`` (``%YAML:1.0`` and ``!!opencv-matrix`` nodes) is read as well,
including the multi-camera layout ``names: [...]`` with ``K_<name>``, ``dist_<name>``, ``R_<name>``
or ``Rot_<name>``, ``T_<name>``. A camera without rotation and translation sits at the origin.

**Rotations** orthonormal only to a tolerance (a file storing 6–7 digits) are projected onto SO(3)
(the nearest rotation, U Vᵀ of the SVD): silently below :data:`ROTATION_EXACT`, logged up to
:data:`ROTATION_TOLERANCE`, refused past it with the figure; a reflection (det < 0) is refused.

**Units**: ``units=`` (``--units``) forces them; else a unit the file states (a ``"units"`` field,
Panoptic's centimetres); else they are inferred from the camera layout and logged: camera centres
whose median distance apart (or from the origin, for one camera) exceeds :data:`MM_SPREAD` are
millimetres (no rig has cameras 50 m apart; none has them 5 cm apart either). A format whose
documents say metres is checked the same way: a layout that says millimetres wins, with a warning.

Every error names the file and the camera and, in words a user knows, the field at fault.
"""

from __future__ import annotations

import json
import logging
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from priortrack.data.calibration_formats import (Layout, RawCamera, is_qualisys, json_layout, qualisys_layout,
                                                 toml_layout)
from priortrack.errors import PriortrackError

log = logging.getLogger(__name__)

UP_AXES = ("x", "y", "z", "-x", "-y", "-z")
#: Translation units, in metres.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
#: max|R Rᵀ − I| below which a rotation is taken as it is; up to which it is projected onto SO(3).
ROTATION_EXACT, ROTATION_TOLERANCE = 1e-9, 1e-3
#: Camera spread (median distance between centres, file units) past which the file is in millimetres.
MM_SPREAD = 50.0


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
    """Cameras in file order; the world's up (an axis name of :data:`UP_AXES`, a (3,) unit vector, or
    None where the file gives no vertical); the file; its format's name; the unit read."""

    cameras: tuple[CameraCalibration, ...]
    up: str | np.ndarray | None
    source: str
    format: str = "OpenCV"
    units: str = "m"

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.cameras)

    @property
    def centres(self) -> np.ndarray:
        """(C, 3) camera centres in the world, metres: −Rᵀ t."""
        return np.array([-c.R.T @ c.t for c in self.cameras]).reshape(-1, 3)


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


def read_calibration(path: str | Path, units: str | None = None) -> Calibration:
    """Read a calibration file, its format recognised from the content (module docstring);
    ``units`` ("m", "cm", "mm") forces the translations' unit."""
    path = Path(path)
    if units is not None and units not in UNITS:
        raise PriortrackError(f"units {units!r}: give one of {', '.join(UNITS)}")
    if not path.is_file():
        raise PriortrackError(f"calibration file {path} does not exist")
    with np.errstate(over="ignore", invalid="ignore"):     # absurd numbers are refused below, by name
        return _read(path, units)


def _read(path: Path, units: str | None) -> Calibration:
    layout = _layout(path, path.read_text(errors="replace"))
    if not layout.cameras:
        raise PriortrackError(f"{path}: no camera found (a camera needs its intrinsic matrix K)")
    names = [c.name for c in layout.cameras]
    if len(set(names)) != len(names):
        raise PriortrackError(f"{path}: camera names repeat: {', '.join(names)}")
    unit = units or _units(path, layout)
    cameras = tuple(_camera(path, raw, UNITS[unit]) for raw in layout.cameras)
    projected = {raw.name: e for raw in layout.cameras if (e := _orthonormality(raw.rotation)) > ROTATION_EXACT}
    if projected:
        log.info("%s: rotations orthonormal only to %.2g (%s): each projected onto the nearest rotation", path,
                 max(projected.values()), ", ".join(projected))
    log.info("%s: %s, %d camera%s, translations in %s", path, layout.format, len(cameras),
             "s" if len(cameras) != 1 else "", {"m": "metres", "cm": "centimetres", "mm": "millimetres"}[unit])
    return Calibration(cameras, _up(path, layout.up), str(path), layout.format, unit)


def _layout(path: Path, text: str) -> Layout:
    suffix = path.suffix.lower()
    if suffix == ".toml":
        try:
            return toml_layout(path, tomllib.loads(text))
        except tomllib.TOMLDecodeError as exc:
            raise PriortrackError(f"{path}: not valid TOML ({exc})") from None
    if suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise PriortrackError(f"{path}: not valid JSON ({exc})") from None
        return json_layout(path, data) or _opencv_layout(path, data)
    if suffix in (".yml", ".yaml"):
        return _opencv_layout(path, _read_opencv_yaml(path, text))
    if suffix in (".txt", ".qca", ".xml") and is_qualisys(text):
        return qualisys_layout(path, text)
    raise PriortrackError(f"{path}: unknown calibration format {suffix!r}; give a .toml (Pose2Sim, anipose, "
                          f"FreeMoCap, caliscope), a .json (OpenCV-style, mmhuman3d, Panoptic, VoxelPose, 4D "
                          f"Association), a .yml/.yaml (OpenCV) or a Qualisys .qca.txt")


def _up(path: Path, up: Any) -> str | np.ndarray | None:
    if up is None or (isinstance(up, str) and up in UP_AXES):
        return up
    try:
        vector = np.asarray(up, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise PriortrackError(f"{path}: up {up!r} is neither one of {', '.join(UP_AXES)} nor a 3-vector") from None
    if not np.isfinite(vector).all() or np.linalg.norm(vector) < 1e-9:
        raise PriortrackError(f"{path}: up {vector.tolist()} is not a direction")
    return vector / np.linalg.norm(vector)


def _units(path: Path, layout: Layout) -> str:
    """The translations' unit: the file's or format's (checked against the layout), else inferred."""
    spread = _spread(layout.cameras)
    inferred = None if spread is None else ("mm" if spread > MM_SPREAD else "m")
    if layout.units is not None and not layout.units_documented:
        return layout.units
    if layout.units is not None:
        if inferred == "mm" and layout.units == "m":
            log.warning("%s: %s files are in metres, but the cameras are %.0f apart: read as millimetres "
                        "(--units m forces metres)", path, layout.format, spread)
            return "mm"
        return layout.units
    if inferred is None:
        return "m"
    log.info("%s: the file does not state its unit; cameras %.3g apart: read as %s (--units forces one)", path,
             spread, "millimetres" if inferred == "mm" else "metres")
    return inferred


def _spread(cameras: list[RawCamera]) -> float | None:
    """Median distance between the camera centres (one camera: from the origin), file units; None
    where no camera has a usable translation."""
    centres = []
    for raw in cameras:
        try:
            t = np.asarray(raw.translation, dtype=np.float64).reshape(3)
            R = _rotation_matrix(raw.rotation)
        except (TypeError, ValueError, PriortrackError):
            continue
        if not (np.isfinite(t).all() and np.isfinite(R).all()):
            continue
        centres.append(t if raw.direction != "world_to_camera" else -R.T @ t)
    if not centres:
        return None
    C = np.array(centres)
    if len(C) == 1:
        distance = float(np.linalg.norm(C[0]))
        return distance if distance > 0 else None
    i, j = np.triu_indices(len(C), 1)
    return float(np.median(np.linalg.norm(C[i] - C[j], axis=1)))


def _rotation_matrix(rotation: Any) -> np.ndarray:
    """A Rodrigues vector or a (nested or flat) 3 × 3 matrix, unchecked."""
    arr = np.asarray(rotation, dtype=np.float64)
    return rodrigues(arr.reshape(3)) if arr.size == 3 else arr.reshape(3, 3)


def _array(path: Path, camera: str, field: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PriortrackError(f"{path}: camera {camera!r}: the {field} is not numeric ({value!r:.80})") from None
    if arr.size == int(np.prod(shape)):
        arr = arr.reshape(shape)
    if arr.shape != shape:
        raise PriortrackError(f"{path}: camera {camera!r}: the {field} has shape {arr.shape}, expected {shape}")
    if not np.isfinite(arr).all():
        raise PriortrackError(f"{path}: camera {camera!r}: the {field} contains NaN or inf")
    return arr


def _rotation(path: Path, name: str, rotation: Any) -> np.ndarray:
    """The checked world → camera rotation of a Rodrigues vector or a 3 × 3 matrix: a matrix off
    SO(3) by more than :data:`ROTATION_EXACT` is projected onto it (logged), by more than
    :data:`ROTATION_TOLERANCE` refused."""
    if np.size(np.asarray(rotation, dtype=object)) == 3:
        rvec = _array(path, name, "rotation (Rodrigues vector)", rotation, (3,))
        if np.linalg.norm(rvec) > 1e6:
            raise PriortrackError(f"{path}: camera {name!r}: the rotation vector {rvec.tolist()} is not an angle-axis "
                                  f"rotation")
        return rodrigues(rvec)
    R = _array(path, name, "rotation matrix", rotation, (3, 3))
    error = float(np.abs(R @ R.T - np.eye(3)).max())
    if np.linalg.det(R) <= 0:
        raise PriortrackError(f"{path}: camera {name!r}: the rotation matrix has determinant {np.linalg.det(R):.3g}: "
                              f"a reflection or degenerate, not a rotation")
    if error > ROTATION_TOLERANCE:
        raise PriortrackError(f"{path}: camera {name!r}: the rotation matrix is not a rotation (max|R Rᵀ − I| = "
                              f"{error:.3g}, more than the {ROTATION_TOLERANCE:g} a file's rounding explains)")
    if error > ROTATION_EXACT:                          # the nearest rotation (as cv2.Rodrigues takes it)
        U, _, Vt = np.linalg.svd(R)
        R = U @ Vt
    return R


def _orthonormality(rotation: Any) -> float:
    """max|R Rᵀ − I| of a file's 3 × 3 rotation (0 for a Rodrigues vector or none)."""
    if rotation is None or np.size(np.asarray(rotation, dtype=object)) != 9:
        return 0.0
    R = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
    return float(np.abs(R @ R.T - np.eye(3)).max())


def _camera(path: Path, raw: RawCamera, unit: float) -> CameraCalibration:
    """Checked CameraCalibration (world → camera, metres) from a file's raw fields."""
    name = raw.name
    if raw.fisheye:
        raise PriortrackError(f"{path}: camera {name!r} is a fisheye camera; only OpenCV's pinhole model (with its "
                              f"5 distortion coefficients) is supported")
    K = _array(path, name, "intrinsic matrix K", raw.K, (3, 3))
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        raise PriortrackError(f"{path}: camera {name!r}: the intrinsic matrix K is not [[fx, s, cx], [0, fy, cy], "
                              f"[0, 0, 1]] with fx, fy > 0: {K.tolist()}")
    try:
        dist = np.zeros(5) if raw.dist is None else np.asarray(raw.dist, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise PriortrackError(f"{path}: camera {name!r}: the distortion coefficients are not numbers") from None
    if dist.size not in (4, 5, 8) or not np.isfinite(dist).all():
        raise PriortrackError(f"{path}: camera {name!r}: the distortion must be 4 or 5 finite OpenCV coefficients "
                              f"(k1 k2 p1 p2 [k3]), got {dist.tolist()}")
    if dist.size == 8 and np.any(dist[5:]):
        raise PriortrackError(f"{path}: camera {name!r}: the rational distortion model (k4-k6) is not supported")
    dist = np.concatenate([dist[:5], np.zeros(max(0, 5 - dist.size))])
    if raw.rotation is None and raw.translation is None:
        R, t = np.eye(3), np.zeros(3)
    elif raw.rotation is None or raw.translation is None:
        raise PriortrackError(f"{path}: camera {name!r}: give both a rotation and a translation, or neither "
                              f"(intrinsics only)")
    else:
        R = _rotation(path, name, raw.rotation)
        t = _array(path, name, "translation", raw.translation, (3,)) * unit
        if raw.direction == "camera_to_world":          # X = R X_c + T, T the camera's position
            R, t = R.T, -R.T @ t
        elif raw.direction == "centre":                 # R world → camera, T the camera's position
            t = -R @ t
    if raw.size is None:
        raise PriortrackError(f"{path}: camera {name!r}: the image size (width, height) is missing")
    size = _array(path, name, "image size", raw.size, (2,))
    if np.any(size < 1) or np.any(size != np.round(size)) or np.any(size > 1e5):
        raise PriortrackError(f"{path}: camera {name!r}: the image size must be two positive whole numbers of "
                              f"pixels (width, height), got {size.tolist()}")
    return CameraCalibration(str(name), K, dist, R, t, (int(size[0]), int(size[1])))


_ALIASES = {"K": ("K", "camera_matrix", "matrix", "intrinsics"),
            "dist": ("dist", "distortion_coefficients", "D", "distortions", "distCoef", "distCoeff"),
            "R": ("R", "Rot", "rotation_matrix", "rvec", "rotation"), "t": ("t", "T", "tvec", "translation")}


def _field(camera: dict, field: str):
    return next((camera[k] for k in _ALIASES[field] if k in camera), None)


def _opencv_one(path: Path, name: str, camera: Any) -> RawCamera:
    if not isinstance(camera, dict):
        raise PriortrackError(f"{path}: camera {name!r} is not a mapping of fields")
    name = str(camera.get("name", name))
    if _field(camera, "K") is None:
        raise PriortrackError(f"{path}: camera {name!r}: no intrinsic matrix (K or camera_matrix)")
    size = camera.get("size", camera.get("image_size", camera.get("resolution")))
    if size is None and "image_width" in camera and "image_height" in camera:
        size = (camera["image_width"], camera["image_height"])
    return RawCamera(name, _field(camera, "K"), size, _field(camera, "dist"), _field(camera, "R"), _field(camera, "t"))


def _opencv_layout(path: Path, data: Any) -> Layout:
    if not isinstance(data, dict):
        raise PriortrackError(f"{path}: expected a mapping (one camera, 'cameras', or names to cameras)")
    up = data.get("up")
    units = data.get("units", data.get("unit"))
    if units is not None and units not in UNITS:
        raise PriortrackError(f"{path}: units {units!r} is not one of {', '.join(UNITS)}")
    if isinstance(data.get("cameras"), list):
        cameras = [_opencv_one(path, f"camera {i}", c) for i, c in enumerate(data["cameras"])]
    elif isinstance(data.get("names"), list):                 # the FileStorage multi-camera layout
        cameras = []
        for name in data["names"]:
            camera = {key: data[f"{key}_{name}"] for keys in _ALIASES.values() for key in keys if f"{key}_{name}" in data}
            for key in ("size", "image_width", "image_height"):
                if f"{key}_{name}" in data:
                    camera[key] = data[f"{key}_{name}"]
            camera.setdefault("size", data.get("size"))
            cameras.append(_opencv_one(path, str(name), camera))
    elif _field(data, "K") is not None:
        cameras = [_opencv_one(path, str(data.get("name", "camera")), data)]
    else:
        cameras = [_opencv_one(path, str(name), c) for name, c in data.items() if isinstance(c, dict)]
    if up is None and len(cameras) == 1 and cameras[0].rotation is None and cameras[0].translation is None:
        up = "-y"                                             # intrinsics only: the camera's own frame
    return Layout("OpenCV-style " + path.suffix.lower().lstrip("."), cameras, up=up, units=units)


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
