"""Tracking a real person: 2D detections from calibrated cameras in, a skeleton motion out.

:func:`track_detections` runs the whole pipeline (no 3D truth is needed):

1. **Cameras.** The detection cameras (folders) are matched to the calibration's in order (both
   as listed: folders sorted by name, calibration cameras in file order, as Pose2Sim does), or by
   ``camera_map`` (folder → calibration name). The calibration's world, whose up the file gives
   (Pose2Sim: Z; mmhuman3d: its floor) or ``up`` does (an axis or a vector), is turned Y-up for the
   priors, which learned from Y-up mocap (:func:`priortrack.geometry.frames.to_y_up`); results are
   turned back. Where neither gives a vertical (anipose, caliscope, FreeMoCap: camera 1's frame),
   up is found from the person (:func:`priortrack.geometry.frames.up_from_person`) and logged.
2. **Time.** The prior steps at its own rate (30 fps for the bundled presets), not the data's: tick
   k is at time k / fps_prior from the first frame, and consumes the detection frame nearest to it
   if one lies within half a data frame (60 fps data: every other frame; 25 fps data: some ticks have
   no frame and the prediction stands). ``frames`` of the result are the input frame numbers used.
   The motion is therefore played at its true speed whatever the data's rate.
3. **Start without truth.** From one camera, the body is the template scaled to the person's
   ``height`` and fitted to the first ticks' detections in 2D, its depth from its image size, the pixels
   weighed by the robust likelihood's Student-t and each limb's depth branches tried
   (:func:`priortrack.body.ik.inverse_kinematics_2d`). From several, each tick's joints are triangulated (confidence-weighted, through the
   lens distortion, under the likelihood's Student-t: :func:`~priortrack.geometry.triangulation.robust_triangulate`,
   a detector's outlier does not drag a joint); the first two consecutive ticks with at least ``MIN_FIT_JOINTS`` joints
   triangulated (fewer where the trial never shows as many, a person seated at a desk: the joints it shows in
   most ticks, :func:`start_joints`; the pose prior fills in what a shelf hides on the first ticks), each reprojecting into every camera about as well as the trial's typical tick
   (:func:`start_ticks`: not a tick where one camera swapped left and right), start the filter: the body (the prior's skeleton, or CMU subject 35's) is scaled to
   the person's own distances, each bone's the median over every tick of the whole trial whose
   triangulation measures it, left and right averaged (robust to a detector's swaps and outliers on
   some frames, and to a first second where the person is half in view; reported as the summary's
   ``bones_m``; a bone no tick measures scaled as the measured ones, named in ``bones_unmeasured``), and fitted to the two ticks by
   inverse kinematics over ``START_TICKS`` ticks (:mod:`priortrack.body.ik`; pulled to the preset's
   training poses, :func:`pose_spread`; each point reweighed by the likelihood's Student-t at its reprojection,
   :func:`robust_start`: a detector's outlier in a joint only two cameras see, which no triangulation can tell, bends
   the start less: a held-out walk's first ticks went from 45 and 64 mm to 20 and 19 mm), both in the detector's joint definitions (:func:`~priortrack.data.keypoints.detector_map`: its pelvis is the mid-hips,
   its neck the mid-shoulders), which the observation model uses too. The two start frames are
   steadied (:func:`steady_start`): the root's translation on the least-squares line through the
   fitted ticks (a velocity from eight noisy frames, not two), its rotation the same in both (no
   turn), and the particle filters start with ``START_TRANSLATION_STD`` of translation uncertainty.
   **Across views**, before that: where three or more cameras see a tick, each camera's person is
   checked against the triangulation of the others, reprojected into it; a camera whose detections
   lie a median ``CROSS_VIEW_GATE`` of the image diagonal away follows someone else there, and its
   detections of that tick are left out (logged, counted in ``cross_view_rejections``).
4. **Filter.** The preset's filter runs with the multi-camera observation model
   (:class:`~priortrack.observation.multiview.MultiViewLikelihood`: Student-t, ν = 4 unless the
   preset's ``[observation]`` says otherwise, weighted by confidence; for the unscented filter, which
   needs a measurement covariance, the Gaussian with variances σ² / confidence).
5. **Mismatch.** A frame is flagged where the prior cannot explain the data: the estimate's mean
   log-likelihood per detection (confidence-weighted) falls more than ``MISMATCH_NATS`` below its
   expectation under the noise model for ``MISMATCH_RUN`` ticks running, and (for the priors a
   fit-check judges, :func:`tracked_fit_check`) the prior itself scores the tracked step there below
   the 1st percentile of its held-out training steps: on data it explains badly *and* on a motion it
   does not know (the likelihood alone flagged 72 % of a held-out walk at 30 fps under pf-lie, whose
   steps the prior finds ordinary); or, with two cameras or more, where the estimate's joints lie on average
   ``LOST_MM`` from the per-tick triangulation for ``MISMATCH_RUN`` ticks (a lost track, whatever the
   prior makes of its steps); or, with three cameras or more, where the estimate explains each camera's
   detections worse than the other cameras' triangulation does (:mod:`~priortrack.tracking.held_out`: an
   estimate worse than triangulation, which the other two let through: pf-gpdm at 2–3× DLT on people it
   never saw had 0 % of its ticks flagged). The ESS is reported, not
   used: with four cameras it collapses on data the prior explains well (ESS ≈ 2 of 1000 particles
   on Pose2Sim's standing person, every joint reprojected within 10–20 px).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from priortrack.body.fk import joint_positions
from priortrack.body.ik import (PoseSpread, body_measures, check_height, fitted_skeleton, inverse_kinematics,
                                own_posture, REWEIGHTS, inverse_kinematics_2d, limb_sides, scaled_to_height, stature,
                                unmeasured_measures)
from priortrack.data.bundled import cmu_skeleton
from priortrack.data.calibration import UP_AXES, Calibration, CameraCalibration
from priortrack.data.detections import Detections
from priortrack.data.motion import Motion
from priortrack.data.skeleton import Skeleton
from priortrack.data.trc import write_trc
from priortrack.filters.smoothing import (PARTICLE_SMOOTHERS, TRAJECTORIES, FixedLagSmoother, joint_spread,
                                         smooth as smooth_run)
from priortrack.data.eval15 import EVAL15_MARKER_NAMES, EVAL15_NAMES
from priortrack.data.keypoints import detector_map
from priortrack.errors import PriortrackError
from priortrack.tracking.held_out import MIN_CAMERAS, WORSE_RATIO, held_out_errors, held_out_ratio
from priortrack.tracking.presets import UNSCENTED_KINDS, Preset, load_preset
from priortrack.tracking.association import NOMINAL_HEIGHT_M
from priortrack.tracking.extra_keypoints import carried
from priortrack.tracking.floor_height import measured_height
from priortrack.tracking.lowpass import lowpassed
from priortrack.tracking.resample import frame_times, interpolated, nearest_tick
from priortrack.filters.snapshot import KNOWN_FRAMES
from priortrack.filters.step_store import DEFAULT_MEMORY, StepStore
from priortrack.geometry.camera import PinholeCamera, pixel_errors
from priortrack.geometry.frames import in_working_frame, to_y_up, up_from_person, up_vector
from priortrack.geometry.triangulation import robust_triangulate, triangulate
from priortrack.models.tracking import TrackingModel
from priortrack.observation.ticks import BLOCK_TICKS, TickObservations
from priortrack.observation.multiview import DEFAULT_NU, DEFAULT_SIGMA_PX, MultiViewLikelihood
from priortrack.output import output_path

log = logging.getLogger(__name__)

#: A camera's person at a tick is someone else's if the others' triangulation reprojects this far from
#: it (median over its joints), as a fraction of the image diagonal.
CROSS_VIEW_GATE = 0.1
#: Joints a tick needs to start the filter there from one camera (detected: the whole body's image size gives its
#: depth; with two cameras or more, MIN_FIT_JOINTS triangulated: a person of a scene is tracked from their first
#: ticks, though a shelf hides an arm there: Shelf, cameras 0, 1, 2, an actor's first 14 frames untracked, 162 →
#: 58 mm) …
START_JOINTS = 14
#: … or, where the trial never shows as many (a person seated at a desk, legs under it or seen by one camera),
#: every joint it shows (triangulated, or detected with one camera) in at least VIEW_SHARE of its ticks, and
#: no fewer than MIN_START_JOINTS (below that the inverse kinematics is not posed: the start is refused).
VIEW_SHARE, MIN_START_JOINTS = 0.5, 6
#: A start tick's worst camera reprojects its triangulation within this many times the trial's median tick's
#: (:func:`start_ticks`).
START_CONSISTENCY = 3.0
#: Ticks fitted together by inverse kinematics for the start (the first two start the filter), as
#: long as each has MIN_FIT_JOINTS joints.
START_TICKS, MIN_FIT_JOINTS = 8, 8
#: The start's uncertainty in the body's translation, metres (each of its two frames), for the
#: particle filters.
START_TRANSLATION_STD = 0.05
#: A tick is a mismatch when its mean log-likelihood per detection is this many nats below the
#: noise model's expectation …
MISMATCH_NATS = 3.0
#: … for this many ticks running.
MISMATCH_RUN = 5
#: With two cameras or more a tick is also a mismatch where the estimate's joints lie on average this far
#: (mm) from the per-tick triangulation of the detections, for MISMATCH_RUN ticks: a limb a hand's width
#: off, beyond DLT's own error (16–28 mm on the real-format bench). The likelihood flag, ANDed with the
#: prior's own judgement of the tracked steps, let pf-lie lose a balance at 149 mm with 14 % flagged.
LOST_MM = 100.0


def in_world(body: np.ndarray, A: np.ndarray, definitions: bool = True) -> np.ndarray:
    """Points (..., 3) of the Y-up working frame → the calibration's world (rows @ A, A the run's
    :attr:`DetectionTrack.working_to_world`); with ``definitions`` eval15 body joints
    (..., 15, 3) are moved to the detector's definitions first (:func:`~priortrack.data.keypoints.detector_map`)."""
    body = np.asarray(body, dtype=float)
    return (np.einsum("ij,...jk->...ik", detector_map(), body) if definitions else body) @ A


@dataclass
class DetectionTrack:
    """The result of :func:`track_detections`.

    Attributes:
        joints: (T, 15, 3) float64 eval15 joints, metres, in the calibration's world, in the detector's
            definitions (pelvis = mid-hips, neck = mid-shoulders).
        frames: (T,) the input frame number each tick consumed (−1: none, the prediction stands).
        fps: the ticks' rate (the prior's).
        spread: (T, 15) the posterior's standard deviation per joint, metres (√ of the trace of each
            joint's covariance over the particles, the translation's Kalman covariance included;
            for a filter without particles, the sigma points' or NaN).
        ess: (T,) effective sample size (NaN where the filter has no particles).
        loglik: (T,) log p(z_t | estimate) under the observation model (NaN where nothing was seen).
        mismatch: (T,) bool, the ticks the prior does not explain (module docstring).
        camera_names: (C,) the detection cameras; reprojection_px (C,): the median pixel error of the
            estimate's projection against each camera's detections (over every tick and joint).
        reprojection_by_tick: (T, C) the same per tick (NaN where the camera saw nothing).
        gated: (T, C, 15) bool, the detections the unscented filter's validation gate held out (all
            False for the other filters).
        filter: the preset's name; seconds: the run's wall time.
    """

    joints: np.ndarray
    frames: np.ndarray
    fps: float
    spread: np.ndarray
    ess: np.ndarray
    loglik: np.ndarray
    mismatch: np.ndarray
    camera_names: tuple[str, ...]
    reprojection_px: np.ndarray
    filter: str
    seconds: float
    #: The calibration world's up (an axis name or a (3,) unit vector), and A (3, 3) with world rows =
    #: working-frame rows @ A (the snapshots' particles are in the Y-up working frame).
    up: str | np.ndarray = "y"
    working_to_world: np.ndarray = field(default_factory=lambda: np.eye(3), repr=False)
    #: The body the filter tracked (the scaled skeleton) and its eval15 joints per tick (T, 15, 3) in the
    #: Y-up working frame, in the body's own definitions (for the BVH).
    skeleton: object = field(default=None, repr=False)
    body_joints: np.ndarray | None = field(default=None, repr=False)
    #: The cameras in the calibration's world, and the observations per tick (T, C, 15, 3): a
    #: :class:`~priortrack.observation.ticks.TickObservations`, which reads them from the detections as asked.
    cameras: list[PinholeCamera] = field(default_factory=list, repr=False)
    observations: TickObservations | None = field(default=None, repr=False)
    #: The filter's snapshots where kept (``keep_snapshots``: every ``snapshot_every``-th tick's), and the
    #: compact record of every tick's step (:class:`~priortrack.filters.snapshot.StepRecord`).
    snapshots: list | None = field(default=None, repr=False)
    steps: list | None = field(default=None, repr=False)
    #: Camera-ticks whose person disagreed with the other cameras' (left out).
    cross_view_rejections: int = 0
    #: Smoothed runs (``smooth=True``): ``joints``, ``spread`` and the BVH's body joints are the
    #: smoother's, the filter's own joints (T, 15, 3) and spread (T, 15) are kept here; ``lag`` the fixed lag
    #: (None: whole run).
    filtered_joints: np.ndarray | None = field(default=None, repr=False)
    lag: int | None = None
    filtered_spread: np.ndarray | None = field(default=None, repr=False)
    #: The run was interrupted (Ctrl-C): it holds the ticks tracked until then.
    interrupted: bool = False
    #: The tracked motion's fit-check under the prior (:mod:`priortrack.priors.support`): "verdict",
    #: "below_p1_fraction", "median_percentile"; None where the preset's prior has no reference.
    fit_check: dict | None = None
    reprojection_by_tick: np.ndarray | None = field(default=None, repr=False)
    gated: np.ndarray | None = field(default=None, repr=False)
    #: The prior's pose spread that the fit-check's inverse kinematics pulls the body's channels to (None: to
    #: rest); the BVH's pulls them to rest (the joints as tracked, not as the prior would have them).
    pose_spread: PoseSpread | None = field(default=None, repr=False)
    #: The body measures (:data:`~priortrack.body.ik.BODY_MEASURES`) no tick measured, which took the template's
    #: proportions (a seated person's legs; :func:`~priortrack.body.ik.fitted_skeleton`).
    bones_unmeasured: tuple[str, ...] = ()
    #: Where the body's height came from (:data:`HEIGHT_FROM`'s keys).
    height_from: str = ""
    #: (T,) the filter's held-out ratio q a tick (:mod:`~priortrack.tracking.held_out`; over ``WORSE_RATIO``: worse
    #: than triangulation), NaN where not judged or with fewer than three cameras.
    held_out_ratio: np.ndarray | None = field(default=None, repr=False)
    #: (T,) each tick's time, seconds from the detections' first frame; the detections' rate and every frame number
    #: (F,) they hold (:meth:`at_detection_frames`).
    tick_times: np.ndarray | None = field(default=None, repr=False)
    data_fps: float | None = None
    data_frames: np.ndarray | None = field(default=None, repr=False)
    #: The cut-off of the Butterworth low-pass the joints went through (:meth:`low_passed`), None where none.
    lowpass_hz: float | None = None
    #: The person's detections and the confidence below which a keypoint is missing (for the keypoints beyond the
    #: 15 joints, :mod:`~priortrack.tracking.extra_keypoints`); at the detections' frames, those keypoints (F, E, 3)
    #: in the calibration's world (NaN where absent) and their marker names (E,).
    detections: object = field(default=None, repr=False)
    min_confidence: float = 0.3
    keypoints: np.ndarray | None = field(default=None, repr=False)
    keypoint_names: tuple[str, ...] = ()

    def in_world(self, body: np.ndarray, definitions: bool = True) -> np.ndarray:
        """Points (..., 3) of the filter's Y-up working frame (a snapshot's estimate, best or cloud, the
        body joints) in the calibration's world, metres; with ``definitions`` an eval15 body's joints
        (..., 15, 3) are also moved to the detector's definitions (pelvis = mid-hips, neck = mid-shoulders),
        as ``joints`` are."""
        return in_world(body, self.working_to_world, definitions)

    @property
    def mismatch_fraction(self) -> float:
        return float(self.mismatch[KNOWN_FRAMES:].mean()) if len(self.mismatch) > KNOWN_FRAMES else 0.0

    def low_passed(self, cutoff_hz: float) -> "DetectionTrack":
        """This result with its joints, the detector's further keypoints and the body's joints a BVH is fitted to
        through a zero-lag Butterworth low-pass at ``cutoff_hz`` (:mod:`~priortrack.tracking.lowpass`)."""
        def passed(values):
            return None if values is None else lowpassed(values, self.fps, cutoff_hz)

        return replace(self, joints=passed(self.joints), body_joints=passed(self.body_joints),
                       keypoints=passed(self.keypoints), lowpass_hz=cutoff_hz)

    def at_detection_frames(self) -> "DetectionTrack":
        """This result at the detections' own frames and rate (:mod:`~priortrack.tracking.resample`): each detection
        frame within half a tick of the tracked ticks, its joints, spread and body the cubic spline through the ticks',
        its verdicts (ESS, log-likelihood, mismatch, reprojection, gate, held-out ratio) the nearest tick's, and the
        detector's keypoints beyond the 15 joints carried by them (:mod:`~priortrack.tracking.extra_keypoints`; two
        cameras or more); ``fps`` the detections'. What a file is written from; the filter's snapshots and
        observations stay with the ticks."""
        times = frame_times(self.data_frames, self.data_fps)
        joints = interpolated(self.joints, self.tick_times, times)
        keep = np.isfinite(joints).all(axis=(1, 2))
        times, joints = times[keep], joints[keep]
        near = nearest_tick(self.tick_times, times)
        extra, names = (None, ()) if self.detections is None or len(self.cameras) < 2 else carried(
            self.detections.load().keypoints[:, keep], self.detections.layout, self.cameras, joints, self.data_fps,
            self.min_confidence, (DEFAULT_SIGMA_PX, DEFAULT_NU))

        def spline(values):
            return None if values is None else interpolated(values, self.tick_times, times)

        return replace(self, joints=joints, frames=self.data_frames[keep], fps=self.data_fps, tick_times=times,
                       spread=spline(self.spread), ess=self.ess[near], loglik=self.loglik[near],
                       mismatch=self.mismatch[near], body_joints=spline(self.body_joints),
                       filtered_joints=spline(self.filtered_joints), filtered_spread=spline(self.filtered_spread),
                       reprojection_by_tick=self.reprojection_by_tick[near], gated=self.gated[near],
                       held_out_ratio=self.held_out_ratio[near], observations=None, snapshots=None, steps=None,
                       keypoints=extra, keypoint_names=names)

    def summary(self) -> dict:
        """The JSON summary: frames, seconds, median reprojection error per camera, mismatch fraction, the
        world's up (an axis, or the vector given or found from the person), the tracked body's measures
        (:func:`~priortrack.body.ik.body_measures`, metres; each limb's left and right,
        :func:`~priortrack.body.ik.limb_sides`) and those of them no tick measured."""
        return {"filter": self.filter, "frames": int(len(self.joints)), "fps": self.fps, "seconds": self.seconds,
                "reprojection_px": {n: float(e) for n, e in zip(self.camera_names, self.reprojection_px)},
                "mismatch_fraction": self.mismatch_fraction, "cross_view_rejections": self.cross_view_rejections,
                "mean_ess": float(np.nanmean(self.ess)) if np.isfinite(self.ess).any() else None,
                "smoothed": self.filtered_joints is not None, "lag": self.lag, "fit_check": self.fit_check,
                "interrupted": self.interrupted,
                "bones_m": None if self.skeleton is None else body_measures(self.skeleton, detector_map()),
                "limbs_left_right_m": None if self.skeleton is None else limb_sides(self.skeleton, detector_map()),
                "height_m": None if self.skeleton is None else stature(self.skeleton), "height_from": self.height_from,
                "bones_unmeasured": list(self.bones_unmeasured),
                "up": self.up if isinstance(self.up, str) else [float(v) for v in self.up]}

    def save_npz(self, path: str | Path) -> Path:
        """``joints`` (T, 15, 3) float64 metres in the calibration's world, ``joint_names``, ``fps``,
        ``frames`` (T,), ``spread`` (T, 15), ``ess`` (T,), ``loglik`` (T,), ``mismatch`` (T,) bool,
        ``camera_names`` (C,), ``reprojection_px`` (T, C) each tick's median pixel error per camera and
        ``gated`` (T, C, 15) bool the detections the validation gate held out, ``held_out_ratio`` (T,) the
        filter's held-out ratio (NaN: not judged), ``lowpass_hz`` where the joints were low-passed, ``keypoints`` (T, E,
        3) and ``keypoint_names`` (E,) the detector's further keypoints where carried, the tracked body
        (:meth:`body_arrays`); a smoothed run adds
        ``filtered_joints`` (T, 15, 3) and ``filtered_spread`` (T, 15), the filter's own (``joints`` and
        ``spread`` are the smoother's)."""
        path = output_path(path, "result file")
        extra = {} if self.filtered_joints is None else {"filtered_joints": self.filtered_joints.astype(np.float64),
                                                         "filtered_spread": self.filtered_spread}
        if self.lowpass_hz is not None:
            extra["lowpass_hz"] = np.array(float(self.lowpass_hz))
        if self.keypoints is not None:
            extra.update(keypoints=self.keypoints, keypoint_names=np.array(self.keypoint_names, dtype=str))
        extra.update(self.body_arrays())
        with open(path, "wb") as f:
            np.savez(f, joints=self.joints.astype(np.float64), joint_names=np.array(EVAL15_NAMES),
                     fps=np.array(float(self.fps)), frames=self.frames.astype(np.int64), spread=self.spread,
                     ess=self.ess, loglik=self.loglik, mismatch=self.mismatch.astype(bool),
                     camera_names=np.array(self.camera_names), reprojection_px=self.reprojection_by_tick,
                     gated=self.gated.astype(bool), held_out_ratio=self.held_out_ratio, **extra)
        return path

    def body_arrays(self) -> dict[str, np.ndarray]:
        """The tracked body as the ``.npz`` holds it (none where there is no skeleton): ``body_measure_names`` (8,) and
        ``body_measures_m`` (8,) (:data:`~priortrack.body.ik.BODY_MEASURES`, a limb's sides averaged),
        ``limb_names`` (4,) and ``limbs_left_right_m`` (4, 2), ``height_m`` ()."""
        if self.skeleton is None:
            return {}
        measures, sides = body_measures(self.skeleton, detector_map()), limb_sides(self.skeleton, detector_map())
        return {"body_measure_names": np.array(list(measures), dtype=str),
                "body_measures_m": np.array(list(measures.values())), "limb_names": np.array(list(sides), dtype=str),
                "limbs_left_right_m": np.array(list(sides.values())), "height_m": np.array(stature(self.skeleton))}

    def save_csv(self, path: str | Path) -> Path:
        """One row per tick (or frame): frame, time (s from the detections' first frame), each joint's x, y, z (metres),
        spread, ESS, loglik, mismatch, then each of the detector's further keypoints' x, y, z where carried."""
        path = output_path(path, "result file")
        header = ["frame", "time_s"] + [f"{n}_{a}" for n in EVAL15_NAMES for a in "xyz"] + \
                 [f"{n}_spread" for n in EVAL15_NAMES] + ["ess", "loglik", "mismatch"] + \
                 [f"{n}_{a}" for n in self.keypoint_names for a in "xyz"]
        extra = np.zeros((len(self.joints), 0)) if self.keypoints is None else self.keypoints.reshape(len(self.joints), -1)
        rows = np.column_stack([self.frames, self.tick_times, self.joints.reshape(len(self.joints), -1),
                                self.spread, self.ess, self.loglik, self.mismatch.astype(int), extra])
        np.savetxt(path, rows, delimiter=",", header=",".join(header), comments="", fmt="%.9g")
        return path

    def markers(self) -> tuple[np.ndarray, tuple[str, ...]]:
        """Every written marker (T, 15 + E, 3), the calibration's world, and its name: the 15 joints under
        :data:`~priortrack.data.eval15.EVAL15_MARKER_NAMES`, then the detector's further keypoints where carried."""
        points = self.joints if self.keypoints is None else np.concatenate([self.joints, self.keypoints], axis=1)
        return points, EVAL15_MARKER_NAMES + self.keypoint_names

    def save_trc(self, path: str | Path) -> Path:
        """The joints as a TRC file (:mod:`priortrack.data.trc`: Y-up, Pose2Sim's axes for a Z-up world;
        a world with another up axis is written in the Y-up working frame), under Pose2Sim's and its OpenSim
        marker sets' names (:data:`~priortrack.data.eval15.EVAL15_MARKER_NAMES`), the detector's further keypoints
        after them where carried (``keypoints``: LBigToe, LHeel, Nose…)."""
        points, names = self.markers()
        if isinstance(self.up, str) and self.up in ("y", "z"):
            return write_trc(path, points, names, self.fps, self.up, int(max(self.frames[0], 0)))
        return write_trc(path, points @ self.working_to_world.T, names, self.fps, "y", int(max(self.frames[0], 0)))

    def save_mot(self, path: str | Path) -> Path:
        """Joint angles (:mod:`priortrack.body.angles`, degrees) as an OpenSim ``.mot`` file, a row per frame at its
        time from the detections' first frame; the ankles' from the heel and big toe where carried (``keypoints``)."""
        from priortrack.body.angles import joint_angles
        from priortrack.data.mot import write_mot

        feet = {}
        for part, names in (("heel", ("LHeel", "RHeel")), ("toe", ("LBigToe", "RBigToe")),
                            ("toe", ("LFootIndex", "RFootIndex"))):
            if self.keypoints is not None and all(n in self.keypoint_names for n in names):
                feet[part] = self.keypoints[:, [self.keypoint_names.index(n) for n in names]]
        return write_mot(path, self.tick_times, joint_angles(self.joints, feet.get("heel"), feet.get("toe")))

    def save_bvh(self, path: str | Path) -> Path:
        """The tracked body's motion as a BVH file: the body's channels fitted by inverse kinematics to
        its tracked joints, in the Y-up working frame (BVH's convention; Blender turns it Z-up on
        import), root position channels absolute, read back by Blender and by
        :func:`priortrack.data.bvh.read_bvh` to the same joints."""
        from priortrack.data.bvh import write_bvh

        path = output_path(path, "BVH file")
        motion = inverse_kinematics(self.body_joints, self.fps, skeleton=self.skeleton, name=Path(path).stem)
        write_bvh(motion, path)
        return path

    def save(self, path: str | Path) -> Path:
        """Write the result by the file's suffix: ``.npz``, ``.csv``, ``.trc``, ``.mot`` or ``.bvh``."""
        writers = {".npz": self.save_npz, ".csv": self.save_csv, ".trc": self.save_trc, ".mot": self.save_mot,
                   ".bvh": self.save_bvh}
        suffix = Path(path).suffix.lower()
        if suffix not in writers:
            raise PriortrackError(f"{path}: results are written as {', '.join(writers)}")
        return writers[suffix](path)


RESULT_SUFFIXES = (".npz", ".csv", ".trc", ".mot", ".bvh")
#: The fewest tracked ticks a fit-check judges.
MIN_FIT_CHECK_TICKS = 10
#: The shipped presets whose priors a motion outside the running prior's support is checked against
#: (:func:`better_fitting`): the walking prior and the one learned from every bundled activity.
ALTERNATIVE_PRIORS = ("pf-lie", "pf-lie-general")


def match_cameras(detections: Detections, calibration: Calibration,
                  camera_map: dict[str, str] | None = None) -> list[CameraCalibration]:
    """The calibration camera of each detection camera (module docstring, step 1)."""
    by_name = {c.name: c for c in calibration.cameras}
    if camera_map:
        unknown = sorted(set(camera_map) - set(detections.camera_names))
        if unknown:
            raise PriortrackError(f"camera map names detection cameras {unknown} that are not among "
                                  f"{', '.join(detections.camera_names)}")
        missing = [n for n in detections.camera_names if n not in camera_map]
        if missing:
            raise PriortrackError(f"camera map has no calibration camera for {', '.join(missing)}")
        bad = sorted(v for v in camera_map.values() if v not in by_name)
        if bad:
            raise PriortrackError(f"{calibration.source}: no camera {', '.join(bad)} (cameras: "
                                  f"{', '.join(by_name)})")
        return [by_name[camera_map[n]] for n in detections.camera_names]
    C, K = len(detections.camera_names), len(calibration.cameras)
    if K < C:
        raise PriortrackError(f"{calibration.source} has {_counted(K, 'camera')} for {_counted(C, 'detection camera')} "
                              f"({', '.join(detections.camera_names)})")
    if K > C:
        raise PriortrackError(f"{calibration.source} has {_counted(K, 'camera')} for {_counted(C, 'detection camera')}: "
                              f"say which is which with a camera map (folder=calibration name)")
    return list(calibration.cameras)


def _counted(n: int, noun: str) -> str:
    """"1 camera", "4 cameras"."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def schedule(frames: np.ndarray, data_fps: float, prior_fps: float) -> np.ndarray:
    """(T,) index into ``frames`` of the frame each prior tick consumes, −1 where none lies within
    half a data frame of the tick (module docstring, step 2). A frame is consumed once, by its
    nearest tick (25 fps data at 30 fps: one tick in six has none)."""
    times = (frames - frames[0]) / data_fps
    ticks = np.arange(int(math.floor(times[-1] * prior_fps + 1e-9)) + 1) / prior_fps
    after = np.clip(np.searchsorted(times, ticks), 0, len(times) - 1)
    before = np.maximum(after - 1, 0)
    nearest = np.where(np.abs(times[before] - ticks) <= np.abs(times[after] - ticks), before, after)
    gap = np.abs(times[nearest] - ticks)
    index = np.where(gap <= 0.5 / data_fps + 1e-9, nearest, -1)
    for frame in np.unique(index[index >= 0]):
        ticks_of = np.flatnonzero(index == frame)
        index[ticks_of[ticks_of != ticks_of[np.argmin(gap[ticks_of])]]] = -1
    return index


def _whole_trial(cameras: list[PinholeCamera], z: TickObservations, names: tuple[str, ...], source: str,
                 min_confidence: float, noise: tuple[float, float]) -> tuple[np.ndarray | None, np.ndarray, np.ndarray | None, np.ndarray]:
    """One pass over the run's ticks z, a block at a time (module docstring, step 3): each tick's
    triangulation X (T, 15, 3) in the working frame after the cross-view check (None with one camera),
    the joints seen (T, 15) (triangulated; one camera: detected), each tick's worst camera's median
    reprojection of X (T,) (None with one camera; −inf where none is measured) and the camera-ticks left
    out as following someone else (T, C) (:func:`cross_view_check`, logged). Refused: a camera that sees
    none of the detections, or that the person lies behind (:func:`_behind`)."""
    T, C = len(z), len(cameras)
    single = C == 1
    X = None if single else np.full((T, 15, 3), np.nan)
    residual = None if single else np.full(T, -np.inf)
    seen, left_out = np.zeros((T, 15), dtype=bool), np.zeros((T, C), dtype=bool)
    shown, behind = np.zeros(C, dtype=bool), np.zeros((C, 2), dtype=int)

    for start, block in z.blocks(raw=True):
        ticks = slice(start, start + len(block))
        shown |= (np.nan_to_num(block[..., 2]) > 0).any(axis=(0, 2))
        every = None if single else triangulated(cameras, block)                         # by every camera
        behind += _behind(cameras, block, every)
        left_out[ticks] = cross_view_check(cameras, block)
        if single:
            seen[ticks] = (np.nan_to_num(block[:, 0, :, 2]) > 0) & np.isfinite(block[:, 0, :, 0])
            continue
        again = left_out[ticks].any(axis=1)                  # the ticks a camera was left out of, by the others
        every[again] = triangulated(cameras, block[again])
        X[ticks] = triangulated(cameras, block, noise)
        seen[ticks] = np.isfinite(X[ticks]).all(axis=-1)
        # the DLT spreads a camera's disagreement (a swap) over every camera's reprojection, where the robust
        # triangulation may follow the swapped camera's joints: the start's consistency is judged on the DLT
        residual[ticks] = np.stack([np.nan_to_num(median_reprojection(camera, every, block[:, c]), nan=-np.inf)
                                    for c, camera in enumerate(cameras)]).max(axis=0)
    for c in np.flatnonzero(~shown):
        raise PriortrackError(f"camera {names[c]} sees none of the detections (no joint above confidence "
                              f"{min_confidence})")
    for c, (joints, back) in enumerate(behind):
        if joints >= 10 and back > 0.9 * joints:
            raise PriortrackError(f"{source}: camera {names[c]!r}: {100 * back / joints:.0f}% of the person it detects "
                                  f"lies behind it once triangulated; its rotation and translation are not world → "
                                  f"camera as read (a camera → world file, or a wrong sign?)")
    for c in np.flatnonzero(left_out.any(axis=0)):
        log.warning("camera %s: at %d ticks its person is not the one the other cameras see; those detections "
                    "are left out", names[c], int(left_out[:, c].sum()))
    return X, seen, residual, left_out


def robust_start(X: np.ndarray, z: np.ndarray, cameras: list[PinholeCamera], fps: float, M: np.ndarray,
                 skeleton: Skeleton, pose: PoseSpread | None, noise: tuple[float, float]) -> Motion:
    """The start's inverse kinematics of the triangulated ticks X (T, 15, 3) (observations z (T, C, 15, 3)), reweighted
    :data:`~priortrack.body.ik.REWEIGHTS` times: each point's weight the least over its cameras of the Student-t's
    ρ = (ν + 2) / (ν + d² / σ²) at the fit's reprojection (``noise`` = (σ px, ν)), over the median such weight, at most
    1. A detector's outlier that only two cameras see is triangulated wherever their rays pass, and no camera can be
    left out; the body's other joints hold the fit away from it, its reprojection is far from the outlying pixel, and
    its weight falls. On real detections, whose every point is a few pixels off, the weights stay near 1."""
    fitted = inverse_kinematics(X, fps, joint_map=M, skeleton=skeleton, pose=pose)
    sigma, nu = noise
    for _ in range(REWEIGHTS):
        J = np.einsum("jk,tkd->tjd", M, joint_positions(fitted))
        rho = np.full(X.shape[:2], np.inf)
        for c, camera in enumerate(cameras):
            d2 = ((camera.project(J)[0] - z[:, c, :, :2]) ** 2).sum(-1)
            seen = np.isfinite(d2) & (np.nan_to_num(z[:, c, :, 2]) > 0)
            rho = np.where(seen, np.minimum(rho, (nu + 2) / (nu + d2 / sigma ** 2)), rho)
        measured = np.isfinite(rho)
        if not measured.any():
            break
        weights = np.where(measured, np.minimum(rho / np.median(rho[measured]), 1.0), 1.0)
        fitted = inverse_kinematics(X, fps, joint_map=M, skeleton=skeleton, pose=pose, weights=weights)
    return fitted


def triangulated(cameras: list[PinholeCamera], block: np.ndarray, noise: tuple[float, float] | None = None) -> np.ndarray:
    """(T, 15, 3) each tick's confidence-weighted triangulation of observations block (T, C, 15, 3): the DLT, or with
    ``noise`` = (σ px, ν) robust to a detector's outliers under that Student-t (:func:`robust_triangulate`)."""
    uv, confidence = block[..., :2].transpose(1, 0, 2, 3), np.nan_to_num(block[..., 2]).transpose(1, 0, 2)
    return triangulate(cameras, uv, confidence) if noise is None else robust_triangulate(cameras, uv, confidence, *noise)


def _behind(cameras: list[PinholeCamera], z: np.ndarray, X: np.ndarray | None) -> np.ndarray:
    """(C, 2) per camera: the joints it detects (z: (T, C, 15, 3)) that X (T, 15, 3), every camera's
    triangulation (None with one camera), places, and how many of them lie behind it (a camera that sees
    nearly everything behind it has a pose that is not the calibration's convention: camera → world read as
    world → camera, a flipped axis)."""
    out = np.zeros((len(cameras), 2), dtype=int)
    if X is None:
        return out
    for c, camera in enumerate(cameras):
        seen = np.isfinite(X).all(axis=-1) & np.isfinite(z[:, c, :, 0])
        out[c] = seen.sum(), (~camera.project(np.where(seen[..., None], X, 0.0))[1][seen]).sum()
    return out


def up_from_detections(cameras: list[PinholeCamera], detections, min_confidence: float, source: str) -> np.ndarray:
    """The world's up found from the person (:func:`priortrack.geometry.frames.up_from_person`) over
    every frame of the detections (:class:`~priortrack.data.detections.Detections` or a
    :class:`~priortrack.data.detections.DetectionFile`, read BLOCK_TICKS frames at a time) triangulated in
    the calibration's world; logged."""
    if len(cameras) < 2:
        raise PriortrackError(f"{source} gives no vertical and one camera cannot triangulate the person to find "
                              f"it; give it (--up: an axis or a vector X,Y,Z)")
    frames = len(detections.frames)
    X = np.concatenate([triangulate(cameras, *detections.eval15(min_confidence, start, start + BLOCK_TICKS))
                        for start in range(0, frames, BLOCK_TICKS)])
    up, what, frames = up_from_person(X)
    log.info("%s gives no vertical: up %s found from the person (%s, robust mean over %d frames)", source,
             np.round(up, 3).tolist(), what, frames)
    return up


@dataclass(frozen=True)
class TrackConfig:
    """How a person's detections are tracked: one object for the command line's options and the API's
    (:func:`track_detections`, and every person of :func:`~priortrack.tracking.people.track_scene`).

    Attributes:
        fps: the detections' frame rate, where their files do not say it.
        up: the calibration world's up, an axis name or a (3,) vector; None: the calibration's, else
            found from the person (module docstring, 1).
        camera_map: {detection camera (folder): calibration camera} where they are not matched in order.
        min_confidence: keypoints below it are missing.
        seed: seeds the filter.
        height: the person's standing height, metres: the body's size and depth from one camera; None: measured
            there from the floor (:mod:`~priortrack.tracking.floor_height`), else :data:`NOMINAL_HEIGHT_M`.
        floor: where the floor is along the calibration's up, metres (0: its origin is on the floor); None: not known
            (one camera then takes the nominal height).
        smooth: also smooth the run (:mod:`priortrack.filters.smoothing`) and give the smoothed joints;
            lag: with a fixed lag of that many ticks (None: over the whole run); particle_smoother: a
            particle filter's, "gaussian" or "backward"; trajectories: backward simulation's.
        keep_snapshots: keep the filter's steps (a recording's particle clouds), every ``snapshot_every``-th
            tick's.
        interruptible: Ctrl-C during the filter's run ends it there; the result holds the ticks tracked
            until then (``interrupted``).
        device: where a particle filter's particles live ("cpu", "cuda"; :meth:`Preset.filter_for`).
        memory: bytes of the whole-run smoother's steps held in memory, the rest spilled to a temporary
            folder (:class:`~priortrack.filters.step_store.StepStore`).
        cache: the prior cache's folder (None: :func:`~priortrack.priors.cache.cache_dir`).
        fit_check: judge the tracked motion under the prior (:func:`tracked_fit_check`); without it the mismatch flag
            is the likelihood's and the triangulation's alone.
    """

    fps: float | None = None
    up: str | np.ndarray | None = None
    camera_map: dict[str, str] | None = None
    min_confidence: float = 0.3
    seed: int = 0
    height: float | None = None
    floor: float | None = 0.0
    smooth: bool = False
    lag: int | None = None
    particle_smoother: str = PARTICLE_SMOOTHERS[0]
    trajectories: int = TRAJECTORIES
    keep_snapshots: bool = False
    snapshot_every: int = 1
    interruptible: bool = False
    device: str = "cpu"
    memory: int = DEFAULT_MEMORY
    cache: Path | str | None = None
    fit_check: bool = True

    def __post_init__(self):
        if self.fps is not None and not (isinstance(self.fps, (int, float)) and 0 < self.fps < 1e4):
            raise PriortrackError(f"fps must be a positive frame rate, got {self.fps}")
        if not isinstance(self.min_confidence, (int, float)) or not 0 <= self.min_confidence <= 1:
            raise PriortrackError(f"min_confidence must be in [0, 1], got {self.min_confidence!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)):
            raise PriortrackError(f"seed must be a whole number, got {self.seed!r}")
        if self.height is not None:
            check_height(self.height)
        if self.floor is not None and not (isinstance(self.floor, (int, float)) and abs(self.floor) < 100):
            raise PriortrackError(f"floor must be the floor's height along up in metres, got {self.floor!r}")


def track_detections(detections: Detections, calibration: Calibration, preset: Preset | str,
                     config: TrackConfig | None = None, skeleton: Skeleton | None = None,
                     progress: Callable[[int, int], None] | None = None) -> DetectionTrack:
    """Track the person of ``detections`` seen by the ``calibration``'s cameras with a filter preset
    (module docstring), as ``config`` says (:class:`TrackConfig`; None: its defaults); ``skeleton``: the
    person's own body (an ASF or BVH skeleton) instead of the template scaled to the detections;
    ``progress(tick, ticks)``: called as the filter goes. :func:`prepared`, the filter's run, then
    :meth:`PersonRun.finished`.

    Memory: the detections' observations are read a block of ticks at a time
    (:class:`~priortrack.observation.ticks.TickObservations`; from a file too, given a
    :class:`~priortrack.data.detections.DetectionFile`), in a pass over the whole trial for the start
    (each tick's triangulation is kept, (T, 15, 3)), as the filter goes, and for the result's
    reprojection errors; each tick's spread and step record are taken as the filter goes; its point sets
    are let go unless kept, or needed by the smoother (the whole run's; a fixed lag keeps the last L + 1)."""
    return prepared(detections, calibration, preset, config, skeleton).tracked(progress)


#: A body measured over a trial is no adult's under this standing height or with a thigh longer than this (metres).
MIN_STATURE_M, MAX_THIGH_M = 1.2, 0.6


def implausible_body(skeleton: Skeleton, M: np.ndarray) -> str:
    """What makes the body (the skeleton fitted to a trial, in the detector's definitions M) no adult's: its standing
    height under :data:`MIN_STATURE_M`, its thigh over :data:`MAX_THIGH_M`; "" where nothing does."""
    height, thigh = stature(skeleton), body_measures(skeleton, M)["thigh"]
    return ", ".join([f"{height:.2f} m tall (under {MIN_STATURE_M})"] * (height < MIN_STATURE_M) +
                     [f"a thigh of {thigh:.2f} m (over {MAX_THIGH_M})"] * (thigh > MAX_THIGH_M))


def data_rate(given: float | None, stated: float | None, source: str) -> float:
    """The detections' frame rate: ``given`` (--fps) where given, else the one their file ``stated``; where both are and
    differ, the given one, warned (its frames are then stepped at that rate: 60 fps frames taken at 30 last twice as
    long); neither: refused."""
    if given is not None and stated is not None and not math.isclose(given, stated, rel_tol=1e-6):
        log.warning("%s says its frames are %g fps; --fps %g is taken (the motion is timed at %g fps: %s as fast as "
                    "the file says)", source, stated, given, given, f"{stated / given:.2g}×")
    rate = given if given is not None else stated
    if rate is None:
        raise PriortrackError(f"{source}: the detections do not say their frame rate; give it (--fps)")
    if not 0 < rate < 1e4:
        raise PriortrackError(f"fps must be a positive frame rate, got {rate}")
    return float(rate)


def prepared(detections: Detections, calibration: Calibration, preset: Preset | str, config: TrackConfig | None = None,
             skeleton: Skeleton | None = None) -> "PersonRun":
    """Everything of :func:`track_detections` before the filter runs (module docstring, 1–4): the cameras in
    the working frame, the tick schedule, the observations, the body, the start and the filter."""
    start_time = time.perf_counter()
    config = config or TrackConfig()
    preset = load_preset(preset) if not isinstance(preset, Preset) else preset
    data_fps = data_rate(config.fps, detections.fps, detections.source)
    calibrated = match_cameras(detections, calibration, config.camera_map)
    world_cameras = [PinholeCamera.from_calibration(c) for c in calibrated]
    up = config.up if config.up is not None else calibration.up
    if up is None:
        up = up_from_detections(world_cameras, detections, config.min_confidence, calibration.source)
    up = up if isinstance(up, str) and up in UP_AXES else up_vector(up)
    A = to_y_up(up)
    cameras = [in_working_frame(c, A) for c in world_cameras]
    prior = preset.prior(config.cache, cameras=len(cameras))
    index = schedule(detections.frames, data_fps, prior.fps)
    z = TickObservations(detections, index, config.min_confidence)     # (T, C, 15, 3), read a block at a time
    single = len(cameras) == 1
    # Student-t by default; the unscented filter needs a Gaussian (R), weighted by confidence as well.
    observation = {"sigma_px": DEFAULT_SIGMA_PX, "robust_nu": None if preset.filter_kind in UNSCENTED_KINDS else DEFAULT_NU,
                   **preset.observation_for(len(cameras))}
    # the start is robust whatever the filter's likelihood: the Student-t of the preset's σ
    noise = (observation["sigma_px"], DEFAULT_NU)
    X, seen, residual, z.left_out = _whole_trial(cameras, z, detections.camera_names, calibration.source,
                                                 config.min_confidence, noise)
    rejected = int(z.left_out.sum())
    counts = seen.sum(axis=-1)
    needed = start_joints(seen, single)
    if not single:          # triangulated joints place the body; the pose prior fills what the first ticks hide
        needed = min(needed, MIN_FIT_JOINTS)
    good = start_ticks(counts, residual, needed)
    if not len(good):
        raise PriortrackError(f"no two consecutive frames have {needed} joints "
                              f"{'detected' if single else 'seen by two cameras'}: cannot start (per tick: "
                              f"{counts[:10].tolist()}…)")
    first = int(good[0])
    if len(index) - first < KNOWN_FRAMES + 1:
        raise PriortrackError(f"{_counted(len(index) - first, 'tick')} from the start to the end of the detections "
                              f"({_counted(len(index), 'tick')} in all, at the prior's {prior.fps:g} fps): the filter "
                              f"needs {KNOWN_FRAMES + 1} to track" + (": give more frames (--frames)" if first == 0 else
                                                                        "; the person is seen well only late"))
    M = detector_map()
    template = getattr(prior.space, "skeleton", None) or cmu_skeleton("35")
    window = first + KNOWN_FRAMES
    while window < min(first + START_TICKS, len(counts)) and counts[window] >= min(MIN_FIT_JOINTS, needed):
        window += 1
    unmeasured, height_from = (), "skeleton"
    if skeleton is None:                           # else the user's own body, as given (not scaled)
        if single:
            height, height_from = _height(config, cameras[0], z, template, M, detections.source)
            skeleton = scaled_to_height(template, height)
        else:
            skeleton, height_from = fitted_skeleton(template, X, M), "triangulated"
        unmeasured = () if single else tuple(unmeasured_measures(X))
        unlikely = None if single else implausible_body(skeleton, M)
        if unlikely:
            log.warning("%s: the body measured over the trial is no adult's (%s): a false positive, two people's "
                        "detections taken for one, or a wrong keypoint layout?", detections.source, unlikely)
    pose = pose_spread(preset, skeleton)
    if pose is not None and not single:
        pose = own_posture(X, prior.fps, skeleton, pose, M, detections.source)
    if single:
        ticks = z[first:window][:, 0]
        fitted = inverse_kinematics_2d(ticks[..., :2], np.nan_to_num(ticks[..., 2]), cameras[0], prior.fps, skeleton, M,
                                       pose=pose, robust=noise)
    else:
        fitted = robust_start(X[first:window], z[first:window], cameras, prior.fps, M, skeleton, pose, noise)
    known = steady_start(fitted)
    model = TrackingModel.fitted(prior, preset.training_motions,
                                 MultiViewLikelihood(cameras, **observation, joint_map=M))
    filt = preset.filter_for(model, config.seed, config.device)
    torch.manual_seed(config.seed)
    initial = {"translation_std": START_TRANSLATION_STD} if preset.filter_kind in ("pf", "apf") else {}
    z, index = z.between(first), index[first:]         # from here on, tick 0 is the filter's first
    if hasattr(filt, "forward"):                     # the trunk's facing from the feet and face
        filt.forward = z.forward()
    if hasattr(filt, "floor") and single and config.floor is not None:    # one camera: a foot on the floor
        filt.floor = config.floor
    return PersonRun(detections, config, preset, prior, model, filt, z, index, None if single else X[first:], A, up,
                     cameras, world_cameras, M, skeleton, pose, unmeasured, rejected, known, initial, start_time,
                     first_tick=first, data_fps=data_fps, height_from=height_from)


#: Where a tracked body's height came from: the summary's ``height_from`` in words.
HEIGHT_FROM = {"triangulated": "measured", "floor": "measured from the floor", "given": "given",
               "nominal": "assumed", "skeleton": "the body given"}


def _height(config: TrackConfig, camera: PinholeCamera, z: TickObservations, template: Skeleton, M: np.ndarray,
            source: str) -> tuple[float, str]:
    """The standing height of one camera's person and where it came from (:data:`HEIGHT_FROM`): ``config.height``
    where given, else measured from the floor over the whole trial
    (:func:`~priortrack.tracking.floor_height.measured_height`), else :data:`NOMINAL_HEIGHT_M`; logged."""
    if config.height is not None:
        return config.height, "given"
    if config.floor is None:
        log.info("%s: one camera, the floor not known: the body is %g m tall (--height)", source, NOMINAL_HEIGHT_M)
        return NOMINAL_HEIGHT_M, "nominal"
    measured, why = measured_height(camera, z[:][:, 0], template, M, config.floor)
    if measured is None:
        log.warning("%s: one camera and no height measured from the floor (%s): the body is %g m tall (--height)",
                    source, why, NOMINAL_HEIGHT_M)
        return NOMINAL_HEIGHT_M, "nominal"
    log.info("%s: %.2f m tall, measured from the floor over %d ticks (quartiles %.2f–%.2f m; --height to give it)",
             source, measured.height_m, measured.ticks, *measured.iqr_m)
    return measured.height_m, "floor"


@dataclass(eq=False)
class PersonRun:
    """One person's run as :func:`prepared` leaves it: the observations z (T, C, 15, 3) from the start tick
    (``index`` (T,) their detection frames), the per-tick triangulation X (T, 15, 3) (None from one camera),
    the working frame's A (world → Y-up) and up, the cameras in the calibration's world, the detector map M,
    the body, the known start motion and the filter's further ``initial`` arguments; :meth:`on_step` takes
    each step's spread (and feeds a smoother) as the filter runs; :meth:`finished` makes the result of the
    filter's run (module docstring, 5)."""

    detections: Detections
    config: TrackConfig
    preset: Preset
    prior: object
    model: TrackingModel
    filt: object
    z: TickObservations
    index: np.ndarray
    X: np.ndarray | None
    A: np.ndarray
    up: object
    cameras: list[PinholeCamera]
    world_cameras: list[PinholeCamera]
    M: np.ndarray
    skeleton: Skeleton
    pose: PoseSpread | None
    unmeasured: tuple
    rejected: int
    known: Motion
    initial: dict
    start_time: float
    #: The filter's first tick on the detections' schedule, and their frame rate.
    first_tick: int = 0
    data_fps: float | None = None
    height_from: str = ""

    def __post_init__(self):
        config = self.config
        self.spread = np.full((len(self.z), 15), np.nan)
        self.whole = config.smooth and config.lag is None     # the whole run's smoother: what it needs of every step
        self.online = (FixedLagSmoother(self.filt, config.lag, config.trajectories, config.seed,
                                        method=config.particle_smoother)
                       if config.smooth and config.lag is not None else None)
        self.for_smoother = StepStore(config.memory) if self.whole else None

    def on_step(self, snapshot) -> None:
        self.spread[snapshot.frame] = _spread(snapshot)
        if self.online is not None:
            self.online.push(snapshot, self.z[snapshot.frame])
        if self.whole:
            self.for_smoother.append(snapshot)

    def tracked(self, progress: Callable[[int, int], None] | None = None) -> DetectionTrack:
        """The filter run over the whole of z, and its result (:meth:`finished`)."""
        config = self.config
        return self.finished(self.filt.run(self.z, self.known, keep_snapshots=config.keep_snapshots, progress=progress,
                                           snapshot_every=config.snapshot_every, on_step=self.on_step,
                                           interruptible=config.interruptible, **self.initial))

    def observe(self, detections: Detections) -> None:
        """Take ``detections`` (the same frames and cameras) as the person's, who is who decided again
        (:mod:`~priortrack.tracking.reassociation`): z read from them (no camera-tick left out) and X
        triangulated again."""
        self.detections = detections
        self.z = TickObservations(detections, self.index, self.config.min_confidence)
        if self.X is not None:
            noise = (self.model.likelihood.sigma_px, DEFAULT_NU)
            self.X = np.concatenate([triangulated(self.cameras, block, noise) for _, block in self.z.blocks()])

    def finished(self, run) -> DetectionTrack:
        """The result (:class:`DetectionTrack`) of the filter's run (a :class:`~priortrack.filters.snapshot.Track`):
        smoothed as the config says, its log-likelihoods, reprojection errors, mismatch flags and fit-check."""
        z, index, spread, X = self.z, self.index, self.spread, self.X
        if self.whole:
            self.for_smoother.truncate(len(run.estimates) - KNOWN_FRAMES)          # an interrupted run's steps
            if self.for_smoother.spilled:
                log.info("smoothing %d ticks, %d of them read back from disk", len(self.for_smoother), self.for_smoother.spilled)
            try:
                smoothed = smooth_run(self.filt, replace(run, snapshots=self.for_smoother), z[:len(run.estimates)],
                                      self.config.trajectories, None, self.config.seed,
                                      method=self.config.particle_smoother)
            except KeyboardInterrupt:
                if not self.config.interruptible:
                    raise
                log.warning("interrupted while smoothing: the filter's estimate is kept, not smoothed")
                smoothed, run = None, replace(run, interrupted=True)
            finally:
                self.for_smoother.close()                    # the smoother has them; let them go
        else:
            smoothed = self.online.result(run.estimates[:KNOWN_FRAMES]) if self.online is not None else None
        T = len(run.estimates) if smoothed is None else min(len(run.estimates), len(smoothed.estimates))
        if T < len(z):                                 # interrupted: what was tracked until then
            z, index, spread, X = z.between(0, T), index[:T], spread[:T], None if X is None else X[:T]
            run = replace(run, estimates=run.estimates[:T], ess=run.ess[:T], steps=run.steps[:T - KNOWN_FRAMES])
            smoothed = None if smoothed is None else replace(smoothed, estimates=smoothed.estimates[:T],
                                                             spread=smoothed.spread[:T])
        filtered_spread = None if smoothed is None else spread.copy()
        if smoothed is not None:
            spread[KNOWN_FRAMES:] = smoothed.spread[KNOWN_FRAMES:]
        estimates = run.estimates if smoothed is None else smoothed.estimates
        loglik = frame_log_likelihoods(self.model.likelihood, run.estimates, z)
        joints = in_world(estimates, self.A)
        errors, weight = _reprojection_errors(self.world_cameras, joints, z)
        mismatch = mismatch_flags(loglik, weight, self.model.likelihood)
        body = np.einsum("ij,tjk->tik", self.M, run.estimates)            # in the detector's joint definitions
        lost = None if X is None else lost_flags(body, X)
        held_out = held_out_ratios(self.cameras, body, z) if len(self.cameras) >= MIN_CAMERAS else None
        with np.errstate(invalid="ignore"):
            worse = None if held_out is None else _in_runs(held_out > WORSE_RATIO)
        # an effective sample size only where there are particles (a UKF's "ESS" is its sigma-point count)
        ess = np.asarray(run.ess, dtype=float) if self.preset.filter_kind in ("pf", "apf") else np.full(T, np.nan)
        reprojection = np.array([_median_of_seen(e) for e in errors])                # over every tick and joint
        by_tick = np.stack([_tick_medians(e) for e in errors], axis=1)               # (T, C)
        del errors, X                      # (T, ·) arrays the fit-check's peak need not hold (a long run's memory)
        gated = np.zeros(z.shape[:3], dtype=bool)                                      # (T, C, 15)
        for step in run.steps:
            if step.held_out is not None and step.frame < T:
                gated[step.frame] = step.held_out.reshape(z.shape[1:3])
        result = DetectionTrack(joints, np.where(index >= 0, self.detections.frames[np.maximum(index, 0)], -1),
                                float(self.prior.fps), spread, ess, loglik, mismatch,
                                self.detections.camera_names, reprojection, self.preset.name, time.perf_counter() - self.start_time,
                                self.up, self.A, self.skeleton, estimates, self.world_cameras, z,
                                run.snapshots, run.steps, self.rejected,
                                None if smoothed is None else in_world(run.estimates, self.A),
                                self.config.lag if self.config.smooth else None,
                                filtered_spread=filtered_spread, interrupted=run.interrupted, reprojection_by_tick=by_tick,
                                gated=gated, pose_spread=self.pose, bones_unmeasured=self.unmeasured,
                                height_from=self.height_from,
                                held_out_ratio=np.full(T, np.nan) if held_out is None else held_out,
                                tick_times=(self.first_tick + np.arange(T)) / float(self.prior.fps),
                                data_fps=self.data_fps, data_frames=np.asarray(self.detections.frames),
                                detections=self.detections, min_confidence=self.config.min_confidence)
        result.fit_check, implausible = None, None
        if self.config.fit_check:
            try:
                result.fit_check, implausible = tracked_fit_check(self.preset, self.prior, result, self.config.cache)
            except KeyboardInterrupt:
                if not self.config.interruptible:
                    raise
                log.warning("interrupted during the fit-check: the result is kept without it")
                result.interrupted = True
        if implausible is not None:          # a mismatch is also a tick the prior itself finds implausible
            result.mismatch = result.mismatch & implausible
        unlikely = result.mismatch.copy()
        for flags in (lost, worse):          # … or one where the estimate has left the data's own triangulation
            if flags is not None:
                result.mismatch = result.mismatch | flags
        if result.fit_check is not None and result.fit_check["verdict"] != "in support":
            from priortrack.priors.support import verdict_rule

            better, unfitted = result.fit_check.get("better_prior"), result.fit_check.get("not_compared", [])
            log.warning("%s: fit-check: the tracked motion is %s the %s prior's support (%.0f%% of its frames below the "
                        "1st percentile of held-out training frames; %s); its estimate leans on a prior that does not "
                        "know the motion: %s%s", self.detections.source,
                        "outside" if result.fit_check["verdict"] == "outside" else "partly in",
                        self.preset.prior_kind, 100 * result.fit_check["below_p1_fraction"], verdict_rule(),
                        "no shipped prior fits it better; fit one on motion like it (priortrack fit)" if better is None else
                        f"the {better['preset']} preset's prior fits it better ({better['verdict']}, "
                        f"{100 * better['below_p1_fraction']:.0f}% of its frames below): track with --filter {better['preset']}",
                        "" if not unfitted else f" (not compared, their priors not fitted yet: {', '.join(unfitted)}; "
                                                f"a run with that --filter fits one once, minutes)")
        if result.mismatch_fraction > 0:
            log.warning("%s: %s", self.detections.source, mismatch_message(result.mismatch, unlikely, lost,
                                                                            self.preset.prior_kind,
                                                                            implausible is not None, worse))
        return result


def no_fit_check(preset: Preset) -> str | None:
    """Why the preset's runs get no fit-check (:func:`tracked_fit_check`), None where they do."""
    from priortrack.priors.registry import PRIOR_KINDS

    return ("the preset names a prior file" if preset.prior_file is not None
            else "a GPDM's pose density is in its training skeleton's angles"
            if "latent" in PRIOR_KINDS[preset.prior_kind].capabilities else None)


def fitted_once(preset: Preset | str, cache=None) -> Preset:
    """The preset, its prior and its fit-check's reference fitted and cached here, so that runs side by side
    (several people's, in worker processes) read them from the cache instead of each fitting them."""
    from priortrack.priors.support import reference

    preset = load_preset(preset) if not isinstance(preset, Preset) else preset
    preset.prior(cache)
    if no_fit_check(preset) is None:
        reference(preset, cache)
    return preset


def tracked_fit_check(preset: Preset, prior, result: DetectionTrack,
                      cache=None) -> tuple[dict | None, np.ndarray | None]:
    """The fit-check (:mod:`priortrack.priors.support`) of the tracked body's motion (its joints fitted
    by inverse kinematics) under the prior, against the preset's held-out reference, and the ticks (T,)
    whose step it scores below the reference's 1st percentile; (None, None) (logged) for a
    prior file (no known training motions), a run too short to judge, or a GPDM: its pose density is
    in the training skeleton's joint angles, and the tracked body is the detector's (hips where the
    detector puts them), so every tracked walk scored "outside" (35_29 and 07_10 on real-format input);
    its runs rely on the likelihood's mismatch flag, which separates them (0 % on those walks, 100 % on
    a balance). The per-tick triangulation was tried as the motion judged instead (a prior-free
    estimate): its detector noise made a held-out walk "outside". The references are read from the run's
    prior ``cache`` (None: the default), where :func:`fitted_once` puts them."""
    from priortrack.priors.support import frame_log_density, reference, reference_path, verdict

    ticks = np.isfinite(result.body_joints).all(axis=(1, 2))
    reason = no_fit_check(preset) or (f"{int(ticks.sum())} tracked ticks" if ticks.sum() < MIN_FIT_CHECK_TICKS
                                      else None)
    if reason is not None:
        log.info("no fit-check of the tracked motion: %s", reason)
        return None, None
    if not reference_path(preset, cache).is_file():
        log.warning("fit-check: fitting the %s prior's held-out reference once (two cross-fits of its %d training "
                    "motions: seconds for diffusion, minutes for a learned prior; cached for later runs; --no-fit-check "
                    "skips the fit-check)", preset.prior_kind, len(preset.train))
    motion = inverse_kinematics(result.body_joints if ticks.all() else result.body_joints[ticks], result.fps,
                                skeleton=result.skeleton, name="tracked", pose=result.pose_spread)
    ell, reference_values = frame_log_density(prior, motion), reference(preset, cache)
    found = verdict(ell, reference_values)
    implausible = np.zeros(len(ticks), dtype=bool)
    implausible[np.flatnonzero(ticks)[1:]] = ell < np.percentile(reference_values, 1)
    check = {key: found[key] for key in ("verdict", "below_p1_fraction", "median_percentile")}
    if found["verdict"] != "in support":
        check["better_prior"], check["not_compared"] = better_fitting(motion, preset, found["below_p1_fraction"], cache)
    return check, implausible


def better_fitting(motion, preset: Preset, below: float, cache=None, fit: bool = False) -> tuple[dict | None, list[str]]:
    """The shipped preset of :data:`ALTERNATIVE_PRIORS` (not ``preset`` itself) whose prior finds ``motion``
    most plausible: the smallest share of its frames below that prior's held-out 1st percentile
    (:mod:`priortrack.priors.support`), if smaller than ``below``, the running preset's share; else None.
    Returns ({"preset", "verdict", "below_p1_fraction"} or None, the alternatives not compared). An alternative whose
    prior or reference the cache does not hold is fitted only with ``fit`` (``eval fit-check``); a tracking run
    does not wait for it (pf-lie-general's 23 activities took over 30 minutes on 2 cores, after every tick was
    tracked and before any result was written), it names it instead."""
    from priortrack.priors.support import frame_log_density, reference, reference_path, verdict

    best, skipped = None, []
    for name in ALTERNATIVE_PRIORS:
        if name == preset.name:
            continue
        alternative = load_preset(name)
        if not fit and not (alternative.prior_path(cache).is_file() and reference_path(alternative, cache).is_file()):
            skipped.append(name)
            continue
        found = verdict(frame_log_density(alternative.prior(cache), motion), reference(alternative, cache))
        if found["below_p1_fraction"] < (below if best is None else best["below_p1_fraction"]):
            best = {"preset": name, "verdict": found["verdict"], "below_p1_fraction": found["below_p1_fraction"]}
    return best, skipped


def pose_spread(preset: Preset, skeleton: Skeleton) -> PoseSpread | None:
    """The pose spread of the preset's training motions (:class:`~priortrack.body.ik.PoseSpread`), which the
    start's and the fit-check's inverse kinematics pull the body to, whatever the prior's state: where it is
    the body's joint angles, the pull keeps only the channels its training moves (a start that turned the others,
    CMU 35's clavicles, lost them on entering the filter); for every prior, it is the start's pose prior. From one
    camera a limb tilted towards it and one tilted away project alike, and the pull weighs between them (the fit
tries each limb's branches, :meth:`~priortrack.body.ik.OneCameraFit.over_branches`): a pull
    to rest (zero angles) started pf-lie on people it never saw 185 mm root-relative off at its first tick (the
    ankles 240–290 mm: the legs on the wrong branch) where the walking poses' pull started it at 32 mm (issue 45).
    None (logged: a pull to rest) where the training motions do not share the skeleton's channels (a user's own
    skeleton)."""
    motions = preset.training_motions
    if any(m.skeleton.channel_names != skeleton.channel_names for m in motions):
        log.info("inverse kinematics pulls the body to rest: the preset's training motions' channels are not the body's")
        return None
    return PoseSpread.of(motions)


def start_joints(seen: np.ndarray, single: bool) -> int:
    """The joints a start tick needs (:data:`START_JOINTS`, or fewer where the trial never shows as many)
    from ``seen`` (T, 15) bool, each tick's joints triangulated (``single``: detected by the one camera), shares
    taken over the ticks that show any joint; logged when fewer, refused below MIN_START_JOINTS."""
    how = "detected" if single else "triangulated"
    seen = seen[seen.any(axis=1)]                # the ticks that show the person at all (one of a scene's may leave)
    shown = (seen.mean(axis=0) >= VIEW_SHARE) if len(seen) else np.zeros(15, dtype=bool)
    if shown.sum() >= START_JOINTS:
        return START_JOINTS
    if shown.sum() < MIN_START_JOINTS:
        raise PriortrackError(f"only {int(shown.sum())} joints ({', '.join(np.array(EVAL15_NAMES)[shown]) or 'none'}) "
                              f"are {how} in at least {VIEW_SHARE:.0%} of the ticks; the start needs "
                              f"{MIN_START_JOINTS} (the upper body in view of {'the camera' if single else 'two cameras'})")
    log.warning("the trial shows %d joints in most ticks (%s; %s missing): the start fits those%s", int(shown.sum()),
                ", ".join(np.array(EVAL15_NAMES)[shown]), ", ".join(np.array(EVAL15_NAMES)[~shown]),
                "; from one camera without the legs the body's depth rests on the upper body's image size (walks "
                "with the legs hidden, on the real-format bench: 0.4–1.1 m off along the ray, against 0.1–0.2 m with "
                "them)" if single and not shown[[11, 14]].any() else "")
    return int(shown.sum())


def start_ticks(counts: np.ndarray, residual: np.ndarray | None = None, needed: int = START_JOINTS) -> np.ndarray:
    """The ticks t (ascending) where t and t + 1 both have ``needed`` joints (``counts`` (T,)) and, given
    ``residual`` (T,) (each tick's worst camera's median reprojection of its triangulation, px), both
    reproject within START_CONSISTENCY times the median such tick's: a start on a tick where one camera
    swapped left and right, or saw someone else, fitted the body to wrong joints (real-format 07_10, seed 2:
    its first start tick's triangulation 276 mm off, the tracked walk's error doubled). Where no tick pair
    is consistent, the counts alone decide (logged)."""
    enough = counts >= needed
    good = np.flatnonzero(enough[1:] & enough[:-1])
    if residual is None or not len(good):
        return good
    consistent = enough & (residual <= START_CONSISTENCY * np.nanmedian(residual[enough]))
    steady = np.flatnonzero(consistent[1:] & consistent[:-1])
    if not len(steady):
        log.info("no two consecutive ticks triangulate consistently in every camera: starting on the first "
                 "with %d joints", needed)
        return good
    if steady[0] != good[0]:
        log.info("start: ticks %d–%d skipped (a camera's detections disagree with the others')", good[0], steady[0] - 1)
    return steady


def cross_view_check(cameras: list[PinholeCamera], z: np.ndarray) -> np.ndarray:
    """Leave out (NaN, in place) at each tick the camera, if any, that follows someone else: the camera
    without which the others agree best (the smallest median reprojection error of their own
    triangulation), if its detections lie a median CROSS_VIEW_GATE of its image diagonal from that
    triangulation (module docstring). z: (T, C, 15, 3); returns the camera-ticks left out (T, C) bool."""
    C = len(cameras)
    left_out = np.zeros(z.shape[:2], dtype=bool)
    if C < 3:
        return left_out
    seen = np.isfinite(z[..., 0]) & (np.nan_to_num(z[..., 2]) > 0)                # (T, C, 15)
    agreement = np.full(z.shape[:2], np.inf)                                       # (T, C): the others', px
    distance = np.zeros(z.shape[:2])                                               # (T, C): c's, in gates

    for c, camera in enumerate(cameras):
        others = [k for k in range(C) if k != c]
        pixels, weights = z[:, others, :, :2], z[:, others][..., 2]                  # (T, C−1, 15, 2), (T, C−1, 15)
        X = triangulate([cameras[k] for k in others],
                        np.where(seen[:, others, :, None], pixels, np.nan).transpose(1, 0, 2, 3),
                        np.where(seen[:, others], weights, 0.0).transpose(1, 0, 2))                  # (T, 15, 3)
        medians = np.stack([median_reprojection(cameras[k], X, z[:, k]) for k in others])   # the worst of the others'
        agreement[:, c] = np.where(np.isfinite(medians).any(axis=0), np.nan_to_num(medians, nan=-np.inf).max(axis=0),
                                   np.inf)
        gate = CROSS_VIEW_GATE * math.hypot(camera.width, camera.height)
        distance[:, c] = np.nan_to_num(median_reprojection(camera, X, z[:, c]) / gate, nan=0.0)
    suspect = np.argmin(agreement, axis=1)
    ticks = np.flatnonzero(np.take_along_axis(distance, suspect[:, None], 1)[:, 0] > 1)
    left_out[ticks, suspect[ticks]] = True
    z[left_out] = np.nan
    return left_out


def steady_start(window: Motion) -> Motion:
    """The first two frames of a fitted ``window`` with the root's translation channels on their
    least-squares line over the window and the root's rotation channels of the second frame in both."""
    skeleton, channels = window.skeleton, window.channels.copy()
    translation = skeleton.trans_channels[0][skeleton.trans_channels[0] >= 0]
    rotation = skeleton.rot_channels[0][skeleton.rot_channels[0] >= 0]
    t = np.arange(len(channels))
    slope, intercept = np.polyfit(t, channels[:, translation], 1) if len(channels) > 1 else (0.0, channels[0, translation])
    channels[:, translation] = intercept + np.outer(t, slope)
    channels[0, rotation] = channels[1, rotation]
    return replace(window, channels=channels[:KNOWN_FRAMES])


def _spread(snapshot) -> np.ndarray:
    """(15,) RMS distance of each joint from the estimate over the snapshot's weighted point set
    (:func:`~priortrack.filters.smoothing.joint_spread`), with the translation's Kalman covariance where
    the filter integrated it out. Particles: about their weighted mean. Sigma points (weights Wm, the
    first negative): about the central point, the mean's joints X_0, as Σ_i Wm_i ‖X_i − X_0‖², the
    unscented transform's variance (Wc_i = Wm_i for i ≥ 1; the central term is zero)."""
    w = snapshot.weights.detach().cpu().double()
    X = snapshot.joints.detach().cpu().double()
    w = w / w.sum()
    centre = X[0] if (w < 0).any() else torch.einsum("p,pjk->jk", w, X)
    variance = joint_spread(X[:, None], centre[None], w)[0] ** 2
    spread = snapshot.translation_spread()
    if spread is not None:
        variance = variance + float(np.trace(spread[1]))
    return np.sqrt(variance)


def _expected_log_density(likelihood: MultiViewLikelihood) -> float:
    """E[ℓ(|d|²)] per detection when the detection noise is the model's: for the bivariate Student-t,
    E[log(1 + |d|²/(ν σ²))] = ψ(1 + ν/2) − ψ(ν/2) = 2/ν; for the Gaussian, E[|d|²] = 2σ²."""
    var, nu = likelihood.sigma_px ** 2, likelihood.robust_nu
    if nu is None:
        return -1.0 - math.log(2 * math.pi * var)
    const = math.lgamma((nu + 2) / 2) - math.lgamma(nu / 2) - math.log(nu * math.pi * var)
    return const - 0.5 * (nu + 2) * (2 / nu)


def frame_log_likelihoods(likelihood, estimates: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(T,) log p(z_t | estimate_t) under the observation model, for estimates (T, J, 3) and the data
    z (T, …) (pixels, with confidences for several cameras); NaN where the estimate is not finite or
    nothing was seen."""
    loglik = np.full(len(estimates), np.nan)
    for t, (joints, frame) in enumerate(zip(estimates, z)):
        if np.isfinite(joints).all() and np.isfinite(frame[..., :2]).any():
            loglik[t] = float(likelihood.log_likelihood(torch.as_tensor(joints)[None], torch.as_tensor(frame))[0])
    return loglik


def mismatch_message(mismatch: np.ndarray, unlikely: np.ndarray, lost: np.ndarray | None, prior_kind: str,
                     judged_by_prior: bool, worse: np.ndarray | None = None) -> str:
    """The warning of a run with ticks flagged as mismatch: how many, and what was measured at each (the
    detections unlikely under the estimate, by MISMATCH_NATS a detection for MISMATCH_RUN ticks, and a
    pose the prior finds implausible where it was judged; the estimate LOST_MM from the triangulation; with
    three cameras or more, ``worse``, an estimate that explains the detections worse than triangulation does).
    It names no other preset: the fit-check's warning does, where a shipped prior fits the motion better."""
    T = len(mismatch) - KNOWN_FRAMES
    causes = [f"{int(unlikely.sum())} where the detections are over {MISMATCH_NATS:g} nats a detection less likely "
              f"than the noise model expects for {MISMATCH_RUN}+ ticks"
              + (f" and the {prior_kind} prior finds the tracked pose implausible" if judged_by_prior else "")]
    if lost is not None:
        causes.append(f"{int(lost.sum())} where the estimate is on average over {LOST_MM:g} mm from the detections' "
                      f"own triangulation")
    if worse is not None:
        causes.append(f"{int(worse.sum())} where it explains each camera's detections over {WORSE_RATIO:g}× worse than "
                      f"the other cameras' triangulation, which never saw them (worse than triangulation)")
    return (f"{int(mismatch.sum())} of {T} tracked ticks ({100 * mismatch.sum() / max(T, 1):.1f}%) are flagged as "
            f"mismatch: {'; '.join(causes)}. The estimate there does not explain the detections: look at those ticks "
            f"(the npz's mismatch, the recording's events) for a detector's swap or a lost limb, or a motion the "
            f"{prior_kind} prior did not learn")


def detection_weight(z: np.ndarray) -> np.ndarray:
    """(T,) each tick's summed confidence Σ w of the detections seen, z (T, C, J, 3) with confidences."""
    return np.nansum(np.where(np.isfinite(z[..., 0]), z[..., 2], 0.0), axis=(1, 2))


def mismatch_flags(loglik: np.ndarray, weight: np.ndarray, likelihood: MultiViewLikelihood) -> np.ndarray:
    """(T,) bool: the ticks in runs of MISMATCH_RUN whose mean log-likelihood per detection is
    MISMATCH_NATS below the noise model's expectation (module docstring). loglik (T,) of the estimates,
    weight (T,) the detections' summed confidence (:func:`detection_weight`), ``likelihood`` any model
    with sigma_px and robust_nu."""
    with np.errstate(invalid="ignore", divide="ignore"):
        per_detection = loglik / weight
    return _in_runs(per_detection < _expected_log_density(likelihood) - MISMATCH_NATS)


def lost_flags(estimates: np.ndarray, triangulated: np.ndarray) -> np.ndarray:
    """(T,) bool: the ticks in runs of MISMATCH_RUN where the estimate's joints lie on average more than
    ``LOST_MM`` from the per-tick triangulation of the detections (both (T, 15, 3) metres, in the
    detector's joint definitions; NaN where a joint was not triangulated, a tick with none is not judged).
    The mean, not the median: a walking prior that cannot raise the arms of a person balancing with arms
    out is off by 0.3–0.5 m at four joints and close at the rest."""
    distance = np.linalg.norm(estimates - triangulated, axis=-1)
    judged = np.isfinite(distance).any(axis=1)
    mean = np.full(len(distance), np.nan)
    mean[judged] = np.nanmean(distance[judged], axis=1)
    with np.errstate(invalid="ignore"):
        return _in_runs(mean > LOST_MM / 1000)


def held_out_ratios(cameras: list[PinholeCamera], E: np.ndarray, z: TickObservations) -> np.ndarray:
    """(T,) each tick's held-out ratio q (:mod:`~priortrack.tracking.held_out`: the estimate's reprojection error in
    each camera over that of the other cameras' triangulation, in a window about the tick; NaN where not judged),
    for the estimate E (T, 15, 3) in the detector's joint definitions and the working frame of the ``cameras``
    (three or more), against the detections the filter saw (z, read a block at a time)."""
    errors = [held_out_errors(cameras, E[start:start + len(block)], block) for start, block in z.blocks()]
    return held_out_ratio(*(np.concatenate([e[k] for e in errors], axis=1) for k in (0, 1)))


def _in_runs(bad: np.ndarray) -> np.ndarray:
    """(T,) bool: the ticks of ``bad`` (T,) in runs of at least MISMATCH_RUN, the known frames never."""
    bad = bad.copy()
    bad[:KNOWN_FRAMES] = False
    flagged = np.zeros_like(bad)
    run = 0
    for t, b in enumerate(bad):
        run = run + 1 if b else 0
        if run >= MISMATCH_RUN:
            flagged[t - run + 1:t + 1] = True
    return flagged


def _reprojection_errors(cameras: list[PinholeCamera], joints: np.ndarray,
                         z: TickObservations) -> tuple[np.ndarray, np.ndarray]:
    """Each camera's :func:`pixel_errors` (C, T, 15) float32 of the ``joints`` (T, 15, 3) (the world's,
    through the world's ``cameras``) against every tick's detections, left-out ones included, and the
    :func:`detection_weight` (T,) of the detections the filter saw; z read a block at a time."""
    errors = np.full((len(cameras), len(z), 15), np.nan, dtype=np.float32)
    weight = np.zeros(len(z))
    for start, raw in z.blocks(raw=True):
        ticks = slice(start, start + len(raw))
        for c, camera in enumerate(cameras):
            errors[c, ticks] = pixel_errors(camera, joints[ticks], raw[:, c, :, :2], np.nan_to_num(raw[:, c, :, 2]))
        raw[z.left_out[ticks]] = np.nan
        weight[ticks] = detection_weight(raw)
    return errors, weight


def _median_of_seen(errors: np.ndarray) -> float:
    """The median of :func:`pixel_errors` (T, J) over every tick and joint seen; NaN if none is."""
    return float(np.nanmedian(errors)) if np.isfinite(errors).any() else float("nan")


def _tick_medians(errors: np.ndarray, least: int = 1) -> np.ndarray:
    """(T,) each tick's median of :func:`pixel_errors` (T, J) over the joints seen; NaN where fewer than
    ``least`` are."""
    seen = np.isfinite(errors).sum(axis=1) >= least
    out = np.full(len(errors), np.nan)
    out[seen] = np.nanmedian(errors[seen], axis=1)
    return out


def median_reprojection(camera: PinholeCamera, X: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(T,) each tick's median pixel distance between the joints X (T, 15, 3) projected through ``camera``
    and its detections z (T, 15, 3: u, v, confidence), over the joints it saw (NaN below 4 of them)."""
    return _tick_medians(pixel_errors(camera, X, z[..., :2], z[..., 2]), least=4)
