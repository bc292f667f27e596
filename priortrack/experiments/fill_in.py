"""Missing-frame fill-in (Wang, Fleet, Hertzmann, PAMI 2008, Table 2), on the bundled walks.

Protocol (``PROTOCOL`` below says it in one line, and :func:`eval_fill_in` returns it):

- training: walks at 30 fps of subject 35 (the first ``TRAIN_35`` training walks of the walk/jog
  set) and subject 07 (07_01, 07_02, 07_09, 120 → 30 fps), each its own sequence; one model per
  method, learned on all of them (both subjects share the CMU channel layout);
- test walks, never trained on: 35_29 (walk/jog test split), 07_10, 07_11 (120 → 30 fps);
- windows: 12 per test walk of T frames; window k = 0..11 is the 50-frame slice starting at
  frame a_k = ⌊k (T − 50) / 11⌋ of the walk, and within it frames 5 + k … 35 + k (31 frames) are
  removed, so that at least 5 frames are observed before the gap and 3 after it;
- error: per missing frame, the RMS over the D angle channels of (filled − true), in degrees;
  averaged over the 31 missing frames of a window, then over all windows of all walks.

Methods:

- ``bgpdm`` / ``gpdm``: a B-GPDM / GPDM (d = 3) fitted to the training walks. The window's
  latent positions X' (50, d) minimise Σ_t −ln p(y_t | x'_t) (eq. 18; a missing frame keeps only
  its ½|x|² term) + ``DYNAMICS_WEIGHT`` · (−ln p(X' | model)) (one-step GP predictions), from:
  observed frames at :meth:`~priortrack.priors.gpdm.GPDM.encode_poses`, missing frames on the
  mean-dynamics rollout from the last observed frame before the gap.
  The missing poses are μ_Y(x'_t).
- ``knn15``: every 50-frame window of every training walk (stride 1) is compared on the
  observed frames (sum of squared angle differences); the missing frames of the 15 nearest are
  averaged.
- ``spline``: a cubic spline (scipy ``CubicSpline``, not-a-knot) per channel through the
  observed frames, evaluated at the missing ones.

Wang et al. report 49.31 (B-GPDM), 73.87 (MAP, i.e. the GPDM), 55.62 (KNN-15) and 93.34 (spline)
as the average RMS per frame; their units (and data scaling) differ from ours (degrees), so only
the ordering compares.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch
from scipy.interpolate import CubicSpline

from priortrack.data.bundled import load_bundled, load_walkjog
from priortrack.data.motion import Motion
from priortrack.priors.gpdm import GPDM

log = logging.getLogger(__name__)

WINDOW = 50
MISSING = 31
FIRST_GAP_START = 5
WINDOWS_PER_WALK = 12
K_NEAREST = 15
FPS = 30.0
TRAIN_35 = 3
TRAIN_07 = ("07_01", "07_02", "07_09")
TEST_07 = ("07_10", "07_11")
#: Weight of the dynamics term when the window's latent positions are optimised (1: the posterior).
DYNAMICS_WEIGHT = 1.0
WANG_2008 = {"bgpdm": 49.31, "gpdm": 73.87, "knn15": 55.62, "spline": 93.34}

PROTOCOL = (f"train: first {TRAIN_35} subject-35 training walks + {', '.join(TRAIN_07)} at {FPS:g} fps; "
            f"test: 35_29, {', '.join(TEST_07)}; {WINDOWS_PER_WALK} windows of {WINDOW} frames per test walk, "
            f"window k at frame floor(k (T-{WINDOW})/{WINDOWS_PER_WALK - 1}), frames {FIRST_GAP_START}+k..{FIRST_GAP_START}"
            f"+k+{MISSING - 1} missing; error: RMS over angle channels per missing frame (degrees), mean over "
            f"frames then windows")


def training_walks() -> list[Motion]:
    """The training walks (30 fps): subject 35's first ``TRAIN_35`` training walks, then 07's."""
    walks = list(load_walkjog().walks("train")[:TRAIN_35])
    return walks + [load_bundled(f"cmu:{name}").resample(FPS) for name in TRAIN_07]


def test_walks() -> list[Motion]:
    """The test walks (30 fps): 35_29, 07_10, 07_11."""
    walk_35 = next(m for m in load_walkjog().test if m.name == "35_29")
    return [walk_35] + [load_bundled(f"cmu:{name}").resample(FPS) for name in TEST_07]


def windows(T: int) -> list[tuple[int, np.ndarray]]:
    """The protocol's windows of a T-frame walk: (first frame a_k, missing frames within the
    window (31,)) for k = 0..11."""
    out = []
    for k in range(WINDOWS_PER_WALK):
        start = (k * (T - WINDOW)) // (WINDOWS_PER_WALK - 1)
        out.append((start, np.arange(FIRST_GAP_START + k, FIRST_GAP_START + k + MISSING)))
    return out


def rms_degrees(filled: np.ndarray, truth: np.ndarray) -> float:
    """Mean over frames of the RMS over channels of (filled − truth), (M, D) radians → degrees."""
    return float(np.degrees(np.sqrt(((filled - truth) ** 2).mean(axis=1))).mean())


def fill_spline(y: np.ndarray, missing: np.ndarray) -> np.ndarray:
    """Cubic spline per channel through the observed frames of y (T, D), at ``missing`` → (M, D)."""
    observed = np.setdiff1d(np.arange(len(y)), missing)
    return CubicSpline(observed, y[observed], axis=0)(missing)


def fill_knn(y: np.ndarray, missing: np.ndarray, train: list[np.ndarray], k: int = K_NEAREST) -> np.ndarray:
    """Average of the missing parts of the k training windows nearest on the observed frames.

    y: (T, D) window; train: training sequences (T_i, D), every T-frame window of each a candidate."""
    T = len(y)
    observed = np.setdiff1d(np.arange(T), missing)
    candidates = np.concatenate([np.lib.stride_tricks.sliding_window_view(s, T, axis=0).transpose(0, 2, 1)
                                 for s in train if len(s) >= T])              # (C, T, D)
    distance = ((candidates[:, observed] - y[observed]) ** 2).sum(axis=(1, 2))
    nearest = np.argsort(distance, kind="stable")[:k]
    return candidates[nearest][:, missing].mean(axis=0)


def fill_gpdm(model: GPDM, y: np.ndarray, missing: np.ndarray, dynamics: float = DYNAMICS_WEIGHT) -> np.ndarray:
    """The window's latent positions optimised under ``model`` (module docstring); → μ_Y at the
    missing frames, (M, D)."""
    T = len(y)
    observed = np.setdiff1d(np.arange(T), missing)
    y_obs = torch.as_tensor(y).clone()
    y_obs[torch.as_tensor(missing)] = float("nan")
    x0 = torch.zeros(T, model.d, dtype=torch.float64)
    x0[observed] = model.encode_poses(y_obs[observed])
    x0[missing] = model.rollout(x0[missing[0] - 1:missing[0]], len(missing))[1:, 0]
    x = model.map_latents(y_obs, x0, dynamics=dynamics)
    return model.reconstruct(x[missing])[0].numpy()


def eval_fill_in(seed: int = 0) -> dict:
    """Run the protocol (module docstring) and return the average RMS per missing frame (degrees):
    ``{"bgpdm", "gpdm", "knn15", "spline", "windows", "test_walks", "train_frames", "missing_frames",
    "protocol", "per_walk", "fit", "seconds", "wang_2008"}``."""
    start = time.perf_counter()
    train = training_walks()
    models = {"bgpdm": GPDM.fit(train, balanced=True, seed=seed), "gpdm": GPDM.fit(train, balanced=False, seed=seed)}
    angles = models["bgpdm"].space.angles
    train_y = [angles.encode(m).numpy() for m in train]
    errors: dict[str, list[float]] = {name: [] for name in ("bgpdm", "gpdm", "knn15", "spline")}
    per_walk = {}
    tests = test_walks()
    for motion in tests:
        y_walk = angles.encode(motion).numpy()
        walk_errors: dict[str, list[float]] = {name: [] for name in errors}
        for a, missing in windows(len(y_walk)):
            y = y_walk[a:a + WINDOW]
            truth = y[missing]
            walk_errors["spline"].append(rms_degrees(fill_spline(y, missing), truth))
            walk_errors["knn15"].append(rms_degrees(fill_knn(y, missing, train_y), truth))
            for name, model in models.items():
                walk_errors[name].append(rms_degrees(fill_gpdm(model, y, missing), truth))
        per_walk[motion.name] = {name: float(np.mean(e)) for name, e in walk_errors.items()}
        for name, e in walk_errors.items():
            errors[name].extend(e)
    result = {name: float(np.mean(e)) for name, e in errors.items()}
    result.update({
        "windows": len(errors["spline"]), "test_walks": [m.name for m in tests],
        "train_frames": sum(len(t) for t in train_y), "missing_frames": MISSING, "protocol": PROTOCOL,
        "per_walk": per_walk, "fit": {name: m.fit_summary for name, m in models.items()},
        "seconds": time.perf_counter() - start, "wang_2008": dict(WANG_2008),
    })
    log.info("fill-in: %s", {k: result[k] for k in ("bgpdm", "gpdm", "knn15", "spline")})
    return result
