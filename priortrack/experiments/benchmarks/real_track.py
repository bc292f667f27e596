"""``priortrack bench real-track``: what ``priortrack track --detections`` does, on real-format input
of a given size, timed, beside per-frame DLT triangulation of the same input as the reference.

The input: CMU 49_18 (a person balancing in place, so that every camera sees them throughout; played
forward and back past its 8 s, :func:`~priortrack.experiments.benchmarks.long.ping_pong`) written as
OpenPose BODY_25B JSON at ``fps`` with the detector errors of :mod:`priortrack.experiments.real_format`,
seen by the Pose2Sim demo's 4 cameras or by ``cameras`` distorted cameras on a ring
(:func:`~priortrack.experiments.benchmarks.ukf.ring_cameras`, a Y-up world). Timed in this process, as
the command runs it: reading the files, fitting or loading the prior, starting, tracking, writing an
.npz; the preset sets the particles. A particle preset that draws from the guided proposal
(:mod:`priortrack.filters.proposal`) is also timed drawing from its prior (``proposal = "prior"``), on the same
input: the guided draw's cost beside the bootstrap filter's. A Gaussian-sum preset (``ukf-sum``: ``ukf-lie``) is also
timed as the one unscented filter on the same prior (``kind = "ukf"``: the mixture moment-matched), on the same input:
the sum's cost beside it.
"""

from __future__ import annotations

import inspect
import tempfile
import time
from pathlib import Path

import numpy as np

from priortrack.data.calibration import Calibration, CameraCalibration, read_calibration
from priortrack.data.detections import read_detections
from priortrack.errors import PriortrackError
from priortrack.experiments.benchmarks.timing import load_average
from priortrack.experiments.real_format import DEFAULT_CALIBRATION, detector_keypoints, placed_walk, write_openpose
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.triangulation import triangulate

MOTION, FPS = "cmu:49_18", 30.0
#: The most frames the benchmark writes (a minute at 30 fps).
MAX_FRAMES = 1800


def _ring_calibration(X: np.ndarray, count: int) -> Calibration:
    """``count`` ring cameras around X (T, 15, 3), Y-up, as a calibration."""
    from priortrack.experiments.benchmarks.ukf import ring_cameras

    def calibrated(c: int, camera: PinholeCamera) -> CameraCalibration:
        return CameraCalibration(f"ring{c + 1}", camera.K.double().numpy(), camera.dist.double().numpy(),
                                 camera.R.double().numpy(), camera.t.double().numpy(), (camera.width, camera.height))

    return Calibration(tuple(calibrated(c, cam) for c, cam in enumerate(ring_cameras(X, count))), "y", "ring")


def bench_real_track(frames: int = 100, preset: str = "pf-lie", seed: int = 0, cameras: int = 4,
                     fps: float = FPS) -> dict:
    """Seconds of the whole command's work on ``frames`` frames × ``cameras`` cameras at ``fps``, and of
    DLT on the same input; for a guided particle preset also the command's seconds with the prior's draw
    (``prior_draw_seconds``) and ``guided_over_prior``; for a Gaussian-sum preset the command's seconds with one
    unscented filter (``single_unscented_seconds``) and ``sum_over_single``."""
    from dataclasses import replace

    from priortrack.experiments.benchmarks.long import LOOP_SECONDS, ping_pong
    from priortrack.tracking.person import TrackConfig, track_detections
    from priortrack.tracking.presets import filter_class, load_preset

    if not 3 <= frames <= MAX_FRAMES:
        raise PriortrackError(f"bench real-track: frames must be in [3, {MAX_FRAMES}], got {frames}")
    if not 2 <= cameras <= 12:
        raise PriortrackError(f"bench real-track: cameras must be in [2, 12], got {cameras}")
    if not 10 <= fps <= 120:
        raise PriortrackError(f"bench real-track: fps must be in [10, 120], got {fps}")
    if cameras == 4:
        calibration = read_calibration(DEFAULT_CALIBRATION)
        X = placed_walk(MOTION, calibration.up, fps=fps, seconds=LOOP_SECONDS)
    else:
        X = placed_walk(MOTION, "y", fps=fps, seconds=LOOP_SECONDS)
        calibration = _ring_calibration(X, cameras)
    X = ping_pong(X, frames)
    views = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    shipped = load_preset(preset)
    guided = shipped.filter_kind == "pf" and shipped.filter_options.get("proposal") == "guided"
    single = None
    if shipped.filter_kind == "ukf-sum":
        taken = inspect.signature(filter_class("ukf").__init__).parameters      # not the sum's own settings
        options = {k: v for k, v in shipped.filter_options.items() if k in taken}
        single = replace(shipped, filter_kind="ukf", filter_options=options)
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_openpose(detector_keypoints(X, views, np.random.default_rng(seed)), Path(tmp) / "pose")

        def command(chosen) -> float:
            start = time.perf_counter()
            detections = read_detections(folder, keypoints="body25b")
            result = track_detections(detections, calibration, chosen, TrackConfig(fps=fps, seed=seed))
            result.save(Path(tmp) / "out.npz")
            return time.perf_counter() - start

        seconds = command(shipped)
        start = time.perf_counter()
        uv, confidence = read_detections(folder, keypoints="body25b").eval15(0.3)
        triangulate(views, uv, confidence)
        dlt_seconds = time.perf_counter() - start
        prior_draw = (command(replace(shipped, filter_options={**shipped.filter_options, "proposal": "prior",
                                                                         "auxiliary": False}))
                      if guided else None)
        single_seconds = None if single is None else command(single)
    return {"frames": frames, "fps": fps, "cameras": len(views), "preset": preset, "command_seconds": seconds,
            "seconds_per_frame": seconds / frames, "dlt_seconds": dlt_seconds, "ratio": seconds / dlt_seconds,
            "prior_draw_seconds": prior_draw, "guided_over_prior": None if prior_draw is None else seconds / prior_draw,
            "single_unscented_seconds": single_seconds,
            "sum_over_single": None if single_seconds is None else seconds / single_seconds,
            "load_average": load_average()}
