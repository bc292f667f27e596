"""Benchmark: one step of the unscented filter with its sigma points propagated as one batch,
against the same filter running f through filterpy's own per-sigma-point loop and h one sigma
point per call (``UnscentedFilter(batched=False)``), timed in the same run.

The model is ``ukf-diffusion-local``: the local joint-angle diffusion prior fitted to the walk/jog
set's training walks (state dim 50 + 12 = 62, so 2·62 + 1 = 125 sigma points), its global motion,
and the Gaussian 2D likelihood (σ_px = 10) of clean synthetic observations of the held-out walk
35_29 through the default camera; with ``cameras`` C > 1, ``ukf-real``'s step instead: C distorted
cameras on a ring (:func:`ring_cameras`), the multi-view Gaussian likelihood (σ = 5 px) and the
validation gate, observations with 5 px noise. Both filters start on the walk's first two frames and step
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
from priortrack.geometry.camera import PinholeCamera
from priortrack.observation.likelihood import JointLikelihood
from priortrack.observation.multiview import MultiViewLikelihood
from priortrack.priors.diffusion import Diffusion
from priortrack.threads import torch_threads
from priortrack.body.fk import joint_positions

logger = logging.getLogger(__name__)


def ring_cameras(X: np.ndarray, count: int) -> list[PinholeCamera]:
    """``count`` cameras on a ring around the motion X (T, 15, 3) (Y-up): each at 1.5 m height on a
    circle about the pelvis track's centre, 1.5 m beyond the default side camera's distance in turn
    (so each sees the whole motion), looking at the centre, with the Pose2Sim demo's first camera's lens
    distortion (the distorted projection real calibrations take)."""
    from priortrack.data.calibration import read_calibration
    from priortrack.experiments.real_format import DEFAULT_CALIBRATION

    side = default_camera(X)
    centre = np.nanmean(X[:, 0], axis=0)
    eye = side.center.numpy() - centre
    eye[1] = 0.0
    radius = np.linalg.norm(eye) + 1.5
    heading = np.arctan2(eye[2], eye[0])
    dist = read_calibration(DEFAULT_CALIBRATION).cameras[0].dist
    target = np.array([centre[0], 1.0, centre[2]])
    cameras = []
    for c in range(count):
        angle = heading + 2 * np.pi * c / count
        at = PinholeCamera.look_at(target + [radius * np.cos(angle), 0.5, radius * np.sin(angle)], target)
        cameras.append(PinholeCamera(at.K, at.R, at.t, at.width, at.height, dist))
    return cameras


def ring_observations(X: np.ndarray, count: int, seed: int, sigma_px: float = 5.0) -> tuple[list[PinholeCamera], np.ndarray]:
    """The ``count`` cameras of :func:`ring_cameras` about X (T, J, 3) and their detections (T, count, J, 3):
    each joint projected, with N(0, σ_px²) noise on its pixels, at confidence 1."""
    views = ring_cameras(X, count)
    rng = np.random.default_rng(seed)
    z = np.ones((len(X), count, X.shape[1], 3))
    for c, view in enumerate(views):
        z[:, c, :, :2] = view.project(X)[0] + rng.normal(0, sigma_px, (len(X), X.shape[1], 2))
    return views, z


def bench_ukf(repeats: int = 5, seed: int = 0, threads: int = 1, cameras: int = 1) -> dict:
    """Median ms per UKF step, batched and per sigma point, on ``ukf-diffusion-local``.

    Args:
        repeats: timed steps of each filter (after one warm-up step each); at most 120.
        seed: seeds the synthetic observations.
        threads: torch threads.
        cameras: 1, the default side camera (the Gaussian 2D likelihood, σ = 10 px); more, as many
            distorted cameras on a ring (:func:`ring_cameras`) under the multi-view Gaussian likelihood
            of ``ukf-real`` (σ = 5 px), with its validation gate: the real-data step.

    Returns:
        ``{"state_dim", "tangent_dim", "sigma_points", "cameras", "batched_ms_per_step",
        "filterpy_ms_per_step", "speedup", "max_abs_mean_diff", "repeats", "threads"}``:
        speedup = filterpy_ms_per_step / batched_ms_per_step; max_abs_mean_diff the largest
        difference of the two filters' mean states after the timed steps (same frames).
    """
    walks = load_walkjog()
    motion = walks.test[1]
    if not 1 <= repeats <= len(motion) - 3 or threads < 1 or not 1 <= cameras <= 8:
        raise PriortrackError(f"bench ukf: repeats must be in [1, {len(motion) - 3}], threads positive and cameras "
                              f"in [1, 8] (got {repeats}, {threads}, {cameras})")
    with torch_threads(threads):
        train = list(walks.walks("train"))
        prior = Diffusion.fit(train, local=True)
        X = joint_positions(motion, "eval15")
        if cameras == 1:
            observations = synthesize(X, motion.fps, default_camera(X), "clean", seed=seed)
            model = TrackingModel.fitted(prior, train, JointLikelihood(observations.camera))
            z = observations.uv
        else:
            views, z = ring_observations(X, cameras, seed)
            model = TrackingModel.fitted(prior, train, MultiViewLikelihood(views, sigma_px=5.0, robust_nu=None))

        filters = {"batched": UnscentedFilter(model, batched=True), "filterpy": UnscentedFilter(model, batched=False)}
        for f in filters.values():
            f.initialise(motion)

        def stepper(f: UnscentedFilter):
            return lambda: f.step(z[f.frame + 1])

        with torch.inference_mode():
            ms = interleaved_median_ms({name: stepper(f) for name, f in filters.items()}, repeats)
    diff = float(np.abs(filters["batched"].kf.x - filters["filterpy"].kf.x).max())
    unscented = filters["batched"].unscented
    result = {
        "state_dim": unscented.dim,
        "tangent_dim": unscented.tangent_dim,
        "sigma_points": 2 * unscented.tangent_dim + 1,
        "cameras": cameras,
        "batched_ms_per_step": ms["batched"],
        "filterpy_ms_per_step": ms["filterpy"],
        "speedup": ms["filterpy"] / ms["batched"],
        "max_abs_mean_diff": diff,
        "repeats": repeats,
        "threads": threads,
    }
    logger.info("bench ukf: %s", result)
    return result
