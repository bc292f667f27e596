"""Error metrics for tracking experiments.

3D errors take positions in metres (T, 15, 3), eval15 order, and return millimetres;
2D errors take pixels.  Per-frame arrays can be reduced with :func:`summarise`.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
import torch

from priortrack.errors import PriortrackError

__all__ = ["mpjpe", "mpjpe_root_relative", "error_2d", "pcp", "summarise"]

logger = logging.getLogger(__name__)

_N_JOINTS = 15
_ROOT = 0  # pelvis in eval15


def _as_array(value: Any, name: str) -> np.ndarray:
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PriortrackError(f"{name}: expected a numeric array ({exc})") from None


def _check_3d(pred: Any, gt: Any) -> tuple[np.ndarray, np.ndarray]:
    p = _as_array(pred, "pred")
    g = _as_array(gt, "gt")
    for name, arr in (("pred", p), ("gt", g)):
        if arr.ndim != 3 or arr.shape[1:] != (_N_JOINTS, 3):
            raise PriortrackError(f"{name}: expected shape (T, 15, 3) metres in eval15 order, got {arr.shape}")
    if p.shape != g.shape:
        raise PriortrackError(f"pred, gt: shapes must match, got pred {p.shape} and gt {g.shape}")
    for name, arr in (("pred", p), ("gt", g)):
        if not np.all(np.isfinite(arr)):
            t = int(np.argwhere(~np.isfinite(arr))[0, 0])
            raise PriortrackError(
                f"{name}: 3D positions must be complete (finite), found NaN/inf at frame {t}"
            )
    return p, g


def mpjpe(pred: Any, gt: Any) -> np.ndarray:
    """Mean per-joint position error per frame, millimetres.

        e_t = 1000 / 15 * sum_j || pred[t, j] - gt[t, j] ||_2

    Args:
        pred, gt: (T, 15, 3) metres (numpy or torch), finite.

    Returns:
        (T,) float64 millimetres.

    Raises:
        PriortrackError: shapes other than (T, 15, 3), mismatched shapes, NaN/inf.
    """
    p, g = _check_3d(pred, gt)
    return 1000.0 * np.linalg.norm(p - g, axis=-1).mean(axis=-1)


def mpjpe_root_relative(pred: Any, gt: Any) -> np.ndarray:
    """MPJPE after subtracting each pose's pelvis (eval15 joint 0), millimetres.

        e_t = 1000 / 15 * sum_j || (pred[t, j] - pred[t, 0]) - (gt[t, j] - gt[t, 0]) ||_2

    Args / Returns / Raises: as :func:`mpjpe`.
    """
    p, g = _check_3d(pred, gt)
    return mpjpe(p - p[:, _ROOT : _ROOT + 1], g - g[:, _ROOT : _ROOT + 1])


def error_2d(pred_uv: Any, obs_uv: Any) -> np.ndarray:
    """Mean pixel distance to the observed 2D joints, per frame.

        e_t = (1 / |O_t|) sum_{j in O_t} || pred_uv[t, j] - obs_uv[t, j] ||_2,
        O_t = { j : obs_uv[t, j] has no NaN },  e_t = NaN if O_t is empty.

    Args:
        pred_uv: (T, J, 2) pixels (e.g. the projected estimate), finite wherever
            obs_uv is observed.
        obs_uv: (T, J, 2) pixels, NaN where missing.

    Returns:
        (T,) float64 pixels, NaN for frames with nothing observed.

    Raises:
        PriortrackError: shapes other than (T, J, 2), mismatched shapes, or a NaN/inf
            prediction at an observed entry.
    """
    p = _as_array(pred_uv, "pred_uv")
    o = _as_array(obs_uv, "obs_uv")
    for name, arr in (("pred_uv", p), ("obs_uv", o)):
        if arr.ndim != 3 or arr.shape[-1] != 2:
            raise PriortrackError(f"{name}: expected shape (T, J, 2) pixels, got {arr.shape}")
    if p.shape != o.shape:
        raise PriortrackError(f"pred_uv, obs_uv: shapes must match, got pred_uv {p.shape} and obs_uv {o.shape}")
    observed = ~np.isnan(o).any(axis=-1)  # (T, J)
    if not np.all(np.isfinite(p[observed])):
        t = int(np.argwhere(observed & ~np.isfinite(p).all(axis=-1))[0, 0])
        raise PriortrackError(f"pred_uv: must be finite where obs_uv is observed, found NaN/inf at frame {t}")
    dist = np.where(observed, np.linalg.norm(np.where(observed[..., None], p - o, 0.0), axis=-1), 0.0)
    count = observed.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, dist.sum(axis=-1) / np.maximum(count, 1), np.nan)


#: The ten parts PCP scores (as on the Shelf and Campus benchmarks), eval15 joint pairs: the head (neck–head),
#: the torso (pelvis–neck), then the eight limb parts: upper and lower arms, upper and lower legs.
PCP_LIMBS = ((1, 2), (0, 1), (3, 4), (4, 5), (6, 7), (7, 8), (9, 10), (10, 11), (12, 13), (13, 14))
#: The eight limb parts alone (what Shelf's truth and the detectors' keypoints share).
PCP_LIMB_PARTS = PCP_LIMBS[2:]


def pcp(estimate: np.ndarray, truth: np.ndarray, limbs=PCP_LIMBS) -> float:
    """Percentage of correct parts of joints (T, 15, 3) against truth (T, 15, 3), metres: a part (a, b) of
    ``limbs`` is correct at a tick when the mean of its two ends' errors is at most half its true length,
    ½ (‖X̂_a − X_a‖ + ‖X̂_b − X_b‖) ≤ ½ ‖X_a − X_b‖; over the ticks and parts whose truth is known, a part
    the estimate lacks (NaN) counting as wrong. NaN where no part's truth is known."""
    correct = []
    for a, b in limbs:
        length = np.linalg.norm(truth[:, a] - truth[:, b], axis=-1)
        error = 0.5 * (np.linalg.norm(estimate[:, a] - truth[:, a], axis=-1) +
                       np.linalg.norm(estimate[:, b] - truth[:, b], axis=-1))
        known = np.isfinite(length)
        with np.errstate(invalid="ignore"):
            correct.append(error[known] <= 0.5 * length[known])
    correct = np.concatenate(correct)
    return float(100 * correct.mean()) if len(correct) else float("nan")


def summarise(per_frame: Any) -> dict[str, float | int]:
    """Summary statistics of a per-frame error, ignoring NaN frames.

    Args:
        per_frame: (T,) errors, NaN for frames without data.

    Returns:
        dict with ``mean``, ``median``, ``max``, ``std`` (population, ddof = 0) over the
        non-NaN frames (all NaN if there are none), ``frames`` (number of non-NaN frames)
        and ``frames_without_data`` (number of NaN frames).  Python floats / ints.

    Raises:
        PriortrackError: ``per_frame`` not one-dimensional.
    """
    x = _as_array(per_frame, "per_frame")
    if x.ndim != 1:
        raise PriortrackError(f"per_frame: expected shape (T,), got {x.shape}")
    valid = x[~np.isnan(x)]
    n = int(valid.size)
    if n == 0:
        stats = dict.fromkeys(("mean", "median", "max", "std"), float("nan"))
    else:
        stats = {
            "mean": float(valid.mean()),
            "median": float(np.median(valid)),
            "max": float(valid.max()),
            "std": float(valid.std()),
        }
    return {**stats, "frames": n, "frames_without_data": int(x.size - n)}


def mean_std(values) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof = 1; 0 for one value) of the finite ``values`` over
    runs (None and NaN left out; NaN, NaN if none is left): a table cell's mean ± std."""
    kept = [float(v) for v in values if v is not None and math.isfinite(v)]
    if not kept:
        return float("nan"), float("nan")
    return float(np.mean(kept)), float(np.std(kept, ddof=1)) if len(kept) > 1 else 0.0
