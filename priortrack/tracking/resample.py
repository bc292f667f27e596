"""Estimates at the detections' own frames: what the filter's ticks say, carried to each frame's time.

The filter steps at its prior's rate (tick k at time k / fps_prior from the first detection frame:
:func:`~priortrack.tracking.person.schedule`), not the camera's; a biomechanics pipeline wants the
camera's frames (Pose2Sim's demo: 100 frames at 60 fps, not 50 ticks at 30). A continuous quantity
(joints, spread) at a frame's time t is the cubic spline through the ticks' values (not-a-knot ends;
straight or constant through a run of fewer than four ticks),

    x(t) = s(t),   s cubic between ticks, twice continuously differentiable, s(t_k) = x_k,

each run of consecutive finite ticks on its own (a person absent for a while is not bridged), and
taken up to half a tick beyond a run's ends (the camera's last frame lies half a 30 fps tick after the
last tick); a frame further from every run has none (NaN). A per-tick verdict (a mismatch flag, the
gate, the ESS, a log-likelihood, a reprojection error) is the nearest tick's. The spline passes
through the ticks: at 30 fps ticks and 60 fps frames, every other frame is a tick's own estimate.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import make_interp_spline

#: How far beyond a run of ticks a frame still takes the spline's value, in ticks.
REACH_TICKS = 0.5


def frame_times(frames: np.ndarray, fps: float) -> np.ndarray:
    """(F,) seconds of detection ``frames`` (F,) at ``fps`` from the first of them."""
    frames = np.asarray(frames, dtype=np.float64)
    return (frames - frames[0]) / fps


def finite_runs(finite: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in ``finite`` (T,) bool (finite values, flagged ticks)."""
    edges = np.diff(np.concatenate([[0], finite.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def interpolated(values: np.ndarray, tick_times: np.ndarray, times: np.ndarray) -> np.ndarray:
    """values (T, ...) at ``tick_times`` (T,) seconds, evenly spaced, → (F, ...) at ``times`` (F,): the cubic
    spline through each run of ticks whose values are all finite (module docstring), NaN at a time more than
    :data:`REACH_TICKS` from every run."""
    values = np.asarray(values, dtype=np.float64)
    out = np.full((len(times),) + values.shape[1:], np.nan)
    if len(tick_times) == 0:
        return out
    period = float(tick_times[1] - tick_times[0]) if len(tick_times) > 1 else np.inf
    reach = REACH_TICKS * period + 1e-9
    finite = np.isfinite(values.reshape(len(values), -1)).all(axis=1)
    for start, stop in finite_runs(finite):
        inside = (times >= tick_times[start] - reach) & (times <= tick_times[stop - 1] + reach)
        if not inside.any():
            continue
        if stop - start == 1:
            out[inside] = values[start]
            continue
        spline = make_interp_spline(tick_times[start:stop], values[start:stop], k=min(3, stop - start - 1))
        out[inside] = spline(times[inside])
    return out


def nearest_tick(tick_times: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(F,) index of the tick nearest each of ``times`` (F,); midway (to a nanosecond), the earlier."""
    after = np.clip(np.searchsorted(tick_times, times), 0, len(tick_times) - 1)
    before = np.maximum(after - 1, 0)
    return np.where(np.abs(tick_times[before] - times) <= np.abs(tick_times[after] - times) + 1e-9, before, after)
