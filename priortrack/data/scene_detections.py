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

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from priortrack.data.detections import (MAX_CAMERAS, MAX_NPZ_BYTES, DetectionsHeader, _camera_folders,
                                        _frame_files, _keypoint_count, _people, _triples, _with_count,
                                        check_frames, cleaned_keypoints)
from priortrack.data.keypoints import layout_for, layout_of_names, to_eval15
from priortrack.data.npz import read_npz
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

    def head(self, n: int) -> "SceneDetections":
        """The first ``n`` frames."""
        return SceneDetections(self.layout, self.camera_names, self.frames[:n], self.fps, self.source,
                               keypoints=self.keypoints[:, :n])


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
    folders = _camera_folders(path)
    files = [_frame_files(folder) for folder in folders]
    frames = np.array(sorted(set().union(*files)))
    check_frames(frames, str(path))
    numbers = frames.tolist()
    K = _keypoint_count(files, numbers, path)
    layout = layout_for(keypoints, K, str(path))
    per_camera = [[_seen(people) for people in _with_count((_people(by_frame[n]) if n in by_frame else []
                                                           for n in numbers), K, path)] for by_frame in files]
    return SceneDetections(layout, tuple(f.name for f in folders), frames, None, str(path),
                           keypoints=_stacked(per_camera, K, str(path)))


def _coco(path: Path, keypoints: str | None) -> SceneDetections:
    try:
        data = json.loads(path.read_text(errors="replace"))
    except json.JSONDecodeError as exc:
        raise PriortrackError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, list) or not data:
        raise PriortrackError(f"{path}: not a COCO results file (a non-empty list of image_id, keypoints, score)")
    by_frame: dict[int, list[np.ndarray]] = {}
    for i, entry in enumerate(data):
        if not isinstance(entry, dict) or "image_id" not in entry or not isinstance(entry.get("keypoints"), list):
            raise PriortrackError(f"{path}: entry {i} lacks image_id or keypoints")
        image = entry["image_id"]
        if isinstance(image, bool) or not isinstance(image, int):
            raise PriortrackError(f"{path}: entry {i}: image_id {image!r} is not a frame number")
        if entry["keypoints"]:
            by_frame.setdefault(image, []).append(_triples(entry["keypoints"], f"{path}: entry {i} keypoints"))
    counts = {len(p) for people in by_frame.values() for p in people}
    if len(counts) != 1:
        raise PriortrackError(f"{path}: " + ("nobody is detected" if not counts else
                                             f"entries have different keypoint counts ({sorted(counts)})"))
    K = counts.pop()
    frames = np.array(sorted(by_frame))
    check_frames(frames, str(path))
    per_camera = [[_seen(by_frame[int(n)]) for n in frames]]
    return SceneDetections(layout_for(keypoints, K, str(path)), (path.stem,), frames, None, str(path),
                           keypoints=_stacked(per_camera, K, str(path)))


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
    names = tuple(str(n) for n in arrays["keypoint_names"].reshape(-1))
    if len(names) != K:
        raise PriortrackError(f"{path}: {len(names)} keypoint_names for {K} keypoints")
    layout, order = layout_of_names(names, str(path))
    if keypoints is not None and layout_for(keypoints, K, str(path)) != layout:
        raise PriortrackError(f"{path}: keypoint_names are layout {layout}, not {keypoints}")
    frames = arrays.get("frames", np.arange(T))
    if frames.shape != (T,) or frames.dtype.kind not in "iu" or np.any(np.diff(frames) <= 0):
        raise PriortrackError(f"{path}: frames must be {T} increasing integers")
    fps = arrays.get("fps")
    fps = None if fps is None else float(fps)
    if fps is not None and not 0 < fps < 1e4:
        raise PriortrackError(f"{path}: fps {fps} is not a frame rate")
    cameras = tuple(str(n) for n in arrays.get("camera_names", np.array([f"cam{c + 1}" for c in range(C)])))
    if len(cameras) != C:
        raise PriortrackError(f"{path}: {len(cameras)} camera_names for {C} cameras")
    order = tuple(int(k) for k in order)
    cleaned = np.stack([cleaned_keypoints(kp[:, :, n], order, f"{path}: person slot {n}") for n in range(N)], axis=2)
    return SceneDetections(layout, cameras, frames.astype(int), fps, str(path), keypoints=cleaned)
