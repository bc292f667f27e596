"""Rerun recordings of skeletons, cameras and 2D observations.

Entity layout of a priortrack recording (timeline ``frame``):

- ``world``: right-handed, Y-up (or the calibration's up axis); the ``eval15`` annotation context;
- ``world/<name>``: a 3D skeleton as keypoints joined by the context's connections;
- ``world/<name>/cloud``: the joints of every particle or sigma point, coloured by weight;
- ``world/<name>/translation``: the 1σ ellipsoid of the body's translation over the particle set
  (a particle filter that integrates the translation out: its depth spread is not in the cloud);
- ``world/<camera>``: a camera's pose (``camera`` by default); ``world/<camera>/image`` its pinhole;
  ``world/<camera>/image/<name>``: 2D points in pixels (missing joints are simply not logged);
- ``metrics/<name>``: per-frame scalars; ``events``: a step's flags as text
  (:class:`~priortrack.viz.logger.RerunLogger`, which also sends the default layout).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import rerun as rr
from scipy.spatial.transform import Rotation

from priortrack.data.eval15 import EVAL15_NAMES, EVAL15_PARENTS
from priortrack.geometry.camera import PinholeCamera
from priortrack.output import output_path

log = logging.getLogger(__name__)

TIMELINE = "frame"
EVAL15_CLASS = 0


class Recording:
    """A rerun recording saved to an ``.rrd`` file.

    Example::

        with Recording("walk.rrd") as rec:
            rec.camera(camera)
            for i, pose in enumerate(positions):
                rec.frame(i)
                rec.skeleton("truth", pose)
    """

    def __init__(self, path: str | Path, application_id: str = "priortrack", up: str = "y", name: str | None = None):
        self.path = output_path(path, "rerun recording")
        self.stream = rr.RecordingStream(application_id)
        self.stream.save(self.path)
        if name is not None:                       # shown in the viewer's list of recordings
            self.stream.send_recording_name(name)
        views = {"y": rr.ViewCoordinates.RIGHT_HAND_Y_UP, "z": rr.ViewCoordinates.RIGHT_HAND_Z_UP,
                 "-y": rr.ViewCoordinates.RIGHT_HAND_Y_DOWN, "-z": rr.ViewCoordinates.RIGHT_HAND_Z_DOWN,
                 "x": rr.ViewCoordinates.RIGHT_HAND_X_UP, "-x": rr.ViewCoordinates.RIGHT_HAND_X_DOWN}
        self.stream.log("world", views[up], static=True)
        connections = [(int(p), j) for j, p in enumerate(EVAL15_PARENTS) if p >= 0]
        context = rr.AnnotationContext([
            rr.ClassDescription(
                info=rr.AnnotationInfo(id=EVAL15_CLASS, label="eval15"),
                keypoint_annotations=[rr.AnnotationInfo(id=j, label=n) for j, n in enumerate(EVAL15_NAMES)],
                keypoint_connections=connections,
            )
        ])
        self.stream.log("world", context, static=True)

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Flush everything to the file."""
        self.stream.flush()
        self.stream.disconnect()
        log.info("wrote rerun recording %s", self.path)

    def frame(self, index: int) -> None:
        """Set the ``frame`` timeline for what is logged next."""
        self.stream.set_time(TIMELINE, sequence=int(index))

    def skeleton(self, name: str, positions, color=(60, 160, 255), colors=None) -> None:
        """Log an eval15 skeleton, positions (15, 3) metres, at ``world/<name>``, in one colour or one
        per joint (``colors`` (15, 3))."""
        self.stream.log(f"world/{name}", rr.Points3D(
            np.asarray(positions), class_ids=EVAL15_CLASS, keypoint_ids=np.arange(len(EVAL15_NAMES)),
            colors=[color] if colors is None else np.asarray(colors, dtype=np.uint8), radii=0.02))

    def cloud(self, name: str, joints, weights) -> None:
        """Log particles' joints (P, 15, 3) metres at ``world/<name>/cloud``, coloured by weight:
        dark blue (lowest) to yellow (highest), by each weight's share of the largest."""
        joints, weights = np.asarray(joints), np.asarray(weights, dtype=float)
        top = weights.max() if weights.size and weights.max() > 0 else 1.0
        share = np.clip(weights / top, 0.0, 1.0)
        low, high = np.array([30, 40, 120]), np.array([255, 230, 40])
        colors = (low + share[:, None] * (high - low)).astype(np.uint8)
        self.stream.log(f"world/{name}/cloud", rr.Points3D(
            joints.reshape(-1, 3), colors=np.repeat(colors, joints.shape[1], axis=0), radii=0.006))

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
        self.stream.log(f"world/{name}", rr.Transform3D(translation=camera.center.cpu().numpy(), mat3x3=R.T),
                        static=True)
        self.stream.log(f"world/{name}/image", rr.Pinhole(
            image_from_camera=camera.K.cpu().numpy(), resolution=[camera.width, camera.height],
            camera_xyz=rr.ViewCoordinates.RDF), static=True)

    def points_2d(self, name: str, uv, color=(255, 120, 0), camera: str = "camera", confidence=None) -> None:
        """Log eval15 2D points, uv (15, 2) pixels with NaN where missing, in a camera's image; with
        ``confidence`` (15,) in [0, 1], each point's radius (2–8 px) and brightness follow it."""
        uv = np.asarray(uv)
        seen = np.flatnonzero(np.all(np.isfinite(uv), axis=-1))
        colors, radii = [color], 4.0
        if confidence is not None:
            c = np.clip(np.asarray(confidence, dtype=float)[seen], 0.0, 1.0)
            colors = (np.asarray(color)[None] * (0.35 + 0.65 * c[:, None])).astype(np.uint8)
            radii = 2.0 + 6.0 * c
        self.stream.log(f"world/{camera}/image/{name}", rr.Points2D(
            uv[seen], class_ids=EVAL15_CLASS, keypoint_ids=seen, colors=colors, radii=radii))

    def scalar(self, name: str, value: float) -> None:
        """Log a per-frame scalar at ``metrics/<name>`` (NaN is skipped)."""
        if np.isfinite(value):
            self.stream.log(f"metrics/{name}", rr.Scalars(float(value)))
