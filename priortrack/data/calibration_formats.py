"""The calibration layouts of the tools our users come from, recognised from the file's content.

A reader turns a parsed file into a :class:`Layout`: the format's name (logged), the cameras as the
file stores them (:class:`RawCamera`), the world's up direction where the file gives one, and the
translation's unit where the format fixes it. :mod:`priortrack.data.calibration` checks the fields,
turns every camera into world → camera (X_c = R X + t, metres) and infers what the file leaves open.

=============================  ==============================================  =========  ============  =======  ======
format                         recognised by                                   rotation   direction     units    up
=============================  ==============================================  =========  ============  =======  ======
Pose2Sim ``Calib.toml``        TOML camera tables (``matrix``) with a          Rodrigues  world→cam     (m)      z
                               ``fisheye`` key each (``toml_write``)
anipose / FreeMoCap            TOML camera tables without ``fisheye`` keys     Rodrigues  world→cam     infer    person
``calibration.toml``           (aniposelib's ``CameraGroup.dump``)
caliscope ``camera_array``     TOML ``[cameras.N]`` tables, 3 × 3 rotations    3 × 3      world→cam     (m)      person
caliscope ``config.toml``      TOML ``[cam_N]`` tables, 3 × 3 rotations        3 × 3      world→cam     (m)      person
mmhuman3d chessboard JSON      JSON cameras with ``distCoeff`` and ``imgSize``  3 × 3 flat camera→world  (m)      floor
Panoptic ``calibration.json``  JSON ``cameras`` with ``panel``/``resolution``  3 × 3      world→cam     cm       person
VoxelPose ``calibration.json``  JSON cameras with ``fx``, ``fy``, ``cx``, ``cy``  3 × 3    T = centre    infer    person
4D Association ``calibration``  JSON cameras with ``K``, ``RT`` (3 × 4 flat)   3 × 4 flat world→cam     infer    person
``.json``                      and ``imgSize``
Qualisys ``.qca.txt``          QTM's XML ``<calibration>``/``<camera>``         3 × 3      centre        mm       z
OpenCV JSON / YAML             ``K``/``camera_matrix`` (module                 either     world→cam     infer    ``up``
                               :mod:`priortrack.data.calibration`)
=============================  ==============================================  =========  ============  =======  ======

"(m)": the format's documents say metres; the camera layout is still checked. "person": the file
gives no vertical (the world is camera 1's frame); "up" is found from the tracked person. A Pose2Sim
file whose first camera sits at the world's origin is one converted from such a tool: up is left
open too. mmhuman3d's depth cameras measure the floor: its normal, averaged over them and turned
into the world (X_world = R x_cam + T), is up.

Qualisys QTM exports each camera's position (``transform`` x, y, z, millimetres), a rotation M (rows
r11…r33, world → a camera frame whose y and z point opposite to OpenCV's) and its intrinsics in
sub-pixels (1/64 px); read as Pose2Sim's ``read_qca``/``calib_qca_fun`` read them: R = diag(1, −1, −1) M
(the π rotation about the camera's x), K = focal length / 64 and principal point / 64 less the video
window's origin, the image size the video window's, and the distortion coefficients [k1, k2, p1, p2]
divided by 64 as Pose2Sim divides them (its default ``undistort_points = false`` ignores them).

Sources: Pose2Sim ``common.py``/``calibration.py`` (``toml_write``, ``retrieve_calib_params``,
``read_qca``, ``calib_qca_fun``), 4D Association's ``camera.cpp`` (``Camera::Parse``: K and RT flat row-major),
aniposelib ``cameras.py`` (``Camera.get_dict``, ``FisheyeCamera``), caliscope
``cameras/camera_array.py`` and its ``persistence`` TOML, mmhuman3d ``CameraParameter.
load_from_chessboard`` (``inverse=True``), the CMU Panoptic toolbox's ``calibration_<seq>.json``
(centimetres), VoxelPose's ``calibration_*.json`` (``T`` the camera centre, millimetres).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from priortrack.errors import PriortrackError

log = logging.getLogger(__name__)


@dataclass
class RawCamera:
    """One camera's fields as the file stores them (checked later).

    ``rotation``: a Rodrigues vector (3,) or a matrix (3 × 3, nested or flat); ``direction``:
    "world_to_camera" (X_c = R X + t), "camera_to_world" (X = R X_c + T, T the camera's position) or
    "centre" (R world → camera, T the camera's position); ``fisheye``: the file's fisheye flag."""

    name: str
    K: Any
    size: Any
    dist: Any = None
    rotation: Any = None
    translation: Any = None
    direction: str = "world_to_camera"
    fisheye: bool = False


@dataclass
class Layout:
    """A recognised file: ``format`` (its name), ``cameras``, ``up`` (an axis name, a (3,) vector or
    None), ``units`` ("m", "cm", "mm" where the file or format states them, else None)."""

    format: str
    cameras: list[RawCamera]
    up: Any = None
    units: str | None = None
    #: True where the format documents its unit (checked against the layout, not taken blindly).
    units_documented: bool = field(default=False)


def _matrix_like(value: Any) -> bool:
    """A 3 × 3 matrix, nested or flat (9 numbers), rather than a rotation vector."""
    return np.size(np.asarray(value, dtype=object)) == 9


def toml_layout(path: Path, table: dict) -> Layout:
    """A TOML calibration: Pose2Sim, anipose/FreeMoCap or caliscope (module docstring)."""
    nested = table.get("cameras")
    if isinstance(nested, dict) and any(isinstance(v, dict) and "matrix" in v for v in nested.values()):
        entries = [(f"cam_{v.get('cam_id', v.get('port', k))}", v) for k, v in nested.items()
                   if isinstance(v, dict) and "matrix" in v]
        return Layout("caliscope camera_array.toml", [_toml_camera(path, n, v) for n, v in entries],
                      units="m", units_documented=True)
    entries = [(key, value) for key, value in table.items() if isinstance(value, dict) and "matrix" in value]
    if any(_matrix_like(v.get("rotation", ())) for _, v in entries):
        return Layout("caliscope config.toml", [_toml_camera(path, k, v) for k, v in entries],
                      units="m", units_documented=True)
    cameras = [_toml_camera(path, str(v.get("name", k)), v) for k, v in entries]
    if entries and all("fisheye" in v for _, v in entries):
        first = cameras[0]
        at_origin = first.rotation is not None and _near_identity(first.rotation, first.translation, cameras)
        if at_origin:
            log.info("%s: the first camera sits at the world's origin: no axis is known to be vertical", path)
        return Layout("Pose2Sim Calib.toml", cameras, up=None if at_origin else "z", units="m",
                      units_documented=True)
    return Layout("anipose/FreeMoCap calibration.toml", cameras)


def _toml_camera(path: Path, name: str, v: dict) -> RawCamera:
    for key, words in (("rotation", "rotation"), ("translation", "translation"), ("size", "image size")):
        if key not in v:
            raise PriortrackError(f"{path}: camera {name!r}: the {words} ({key!r}) is missing")
    return RawCamera(name, v["matrix"], v["size"], v.get("distortions"), v["rotation"], v["translation"],
                     fisheye=bool(v.get("fisheye", False)))


def _near_identity(rotation: Any, translation: Any, cameras: list[RawCamera]) -> bool:
    """A Rodrigues camera at the origin: angle below 0.05 rad, position within 5 % of the others'."""
    try:
        rvec, t = np.asarray(rotation, dtype=float).reshape(-1), np.asarray(translation, dtype=float).reshape(-1)
        others = [np.linalg.norm(np.asarray(c.translation, dtype=float)) for c in cameras[1:]]
    except (TypeError, ValueError):
        return False
    if rvec.size != 3 or t.size != 3 or not others:
        return False
    return bool(np.linalg.norm(rvec) < 0.05 and np.linalg.norm(t) < 0.05 * np.median(others))


def json_layout(path: Path, data: Any) -> Layout | None:
    """A JSON calibration of mmhuman3d, Panoptic or VoxelPose (module docstring); None for others."""
    if isinstance(data, dict) and isinstance(data.get("cameras"), list) and data["cameras"] and all(
            isinstance(c, dict) and "resolution" in c and ("panel" in c or "node" in c) for c in data["cameras"]):
        return Layout("CMU Panoptic calibration.json",
                      [RawCamera(str(c.get("name", i)), c.get("K"), c.get("resolution"), c.get("distCoef"),
                                 c.get("R"), c.get("t")) for i, c in enumerate(data["cameras"])],
                      units="cm", units_documented=True)
    if not isinstance(data, dict):
        return None
    cameras = {k: v for k, v in data.items() if isinstance(v, dict)}
    if cameras and all({"K", "RT", "imgSize"} <= set(c) for c in cameras.values()):
        return Layout("4D Association calibration.json", [_four_d_camera(path, str(k), c) for k, c in cameras.items()])
    if cameras and all("distCoeff" in c and "imgSize" in c for c in cameras.values()):
        raw = [RawCamera(str(k), c.get("K"), c.get("imgSize"), c.get("distCoeff"), c.get("R"), c.get("T"),
                         direction="camera_to_world") for k, c in cameras.items()]
        return Layout("mmhuman3d chessboard .json", raw, up=_floor_up(path, cameras), units="m",
                      units_documented=True)
    if cameras and all({"fx", "fy", "cx", "cy", "R", "T"} <= set(c) for c in cameras.values()):
        raw = []
        for k, c in cameras.items():
            K = [[c["fx"], 0.0, c["cx"]], [0.0, c["fy"], c["cy"]], [0.0, 0.0, 1.0]]
            k3 = np.asarray(c.get("k", [0, 0, 0]), dtype=object).reshape(-1).tolist()
            p2 = np.asarray(c.get("p", [0, 0]), dtype=object).reshape(-1).tolist()
            dist = (k3[:2] + p2 + k3[2:3]) if len(k3) == 3 and len(p2) == 2 else k3 + p2
            size = c.get("size", c.get("resolution"))
            if size is None:                                # VoxelPose stores none: the principal point's double
                size = _size_from_principal_point(c["cx"], c["cy"])
                log.warning("%s: camera %r gives no image size; taken as %s from its principal point", path, k, size)
            raw.append(RawCamera(str(k), K, size, dist, c["R"], c["T"], direction="centre"))
        return Layout("VoxelPose calibration.json", raw)
    return None


def _size_from_principal_point(cx: Any, cy: Any) -> list[int] | None:
    try:
        return [int(round(2 * float(cx))), int(round(2 * float(cy)))]
    except (TypeError, ValueError):
        return None


def _floor_up(path: Path, cameras: dict) -> np.ndarray | None:
    """The world's up from mmhuman3d's floor planes: each measured normal n (its camera's frame) turned
    into the world (R n), signed to point from the floor towards the camera, averaged."""
    normals = []
    for name, c in cameras.items():
        floor = c.get("floor")
        try:
            n = np.asarray(floor["normal"], dtype=float).reshape(3)
            centre = np.asarray(floor["center"], dtype=float).reshape(3)
            R = np.asarray(c["R"], dtype=float).reshape(3, 3)
        except (TypeError, KeyError, ValueError):
            continue
        if not (np.isfinite(n).all() and np.isfinite(centre).all() and np.isfinite(R).all()) or \
                np.linalg.norm(n) < 1e-9 or not floor.get("pnum"):
            continue
        n = n / np.linalg.norm(n)
        n = -n if n @ -centre < 0 else n                   # towards the camera (at its frame's origin)
        normals.append(R @ n)
    if not normals:
        return None
    up = np.mean(normals, axis=0)
    log.info("%s: up from the floor seen by %d depth cameras: %s", path, len(normals), np.round(up / np.linalg.norm(up), 3))
    return up / np.linalg.norm(up)


def _four_d_camera(path: Path, name: str, c: dict) -> RawCamera:
    """A camera of 4D Association's calibration: ``RT`` the 3 × 4 world → camera [R | t], flat row-major."""
    try:
        RT = np.asarray(c["RT"], dtype=float).reshape(3, 4)
    except (TypeError, ValueError):
        raise PriortrackError(f"{path}: camera {name!r}: RT must be 12 numbers (a 3 × 4 [R | t], row-major), "
                              f"got {c['RT']!r}") from None
    return RawCamera(name, c["K"], c["imgSize"], c.get("distCoeff"), RT[:, :3], RT[:, 3])


def is_qualisys(text: str) -> bool:
    """A Qualisys QTM calibration export: an XML ``<calibration>`` holding ``<cameras>``."""
    head = text.lstrip()[:2000]
    return head.startswith("<") and "<calibration" in head and "<cameras" in text


def qualisys_layout(path: Path, text: str) -> Layout:
    """A Qualisys ``.qca.txt`` (module docstring), read as Pose2Sim reads it."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise PriortrackError(f"{path}: not valid XML ({exc})") from None
    cameras = []
    for i, camera in enumerate(root.findall("cameras/camera")):
        name = camera.get("serial") or f"camera {i}"
        fov, intrinsic, transform = (camera.find(tag) for tag in ("fov_video", "intrinsic", "transform"))
        for tag, element in (("fov_video", fov), ("intrinsic", intrinsic), ("transform", transform)):
            if element is None:
                raise PriortrackError(f"{path}: camera {name!r}: no <{tag}> element")

        def number(element, key: str) -> float:
            try:
                return float(element.get(key))
            except (TypeError, ValueError):
                raise PriortrackError(f"{path}: camera {name!r}: <{element.tag}> {key}={element.get(key)!r} is "
                                      f"not a number") from None

        left, top = number(fov, "left"), number(fov, "top")
        size = [number(fov, "right") - left + 1, number(fov, "bottom") - top + 1]
        sub = {k: number(intrinsic, k) / 64 for k in ("focalLengthU", "focalLengthV", "centerPointU", "centerPointV",
                                                     "radialDistortion1", "radialDistortion2",
                                                     "tangentalDistortion1", "tangentalDistortion2")}
        K = [[sub["focalLengthU"], 0.0, sub["centerPointU"] - left], [0.0, sub["focalLengthV"], sub["centerPointV"] - top],
             [0.0, 0.0, 1.0]]
        dist = [sub["radialDistortion1"], sub["radialDistortion2"], sub["tangentalDistortion1"],
                sub["tangentalDistortion2"]]
        M = np.array([[number(transform, f"r{i}{j}") for j in (1, 2, 3)] for i in (1, 2, 3)])
        centre = [number(transform, axis) for axis in "xyz"]
        cameras.append(RawCamera(name, K, size, dist, np.diag([1.0, -1.0, -1.0]) @ M, centre, direction="centre"))
    return Layout("Qualisys .qca.txt", cameras, up="z", units="mm", units_documented=True)
