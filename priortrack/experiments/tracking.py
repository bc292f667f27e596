"""Tracking a motion with a filter preset, and the accuracy table over presets × scenarios × seeds.

One run (:func:`track`): the motion is resampled to the prior's rate; synthetic 2D observations of
its eval15 joints are drawn for the scenario (``synthesize`` with the default side camera and the
paper's observed joints); the filter starts from the first two ground-truth frames (pose and
placement, as in the papers' experiments) and filters the rest. Errors are over the filtered frames
(frame 2 on): MPJPE in world coordinates, root-relative MPJPE, and the 2D error of the estimate's
projection against the clean projection of the truth, all joints. With ``smooth`` the run is also
smoothed (:mod:`priortrack.filters.smoothing`): the errors are the smoothed estimate's, and the
filter's own are given beside them as ``filtered_…``, from the same run.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import multiprocessing
import os
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

import numpy as np
import torch

from priortrack.data.load import load_motion
from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.experiments.metrics import error_2d, mean_std, mpjpe, mpjpe_root_relative
from priortrack.tracking.presets import Preset, load_preset
from priortrack.filters.smoothing import PARTICLE_SMOOTHERS, TRAJECTORIES, Smoothed, smooth as smooth_run
from priortrack.filters.snapshot import KNOWN_FRAMES, Track
from priortrack.observation.synthetic import Observations, default_camera, parse_scenario, synthesize
from priortrack.body.fk import joint_positions

log = logging.getLogger(__name__)

#: The accuracy table's protocol: held-out walks, 5 px noise on the paper's observed joints.
TABLE_MOTIONS = ("walkjog:35_29", "cmu:07_10", "cmu:07_11")
TABLE_SCENARIOS = ("clean:sigma_px=5", "occlusion:sigma_px=5", "blackout:sigma_px=5")
TABLE_PRESETS = ("pf-diffusion-global", "pf-diffusion-local", "pf-gpdm", "pf-lie", "apf-diffusion-local",
                 "ukf-diffusion-local", "ukf-gpdm", "map-gpdm", "map-gpdm-validated")
TABLE_SEEDS = 5
#: The preset every other is compared with.
BASELINE = "pf-diffusion-local"
#: Thread-count variables of the runtimes torch, numpy and numba start with (set for ``jobs`` workers).
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")


def _mean_std(rows: list[dict], key: str) -> dict[str, float]:
    mean, std = mean_std([r[key] for r in rows])
    return {key: mean, f"{key}_std": std}


@dataclass
class TrackingRun:
    """One tracked motion: the result row, and what a recording or notebook needs."""

    result: dict
    motion: Motion
    observations: Observations
    track: Track
    smoothed: Smoothed | None = None


def _errors(estimates: np.ndarray, truth: np.ndarray, camera) -> dict[str, float]:
    """MPJPE, root-relative MPJPE (mm) and the 2D error (px, against the clean projection) of estimates (T, 15, 3).
    A joint the estimate puts behind the camera has no pixel: it is left out of the 2D error (logged; the 3D
    errors count it), as a filter lost at an extreme noise setting can do (σ = 0.01 px, tests/test_hardening.py)."""
    uv_est, in_front = camera.project(torch.as_tensor(estimates))
    uv_true, _ = camera.project(torch.as_tensor(truth))
    uv_true = uv_true.numpy()
    behind = ~in_front.numpy() & np.isfinite(uv_true).all(axis=-1)
    if behind.any():
        log.warning("%d joint-frames of the estimate lie behind the camera: left out of the 2D error", int(behind.sum()))
        uv_true[behind] = np.nan
    return {"mpjpe_mm": float(mpjpe(estimates, truth).mean()),
            "mpjpe_root_rel_mm": float(mpjpe_root_relative(estimates, truth).mean()),
            "err2d_px": float(np.nanmean(error_2d(uv_est.numpy(), uv_true)))}


def track(motion: Motion | str, preset: Preset | str, scenario: str = "clean", seed: int = 0,
          keep_snapshots: bool = False, progress: Callable[[int, int], None] | None = None,
          cache=None, frames: int | None = None, smooth: bool = False, lag: int | None = None,
          trajectories: int = TRAJECTORIES, device: str = "cpu", particle_smoother: str = PARTICLE_SMOOTHERS[0]
          ) -> TrackingRun:
    """Track ``motion`` with ``preset`` under ``scenario`` ("NAME" or "NAME:key=value,...").

    ``frames`` keeps only the first frames (at the prior's rate) of the motion. ``smooth`` also
    smooths the run (with a fixed ``lag`` in frames, or over the whole run; a particle filter's by
    ``particle_smoother``, "gaussian" or "backward", the latter drawing ``trajectories``). ``device``: where a
    particle filter's particles live ("cpu", "cuda"; :meth:`Preset.filter_for`).

    Returns the result {"filter", "motion", "scenario", "frames", "mpjpe_mm", "mpjpe_root_rel_mm",
    "err2d_px", "seconds_per_frame", "mean_ess"} with the run behind it; smoothed, the errors are
    the smoothed estimate's, with "filtered_mpjpe_mm", "filtered_mpjpe_root_rel_mm",
    "filtered_err2d_px", "lag" and "smoothing_seconds" added. The seed drives both the observation
    noise and the filter.
    """
    preset = load_preset(preset) if not isinstance(preset, Preset) else preset
    motion = load_motion(motion) if isinstance(motion, str) else motion
    motion = motion if motion.fps == preset.fps else motion.resample(preset.fps)
    if frames is not None:
        if frames < 3:
            raise PriortrackError(f"frames must be at least 3 (two known, one tracked), got {frames}")
        motion = motion[:frames]
    name, params = parse_scenario(scenario)
    X = joint_positions(motion, "eval15")
    camera = default_camera(X)
    observations = synthesize(X, motion.fps, camera, name, seed=seed, **params)
    torch.manual_seed(seed)
    filt = preset.build(camera, seed=seed, cache=cache, device=device)
    result_track = filt.run(observations.uv, motion, keep_snapshots=keep_snapshots or smooth, progress=progress)
    smoothed = smooth_run(filt, result_track, observations.uv, trajectories, lag, seed,
                          method=particle_smoother) if smooth else None
    truth = X[KNOWN_FRAMES:]
    filtered = _errors(result_track.estimates[KNOWN_FRAMES:], truth, camera)
    result = {
        "filter": preset.name, "motion": motion.name, "scenario": scenario, "seed": seed,
        "frames": len(motion),
        **(filtered if smoothed is None else _errors(smoothed.estimates[KNOWN_FRAMES:], truth, camera)),
        "seconds_per_frame": result_track.seconds_per_frame,
        # The MAP tracker keeps no weighted set: no ESS (null in JSON).
        "mean_ess": float(np.nanmean(result_track.ess)) if np.isfinite(result_track.ess).any() else None,
    }
    if smoothed is not None:
        result.update({f"filtered_{key}": value for key, value in filtered.items()})
        result.update(lag=lag, smoothing_seconds=smoothed.seconds)
    return TrackingRun(result, motion, observations, result_track, smoothed)


def _table_run(preset: str, motion: str, scenario: str, seed: int, cache, threads: int) -> dict:
    """One run of :func:`eval_tracking`'s table on ``threads`` torch threads, its result row.
    Motions and presets are loaded once per process (:func:`_table_motion`, :func:`_table_preset`)."""
    torch.set_num_threads(threads)
    return track(_table_motion(motion), _table_preset(preset), scenario, seed, cache=cache).result


@functools.cache
def _table_motion(name: str) -> Motion:
    return load_motion(name)


@functools.cache
def _table_preset(name: str) -> Preset:
    return load_preset(name)


def _table_runs(presets, scenarios, motions, seeds, cache, progress, jobs) -> dict[tuple, dict]:
    """Every run of the table: (preset, motion, scenario, seed) → result row (:func:`eval_tracking`)."""
    for name in motions:
        _table_motion(name)                                   # a missing motion fails before any run
    for name in presets:
        _table_preset(name).prior(cache)                      # fit (or load) once, before timing runs
    runs = [(name, motion, scenario, seed) for name in presets for scenario in scenarios
            for motion in motions for seed in range(seeds)]
    results: dict[tuple, dict] = {}

    def done(key: tuple, row: dict) -> None:
        results[key] = row
        if progress:
            progress(row)

    if jobs == 1:
        for key in runs:
            done(key, _table_run(*key, cache, torch.get_num_threads()))
        return results
    # Each worker gets its share of this process's threads, in torch and in the BLAS and OpenMP
    # runtimes it starts with: oversubscribed, their spinning threads slowed a UKF run 4×.
    threads = max(1, torch.get_num_threads() // jobs)
    context = multiprocessing.get_context("spawn")            # a forked child can hang in the parent's OpenMP pool
    with environment({name: str(threads) for name in THREAD_VARIABLES}), \
            ProcessPoolExecutor(jobs, mp_context=context) as pool:
        futures = {pool.submit(_table_run, *key, cache, threads): key for key in runs}
        for future in as_completed(futures):
            done(futures[future], future.result())
    return results


@contextlib.contextmanager
def environment(values: dict[str, str]) -> Iterator[None]:
    """Set environment variables inside the block (for the processes started there), restoring them after."""
    previous = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, value in previous.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def eval_tracking(presets: Sequence[str] = TABLE_PRESETS, scenarios: Sequence[str] = TABLE_SCENARIOS,
                  motions: Sequence[str] = TABLE_MOTIONS, seeds: int = TABLE_SEEDS, cache=None,
                  progress: Callable[[dict], None] | None = None, jobs: int = 1) -> dict:
    """The accuracy table: every preset × scenario, MPJPE mean ± std over motions × seeds.

    ``jobs`` > 1 runs the table's runs in that many worker processes (spawned), each with its share
    of this process's threads. The table is the same: at the presets' particle counts a run gives
    the same numbers on one thread as on two (checked for pf-diffusion-local, pf-lie, pf-gpdm,
    apf-diffusion-local, ukf-diffusion-local, ukf-gpdm and map-gpdm; tests compare tables). The MAP tracker and the
    unscented filter run on one thread anyway, so on two cores two jobs about halve their rows' time.

    Returns {"table": {preset: {scenario: {"mpjpe_mm", "mpjpe_mm_std", "mpjpe_root_rel_mm",
    "mpjpe_root_rel_mm_std", "runs", "seconds_per_frame"}}}, "ratios": {"mpjpe_mm" or
    "mpjpe_root_rel_mm": {preset: {scenario: its mean / pf-diffusion-local's}}}, "motions", "seeds",
    "seconds"}. ``progress`` sees every run's result row as it finishes.
    """
    if seeds < 1:
        raise PriortrackError(f"seeds must be at least 1, got {seeds}")
    if not isinstance(jobs, int) or jobs < 1:
        raise PriortrackError(f"jobs must be a positive integer, got {jobs!r}")
    start = time.perf_counter()
    try:
        results = _table_runs(presets, scenarios, motions, seeds, cache, progress, jobs)
    finally:                                                  # a later call re-reads edited presets
        _table_motion.cache_clear()
        _table_preset.cache_clear()
    table: dict[str, dict[str, dict]] = {}
    for name in presets:
        table[name] = {}
        for scenario in scenarios:
            rows = [results[name, motion, scenario, seed] for motion in motions for seed in range(seeds)]
            table[name][scenario] = {
                **_mean_std(rows, "mpjpe_mm"), **_mean_std(rows, "mpjpe_root_rel_mm"),
                "seconds_per_frame": float(np.mean([r["seconds_per_frame"] for r in rows])),
                "runs": len(rows),
            }
    ratios = {}
    if BASELINE in table:
        base = table[BASELINE]
        ratios = {key: {name: {s: row[s][key] / base[s][key] for s in row if s in base} for name, row in table.items()}
                  for key in ("mpjpe_mm", "mpjpe_root_rel_mm")}
    return {"table": table, "ratios": ratios, "motions": list(motions), "seeds": seeds,
            "seconds": time.perf_counter() - start}
