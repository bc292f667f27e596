"""``priortrack bench real-track``: the whole ``priortrack track --detections`` command on real-format
input of a given size, timed, beside per-frame DLT triangulation of the same input as the reference.

The input: CMU 49_18 (a person balancing in place, so that all 4 of the Pose2Sim demo's cameras see
them throughout) written as OpenPose BODY_25B JSON at 30 fps with the detector errors of
:mod:`priortrack.experiments.real_format`. The command runs in this process (reading the files,
fitting or loading the prior, starting, tracking, writing an .npz); the preset sets the particles.
"""

from __future__ import annotations

import contextlib
import io
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
    """Seconds of the whole command on ``frames`` frames × 4 cameras, and of DLT on the same input."""
    from priortrack.cli.main import main

    if not 3 <= frames <= 240:
        raise PriortrackError(f"bench real-track: frames must be in [3, 240] (8 s of {MOTION}), got {frames}")
    calibration = read_calibration(DEFAULT_CALIBRATION)
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    X = placed_walk(MOTION, calibration.up, fps=FPS, seconds=frames / FPS)
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_openpose(detector_keypoints(X, cameras, np.random.default_rng(seed)), Path(tmp) / "pose")
        argv = ["track", "--detections", str(folder), "--cameras", str(DEFAULT_CALIBRATION), "--keypoints", "body25b",
                "--fps", str(FPS), "--filter", preset, "--seed", str(seed), "--out", str(Path(tmp) / "out.npz")]
        start = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):                    # its summary line; ours is the JSON
            status = main(argv)
        if status != 0:
            raise PriortrackError("bench real-track: the track command failed (its error is above)")
        seconds = time.perf_counter() - start
        start = time.perf_counter()
        uv, confidence = read_detections(folder, keypoints="body25b").eval15(0.3)
        triangulate(cameras, uv, confidence)
        dlt_seconds = time.perf_counter() - start
    return {"frames": frames, "cameras": len(cameras), "preset": preset, "command_seconds": seconds,
            "dlt_seconds": dlt_seconds, "ratio": seconds / dlt_seconds, "load_average": load_average()}
