"""``priortrack compare --detections``: filters compared on a user's own recording, scored without 3D
truth by leaving each camera out in turn.

A run is one preset, one held-out camera c and one seed: the preset tracks the person from every
camera but c (:func:`~priortrack.tracking.person.track_detections`), and the estimate's joints are
projected into c (its lens distortion included) and compared with c's own detections over the limb
joints (shoulders to ankles, where c's confidence exceeds ``min_confidence``): e_{t,j} = ‖π_c(X̂_{t,j})
− u_{c,t,j}‖ in pixels, at every tick that consumed a frame. A camera the tracker never saw is an
independent view: how well a 3D estimate explains it is its cross-validation where no truth exists.
The baseline is per-frame confidence-weighted DLT of the same other cameras on the same frames,
projected the same way (a row of the table beside the presets). With ``smooth`` the smoothed joints
are scored, the filter's own beside them. With ``lowpass`` (Hz) the estimate scored is passed through Pose2Sim's
zero-lag Butterworth (:mod:`~priortrack.tracking.lowpass`, at the ticks' rate; the filter's own estimate beside a
smoothed one is not), and a second baseline row, "DLT +
low-pass", is the DLT of every frame of the other cameras through the same filter at the detections' rate (what
Pose2Sim gives from those cameras), scored on the same frames.

With a truth file (3D joints of the same frames: a TRC or an NPZ, :func:`read_truth`) each preset
also tracks from every camera (held-out camera "", the "all cameras" run), scored by world MPJPE
over the same joints against the truth, beside the DLT of every camera.

The grid is cached, resumable and Dask-able as the motion-capture grid is
(:func:`priortrack.experiments.compare.compare`): a run's key covers the detections', calibration's
and truth's bytes. A worker reads those files by their paths: on a remote scheduler's workers they
must be where the paths say (a shared folder, given as absolute paths). The summary pools every held-out camera's errors per preset (median and 90th
percentile, pixels) and breaks them down by camera and by joint.
"""

from __future__ import annotations

import hashlib
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np

from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.errors import PriortrackError

log = logging.getLogger(__name__)
#: The eval15 joints scored by default: shoulders to ankles (pelvis, neck and head are defined differently
#: by each detector); a grid may score fewer (the upper body of a person seated at a desk).
LIMBS = EVAL15_NAMES[3:]
#: The CSV's columns, in order (truth and smoothing add theirs where given).
COLUMNS = ("filter", "held_out", "seed", "median_px", "p90_px", "dlt_median_px", "dlt_p90_px", "ticks",
           "s_per_frame", "mismatch_fraction", "error", "config_hash")
TRUTH_COLUMNS = ("mpjpe_mm", "dlt_mpjpe_mm")
LOWPASS_COLUMNS = ("dlt_lowpass_median_px", "dlt_lowpass_p90_px")
#: The baselines of the table: {row: the series of each run that holds its held-out errors}.
BASELINES = {"DLT": "dlt_px", "DLT + low-pass": "dlt_lowpass_px"}
SMOOTHED_COLUMNS = ("filtered_median_px", "filtered_p90_px", "filtered_mpjpe_mm")
#: Every held-out camera's name for the run that tracks from all cameras (scored by the truth only).
ALL_CAMERAS = ""


def _digest(path: Path) -> bytes:
    """SHA-256 of a file's bytes, or of a folder's files (relative names and bytes, in sorted order)."""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        h.update(str(f.relative_to(path) if path.is_dir() else f.name).encode())
        h.update(f.read_bytes())
    return h.digest()


@dataclass(frozen=True)
class DetectionRunConfig:
    """One run of a detections grid (plain values: what a Dask worker is sent). ``held_out``: the
    detection camera left out (its name), or :data:`ALL_CAMERAS`; ``person``: in files of several people,
    the scene tracker's id of the person tracked (:func:`~priortrack.tracking.people.associated`, from every
    camera: the camera left out helps tell who is who, never where they are); None: files of one person."""

    filter: str
    detections: str
    cameras: str
    held_out: str
    seed: int
    truth: str | None = None
    keypoints: str | None = None
    fps: float | None = None
    frames: int | None = None
    smooth: bool = False
    joints: tuple[str, ...] = LIMBS
    person: int | None = None
    lowpass: float | None = None

    @cached_property
    def key(self) -> str:
        """The configuration hash: the fields, priortrack's version, the preset file's text and the
        bytes of the detections, calibration and truth (16 hex digits)."""
        from priortrack.experiments.compare import config_key

        return config_key(self, b"".join(_digest(Path(p)) for p in (self.detections, self.cameras, self.truth)
                                         if p is not None))

    @property
    def label(self) -> str:
        """filter · held-out camera · seed: the run's name in recordings and logs."""
        who = "" if self.person is None else f"person {self.person} · "
        return (f"{who}{self.filter} · {'all cameras' if self.held_out == ALL_CAMERAS else 'without ' + self.held_out}"
                f" · seed {self.seed}")

    @property
    def recording_stem(self) -> str:
        return "_".join((self.filter, self.held_out or "all", f"seed{self.seed}"))

    def run(self, cache: str | None = None, rrd: bool = False) -> tuple[dict, dict[str, list], bytes | None]:
        return run_detections(self, cache, rrd)

    @staticmethod
    def write_results(rows: Sequence[dict], series: dict[str, dict[str, np.ndarray]], out: Path) -> None:
        """``out``/results.csv, summary.md and plots/ (:func:`summary`)."""
        from priortrack.experiments.compare import write_csv
        from priortrack.viz.compare_plots import write_detection_plots

        extra = [c for c in TRUTH_COLUMNS + SMOOTHED_COLUMNS + LOWPASS_COLUMNS if any(r.get(c) is not None for r in rows)]
        write_csv(rows, out / "results.csv", list(COLUMNS) + extra)
        (out / "summary.md").write_text(summary_markdown(summary(rows, series)))
        write_detection_plots(rows, series, out / "plots")


def _inputs(config: DetectionRunConfig):
    """The detections (their first ``frames``; two cameras or more), calibration and each detection
    camera's calibration."""
    from priortrack.data.calibration import read_calibration
    from priortrack.data.detections import read_detections
    from priortrack.tracking.person import match_cameras

    calibration = read_calibration(config.cameras)
    if config.person is None:
        detections = read_detections(config.detections, keypoints=config.keypoints)
        if config.frames is not None:
            detections = detections.head(config.frames)
    else:
        detections = scene_person(config)
    if len(detections.camera_names) < 2:
        raise PriortrackError(f"compare --detections scores each camera left out: {config.detections} has "
                              f"{len(detections.camera_names)} camera; it needs two or more")
    return detections, calibration, match_cameras(detections, calibration)


def scene_people(detections: str, cameras: str, people, keypoints: str | None = None, fps: float | None = None,
                 frames: int | None = None) -> list[int]:
    """The scene tracker's ids of the ``people`` asked for (:func:`~priortrack.tracking.people.parse_people`'s
    forms) in files of several people."""
    from priortrack.tracking.people import chosen_people, indexed

    if indexed(people) is not None:
        raise PriortrackError("compare --people: index:N is track's (the files' own order); compare takes the scene "
                              "tracker's people: all, N, id:A,B, at:… or box:…")
    scene, association = _associated(detections, cameras, keypoints, fps, frames, _inputs_digest(detections, cameras))
    return [int(association.person_ids[p]) for p in chosen_people(association, people, scene)]


def scene_person(config: DetectionRunConfig):
    """The detections of ``config.person`` in files of several people (:class:`DetectionRunConfig`)."""
    from priortrack.tracking.people import chosen_people

    scene, association = _associated(config.detections, config.cameras, config.keypoints, config.fps, config.frames,
                                     _inputs_digest(config.detections, config.cameras))
    return association.detections_of(scene, chosen_people(association, [config.person], scene)[0])


def _inputs_digest(detections: str, cameras: str) -> bytes:
    return _digest(Path(detections)) + _digest(Path(cameras))


@lru_cache(maxsize=2)
def _associated(detections: str, cameras: str, keypoints: str | None, fps: float | None, frames: int | None,
                digest: bytes):
    """Every person of the files and who is who (:func:`~priortrack.tracking.people.associated`), read and
    decided once in a process for every run of a grid (the files' bytes, ``digest``, in the key: files changed
    since are read again)."""
    from priortrack.data.calibration import read_calibration
    from priortrack.tracking.people import associated

    scene, rate = _scene(detections, keypoints, fps, frames)
    association, _ = associated(scene, read_calibration(cameras), rate)
    return scene, association


def _scene(detections: str, keypoints: str | None, fps: float | None, frames: int | None):
    """Every person of the files (their first ``frames``) and their frame rate."""
    from priortrack.data.scene_detections import read_scene_detections

    scene = read_scene_detections(detections, keypoints=keypoints)
    if frames is not None:
        scene = scene.head(frames)
    rate = fps if fps is not None else scene.fps
    if rate is None:
        raise PriortrackError(f"{detections}: the detections do not say their frame rate; give it (--fps)")
    return scene, rate


def plan_detections(filters: Sequence[str], detections: str, cameras: str, seeds: int, truth: str | None = None,
                    keypoints: str | None = None, fps: float | None = None, frames: int | None = None,
                    smooth: bool = False, joints: Sequence[str] = LIMBS,
                    person: int | None = None, lowpass: float | None = None) -> list[DetectionRunConfig]:
    """Every run of the grid (each preset × each held-out camera × each seed, and with a ``truth`` the
    all-camera runs), after checking every argument (one PriortrackError naming the first bad one,
    before any work): the presets, the files, at least two cameras, the joints scored (eval15 names from
    the shoulders down), the truth's joints and frames."""
    from priortrack.experiments.compare import check_grid

    joints = tuple(joints)
    unknown = [j for j in joints if j not in LIMBS]
    if not joints or unknown or len(set(joints)) < len(joints):
        raise PriortrackError(f"compare: --joints must name distinct joints among {', '.join(LIMBS)}"
                              + (f"; {', '.join(unknown)} is not one" if unknown else ""))
    check_grid(filters, seeds, frames, smooth)
    probe = DetectionRunConfig(filters[0], str(detections), str(cameras), ALL_CAMERAS, 0, truth, keypoints, fps, frames,
                               person=person)
    found, calibration, _ = _inputs(probe)
    if fps is None and found.fps is None:
        raise PriortrackError(f"{detections}: the detections do not say their frame rate; give it (--fps)")
    if lowpass is not None:                     # the estimate is low-passed at the priors' ticks, the DLT at the data's
        from priortrack.priors.base import DEFAULT_FPS
        from priortrack.tracking.lowpass import check_cutoff

        check_cutoff(lowpass, min(fps or found.fps, DEFAULT_FPS))
    if truth is not None:
        read_truth(truth, found, calibration, joints, fps)
    held = list(found.camera_names) + ([ALL_CAMERAS] if truth is not None else [])
    return [DetectionRunConfig(f, str(detections), str(cameras), c, seed, truth, keypoints, fps, frames, smooth, joints,
                               person, lowpass) for f in filters for c in held for seed in range(seeds)]


# ---- truth --------------------------------------------------------------------------------------

def _normalised(name: str) -> str:
    """A joint name compared across tools: lower case, no separators, left/right as l/r
    ("RShoulder", "right_shoulder", "rshoulder" → "rshoulder")."""
    key = "".join(ch for ch in name.lower() if ch.isalnum())
    for side in ("left", "right"):
        if key.startswith(side):
            key = side[0] + key[len(side):]
    return key


def read_truth(path: str | Path, detections, calibration, joints: Sequence[str] = LIMBS,
               fps: float | None = None) -> np.ndarray:
    """(T, J, 3) world positions (metres, the calibration's world) of the eval15 ``joints`` at each
    detection frame, NaN where the truth has none.

    - NPZ: ``joints`` (N, J, 3) metres in the calibration's world, ``joint_names`` (J,) (eval15 if absent
      and J = 15) and ``frames`` (N,), the detection frame numbers (else row k is the k-th detection
      frame); priortrack's own ``track --out`` NPZ is one.
    - TRC (Pose2Sim, OpenSim): Y-up as TRC files are; turned back into a Z-up calibration's world as
      Pose2Sim writes it (:mod:`priortrack.data.trc`); row k is the k-th detection frame, at the same rate
      (the detections' ``fps``, given or their own).

    Marker names match eval15's across spellings (RShoulder, right_shoulder, rshoulder)."""
    from priortrack.data.npz import read_npz
    from priortrack.data.trc import read_trc

    path = Path(path)
    if not path.is_file():
        raise PriortrackError(f"truth {path} does not exist")
    suffix = path.suffix.lower()
    rows = None
    if suffix == ".npz":
        arrays = read_npz(path, 1 << 31, "truth")
        if "joints" not in arrays:
            raise PriortrackError(f"truth {path} has no 'joints' array (N, J, 3) of metres")
        points = np.asarray(arrays["joints"], dtype=float)
        if points.ndim != 3 or points.shape[-1] != 3:
            raise PriortrackError(f"truth {path}: joints have shape {points.shape}; expected (N, J, 3)")
        if "joint_names" in arrays:
            names = tuple(str(n) for n in arrays["joint_names"])
            if len(names) != points.shape[1]:
                raise PriortrackError(f"truth {path}: {len(names)} joint_names for {points.shape[1]} joints")
        elif points.shape[1] == 15:
            names = EVAL15_NAMES
        else:
            raise PriortrackError(f"truth {path}: {points.shape[1]} joints and no 'joint_names' to say which")
        if "frames" in arrays:
            frames = np.asarray(arrays["frames"]).astype(np.int64)
            if frames.shape != (len(points),):
                raise PriortrackError(f"truth {path}: frames have shape {frames.shape}; expected ({len(points)},)")
            at = np.searchsorted(detections.frames, frames)
            known = (at < len(detections.frames)) & (detections.frames[np.minimum(at, len(detections.frames) - 1)] == frames)
            rows = np.full(len(detections.frames), -1)
            rows[at[known]] = np.flatnonzero(known)
    elif suffix == ".trc":
        up = calibration.up if isinstance(calibration.up, str) and calibration.up in ("y", "z") else "y"
        points, names, rate = read_trc(path, up)
        fps = fps or detections.fps
        if fps is not None and abs(rate - fps) > 1e-6 * fps:
            raise PriortrackError(f"truth {path} is at {rate:g} fps, the detections at {fps:g}: "
                                  f"give the truth at the detections' rate")
    else:
        raise PriortrackError(f"truth {path}: give a .trc or .npz file of 3D joints")
    by_name = {_normalised(n): i for i, n in enumerate(names)}
    columns = [by_name.get(_normalised(j)) for j in joints]
    missing = [j for j, c in zip(joints, columns) if c is None]
    if missing:
        raise PriortrackError(f"truth {path} lacks the joints {', '.join(missing)} (it has {', '.join(names)})")
    if rows is None:
        rows = np.where(np.arange(len(detections.frames)) < len(points), np.arange(len(detections.frames)), -1)
    truth = np.full((len(detections.frames), len(joints), 3), np.nan)
    has = np.flatnonzero(rows >= 0)
    truth[has] = points[rows[has]][:, columns]
    if not np.isfinite(truth).any():
        raise PriortrackError(f"truth {path} covers none of the detections' frames")
    return truth


# ---- one run ------------------------------------------------------------------------------------

def _finite(values) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    return values[np.isfinite(values)]


def _quantile(values: np.ndarray, q: float) -> float | None:
    finite = _finite(values)
    return float(np.quantile(finite, q)) if len(finite) else None


def _mean(values: np.ndarray) -> float | None:
    finite = _finite(values)
    return float(finite.mean()) if len(finite) else None


def _mm(X: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(T, J) joint errors in mm (NaN where either is missing)."""
    return 1000 * np.linalg.norm(X - truth, axis=-1)


def run_detections(config: DetectionRunConfig, cache: str | None = None,
                   rrd: bool = False) -> tuple[dict, dict[str, list], bytes | None]:
    """One run on the compare grid's torch threads: its CSV row, its series (``frames`` (T,), the
    detection frame number each scored tick consumed; per tick × scored joint: ``error_px``, ``dlt_px``,
    ``filtered_px`` held-out pixel errors, ``error_mm``, ``dlt_mm`` against a truth) and, with ``rrd``,
    its recording's bytes. A run that cannot track (:class:`PriortrackError`) gives a row with its
    ``error`` and no series."""
    import tempfile

    from priortrack.data.calibration import Calibration
    from priortrack.experiments.compare import RUN_THREADS
    from priortrack.geometry.camera import pixel_errors
    from priortrack.tracking.person import TrackConfig, track_detections, up_from_detections
    from priortrack.geometry.camera import PinholeCamera
    from priortrack.geometry.triangulation import triangulate
    from priortrack.threads import torch_threads
    from priortrack.tracking.lowpass import lowpassed

    detections, calibration, matched = _inputs(config)
    names = detections.camera_names
    if config.held_out != ALL_CAMERAS and config.held_out not in names:
        raise PriortrackError(f"held-out camera {config.held_out!r} is not among {', '.join(names)}")
    kept = [c for c, n in enumerate(names) if n != config.held_out]
    cameras = [PinholeCamera.from_calibration(c) for c in matched]
    uv, confidence = detections.eval15(0.3)
    # the world's up is the recording's: from the file, else from the person seen by every camera
    up = calibration.up if calibration.up is not None else up_from_detections(cameras, detections, 0.3,
                                                                              calibration.source)
    seen = replace(detections, keypoints=detections.keypoints[kept], camera_names=tuple(names[c] for c in kept),
                   switches=tuple(detections.switches[c] for c in kept) if detections.switches else ())
    row = {"filter": config.filter, "held_out": config.held_out, "seed": config.seed, "joints": list(config.joints),
           "config_hash": config.key}
    try:
        with torch_threads(RUN_THREADS):
            others = Calibration(tuple(matched[c] for c in kept), up, calibration.source, calibration.format,
                                 calibration.units)
            result = track_detections(seen, others, config.filter,
                                      TrackConfig(fps=config.fps, seed=config.seed, cache=cache, smooth=config.smooth,
                                                  keep_snapshots=rrd))
    except PriortrackError as exc:                 # e.g. too few joints seen by two of the other cameras to start
        log.warning("compare: %s could not track: %s", config.label, exc)
        return {**row, "error": str(exc)}, {}, None
    if config.lowpass is not None:
        result = result.low_passed(config.lowpass)
    ticks = result.frames >= 0
    at = np.searchsorted(detections.frames, result.frames[ticks])              # detection index of each tick
    J = [EVAL15_NAMES.index(j) for j in config.joints]
    dlt = triangulate([cameras[c] for c in kept], uv[kept][:, at], confidence[kept][:, at])[:, J]
    row.update(ticks=int(ticks.sum()), s_per_frame=result.seconds / max(len(result.joints), 1),
               mismatch_fraction=result.mismatch_fraction)
    series: dict[str, np.ndarray] = {"frames": result.frames[ticks]}
    if config.held_out != ALL_CAMERAS:
        c = names.index(config.held_out)

        def held_out_px(X: np.ndarray) -> np.ndarray:
            return pixel_errors(cameras[c], X, uv[c, at][:, J], confidence[c, at][:, J])

        series["error_px"], series["dlt_px"] = held_out_px(result.joints[ticks][:, J]), held_out_px(dlt)
        if config.lowpass is not None:                # every frame's DLT through the filter, at the data's rate
            every = triangulate([cameras[c] for c in kept], uv[kept], confidence[kept])[:, J]
            series["dlt_lowpass_px"] = held_out_px(lowpassed(every, result.data_fps, config.lowpass)[at])
        if config.smooth:
            series["filtered_px"] = held_out_px(result.filtered_joints[ticks][:, J])
    if config.truth is not None:
        truth = read_truth(config.truth, detections, calibration, config.joints, config.fps)[at]
        series["error_mm"], series["dlt_mm"] = _mm(result.joints[ticks][:, J], truth), _mm(dlt, truth)
        row["mpjpe_mm"], row["dlt_mpjpe_mm"] = _mean(series["error_mm"]), _mean(series["dlt_mm"])
        if config.smooth:
            row["filtered_mpjpe_mm"] = _mean(_mm(result.filtered_joints[ticks][:, J], truth))
    for prefix, key in (("", "error_px"), ("dlt_", "dlt_px"), ("filtered_", "filtered_px"),
                        ("dlt_lowpass_", "dlt_lowpass_px")):
        if key in series:
            row[prefix + "median_px"], row[prefix + "p90_px"] = (_quantile(series[key], q) for q in (0.5, 0.9))
    recording = None
    if rrd:
        from priortrack.viz.real import record_detections

        with tempfile.TemporaryDirectory() as folder:
            recording = record_detections(result, Path(folder) / "run.rrd").read_bytes()
    return row, {k: v.tolist() for k, v in series.items()}, recording


# ---- the summary ---------------------------------------------------------------------------------

def _pooled(runs: Sequence[dict], series: dict[str, dict[str, np.ndarray]], key: str, J: int) -> np.ndarray:
    """Every value of ``key``'s series over the runs, (N, J) stacked (runs without it add nothing)."""
    arrays = [np.asarray(series[r["config_hash"]][key]).reshape(-1, J) for r in runs
              if key in series[r["config_hash"]]]
    return np.concatenate(arrays) if arrays else np.empty((0, J))


def _tracked_by_name(rows: Sequence[dict]) -> dict[str, list[dict]]:
    """The runs that tracked, by preset, and as "DLT" each held-out camera's (and the all-camera run's)
    first run that tracked: the DLT of the other cameras on its frames, the same for every preset; as "DLT +
    low-pass" the same runs where they were low-passed (:data:`BASELINES`)."""
    tracked = [r for r in rows if "error" not in r]
    cameras = dict.fromkeys(r["held_out"] for r in tracked)
    first = [next(r for r in tracked if r["held_out"] == c) for c in cameras]
    return {**{f: [r for r in tracked if r["filter"] == f] for f in dict.fromkeys(r["filter"] for r in rows)},
            "DLT": first, **({"DLT + low-pass": first} if any("dlt_lowpass_median_px" in r for r in first) else {})}


def _series_key(name: str) -> str:
    """The series a table row's held-out errors are in: a baseline's own (:data:`BASELINES`), else the preset's."""
    return BASELINES.get(name, "error_px")


def held_out_errors(rows: Sequence[dict], series: dict[str, dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """{preset, and each baseline ("DLT", "DLT + low-pass"): (N, J) the pixel errors in the cameras left out, every
    run's ticks stacked}."""
    J = len(rows[0]["joints"])
    return {name: _pooled([r for r in runs if r["held_out"] != ALL_CAMERAS], series, _series_key(name), J)
            for name, runs in _tracked_by_name(rows).items()}


def summary(rows: Sequence[dict], series: dict[str, dict[str, np.ndarray]]) -> dict:
    """The grid's table: {"held_out": {name: {"median_px", "p90_px", "ratio_median", "ratio_p90",
    "filtered_median_px", "filtered_p90_px", "by_camera": {camera: median}, "by_joint": {joint: median},
    "mpjpe_mm", "filtered_mpjpe_mm"}}, "cameras", "joints", "seeds", "failed": [(filter, held_out, seed,
    error)]}; the DLT of the other cameras is the row "DLT" (its errors from each held-out camera's first
    run that tracked: the same frames). Pixel figures pool every held-out camera's ticks and joints;
    "mpjpe_mm" is the all-camera runs' mean against a truth; ratios are the preset's over DLT's."""
    cameras = list(dict.fromkeys(r["held_out"] for r in rows if r["held_out"] != ALL_CAMERAS))
    joints = list(rows[0]["joints"])
    pooled = held_out_errors(rows, series)
    table: dict[str, dict] = {}
    for name, runs in _tracked_by_name(rows).items():
        key = _series_key(name)
        loco = [r for r in runs if r["held_out"] != ALL_CAMERAS]
        errors = pooled[name]
        entry = {"median_px": _quantile(errors, 0.5), "p90_px": _quantile(errors, 0.9),
                 "by_camera": {c: _quantile(_pooled([r for r in loco if r["held_out"] == c], series, key,
                                                    len(joints)), 0.5) for c in cameras},
                 "by_joint": {j: _quantile(errors[:, i], 0.5) for i, j in enumerate(joints)}}
        if name not in BASELINES and any("filtered_px" in series[r["config_hash"]] for r in loco):
            filtered = _pooled(loco, series, "filtered_px", len(joints))
            entry.update(filtered_median_px=_quantile(filtered, 0.5), filtered_p90_px=_quantile(filtered, 0.9))
        everything = [r for r in runs if r["held_out"] == ALL_CAMERAS]
        if everything and name != "DLT + low-pass":
            entry["mpjpe_mm"] = _mean(np.array([r["dlt_mpjpe_mm" if name == "DLT" else "mpjpe_mm"] for r in everything],
                                               dtype=float))
            if name not in BASELINES and everything[0].get("filtered_mpjpe_mm") is not None:
                entry["filtered_mpjpe_mm"] = _mean(np.array([r["filtered_mpjpe_mm"] for r in everything], dtype=float))
        table[name] = entry
    dlt = table["DLT"]
    for entry in table.values():
        for q in ("median", "p90"):
            mine, theirs = entry[f"{q}_px"], dlt[f"{q}_px"]
            entry[f"ratio_{q}"] = None if mine is None or not theirs else mine / theirs
    failed = [(r["filter"], r["held_out"], r["seed"], r["error"]) for r in rows if "error" in r]
    return {"held_out": table, "cameras": cameras, "joints": joints, "seeds": len({r["seed"] for r in rows}),
            "failed": failed}


def _cell(value: float | None, digits: int = 1) -> str:
    return "—" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def summary_table(result: dict) -> list[str]:
    """The Markdown lines of the main table: a row per preset and the DLT baseline."""
    table = result["held_out"]
    smoothed = any("filtered_median_px" in e for e in table.values())
    truth = any("mpjpe_mm" in e for e in table.values())
    head = ["filter", "median px", "p90 px", "× DLT median", "× DLT p90"]
    head += ["filtered median px", "filtered p90 px"] if smoothed else []
    head += ["MPJPE mm (all cameras)"] + (["filtered MPJPE mm"] if smoothed else []) if truth else []
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for name, e in table.items():
        cells = [name, _cell(e["median_px"]), _cell(e["p90_px"]), _cell(e["ratio_median"], 2), _cell(e["ratio_p90"], 2)]
        cells += [_cell(e.get("filtered_median_px")), _cell(e.get("filtered_p90_px"))] if smoothed else []
        cells += [_cell(e.get("mpjpe_mm"))] + ([_cell(e.get("filtered_mpjpe_mm"))] if smoothed else []) if truth else []
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def summary_markdown(result: dict) -> str:
    """summary.md: the main table, then the median by held-out camera and by joint."""
    table, cameras = result["held_out"], result["cameras"]
    lines = ["# Filter comparison on detections, each camera left out in turn\n",
             f"Each preset tracked from every camera but one ({len(cameras)} cameras, {result['seeds']} seed(s)); "
             f"its joints ({', '.join(result['joints'])}) projected into the camera left out and compared with that camera's "
             "detections (confidence > 0.3), pixels, pooled over the cameras left out. DLT: per-frame triangulation "
             "of the same other cameras on the same frames. × DLT: the preset's figure over DLT's (below 1: better).\n",
             *summary_table(result), "", "## Median by camera left out (px)\n",
             "| filter | " + " | ".join(cameras) + " |", "|---" * (len(cameras) + 1) + "|"]
    lines += [f"| {n} | " + " | ".join(_cell(e["by_camera"][c]) for c in cameras) + " |" for n, e in table.items()]
    joints = result["joints"]
    lines += ["", "## Median by joint (px)\n", "| filter | " + " | ".join(joints) + " |",
              "|---" * (len(joints) + 1) + "|"]
    lines += [f"| {n} | " + " | ".join(_cell(e["by_joint"][j]) for j in joints) + " |" for n, e in table.items()]
    if result["failed"]:
        lines += ["", "## Runs that could not track (left out of the figures above)\n"]
        lines += [f"- {f}, {'all cameras' if c == ALL_CAMERAS else 'without ' + c}, seed {seed}: {error}"
                  for f, c, seed, error in result["failed"]]
    return "\n".join(lines) + "\n"
