"""2D detections from pose detectors: OpenPose JSON, COCO results, NPZ; one person followed.

:func:`read_detections` takes

- a folder of OpenPose JSON files (one per frame: ``people[i].pose_keypoints_2d`` = x, y,
  confidence per keypoint; an empty list is a person not there), or a folder of such folders, one per camera (sorted by name, as
  Pose2Sim does); frame numbers come from the file names' last run of digits
  (``cam01.000012.json``, ``..._000000000012_keypoints.json``). The same JSON layout with 17 or 33
  keypoints carries COCO-17 (MMPose, RTMPose, ViTPose, YOLO-pose) or MediaPipe output. The files are
  parsed one at a time as each camera's person is followed (a long recording's people are not all held);
- a COCO results file (``.json``: a list of ``{"image_id", "keypoints", "score"}``), one camera,
  ``image_id`` the frame number;
- an ``.npz`` with ``keypoints`` (cameras, frames, keypoints, 3) = x, y, confidence (missing: NaN,
  confidence 0, or the point (0, 0) as OpenPose writes it), ``keypoint_names`` (a layout's names in
  any order, ours or the detector's own: ``LShoulder``; :func:`~priortrack.data.keypoints.layout_of_names`),
  and optional ``fps``, ``camera_names`` and ``frames``;
- a FreeMoCap-style ``.npy`` (cameras, frames, points, 2 or 3) of x, y[, confidence] (NaN or
  (0, 0) missing; no confidence: 1), MediaPipe's 33 body points first (FreeMoCap's 543), cameras
  named ``cam_0``…; the frame rate must be given;
- a caliscope ``xy_<TRACKER>.csv`` (:mod:`priortrack.data.caliscope`: its cameras aligned by time).

The layout follows from the keypoint count (``keypoints=`` names it; BODY_25 and BODY_25B both
have 25 and must be named). Confidences must be finite and non-negative (NaN coordinates with
confidence 0 are OpenPose's "not found" too).

**Several people in a frame.** Per camera, the person followed is the one with the largest summed
confidence in the first frame where anyone is seen (``person=i`` pins index i of each frame's
list instead); in each later frame it is the candidate nearest the last position followed (median
distance over the keypoints both have, or between the centroids where they share none),
accepted if within ``SWITCH_GATE`` of the person's size (the larger diagonal of the two
keypoint boxes, at least ``MIN_SIZE_PX``). A frame whose nearest candidate is further is left
missing and logged as a possible switch, never taken silently; after ``REACQUIRE`` such frames in
a row the most confident person is followed again (logged).
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from priortrack.data.caliscope import is_caliscope_csv, read_caliscope
from priortrack.data.keypoints import LAYOUTS, layout_candidates, layout_for, layout_of_names, settled_layout, to_eval15
from priortrack.data.npz import ArrayOnDisk, npz_member_on_disk, read_npz
from priortrack.errors import PriortrackError

log = logging.getLogger(__name__)

#: A later frame's candidate is the same person if its median keypoint distance to the last one
#: followed is below this fraction of that person's size (box diagonal).
SWITCH_GATE = 0.5
MIN_SIZE_PX = 100.0
REACQUIRE = 10
#: Most frames and cameras a reader accepts (a guard against absurd inputs).
MAX_FRAMES, MAX_CAMERAS = 1_000_000, 64
#: The most an NPZ of detections may hold, bytes.
MAX_NPZ_BYTES = 4 << 30
#: FreeMoCap's MediaPipe points per frame: 33 body, 21 + 21 hands, 468 face.
FREEMOCAP_POINTS = 543


@dataclass(frozen=True)
class DetectionsHeader:
    """What detections of one followed person say besides their keypoints (:class:`Detections`,
    :class:`DetectionFile`).

    Attributes:
        layout: the keypoint layout's name (:data:`priortrack.data.keypoints.LAYOUTS`).
        camera_names: (C,) names (folder names, or ``camera_names`` of an npz).
        frames: (T,) int input frame numbers.
        fps: the frame rate if the input says it, else None.
        source: the path read.
        switches: (C,) frames per camera left missing as a possible identity switch.
    """

    layout: str
    camera_names: tuple[str, ...]
    frames: np.ndarray
    fps: float | None
    source: str
    switches: tuple[int, ...] = ()

    @property
    def keypoint_names(self) -> tuple[str, ...]:
        return LAYOUTS[self.layout]


@dataclass(frozen=True)
class Detections(DetectionsHeader):
    """Keypoints of one followed person (and :class:`DetectionsHeader`'s fields, given first).

    Attributes:
        keypoints: (C, T, K, 3) float32 x, y (pixels, origin top-left), confidence; NaN where missing
            (float32 holds a pixel to 10⁻⁴ px at 4,000 px, finer than any detector, in half the memory
            of float64: an hour at 60 fps of 4 cameras' BODY_25 is 260 MB; any other dtype given is
            converted); keyword only.
    """

    keypoints: np.ndarray = field(kw_only=True)

    def __post_init__(self):
        object.__setattr__(self, "keypoints", np.asarray(self.keypoints).astype(np.float32, copy=False))

    def head(self, n: int) -> "Detections":
        """The first ``n`` frames (all of them if there are fewer)."""
        n = _count(n)
        return replace(self, keypoints=self.keypoints[:, :n], frames=self.frames[:n])

    def eval15(self, min_confidence: float = 0.3, start: int = 0, stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(C, T, 15, 2) eval15 pixels of the frames [start, stop) (all by default), NaN where missing or
        below ``min_confidence``, and their confidences (C, T, 15) (:func:`priortrack.data.keypoints.to_eval15`)."""
        return _eval15(self.keypoints[:, start:stop], self.keypoint_names, min_confidence)

    def load(self) -> "Detections":
        """These detections (already in memory; :meth:`DetectionFile.load` reads a file's)."""
        return self


def _count(n) -> int:
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise PriortrackError(f"frames must be a positive count, got {n!r}")
    return n


def _eval15(keypoints: np.ndarray, names: tuple[str, ...], min_confidence: float) -> tuple[np.ndarray, np.ndarray]:
    if not 0 <= min_confidence < 1:
        raise PriortrackError(f"min_confidence must be in [0, 1), got {min_confidence}")
    return to_eval15(keypoints, names, min_confidence)


def read_detections(path: str | Path, keypoints: str | None = None, person: int | None = None) -> Detections:
    """Read detections (module docstring): an OpenPose folder, a COCO results ``.json``, or an ``.npz``."""
    return open_detections(path, keypoints, person).load()


def open_detections(path: str | Path, keypoints: str | None = None,
                    person: int | None = None) -> "Detections | DetectionFile":
    """:func:`read_detections`, except that an ``.npy``, or an ``.npz`` whose keypoints are stored
    uncompressed (``np.savez``), is opened as a :class:`DetectionFile` (its keypoints read a block of frames
    at a time when tracked); the other formats (and a compressed npz) are read whole."""
    path = Path(path)
    if person is not None and (isinstance(person, bool) or not isinstance(person, int) or person < 0):
        raise PriortrackError(f"person must be a non-negative index, got {person!r}")
    if path.is_dir():
        return _read_openpose(path, keypoints, person)
    if not path.is_file():
        raise PriortrackError(f"detections {path} do not exist")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return _npz_source(path, keypoints)
    if suffix == ".json":
        return _read_coco_results(path, keypoints, person)
    if suffix == ".npy":
        return _npy_source(path, keypoints)
    if suffix == ".csv" and is_caliscope_csv(path):
        return read_caliscope(path, keypoints)
    raise PriortrackError(f"{path}: detections are a folder of OpenPose JSON files, a COCO results .json, an .npz, "
                          f"a FreeMoCap-style .npy or a caliscope xy_*.csv")


# ---- OpenPose folders --------------------------------------------------------------------------

def _frame_number(path: Path) -> int:
    runs = re.findall(r"\d+", path.stem)
    if not runs:
        raise PriortrackError(f"{path}: no frame number in the file name")
    return int(runs[-1])


def _people(path: Path) -> list[np.ndarray]:
    """The (K, 3) keypoints of every person in one OpenPose JSON file."""
    try:
        data = json.loads(path.read_text(errors="replace"))
    except json.JSONDecodeError as exc:
        raise PriortrackError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("people"), list):
        raise PriortrackError(f"{path}: not OpenPose JSON (no 'people' list)")
    people = []
    for i, p in enumerate(data["people"]):
        values = p.get("pose_keypoints_2d") if isinstance(p, dict) else None
        if values == []:                         # an entry with no keypoints (Pose2Sim's files have them): nobody
            continue
        if not isinstance(values, list) or len(values) % 3:
            raise PriortrackError(f"{path}: people[{i}].pose_keypoints_2d is not a list of x, y, confidence triples")
        people.append(_triples(values, f"{path}: people[{i}].pose_keypoints_2d"))
    return people


def _triples(values, where: str) -> np.ndarray:
    """(K, 3) x, y, confidence from a flat list, checked: numbers, confidences finite and ≥ 0."""
    try:
        arr = np.asarray(values, dtype=np.float64).reshape(-1, 3)
    except (TypeError, ValueError):
        raise PriortrackError(f"{where}: not numbers") from None
    conf = arr[:, 2]
    if not np.isfinite(conf).all() or (conf < 0).any():
        bad = int(np.flatnonzero(~np.isfinite(conf) | (conf < 0))[0])
        raise PriortrackError(f"{where}: keypoint {bad} has confidence {conf[bad]} (must be finite and ≥ 0)")
    bad = (conf > 0) & ~np.isfinite(arr[:, :2]).all(axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise PriortrackError(f"{where}: keypoint {k} has confidence {conf[k]} but coordinates {arr[k, :2].tolist()}")
    arr[conf == 0, :2] = np.nan                              # OpenPose writes (0, 0, 0) for "not found"
    return arr


def _camera_folders(path: Path) -> list[Path]:
    """``path`` itself if it holds JSON files, else its sub-folders that do (sorted)."""
    if any(path.glob("*.json")):
        return [path]
    folders = sorted(p for p in path.iterdir() if p.is_dir() and any(p.glob("*.json")))
    if not folders:
        raise PriortrackError(f"{path}: no OpenPose JSON files in it or in its sub-folders")
    if len(folders) > MAX_CAMERAS:
        raise PriortrackError(f"{path}: {len(folders)} camera folders (at most {MAX_CAMERAS})")
    return folders


def openpose_cameras(path: Path, keypoints: str | None):
    """An OpenPose folder (or folder of camera folders): (camera names (C,), frames (T,), the layouts it may have
    (:func:`~priortrack.data.keypoints.layout_candidates`; :func:`~priortrack.data.keypoints.settled_layout` decides
    once the keypoints are read), K, people)
    where ``people(c)`` yields camera c's frames' people, (K, 3) each, in frame order, one file parsed at a
    time and each person's keypoint count checked as it is read."""
    folders = _camera_folders(path)
    files = [_frame_files(folder) for folder in folders]
    frames = np.array(sorted(set().union(*files)))
    check_frames(frames, str(path))
    numbers = frames.tolist()
    K = _keypoint_count(files, numbers, path)

    def people(c: int) -> Iterator[list[np.ndarray]]:
        return _with_count((_people(files[c][n]) if n in files[c] else [] for n in numbers), K, path)

    return tuple(f.name for f in folders), frames, layout_candidates(keypoints, K, str(path)), K, people


def _read_openpose(path: Path, keypoints: str | None, person: int | None) -> Detections:
    """Each camera's files parsed one at a time, in frame order, as its person is followed: a file's people
    are let go once the followed one is kept (an hour of several people's detections is not held at once)."""
    cameras, frames, candidates, K, people = openpose_cameras(path, keypoints)
    out = np.full((len(cameras), len(frames), K, 3), np.nan, dtype=np.float32)
    switches = tuple(follow(people(c), out[c], person, name) for c, name in enumerate(cameras))
    layout = settled_layout(out, candidates, str(path))
    return Detections(layout, cameras, frames, None, str(path), switches, keypoints=out)


def _frame_files(folder: Path) -> dict[int, Path]:
    """A camera folder's OpenPose files by frame number (a number twice is refused)."""
    files: dict[int, Path] = {}
    for f in sorted(folder.glob("*.json")):
        number = _frame_number(f)
        if number in files:
            raise PriortrackError(f"{folder}: frame {number} appears twice ({files[number].name}, {f.name})")
        files[number] = f
    return files


def _keypoint_count(files: list[dict[int, Path]], numbers: list[int], path: Path) -> int:
    """K, the keypoints of the first person seen (the cameras' files parsed in frame order until one is)."""
    for by_frame in files:
        for n in numbers:
            if n in by_frame and (people := _people(by_frame[n])):
                return len(people[0])
    raise PriortrackError(f"{path}: nobody is detected in any frame")


def _with_count(frames: Iterable[list[np.ndarray]], K: int, where: Path) -> Iterator[list[np.ndarray]]:
    """The frames' people, each checked to have K keypoints as it is read."""
    for people in frames:
        for p in people:
            if len(p) != K:
                raise PriortrackError(f"{where}: people have different keypoint counts ({sorted({K, len(p)})})")
        yield people


def check_frames(frames: np.ndarray, where: str) -> None:
    if len(frames) > MAX_FRAMES:
        raise PriortrackError(f"{where}: {len(frames)} frames (at most {MAX_FRAMES})")
    if len(frames) < 1:
        raise PriortrackError(f"{where}: no frames")


def _size(p: np.ndarray) -> float:
    xy = p[np.isfinite(p[:, :2]).all(axis=1), :2]
    return float(np.linalg.norm(xy.max(axis=0) - xy.min(axis=0))) if len(xy) > 1 else 0.0


def follow(people: Iterable[list[np.ndarray]], out: np.ndarray, person: int | None, camera: str) -> int:
    """Write into ``out`` (T, K, 3) (NaN where nobody is followed) the keypoints of the person followed through
    one camera's T frames of people, read in order (module docstring); returns the number of frames left
    missing as possible switches."""
    if person is not None:
        for t, frame in enumerate(people):
            if person < len(frame):
                out[t] = frame[person]
        return 0
    last, switches, rejected = None, 0, 0
    for t, frame in enumerate(people):
        frame = [p for p in frame if np.isfinite(p[:, :2]).all(axis=1).any()]
        if not frame:
            continue
        if last is None or rejected >= REACQUIRE:
            if last is not None:
                log.warning("camera %s, frame index %d: following the most confident person again", camera, t)
            chosen, rejected = max(frame, key=lambda p: np.nansum(p[:, 2])), 0
        else:
            distances = [_distance(p, last) for p in frame]
            best = int(np.argmin(distances))
            if not distances[best] <= SWITCH_GATE * max(_size(last), _size(frame[best]), MIN_SIZE_PX):
                switches, rejected = switches + 1, rejected + 1
                log.warning("camera %s, frame index %d: no detection near the person followed (nearest %.0f px); "
                            "left missing", camera, t, distances[best])
                continue
            chosen, rejected = frame[best], 0
        out[t] = chosen
        last = chosen
    return switches


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """Median distance over the keypoints both (K, 3) have, or between centroids if they share none."""
    seen_a, seen_b = np.isfinite(a[:, :2]).all(axis=1), np.isfinite(b[:, :2]).all(axis=1)
    both = seen_a & seen_b
    if both.any():
        return float(np.median(np.linalg.norm(a[both, :2] - b[both, :2], axis=1)))
    return float(np.linalg.norm(a[seen_a, :2].mean(axis=0) - b[seen_b, :2].mean(axis=0)))


# ---- COCO results and NPZ ---------------------------------------------------------------------

def coco_people(path: Path) -> tuple[dict[int, list[np.ndarray]], int]:
    """A COCO results file's people by frame (``image_id``: a list of (K, 3) keypoints each; an entry with an
    empty keypoint list is nobody) and K, checked: one keypoint count, frame numbers whole."""
    try:
        data = json.loads(path.read_text(errors="replace"))
    except json.JSONDecodeError as exc:
        raise PriortrackError(f"{path}: not valid JSON ({exc})") from None
    if isinstance(data, dict) and "people" in data:
        raise PriortrackError(f"{path}: an OpenPose JSON file; give the folder that holds the frames' files")
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
    return by_frame, counts.pop()


def _read_coco_results(path: Path, keypoints: str | None, person: int | None) -> Detections:
    by_frame, K = coco_people(path)
    candidates = layout_candidates(keypoints, K, str(path))
    frames = np.array(sorted(by_frame))
    check_frames(frames, str(path))
    followed = np.full((1, len(frames), K, 3), np.nan, dtype=np.float32)
    switches = follow([by_frame[int(n)] for n in frames], followed[0], person, path.stem)
    layout = settled_layout(followed, candidates, str(path))
    return Detections(layout, (path.stem,), frames, None, str(path), (switches,), keypoints=followed)


def _npz_source(path: Path, keypoints: str | None) -> "Detections | DetectionFile":
    on_disk = npz_member_on_disk(path, "keypoints")            # None: compressed, read whole with the rest
    arrays = read_npz(path, MAX_NPZ_BYTES, "detections file", skip=() if on_disk is None else ("keypoints",))
    if "keypoint_names" not in arrays:
        raise PriortrackError(f"{path}: the array 'keypoint_names' is missing")
    kp = arrays.get("keypoints")
    shape, dtype = (kp.shape, kp.dtype) if on_disk is None else (on_disk.shape, on_disk.dtype)
    if len(shape) != 4 or shape[-1] != 3 or dtype.kind not in "fiu":
        raise PriortrackError(f"{path}: keypoints has shape {shape} ({dtype}); expected (cameras, frames, "
                              f"keypoints, 3) numbers")
    C, T, K, _ = shape
    if not 1 <= C <= MAX_CAMERAS or T < 1:
        raise PriortrackError(f"{path}: keypoints has {C} cameras and {T} frames")
    layout, order, frames, fps, names_c = npz_header(path, arrays, C, T, K, keypoints)
    source = DetectionFile(layout, names_c, frames, fps, str(path), (0,) * C, array=on_disk, order=order)
    return source if kp is None else source.in_memory(cleaned_keypoints(kp, source.order, source.source))


def npz_header(path: Path, arrays: dict, C: int, T: int, K: int, keypoints: str | None):
    """What an .npz of detections says besides its keypoints, checked: (layout, the stored keypoints of the
    layout in its order (K,), frames (T,) int, fps or None, camera names (C,)), from its ``keypoint_names``
    and optional ``frames``, ``fps``, ``camera_names``; ``keypoints`` the layout the user named, or None."""
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
    return layout, tuple(int(k) for k in order), frames.astype(int), fps, cameras


def _npy_source(path: Path, keypoints: str | None) -> "Detections | DetectionFile":
    """FreeMoCap-style 2D: an array (cameras, frames, points, 2 or 3) of x, y[, confidence], NaN (or
    (0, 0, 0)) where missing; MediaPipe's 33 body points first (FreeMoCap's 543 = body, hands, face)."""
    from priortrack.data.npz import npy_on_disk, read_npy

    on_disk = npy_on_disk(path, MAX_NPZ_BYTES, "detections array")
    kp = read_npy(path, MAX_NPZ_BYTES, "detections array") if on_disk is None else None
    shape, dtype = (kp.shape, kp.dtype) if on_disk is None else (on_disk.shape, on_disk.dtype)
    if len(shape) != 4 or shape[-1] not in (2, 3) or dtype.kind not in "fiu":
        raise PriortrackError(f"{path}: an array of shape {shape} ({dtype}); expected (cameras, frames, points, "
                              f"2 or 3) numbers")
    C, T, P, D = shape
    if not 1 <= C <= MAX_CAMERAS or T < 1:
        raise PriortrackError(f"{path}: {C} cameras and {T} frames")
    if keypoints is not None:
        key = keypoints.lower().replace("_", "").replace("-", "")
        layout = layout_for(keypoints, len(LAYOUTS[key]) if key in LAYOUTS else -1, str(path))
    elif P == FREEMOCAP_POINTS or any(len(v) == P for v in LAYOUTS.values()):
        layout = "mediapipe33" if P == FREEMOCAP_POINTS else layout_for(None, P, str(path))
    else:
        raise PriortrackError(f"{path}: {P} points per frame fit no layout (FreeMoCap's MediaPipe: 33 or "
                              f"{FREEMOCAP_POINTS}); say which with --keypoints ({', '.join(LAYOUTS)})")
    K = len(LAYOUTS[layout])
    if P < K:
        raise PriortrackError(f"{path}: {P} points per frame, fewer than layout {layout}'s {K}")
    if D == 2:
        log.warning("%s: no confidence in the array; every point is taken at confidence 1", path)
    source = DetectionFile(layout, tuple(f"cam_{c}" for c in range(C)), np.arange(T), None, str(path), (0,) * C,
                           array=on_disk, order=tuple(range(K)))
    return source if kp is None else source.in_memory(cleaned_keypoints(kp, source.order, source.source))


def cleaned_keypoints(stored: np.ndarray, order: tuple[int, ...], where: str, first: int = 0) -> np.ndarray:
    """(C, T, K, 3) float32 keypoints of a layout from a file's (C, T, P, 2 or 3) x, y[, confidence]: its
    points ``order`` (the layout's, in the layout's order), confidence 1 where the file has none, checked (no
    inf, no negative confidence: refused, naming the [camera, frame, keypoint] counted from ``first``), and NaN
    where missing (a NaN, confidence 0, or the point (0, 0) as OpenPose writes it)."""
    with np.errstate(over="ignore"):                # beyond float32's range: inf, refused below
        kp = stored[:, :, list(order)].astype(np.float32)
    if kp.shape[-1] == 2:
        kp = np.concatenate([kp, np.ones(kp.shape[:-1] + (1,), dtype=np.float32)], axis=-1)

    def at(bad: np.ndarray) -> list[int]:
        return (np.argwhere(bad)[0] + [0, first, 0]).tolist()

    if np.isinf(kp).any():
        raise PriortrackError(f"{where}: keypoints has inf or a value beyond float32's range (first at "
                              f"{at(np.isinf(kp).any(axis=-1))}); NaN marks a missing keypoint")
    if (kp[..., 2] < 0).any():
        raise PriortrackError(f"{where}: keypoints has negative confidences (first at {at(kp[..., 2] < 0)})")
    kp[np.isnan(kp).any(axis=-1) | (kp[..., 2] == 0) | (kp[..., :2] == 0).all(axis=-1)] = np.nan
    return kp


@dataclass(frozen=True)
class DetectionFile(DetectionsHeader):
    """Detections of an .npz or .npy whose keypoints stay in the file and are read a block of frames at a
    time: :class:`Detections`' fields and its :meth:`eval15` of a block, without the (C, T, K, 3) array in
    memory, so that tracking a long recording (:func:`~priortrack.tracking.person.track_detections`)
    does not hold it. Each block is checked as it is read (:func:`cleaned_keypoints`). :func:`open_detections`
    gives one; :meth:`load` reads it whole.

    Attributes (keyword only, after :class:`DetectionsHeader`'s; its ``frames`` may be the first T of the
    stored frames: :meth:`head`):
        array: the stored keypoints (C, T_stored, P, 2 or 3) on disk (:class:`~priortrack.data.npz.ArrayOnDisk`;
            None where they were read whole).
        order: (K,) the stored points of the layout, in its order."""

    array: ArrayOnDisk | None = field(kw_only=True)
    order: tuple[int, ...] = field(kw_only=True)

    def keypoints_of(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """(C, stop − start, K, 3) float32 keypoints of the frames [start, stop) (:func:`cleaned_keypoints`)."""
        stop = len(self.frames) if stop is None else min(stop, len(self.frames))
        return cleaned_keypoints(self.array.columns(start, stop), self.order, self.source, start)

    def eval15(self, min_confidence: float = 0.3, start: int = 0, stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`Detections.eval15` of the frames [start, stop), read from the file."""
        return _eval15(self.keypoints_of(start, stop), self.keypoint_names, min_confidence)

    def head(self, n: int) -> "DetectionFile":
        """The first ``n`` frames (all of them if there are fewer)."""
        return replace(self, frames=self.frames[:_count(n)])

    def in_memory(self, keypoints: np.ndarray) -> Detections:
        """These detections with their (C, T, K, 3) ``keypoints`` (cleaned) in memory."""
        return Detections(self.layout, self.camera_names, self.frames, self.fps, self.source, self.switches,
                          keypoints=keypoints)

    def load(self) -> Detections:
        """Every frame's keypoints, read into memory."""
        return self.in_memory(self.keypoints_of())
