"""``priortrack eval against-trc``: our output beside another tool's TRC of the same person (Pose2Sim's).

The detections are tracked as a user would (``track --people all``, at the detections' rate with every keypoint),
filtered and smoothed, each with and without the 6 Hz low-pass (:mod:`priortrack.tracking.lowpass`); the person
nearest the reference (median distance over the 12 limb joints) is compared with it, marker by marker under the
reference's names (case-insensitive), frame by frame (the reference's rows are the detections' frames from the
first, as Pose2Sim writes a trial), as the median distance over the 12 limb joints and over the feet markers (big
toes, small toes, heels), and the right wrist's acceleration RMS by central differences at the frame rate beside
the reference's own. The reference is no truth (it is another tracker's triangulation); the figures say how near we
are to what the user compares us with, and how smooth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from priortrack.data.trc import read_trc
from priortrack.errors import PriortrackError

#: The runs compared: (label, smoothed, low-pass cut-off in Hz or None).
VARIANTS = (("filtered", False, None), ("--lowpass 6", False, 6.0), ("--smooth", True, None),
            ("--smooth --lowpass 6", True, 6.0))
LIMB_MARKERS = tuple(f"{s}{p}" for s in "LR" for p in ("Shoulder", "Elbow", "Wrist", "Hip", "Knee", "Ankle"))
FEET_MARKERS = tuple(f"{s}{p}" for s in "LR" for p in ("BigToe", "SmallToe", "Heel"))


def acceleration_rms(points: np.ndarray, fps: float) -> float:
    """√ mean |a|² of a point's track (F, 3), a_t = (x_{t+1} − 2 x_t + x_{t−1}) fps² (central differences), NaN
    frames left out."""
    a = (points[2:] - 2 * points[1:-1] + points[:-2]) * fps ** 2
    return float(np.sqrt(np.nanmean(np.sum(a ** 2, axis=-1))))


def _markers(result) -> tuple[np.ndarray, list[str]]:
    """One person's written markers (F, M, 3) (:meth:`~priortrack.tracking.person.DetectionTrack.markers`) and their
    names, lower case."""
    points, names = result.markers()
    return points, [n.lower() for n in names]


def _distance_to(person, frames: np.ndarray, theirs: np.ndarray, their_names: list[str], markers) -> float | None:
    """The median distance, metres, between one person's written markers and the reference's rows (the detections'
    ``frames`` from the first) over the frames both have and the ``markers`` both name; None where they share none."""
    ours, names = _markers(person)
    common = [m.lower() for m in markers if m.lower() in names and m.lower() in their_names]
    rows = np.searchsorted(frames, person.frames)
    both = rows < len(theirs)
    if not common or not both.any():
        return None
    a = ours[both][:, [names.index(m) for m in common]]
    b = theirs[rows[both]][:, [their_names.index(m) for m in common]]
    return float(np.nanmedian(np.linalg.norm(a - b, axis=-1)))


def against_trc(detections: str | Path, cameras: str | Path, reference: str | Path, fps: float | None = None,
                preset: str = "ukf-real", keypoints: str | None = None, camera_map: dict[str, str] | None = None,
                height: float | None = None, floor: float | None = 0.0) -> dict:
    """The table of the module docstring: {"person": id, "frames", "fps", "reference_wrist_m_s2", "rows": [{"run",
    "limbs_mm", "feet_mm", "wrist_m_s2"}]}; ``camera_map``, ``height`` and ``floor`` as ``track`` takes them (one camera: the
    body's size and depth)."""
    from priortrack.data.calibration import read_calibration
    from priortrack.data.scene_detections import read_scene_detections
    from priortrack.tracking.people import track_scene
    from priortrack.tracking.person import TrackConfig

    scene = read_scene_detections(detections, keypoints=keypoints)
    calibration = read_calibration(cameras)
    rows, chosen = [], None
    for smooth in (False, True):
        tracked = track_scene(scene, calibration, preset, TrackConfig(fps=fps, smooth=smooth, camera_map=camera_map,
                                                                  height=height, floor=floor)
                              ).at_detection_frames()
        up = tracked.people[0].up
        if not (isinstance(up, str) and up in ("y", "z")):
            raise PriortrackError(f"{cameras}: a TRC is compared in a Y-up or Z-up world; this calibration's up is {up!r}")
        theirs, their_names, their_fps = read_trc(reference, up=up)
        their_names = [n.lower() for n in their_names]
        if chosen is None:                           # the person the reference is of: nearest over the limbs
            gaps = [_distance_to(p, scene.frames, theirs, their_names, LIMB_MARKERS) for p in tracked.people]
            if all(g is None for g in gaps):
                raise PriortrackError(f"{reference}: none of its markers is a limb joint's ({', '.join(LIMB_MARKERS)})")
            chosen = int(tracked.person_ids[int(np.argmin([np.inf if g is None else g for g in gaps]))])
        own = tracked.people[tracked.person_ids.tolist().index(chosen)]
        for label, smoothed, cutoff in VARIANTS:
            if smoothed != smooth:
                continue
            person = own if cutoff is None else own.low_passed(cutoff)
            feet = _distance_to(person, scene.frames, theirs, their_names, FEET_MARKERS)
            ours, names = _markers(person)
            rows.append({"run": label,
                         "limbs_mm": 1000 * _distance_to(person, scene.frames, theirs, their_names, LIMB_MARKERS),
                         "feet_mm": None if feet is None else 1000 * feet,
                         "wrist_m_s2": acceleration_rms(ours[:, names.index("rwrist")], person.fps)})
    wrist = their_names.index("rwrist") if "rwrist" in their_names else None
    return {"person": chosen, "frames": int(len(own.joints)), "fps": float(own.fps), "preset": preset,
            "reference_wrist_m_s2": None if wrist is None else acceleration_rms(theirs[:, wrist], their_fps),
            "rows": rows}
