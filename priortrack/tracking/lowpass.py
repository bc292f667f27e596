"""A zero-lag Butterworth low-pass of tracked joints: the filter biomechanics applies to marker trajectories.

Pose2Sim filters its triangulated markers so (its default: order 4, 6 Hz; Winter, *Biomechanics and
Motor Control of Human Movement*, 4th ed., §3.4), and a user comparing priortrack's output with its
output, or feeding OpenSim, expects it. The filter is a 2nd-order Butterworth low-pass run forward and
backward (``scipy.signal.filtfilt``): a 4th-order response with no phase lag,

    |H(f)|² = 1 / (1 + (f / f_c)^4)²,

applied to each coordinate of each joint over each run of consecutive frames where the joint is
present (an absence is not bridged), with ``filtfilt``'s odd extension of ``PADLEN`` frames at each
end; a run too short to pad is left as it is (logged). It acts on a result's estimate, after the
Bayesian filter or smoother; it knows no body, so bone lengths are kept only as well as the estimate
kept them (a 6 Hz cut-off removes little of a walk's motion, which lies mostly below it).
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.signal import butter, filtfilt

from priortrack.errors import PriortrackError
from priortrack.tracking.resample import finite_runs

log = logging.getLogger(__name__)

#: The Butterworth prototype's order; run twice (forward and backward), the response is of twice this order.
HALF_ORDER = 2
#: Frames of odd extension at each end of a run (Pose2Sim's and ``filtfilt``'s 3 × the coefficients' length).
PADLEN = 3 * (HALF_ORDER + 1)


def check_cutoff(cutoff_hz: float, fps: float) -> None:
    """Refuse a cut-off that is not a frequency below the Nyquist frequency of ``fps`` (a PriortrackError)."""
    if not np.isfinite(cutoff_hz) or not 0 < cutoff_hz < fps / 2:
        raise PriortrackError(f"--lowpass {cutoff_hz:g} Hz: the cut-off must lie between 0 and half the output's "
                              f"{fps:g} fps ({fps / 2:g} Hz)")


def lowpassed(values: np.ndarray, fps: float, cutoff_hz: float) -> np.ndarray:
    """values (F, ..., 3) sampled at ``fps``, each trailing point (..., 3) low-passed over time at ``cutoff_hz``
    (module docstring) where it is finite, NaN kept where it is not."""
    check_cutoff(cutoff_hz, fps)
    values = np.asarray(values, dtype=np.float64)
    b, a = butter(HALF_ORDER, cutoff_hz / (fps / 2), btype="low")
    points = values.reshape(len(values), -1, values.shape[-1])                       # (F, N, 3)
    out = points.copy()
    short = 0
    for n in range(points.shape[1]):
        for start, stop in finite_runs(np.isfinite(points[:, n]).all(axis=-1)):
            if stop - start <= PADLEN:
                short += 1
                continue
            out[start:stop, n] = filtfilt(b, a, points[start:stop, n], axis=0, padlen=PADLEN)
    if short:
        log.info("low-pass: %d runs of %d frames or fewer left as they are (too short to filter)", short, PADLEN)
    return out.reshape(values.shape)
