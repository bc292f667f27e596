"""The lab bench for real data: mocap written as a detector would, tracked, compared with the mocap.

A held-out walk is placed in a calibration's world (the Pose2Sim demo's 4 cameras by default: Z-up,
the walk's middle ``SECONDS`` seconds centred on the origin, where the cameras look), projected
through each camera (distortion included) at ``DATA_FPS``, and given a detector's errors:

- pixel noise N(0, ``NOISE_PX``²) per coordinate, confidences U(0.6, 1);
- each keypoint dropped (confidence 0) with probability ``DROP``, and every keypoint outside the image;
- in a fraction ``SWAP`` of a camera's frames, left and right swapped (every pair);
- a fraction ``OUTLIERS`` of keypoints thrown 50–150 px away, with confidences U(0.3, 0.6).

The keypoints are written as OpenPose BODY_25B JSON files (one folder per camera; the keypoints a
mocap body does not give, nose, eyes, ears, upper neck and feet, as OpenPose's (0, 0, 0)), read back
by :func:`~priortrack.data.detections.read_detections` and tracked by
:func:`~priortrack.tracking.person.track_detections`, without the truth. The error is the world
MPJPE over the 12 joints from shoulders to ankles, at the ticks the tracker consumed, against the
mocap's joints (and the same relative to the mid-hips: ``relative_mm``); beside it, per-frame DLT
triangulation of the same detections, over the same joints where it has them (none from one camera).
With ``smooth`` the run is smoothed too: the error is the smoothed joints', the filter's own beside it
(``filtered_mm``), and the jitter of each (the mean joint acceleration ‖X_{t+1} − 2 X_t + X_{t−1}‖ over
the same joints and consecutive ticks, mm per tick²) beside the mocap truth's.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from priortrack.body.fk import joint_positions
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.calibration import Calibration, read_calibration
from priortrack.data.detections import read_detections
from priortrack.data.keypoints import LAYOUTS
from priortrack.data.load import load_motion
from priortrack.errors import PriortrackError
from priortrack.tracking.presets import Preset
from priortrack.tracking.person import TrackConfig, track_detections
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.frames import to_y_up
from priortrack.geometry.triangulation import triangulate

DATA_FPS = 60.0
SECONDS = 1.5
NOISE_PX, DROP, SWAP, OUTLIERS = 3.0, 0.05, 0.02, 0.01
#: eval15 joints from shoulders to ankles (the error's joints), and the BODY_25B keypoint of each
#: eval15 joint that a mocap body gives (the head is the head top).
SHOULDERS_TO_ANKLES = list(range(3, 15))
BODY25B_OF = {2: "head_top", 3: "left_shoulder", 4: "left_elbow", 5: "left_wrist", 6: "right_shoulder",
               7: "right_elbow", 8: "right_wrist", 9: "left_hip", 10: "left_knee", 11: "left_ankle",
               12: "right_hip", 13: "right_knee", 14: "right_ankle"}
DEFAULT_CALIBRATION = POSE2SIM_DIR / "Calib.toml"


def placed_walk(motion: str, up: str = "z", fps: float = DATA_FPS, seconds: float = SECONDS) -> np.ndarray:
    """(T, 15, 3) eval15 joints of the motion's middle ``seconds`` at ``fps``, in a world whose up axis
    is ``up``, its ground track centred on the origin."""
    walk = load_motion(motion).resample(fps)
    T = int(round(seconds * fps))
    if len(walk) < T:
        raise PriortrackError(f"{motion} is shorter than {seconds} s")
    first = (len(walk) - T) // 2
    X = joint_positions(walk[first:first + T]) @ to_y_up(up)                 # world rows = Y-up rows @ A
    up_index = {"x": 0, "y": 1, "z": 2}[up.lstrip("-")]
    ground = [k for k in range(3) if k != up_index]
    X[..., ground] -= X[:, 0, ground].mean(axis=0)
    return X


def detector_keypoints(X: np.ndarray, cameras: list[PinholeCamera], rng: np.random.Generator) -> np.ndarray:
    """(C, T, 25, 3) BODY_25B keypoints of the joints X (T, 15, 3) through each camera, with the
    detector's errors of the module docstring."""
    names = LAYOUTS["body25b"]
    C, T = len(cameras), len(X)
    out = np.zeros((C, T, len(names), 3))
    left = [names.index(n) for n in names if n.startswith("left_")]
    right = [names.index("right_" + names[k][5:]) for k in left]
    for c, camera in enumerate(cameras):
        uv, in_front = camera.project(X)
        inside = in_front & (uv[..., 0] >= 0) & (uv[..., 0] < camera.width) & (uv[..., 1] >= 0) & \
            (uv[..., 1] < camera.height)
        for j, name in BODY25B_OF.items():
            k = names.index(name)
            noisy = uv[:, j] + rng.normal(0, NOISE_PX, size=(T, 2))
            confidence = rng.uniform(0.6, 1.0, size=T)
            thrown = rng.random(T) < OUTLIERS
            angle = rng.uniform(0, 2 * np.pi, size=T)
            noisy[thrown] += rng.uniform(50, 150, size=(thrown.sum(), 1)) * np.stack(
                [np.cos(angle[thrown]), np.sin(angle[thrown])], axis=1)
            confidence[thrown] = rng.uniform(0.3, 0.6, size=thrown.sum())
            kept = inside[:, j] & (rng.random(T) >= DROP)
            out[c, kept, k, :2] = noisy[kept]
            out[c, kept, k, 2] = confidence[kept]
        for t in np.flatnonzero(rng.random(T) < SWAP):
            out[c, t, left + right] = out[c, t, right + left]
    return out


def write_openpose(keypoints: np.ndarray, folder: Path, stem: str = "walk") -> Path:
    """Write (C, T, K, 3) keypoints as OpenPose JSON: ``folder/cam0<c+1>/<stem>_cam0<c+1>.<t:05d>.json``."""
    for c in range(keypoints.shape[0]):
        camera = folder / f"cam{c + 1:02d}"
        camera.mkdir(parents=True, exist_ok=True)
        for t in range(keypoints.shape[1]):
            people = [{"person_id": [-1], "pose_keypoints_2d": keypoints[c, t].ravel().round(3).tolist()}]
            (camera / f"{stem}_cam{c + 1:02d}.{t:05d}.json").write_text(json.dumps({"version": 1.3, "people": people}))
    return folder


def jitter_mm(J: np.ndarray) -> float:
    """Mean joint acceleration ‖X_{t+1} − 2 X_t + X_{t−1}‖ (mm per tick²) of joints J (T, K, 3), metres."""
    return 1000 * float(np.nanmean(np.linalg.norm(np.diff(J, 2, axis=0), axis=-1)))


def run_real_format(preset: Preset | str, motion: str, seed: int = 0, calibration: Calibration | None = None,
                    cameras: list[int] | None = None, cache=None, smooth: bool = False) -> dict:
    """One run of the bench (module docstring): the tracker's and the triangulation's world MPJPE (mm)
    from shoulders to ankles, with the run's time and mismatch fraction; smoothed, also the filter's
    own error and the jitter of both and of the truth."""
    calibration = calibration or read_calibration(DEFAULT_CALIBRATION)
    chosen = list(range(len(calibration.cameras))) if cameras is None else cameras
    calibration = Calibration(tuple(calibration.cameras[c] for c in chosen), calibration.up, calibration.source)
    views = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    X = placed_walk(motion, calibration.up or "y")
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_openpose(detector_keypoints(X, views, rng), Path(tmp))
        detections = read_detections(folder, keypoints="body25b")
        start = time.perf_counter()
        result = track_detections(detections, calibration, preset,
                                  TrackConfig(fps=DATA_FPS, seed=seed, cache=cache, smooth=smooth))
        seconds = time.perf_counter() - start
    ticks = result.frames >= 0
    truth_all, tracked_all = X[result.frames[ticks]], result.joints[ticks]
    truth, tracked = truth_all[:, SHOULDERS_TO_ANKLES], tracked_all[:, SHOULDERS_TO_ANKLES]

    def hips_relative(J: np.ndarray) -> np.ndarray:
        return J[:, SHOULDERS_TO_ANKLES] - J[:, [9, 12]].mean(axis=1, keepdims=True)

    relative = np.linalg.norm(hips_relative(tracked_all) - hips_relative(truth_all), axis=-1)
    uv, confidence = detections.eval15(0.3)
    dlt = triangulate(views, uv[:, result.frames[ticks]], confidence[:, result.frames[ticks]])[:, SHOULDERS_TO_ANKLES]
    has = np.isfinite(dlt).all(axis=-1)
    error = np.linalg.norm(tracked - truth, axis=-1)
    smoothed = {}
    if smooth:
        filtered = result.filtered_joints[ticks][:, SHOULDERS_TO_ANKLES]
        run = np.flatnonzero(ticks)
        run = run[:np.argmax(np.diff(run) != 1) + 1] if (np.diff(run) != 1).any() else run   # consecutive ticks
        smoothed = {"filtered_mm": 1000 * float(np.linalg.norm(filtered - truth, axis=-1).mean()),
                    "jitter_mm": jitter_mm(result.joints[run][:, SHOULDERS_TO_ANKLES]),
                    "filtered_jitter_mm": jitter_mm(result.filtered_joints[run][:, SHOULDERS_TO_ANKLES]),
                    "truth_jitter_mm": jitter_mm(X[result.frames[run]][:, SHOULDERS_TO_ANKLES])}
    return {**smoothed, "preset": preset if isinstance(preset, str) else preset.name, "motion": motion, "seed": seed, "cameras": len(views), "ticks": int(ticks.sum()),
            "mpjpe_mm": 1000 * float(error.mean()), "relative_mm": 1000 * float(relative.mean()),
            "mpjpe_where_dlt_mm": 1000 * float(error[has].mean()) if has.any() else float("nan"),
            "dlt_mm": 1000 * float(np.linalg.norm(dlt - truth, axis=-1)[has].mean()) if has.any() else float("nan"),
            "dlt_coverage": float(has.mean()), "seconds": seconds,
            "mismatch_fraction": result.mismatch_fraction,
            "fit_check": None if result.fit_check is None else result.fit_check["verdict"],
            "better_prior": None if result.fit_check is None else result.fit_check.get("better_prior")}


def eval_real_format(presets, motions, seeds: int = 1, cameras: list[int] | None = None, cache=None,
                     smooth: bool = False) -> dict:
    """Every preset × motion × seed of :func:`run_real_format`: {"table": {preset: {"mpjpe_mm",
    "relative_mm", "dlt_mm", "ratio", "seconds"}}, "runs": [...], "cameras": C}, means over motions and
    seeds (DLT NaN from one camera); smoothed, each row adds the means of "filtered_mm", "jitter_mm",
    "filtered_jitter_mm" and "truth_jitter_mm"."""
    if seeds < 1:
        raise PriortrackError(f"seeds must be at least 1, got {seeds}")
    runs = [run_real_format(p, m, s, cameras=cameras, cache=cache, smooth=smooth) for p in presets for m in motions
            for s in range(seeds)]
    table = {}
    for p in presets:
        rows = [r for r in runs if r["preset"] == p]
        tracker, dlt = np.mean([r["mpjpe_where_dlt_mm"] for r in rows]), np.mean([r["dlt_mm"] for r in rows])
        table[p] = {"mpjpe_mm": float(np.mean([r["mpjpe_mm"] for r in rows])),
                    "relative_mm": float(np.mean([r["relative_mm"] for r in rows])), "dlt_mm": float(dlt),
                    "ratio": float(tracker / dlt), "seconds": float(np.mean([r["seconds"] for r in rows])),
                    **{key: float(np.mean([r[key] for r in rows])) for key in
                       ("filtered_mm", "jitter_mm", "filtered_jitter_mm", "truth_jitter_mm") if smooth}}
    return {"table": table, "runs": runs, "cameras": runs[0]["cameras"] if runs else 0}
