"""What every filter shares: running over a whole sequence of observations.

A filter (particle, annealed, unscented, MAP) keeps ``model`` (its ``prior.fps`` is the frame
rate of the observations), ``initialise(motion)`` (start on the first two, known frames) and
``step(z) -> Snapshot``; :class:`SequentialFilter` turns those into ``run(observations, motion)
-> Track``, so a notebook can step frame by frame and a script can run the whole clip. The particle and
unscented filters also step in halves, ``advance()`` then ``correct(z)``, with ``predicted_measurement()``
between (each observed point's predicted pixels and their spread): the scene tracker decides whose
detection is whose from it (:mod:`priortrack.tracking.reassociation`), recording each step in the
:class:`Run` that :meth:`SequentialFilter.started` gives.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np

from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.filters.snapshot import KNOWN_FRAMES, Snapshot, StepRecord, Track
from priortrack.body.fk import joint_positions
from priortrack.observation.ticks import TickObservations

log = logging.getLogger(__name__)


class SequentialFilter:
    """The ``run`` loop over ``initialise`` and ``step``, which subclasses provide."""

    def run(self, observations, motion: Motion, keep_snapshots: bool = False,
            progress: Callable[[int, int], None] | None = None, snapshot_every: int = 1,
            on_step: Callable[[Snapshot], None] | None = None, interruptible: bool = False, **initial) -> Track:
        """Initialise on the first two frames of ``motion`` and filter the rest.

        Memory: without kept snapshots the run holds its estimates and a :class:`StepRecord` a frame,
        not the steps' point sets; ``on_step`` sees each step's snapshot before it is let go.
        ``interruptible``: interrupted (Ctrl-C, KeyboardInterrupt) after its first filtered frame, the run
        ends there and the Track holds the frames tracked so far (``interrupted`` set, logged); otherwise
        (an experiment must not count a cut run) the interrupt is raised.

        Args:
            observations: (T, *model.observation_shape) at the prior's frame rate, NaN where missing: an
                array, or a :class:`~priortrack.observation.ticks.TickObservations` (read as the run goes).
            motion: the known motion whose first two frames start the filter.
            keep_snapshots: keep the steps' Snapshots in the Track …
            snapshot_every: … every k-th filtered frame's (1: every one).
            progress: called as progress(t, T) after each frame.
            on_step: called with each step's Snapshot (to reduce it as the run goes).
            interruptible: Ctrl-C ends the run with what it tracked (above).
            initial: further arguments of the filter's ``initialise`` (the particle filter's
                ``translation_std``, for a start that is itself an estimate).
        """
        if not isinstance(observations, TickObservations):            # else read a block at a time
            observations = np.asarray(observations, dtype=float)
        T = len(observations)
        shape = tuple(self.model.observation_shape)
        if observations.shape[1:] != shape or T < KNOWN_FRAMES + 1:
            raise PriortrackError(f"observations have shape {observations.shape}; expected (T ≥ 3, "
                                  f"{', '.join(map(str, shape))})")
        run = self.started(motion, T, keep_snapshots, progress, snapshot_every, on_step, **initial)
        try:
            for t in range(KNOWN_FRAMES, T):
                run.record(self.step(observations[t]))
        except KeyboardInterrupt:
            if not interruptible or run.done == KNOWN_FRAMES:
                raise
            log.warning("interrupted: %d of %d frames tracked; the run ends there", run.done, T)
        return run.result()

    def started(self, motion: Motion, T: int, keep_snapshots: bool = False,
                progress: Callable[[int, int], None] | None = None, snapshot_every: int = 1,
                on_step: Callable[[Snapshot], None] | None = None, **initial) -> "Run":
        """The filter initialised on ``motion``'s first two frames, and a :class:`Run` of T frames to record its
        steps in (:meth:`run`'s arguments): where something else feeds the filter frame by frame (the scene
        tracker steps every person's filter together, :meth:`advance` and ``correct`` apart)."""
        if isinstance(snapshot_every, bool) or not isinstance(snapshot_every, int) or snapshot_every < 1:
            raise PriortrackError(f"snapshot_every must be a whole number ≥ 1, got {snapshot_every!r}")
        start = time.perf_counter()
        self.initialise(motion, **initial)
        fps = self.model.prior.fps
        known = motion if motion.fps == fps else motion.resample(fps)
        return Run(joint_positions(known, "eval15")[:KNOWN_FRAMES], T, start, keep_snapshots, progress,
                   snapshot_every, on_step)


class Run:
    """A filter's run in progress over T frames: the known frames' joints, then each step's estimate, ESS,
    flags and :class:`StepRecord` as :meth:`record` is given its Snapshot; :meth:`result` the
    :class:`Track` of the frames done (:meth:`SequentialFilter.run` says what the arguments do)."""

    def __init__(self, given: np.ndarray, T: int, start: float, keep_snapshots: bool,
                 progress: Callable[[int, int], None] | None, snapshot_every: int,
                 on_step: Callable[[Snapshot], None] | None):
        self.T, self.start, self.keep_snapshots, self.progress = T, start, keep_snapshots, progress
        self.snapshot_every, self.on_step = snapshot_every, on_step
        self.estimates = np.full((T,) + given.shape[1:], np.nan)
        self.estimates[:KNOWN_FRAMES] = given
        self.ess = np.full(T, np.nan)
        self.flags: list[list[str]] = [[] for _ in range(KNOWN_FRAMES)]
        self.snapshots: list[Snapshot] = []
        self.steps: list[StepRecord] = []
        #: frames whose estimate is in
        self.done = KNOWN_FRAMES

    def record(self, snap: Snapshot) -> None:
        """Frame ``done``'s step."""
        t = self.done
        self.estimates[t], self.ess[t] = snap.estimate, snap.ess
        self.flags.append(snap.flags)
        self.steps.append(StepRecord.of(snap))
        self.done = t + 1
        if self.on_step is not None:
            self.on_step(snap)
        if self.keep_snapshots and (t - KNOWN_FRAMES) % self.snapshot_every == 0:
            self.snapshots.append(snap)
        if self.progress:
            self.progress(t, self.T)

    def result(self) -> Track:
        done = self.done
        return Track(self.estimates[:done], self.ess[:done], self.flags[:done], time.perf_counter() - self.start,
                     self.snapshots if self.keep_snapshots else None, self.steps[:done - KNOWN_FRAMES],
                     interrupted=done < self.T)
