"""Every person of a scene tracked by a filter preset: the scene tracker decides who is who
(:mod:`priortrack.tracking.scene`), then each kept person's own detections are tracked by the preset
with their own body (:func:`~priortrack.tracking.person.track_detections`: their bones measured over
their whole trial, their start, their filter), and the people are gathered on one tick grid. With
``SceneConfig(association="filter")`` (the default on two or three cameras, :meth:`SceneConfig.decided_by`) the
people's filters are stepped together in this process instead, and each tick's detections decided again through
their predictions (:mod:`~priortrack.tracking.reassociation`).

:func:`track_scene` gives a :class:`SceneTrack`: ``joints`` (T, P, 15, 3) in the calibration's world,
NaN where a person is not in the scene (before they appear, after their track ended and until they
return); each person's spread, log-likelihood and mismatch flags on the same grid; and each person's
whole single-person result (:class:`~priortrack.tracking.person.DetectionTrack`) for their recording,
BVH and TRC.

Which people: ``people="all"``; an int N (the N seen most: :func:`seen_most`); a list of ids, or of
``("at", camera, (x, y))`` / ``("box", camera, (x0, y0, x1, y1))``: the person there in that camera's
first frame with people; ``("index", N)``: the person at index N of each frame's list, no scene tracker (files whose
people keep their order); :func:`parse_people` reads the command line's forms.
"""

from __future__ import annotations

import csv
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from priortrack.data.calibration import Calibration
from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.data.scene_detections import SceneDetections
from priortrack.data.skeleton import Skeleton
from priortrack.errors import PriortrackError
from priortrack.tracking.person import (DetectionTrack, TrackConfig, data_rate, fitted_once, match_cameras, output_path,
                                         prepared, schedule, track_detections, up_from_detections)
from priortrack.geometry.camera import PinholeCamera
from priortrack.tracking.presets import Preset, load_preset
from priortrack.tracking.reassociation import predicts, reassociated
from priortrack.tracking.single_view import MIN_BONES
from priortrack.tracking.lowpass import lowpassed
from priortrack.tracking.resample import frame_times, interpolated, nearest_tick
from priortrack.tracking.scene import SceneAssociation, SceneConfig, SceneTracker

log = logging.getLogger(__name__)



def parse_people(words: list[str] | str | None):
    """The people asked for on the command line: ``all``; N (the N seen most, :func:`seen_most`); ``id:A,B``;
    ``at:CAMERA:X,Y`` (the person at that pixel of the camera's first frame with people); ``box:CAMERA:X0,Y0,X1,Y1``
    (the person whose keypoints' box overlaps it most there); ``index:N`` (the person at index N of each frame's list,
    for files whose people keep their order: :func:`indexed`). Returns what :func:`chosen_people` takes."""
    words = [words] if isinstance(words, str) else list(words or ["all"])
    if words == ["all"]:
        return "all"
    if len(words) == 1 and words[0].isdigit():
        return int(words[0])
    if any(word.startswith("index:") for word in words):
        number = words[0].partition(":")[2]
        if len(words) > 1 or not number.isdigit():
            raise PriortrackError(f"--people {' '.join(words)}: index:N alone, N a whole number ≥ 0 (the person at "
                                  f"that index of each frame's list of people)")
        return ("index", int(number))
    chosen = []
    for word in words:
        kind, _, rest = word.partition(":")
        try:
            if kind == "id":
                chosen += [int(v) for v in rest.split(",")]
                continue
            camera, _, numbers = rest.rpartition(":")
            values = tuple(float(v) for v in numbers.split(","))
            if kind in ("at", "box") and camera and len(values) == (2 if kind == "at" else 4):
                chosen.append((kind, camera, values))
                continue
        except ValueError:
            pass
        raise PriortrackError(f"--people {word}: give all, a number N, id:A,B, at:CAMERA:X,Y or "
                              f"box:CAMERA:X0,Y0,X1,Y1")
    return chosen


def seen_most(association: SceneAssociation, scene: SceneDetections | None, min_confidence: float = 0.3) -> np.ndarray:
    """(P,) how much each person of ``association`` was seen: the keypoints detected (confidence ≥ ``min_confidence``)
    over every camera and frame of ``scene`` given to them; without the scene, the frames they were seen in. A person
    fully in view outranks one as long in view whose detector finds less of them (Pose2Sim's demo: its synthetic
    0.6 m figure, 21 keypoints a view, and the participant, 22.5: both in all 100 frames)."""
    if scene is None:
        return (association.slots >= 0).any(axis=1).sum(axis=0)
    counts = np.zeros(len(association.person_ids))
    t, c, p = np.nonzero(association.slots >= 0)
    kp = scene.keypoints[c, t, association.slots[t, c, p]]                          # (n, K, 3)
    found = np.isfinite(kp[..., :2]).all(axis=-1) & (np.nan_to_num(kp[..., 2]) >= min_confidence)
    np.add.at(counts, p, found.sum(axis=-1))
    return counts


def indexed(people) -> int | None:
    """N where ``people`` (:func:`parse_people`'s forms) asks for the person at index N of each frame's list (their
    association the files' own: :meth:`~priortrack.tracking.scene.SceneAssociation.indexed`), else None."""
    return people[1] if isinstance(people, tuple) and people[:1] == ("index",) else None


def chosen_people(association: SceneAssociation, people, scene: SceneDetections | None = None) -> list[int]:
    """Indices into ``association.person_ids`` of the people asked for (:func:`parse_people`'s forms, or
    a list of ids; N: the N :func:`seen_most`; ``index:N``'s association holds that one person)."""
    if people is None or people == "all" or indexed(people) is not None:
        return list(range(len(association.person_ids)))
    if isinstance(people, int) and not isinstance(people, bool):
        if people < 1:
            raise PriortrackError(f"people: give 'all', a number ≥ 1 or person ids, got {people}")
        return sorted(np.argsort(-seen_most(association, scene), kind="stable")[:people].tolist())
    ids = association.person_ids.tolist()
    chosen = []
    for item in people:
        if isinstance(item, tuple):
            chosen.append(_person_at(association, scene, *item))
        elif item in ids:
            chosen.append(ids.index(item))
        else:
            raise PriortrackError(f"people: no person {item} in the scene (people: "
                                  f"{', '.join(map(str, ids)) or 'none'})")
    return sorted(set(chosen))


def _person_at(association: SceneAssociation, scene: SceneDetections, kind: str, camera: str, values) -> int:
    """The person at a point (``at``) or overlapping a box (``box``) most in ``camera``'s first frame that
    holds anyone's detection."""
    if scene is None or camera not in scene.camera_names:
        raise PriortrackError(f"--people {kind}:{camera}: no camera {camera!r} (cameras: "
                              f"{', '.join(scene.camera_names) if scene is not None else 'none'})")
    c = scene.camera_names.index(camera)
    slots = association.slots[:, c]                                                 # (T, P)
    frames = np.flatnonzero((slots >= 0).any(axis=1))
    if not len(frames):
        raise PriortrackError(f"--people {kind}:{camera}: nobody tracked is seen by {camera}")
    t = int(frames[0])
    best, score, near = None, -np.inf, True
    for p in np.flatnonzero(slots[t] >= 0):
        xy = scene.keypoints[c, t, slots[t, p], :, :2]
        xy = xy[np.isfinite(xy).all(axis=1)]
        if not len(xy):
            continue
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        if kind == "at":
            s = -float(np.linalg.norm(np.clip(values, lo, hi) - np.asarray(values)))      # 0 inside the box
            close = -s <= 0.5 * float(np.linalg.norm(hi - lo))         # within half the person's size of their box
        else:
            x0, y0, x1, y1 = values
            overlap = np.clip(np.minimum(hi, [x1, y1]) - np.maximum(lo, [x0, y0]), 0, None).prod()
            s = float(overlap / ((hi - lo).prod() + (x1 - x0) * (y1 - y0) - overlap + 1e-9))
            close = overlap > 0
        if s > score:
            best, score, near = int(p), s, close
    if best is None or not near:
        raise PriortrackError(f"--people {kind}:{camera}:{','.join(f'{v:g}' for v in values)}: nobody is there in "
                              f"{camera}'s first frame with people (frame {scene.frames[t]}; "
                              f"{'the nearest person is further than half their size' if kind == 'at' else 'no person overlaps it'})")
    log.info("--people %s:%s picked person %d (frame %d)", kind, camera, association.person_ids[best],
             scene.frames[t])
    return best


@dataclass
class SceneTrack:
    """Every kept person of a scene (module docstring).

    Attributes:
        person_ids: (P,) ids (the scene tracker's, in order of first appearance).
        frames: (T,) the detection frame each tick consumed (−1 where none), fps the tick rate.
        joints: (T, P, 15, 3) metres in the calibration's world, NaN where the person is absent (no
            detection of theirs, beyond gaps the scene tracker bridges: :attr:`SceneAssociation.present`).
        spread, loglik, mismatch: (T, P, 15), (T, P), (T, P) bool per person, NaN / False where absent.
        held_out_ratio: (T, P) each person's held-out ratio (:mod:`~priortrack.tracking.held_out`), NaN where
            absent or not judged.
        people: each person's single-person result, in ``person_ids``' order.
        association: the scene tracker's decisions (slots per frame, camera and person).
        skipped: {id: why} the people asked for that could not be tracked.
        seconds: the whole run's wall time.
        detections, index: every detected person (for a recording's unassigned detections) and, per tick,
            the index of the detection frame it consumed (−1 where none).
        ess: (T, P) each person's effective sample size (NaN where absent or the filter has no particles);
        reprojection_px: (T, P, C) each person's median pixel error per camera and tick; gated: (T, P, C, 15) the
            detections each person's validation gate held out; filtered_joints: (T, P, 15, 3) the filter's own joints
            where the run was smoothed (``joints`` the smoother's), else None: one person's outputs, per person.
    """

    person_ids: np.ndarray
    frames: np.ndarray
    fps: float
    joints: np.ndarray
    spread: np.ndarray
    loglik: np.ndarray
    mismatch: np.ndarray
    held_out_ratio: np.ndarray
    people: list[DetectionTrack] = field(repr=False)
    association: SceneAssociation = field(repr=False)
    skipped: dict[int, str] = field(default_factory=dict)
    seconds: float = 0.0
    detections: SceneDetections | None = field(default=None, repr=False)
    index: np.ndarray | None = field(default=None, repr=False)
    ess: np.ndarray | None = field(default=None, repr=False)
    reprojection_px: np.ndarray | None = field(default=None, repr=False)
    gated: np.ndarray | None = field(default=None, repr=False)
    filtered_joints: np.ndarray | None = field(default=None, repr=False)
    #: The detections' frame rate (tick k is at k / fps from the first detection frame).
    data_fps: float | None = None
    #: The cut-off of the Butterworth low-pass the joints went through (:meth:`low_passed`), None where none.
    lowpass_hz: float | None = None
    #: Ctrl-C ended the run: it holds what was tracked until then.
    interrupted: bool = False
    #: {camera: frames} where a camera detected someone who is nobody for a second or more (not tracked).
    unclaimed: dict = field(default_factory=dict)
    #: (P,) the tick of this result's grid at which each person's own run (``people[p]``) starts.
    starts: np.ndarray | None = field(default=None, repr=False)

    @property
    def camera_names(self) -> tuple[str, ...]:
        return self.people[0].camera_names if self.people else ()

    def summary(self) -> dict:
        """The JSON summary: people, ticks, seconds, and per person their frames present, median
        reprojection error per camera, mismatch fraction and body measures."""
        present = np.isfinite(self.joints[..., 0, 0])
        columns = [self.association.person_ids.tolist().index(pid) for pid in self.person_ids]
        seen = self.association.slots[:, :, columns] >= 0                                 # (T_frames, C, P)
        names = self.camera_names
        per_person = {}
        for p, (pid, result) in enumerate(zip(self.person_ids, self.people)):
            own = result.summary()
            with np.errstate(invalid="ignore"):
                at = np.nanmean(self.joints[present[:, p], p, 0], axis=0) if present[:, p].any() else None
            per_person[str(int(pid))] = {
                "ticks_present": int(present[:, p].sum()), "frames_seen": int(seen[:, :, p].any(axis=1).sum()),
                "cameras": [names[c] for c in np.flatnonzero(seen[:, :, p].any(axis=0))],
                "mean_position_m": None if at is None else [float(v) for v in at],
                "height_m": own["height_m"], "height_from": own["height_from"], "reprojection_px": own["reprojection_px"],
                "mismatch_fraction": result.mismatch_fraction, "bones_m": own["bones_m"]}
        return {"people": [int(i) for i in self.person_ids], "frames": int(len(self.frames)), "fps": self.fps,
                "seconds": self.seconds, "interrupted": self.interrupted, "unclaimed_frames": self.unclaimed,
                "skipped": {str(k): v for k, v in self.skipped.items()}, "per_person": per_person}

    def low_passed(self, cutoff_hz: float) -> "SceneTrack":
        """The scene with every person's joints through a zero-lag Butterworth low-pass at ``cutoff_hz``, each over
        the frames they are present (:mod:`~priortrack.tracking.lowpass`), and each person's own result so."""
        return replace(self, joints=lowpassed(self.joints, self.fps, cutoff_hz), lowpass_hz=cutoff_hz,
                       people=[r.low_passed(cutoff_hz) for r in self.people])

    def at_detection_frames(self) -> "SceneTrack":
        """The scene at every detection frame and the detections' rate, each person's joints and spread carried to
        each frame's time and their verdicts the nearest tick's, absent where the person is
        (:mod:`~priortrack.tracking.resample`; one person's :meth:`~priortrack.tracking.person.DetectionTrack.at_detection_frames`
        each). What a file is written from."""
        frames = self.association.frames
        ticks, times = np.arange(len(self.frames)) / self.fps, frame_times(frames, self.data_fps)
        near = nearest_tick(ticks, times)
        joints = np.stack([interpolated(self.joints[:, p], ticks, times) for p in range(len(self.person_ids))], axis=1)
        present = np.isfinite(joints).all(axis=(2, 3))                                 # (F, P)

        def spline(grid):
            if grid is None:
                return None
            out = np.stack([interpolated(grid[:, p], ticks, times) for p in range(grid.shape[1])], axis=1)
            out[~present] = np.nan
            return out

        def nearest(grid, absent=np.nan):
            out = grid[near].copy()
            out[~present] = absent
            return out

        return replace(self, frames=np.asarray(frames), fps=self.data_fps, joints=joints, spread=spline(self.spread),
                       loglik=nearest(self.loglik), mismatch=nearest(self.mismatch, False),
                       held_out_ratio=nearest(self.held_out_ratio), people=[r.at_detection_frames() for r in self.people],
                       index=np.arange(len(frames)), ess=nearest(self.ess), reprojection_px=nearest(self.reprojection_px),
                       gated=nearest(self.gated, False), filtered_joints=spline(self.filtered_joints))

    def save(self, path: str | Path) -> list[Path]:
        """Write by suffix: ``.npz`` and ``.csv`` hold every person; ``.trc``, ``.mot`` and ``.bvh`` are written one
        per person, ``<stem>_person<id><suffix>``. Returns the files written."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix == ".npz":
            return [self.save_npz(path)]
        if suffix == ".csv":
            return [self.save_csv(path)]
        if suffix in (".trc", ".mot", ".bvh"):
            return [result.save(path.with_name(f"{path.stem}_person{pid}{path.suffix}"))
                    for pid, result in zip(self.person_ids, self.people)]
        raise PriortrackError(f"{path}: a scene is written as .npz, .csv, .trc, .mot or .bvh")

    def save_npz(self, path: str | Path) -> Path:
        """``joints`` (T, P, 15, 3), ``person_ids`` (P,), ``frames`` (T,), ``fps``, ``joint_names``,
        ``spread`` (T, P, 15), ``loglik`` (T, P), ``mismatch`` (T, P), ``held_out_ratio`` (T, P), ``ess`` (T, P),
        ``camera_names`` (C,), ``reprojection_px`` (T, P, C), ``gated`` (T, P, C, 15), ``filtered_joints``
        (T, P, 15, 3) where smoothed, and the association's ``slots`` (T_frames, C, P) with ``detection_frames``
        (T_frames,), ``lowpass_hz`` where the joints were low-passed, ``keypoints`` (T, P, E, 3) and ``keypoint_names``
        (E,) the detector's further keypoints where carried (at the detections' frames), each person's body
        (``height_m`` (P,), ``body_measures_m`` (P, 8), ``limbs_left_right_m`` (P, 4, 2) and their names): one
        person's fields (:meth:`~priortrack.tracking.person.DetectionTrack.save_npz`) per person."""
        path = output_path(path, "result file")
        extra = {} if self.filtered_joints is None else {"filtered_joints": self.filtered_joints}
        if self.lowpass_hz is not None:
            extra["lowpass_hz"] = np.array(float(self.lowpass_hz))
        keypoints, names = self._keypoints()
        if keypoints is not None:
            extra.update(keypoints=keypoints, keypoint_names=np.array(names, dtype=str))
        bodies = [r.body_arrays() for r in self.people]
        if bodies and all(bodies):                                   # each person's body: (P, …), names once
            extra.update({k: (v if k.endswith("names") else np.stack([b[k] for b in bodies]))
                          for k, v in bodies[0].items()})
        with open(path, "wb") as f:
            np.savez(f, joints=self.joints, person_ids=self.person_ids, frames=self.frames, fps=np.array(self.fps),
                     joint_names=np.array(EVAL15_NAMES), spread=self.spread, loglik=self.loglik,
                     mismatch=self.mismatch, held_out_ratio=self.held_out_ratio, ess=self.ess,
                     camera_names=np.array(self.camera_names), reprojection_px=self.reprojection_px,
                     gated=self.gated, slots=self.association.slots, detection_frames=self.association.frames,
                     **extra)
        return path

    def _keypoints(self) -> tuple[np.ndarray | None, tuple[str, ...]]:
        """Every person's further keypoints (T, P, E, 3) on this result's frames, NaN where they have none, and their
        names (E,); (None, ()) where not every person's were carried."""
        if not self.people or any(r.keypoints is None for r in self.people):
            return None, ()
        row = {int(f): t for t, f in enumerate(self.frames) if f >= 0}
        out = np.full((len(self.frames), len(self.people)) + self.people[0].keypoints.shape[1:], np.nan)
        for p, result in enumerate(self.people):
            out[[row[int(f)] for f in result.frames], p] = result.keypoints
        return out, self.people[0].keypoint_names

    def save_csv(self, path: str | Path) -> Path:
        """One row per tick (or frame) and present person: frame, time (s), person, each joint's x, y, z, spread,
        loglik, mismatch, then each of the detector's further keypoints' x, y, z where carried."""
        path = output_path(path, "result file")
        extra, names = self._keypoints()
        if extra is None:
            extra = np.zeros(self.joints.shape[:2] + (0, 3))
        with open(path, "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["frame", "time_s", "person"] + [f"{n}_{a}" for n in EVAL15_NAMES for a in "xyz"] +
                            [f"{n}_spread" for n in EVAL15_NAMES] + ["loglik", "mismatch"] +
                            [f"{n}_{a}" for n in names for a in "xyz"])
            for t, frame in enumerate(self.frames):
                for p, pid in enumerate(self.person_ids):
                    if np.isfinite(self.joints[t, p]).any():
                        writer.writerow([int(frame), f"{t / self.fps:.9g}", int(pid)] +
                                        [f"{v:.9g}" for v in self.joints[t, p].ravel()] +
                                        [f"{v:.9g}" for v in self.spread[t, p]] +
                                        [f"{self.loglik[t, p]:.9g}", int(self.mismatch[t, p])] +
                                        [f"{v:.9g}" for v in extra[t, p].ravel()])
        return path


def track_scene(scene: SceneDetections, calibration: Calibration, preset, config: TrackConfig | None = None,
                scene_config: SceneConfig | None = None, people="all", workers: int | None = None,
                skeleton: Skeleton | None = None, progress: Callable[[int, int], None] | None = None) -> SceneTrack:
    """Track every person of ``scene`` (module docstring) with ``preset``: who is who as ``scene_config``
    says (:class:`~priortrack.tracking.scene.SceneConfig`), each person as ``config`` says
    (:class:`~priortrack.tracking.person.TrackConfig`: its frame rate, up, camera map, confidence threshold
    and seed are the scene's too). ``workers``: processes that track people side by side (None: one per core
    this process may use; 1: every person in this process; the filters' association is tracked here). An
    ``interruptible`` run (``config.interruptible``) that Ctrl-C stops keeps what was tracked: the filters in lockstep
    end at the tick reached; tracked one by one, the person being tracked ends there and those not yet tracked are
    skipped (in workers, those not finished are); ``interrupted`` is set. A person's run in a worker is the one here,
    up to rounding where the worker's torch has fewer threads. ``progress(done, total)``: a scene of one's ticks as its filter goes, or the ticks of
    the filters stepped together, else the people tracked so far. A scene of one (``people=1``, or one id) may
    take their own body (``skeleton``)."""
    start = time.perf_counter()
    config, scene_config = config or TrackConfig(), scene_config or SceneConfig()
    data_fps = data_rate(config.fps, scene.fps, scene.source)
    preset = load_preset(preset) if not isinstance(preset, Preset) else preset
    how = "joints" if indexed(people) is not None else scene_config.decided_by(len(scene.camera_names))
    if scene_config.association == "auto" and how == "filter" and config.smooth and config.lag is not None:
        how = "joints"                                # a fixed lag releases ticks the filters' association decides
    in_lockstep = how == "filter" and predicts(preset)                               # in this process
    if how == "filter" and not in_lockstep:
        log.info("the %s filter does not predict its detections: each person is tracked on the scene tracker's "
                 "decisions", preset.filter_kind)
    log.info("who is who: decided by %s", "every person's filter, stepped together" if in_lockstep else
             "the files' order" if indexed(people) is not None else "the scene tracker's joint model")
    if in_lockstep and config.smooth and config.lag is not None:
        raise PriortrackError("the filters' association decides each tick as the filters go: smooth the whole run "
                              "(--smooth without --lag), or decide by the joint model (--association joints)")
    pool = _Pool(1 if skeleton is not None or in_lockstep else worker_count(workers))      # its workers start now
    association, cameras = associated(scene, calibration, data_fps, config, scene_config, people)
    chosen = chosen_people(association, people, scene)
    if skeleton is not None and len(chosen) > 1:
        raise PriortrackError(f"a skeleton is one person's body: choose one of the scene's {len(chosen)} people")
    if not chosen:
        views = min(scene_config.birth_views, len(cameras))
        seen = f"by {views} cameras" if views > 1 else f"whole enough ({MIN_BONES} bones) by its one camera"
        short = (f" (the detections hold {len(scene.frames)} frames, {len(scene.frames) / data_fps:.2g} s at "
                 f"{data_fps:g} fps: give more frames)" if len(scene.frames) / data_fps < scene_config.birth_s else "")
        raise PriortrackError(f"{scene.source}: nobody was seen {seen} for {scene_config.birth_s} s: no person to "
                              f"track{short}")
    log.info("%s: %d people in the scene (%s); tracking %s", scene.source, len(association.person_ids),
             ", ".join(map(str, association.person_ids.tolist())),
             ", ".join(str(association.person_ids[p]) for p in chosen))
    unclaimed = _unclaimed(association, scene, data_fps, config.min_confidence)
    detections = {p: association.detections_of(scene, p) for p in chosen}
    up = config.up
    if up is None and calibration.up is None:                # one up for every person: the longest-seen's
        longest = max(chosen, key=lambda p: int((association.slots[:, :, p] >= 0).sum()))
        up = up_from_detections(cameras, detections[longest], config.min_confidence, calibration.source)
    if pool.executor is not None and len(chosen) > 1:
        preset = fitted_once(preset, config.cache)
    person = replace(config, fps=data_fps, up=up)
    one = len(chosen) == 1
    jobs = [(detections[p], calibration, preset, person, skeleton) for p in chosen]
    if in_lockstep:
        association, runs = _in_lockstep(scene, association, chosen, jobs, scene_config.gate, progress)
    else:
        runs = pool.track([job + (progress if one else None,) for job in jobs], None if one else progress,
                          config.interruptible)
    results, kept, skipped = [], [], {}
    for p, (result, error) in zip(chosen, runs):
        if error is None:
            results.append(result)
            kept.append(p)
        else:
            skipped[int(association.person_ids[p])] = error
            if error != INTERRUPTED:
                log.warning("person %d cannot be tracked: %s", association.person_ids[p], error)
    if not results:
        if INTERRUPTED in skipped.values():
            raise KeyboardInterrupt
        raise PriortrackError(f"{scene.source}: no person could be tracked ({'; '.join(skipped.values())})")
    gathered = _gathered(association, kept, results, schedule(scene.frames, data_fps, results[0].fps), scene.frames,
                         skipped)
    gathered.detections, gathered.seconds, gathered.data_fps = scene, time.perf_counter() - start, data_fps
    gathered.interrupted = INTERRUPTED in skipped.values() or any(r.interrupted for r in results)
    gathered.unclaimed = unclaimed
    return gathered


def associated(scene: SceneDetections, calibration: Calibration, fps: float, config: TrackConfig | None = None,
               scene_config: SceneConfig | None = None, people=None) -> tuple[SceneAssociation, list[PinholeCamera]]:
    """Who is who in ``scene`` (the scene tracker's decisions, at the detections' ``fps``; where ``people`` asks for
    an index of each frame's list, :func:`indexed`, the files' order) and the detection cameras, matched to the
    calibration as ``config`` says."""
    config = config or TrackConfig()
    cameras = [PinholeCamera.from_calibration(c) for c in match_cameras(scene, calibration, config.camera_map)]
    if indexed(people) is not None:
        return SceneAssociation.indexed(scene, indexed(people)), cameras
    uv, confidence = scene.eval15(config.min_confidence)
    return SceneTracker(cameras, fps, scene_config).run(uv, confidence, scene.frames), cameras


def worker_count(workers: int | None) -> int:
    """The processes to track people in: ``workers``, or one per core this process may use."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise PriortrackError(f"workers must be a number of processes ≥ 1, got {workers!r}")
    return workers if workers is not None else len(os.sched_getaffinity(0))


def _in_lockstep(scene: SceneDetections, association: SceneAssociation, chosen: list[int], jobs: list,
                 gate: float, progress: Callable[[int, int], None] | None) -> tuple[SceneAssociation, list]:
    """The chosen people's runs prepared (``jobs``: :func:`~priortrack.tracking.person.prepared`'s arguments),
    their filters run in lockstep, who is who decided again through them
    (:func:`~priortrack.tracking.reassociation.reassociated`); the association and, per chosen person, the
    result or None and why they could not be tracked."""
    runs, errors = {}, {}
    for p, job in zip(chosen, jobs):
        try:
            runs[p] = prepared(*job)
        except PriortrackError as exc:
            errors[p] = str(exc)
    results = {}
    if runs:
        run = next(iter(runs.values()))
        association, tracks = reassociated(scene, association, runs, schedule(scene.frames, run.config.fps,
                                                                              run.prior.fps),
                                           run.config.min_confidence, gate, progress, run.config.interruptible)
        results = {p: runs[p].finished(track) for p, track in tracks.items()}
    return association, [(results.get(p), errors.get(p)) for p in chosen]


#: Why a person was not tracked: Ctrl-C came first.
INTERRUPTED = "interrupted (Ctrl-C) before their run"


def _track_person(job) -> tuple[DetectionTrack | None, str | None]:
    """One person's :func:`track_detections` (``job``: its arguments, detections to progress): the result, or
    None and why it could not be tracked. Runs in a worker or here; a worker's log records are re-logged
    here by :class:`_Pool`."""
    try:
        return track_detections(*job), None
    except PriortrackError as exc:
        return None, str(exc)


class _Captured(logging.Handler):
    """A worker's log records, kept to be handed back with its result."""

    def __init__(self):
        super().__init__()
        self.records = []

    def emit(self, record: logging.LogRecord) -> None:
        record.msg, record.args, record.exc_info = record.getMessage(), None, None
        self.records.append(record)


def _in_worker(job, level: int):
    """:func:`_track_person` in a worker process, with the log records it made at ``level`` or above."""
    handler = _Captured()
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel(level)
    try:
        return _track_person(job), handler.records
    finally:
        root.removeHandler(handler)


def _worker_start(threads: int) -> None:
    """A worker's start: torch on its share of the cores (importing this module imports the tracking code,
    while the parent associates the scene)."""
    import torch

    torch.set_num_threads(threads)


def _ready() -> None:
    """A task that starts a worker."""


class _Pool:
    """People's runs side by side in ``workers`` processes (each its own torch; none where ``workers`` is
    1), from loky's reusable executor: it needs no ``if __name__ == "__main__"`` in a user's script, which
    the standard library's spawned processes do, and keeps its workers (their imports) for the next scene
    for a few minutes (``IDLE_S``)."""

    IDLE_S = 300

    def __init__(self, workers: int):
        self.executor = None
        if workers > 1:
            from loky import get_reusable_executor

            threads = max(1, len(os.sched_getaffinity(0)) // workers)
            self.executor = get_reusable_executor(workers, timeout=self.IDLE_S, initializer=_worker_start,
                                                  initargs=(threads,))
            for _ in range(workers):             # the executor starts its processes for waiting tasks
                self.executor.submit(_ready)

    def track(self, jobs: list, progress: Callable[[int, int], None] | None = None, interruptible: bool = False) -> list:
        """Each job's :func:`_track_person`, in the jobs' order, ``progress(done, total)`` after each. ``interruptible``:
        Ctrl-C (a run that ended interrupted, or KeyboardInterrupt between runs or while waiting for the workers)
        keeps the outcomes so far, the other jobs' (None, :data:`INTERRUPTED`)."""
        in_workers = self.executor is not None and len(jobs) > 1
        outcomes = self._in_workers(jobs) if in_workers else map(_track_person, jobs)
        results = []
        try:
            for outcome in outcomes:
                results.append(outcome)
                if outcome[0] is not None and outcome[0].interrupted:
                    break
                if progress is not None:
                    progress(len(results), len(jobs))
        except KeyboardInterrupt:
            if not interruptible:
                raise
            if in_workers:
                self.executor.shutdown(wait=False, kill_workers=True)
        if len(results) < len(jobs):
            log.warning("interrupted: %d of %d people tracked; the others are not", len(results), len(jobs))
        return results + [(None, INTERRUPTED)] * (len(jobs) - len(results))

    def _in_workers(self, jobs: list):
        """The jobs' outcomes from the workers as they come, in order, each worker's log records re-logged here."""
        from loky.process_executor import TerminatedWorkerError

        level = logging.getLogger().getEffectiveLevel()
        try:
            for outcome, records in self.executor.map(_in_worker, jobs, [level] * len(jobs)):
                for record in records:
                    logging.getLogger(record.name).handle(record)
                yield outcome
        except TerminatedWorkerError as exc:
            log.debug("loky: %s", exc)
            raise PriortrackError("a worker process tracking a person ended abruptly (killed out of memory, or a "
                                  "crash): track the people one at a time (workers=1, --workers 1)") from None


#: Seconds of a camera's detections of nobody (:meth:`~priortrack.tracking.scene.SceneAssociation.unclaimed`) worth a
#: warning.
UNCLAIMED_S = 1.0


def _unclaimed(association: SceneAssociation, scene: SceneDetections, fps: float, min_confidence: float) -> dict:
    """{camera: frames} of each camera's detections of someone who is nobody for :data:`UNCLAIMED_S` or more, each
    warned: a person only that camera sees is not tracked."""
    frames, first = association.unclaimed(scene, min_confidence)
    out = {}
    for c in np.flatnonzero(frames >= UNCLAIMED_S * fps):
        out[scene.camera_names[c]] = int(frames[c])
        log.warning("%s: %s detects someone who is none of the people tracked in %d of %d frames (first in frame %d, "
                    "about pixel %.0f, %.0f): a person only that camera sees starts no track (or a detector's false "
                    "positive)", scene.source, scene.camera_names[c], frames[c], len(scene.frames),
                    scene.frames[int(first[c, 0])], first[c, 1], first[c, 2])
    return out


def _gathered(association: SceneAssociation, kept: list[int], results: list[DetectionTrack], index: np.ndarray,
              frames: np.ndarray, skipped: dict[int, str]) -> SceneTrack:
    """The people's results on one tick grid (``index`` into the detection frames per tick), NaN (False) where a
    person is absent (:attr:`SceneAssociation.present`)."""
    tick_frames = np.where(index >= 0, frames[np.maximum(index, 0)], -1)
    T, P = len(index), len(kept)
    per_tick = {name: lambda r, name=name: getattr(r, name) for name in
                ("joints", "spread", "loglik", "mismatch", "held_out_ratio", "ess", "gated", "filtered_joints")}
    per_tick["reprojection_px"] = lambda r: r.reprojection_by_tick
    smoothed = results[0].filtered_joints is not None
    grids = {name: np.full((T, P) + np.shape(get(results[0]))[1:], False if name in ("mismatch", "gated") else np.nan)
             for name, get in per_tick.items() if name != "filtered_joints" or smoothed}
    position = {int(f): t for t, f in enumerate(tick_frames) if f >= 0}
    # each tick's detection frame, a tick without one taking the last tick's (25 fps data at 30 fps ticks)
    nearest = np.maximum.accumulate(np.where(index >= 0, np.arange(T), 0))
    live = association.present[np.maximum(index[nearest], 0)]                      # (T, P_all)
    starts = np.zeros(len(kept), dtype=int)
    for q, (p, result) in enumerate(zip(kept, results)):
        k0 = int(np.flatnonzero(result.frames >= 0)[0])
        starts[q] = position[int(result.frames[k0])] - k0
        ticks = starts[q] + np.arange(len(result.frames))                               # the run's ticks on the grid
        keep = (ticks < T) & live[np.minimum(ticks, T - 1), p]
        t, k = ticks[keep], np.flatnonzero(keep)
        for name, grid in grids.items():
            grid[t, q] = per_tick[name](result)[k]
    return SceneTrack(association.person_ids[kept], tick_frames, results[0].fps, grids["joints"], grids["spread"],
                      grids["loglik"], grids["mismatch"], grids["held_out_ratio"], results, association, skipped,
                      index=index, ess=grids["ess"], reprojection_px=grids["reprojection_px"], gated=grids["gated"],
                      filtered_joints=grids.get("filtered_joints"), starts=starts)
