"""Smoothing: each frame's estimate given every frame of a finished run (or, with a lag L, the
frames up to L after it), from the filter's stored steps.

- The particle filter: forward-filtering backward-simulation of M trajectories
  (:mod:`priortrack.filters.backward_simulation`) with the tracking model's transition density;
  with the translation integrated out, the pose and rotation are drawn and each trajectory's
  translation is Kalman-smoothed given them (Rao–Blackwellised:
  :func:`~priortrack.filters.marginal_translation.smooth_translation`). The estimate is the mean of
  the trajectories' joints, the spread their RMS distance from it.
- The unscented filter: the iterated posterior-linearisation smoother
  (:mod:`priortrack.filters.posterior_linearisation`, whose first pass is the unscented RTS smoother
  of :mod:`priortrack.filters.unscented_rts`); the estimate is the joints of the smoothed mean, the
  spread the RMS of the joints over the smoothed Gaussian (its sigma points, weights Wc).
- Refused: the annealed particle filter (its tempered weights are not a posterior) and the MAP
  tracker (itself a sliding-window smoother, keeping no distribution).

**Fixed lag L** (online use): the estimate of frame t − L is released at frame t, smoothed over the
window t − L … t (frames 0 … L − 1 of the window's end come out of the last window). L = 0 is the
filter; a lag longer than the run is the whole-run smoother. Each window is smoothed anew from the
filter's steps in it, so the cost is L + 1 times the whole-run smoother's.
"""

from __future__ import annotations

import logging
import time
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


def smooth(filt, track: Track, observations, trajectories: int = TRAJECTORIES, lag: int | None = None,
           seed: int = 0, moves: int | None = MOVES) -> Smoothed:
    """The smoothed estimates of a finished run (module docstring).

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
    """
    if not hasattr(filt, "smooth_window"):
        raise PriortrackError(f"{type(filt).__name__} has no smoother (the particle filters and the unscented filter "
                              f"have one; the MAP tracker is itself a sliding-window smoother)")
    if track.snapshots is None:
        raise PriortrackError("smoothing needs the filter's steps: run it with keep_snapshots=True")
    if isinstance(trajectories, bool) or not isinstance(trajectories, int) or trajectories < 1:
        raise PriortrackError(f"trajectories must be a positive whole number, got {trajectories!r}")
    if moves is not None and (isinstance(moves, bool) or not isinstance(moves, int) or moves < 0):
        raise PriortrackError(f"moves must be a whole number ≥ 0 or None (the exact draw), got {moves!r}")
    if lag is not None and (isinstance(lag, bool) or not isinstance(lag, int) or lag < 0):
        raise PriortrackError(f"lag must be a whole number of frames ≥ 0, got {lag!r}")
    snapshots = track.snapshots
    observations = np.asarray(observations, dtype=float)
    if len(observations) != KNOWN_FRAMES + len(snapshots):
        raise PriortrackError(f"{len(observations)} frames of observations for a run of "
                              f"{KNOWN_FRAMES + len(snapshots)} frames")
    start = time.perf_counter()
    generator = torch.Generator().manual_seed(seed)
    data = observations[KNOWN_FRAMES:]

    def window(first: int, last: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        return filt.smooth_window(snapshots[first:last + 1], data[first:last + 1], generator,
                                  trajectories=trajectories, moves=moves)

    n = len(snapshots)
    if lag is None or lag >= n - 1:
        estimates, spread, distinct = window(0, n - 1)
    else:
        parts = [window(t - lag, t) for t in range(lag, n)]
        estimates, spread, distinct = (
            None if parts[0][k] is None else np.concatenate([p[k][:1] for p in parts] + [parts[-1][k][1:]])
            for k in range(3))
    if distinct is not None and len(distinct) > 1 and np.median(distinct) < COALESCED * trajectories:
        log.warning("the %d smoothed trajectories pass through a median of %d distinct particles a frame: the "
                    "transition is narrow next to the particle cloud, the smoother follows few paths and its "
                    "spread understates the uncertainty", trajectories, int(np.median(distinct)))
    known = track.estimates[:KNOWN_FRAMES]
    return Smoothed(np.concatenate([known, estimates]), np.concatenate([np.zeros(known.shape[:2]), spread]), lag,
                    time.perf_counter() - start,
                    None if distinct is None else np.concatenate([np.zeros(KNOWN_FRAMES, int), distinct]))
