"""Smoothing: each frame's estimate given every frame of a finished run (or, with a lag L, the
frames up to L after it), from the filter's stored steps.

- The particle filter, by default (``method="gaussian"``): the RTS recursion with each frame's mean,
  covariance and prediction taken from its cloud (:mod:`priortrack.filters.cloud_smoother`); the estimate
  is the joints of the smoothed mean, the spread as the unscented filter's below. With ``method="backward"``:
  forward-filtering backward-simulation of M trajectories
  (:mod:`priortrack.filters.backward_simulation`) with the tracking model's transition density;
  with the translation integrated out, the pose and rotation are drawn and each trajectory's
  translation is Kalman-smoothed given them (Rao–Blackwellised:
  :func:`~priortrack.filters.marginal_translation.smooth_translation`). The estimate is the mean of
  the trajectories' joints, the spread their RMS distance from it. Backward simulation keeps a
  multimodal cloud's modes, but where the transition is narrow next to the cloud its trajectories
  follow one particle a frame (below); the Gaussian smoother averages the cloud as the filter does.
- The unscented filter: the iterated posterior-linearisation smoother
  (:mod:`priortrack.filters.posterior_linearisation`, whose first pass is the unscented RTS smoother
  of :mod:`priortrack.filters.unscented_rts`); the estimate is the joints of the smoothed mean, the
  spread the RMS of the joints over the smoothed Gaussian (its sigma points, weights Wc).
- Refused: the annealed particle filter (its tempered weights are not a posterior) and the MAP
  tracker (itself a sliding-window smoother, keeping no distribution).

**Rounding** (backward simulation). Where the filter's cloud collapses (ESS a few particles of 1000, as a learned prior in a
particle filter under several sharp cameras), the backward trajectories pass through one or two particles a
frame (the warning below): which ones follows the last bits of the weights, so the smoothed joints of the
same run differ from one processor's floating point to another's by as much as the cloud's reach (the
Pose2Sim trial's pf-gpdm run: a wrist 135 mm from the filtered estimate on an AVX2 CPU with one torch
thread, 19 mm with two, under 100 mm on the AVX-512 CPU an earlier test was tuned on; each within the cloud). Tests bound the smoother by
the cloud's reach, never by one processor's figure; the guided proposals of issue 45 are to remove the cause.

**Fixed lag L** (online use): the estimate of frame t − L is released at frame t, smoothed over the
window t − L … t (frames 0 … L − 1 of the window's end come out of the last window). L = 0 is the
filter; a lag longer than the run is the whole-run smoother. Each window is smoothed anew from the
filter's steps in it, so the cost is L + 1 times the whole-run smoother's.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from priortrack.errors import PriortrackError
from priortrack.filters.snapshot import KNOWN_FRAMES, Track

log = logging.getLogger(__name__)

#: Below this fraction of distinct particles a frame (median), the smoothed trajectories have coalesced.
COALESCED = 0.1
#: Smoothed trajectories drawn by default from a particle filter's sets.
TRAJECTORIES = 100
#: Metropolis–Hastings moves per frame of the particle smoother's backward kernel, by default.
MOVES = 10
#: A particle filter's smoothers (module docstring), the default first.
PARTICLE_SMOOTHERS = ("gaussian", "backward")


@dataclass
class Smoothed:
    """A smoothed run.

    Attributes:
        estimates: (T, J, 3) smoothed joints, metres (the known first frames as given).
        spread: (T, J) RMS distance, metres, of the smoothed distribution's joints from the
            estimate (0 on the known frames).
        lag: the fixed lag L, None for the whole run.
        seconds: the smoother's time.
        distinct: (T,) a particle smoother's distinct particles among its trajectories per frame
            (of the window that released the frame; 0 on the known frames), None for the unscented one.
    """

    estimates: np.ndarray
    spread: np.ndarray
    lag: int | None
    seconds: float
    distinct: np.ndarray | None = None


def joint_spread(joints: torch.Tensor, centre: torch.Tensor, weights: torch.Tensor) -> np.ndarray:
    """RMS distance (W, J) of joints (M, W, J, 3) from centre (W, J, 3) under weights (M,) summing to 1
    (negative ones allowed, as sigma points' Wc): √max(Σ_m w_m ‖X_m − centre‖², 0)."""
    sq = ((joints - centre) ** 2).sum(-1).to(torch.float64)
    return torch.einsum("m,mwj->wj", weights.to(sq), sq).clamp(min=0).sqrt().cpu().numpy()


def blockwise_spread(frames: int, block: int, decode) -> tuple[np.ndarray, np.ndarray]:
    """The centre (W, J, 3) and spread (W, J) of a smoothed run's points, ``block`` frames at a time (a
    long run's points decoded at once would not fit in memory): ``decode(frames)`` gives the joints of
    those frames' points (M, w, J, 3), their centre (w, J, 3) and the points' weights (M,) (:func:`joint_spread`)."""
    centres, spreads = [], []
    for start in range(0, frames, block):
        joints, centre, weights = decode(slice(start, start + block))
        centres.append(centre.detach().cpu().numpy().astype(float))
        spreads.append(joint_spread(joints, centre, weights))
    return np.concatenate(centres), np.concatenate(spreads)


def gaussian_joints(form, points, means: Sequence[np.ndarray], covariances, block: int) -> tuple[np.ndarray, np.ndarray]:
    """The joints (W, J, 3) of W smoothed Gaussians' means (A,) and their spread (W, J) over each Gaussian's
    sigma points (``points``, weights Wc; covariances (n, n) indexable by frame), decoded by the unscented form
    ``form`` ``block`` frames at a time."""
    Wc = torch.from_numpy(points.Wc)

    def decode(frames: slice):
        sigmas = torch.from_numpy(np.stack([points.sigma_points(m, P) for m, P in zip(means[frames], covariances[frames])]))
        joints = form.observe(sigmas.flatten(0, 1)).reshape(sigmas.shape[:2] + (-1, 3)).transpose(0, 1)
        return joints, form.observe(torch.from_numpy(np.stack(means[frames]))), Wc

    return blockwise_spread(len(means), block, decode)


def draws_for(filt, seed: int) -> torch.Generator:
    """The smoother's own generator, seeded, on the filter's device (a particle filter's particles may
    live on a GPU; the unscented filter's sigma points on the CPU)."""
    return torch.Generator(device=getattr(filt, "device", "cpu")).manual_seed(seed)


def _check(filt, trajectories: int, moves: int | None, lag: int | None, method: str = PARTICLE_SMOOTHERS[0]) -> None:
    """Refuse a filter without a smoother and malformed smoothing arguments, naming them."""
    if not hasattr(filt, "smooth_window"):
        raise PriortrackError(f"{type(filt).__name__} has no smoother (the particle filters and the unscented filter "
                              f"have one; the MAP tracker is itself a sliding-window smoother)")
    if isinstance(trajectories, bool) or not isinstance(trajectories, int) or trajectories < 1:
        raise PriortrackError(f"trajectories must be a positive whole number, got {trajectories!r}")
    if moves is not None and (isinstance(moves, bool) or not isinstance(moves, int) or moves < 0):
        raise PriortrackError(f"moves must be a whole number ≥ 0 or None (the exact draw), got {moves!r}")
    if lag is not None and (isinstance(lag, bool) or not isinstance(lag, int) or lag < 0):
        raise PriortrackError(f"lag must be a whole number of frames ≥ 0, got {lag!r}")
    if method not in PARTICLE_SMOOTHERS:
        raise PriortrackError(f"a particle smoother is one of {', '.join(PARTICLE_SMOOTHERS)}, got {method!r}")


class FixedLagSmoother:
    """Fixed-lag smoothing as the filter runs (module docstring), holding only the last L + 1 steps:
    :meth:`push` each step's snapshot with its observation, as the filter makes them, then
    :meth:`result`. The windows are those of a whole run smoothed afterwards with the same lag, in the
    same order from the same generator: the same numbers.

    Args:
        filt: the running filter (a ParticleFilter or UnscentedFilter).
        lag: L, in frames (≥ 0).
        trajectories, seed, moves, method: as :func:`smooth`.
    """

    def __init__(self, filt, lag: int, trajectories: int = TRAJECTORIES, seed: int = 0, moves: int | None = MOVES,
                 method: str = PARTICLE_SMOOTHERS[0]):
        _check(filt, trajectories, moves, lag, method)
        if lag is None:
            raise PriortrackError("a fixed-lag smoother needs a lag (whole frames ≥ 0)")
        self.filt, self.lag, self.trajectories, self.moves, self.method = filt, lag, trajectories, moves, method
        self.generator = draws_for(filt, seed)
        self.window: deque = deque(maxlen=lag + 1)             # (snapshot, observation) of the last L + 1 frames
        self.released: list[tuple] = []                       # per released frame: (estimate, spread, distinct)
        self.last: tuple | None = None                         # the last window smoothed
        self.seconds = 0.0

    def _smoothed(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        start = time.perf_counter()
        snapshots, data = zip(*self.window)
        part = self.filt.smooth_window(list(snapshots), np.stack(data), self.generator,
                                       trajectories=self.trajectories, moves=self.moves, method=self.method)
        self.seconds += time.perf_counter() - start
        return part

    @staticmethod
    def _row(part: tuple, i: int) -> tuple:
        """Frame i of a smoothed window (estimates, spread, distinct): (estimate, spread, distinct or None)."""
        return tuple(None if values is None else values[i] for values in part)

    def push(self, snapshot, observation) -> None:
        """Add the filter's step of frame t and its observation; frame t − L is released once L + 1 are in."""
        self.window.append((snapshot, np.asarray(observation, dtype=float)))
        if len(self.window) == self.window.maxlen:
            self.last = self._smoothed()
            self.released.append(self._row(self.last, 0))

    def result(self, known: np.ndarray) -> Smoothed:
        """The smoothed run: the frames still in the window from the last window smoothed (or, for a run
        no longer than the lag, the whole run's smoother), after the ``known`` (KNOWN_FRAMES, J, 3) frames."""
        if not self.window:
            raise PriortrackError("nothing to smooth: no step was pushed")
        last = self.last if self.last is not None else self._smoothed()
        skip = 1 if self.last is not None else 0
        rows = self.released + [self._row(last, i) for i in range(skip, len(last[0]))]
        estimates, spread = np.stack([r[0] for r in rows]), np.stack([r[1] for r in rows])
        distinct = None if rows[0][2] is None else np.array([r[2] for r in rows])
        return _assembled(known, estimates, spread, distinct, self.lag, self.seconds, self.trajectories)


def _assembled(known: np.ndarray, estimates: np.ndarray, spread: np.ndarray, distinct: np.ndarray | None,
               lag: int | None, seconds: float, trajectories: int) -> Smoothed:
    """The Smoothed run from the smoothed filtered frames, after the known ones (warning where the
    particle smoother's trajectories coalesced)."""
    if distinct is not None and len(distinct) > 1 and np.median(distinct) < COALESCED * trajectories:
        log.warning("the %d smoothed trajectories pass through a median of %d distinct particles a frame: the "
                    "transition is narrow next to the particle cloud, the smoother follows few paths and its "
                    "spread understates the uncertainty", trajectories, int(np.median(distinct)))
    return Smoothed(np.concatenate([known, estimates]), np.concatenate([np.zeros(known.shape[:2]), spread]), lag,
                    seconds, None if distinct is None else np.concatenate([np.zeros(KNOWN_FRAMES, int), distinct]))


def smooth(filt, track: Track, observations, trajectories: int = TRAJECTORIES, lag: int | None = None,
           seed: int = 0, moves: int | None = MOVES, method: str = PARTICLE_SMOOTHERS[0]) -> Smoothed:
    """The smoothed estimates of a finished run (module docstring); with a ``lag``, by
    :class:`FixedLagSmoother` over the run's steps.

    Args:
        filt: the filter that made ``track`` (a ParticleFilter or UnscentedFilter), as it was
            after the run.
        track: its run, with ``keep_snapshots=True``.
        observations: (T, *observation_shape) what the run was given.
        trajectories: M, the particle smoother's trajectories (ignored by the unscented smoother).
        lag: the fixed lag L in frames, None to smooth over the whole run.
        seed: the backward draws' seed.
        moves: the particle smoother's backward kernel: K Metropolis–Hastings moves from the
            genealogy's ancestor, (K + 1) M densities a frame; None: the exact draw, M N densities
            a frame (:mod:`priortrack.filters.backward_simulation`).
        method: a particle filter's smoother, "gaussian" or "backward" (module docstring; trajectories and
            moves are backward simulation's).
    """
    _check(filt, trajectories, moves, lag, method)
    if track.snapshots is None:
        raise PriortrackError("smoothing needs the filter's steps: run it with keep_snapshots=True")
    snapshots = track.snapshots
    observations = np.asarray(observations, dtype=float)
    if len(observations) != KNOWN_FRAMES + len(snapshots):
        raise PriortrackError(f"{len(observations)} frames of observations for a run of "
                              f"{KNOWN_FRAMES + len(snapshots)} frames")
    known = track.estimates[:KNOWN_FRAMES]
    if lag is not None:
        online = FixedLagSmoother(filt, lag, trajectories, seed, moves, method)
        for snapshot, z in zip(snapshots, observations[KNOWN_FRAMES:]):
            online.push(snapshot, z)
        return online.result(known)
    start = time.perf_counter()
    estimates, spread, distinct = filt.smooth_window(snapshots, observations[KNOWN_FRAMES:],
                                                     draws_for(filt, seed),
                                                     trajectories=trajectories, moves=moves, method=method)
    return _assembled(known, estimates, spread, distinct, None, time.perf_counter() - start, trajectories)
