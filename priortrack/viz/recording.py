"""Rerun recordings of skeletons, cameras and 2D observations.

Entity layout of a priortrack recording (timeline ``frame``):

- ``world``: right-handed, Y-up (or the calibration's up axis); the ``eval15`` annotation context, one
  class per skeleton colour so that each skeleton's bones are drawn in its colour;
- ``world/<name>``: a 3D skeleton as keypoints joined by the context's connections;
- ``world/<name>/cloud``: the joints of every particle or sigma point, coloured by weight;
- ``world/<name>/translation``: the 1σ ellipsoid of the body's translation over the particle set
  (a particle filter that integrates the translation out: its depth spread is not in the cloud);
- ``world/<camera>``: a camera's pose (``camera`` by default); ``world/<camera>/image`` its pinhole;
  ``world/<camera>/image/<name>``: 2D points in pixels (missing joints are simply not logged);
- ``metrics/<quantity>``: per-frame scalars, one quantity in its own units each (several series of
  one quantity, such as each camera's reprojection error, under ``metrics/<quantity>/<series>``);
- ``events``: text events (resampling, gating, the gate reopened, mismatch, missing frames).

Labels are off (the joints' names show on hover and for a selected entity). On closing, the
recording gets its layout (:meth:`Recording.layout`): the 3D view framed on the person and the
cameras, each camera's image, one time-series view per quantity logged, and the events. Entry
names (the application id, file names) keep to letters, digits, ``-`` and ``_``
(:func:`entry_name`), as the viewer asks.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy.spatial.transform import Rotation

from priortrack.data.eval15 import EVAL15_NAMES, EVAL15_PARENTS
from priortrack.geometry.camera import PinholeCamera
from priortrack.output import output_path
from priortrack.viz.weights import weight_levels

log = logging.getLogger(__name__)

TIMELINE = "frame"
EVAL15_CLASS = 0
#: Each per-frame quantity's title in the layout, its unit in it.
QUANTITIES = {"error_mm": "world error (mm)", "ess_fraction": "ESS (fraction of the particles)",
              "loglik": "log-likelihood of the estimate", "mismatch": "mismatch (1: the prior does not explain it)",
              "reprojection_px": "median reprojection error (px), per camera",
              "held_out_ratio": "held-out ratio (over 1.2: worse than triangulation)"}


def entry_name(text: str) -> str:
    """``text`` as a valid rerun entry name: letters, digits, ``-`` and ``_`` (others → ``-``)."""
    return re.sub(r"[^A-Za-z0-9_-]+", "-", str(text)).strip("-") or "priortrack"


class Recording:
    """A rerun recording saved to an ``.rrd`` file; ``colors``: the skeletons' colours known at the start (one
    annotation context for the whole recording; a colour first used later re-sends it).

    Example::

        with Recording("walk.rrd") as rec:
            rec.camera(camera)
            for i, pose in enumerate(positions):
                rec.frame(i)
                rec.skeleton("truth", pose)
    """

    def __init__(self, path: str | Path, application_id: str = "priortrack", up: str = "y", name: str | None = None,
                 up_vector=None, colors=()):
        self.path = output_path(path, "rerun recording")
        self.stream = rr.RecordingStream(entry_name(application_id))
        self.stream.save(self.path)
        if name is not None:                       # shown in the viewer's list of recordings
            self.stream.send_recording_name(name)
        #: What the layout is made of: the quantities and cameras logged, where the people and cameras are.
        self.quantities: dict[str, None] = {}
        self.styled: set[str] = set()                  # the series whose colour was set
        self.cameras: dict[str, np.ndarray] = {}
        self.people: list[np.ndarray] = []
        axes = {"x": (1.0, 0, 0), "y": (0, 1.0, 0), "z": (0, 0, 1.0)}
        self.up = np.asarray(up_vector if up_vector is not None else axes[up.lstrip("-")], dtype=float) * \
            (-1.0 if up_vector is None and up.startswith("-") else 1.0)
        views = {"y": rr.ViewCoordinates.RIGHT_HAND_Y_UP, "z": rr.ViewCoordinates.RIGHT_HAND_Z_UP,
                 "-y": rr.ViewCoordinates.RIGHT_HAND_Y_DOWN, "-z": rr.ViewCoordinates.RIGHT_HAND_Z_DOWN,
                 "x": rr.ViewCoordinates.RIGHT_HAND_X_UP, "-x": rr.ViewCoordinates.RIGHT_HAND_X_DOWN}
        self.stream.log("world", views[up], static=True)
        #: One annotation class per skeleton colour (its bones drawn in it), class 0 uncoloured.
        self.classes: dict[tuple[int, int, int] | None, int] = {None: EVAL15_CLASS}
        for color in colors:                       # the colours known now: one context for the whole recording
            self.classes.setdefault(tuple(int(c) for c in color), len(self.classes))
        self._send_context()

    def _send_context(self) -> None:
        """The eval15 annotation context (joint names, bones), one class per colour in use (static)."""
        connections = [(int(p), j) for j, p in enumerate(EVAL15_PARENTS) if p >= 0]
        joints = [rr.AnnotationInfo(id=j, label=n) for j, n in enumerate(EVAL15_NAMES)]
        self.stream.log("world", rr.AnnotationContext([
            rr.ClassDescription(info=rr.AnnotationInfo(id=k, label="eval15", color=color),
                                keypoint_annotations=joints, keypoint_connections=connections)
            for color, k in self.classes.items()]), static=True)

    def _class(self, color) -> int:
        """The annotation class whose bones are drawn in ``color`` (RGB), added on first use."""
        key = tuple(int(c) for c in color)
        if key not in self.classes:
            self.classes[key] = len(self.classes)
            self._send_context()
        return self.classes[key]

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Send the layout, flush everything to the file."""
        self.stream.send_blueprint(self.layout())
        self.stream.flush()
        self.stream.disconnect()
        log.info("wrote rerun recording %s", self.path)

    def frame(self, index: int) -> None:
        """Set the ``frame`` timeline for what is logged next."""
        self.stream.set_time(TIMELINE, sequence=int(index))

    def skeleton(self, name: str, positions, color=(60, 160, 255), colors=None, label: str | None = None) -> None:
        """Log an eval15 skeleton, positions (15, 3) metres, at ``world/<name>``, in one colour or one
        per joint (``colors`` (15, 3)); a ``label`` is shown at its head (``world/<name>/label``)."""
        positions = np.asarray(positions)
        if len(self.people) < 64 and np.isfinite(positions).all():
            self.people.append(positions.mean(axis=0))
        self.stream.log(f"world/{name}", rr.Points3D(
            positions, class_ids=self._class(color), keypoint_ids=np.arange(len(EVAL15_NAMES)),
            colors=[color] if colors is None else np.asarray(colors, dtype=np.uint8), radii=0.02, show_labels=False))
        if label is not None:
            self.stream.log(f"world/{name}/label", rr.Points3D(
                positions[EVAL15_NAMES.index("head")][None], labels=[label], colors=[color], radii=0.001,
                show_labels=True))

    def cloud(self, name: str, joints, weights) -> None:
        """Log particles' joints (P, 15, 3) metres at ``world/<name>/cloud``, coloured by weight: dark blue
        (:data:`~priortrack.viz.weights.DECADES` decades below the heaviest, and lower) to yellow (the heaviest), by
        :func:`~priortrack.viz.weights.weight_levels`."""
        joints = np.asarray(joints)
        level = weight_levels(weights)
        low, high = np.array([30, 40, 120]), np.array([255, 230, 40])
        colors = (low + level[:, None] * (high - low)).astype(np.uint8)
        self.stream.log(f"world/{name}/cloud", rr.Points3D(
            joints.reshape(-1, 3), colors=np.repeat(colors, joints.shape[1], axis=0), radii=0.01))

    def ellipsoid(self, name: str, center, covariance, color=(255, 90, 60)) -> None:
        """Log the 1σ ellipsoid {c + v : vᵀ Σ⁻¹ v ≤ 1} of a 3D Gaussian at ``world/<name>``: the
        half-axes are the square roots of Σ's eigenvalues (3,) metres, along its eigenvectors
        (the rotation taking the x, y, z axes to them, as a quaternion)."""
        eigenvalues, axes = np.linalg.eigh(np.asarray(covariance, dtype=float))
        axes[:, 2] *= np.sign(np.linalg.det(axes))                # a rotation, not a reflection
        self.stream.log(f"world/{name}", rr.Ellipsoids3D(
            centers=[np.asarray(center, dtype=float)], half_sizes=[np.sqrt(np.clip(eigenvalues, 0.0, None))],
            quaternions=[rr.Quaternion(xyzw=Rotation.from_matrix(axes).as_quat())], colors=[color]))

    def camera(self, camera: PinholeCamera, name: str = "camera") -> None:
        """Log the camera pose and pinhole (static) at ``world/<name>``."""
        R = camera.R.cpu().numpy()
        self.cameras[name] = camera.center.cpu().numpy()
        self.stream.log(f"world/{name}", rr.Transform3D(translation=camera.center.cpu().numpy(), mat3x3=R.T),
                        static=True)
        self.stream.log(f"world/{name}/image", rr.Pinhole(
            image_from_camera=camera.K.cpu().numpy(), resolution=[camera.width, camera.height],
            camera_xyz=rr.ViewCoordinates.RDF), static=True)

    def points_2d(self, name: str, uv, color=(255, 120, 0), camera: str = "camera", confidence=None,
                  radius: float = 4.0) -> None:
        """Log eval15 2D points, uv (15, 2) pixels with NaN where missing, in a camera's image, ``radius``
        pixels; with ``confidence`` (15,) in [0, 1], each point's radius (2–8 px) and brightness follow it."""
        uv = np.asarray(uv)
        seen = np.flatnonzero(np.all(np.isfinite(uv), axis=-1))
        colors, radii = [color], radius
        if confidence is not None:
            c = np.clip(np.asarray(confidence, dtype=float)[seen], 0.0, 1.0)
            colors = (np.asarray(color)[None] * (0.35 + 0.65 * c[:, None])).astype(np.uint8)
            radii = 2.0 + 6.0 * c
        self.stream.log(f"world/{camera}/image/{name}", rr.Points2D(
            uv[seen], class_ids=self._class(color), keypoint_ids=seen, colors=colors, radii=radii, show_labels=False))

    def links_2d(self, name: str, a, b, color=(255, 120, 0), camera: str = "camera", label: str | None = None) -> None:
        """Log a segment from each point of ``a`` (J, 2) pixels to the same joint of ``b`` (J, 2) where both are
        seen, in a camera's image (a detection to the estimate it was given to)."""
        a, b = np.asarray(a, dtype=np.float32), np.asarray(b, dtype=np.float32)
        seen = np.flatnonzero(np.isfinite(a).all(axis=-1) & np.isfinite(b).all(axis=-1))
        if len(seen):
            self.stream.log(f"world/{camera}/image/{name}", rr.LineStrips2D(
                np.stack([a[seen], b[seen]], axis=1), colors=[color], radii=1.0,
                labels=None if label is None else [label], show_labels=False))

    def scalar(self, name: str, value: float, color=None) -> None:
        """Log a per-frame scalar at ``metrics/<name>`` (NaN is skipped); ``name``'s first part is its
        quantity (:data:`QUANTITIES`), which gets its own time-series view; ``color`` (RGB), the line's (set
        once, static: a person's series in the person's colour)."""
        if np.isfinite(value):
            self.quantities[name.split("/", 1)[0]] = None
            if color is not None and name not in self.styled:
                self.styled.add(name)
                self.stream.log(f"metrics/{name}", rr.SeriesLines(colors=[color]), static=True)
            self.stream.log(f"metrics/{name}", rr.Scalars(float(value)))

    def event(self, text: str, level: str = "INFO") -> None:
        """Log a text event at ``events`` (level "DEBUG", "INFO" or "WARN")."""
        self.stream.log("events", rr.TextLog(text, level=level))

    def layout(self) -> rrb.Blueprint:
        """The recording's layout from what was logged: the 3D view looking at the people from just
        beyond the cameras (the eye 1.15 times the farthest camera's distance out, at least 2.5 m, and
        0.5 m up), each camera's image in a tab, one time-series view per quantity with its unit, and
        the events."""
        target = np.median(self.people, axis=0) if self.people else np.zeros(3)
        up = self.up / np.linalg.norm(self.up)
        cameras = np.array(list(self.cameras.values())) if self.cameras else target[None] + np.array([[0, 0, 4.0]])
        away = cameras.mean(axis=0) - target
        away -= (away @ up) * up                                 # look across, not down
        distance = max(2.5, 1.15 * float(np.linalg.norm(cameras - target, axis=1).max()))
        direction = away if np.linalg.norm(away) > 1e-6 else np.cross(up, [1.0, 0, 0]) + np.cross(up, [0, 0, 1.0])
        eye = rrb.EyeControls3D(position=target + distance * direction / np.linalg.norm(direction) + 0.5 * up,
                                look_target=target, eye_up=up)
        world = rrb.Spatial3DView(origin="world", name="3D", eye_controls=eye)
        images = [rrb.Spatial2DView(origin=f"world/{c}/image", name=c) for c in self.cameras]
        series = [rrb.TimeSeriesView(origin=f"metrics/{q}", name=QUANTITIES.get(q, q)) for q in self.quantities]
        top = rrb.Horizontal(world, rrb.Tabs(*images) if len(images) > 1 else images[0]) if images else world
        bottom = rrb.Horizontal(*series, rrb.TextLogView(origin="events", name="events"))
        return rrb.Blueprint(rrb.Vertical(top, bottom, row_shares=[3, 1]), collapse_panels=True)
