"""caliscope's long-format 2D keypoints (``xy_<TRACKER>.csv``), its cameras aligned by time.

One row per point a camera saw in a synchronised frame. Three column sets occur (caliscope's
history; all are read):

- 2023 (``port``): ``sync_index, port, frame_index, frame_time, point_id, img_loc_x, img_loc_y[,
  obj_loc_x, obj_loc_y]``;
- 2026 (``cam_id``, ``object_id``/``keypoint_id``): ``sync_index, cam_id, object_id, keypoint_id,
  img_loc_x, img_loc_y, obj_loc_x, obj_loc_y, obj_loc_z``, with or without ``frame_time``.

Camera ``N`` (``port``/``cam_id``) is named ``cam_N``, as its calibration's cameras are
(:mod:`priortrack.data.calibration_formats`). The point ids of caliscope's MediaPipe trackers
(``HOLISTIC``, ``POSE``, ``SIMPLE_HOLISTIC``) are the 33 pose landmarks (0–32; hands from 100,
face from 500, not used); another tracker's need ``keypoints=`` (or are inferred from the ids:
0–16 COCO-17, 0–32 MediaPipe-33). A ``CHARUCO`` file holds a calibration board, not a person.
caliscope saves **no confidence**: every point is taken at confidence 1 (logged).

**Time.** caliscope's webcams run free and it groups their frames into sync indices by nearest
timestamp (±10 ms apart). Where the file has ``frame_time`` (or a ``frame_time_history.csv`` lies
beside it: ``sync_index, port|cam_id, frame_time``), each camera is resampled onto one clock: frame
i at time t₀ + i Δt, Δt the cameras' median frame interval, each keypoint linearly interpolated
between the camera's two samples around that time (x(t) = x_k + (t − t_k)/(t_{k+1} − t_k)
(x_{k+1} − x_k), samples at most 1.5 Δt apart), or the nearest sample within Δt/2 where only it has
the point. The frame rate is 1/Δt. Without times, sync indices are the frames and the frame rate
must be given.
"""

from __future__ import annotations

import csv
import logging
import re
from pathlib import Path

import numpy as np

from priortrack.data.keypoints import LAYOUTS, layout_for
from priortrack.errors import PriortrackError

log = logging.getLogger(__name__)

#: caliscope trackers whose point ids 0–32 are MediaPipe's 33 pose landmarks.
MEDIAPIPE_TRACKERS = ("HOLISTIC", "POSE", "SIMPLE_HOLISTIC")
#: Most rows read, largest camera/point/object id and sync index (guards against absurd inputs).
MAX_ROWS, MAX_ID, MAX_SYNC = 50_000_000, 100_000, 1_000_000_000


def is_caliscope_csv(path: Path) -> bool:
    """A CSV whose header has caliscope's columns."""
    with open(path, newline="", errors="replace") as f:
        header = f.readline().strip().split(",")
    return {"sync_index", "img_loc_x", "img_loc_y"} <= set(header)


def read_caliscope(path: Path, keypoints: str | None = None):
    """Detections of a caliscope ``xy_*.csv`` (module docstring)."""
    from priortrack.data.detections import Detections, check_frames

    named = re.search(r"xy_(\w+)$", path.stem)
    tracker = named.group(1).upper() if named else path.stem.upper()
    if tracker == "CHARUCO":
        raise PriortrackError(f"{path}: caliscope's ChArUco board corners, not a person's keypoints")
    rows = _rows(path)
    camera_ids = sorted(set(rows["camera"].tolist()))
    sync = np.array(sorted(set(rows["sync"].tolist())))
    check_frames(sync, str(path))
    layout = _layout(path, tracker, rows["point"], keypoints)
    K = len(LAYOUTS[layout])
    body = rows["point"] < K
    if (~body).any():
        log.info("%s: %d rows of points %d and above (hands, face) are not used", path, int((~body).sum()), K)
    C, T = len(camera_ids), len(sync)
    keypoints_ = np.full((C, T, K, 3), np.nan)
    c = np.searchsorted(camera_ids, rows["camera"][body])
    t = np.searchsorted(sync, rows["sync"][body])
    keypoints_[c, t, rows["point"][body]] = np.column_stack([rows["xy"][body], np.ones(int(body.sum()))])
    log.warning("%s: caliscope saves no confidence; every point is taken at confidence 1", path)
    names = tuple(f"cam_{i}" for i in camera_ids)
    times = _times(path, rows, camera_ids, sync)
    if times is None:
        return Detections(layout, names, sync.astype(int), None, str(path), (0,) * C, keypoints=keypoints_)
    try:
        aligned, dt = align_by_time(keypoints_, times)
    except PriortrackError as exc:
        raise PriortrackError(f"{path}: {exc}") from None
    spread = np.nanmax(times, axis=1) - np.nanmin(times, axis=1)
    log.info("%s: %d cameras aligned by their frame times: %.2f fps; within a sync index they were up to %.1f ms "
             "apart", path, C, 1 / dt, 1000 * float(np.nanmax(spread)) if np.isfinite(spread).any() else 0.0)
    return Detections(layout, names, np.arange(aligned.shape[1]), 1 / dt, str(path), (0,) * C, keypoints=aligned)


def _rows(path: Path) -> dict[str, np.ndarray]:
    """The columns used: camera, sync, point (ints), xy (float), time (float, NaN where absent)."""
    with open(path, newline="", errors="replace") as f:
        reader = csv.DictReader(f)
        header = reader.fieldnames or []
        camera_key = next((k for k in ("cam_id", "port") if k in header), None)
        point_key = next((k for k in ("keypoint_id", "point_id") if k in header), None)
        if camera_key is None or point_key is None:
            raise PriortrackError(f"{path}: a caliscope CSV needs a camera column (cam_id or port) and a point column "
                                  f"(keypoint_id or point_id); it has {', '.join(header)}")
        camera, sync, point, obj, xy, time = [], [], [], [], [], []
        for i, row in enumerate(reader):
            if i >= MAX_ROWS:
                raise PriortrackError(f"{path}: more than {MAX_ROWS} rows")
            try:
                camera.append(int(row[camera_key]))
                sync.append(int(row["sync_index"]))
                point.append(int(row[point_key]))
                obj.append(int(row.get("object_id") or 0))
                xy.append((float(row["img_loc_x"]), float(row["img_loc_y"])))
                time.append(float(row["frame_time"]) if row.get("frame_time") else np.nan)
            except (TypeError, ValueError):
                raise PriortrackError(f"{path}: row {i + 2} is not numbers where caliscope writes them: "
                                      f"{dict(list(row.items())[:7])}") from None
    if not camera:
        raise PriortrackError(f"{path}: no rows")
    if max(map(abs, camera + sync + point + obj)) > MAX_SYNC:
        raise PriortrackError(f"{path}: ids past {MAX_SYNC}")
    rows = {"camera": np.array(camera), "sync": np.array(sync), "point": np.array(point), "object": np.array(obj),
            "xy": np.array(xy, dtype=np.float64), "time": np.array(time)}
    for key, most in (("camera", MAX_ID), ("point", MAX_ID), ("sync", MAX_SYNC), ("object", MAX_ID)):
        if not ((rows[key] >= 0) & (rows[key] <= most)).all():
            raise PriortrackError(f"{path}: {key} ids must be whole numbers from 0 to {most}")
    if not np.isfinite(rows["xy"]).all():
        raise PriortrackError(f"{path}: image locations that are NaN or inf")
    objects = np.unique(rows["object"])
    if len(objects) > 1:
        log.warning("%s: %d objects; following object_id %d", path, len(objects), int(objects[0]))
        keep = rows["object"] == objects[0]
        rows = {k: v[keep] for k, v in rows.items()}
    return rows


def _layout(path: Path, tracker: str, point: np.ndarray, keypoints: str | None) -> str:
    if keypoints is not None:
        key = keypoints.lower().replace("_", "").replace("-", "")
        return layout_for(keypoints, len(LAYOUTS[key]) if key in LAYOUTS else -1, str(path))
    if tracker in MEDIAPIPE_TRACKERS:
        return "mediapipe33"
    largest = int(point[point < 100].max(initial=-1))
    if 17 <= largest < 33:
        return "mediapipe33"
    if 0 <= largest < 17:
        return "coco17"
    raise PriortrackError(f"{path}: tracker {tracker!r} with point ids up to {largest}: say which layout with "
                          f"--keypoints ({', '.join(LAYOUTS)})")


def _times(path: Path, rows: dict, camera_ids: list[int], sync: np.ndarray) -> np.ndarray | None:
    """(T, C) frame time of each sync index and camera (NaN where unknown), from the file's
    ``frame_time`` or a ``frame_time_history.csv`` beside it; None where neither has them."""
    times = np.full((len(sync), len(camera_ids)), np.nan)
    if np.isfinite(rows["time"]).any():
        ok = np.isfinite(rows["time"])
        times[np.searchsorted(sync, rows["sync"][ok]), np.searchsorted(camera_ids, rows["camera"][ok])] = rows["time"][ok]
        return times
    history = path.with_name("frame_time_history.csv")
    if not history.is_file():
        return None
    with open(history, newline="", errors="replace") as f:
        reader = csv.DictReader(f)
        key = next((k for k in ("cam_id", "port") if k in (reader.fieldnames or [])), None)
        if key is None or "frame_time" not in (reader.fieldnames or []):
            raise PriortrackError(f"{history}: expected columns sync_index, port or cam_id, frame_time")
        for row in reader:
            try:
                s, c, value = int(row["sync_index"]), int(row[key]), float(row["frame_time"])
            except (TypeError, ValueError):
                raise PriortrackError(f"{history}: a row is not numbers: {row}") from None
            i, j = np.searchsorted(sync, s), np.searchsorted(camera_ids, c)
            if i < len(sync) and sync[i] == s and j < len(camera_ids) and camera_ids[j] == c:
                times[i, j] = value
    log.info("%s: frame times from %s", path, history.name)
    return times if np.isfinite(times).any() else None


def align_by_time(keypoints: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, float]:
    """Resample each camera's (C, T, K, 3) keypoints, sampled at its own times (T, C) (NaN: no
    frame), onto one clock t₀ + i Δt (module docstring). Returns the (C, N, K, 3) keypoints and Δt."""
    C = keypoints.shape[0]
    steps = [np.diff(np.sort(times[np.isfinite(times[:, c]), c])) for c in range(C)]
    steps = np.concatenate([s[s > 0] for s in steps]) if any(len(s) for s in steps) else np.array([])
    if not len(steps):
        raise PriortrackError("the frame times do not advance: cannot align the cameras")
    dt = float(np.median(steps))
    t0, t1 = float(np.nanmin(times)), float(np.nanmax(times))
    if not np.isfinite(t1 - t0) or (t1 - t0) / dt > 4 * len(times) + 10:
        raise PriortrackError(f"the frame times span {t1 - t0:.3g} s for {len(times)} frames {dt:.3g} s apart: "
                              f"not one recording's clock")
    grid = t0 + dt * np.arange(int(np.floor((t1 - t0) / dt + 0.5)) + 1)
    out = np.full((C, len(grid)) + keypoints.shape[2:], np.nan)
    for c in range(C):
        ok = np.isfinite(times[:, c])
        tc, kc = times[ok, c], keypoints[c, ok]
        order = np.argsort(tc, kind="stable")
        tc, kc = tc[order], kc[order]
        if not len(tc):
            continue
        after = np.clip(np.searchsorted(tc, grid, side="right"), 1, max(len(tc) - 1, 1))
        before = after - 1 if len(tc) > 1 else np.zeros_like(after)
        after = after if len(tc) > 1 else np.zeros_like(after)
        ta, tb = tc[before], tc[after]
        span = tb - ta
        w = np.where(span > 0, (grid - ta) / np.where(span > 0, span, 1.0), 0.0)[:, None, None]
        inside = (grid >= ta) & (grid <= tb) & (span <= 1.5 * dt)
        both = inside[:, None] & np.isfinite(kc[before, :, 0]) & np.isfinite(kc[after, :, 0])
        interpolated = (1 - w) * kc[before] + w * kc[after]
        nearest = np.where((np.abs(grid - ta) <= np.abs(grid - tb))[:, None, None], kc[before], kc[after])
        close = (np.minimum(np.abs(grid - ta), np.abs(grid - tb)) <= 0.5 * dt)[:, None] & np.isfinite(nearest[..., 0])
        out[c] = np.where(both[..., None], interpolated, np.where(close[..., None], nearest, np.nan))
    return out, dt
