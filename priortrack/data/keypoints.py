"""2D keypoint layouts of pose detectors, and their map to the 15 ``eval15`` joints.

One table per layout names its keypoints in the detector's order:

- ``body25``: OpenPose BODY_25; ``body25b``: OpenPose's experimental BODY_25B (what Pose2Sim
  uses); ``coco18``: OpenPose's COCO model; ``coco17``: the COCO keypoints (MMPose, RTMPose,
  ViTPose, YOLO-pose); ``mediapipe33``: MediaPipe Pose's landmarks, named as its ``PoseLandmark``
  in lower case.

Keypoint names in a file may be ours or the detector's own, in any order (:func:`layout_of_names`):
OpenPose's ``LShoulder``, ``RBigToe``, ``MidHip`` (BODY_25B's ``Neck`` and ``Head`` are its
``upper_neck`` and ``head_top``), MediaPipe's ``LEFT_SHOULDER``, COCO's ``left_shoulder``.

The eval15 joints are taken from keypoints of the same name (shoulders, elbows, wrists, hips,
knees, ankles), and the three a detector lacks are derived, the same way for every layout:

    pelvis = mid-hips,   neck = mid-shoulders,   head = the head-top where the layout has one
    (BODY_25B), else mid-ears (one definition per layout: never mixed from frame to frame).

A derived joint is observed only where all its parts are, with the smallest of their confidences.
These are the detector's joint definitions, not a mocap skeleton's: the mocap pelvis (CMU's root)
lies some 10 cm above the mid-hips, its neck (the thorax's top) above the mid-shoulders. A body's
eval15 joints X (15, 3) are taken to the detector's definitions by the linear map
:func:`detector_map` (rows summing to one, so a translation of the body moves them alike); the
head is the body's head top in every layout (for the layouts without one, mid-ears stands for it:
an approximation, a few centimetres low).
"""

from __future__ import annotations

import logging
import re

import numpy as np

from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.errors import PriortrackError

log = logging.getLogger(__name__)

_LR = ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")

LAYOUTS: dict[str, tuple[str, ...]] = {
    "body25": ("nose", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder", "left_elbow",
               "left_wrist", "mid_hip", "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee",
               "left_ankle", "right_eye", "left_eye", "right_ear", "left_ear", "left_big_toe", "left_small_toe",
               "left_heel", "right_big_toe", "right_small_toe", "right_heel"),
    "body25b": ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
                "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
                "right_knee", "left_ankle", "right_ankle", "upper_neck", "head_top", "left_big_toe",
                "left_small_toe", "left_heel", "right_big_toe", "right_small_toe", "right_heel"),
    "coco18": ("nose", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder", "left_elbow",
               "left_wrist", "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle",
               "right_eye", "left_eye", "right_ear", "left_ear"),
    "coco17": ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
               "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
               "right_knee", "left_ankle", "right_ankle"),
    "mediapipe33": ("nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
                    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
                    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
                    "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip", "right_hip",
                    "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel", "right_heel",
                    "left_foot_index", "right_foot_index"),
}

#: eval15 joint → the keypoints it is the mean of (in order of preference for the head).
EVAL15_PARTS: dict[str, tuple[tuple[str, ...], ...]] = {
    "pelvis": (("left_hip", "right_hip"),),
    "neck": (("left_shoulder", "right_shoulder"),),
    "head": (("head_top",), ("left_ear", "right_ear")),
    **{f"{side[0]}{part}": ((f"{side}_{part}",),) for side in ("left", "right") for part in _LR},
}


#: Per layout, the detector's own names that are not ours after :func:`_snake` (BODY_25B as Pose2Sim
#: names it: "Neck" is the upper neck, "Head" the head top).
_DETECTOR_NAMES = {"body25b": {"neck": "upper_neck", "head": "head_top"}}


def _snake(name: str) -> str:
    """A detector's keypoint name in ours: "LShoulder" → "left_shoulder", "RBigToe" →
    "right_big_toe", "MidHip" → "mid_hip", "LEFT_SHOULDER" → "left_shoulder"."""
    name = str(name).strip()
    name = re.sub(r"^([LR])(?=[A-Z][a-z])", lambda m: {"L": "Left", "R": "Right"}[m.group(1)], name)
    name = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name)
    return re.sub(r"[\s-]+", "_", name).lower()


def layout_of_names(names: tuple[str, ...], where: str) -> tuple[str, np.ndarray]:
    """The layout whose keypoints ``names`` are, in any order and in ours or the detector's spelling,
    and the (K,) index putting a file's keypoints in the layout's order."""
    spelled = [_snake(n) for n in names]
    for layout, ours in LAYOUTS.items():
        aliases = _DETECTOR_NAMES.get(layout, {})
        mine = [aliases.get(n, n) if n not in ours else n for n in spelled]
        if len(mine) == len(ours) and sorted(mine) == sorted(ours):
            position = {n: i for i, n in enumerate(mine)}
            return layout, np.array([position[n] for n in ours])
    raise PriortrackError(f"{where}: keypoint names ({len(names)}: {', '.join(map(str, names[:5]))}, …) are not one "
                          f"layout's ({', '.join(f'{k}: {len(v)}' for k, v in LAYOUTS.items())}); names are ours "
                          f"(left_shoulder) or the detector's (LShoulder, LEFT_SHOULDER); see priortrack.data.keypoints")


def detector_map() -> np.ndarray:
    """M (15, 15): the detector-defined eval15 joints M X of a body's eval15 joints X (15, 3):
    pelvis = ½ (lhip + rhip), neck = ½ (lshoulder + rshoulder), every other joint itself."""
    M = np.eye(15)
    index = {n: i for i, n in enumerate(EVAL15_NAMES)}
    for joint, (a, b) in (("pelvis", ("lhip", "rhip")), ("neck", ("lshoulder", "rshoulder"))):
        M[index[joint]] = 0.0
        M[index[joint], [index[a], index[b]]] = 0.5
    return M


def layout_candidates(name: str | None, count: int, where: str) -> tuple[str, ...]:
    """The layouts keypoints that number ``count`` may have: ``name`` (any case) checked against the count, or
    every layout with that many keypoints (BODY_25 and BODY_25B both have 25: :func:`settled_layout` tells them
    apart by the keypoints themselves)."""
    if name is not None:
        key = name.lower().replace("_", "").replace("-", "")
        if key not in LAYOUTS:
            raise PriortrackError(f"unknown keypoint layout {name!r}; layouts: {', '.join(LAYOUTS)}")
        if len(LAYOUTS[key]) != count:
            raise PriortrackError(f"{where}: {count} keypoints per person, but layout {key} has {len(LAYOUTS[key])}")
        return (key,)
    matches = tuple(k for k, names in LAYOUTS.items() if len(names) == count)
    if not matches:
        raise PriortrackError(f"{where}: {count} keypoints per person fit no layout "
                              f"({', '.join(f'{k}: {len(v)}' for k, v in LAYOUTS.items())})")
    return matches


def layout_for(name: str | None, count: int, where: str) -> str:
    """The one layout of :func:`layout_candidates` (for a reader that cannot look at the keypoints: a name is
    needed where two layouts have ``count`` keypoints)."""
    matches = layout_candidates(name, count, where)
    if len(matches) > 1:
        raise PriortrackError(f"{where}: {count} keypoints fit {' and '.join(matches)}; say which with "
                              f"--keypoints ({', '.join(matches)})")
    return matches[0]


#: BODY_25's keypoint 8 (MidHip) lies midway between 9 and 12 (its hips); BODY_25B's 8, 9 and 12 (right elbow, left
#: wrist, right hip) do not: the median over people and frames of |k8 − (k9 + k12) / 2| over the person's size (their
#: keypoints' box diagonal) is under this for BODY_25 (Shelf's OpenPose: 0.004, 90th percentile 0.01) and far over it
#: for BODY_25B (Pose2Sim's two demos: 0.25 and 0.28, 10th percentile 0.07 and 0.12) …
MIDHIP_TOLERANCE = 0.05
#: … judged where this many people-frames show all three.
MIN_JUDGED = 10


_NAMES = {"body25": "BODY_25", "body25b": "BODY_25B"}


def _midhip_gap(keypoints: np.ndarray, min_confidence: float) -> tuple[float | None, int]:
    """The median over people-frames of |k8 − (k9 + k12) / 2| over the person's size (their keypoints' box diagonal)
    of 25-keypoint detections (..., 25, 3), and the people-frames judged; None where fewer than ``MIN_JUDGED``."""
    kp = np.asarray(keypoints, dtype=np.float64).reshape(-1, 25, 3)
    xy = np.where((np.nan_to_num(kp[..., 2:]) > min_confidence) & np.isfinite(kp[..., :2]), kp[..., :2], np.nan)
    shown = np.isfinite(xy[:, [8, 9, 12]]).all(axis=(-1, -2))
    if shown.sum() < MIN_JUDGED:
        return None, int(shown.sum())
    xy = xy[shown]
    size = np.linalg.norm(np.fmax.reduce(xy, axis=1) - np.fmin.reduce(xy, axis=1), axis=-1)
    gap = float(np.median(np.linalg.norm(xy[:, 8] - 0.5 * (xy[:, 9] + xy[:, 12]), axis=-1) / np.maximum(size, 1e-9)))
    return gap, int(shown.sum())


def settled_layout(keypoints: np.ndarray, candidates: tuple[str, ...], where: str, min_confidence: float = 0.3) -> str:
    """The layout of keypoints (..., K, 3) among ``candidates`` (:func:`layout_candidates`). BODY_25 and BODY_25B are
    told apart by keypoint 8 (:data:`MIDHIP_TOLERANCE`): where both were possible (no ``--keypoints``), the one the
    keypoints show is taken and logged; where one was named, keypoints that are the other's are refused (every point
    of a wrong layout is some other joint, and the bodies it makes are no one's); too few people-frames to tell: a
    named layout is taken as named, two possible ones need a name."""
    if not set(candidates) <= set(_NAMES):
        return candidates[0]
    gap, judged = _midhip_gap(keypoints, min_confidence)
    if gap is None:
        if len(candidates) == 1:
            return candidates[0]
        raise PriortrackError(f"{where}: 25 keypoints fit body25 and body25b, and too few people-frames ({judged}) show "
                              f"keypoints 8, 9 and 12 to tell which; say which with --keypoints (body25, body25b)")
    midway = gap < MIDHIP_TOLERANCE
    found = "body25" if midway else "body25b"
    why = (f"keypoint 8 is {'' if midway else 'not '}the midpoint of 9 and 12 (median distance {gap:.3f} of the "
           f"person's size over {judged} people-frames; BODY_25's MidHip is within {MIDHIP_TOLERANCE}, BODY_25B's right "
           f"elbow is not)")
    if len(candidates) > 1:
        log.info("%s: read as %s: %s (--keypoints to say otherwise)", where, _NAMES[found], why)
        return found
    if found != candidates[0]:
        raise PriortrackError(f"{where}: read as {_NAMES[candidates[0]]} (--keypoints {candidates[0]}), but its {why}: "
                              f"{_NAMES[found]} detections? --keypoints {found}")
    return found


def to_eval15(keypoints: np.ndarray, names: tuple[str, ...], min_confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """(..., K, 3) keypoints (x, y, confidence) named ``names`` → eval15 pixels (..., 15, 2), NaN where
    missing, and confidences (..., 15), 0 where missing, in the keypoints' float dtype (float64 for
    integers). A keypoint is observed when x, y and its confidence are finite and the confidence is at
    least ``min_confidence`` (and above 0)."""
    index = {n: i for i, n in enumerate(names)}
    xy, conf = keypoints[..., :2], keypoints[..., 2]
    seen = np.isfinite(xy).all(axis=-1) & np.isfinite(conf) & (conf >= min_confidence) & (conf > 0)
    dtype = keypoints.dtype if keypoints.dtype.kind == "f" else np.float64
    uv = np.full(keypoints.shape[:-2] + (15, 2), np.nan, dtype=dtype)
    confidence = np.zeros(keypoints.shape[:-2] + (15,), dtype=dtype)
    for j, joint in enumerate(EVAL15_NAMES):
        options = [parts for parts in EVAL15_PARTS[joint] if all(p in index for p in parts)]
        if not options:
            raise PriortrackError(f"the keypoints ({len(names)}: {', '.join(names[:4])}, …) have nothing for the "
                                  f"eval15 joint {joint!r} (looked for {EVAL15_PARTS[joint]})")
        k = [index[p] for p in options[0]]                  # one definition per layout, never mixed
        ok = seen[..., k].all(axis=-1)
        uv[..., j, :] = np.where(ok[..., None], xy[..., k, :].mean(axis=-2), np.nan)
        confidence[..., j] = np.where(ok, conf[..., k].min(axis=-1), 0.0)
    return uv, confidence
