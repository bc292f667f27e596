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
  its ½|x|² term) + ``DYNAMICS_WEIGHT`` · (−ln p(X' | model)) (one-step GP predictions). The
  observed frames start at :meth:`~priortrack.priors.gpdm.GPDM.encode_poses`; the missing ones
  start (a) on the mean-dynamics rollout from the last observed frame before the gap and (b) on
  the straight latent line across the gap; both are optimised and the lower-energy optimum kept
  (a choice by the objective itself: (a) alone fails where the rollout drifts out of phase, (b)
  alone where the line cuts across the latent cycle), each run for at most ``MAP_MAXITER``
  L-BFGS-B iterations (the runtime budget; 50, 80, 150 gave B-GPDM 7.30, 7.35, 7.26 with an
  earlier two-thread fit). The missing poses are μ_Y(x'_t).
- ``knn15``: every 50-frame window of every training walk (stride 1; none crosses a sequence
  boundary) is compared on the observed frames (sum of squared angle differences); the missing
  frames of the 15 nearest are averaged.
- ``spline``: a cubic spline (scipy ``CubicSpline``, not-a-knot) per channel through the
  observed frames, evaluated at the missing ones.
- ``bgpdm_floor`` / ``gpdm_floor`` (a diagnostic, not a method): :func:`fill_floor`, μ_Y at each
  missing frame's eq.-18 latent inferred from its true pose, i.e. the fill-in were the gap seen.

Torch runs on one thread (``TORCH_THREADS``): the same fit on any core count (the loss differs in
its last digits between one and two threads, so the fits' L-BFGS-B paths part: two threads gave
B-GPDM 7.30), and on the 2 shared, loaded cores of the development machine one loss + gradient at
N = 431 costs 58–98 ms on one thread against 410–550 ms on two.

Wang et al. report 49.31 (B-GPDM), 73.87 (MAP, i.e. the GPDM), 55.62 (KNN-15) and 93.34 (spline)
as the average RMS per frame; their units (and data scaling) differ from ours (degrees), so only
the ordering compares.

What we measure (seed 0, 431 training frames; per walk 35_29 / 07_10 / 07_11): B-GPDM 7.36
(5.91 / 6.24 / 9.95), GPDM 10.68 (7.91 / 10.69 / 13.43), KNN-15 4.63 (4.36 / 4.03 / 5.51),
spline 17.36 (11.26 / 21.00 / 19.83); floors B-GPDM 4.85 (4.47 / 3.83 / 6.26), GPDM 5.99.
B-GPDM < GPDM < spline as in the paper, but KNN-15 beats the B-GPDM, and overall even its floor.
Checked, all on this protocol:

- the fit: both models converge by the ``FTOL`` test (1095 and 2162 iterations); μ_Y is not
  over-smoothed (training frames reconstructed to 0.85° / 0.54° per frame against a fitted noise
  std of 0.61° / 0.43° per channel, median of √(1/β3)/w_k); whitened-PCA start, ∏θ⁻¹ priors and
  closed-form W as in the paper; the training set is walks only; 07 and 35 share one channel
  layout, their clip means differ by style only (largest ≈ 50° on hand and thumb channels, no 2π).
- why: held-out poses lie 2.7 / 3.2 / 4.5° from the nearest training pose, far beyond the fitted
  noise. μ_Y's manifold passes close to them (latents fitted to each test-walk frame by unweighted
  least squares: 2.6 / 2.8 / 4.2°), but eq. 18 divides the residual by σ²(x) and so explains such
  poses by latents where σ²(x) is large (mean σ² 0.13 / 0.09 / 0.23 against 0.01 on the training
  latents), where μ_Y is poor: the floors above. Inside the gap the path drifts there too (mean
  σ² up to 1 on the worst windows).
- the objective, not the optimiser: keeping the lower-energy of the found optimum and one started
  from the all-frames-observed MAP path gives 5.0 / 5.6 / 9.6: lower energy, no better fill.
- a homoscedastic variant (σ²(x) in eq. 18 replaced by the noise 1/β3; not the model's predictive
  likelihood, so not adopted): B-GPDM 4.80 (3.53 / 4.13 / 6.74) at 200 iterations, 5.83 at 50;
  GPDM 10.39 at 50. It beats KNN-15 on 35_29 only.
- learning with the window included (the PAMI paper's missing-data learning: the window's
  observed frames join the training set, its missing frames' latents are held by the dynamics
  alone, i.e. their rows are marginalised out of the reconstruction GP; warm-started from the
  fitted model and the MAP path, 200 L-BFGS-B iterations; a scratch prototype, not kept):
  B-GPDM 5.62 / 5.77 / 8.30 with the window and the whole model (W included) refitted per window
  (07_11 8.32 with the window's latents only), against 5.98 / 6.37 / 9.40 here and KNN-15's
  4.36 / 4.03 / 5.51: mean 6.56 against 4.63. Better, but far from KNN-15.
- the dynamics noise floor (``GPDM.fit(dynamics_noise_floor=…)``, 10⁻⁴ here), raised as for the
  ``map-gpdm`` tracker: B-GPDM 7.92 at 10⁻³ (35_29 4.76, 07_11 12.12) and 8.25 at 10⁻², GPDM
  9.96 / 9.62; no help.
- dynamics: the model's are first order; a second-order GPDM (as some of the PAMI paper's
  walking models) needs another state and kernel in the model and was not tried.
- training data: with the first 3 subject-35 walks (538 frames, ~1.5× the run time) the B-GPDM
  reached 6.31 (3.40 / 4.36 / 11.16) against KNN-15's 4.70; 1 walk (329 frames) 8.17 against
  4.68. More subject-35 walks cannot help on 07_10 and 07_11, whose 15 nearest windows all come
  from subject 07's three training walks (KNN-15 there is the same with 1 to 22 subject-35 walks).
- latent start (538 frames, to tolerance): rollout alone 6.41, straight line alone 8.80, a rollout
  time-warped to end after the gap 7.58, the lower-energy of three 6.26.
- dynamics weight (annealing) on 07_11: 0.1 → 9.5–9.8, 0.5 → 10.1–10.6, 1 → 10.4–11.1,
  D/d → 10.5; over all walks D/d is worse than 1 (7.02 vs 6.41).
- latent dimension: 07_11's floor is 7.0° at d = 3, 5.6° at d = 4, 4.8° at d = 5 (538 frames);
  d = 5 fills 35_29 worse (5.84 vs 3.40) and fits 2.5× slower.
  Chosen on validation instead (trained on 35_01, 07_01, 07_02; windows of 35_02 and 07_09):
  B-GPDM 2.89 / 6.43 at d = 3 and 3.17 / 5.87 at d = 4 against KNN-15's 3.74 / 4.61 (floors
  3.04 / 6.11 and 2.63 / 4.21): neither beats KNN-15, which wins on subject 07 at either d.
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
from priortrack.threads import torch_threads

log = logging.getLogger(__name__)

WINDOW = 50
MISSING = 31
FIRST_GAP_START = 5
WINDOWS_PER_WALK = 12
K_NEAREST = 15
FPS = 30.0
TRAIN_35 = 2
TRAIN_07 = ("07_01", "07_02", "07_09")
TEST_07 = ("07_10", "07_11")
#: Weight of the dynamics term when the window's latent positions are optimised (1: the posterior).
DYNAMICS_WEIGHT = 1.0
#: Iteration cap of each window optimisation.
MAP_MAXITER = 50
#: Torch threads for the whole experiment (one: the same numbers on any core count; see the docstring).
TORCH_THREADS = 1
WANG_2008 = {"bgpdm": 49.31, "gpdm": 73.87, "knn15": 55.62, "spline": 93.34}

PROTOCOL = (f"train: first {TRAIN_35} subject-35 training walks + {', '.join(TRAIN_07)} at {FPS:g} fps; "
            f"test: 35_29, {', '.join(TEST_07)}; {WINDOWS_PER_WALK} windows of {WINDOW} frames per test walk, "
            f"window k at frame floor(k (T-{WINDOW})/{WINDOWS_PER_WALK - 1}), "
            f"frames {FIRST_GAP_START}+k..{FIRST_GAP_START}+k+{MISSING - 1} missing; error: RMS over angle channels "
            f"per missing frame (degrees), mean over frames then windows")


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


def window_energy(model: GPDM, x: torch.Tensor, y: torch.Tensor, dynamics: float = DYNAMICS_WEIGHT) -> float:
    """The objective :meth:`~priortrack.priors.gpdm.GPDM.map_latents` minimises for a window:
    Σ_t reconstruction_energy(x_t, y_t) + dynamics · (−ln p(X' | model)); x (T, d), y (T, D) with NaN rows."""
    with torch.no_grad():
        return float(model.reconstruction_energy(x, y).sum() + model.dynamics_energy(x[:, None, :], dynamics).sum())


def fill_gpdm(model: GPDM, y: np.ndarray, missing: np.ndarray, dynamics: float = DYNAMICS_WEIGHT) -> np.ndarray:
    """The window's latent positions optimised under ``model`` (module docstring) from each
    starting path, the lower-energy optimum kept; → μ_Y at the missing frames, (M, D)."""
    T = len(y)
    observed = np.setdiff1d(np.arange(T), missing)
    y_obs = torch.as_tensor(y).clone()
    y_obs[torch.as_tensor(missing)] = float("nan")
    start = torch.zeros(T, model.d, dtype=torch.float64)
    start[observed] = model.encode_poses(y_obs[observed])
    before, after = missing[0] - 1, missing[-1] + 1
    s = torch.linspace(0, 1, len(missing) + 2, dtype=torch.float64)[1:-1, None]
    starts = [start.clone(), start.clone()]
    starts[0][missing] = model.rollout(start[before:before + 1], len(missing))[1:, 0]
    starts[1][missing] = (1 - s) * start[before] + s * start[after]
    optima = [model.map_latents(y_obs, x0, dynamics=dynamics, maxiter=MAP_MAXITER) for x0 in starts]
    x = min(optima, key=lambda x: window_energy(model, x, y_obs, dynamics))
    return model.pose_mean(x[missing]).numpy()


def fill_floor(model: GPDM, truth: np.ndarray) -> np.ndarray:
    """μ_Y at each missing frame's own latent, inferred from its true pose alone (eq. 18 through
    :meth:`~priortrack.priors.gpdm.GPDM.encode_poses`, no dynamics): what the model reconstructs
    were the gap observed. truth (M, D) radians → (M, D); its error is the window's floor."""
    return model.pose_mean(model.encode_poses(torch.as_tensor(truth))).numpy()


def eval_fill_in(seed: int = 0) -> dict:
    """Run the protocol (module docstring) and return the average RMS per missing frame (degrees):
    ``{"bgpdm", "gpdm", "knn15", "spline", "bgpdm_floor", "gpdm_floor", "windows", "test_walks",
    "train_frames", "missing_frames", "protocol", "per_walk", "fit", "seconds", "wang_2008"}``
    (``*_floor``: :func:`fill_floor`'s error). Torch runs on ``TORCH_THREADS`` threads throughout."""
    with torch_threads(TORCH_THREADS):
        return _eval_fill_in(seed)


def _eval_fill_in(seed: int) -> dict:
    start = time.perf_counter()
    train = training_walks()
    models = {"bgpdm": GPDM.fit(train, balanced=True, seed=seed), "gpdm": GPDM.fit(train, balanced=False, seed=seed)}
    angles = models["bgpdm"].space.angles
    train_y = [angles.encode(m).numpy() for m in train]
    errors: dict[str, list[float]] = {name: [] for name in ("bgpdm", "gpdm", "knn15", "spline",
                                                            "bgpdm_floor", "gpdm_floor")}
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
                walk_errors[f"{name}_floor"].append(rms_degrees(fill_floor(model, truth), truth))
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
    log.info("fill-in: %s", {k: result[k] for k in errors})
    return result
