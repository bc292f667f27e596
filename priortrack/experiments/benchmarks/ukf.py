"""Benchmark: one step of the unscented filter with its sigma points propagated as one batch,
against the same filter running f through filterpy's own per-sigma-point loop and h one sigma
point per call (``UnscentedFilter(batched=False)``), timed in the same run.

The model is ``ukf-diffusion-local``: the local joint-angle diffusion prior fitted to the walk/jog
set's training walks (state dim 50 + 12 = 62, so 2·62 + 1 = 125 sigma points), its global motion,
and the Gaussian 2D likelihood (σ_px = 10) of clean synthetic observations of the held-out walk
35_29 through the default camera. Both filters start on the walk's first two frames and step
through the same frames in turn; timings are medians over interleaved repeats
(:func:`priortrack.experiments.benchmarks.timing.interleaved_median_ms`), each repeat one whole ``step``.
"""

from __future__ import annotations

import logging

import numpy as np
import torch

from priortrack.data.bundled import load_walkjog
from priortrack.errors import PriortrackError
from priortrack.experiments.benchmarks.timing import interleaved_median_ms
from priortrack.models.tracking import TrackingModel
from priortrack.filters.ukf import UnscentedFilter
from priortrack.observation import default_camera, synthesize
from priortrack.observation.likelihood import JointLikelihood
from priortrack.priors.diffusion import Diffusion
from priortrack.threads import torch_threads
from priortrack.body.fk import joint_positions

logger = logging.getLogger(__name__)


def bench_ukf(repeats: int = 5, seed: int = 0, threads: int = 1) -> dict:
    """Median ms per UKF step, batched and per sigma point, on ``ukf-diffusion-local``.

    Args:
        repeats: timed steps of each filter (after one warm-up step each); at most 120.
        seed: seeds the synthetic observations.
        threads: torch threads.

    Returns:
        ``{"state_dim", "tangent_dim", "sigma_points", "batched_ms_per_step",
        "filterpy_ms_per_step", "speedup", "max_abs_mean_diff", "repeats", "threads"}``:
        speedup = filterpy_ms_per_step / batched_ms_per_step; max_abs_mean_diff the largest
        difference of the two filters' mean states after the timed steps (same frames).
    """
    walks = load_walkjog()
    motion = walks.test[1]
    if not 1 <= repeats <= len(motion) - 3 or threads < 1:
        raise PriortrackError(f"bench ukf: repeats must be in [1, {len(motion) - 3}] and threads positive "
                              f"(got {repeats}, {threads})")
    with torch_threads(threads):
        train = list(walks.walks("train"))
        prior = Diffusion.fit(train, local=True)
        X = joint_positions(motion, "eval15")
        observations = synthesize(X, motion.fps, default_camera(X), "clean", seed=seed)
        model = TrackingModel.fitted(prior, train, JointLikelihood(observations.camera))

        filters = {"batched": UnscentedFilter(model, batched=True), "filterpy": UnscentedFilter(model, batched=False)}
        for f in filters.values():
            f.initialise(motion)

        def stepper(f: UnscentedFilter):
            return lambda: f.step(observations.uv[f.frame + 1])

        with torch.inference_mode():
            ms = interleaved_median_ms({name: stepper(f) for name, f in filters.items()}, repeats)
    diff = float(np.abs(filters["batched"].kf.x - filters["filterpy"].kf.x).max())
    unscented = filters["batched"].unscented
    result = {
        "state_dim": unscented.dim,
        "tangent_dim": unscented.tangent_dim,
        "sigma_points": 2 * unscented.tangent_dim + 1,
        "batched_ms_per_step": ms["batched"],
        "filterpy_ms_per_step": ms["filterpy"],
        "speedup": ms["filterpy"] / ms["batched"],
        "max_abs_mean_diff": diff,
        "repeats": repeats,
        "threads": threads,
    }
    logger.info("bench ukf: %s", result)
    return result
