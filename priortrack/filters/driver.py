"""What every filter shares: running over a whole sequence of observations.

A filter (particle, annealed, unscented, MAP) keeps ``model`` (its ``prior.fps`` is the frame
rate of the observations), ``initialise(motion)`` (start on the first two, known frames) and
``step(z) -> Snapshot``; :class:`SequentialFilter` turns those into ``run(observations, motion)
-> Track``, so a notebook can step frame by frame and a script can run the whole clip.
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
        if isinstance(snapshot_every, bool) or not isinstance(snapshot_every, int) or snapshot_every < 1:
            raise PriortrackError(f"snapshot_every must be a whole number ≥ 1, got {snapshot_every!r}")
        start = time.perf_counter()
        self.initialise(motion, **initial)
        fps = self.model.prior.fps
        known = motion if motion.fps == fps else motion.resample(fps)
        given = joint_positions(known, "eval15")[:KNOWN_FRAMES]
        estimates = np.full((T,) + given.shape[1:], np.nan)
        estimates[:KNOWN_FRAMES] = given
        ess = np.full(T, np.nan)
        flags: list[list[str]] = [[] for _ in range(KNOWN_FRAMES)]
        snapshots, steps = [], []
        done = KNOWN_FRAMES                                   # frames whose estimate is in
        try:
            for t in range(KNOWN_FRAMES, T):
                snap = self.step(observations[t])
                estimates[t], ess[t] = snap.estimate, snap.ess
                flags.append(snap.flags)
                steps.append(StepRecord.of(snap))
                done = t + 1
                if on_step is not None:
                    on_step(snap)
                if keep_snapshots and (t - KNOWN_FRAMES) % snapshot_every == 0:
                    snapshots.append(snap)
                if progress:
                    progress(t, T)
        except KeyboardInterrupt:
            if not interruptible or done == KNOWN_FRAMES:
                raise
            log.warning("interrupted: %d of %d frames tracked; the run ends there", done, T)
        return Track(estimates[:done], ess[:done], flags[:done], time.perf_counter() - start,
                     snapshots if keep_snapshots else None, steps[:done - KNOWN_FRAMES], interrupted=done < T)
