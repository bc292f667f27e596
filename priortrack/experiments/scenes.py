"""The lab bench for several people: bundled walks composed into one scene, written as a multi-person
detector writes them, tracked by the scene tracker, scored against the mocap.

Each walk is placed as :func:`~priortrack.experiments.real_format.placed_walk` places one (its middle
``seconds``, ground track centred, in the Pose2Sim demo's Z-up world), turned to walk along a heading,
shifted sideways and to the middle of the floor every camera sees (:func:`capture_centre`); the scenes
(:data:`SCENES`):

- ``passing``: two people walking towards each other, passing ``gap`` metres apart (centre to centre);
- ``return``: two side by side 0.8 m apart; the second leaves the cameras' view for ``away_s`` seconds
  in the middle (no detection of them anywhere) and comes back;
- ``crossing``: three people on headings 0°, 150° and 210°, their paths offset 0.3 m from the centre,
  crossing one another (the demo's common view is a strip about 2 m long);
- ``together``: two people walking side by side, shoulder to shoulder (0.5 m apart centre to centre), the whole
  clip: the nearer one hides much of the other from the side cameras.

Every person gets a detector's errors (:func:`~priortrack.experiments.real_format.detector_keypoints`);
a joint hidden behind a nearer person (within :data:`BODY_RADIUS_M` of one of their bones, seen from the
camera) is dropped; a static false positive (a standing body 1 m or more from the walkers, confidences
0.3–0.5) is seen by the first two cameras only, consistently (it triangulates); and each file holds every person, in a shuffled order, with no id
(:func:`write_scene_openpose`). The walkers are people the preset's prior never saw: its prior is learned
again without them (:func:`~priortrack.experiments.people.fold_preset`).

The scores (:func:`score_scene`): CLEAR-MOT and identity metrics by py-motmetrics (MOTA, IDF1, identity
switches, false positives), a track matching a walker when its joints (shoulders to ankles) are within
:data:`MATCH_M` median of theirs; false tracks (tracks that match no walker in most of their ticks); per
walker, PCP (a limb correct when the mean of its two ends' errors is at most half its length: upper and
lower arms and legs, the torso and the head, the detector's pelvis and neck) and MPJPE shoulders to
ankles of the track that matched them most, and the MPJPE of the same walker tracked alone from their own
detections (:func:`~priortrack.tracking.person.track_detections`, the others removed).
"""

from __future__ import annotations

import json
import logging
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from priortrack.data.calibration import read_calibration
from priortrack.data.detections import read_detections
from priortrack.data.eval15 import EVAL15_PARENTS
from priortrack.data.keypoints import LAYOUTS, detector_map
from priortrack.data.scene_detections import read_scene_detections
from priortrack.errors import PriortrackError
from priortrack.experiments.metrics import pcp
from priortrack.experiments.real_format import (BODY25B_OF, DATA_FPS, DEFAULT_CALIBRATION, SHOULDERS_TO_ANKLES,
                                                detector_keypoints, placed_walk, write_openpose)
from priortrack.geometry.camera import PinholeCamera

log = logging.getLogger(__name__)

#: A joint is hidden behind a nearer person when its pixel lies within this body radius (metres, at the
#: nearer person's depth) of one of their bones.
BODY_RADIUS_M = 0.1
#: A track matches a walker at a tick when their joints (shoulders to ankles) are within this median distance.
MATCH_M = 0.3
SECONDS = 1.6


@dataclass(frozen=True)
class Walker:
    """One person of a scene: a bundled walk, its heading (degrees about up) and sideways offset (metres)."""

    motion: str
    person: str
    heading: float
    offset: float


#: The scenes (module docstring): walkers of people held out of the priors, and what each scene does.
SCENES: dict[str, tuple[Walker, ...]] = {
    "passing": (Walker("cmu:02_01", "02", 0.0, 0.25), Walker("cmu:05_01", "05", 180.0, 0.25)),
    "return": (Walker("cmu:07_10", "07", 0.0, 0.4), Walker("cmu:08_04", "08+39", 0.0, -0.4)),
    "crossing": (Walker("walkjog:35_29", "35", 0.0, 0.3), Walker("cmu:02_02", "02", 150.0, 0.3),
                 Walker("cmu:08_04", "08+39", 210.0, 0.3)),
    "together": (Walker("cmu:02_01", "02", 0.0, 0.25), Walker("cmu:05_01", "05", 0.0, -0.25)),
}


def _floor_seen(cameras: list[PinholeCamera], up: str, step: float = 0.1, reach: float = 5.0):
    """The floor grid (two (n, n) coordinate arrays along the floor axes of a world whose up is ``up``) and
    where each camera sees a standing body (up from 0.05 to 1.8 m) whole: (C, n, n) bool."""
    grid = np.arange(-reach, reach + 1e-9, step)
    a, b = np.meshgrid(grid, grid)
    k = "xyz".index(up)
    floor = [i for i in range(3) if i != k]
    seen = np.ones((len(cameras),) + a.shape, dtype=bool)
    for height in (0.05, 1.8):
        points = np.zeros(a.shape + (3,))
        points[..., floor[0]], points[..., floor[1]], points[..., k] = a, b, height
        for c, camera in enumerate(cameras):
            uv, front = camera.project(points.reshape(-1, 1, 3))
            inside = front & (uv[..., 0] >= 0) & (uv[..., 0] < camera.width) & (uv[..., 1] >= 0) & \
                (uv[..., 1] < camera.height)
            seen[c] &= inside.reshape(a.shape)
    return a, b, floor, seen


def capture_centre(cameras: list[PinholeCamera], up: str = "z") -> np.ndarray:
    """(3,) the centre, on the floor, of the ground points whose standing body every camera sees whole:
    the place a scene is played (the Pose2Sim demo's four cameras share about 2 × 1.3 m around
    (−0.8, −0.1))."""
    a, b, floor, seen = _floor_seen(cameras, up)
    every = seen.all(axis=0)
    if not every.any():
        raise PriortrackError("no place on the floor within 5 m is seen by every camera: no scene can be played")
    centre = np.zeros(3)
    centre[floor] = a[every].mean(), b[every].mean()
    return centre


def false_positive_place(X: np.ndarray, cameras: list[PinholeCamera], up: str = "z") -> np.ndarray:
    """(3,) where on the floor the static false positive stands: seen whole by the first two cameras, at
    least 1 m from every walker's path (X (P, T, 15, 3)), the nearest such place to the walkers."""
    a, b, floor, seen = _floor_seen(cameras[:2], up)
    paths = X[:, :, 0][..., floor].reshape(-1, 2)
    gap = np.min(np.linalg.norm(np.stack([a, b], axis=-1)[:, :, None] - paths[None, None], axis=-1), axis=-1)
    fits = seen.all(axis=0) & (gap >= 1.0)
    if not fits.any():
        raise PriortrackError("the first two cameras share no floor 1 m from the walkers for a false positive")
    i = np.argmin(np.where(fits, gap, np.inf))
    place = np.zeros(3)
    place[floor] = a.flat[i], b.flat[i]
    return place


def composed(walkers: tuple[Walker, ...], seconds: float = SECONDS, fps: float = DATA_FPS,
             gap: float | None = None, centre: np.ndarray = np.zeros(3)) -> np.ndarray:
    """(P, T, 15, 3) the walkers' joints in a Z-up world: each walk turned to its heading (its own
    direction of travel first turned onto +x), shifted by its offset to its left and by ``centre``;
    ``gap`` replaces a two-person scene's offsets (each walker ``gap`` / 2 to their left: facing walkers
    pass ``gap`` apart)."""
    out = []
    for w in walkers:
        X = placed_walk(w.motion, "z", fps=fps, seconds=seconds)
        travel = X[-1, 0, :2] - X[0, 0, :2]
        angle = np.radians(w.heading) - np.arctan2(travel[1], travel[0])
        c, s = np.cos(angle), np.sin(angle)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        left = np.array([-np.sin(np.radians(w.heading)), np.cos(np.radians(w.heading)), 0.0])
        offset = w.offset if gap is None else gap / 2
        out.append(X @ R.T + offset * left + centre)
    return np.stack(out)


def hidden(X: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """(P, T, 15) bool: joint j of person p at frame t hidden in ``camera`` by a nearer person (module
    docstring: within BODY_RADIUS_M of a bone of theirs in the image, their mean depth nearer)."""
    P, T = X.shape[:2]
    uv = np.stack([camera.project(x)[0] for x in X])                                    # (P, T, 15, 2)
    R, t = camera.R.double().numpy(), camera.t.double().numpy()
    depth = (X @ R.T + t)[..., 2]                                                        # (P, T, 15)
    child = np.flatnonzero(EVAL15_PARENTS >= 0)
    out = np.zeros((P, T, 15), dtype=bool)
    for q in range(P):                                                                   # the occluder
        a, b = uv[q][:, EVAL15_PARENTS[child]], uv[q][:, child]                         # (T, 14, 2)
        radius = camera.fx * BODY_RADIUS_M / depth[q].mean(axis=1)                       # (T,) pixels
        for p in range(P):
            if p == q:
                continue
            point = uv[p][:, :, None]                                                    # (T, 15, 1, 2)
            ab = (b - a)[:, None]
            s = np.clip(((point - a[:, None]) * ab).sum(-1) / np.maximum((ab ** 2).sum(-1), 1e-9), 0, 1)
            gap = np.linalg.norm(point - (a[:, None] + s[..., None] * ab), axis=-1).min(axis=-1)   # (T, 15)
            nearer = depth[q].mean(axis=1)[:, None] < depth[p]
            out[p] |= (gap < radius[:, None]) & nearer
    return out


def scene_keypoints(X: np.ndarray, cameras: list[PinholeCamera], rng: np.random.Generator,
                    away: np.ndarray | None = None, up: str = "z") -> np.ndarray:
    """(C, T, P + 1, 25, 3) BODY_25B keypoints of the walkers X (P, T, 15, 3) and the static false
    positive (the last slot: the first walker's first pose, standing where :func:`false_positive_place`
    puts it in a world whose up is ``up``; first two cameras only), with the detector's errors, occlusions,
    and nothing of walker p at the frames where ``away`` (P, T) holds."""
    P, T = X.shape[:2]
    people = [detector_keypoints(X[p], cameras, rng) for p in range(P)]                 # each (C, T, 25, 3)
    out = np.zeros((len(cameras), T, P + 1, 25, 3))
    names = LAYOUTS["body25b"]
    for c, camera in enumerate(cameras):
        gone = hidden(X, camera)
        for p in range(P):
            kp = people[p][c].copy()
            for j, name in BODY25B_OF.items():
                kp[gone[p, :, j], names.index(name)] = 0.0
            if away is not None:
                kp[away[p]] = 0.0
            out[c, :, p] = kp
    k = "xyz".index(up)
    standing = X[0, 0] + false_positive_place(X, cameras, up) - np.where(np.arange(3) == k, 0.0, X[0, 0, 0])
    for c in range(min(2, len(cameras))):
        still = detector_keypoints(np.repeat(standing[None], T, axis=0), cameras[c:c + 1], rng)[0]
        still[..., 2] = np.where(still[..., 2] > 0, rng.uniform(0.3, 0.5, still.shape[:2]), 0.0)
        out[c, :, P] = still
    return out


def write_scene_openpose(keypoints: np.ndarray, folder: Path, rng: np.random.Generator) -> Path:
    """Write (C, T, N, K, 3) keypoints as OpenPose JSON, every person with a keypoint in each file in a
    shuffled order, ``person_id`` −1: ``folder/cam0<c+1>/scene_cam0<c+1>.<t:05d>.json``."""
    for c in range(keypoints.shape[0]):
        camera = folder / f"cam{c + 1:02d}"
        camera.mkdir(parents=True, exist_ok=True)
        for t in range(keypoints.shape[1]):
            people = [keypoints[c, t, n] for n in rng.permutation(keypoints.shape[2])
                      if (keypoints[c, t, n, :, 2] > 0).any()]
            (camera / f"scene_cam{c + 1:02d}.{t:05d}.json").write_text(json.dumps({"version": 1.3, "people": [
                {"person_id": [-1], "pose_keypoints_2d": p.ravel().round(3).tolist()} for p in people]}))
    return folder


def _median_gap(a: np.ndarray, b: np.ndarray) -> float:
    gap = np.linalg.norm(a[SHOULDERS_TO_ANKLES] - b[SHOULDERS_TO_ANKLES], axis=-1)
    gap = gap[np.isfinite(gap)]
    return float(np.median(gap)) if len(gap) else np.inf


def score_scene(result, truth: np.ndarray, present: np.ndarray, alone_mm: list[float] | None = None) -> dict:
    """The scores of the module docstring: ``result`` a SceneTrack, ``truth`` (P, T_frames, 15, 3) the
    walkers' joints in the detector's definitions at every detection frame, ``present`` (P, T_frames)
    where each is in view."""
    try:
        import motmetrics as mm
    except ImportError:
        raise PriortrackError("scoring scenes needs py-motmetrics: pip install 'priortrack[scenes]'") from None
    accumulator = mm.MOTAccumulator(auto_id=True)
    ticks = np.flatnonzero(result.frames >= 0)
    matches = np.zeros((truth.shape[0], len(result.person_ids)), dtype=int)
    lived = np.zeros(len(result.person_ids), dtype=int)
    for t in ticks:
        f = int(result.frames[t])
        walkers = [p for p in range(len(truth)) if present[p, f]]
        tracks = [q for q in range(len(result.person_ids)) if np.isfinite(result.joints[t, q]).all()]
        lived[tracks] += 1
        distance = np.array([[_median_gap(result.joints[t, q], truth[p, f]) for q in tracks] for p in walkers])
        for i, p in enumerate(walkers):
            for j, q in enumerate(tracks):
                matches[p, q] += distance[i, j] < MATCH_M
        accumulator.update(walkers, [int(result.person_ids[q]) for q in tracks],
                           np.where(distance < MATCH_M, distance, np.nan) if distance.size else
                           np.empty((len(walkers), len(tracks))))
    metrics = mm.metrics.create().compute(accumulator, metrics=["mota", "idf1", "num_switches",
                                                                "num_false_positives", "num_misses"], name="scene")
    row = {k: float(metrics[k].iloc[0]) for k in metrics.columns}
    row["false_tracks"] = int(sum(matches[:, q].max() < 0.5 * lived[q] for q in range(len(result.person_ids))))
    row["tracks"] = len(result.person_ids)
    per = []
    for p in range(len(truth)):
        q = int(np.argmax(matches[p])) if matches[p].max() > 0 else None
        if q is None:
            per.append({"pcp": 0.0, "mpjpe_mm": None})
            continue
        f = result.frames[ticks]
        seen = present[p, f] & np.isfinite(result.joints[ticks, q]).all(axis=(-1, -2))
        estimate, target = result.joints[ticks[seen], q], truth[p, f[seen]]
        error = 1000 * np.linalg.norm(estimate[:, SHOULDERS_TO_ANKLES] - target[:, SHOULDERS_TO_ANKLES], axis=-1)
        per.append({"pcp": pcp(estimate, target), "mpjpe_mm": float(np.nanmean(error))})
    for p, alone in enumerate(alone_mm or []):
        per[p]["alone_mm"] = alone
        per[p]["ratio_to_alone"] = None if per[p]["mpjpe_mm"] is None else per[p]["mpjpe_mm"] / alone
    row["people"] = per
    return row


def run_scene(scene: str, preset, seed: int = 0, gap: float | None = None, away_s: float = 0.8,
              alone: bool = True, cache=None, scene_config=None) -> dict:
    """One scene (module docstring) tracked by ``preset`` (its prior learned without the scene's walkers)
    with every person (as ``scene_config`` says: :class:`~priortrack.tracking.scene.SceneConfig`), scored; with
    ``alone``, each walker also tracked from their own detections."""
    from priortrack.experiments.people import fold_preset
    from priortrack.tracking.presets import load_preset
    from priortrack.tracking.person import TrackConfig, track_detections
    from priortrack.tracking.people import track_scene

    if scene not in SCENES:
        raise PriortrackError(f"unknown scene {scene!r}; scenes: {', '.join(SCENES)}")
    walkers = SCENES[scene]
    preset = fold_preset(load_preset(preset) if isinstance(preset, str) else preset,
                         tuple(sorted({w.person for w in walkers})))
    calibration = read_calibration(DEFAULT_CALIBRATION)
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    X = composed(walkers, gap=gap if scene == "passing" else None, centre=capture_centre(cameras))
    present = np.ones(X.shape[:2], dtype=bool)
    if scene == "return":
        middle, half = X.shape[1] // 2, int(round(away_s * DATA_FPS / 2))
        present[1, middle - half:middle + half] = False
    rng = np.random.default_rng(seed)
    keypoints = scene_keypoints(X, cameras, rng, ~present)
    truth = np.einsum("ij,ptjk->ptik", detector_map(), X)
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_scene_openpose(keypoints, Path(tmp) / "scene", rng)
        detections = read_scene_detections(folder, keypoints="body25b")
        result = track_scene(detections, calibration, preset, TrackConfig(fps=DATA_FPS, seed=seed, cache=cache),
                             scene_config)
        alone_mm = []
        for p in range(len(walkers)) if alone else ():
            own = write_openpose(keypoints[:, :, p], Path(tmp) / f"alone{p}")
            single = track_detections(read_detections(own, keypoints="body25b"), calibration, preset,
                                      TrackConfig(fps=DATA_FPS, seed=seed, cache=cache))
            f = single.frames
            ok = (f >= 0) & present[p, np.maximum(f, 0)]
            error = np.linalg.norm(single.joints[ok][:, SHOULDERS_TO_ANKLES] - truth[p, f[ok]][:, SHOULDERS_TO_ANKLES],
                                   axis=-1)
            alone_mm.append(float(1000 * np.nanmean(error)))
    row = score_scene(result, truth, present, alone_mm if alone else None)
    return {"scene": scene, "preset": preset.name, "seed": seed, "gap": gap, "seconds": result.seconds,
            "trained_without": sorted({w.person for w in walkers}), **row}


def eval_scenes(scenes=tuple(SCENES), presets=("ukf-real", "pf-lie"), seeds: int = 3,
                gaps=(0.3, 1.0), association: str = "joints", cache=None) -> dict:
    """Every scene × preset × seed (``passing`` once per gap), each :func:`run_scene` with who is who decided
    as ``association`` says (:class:`~priortrack.tracking.scene.SceneConfig`); the rows and a summary per scene
    and preset: mean MOTA and IDF1, identity switches and false tracks summed, the lowest PCP and the highest
    MPJPE ratio to the person tracked alone."""
    from priortrack.tracking.scene import SceneConfig

    scene_config = SceneConfig(association=association)
    unknown = [s for s in scenes if s not in SCENES]
    if unknown:
        raise PriortrackError(f"unknown scene {unknown[0]!r}; scenes: {', '.join(SCENES)}")
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise PriortrackError(f"seeds must be a whole number ≥ 1, got {seeds!r}")
    rows = []
    for scene in scenes:
        for gap in (gaps if scene == "passing" else (None,)):
            for preset in presets:
                for seed in range(seeds):
                    rows.append(run_scene(scene, preset, seed, gap, cache=cache, scene_config=scene_config))
                    log.info("%s%s %s seed %d: IDF1 %.3f, %d switches, %d false tracks", scene,
                             "" if gap is None else f" {gap} m", preset, seed, rows[-1]["idf1"],
                             rows[-1]["num_switches"], rows[-1]["false_tracks"])
    summary = {}
    for row in rows:
        key = f"{row['scene']}{'' if row['gap'] is None else ' ' + str(row['gap']) + ' m'} · {row['preset']}"
        summary.setdefault(key, []).append(row)
    table = {key: {"runs": len(group), "mota": float(np.mean([r["mota"] for r in group])),
                   "idf1": float(np.mean([r["idf1"] for r in group])),
                   "switches": int(sum(r["num_switches"] for r in group)),
                   "false_tracks": int(sum(r["false_tracks"] for r in group)),
                   "min_pcp": float(min(p["pcp"] for r in group for p in r["people"])),
                   "mpjpe_mm": float(np.mean([p["mpjpe_mm"] for r in group for p in r["people"]
                                              if p["mpjpe_mm"] is not None])),
                   "max_ratio_to_alone": float(max(p.get("ratio_to_alone") or np.inf for r in group
                                                   for p in r["people"]))}
             for key, group in summary.items()}
    return {"rows": rows, "table": table}
