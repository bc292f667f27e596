"""Every person a detector found, in every camera and frame, with no identity assumed.

A multi-person detector (OpenPose, MMPose/RTMPose, MediaPipe with several poses) writes each frame's
people in no stable order, and its per-camera ids, where it writes any, agree with no other camera's.
:func:`read_scene_detections` keeps them all: :class:`SceneDetections` holds ``keypoints`` (C, T, N,
K, 3), person slot n of camera c at frame t, NaN where that slot is empty (N is the most people any
camera saw in one frame). Slot order is the file's and means nothing; who is who is the scene
tracker's to decide (:mod:`priortrack.tracking`).

Sources, as :mod:`priortrack.data.detections` reads them: a folder of OpenPose JSON files or of
camera folders (an empty ``pose_keypoints_2d`` is nobody; a person with no keypoint seen is dropped),
a COCO results ``.json`` (one camera: every entry of an ``image_id``), or an ``.npz`` whose
``keypoints`` are (cameras, frames, people, K, 3) with ``keypoint_names`` and optional ``fps``,
``camera_names``, ``frames``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from priortrack.data.detections import (MAX_CAMERAS, MAX_NPZ_BYTES, Detections, DetectionsHeader, check_frames,
                                        cleaned_keypoints, coco_people, follow, npz_header, openpose_cameras)
from priortrack.data.keypoints import layout_candidates, settled_layout, to_eval15
from priortrack.data.npz import npz_member_shape, read_npz
from priortrack.errors import PriortrackError

#: Most people one camera may hold in one frame (a guard against absurd inputs).
MAX_PEOPLE = 64


@dataclass(frozen=True)
class SceneDetections(DetectionsHeader):
    """Every detected person (and :class:`~priortrack.data.detections.DetectionsHeader`'s fields).

    Attributes:
        keypoints: (C, T, N, K, 3) float32 x, y (pixels), confidence; NaN where missing, a whole slot
            NaN where camera c held fewer than N people at frame t; keyword only.
    """

    keypoints: np.ndarray = field(kw_only=True)

    def __post_init__(self):
        object.__setattr__(self, "keypoints", np.asarray(self.keypoints).astype(np.float32, copy=False))

    @property
    def people(self) -> np.ndarray:
        """(C, T) how many people each camera holds at each frame."""
        return np.isfinite(self.keypoints[..., :2]).all(-1).any(-1).sum(-1)

    def eval15(self, min_confidence: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
        """(C, T, N, 15, 2) pixels (NaN where missing) and (C, T, N, 15) confidences (0 where missing)
        in the evaluation layout (:func:`~priortrack.data.keypoints.to_eval15`)."""
        return to_eval15(self.keypoints, self.keypoint_names, min_confidence)

    def followed(self) -> Detections:
        """One person per camera, followed from frame to frame as
        :func:`~priortrack.data.detections.read_detections` follows them in the files (the same result,
        without parsing them again)."""
        out = np.full(self.keypoints.shape[:2] + self.keypoints.shape[3:], np.nan, dtype=np.float32)
        switches = tuple(follow(iter(self.keypoints[c]), out[c], None, name) for c, name in enumerate(self.camera_names))
        return Detections(self.layout, self.camera_names, self.frames, self.fps, self.source, switches, keypoints=out)

    def head(self, n: int) -> "SceneDetections":
        """The first ``n`` frames."""
        return SceneDetections(self.layout, self.camera_names, self.frames[:n], self.fps, self.source,
                               keypoints=self.keypoints[:, :n])


def holds_people(path: str | Path) -> bool:
    """Whether detections at ``path`` are read as every person's (:func:`read_scene_detections`): an OpenPose folder,
    COCO results (.json), an .npz of (cameras, frames, people, keypoints, 3); not one person's .npz or .npy (read a
    block of frames at a time) or a caliscope CSV."""
    path = Path(path)
    if path.is_dir() or path.suffix.lower() == ".json":
        return True
    if path.suffix.lower() == ".npz" and path.is_file():
        shape = npz_member_shape(path, "keypoints")
        return shape is not None and len(shape) == 5
    return False


def read_scene_detections(path: str | Path, keypoints: str | None = None) -> SceneDetections:
    """Read every person of a detector's output (module docstring); ``keypoints`` names the layout
    where the count does not (BODY_25 and BODY_25B both have 25)."""
    path = Path(path)
    if path.is_dir():
        return _openpose(path, keypoints)
    if not path.is_file():
        raise PriortrackError(f"detections {path} do not exist")
    if path.suffix.lower() == ".json":
        return _coco(path, keypoints)
    if path.suffix.lower() == ".npz":
        return _npz(path, keypoints)
    raise PriortrackError(f"{path}: several people are read from an OpenPose folder, a COCO results .json or an "
                          f".npz of (cameras, frames, people, keypoints, 3)")


def _seen(people: list[np.ndarray]) -> list[np.ndarray]:
    return [p for p in people if np.isfinite(p[:, :2]).all(axis=1).any()]


def _stacked(per_camera: list[list[list[np.ndarray]]], K: int, where: str) -> np.ndarray:
    """(C, T, N, K, 3) from each camera's frames' lists of (K, 3) people, NaN-padded."""
    N = max([len(people) for frames in per_camera for people in frames] + [1])
    if N > MAX_PEOPLE:
        raise PriortrackError(f"{where}: {N} people in one frame (at most {MAX_PEOPLE})")
    out = np.full((len(per_camera), len(per_camera[0]), N, K, 3), np.nan, dtype=np.float32)
    for c, frames in enumerate(per_camera):
        for t, people in enumerate(frames):
            for n, p in enumerate(people):
                out[c, t, n] = p
    return out


def _openpose(path: Path, keypoints: str | None) -> SceneDetections:
    cameras, frames, candidates, K, people = openpose_cameras(path, keypoints)
    per_camera = [[_seen(frame) for frame in people(c)] for c in range(len(cameras))]
    stacked = _stacked(per_camera, K, str(path))
    layout = settled_layout(stacked, candidates, str(path))
    return SceneDetections(layout, cameras, frames, None, str(path), keypoints=stacked)


def _coco(path: Path, keypoints: str | None) -> SceneDetections:
    by_frame, K = coco_people(path)
    frames = np.array(sorted(by_frame))
    check_frames(frames, str(path))
    per_camera = [[_seen(by_frame[int(n)]) for n in frames]]
    stacked = _stacked(per_camera, K, str(path))
    layout = settled_layout(stacked, layout_candidates(keypoints, K, str(path)), str(path))
    return SceneDetections(layout, (path.stem,), frames, None, str(path), keypoints=stacked)


def _npz(path: Path, keypoints: str | None) -> SceneDetections:
    arrays = read_npz(path, MAX_NPZ_BYTES, "detections file")
    if "keypoints" not in arrays or "keypoint_names" not in arrays:
        raise PriortrackError(f"{path}: the arrays 'keypoints' and 'keypoint_names' are needed")
    kp = arrays["keypoints"]
    if kp.ndim != 5 or kp.shape[-1] != 3 or kp.dtype.kind not in "fiu":
        raise PriortrackError(f"{path}: keypoints has shape {kp.shape} ({kp.dtype}); expected (cameras, frames, "
                              f"people, keypoints, 3) numbers")
    C, T, N, K, _ = kp.shape
    if not 1 <= C <= MAX_CAMERAS or T < 1 or not 1 <= N <= MAX_PEOPLE:
        raise PriortrackError(f"{path}: keypoints has {C} cameras, {T} frames and {N} people a frame")
    layout, order, frames, fps, cameras = npz_header(path, arrays, C, T, K, keypoints)
    cleaned = np.stack([cleaned_keypoints(kp[:, :, n], order, f"{path}: person slot {n}") for n in range(N)], axis=2)
    return SceneDetections(layout, cameras, frames, fps, str(path), keypoints=cleaned)
