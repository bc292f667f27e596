"""``priortrack eval shelf``: several real people, few cameras, manual 3D truth (Shelf, or Campus).

The benchmark stays where the user keeps it, a folder as 4D Association (Zhang et al., CVPR 2020) ships it:
``calibration.json`` (each camera's ``K``, ``RT``, ``imgSize``), ``gt.txt`` (:mod:`priortrack.data.shelf_truth`),
and every person's detections in any layout priortrack reads (``scene.npz`` there by default;
:func:`~priortrack.data.scene_detections.read_scene_detections`). For each subset of the cameras asked for,
the scene tracker follows every person with a preset from the detections alone
(:func:`~priortrack.tracking.people.track_scene`: no ids, no truth), and each annotated actor is scored:

- **PCP** over the eight limb parts (upper arms, forearms, thighs, shins;
  :func:`~priortrack.experiments.metrics.pcp`) and **MPJPE** over the twelve limb joints (shoulders to ankles),
  at every frame with the actor's truth, of the track nearest the actor there (the mean error of those joints:
  the field's convention); a frame with no track at all scores every part wrong.
- the same MPJPE over the joints and frames the oracle DLT triangulates (``mpjpe_beside_mm``: where two cameras show
  the joint; a person one camera sees has no DLT, and the tracker's estimate there is scored only in ``mpjpe_mm``),
- beside the **oracle DLT**: per frame and camera the detections are given to the actors by an optimal assignment
  on their distance to the truth's projection (the median over the limb joints, within :data:`ORACLE_GATE` of the
  actor's size in the image): the true association, which no tracker has; each actor's joints are then the
  confidence-weighted DLT of their detections (:func:`~priortrack.geometry.triangulation.triangulate`).
- with **one camera** (``--cameras 2``, ``--subsets 1``) there is no DLT (its scores are None), the world's up comes
  from the truth's people (:func:`truth_up`; one camera cannot find it), and what one view measures best is the
  root-relative MPJPE (``mpjpe_root_mm``: the mid-hips aligned), its depth resting on the body's assumed size;
- **identity switches**: per annotated actor (scored or not), the track an optimal assignment of actors to tracks
  gives them at a frame (median limb-joint distance within :data:`MATCH_M`) changes between two such frames;
- **false tracks**: tracks never so given to an annotated actor though most of their detections are annotated
  actors' (the oracle's): a second track of someone, or one made of different people's detections
  (:func:`false_tracks`; a track of someone the truth does not annotate there is not judged).
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from priortrack.body.ik import ANKLE_HEIGHT
from priortrack.data.calibration import Calibration, read_calibration
from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.data.scene_detections import SceneDetections, read_scene_detections
from priortrack.data.shelf_truth import read_shelf_truth
from priortrack.errors import PriortrackError
from priortrack.experiments.metrics import PCP_LIMB_PARTS, pcp
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.frames import up_from_person, up_vector
from priortrack.geometry.triangulation import triangulate
from priortrack.tracking.scene import SceneConfig, median_of_seen

log = logging.getLogger(__name__)

#: The twelve limb joints scored (eval15: shoulders, elbows, wrists, hips, knees, ankles).
LIMB_JOINTS = list(range(3, 15))
#: The hips (eval15), whose midpoint is the root of the root-relative MPJPE.
HIP_JOINTS = [9, 12]
#: The oracle gives an actor a detection whose limb joints lie within this fraction of the actor's size in the image
#: (the diagonal of the box around their projected limb joints; a standing person's height, about) of the truth's
#: projection (median over the joints): a detection of the actor, not of someone beside them.
ORACLE_GATE = 0.15
#: A track is an actor's at a frame when their limb joints lie within this median distance (metres).
MATCH_M = 0.3
#: The actors the field scores on Shelf and Campus.
SCORED_ACTORS = (0, 1, 2)
#: Shelf's and Campus's frame rate as the field takes it (the source does not state it).
SHELF_FPS = 25.0


def camera_subsets(count: int, cameras: str | None = None, sizes: list[int] | None = None) -> list[tuple[int, ...]]:
    """The subsets of a rig's ``count`` cameras to evaluate: ``cameras`` "0,2,4" (indices in the calibration's
    order) is one; ``sizes`` [2, 3] every subset of 2 and of 3; neither: all of them."""
    if cameras is not None and sizes:
        raise PriortrackError("give --cameras or --subsets, not both")
    if cameras is not None:
        try:
            chosen = tuple(int(c) for c in str(cameras).split(","))
        except ValueError:
            chosen = ()
        if not chosen or len(set(chosen)) != len(chosen) or not all(0 <= c < count for c in chosen):
            raise PriortrackError(f"--cameras {cameras}: give one or more different camera indices from 0 to "
                                  f"{count - 1}, comma-separated")
        return [tuple(sorted(chosen))]
    if sizes:
        bad = [k for k in sizes if not 1 <= k <= count]
        if bad:
            raise PriortrackError(f"--subsets {bad[0]}: subsets of 1 to {count} cameras")
        return [c for k in sorted(set(sizes)) for c in itertools.combinations(range(count), k)]
    return [tuple(range(count))]


def benchmark_files(directory: str | Path, detections: str | Path | None = None) -> tuple[Path, Path, Path]:
    """The calibration, truth and detections of a benchmark folder (module docstring), checked to exist."""
    directory = Path(directory)
    if not directory.is_dir():
        raise PriortrackError(f"{directory} is not a folder: give the folder that holds the benchmark's "
                              f"calibration.json and gt.txt")
    found = directory / "calibration.json", directory / "gt.txt"
    for path in found:
        if not path.is_file():
            raise PriortrackError(f"{directory} has no {path.name} (the benchmark as 4D Association ships it)")
    detections = Path(detections) if detections is not None else directory / "scene.npz"
    if not detections.exists():
        raise PriortrackError(f"detections {detections} do not exist: give them (--detections), every person of "
                              f"every camera (an OpenPose folder of camera folders, COCO results or an .npz)")
    return found[0], found[1], detections


def read_benchmark(directory: str | Path, detections: str | Path | None = None, actors=None):
    """The benchmark folder's calibration, every annotated actor's truth (T, A_all, 15, 3) in the eval15 layout,
    the indices of the actors scored among them (``actors``: ids; None: :data:`SCORED_ACTORS` where annotated, else
    every one) with their ids, and the detections (their frames checked against the truth's)."""
    calibration_path, truth_path, detections_path = benchmark_files(directory, detections)
    calibration = read_calibration(calibration_path)
    truth = read_shelf_truth(truth_path)
    if actors is None:
        actors = [a for a in SCORED_ACTORS if a in truth.ids] or truth.ids.tolist()
    missing = [a for a in actors if a not in truth.ids]
    if missing:
        raise PriortrackError(f"{truth_path}: no actor {missing[0]} (actors: {', '.join(map(str, truth.ids))})")
    scene = read_scene_detections(detections_path)
    if not ((scene.frames >= 0) & (scene.frames < len(truth.joints))).any():
        raise PriortrackError(f"{detections_path}: none of its frames ({scene.frames[0]} …) is one of the truth's "
                              f"0 … {len(truth.joints) - 1}")
    return (calibration, truth.eval15(), [int(np.flatnonzero(truth.ids == a)[0]) for a in actors],
            [int(a) for a in actors], scene)


def truth_up(truth: np.ndarray) -> np.ndarray:
    """(3,) the world's up from the truth's people (T, A, 15, 3) (:func:`~priortrack.geometry.frames.up_from_person`,
    the neck the mid-shoulders where the truth has none): a property of the benchmark's world that several cameras find
    from the detections and one camera cannot."""
    people = truth.reshape(-1, *truth.shape[2:]).copy()
    people[:, 1] = np.where(np.isfinite(people[:, 1]), people[:, 1], 0.5 * (people[:, 3] + people[:, 6]))
    return up_from_person(people)[0]


def truth_floor(truth: np.ndarray, up: np.ndarray | str) -> float:
    """The floor's level along ``up`` (an axis name or (3,)) from the truth's people (T, A, 15, 3): the median over
    frames and people of their lower ankle's, less :data:`~priortrack.body.ik.ANKLE_HEIGHT` (Shelf's annotated ankles
    lie 0.01–0.06 m *below* its origin: the floor is not at 0); what a one-camera person's height is measured from
    (:mod:`~priortrack.tracking.floor_height`), like the up a property of the world that one camera cannot find."""
    axis = np.asarray(up_vector(up), dtype=np.float64)
    lower = np.nanmin(truth[:, :, [11, 14]] @ axis, axis=-1)
    return float(np.nanmedian(lower) - ANKLE_HEIGHT)


def oracle_slots(cameras: list[PinholeCamera], uv: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(C, T, A) the detection slot the true association gives actor a in camera c at frame t, −1 where none
    (module docstring): uv (C, T, N, 15, 2) the detections' eval15 pixels, truth (T, A, 15, 3)."""
    C, T = uv.shape[:2]
    slots = np.full((C, T, truth.shape[1]), -1, dtype=int)
    limbs = truth[:, :, LIMB_JOINTS]
    for c, camera in enumerate(cameras):
        projected = camera.project(limbs)[0]                                            # (T, A, 12, 2)
        size = np.linalg.norm(np.fmax.reduce(projected, axis=2) - np.fmin.reduce(projected, axis=2), axis=-1)  # (T, A)
        gap = np.linalg.norm(projected[:, :, None] - uv[c][:, None, :, LIMB_JOINTS], axis=-1)   # (T, A, N, 12)
        cost = median_of_seen(gap, np.isfinite(gap)) / np.where(np.isfinite(size), size, np.nan)[..., None]
        cost = np.where(np.isfinite(cost), cost, np.inf)                                # (T, A, N), inf: none
        for t in range(T):
            rows, cols = linear_sum_assignment(np.where(cost[t] < ORACLE_GATE, cost[t], 1e12))
            for a, n in zip(rows, cols):
                if cost[t, a, n] < ORACLE_GATE:
                    slots[c, t, a] = n
    return slots


def oracle_dlt(cameras: list[PinholeCamera], uv: np.ndarray, confidence: np.ndarray, slots: np.ndarray) -> np.ndarray:
    """(T, A, 15, 3) each actor's confidence-weighted DLT of the detections the true association gives them
    (``slots`` (C, T, A), :func:`oracle_slots`), NaN where fewer than two cameras show a joint: uv (C, T, N, 15, 2)
    eval15 pixels, confidence (C, T, N, 15)."""
    taken = np.take_along_axis(uv, np.maximum(slots, 0)[..., None, None], axis=2)      # (C, T, A, 15, 2)
    weight = np.take_along_axis(confidence, np.maximum(slots, 0)[..., None], axis=2)   # (C, T, A, 15)
    missing = (slots < 0)[..., None] | ~np.isfinite(taken).all(-1)
    return triangulate(cameras, np.where(missing[..., None], np.nan, taken), np.where(missing, 0.0, weight))


def false_tracks(taken: np.ndarray, oracle: np.ndarray, given: np.ndarray) -> np.ndarray:
    """(P,) whether each track is false: never given to an annotated actor (``given`` (T, A) the track of each actor
    at each frame, :func:`identities`), though at least half of its detections (``taken`` (T, C, P) its detection slot
    per frame and camera, −1 none) are annotated actors' (``oracle`` (C, T, A), :func:`oracle_slots`): a second track
    of someone, or one made of different people's detections. A track whose detections are nobody's the truth
    annotates (a person walking by unannotated) is not judged."""
    mine = taken >= 0                                                                   # (T, C, P)
    theirs = (taken[..., None] == oracle.transpose(1, 0, 2)[:, :, None, :]).any(-1) & mine
    return np.array([not (given == p).any() and 0 < mine[..., p].sum() <= 2 * theirs[..., p].sum()
                     for p in range(taken.shape[-1])], dtype=bool)


def nearest_tracks(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(T, A, 15, 3) per frame the track of estimate (T, P, 15, 3) (NaN where a track is absent) nearest each
    actor of truth (T, A, 15, 3) by the mean error of the limb joints they share; NaN where no track is there."""
    if not estimate.shape[1]:
        return np.full(truth.shape, np.nan)
    gap = np.linalg.norm(estimate[:, None, :, LIMB_JOINTS] - truth[:, :, None, LIMB_JOINTS], axis=-1)   # (T, A, P, 12)
    seen = np.isfinite(gap)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(seen.any(-1), np.where(seen, gap, 0.0).sum(-1) / seen.sum(-1), np.inf)        # (T, A, P)
    best = np.argmin(mean, axis=-1)                                                                     # (T, A)
    there = np.isfinite(np.take_along_axis(mean, best[..., None], -1)[..., 0])
    return np.where(there[..., None, None], np.take_along_axis(estimate, best[..., None, None], axis=1), np.nan)


def identities(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(T, A) the track (index into estimate's P) given to each actor at each frame by an optimal assignment on
    the median limb-joint distance within :data:`MATCH_M`, −1 where none: estimate (T, P, 15, 3), truth (T, A, 15, 3)."""
    T, A = truth.shape[:2]
    given = np.full((T, A), -1, dtype=int)
    if not estimate.shape[1]:
        return given
    gap = np.linalg.norm(estimate[:, None, :, LIMB_JOINTS] - truth[:, :, None, LIMB_JOINTS], axis=-1)   # (T, A, P, 12)
    cost = median_of_seen(gap, np.isfinite(gap))
    for t in range(T):
        rows, cols = linear_sum_assignment(np.where(cost[t] < MATCH_M, cost[t], 1e12))
        for a, q in zip(rows, cols):
            if cost[t, a, q] < MATCH_M:
                given[t, a] = q
    return given


def switches(given: np.ndarray) -> np.ndarray:
    """(A,) per actor, how often the track given them (:func:`identities`, (T, A)) changes between two frames
    where one is given."""
    return np.array([int((np.diff(column[column >= 0]) != 0).sum()) for column in given.T], dtype=int)


def score(estimate: np.ndarray, truth: np.ndarray, frames: np.ndarray, beside: np.ndarray | None = None) -> list[dict]:
    """Per actor, at ``frames`` (T,) bool, the scores of the module docstring of their estimate (T, A, 15, 3)
    (the nearest track's, :func:`nearest_tracks`, or the oracle DLT's; NaN where none) against truth
    (T, A, 15, 3): PCP % of the limb parts, MPJPE mm of the limb joints and per limb joint (where both are known),
    the root-relative MPJPE (``mpjpe_root_mm``: each pose moved to put its mid-hips on the origin; the other ten limb
    joints: one camera's measure, whose depth is the body's size), and the frames scored; given ``beside``
    (T, A, 15, 3), another estimate (the oracle DLT's), also
    ``mpjpe_beside_mm``: the MPJPE over the joints and frames that one has (where DLT triangulates: two cameras show
    the joint), and ``per_joint_beside_mm`` each limb joint's over the frames that one has it (side by side with it:
    a joint the DLT lacks is one no two cameras show, where the tracker's error is larger)."""
    rows = []
    for a in range(truth.shape[1]):
        annotated = frames & np.isfinite(truth[:, a, LIMB_JOINTS]).all(-1).any(-1)
        X, Y = estimate[annotated, a], truth[annotated, a]
        error = 1000 * np.linalg.norm(X[:, LIMB_JOINTS] - Y[:, LIMB_JOINTS], axis=-1)              # (F, 12)
        known = np.isfinite(error)
        hips = [LIMB_JOINTS.index(j) for j in HIP_JOINTS]
        aligned = 1000 * np.linalg.norm((X[:, LIMB_JOINTS] - X[:, HIP_JOINTS].mean(1, keepdims=True)) -
                                        (Y[:, LIMB_JOINTS] - Y[:, HIP_JOINTS].mean(1, keepdims=True)), axis=-1)
        aligned[:, hips] = np.nan                                    # the hips' own alignment is no error
        row = {"pcp": pcp(X, Y, PCP_LIMB_PARTS), "mpjpe_mm": _mean(error[known]),
               "mpjpe_root_mm": _mean(aligned[np.isfinite(aligned)]),
               "per_joint_mm": {EVAL15_NAMES[j]: _mean(error[known[:, k], k]) for k, j in enumerate(LIMB_JOINTS)},
               "frames": int(annotated.sum())}
        if beside is not None:
            theirs = known & np.isfinite(beside[annotated, a][:, LIMB_JOINTS]).all(-1)
            row["mpjpe_beside_mm"] = _mean(error[theirs])
            row["per_joint_beside_mm"] = {EVAL15_NAMES[j]: _mean(error[theirs[:, k], k])
                                          for k, j in enumerate(LIMB_JOINTS)}
        rows.append(row)
    return rows


def _mean(values: np.ndarray) -> float | None:
    return float(values.mean()) if len(values) else None


def matched_cameras(scene: SceneDetections, calibration: Calibration) -> list[int]:
    """The calibration camera (index) of each detection camera: by name where every detection camera is named as
    one of the calibration's (Shelf's "0" … "4"), else in order."""
    names = [c.name for c in calibration.cameras]
    if set(scene.camera_names) <= set(names):
        return [names.index(n) for n in scene.camera_names]
    if len(scene.camera_names) != len(names):
        raise PriortrackError(f"{scene.source}: {len(scene.camera_names)} detection cameras "
                              f"({', '.join(scene.camera_names)}) for the calibration's {len(names)} "
                              f"({', '.join(names)}), not named alike")
    return list(range(len(names)))


def eval_shelf(directory: str | Path, presets=("ukf-real",), cameras: str | None = None, sizes: list[int] | None = None,
               detections: str | Path | None = None, fps: float = SHELF_FPS, actors=None, seed: int = 0,
               workers: int | None = None, min_confidence: float = 0.3, cache=None, association: str = "auto") -> dict:
    """Every preset on every subset of the benchmark's cameras asked for (:func:`camera_subsets`), scored as the
    module docstring says beside the oracle DLT of the same cameras; ``actors``: the annotated actors scored (None:
    :data:`SCORED_ACTORS` where annotated, else every one); ``association``: who is who decided as
    :class:`~priortrack.tracking.scene.SceneConfig` says. Returns {"rows": one per subset and preset
    (cameras, preset, per actor the tracker's and the DLT's scores, switches, false tracks, tracks, seconds),
    "actors", "frames"}."""
    from priortrack.tracking.people import track_scene
    from priortrack.tracking.person import TrackConfig, fitted_once
    from priortrack.tracking.presets import load_preset

    scene_config = SceneConfig(association=association)
    calibration, everyone, scored, actors, scene = read_benchmark(directory, detections, actors)
    truth = everyone[:, scored]                                                        # (T, A, 15, 3)
    subsets = camera_subsets(len(calibration.cameras), cameras, sizes)
    presets = [load_preset(p) for p in presets]
    of_calibration = matched_cameras(scene, calibration)
    frames = np.zeros(len(truth), dtype=bool)
    frames[scene.frames[(scene.frames >= 0) & (scene.frames < len(truth))]] = True
    uv, confidence = scene.eval15(min_confidence)
    up = calibration.up if calibration.up is not None else truth_up(everyone)
    floor = truth_floor(everyone, up)
    at = np.flatnonzero((scene.frames >= 0) & (scene.frames < len(truth)))            # detection frames with truth
    rows = []
    for subset in subsets:
        missing = [c for c in subset if c not in of_calibration]
        if missing:
            raise PriortrackError(f"{scene.source} has no detections of the calibration's camera "
                                  f"{calibration.cameras[missing[0]].name}")
        own = [of_calibration.index(c) for c in subset]
        world = [PinholeCamera.from_calibration(calibration.cameras[c]) for c in subset]
        seen, weight = uv[own][:, at], confidence[own][:, at]
        slots = oracle_slots(world, seen, everyone[scene.frames[at]])                  # (C, F, every actor)
        dlt = np.full(truth.shape, np.nan)
        if len(subset) > 1:
            dlt[scene.frames[at]] = oracle_dlt(world, seen, weight, slots[..., scored])
            oracle = score(dlt, truth, frames)
        else:                                                           # one camera: no DLT
            oracle = [{"pcp": None, "mpjpe_mm": None, "mpjpe_root_mm": None, "frames": row["frames"],
                       "per_joint_mm": dict.fromkeys(row["per_joint_mm"])} for row in score(dlt, truth, frames)]
        part = replace(scene, camera_names=tuple(scene.camera_names[c] for c in own), keypoints=scene.keypoints[own])
        config = TrackConfig(fps=fps, seed=seed, min_confidence=min_confidence, cache=cache,
                             up=up if len(subset) == 1 else None, floor=floor,
                             camera_map={scene.camera_names[o]: calibration.cameras[c].name for o, c in zip(own, subset)})
        for preset in presets:
            fitted_once(preset, cache)                                     # the prior's fit is not the run's time
            result = track_scene(part, calibration, preset, config, scene_config, workers=workers)
            estimate = np.full((len(truth), len(result.person_ids), 15, 3), np.nan)
            ticks = np.flatnonzero((result.frames >= 0) & (result.frames < len(truth)))
            estimate[result.frames[ticks]] = result.joints[ticks]
            given = identities(estimate, everyone)
            tracker = score(nearest_tracks(estimate, truth), truth, frames, dlt)
            kept = [result.association.person_ids.tolist().index(pid) for pid in result.person_ids]
            false = result.person_ids[false_tracks(result.association.slots[at][:, :, kept], slots,
                                                   given[scene.frames[at]])].tolist()
            rows.append({"cameras": [calibration.cameras[c].name for c in subset], "preset": preset.name,
                         "actors": [{"actor": int(a), **mine, "dlt": dlt_row} for a, mine, dlt_row in
                                    zip(actors, tracker, oracle)],
                         "switches": int(switches(given).sum()), "false_tracks": false,
                         "tracks": int(len(result.person_ids)), "seconds": float(result.seconds)})
            log.info("cameras %s, %s: PCP %s (DLT %s), %d switches, %d false tracks, %.1f s",
                     ",".join(rows[-1]["cameras"]), preset.name,
                     " / ".join(f"{r['pcp']:.1f}" for r in tracker),
                     " / ".join("—" if r["pcp"] is None else f"{r['pcp']:.1f}" for r in oracle),
                     rows[-1]["switches"], len(false), result.seconds)
    return {"rows": rows, "actors": actors, "frames": int(frames.sum()), "fps": fps, "detections": scene.source}


#: The lags (frames) at which :func:`diagnose` measures the DLT error's autocorrelation, and the width (frames) of
#: the centred moving average that bounds what smoothing the DLT could gain.
LAGS, SMOOTHING_WIDTH = (1, 2, 4, 8), 5


def diagnose(directory: str | Path, cameras: str | None = None, detections: str | Path | None = None,
             fps: float = SHELF_FPS, actors=None, min_confidence: float = 0.3) -> dict:
    """What per-frame triangulation's error on the benchmark is made of (issue 58, item 2), for one subset of its
    cameras (:func:`camera_subsets`), over the oracle DLT of the actors (:func:`oracle_dlt`). Per limb joint:

    - ``rms_mm``: the RMS error; ``bias_mm``: its mean in each actor's body frame (origin the mid-hips, axes the
      hips' line and the forward direction on the floor, and up), a bias no filter removes (the annotators'
      joints are not the detector's keypoints); ``bias_share``: |bias|² / RMS²;
    - ``autocorrelation``: of the error less its bias, at :data:`LAGS` frames (0: white noise, which a temporal
      model averages out; near 1: errors that last, which it cannot);
    - ``smoothed_rms_mm``: the RMS of the DLT averaged over :data:`SMOOTHING_WIDTH` centred frames, a bound on what
      smoothing alone gains;
    - ``body_rms_mm``: the RMS of the tracker's body (the template scaled to the actor, CMU subject 35's, through
      the detector's joint definitions) fitted by inverse kinematics to the DLT, each frame; and ``truth_body_rms_mm``
      fitted to the truth itself (what the body model cannot represent);

    and over the whole: ``swapped_share`` (the camera-detections whose left–right mirror lies nearer the truth's
    projection), ``truth_still_share`` per joint (frames where the annotation did not move at all from the last),
    and ``tick_offset_mm`` (how far the joints move in the time between a detection frame and the 30 fps tick that
    consumes it: :func:`~priortrack.tracking.person.schedule`)."""
    from priortrack.body.fk import joint_positions
    from priortrack.body.ik import fitted_skeleton, inverse_kinematics
    from priortrack.data.bundled import cmu_skeleton
    from priortrack.data.keypoints import detector_map
    from priortrack.geometry.frames import to_y_up, up_from_person
    from priortrack.tracking.person import schedule
    from priortrack.tracking.scene import MIRRORED

    calibration, everyone, scored, actors, scene = read_benchmark(directory, detections, actors)
    (subset,) = camera_subsets(len(calibration.cameras), cameras)
    own = [matched_cameras(scene, calibration).index(c) for c in subset]
    world = [PinholeCamera.from_calibration(calibration.cameras[c]) for c in subset]
    at = np.flatnonzero((scene.frames >= 0) & (scene.frames < len(everyone)))
    uv, confidence = scene.eval15(min_confidence)
    everyone = everyone[scene.frames[at]]                                              # (F, every actor, 15, 3)
    truth = everyone[:, scored]                                                        # (F, A, 15, 3)
    uv, confidence = uv[own][:, at], confidence[own][:, at]
    slots = oracle_slots(world, uv, everyone)[..., scored]
    dlt = oracle_dlt(world, uv, confidence, slots)
    error = dlt - truth
    left, right = truth[..., 9, :], truth[..., 12, :]
    standing = truth.reshape(-1, 15, 3).copy()
    standing[:, 1] = 0.5 * (standing[:, 3] + standing[:, 6])                  # the truth has no neck: mid-shoulders
    up = up_from_person(standing)[0]
    side = (left - right) - ((left - right) @ up)[..., None] * up
    side /= np.linalg.norm(side, axis=-1, keepdims=True)
    frame = np.stack([side, np.cross(up, side), np.broadcast_to(up, side.shape)], axis=-2)      # (F, A, 3, 3) rows
    local = np.einsum("faij,fakj->faki", frame, error)                                  # (F, A, 15, 3)
    A = to_y_up(up)
    M = detector_map()
    body, truth_body = np.full(dlt.shape, np.nan), np.full(dlt.shape, np.nan)
    for a in range(len(actors)):
        for source, out in ((dlt, body), (truth, truth_body)):
            X = source[:, a] @ A.T                                                          # Y-up, as the tracker's
            fit = np.isfinite(X).all(-1).sum(-1) >= 6
            if fit.sum() < 2:
                continue
            skeleton = fitted_skeleton(cmu_skeleton("35"), X[fit], M)
            motion = inverse_kinematics(X[fit], fps, joint_map=M, skeleton=skeleton)
            out[fit, a] = np.einsum("jk,tkd->tjd", M, joint_positions(motion)) @ A
    smoothed = _moving_average(dlt, SMOOTHING_WIDTH)
    rows = {}
    for j in LIMB_JOINTS:
        e = local[:, :, j]                                                                 # (F, A, 3)
        seen = np.isfinite(e).all(-1)
        bias = np.nanmean(np.where(seen[..., None], e, np.nan).reshape(-1, 3), axis=0)
        rms = _rms(e)
        centred = np.where(seen[..., None], e - bias, np.nan)
        rows[EVAL15_NAMES[j]] = {"rms_mm": 1000 * rms, "bias_mm": 1000 * float(np.linalg.norm(bias)),
                                 "bias_share": float(bias @ bias / rms ** 2),
                                 "autocorrelation": [_autocorrelation(centred, lag) for lag in LAGS],
                                 "smoothed_rms_mm": 1000 * _rms(smoothed[:, :, j] - truth[:, :, j]),
                                 "body_rms_mm": 1000 * _rms(body[:, :, j] - truth[:, :, j]),
                                 "truth_body_rms_mm": 1000 * _rms(truth_body[:, :, j] - truth[:, :, j]),
                                 "truth_still_share": float(np.mean(np.linalg.norm(np.diff(truth[:, :, j], axis=0),
                                                                                   axis=-1)[np.isfinite(
                                     np.diff(truth[:, :, j], axis=0)).all(-1)] < 1e-4))}
    swapped = []
    for c, camera in enumerate(world):
        projected = camera.project(truth)[0]                                              # (F, A, 15, 2)
        mine = np.take_along_axis(uv[c], np.maximum(slots[c], 0)[..., None, None], axis=1)   # (F, A, 15, 2)
        gap = [median_of_seen(np.linalg.norm(m[..., LIMB_JOINTS, :] - projected[..., LIMB_JOINTS, :], axis=-1),
                              np.isfinite(m[..., LIMB_JOINTS, 0]) & np.isfinite(projected[..., LIMB_JOINTS, 0]))
               for m in (mine, mine[..., MIRRORED, :])]
        swapped.append((gap[1] < gap[0])[slots[c] >= 0])
    index = schedule(scene.frames[at], fps, 30.0)
    offset = np.full(len(at), np.nan)
    offset[index[index >= 0]] = np.abs(np.flatnonzero(index >= 0) / 30.0 - (scene.frames[at][index[index >= 0]]
                                                                             - scene.frames[at][0]) / fps)
    speed = np.linalg.norm(np.gradient(truth, axis=0), axis=-1) * fps                       # (F, A, 15) m/s
    moved = (speed * offset[:, None, None])[..., LIMB_JOINTS]
    summary = {key: float(np.mean([r[key] for r in rows.values()])) for key in
               ("rms_mm", "bias_mm", "bias_share", "smoothed_rms_mm", "body_rms_mm", "truth_body_rms_mm")}
    return {"cameras": [calibration.cameras[c].name for c in subset], "actors": actors,
            "joints": rows, "summary": summary,
            "swapped_share": float(np.concatenate(swapped).mean()) if swapped else float("nan"),
            "tick_offset_mm": {"mean": 1000 * float(np.nanmean(moved)), "p95": 1000 * float(np.nanpercentile(moved, 95))}}


def _rms(e: np.ndarray) -> float:
    """The root mean square of the finite vectors of e (..., 3)."""
    seen = np.isfinite(e).all(-1)
    return float(np.sqrt((e[seen] ** 2).sum(-1).mean())) if seen.any() else float("nan")


def _autocorrelation(e: np.ndarray, lag: int) -> float:
    """The correlation of e (F, A, 3) with itself ``lag`` frames on, over every actor, coordinate and frame pair
    where both are finite."""
    a, b = e[:-lag], e[lag:]
    both = np.isfinite(a).all(-1) & np.isfinite(b).all(-1)
    a, b = a[both], b[both]
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum())) if len(a) > 1 else float("nan")


def _moving_average(X: np.ndarray, width: int) -> np.ndarray:
    """X (F, ...) averaged over the ``width`` frames centred on each (the finite ones), NaN where X is."""
    half = width // 2
    padded = np.concatenate([np.full((half,) + X.shape[1:], np.nan), X, np.full((half,) + X.shape[1:], np.nan)])
    window = np.stack([padded[k:k + len(X)] for k in range(width)])
    seen = np.isfinite(window)
    with np.errstate(invalid="ignore"):
        mean = np.where(seen, window, 0.0).sum(0) / seen.sum(0)
    return np.where(np.isfinite(X), mean, np.nan)
