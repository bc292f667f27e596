"""Held-out log-likelihood of the kinematic priors (the protocol of Simo-Serra et al. 2015, Table 2).

Every model is scored by the same quantity, the mean over frames of

    ln p(v_t | x_t),   v_t = s · log_{x_t}(x_{t+1}) ∈ T_{x_t} (S²)¹⁴,

x_t the 14 bone directions and s the velocity scale (30), in orthonormal tangent coordinates
of T_x (2 per bone, 28 in all). For the Lie prior this is :meth:`LiePrior.velocity_log_prob`.
A diffusion on the directions space models the step u = log_x(x_next) = v / s as an
isotropic Gaussian per bone, so its density of v is

    ln p(v | x) = ln p_u(v / s) − 28 ln s = Diffusion.log_prob(x_next, x) − 28 ln s.

**Calibration** of each model's step as the unscented filters run it (its mean step and ``transition_covariance``:
the Lie mixture moment-matched to one Gaussian, which at a walking pose is its one responsible component, π_k ≈ 1):
the normalised squared distance of each held-out step u_t = log_{x_t}(x_{t+1}),

    d²_t / n = (u_t − ū(x_t))ᵀ Q(x_t)⁻¹ (u_t − ū(x_t)) / n,   n = 28,

is 1 on average, and above the χ²_n 99th percentile at 1 % of the frames, for a model whose covariance is the
spread of the steps it predicts; more means an over-confident model (a filter trusting a wrong prediction).

The defensive mixture of the ``pf-lie-defensive`` preset, (1 − ε) Lie + ε local diffusion with
that preset's ε (:class:`~priortrack.priors.defensive.DefensiveMixture`), is scored the same way:
its density of the step, less 28 ln s.

Protocol: leave one subject out over the bundled CMU subjects (08 and 39, one person, leave together). Each fold trains the Lie prior,
the local and the global diffusion (all on the directions space, at 30 fps) on every other
subject's clips and scores the training frames and the left-out subject's frames. The
subject-35 walk/jog set (``walkjog:``) can be added as more subject-35 data.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence

import numpy as np
import torch
from scipy.stats import chi2

from priortrack.data.bundled import bundled_clips
from priortrack.data.load import load_motion
from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.tracking.presets import load_preset
from priortrack.priors.base import DEFAULT_FPS
from priortrack.priors.defensive import DefensiveMixture
from priortrack.priors.diffusion import Diffusion
from priortrack.priors.lie import DEFAULT_SCALE, LiePrior

logger = logging.getLogger(__name__)

MODELS = ("lie", "lie_defensive", "diffusion_local", "diffusion_global")
#: The χ²_n quantile of the calibration's share of frames beyond it (module docstring).
CALIBRATION_QUANTILE = 0.99
#: The preset whose defensive mixture is scored as ``lie_defensive``.
DEFENSIVE_PRESET = "pf-lie-defensive"


def _velocity_log_probs(models: dict, motions: Sequence[Motion], scale: float) -> dict[str, np.ndarray]:
    """Per-frame ln p(v_t | x_t) of every model over the frame pairs of ``motions``: name → (T,)."""
    lie = models["lie"]
    scores: dict[str, list[torch.Tensor]] = {name: [] for name in models}
    for m in motions:
        x = lie.encode(m)                       # every model here shares the directions space at lie.fps
        if len(x) < 2:
            continue
        scores["lie"].append(lie.velocity_log_prob(x[1:], x[:-1]))
        for name in ("lie_defensive", "diffusion_local", "diffusion_global"):
            dims = float(models[name].space.tangent_dims.sum())
            scores[name].append(models[name].log_prob(x[1:], x[:-1]) - dims * math.log(scale))
    if not scores["lie"]:
        raise PriortrackError(f"loglik: no frame pairs to score in {', '.join(m.name for m in motions)}")
    return {name: torch.cat(s).numpy() for name, s in scores.items()}


def _normalised_distances(models: dict, motions: Sequence[Motion]) -> dict[str, np.ndarray]:
    """Per-frame d²_t / n of every model's Gaussian step (module docstring, Calibration): name → (T,)."""
    lie = models["lie"]
    out: dict[str, list[torch.Tensor]] = {name: [] for name in models}
    for m in motions:
        x = lie.encode(m).to(torch.float64)
        if len(x) < 2:
            continue
        for name, model in models.items():
            space = model.space
            r = space.local(x[1:], x[:-1]) - space.local(model.mean(x[:-1]), x[:-1])
            Q = model.transition_covariance(x[:-1]).to(r)
            out[name].append((r[:, None] @ torch.linalg.solve(Q, r[..., None]))[:, 0, 0] / r.shape[1])
    return {name: torch.cat(d).numpy() for name, d in out.items()}


def _split(train: Sequence[Motion], test: Sequence[Motion], seed: int, scale: float, fps: float,
           max_components: int, subsample: int | None, epsilon: float) -> dict:
    """Fit the three models on ``train`` (and the defensive mixture of the Lie prior and local diffusion
    with fraction ``epsilon``) and score ``train`` and ``test``: one row of the table."""
    start = time.perf_counter()
    models = {
        "lie": LiePrior.fit(train, fps=fps, scale=scale, max_components=max_components, subsample=subsample,
                            seed=seed),
        "diffusion_local": Diffusion.fit(train, local=True, space="directions", fps=fps),
        "diffusion_global": Diffusion.fit(train, local=False, space="directions", fps=fps),
    }
    models["lie_defensive"] = DefensiveMixture(models["lie"], models["diffusion_local"], epsilon)
    on_train = _velocity_log_probs(models, train, scale)
    on_test = _velocity_log_probs(models, test, scale)
    distances = _normalised_distances(models, test)
    beyond = chi2.ppf(CALIBRATION_QUANTILE, 2 * models["lie"].mixture.bones) / (2 * models["lie"].mixture.bones)
    row = {name: {"train": float(on_train[name].mean()), "test": float(on_test[name].mean()),
                  "test_d2": float(distances[name].mean()), "test_beyond": float((distances[name] > beyond).mean())}
           for name in MODELS}
    row.update(clusters=models["lie"].clusters, train_frames=len(on_train["lie"]), test_frames=len(on_test["lie"]),
               fit_frames=models["lie"].train_frames, seconds=time.perf_counter() - start)
    return row


def _subjects(walkjog: bool) -> dict[str, list[str]]:
    """Bundled names per person (CMU subjects 08 and 39 are one): the ``cmu:`` trials, plus the walk/jog
    set as subject 35 if asked."""
    subjects: dict[str, list[str]] = {}
    for clip in bundled_clips():
        if clip.name.startswith("cmu:") or (walkjog and clip.name.startswith("walkjog:")):
            subjects.setdefault(clip.person, []).append(clip.name)
    return subjects


def eval_loglik(train: Sequence[str] | None = None, test: Sequence[str] | None = None, seed: int = 0,
                scale: float = DEFAULT_SCALE, fps: float = DEFAULT_FPS, max_components: int = 30,
                subsample: int | None = None, walkjog: bool = False) -> dict:
    """Mean per-frame ln p(v_t | x_t) of the Lie prior and the two diffusions on train and held-out data.

    Args:
        train, test: bundled names or motion paths (:func:`load_motion`) for one split; both
            None: leave one subject out over the bundled subjects.
        seed: seeds the Lie prior's EM start (and subsampling).
        scale: s in v = s · log_x(x_next); fps: the frame rate every model runs at.
        max_components, subsample: passed to :meth:`LiePrior.fit`.
        walkjog: add the subject-35 walk/jog set (33 trials) to subject 35 in the folds.

    Returns:
        ``{"lie": {"train", "test", "test_d2", "test_beyond"}, "lie_defensive": {…}, "diffusion_local": {…}, "diffusion_global": {…},
        "clusters", "train_frames", "test_frames", "folds": [row, …]}``; ``test_d2`` the mean d²/n of the held-out
        steps and ``test_beyond`` the share of them beyond the χ²_n 99th percentile (module docstring, Calibration). A row holds the same
        per-model numbers for one fold plus ``subject``, ``test_clips``, ``clusters``,
        ``train_frames`` and ``test_frames`` (frame pairs scored), ``fit_frames`` (samples the
        Lie prior learnt from) and ``seconds``. The top-level model numbers, ``clusters``
        and ``train_frames`` are means over folds; ``test_frames`` is the total over folds.
    """
    if (train is None) != (test is None):
        raise PriortrackError("eval_loglik: give both train and test, or neither (leave one subject out)")
    epsilon = load_preset(DEFENSIVE_PRESET).defensive
    if train is not None:
        if not train or not test:
            raise PriortrackError("eval_loglik: train and test must each name at least one motion")
        row = _split([load_motion(n) for n in train], [load_motion(n) for n in test], seed, scale, fps,
                     max_components, subsample, epsilon)
        row.update(subject=None, test_clips=list(test))
        folds = [row]
    else:
        subjects = _subjects(walkjog)
        motions = {s: [load_motion(n) for n in names] for s, names in subjects.items()}
        folds = []
        for subject, names in subjects.items():
            rest = [m for other, ms in motions.items() if other != subject for m in ms]
            row = _split(rest, motions[subject], seed, scale, fps, max_components, subsample, epsilon)
            row.update(subject=subject, test_clips=names)
            logger.info("loglik fold %s: lie %.2f / %.2f, defensive %.2f / %.2f, local %.2f / %.2f, global %.2f / %.2f "
                        "(train / test), %d clusters, %.0f s", subject, row["lie"]["train"], row["lie"]["test"],
                        row["lie_defensive"]["train"], row["lie_defensive"]["test"],
                        row["diffusion_local"]["train"], row["diffusion_local"]["test"],
                        row["diffusion_global"]["train"], row["diffusion_global"]["test"],
                        row["clusters"], row["seconds"])
            folds.append(row)
    result = {name: {part: float(np.mean([f[name][part] for f in folds]))
                     for part in ("train", "test", "test_d2", "test_beyond")} for name in MODELS}
    result.update(clusters=float(np.mean([f["clusters"] for f in folds])),
                  train_frames=float(np.mean([f["train_frames"] for f in folds])),
                  test_frames=int(sum(f["test_frames"] for f in folds)), folds=folds)
    return result
