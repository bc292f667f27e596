"""``priortrack bench real-track``: what ``priortrack track --detections`` does, on real-format input
of a given size, timed, beside per-frame DLT triangulation of the same input as the reference.

The input: CMU 49_18 (a person balancing in place, so that all 4 of the Pose2Sim demo's cameras see
them throughout) written as OpenPose BODY_25B JSON at 30 fps with the detector errors of
:mod:`priortrack.experiments.real_format`. Timed in this process, as the command runs it: reading the
files, fitting or loading the prior, starting, tracking, writing an .npz; the preset sets the particles.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from priortrack.data.calibration import read_calibration
from priortrack.data.detections import read_detections
from priortrack.errors import PriortrackError
from priortrack.experiments.benchmarks.timing import load_average
from priortrack.experiments.real_format import DEFAULT_CALIBRATION, detector_keypoints, placed_walk, write_openpose
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.triangulation import triangulate

MOTION, FPS = "cmu:49_18", 30.0


def bench_real_track(frames: int = 100, preset: str = "pf-lie", seed: int = 0) -> dict:
    """Seconds of the whole command's work on ``frames`` frames × 4 cameras, and of DLT on the same input."""
    from priortrack.experiments.real import track_detections

    if not 3 <= frames <= 240:
        raise PriortrackError(f"bench real-track: frames must be in [3, 240] (8 s of {MOTION}), got {frames}")
    calibration = read_calibration(DEFAULT_CALIBRATION)
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    X = placed_walk(MOTION, calibration.up, fps=FPS, seconds=frames / FPS)
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_openpose(detector_keypoints(X, cameras, np.random.default_rng(seed)), Path(tmp) / "pose")
        start = time.perf_counter()
        detections = read_detections(folder, keypoints="body25b")
        result = track_detections(detections, read_calibration(DEFAULT_CALIBRATION), preset, fps=FPS, seed=seed)
        result.save(Path(tmp) / "out.npz")
        seconds = time.perf_counter() - start
        start = time.perf_counter()
        uv, confidence = read_detections(folder, keypoints="body25b").eval15(0.3)
        triangulate(cameras, uv, confidence)
        dlt_seconds = time.perf_counter() - start
    return {"frames": frames, "cameras": len(cameras), "preset": preset, "command_seconds": seconds,
            "dlt_seconds": dlt_seconds, "ratio": seconds / dlt_seconds, "load_average": load_average()}
