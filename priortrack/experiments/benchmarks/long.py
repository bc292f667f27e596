"""``priortrack bench long``: a long recording tracked as ``track --detections`` tracks it, for peak
memory and for time per frame along the run, beside a run a tenth as long as the reference.

The input: CMU 49_18 (a person balancing in place, in view of all 4 of the Pose2Sim demo's cameras)
at 60 fps, played forward and back (a ping-pong loop: no jump where it turns) to the asked length,
projected through the 4 cameras with the detector errors of :mod:`priortrack.experiments.real_format`
and written as an ``.npz`` of BODY_25B keypoints (``keypoints`` (C, T, 25, 3), ``keypoint_names``,
``fps``). Each run is its own process, so that its peak resident memory is the run's own (Linux: the
process's ``VmHWM``, its memory's high-water mark; not ``ru_maxrss``, which Linux carries across the
fork and exec that start it from the parent's resident size, here the bench's, which wrote a 36,000-frame
input: every run read the parent's 586 MB): the file read, the prior fitted or loaded, the filter run (the
ticks timed by the progress callback), the result written as ``.npz``. Time per frame is the mean over the
first and over the last tenth of the ticks; their ratio says whether a step's cost grows with the run.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from priortrack.data.calibration import read_calibration
from priortrack.data.keypoints import LAYOUTS
from priortrack.errors import PriortrackError
from priortrack.experiments.benchmarks.timing import load_average
from priortrack.experiments.real_format import DEFAULT_CALIBRATION, detector_keypoints, placed_walk
from priortrack.geometry.camera import PinholeCamera

MOTION, FPS = "cmu:49_18", 60.0
#: Seconds of the motion looped (its middle, inside the clip's 9.2 s).
LOOP_SECONDS = 8.0


def ping_pong(X: np.ndarray, frames: int) -> np.ndarray:
    """``frames`` frames of the motion X (T, …) played forward and back (no jump where it turns)."""
    period = 2 * len(X) - 2
    phase = np.arange(frames) % period
    return X[np.where(phase < len(X), phase, period - phase)]


def write_long_input(frames: int, path: Path, seed: int = 0) -> Path:
    """The benchmark's input (module docstring): ``frames`` frames at 60 fps × 4 cameras, as an .npz."""
    calibration = read_calibration(DEFAULT_CALIBRATION)
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    X = ping_pong(placed_walk(MOTION, calibration.up, fps=FPS, seconds=LOOP_SECONDS), frames)
    keypoints = detector_keypoints(X, cameras, np.random.default_rng(seed)).astype(np.float32)
    with open(path, "wb") as f:
        np.savez(f, keypoints=keypoints, keypoint_names=np.array(LAYOUTS["body25b"]), fps=np.array(FPS))
    return path


def run_once(detections: str, preset: str, smooth: bool, out: str) -> dict:
    """One tracked run in this process: seconds, ticks, time per tick over the first and last tenth, and
    this process's peak resident memory (MB)."""
    from priortrack.data.detections import open_detections
    from priortrack.tracking.person import TrackConfig, track_detections

    stamps = []
    start = time.perf_counter()
    read = open_detections(detections)                # as the command opens it: read a block of frames at a time
    result = track_detections(read, read_calibration(DEFAULT_CALIBRATION), preset,
                              TrackConfig(smooth=smooth), progress=lambda t, T: stamps.append(time.perf_counter()))
    result.save(out)
    seconds = time.perf_counter() - start
    per_tick = np.diff(stamps)
    tenth = max(len(per_tick) // 10, 1)
    first, last = float(per_tick[:tenth].mean()), float(per_tick[-tenth:].mean())
    return {"preset": preset, "smooth": smooth, "frames": int(len(read.frames)),
            "ticks": len(result.joints), "seconds": seconds, "first_tenth_ms_per_tick": 1000 * first,
            "last_tenth_ms_per_tick": 1000 * last, "last_over_first": last / first,
            "peak_rss_mb": peak_rss_mb()}


def peak_rss_mb() -> float:
    """This process's peak resident memory, MB: ``VmHWM`` of /proc/self/status where there is one (Linux), else
    ``ru_maxrss`` (kB on Linux, bytes on macOS)."""
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 1024
    except (OSError, StopIteration):
        maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return maxrss / 1024 ** 2 if sys.platform == "darwin" else maxrss / 1024


def bench_long(frames: int = 36_000, presets=("ukf-real", "pf-lie"), smooth: bool = False,
               reference_frames: int | None = None, seed: int = 0) -> dict:
    """Each preset on ``frames`` and on ``reference_frames`` (default a tenth) frames, each run in a
    fresh process: peak memory, its ratio to the reference's, and time per tick along the run."""
    reference_frames = reference_frames or max(frames // 10, 300)
    if not 300 <= reference_frames <= frames:
        raise PriortrackError(f"bench long: frames must be ≥ 300 and ≥ the reference's (got {frames}, {reference_frames})")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        inputs = {n: write_long_input(n, Path(tmp) / f"long_{n}.npz", seed) for n in (reference_frames, frames)}
        for preset in presets:
            runs = {}
            for n, path in inputs.items():
                command = [sys.executable, "-m", "priortrack.experiments.benchmarks.long", str(path), preset,
                           "1" if smooth else "0", str(Path(tmp) / "out.npz")]
                done = subprocess.run(command, capture_output=True, text=True)
                if done.returncode != 0:
                    raise PriortrackError(f"bench long: the {preset} run on {n} frames failed: {done.stderr.strip()[-500:]}")
                runs[n] = json.loads(done.stdout.strip().splitlines()[-1])
            long_run, short_run = runs[frames], runs[reference_frames]
            rows.append({**long_run, "reference_frames": reference_frames,
                         "reference_peak_rss_mb": short_run["peak_rss_mb"],
                         "peak_over_reference": long_run["peak_rss_mb"] / short_run["peak_rss_mb"]})
    return {"runs": rows, "load_average": load_average()}


if __name__ == "__main__":
    print(json.dumps(run_once(sys.argv[1], sys.argv[2], sys.argv[3] == "1", sys.argv[4])))
