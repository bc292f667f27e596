"""``RerunLogger``: a filter run written to a rerun recording as it goes, for users' own loops
(``replay`` and ``priortrack compare --rrd`` use it too).

Per frame (:meth:`RerunLogger.log`): the truth skeleton (joints missing from that frame's
observation drawn grey), the 2D observations and the estimate's reprojection in the camera's image,
the estimate (and smoothed) skeletons, the particle cloud or sigma points coloured by weight, the
translation's 1σ ellipsoid; the quantities ``metrics/error_mm`` (against the truth),
``metrics/ess_fraction`` (ESS / particles), ``metrics/loglik`` (the observation model's
log-likelihood of the estimate) and ``metrics/mismatch``, each in its own time-series view; and text
events at ``events`` (:func:`step_events`). The recording opens on the layout of
:meth:`~priortrack.viz.recording.Recording.layout`.

Example::

    with RerunLogger("run.rrd", camera, name="pf-lie · my walk", likelihood=model.likelihood) as logger:
        for t, z in enumerate(observations[2:], start=2):
            logger.log(t, filt.step(z), observation=z, truth=truth[t])
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from priortrack.filters.snapshot import StepRecord
from priortrack.geometry.camera import PinholeCamera
from priortrack.viz.recording import Recording

TRUTH_COLOR, OCCLUDED_COLOR = (60, 160, 255), (150, 150, 150)
ESTIMATE_COLOR, SMOOTHED_COLOR = (255, 90, 60), (120, 230, 90)
OBSERVATION_COLOR = (40, 200, 255)


#: A step's flags as events: (text, level).
FLAG_EVENTS = {"innovation-gated": ("the gate held out detections the prediction cannot explain", "INFO"),
               "outlier-gated": ("detections far off the body left out", "INFO"),
               "swap-corrected": ("a detector's left/right swap undone", "INFO"),
               "branch-repaired": ("an elbow one camera sees moved off its branch through the chest", "INFO"),
               "facing-turned": ("a trunk one camera sees turned to the facing its feet and face show", "INFO"),
               "floor-contact": ("the lower ankle held on the floor (one camera)", "DEBUG"),
               "gate-reopened": ("the gate reopened: every detection had failed it too long", "WARN"),
               "joint-reacquired": ("a joint every camera had seen away from the estimate too long taken again",
                                    "WARN"),
               "no-observation": ("nothing observed: the prediction stands", "WARN"),
               "weights-underflow": ("every particle's likelihood underflowed: weights reset", "WARN"),
               "covariance-repaired": ("covariance repaired to positive definite", "DEBUG"),
               "behind-camera": ("some sigma points behind a camera", "DEBUG")}


def step_events(frame: int, step: StepRecord | None = None, mismatch: bool | None = None,
                observed: bool = True) -> list[tuple[str, str]]:
    """The text events of one frame, (text, level): resampling, the flags of :data:`FLAG_EVENTS`
    (a held-out count where the step says it), mismatch, a frame with nothing observed. A negative ``frame`` is a
    tick without a detection frame (the prior's ticks outrun the detections' rate, or the person's detections have
    ended): said so, not "frame -1"."""
    events = []
    where = f"frame {frame}" if frame >= 0 else "a tick without a detection frame"
    if step is not None:
        if step.resampled:
            events.append((f"{where}: resampled (ESS {step.ess:.0f} of {step.points})", "DEBUG"))
        for flag in step.flags:
            text, level = FLAG_EVENTS.get(flag, (flag, "INFO"))
            count = (f" ({int(step.held_out.sum())} points)" if flag == "innovation-gated" and step.held_out is not None
                     else "")
            events.append((f"{where}: {text}{count}", level))
    if mismatch:
        events.append((f"{where}: mismatch: the prior does not explain this frame", "WARN"))
    if not observed and not (step is not None and "no-observation" in step.flags):
        events.append((f"{where}: missing: nothing observed", "WARN"))
    return events


class RerunLogger:
    """A recording of one filter run, frame by frame (module docstring).

    Args:
        path: the ``.rrd`` file.
        camera: the camera the observations were taken with (its pinhole and image are logged).
        name: the recording's name in the viewer (filter · motion · scenario · seed, say).
        likelihood: an observation model (``log_likelihood(joints, z)``) to log the estimate's
            log-likelihood with; none, none logged.
    """

    def __init__(self, path: str | Path, camera: PinholeCamera, name: str | None = None, likelihood=None):
        self.recording = Recording(path, name=name)
        self.recording.camera(camera)
        self.camera, self.likelihood = camera, likelihood

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.recording.close()

    @property
    def path(self) -> Path:
        return self.recording.path

    def log(self, frame: int, snapshot=None, observation=None, truth=None, estimate=None, smoothed=None,
            mismatch: bool | None = None) -> None:
        """Log one frame.

        Args:
            frame: the frame index (the ``frame`` timeline).
            snapshot: the filter's step (:class:`~priortrack.filters.snapshot.Snapshot`): its estimate,
                cloud, ESS, flags, resampling and translation spread.
            observation: the frame's 2D joints (15, 2) pixels, NaN where missing.
            truth: (15, 3) the true joints, metres, if known.
            estimate: (15, 3) joints to draw as the estimate when there is no snapshot (a known frame).
            smoothed: (15, 3) the smoothed joints, if the run was smoothed.
            mismatch: the frame's mismatch flag, if computed.
        """
        rec = self.recording
        rec.frame(frame)
        seen = None if observation is None else np.isfinite(np.asarray(observation)).all(axis=-1)
        if observation is not None:
            rec.points_2d("observations", observation, color=OBSERVATION_COLOR)
        if truth is not None:
            colours = np.tile(TRUTH_COLOR, (len(truth), 1))
            if seen is not None:
                colours[~seen] = OCCLUDED_COLOR
            rec.skeleton("truth", truth, colors=colours)
        if snapshot is not None:
            estimate = snapshot.estimate
            rec.cloud("estimate", snapshot.joints.detach().cpu().numpy(), snapshot.weights.detach().cpu().numpy())
            spread = snapshot.translation_spread()
            if spread is not None:
                rec.ellipsoid("estimate/translation", *spread, color=ESTIMATE_COLOR)
            if snapshot.covariance is None:                   # a particle set (a Gaussian filter's has no ESS)
                rec.scalar("ess_fraction", snapshot.ess / len(snapshot.weights))
        if estimate is not None and np.isfinite(estimate).all():
            rec.skeleton("estimate", estimate, color=ESTIMATE_COLOR)
            uv, _ = self.camera.project(torch.as_tensor(estimate))
            rec.points_2d("estimate", uv.numpy(), color=ESTIMATE_COLOR)
            if truth is not None:
                rec.scalar("error_mm", 1000 * float(np.linalg.norm(np.asarray(estimate) - truth, axis=-1).mean()))
            if self.likelihood is not None and seen is not None and seen.any():
                rec.scalar("loglik", float(self.likelihood.log_likelihood(
                    torch.as_tensor(estimate, dtype=torch.float64)[None],
                    torch.as_tensor(observation, dtype=torch.float64))[0]))
        if smoothed is not None and np.isfinite(smoothed).all():
            rec.skeleton("smoothed", smoothed, color=SMOOTHED_COLOR)
        if mismatch is not None:
            rec.scalar("mismatch", float(mismatch))
        step = None if snapshot is None else StepRecord.of(snapshot)
        for text, level in step_events(frame, step, mismatch, observation is None or bool(seen.any())):
            rec.event(text, level)
