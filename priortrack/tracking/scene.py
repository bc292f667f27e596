"""The scene tracker: every person of a multi-camera recording, each with an identity that holds.

Per frame, as Stone Soup's ``MultiTargetTracker`` steps (associate; update or predict; delete; initiate):

1. **predict** every live track's joints (:class:`~priortrack.tracking.motion.JointKalman`);
2. **associate** (:class:`PredictionAssociator`): in each camera, every track's predicted joints are
   projected with their spread S (2 × 2 a joint, in undistorted normalised image coordinates); a
   detection's cost for a track is the median over the joints both have of the Mahalanobis distance
   eᵀ S⁻¹ e (e the residual, S with the detection's confidence in R), over as few as one joint (a person
   half hidden behind another shows a few); an optimal assignment (Hungarian,
   :func:`scipy.optimize.linear_sum_assignment`) with a "not this track" option at the gate's cost, so no
   detection is forced onto a track;
3. **update** each track with its detections, camera by camera (a track with none is predicted only);
4. **delete** (:class:`MissedFramesDeleter`): a track no camera has seen for ``death_s`` seconds ends
   (kept, for re-identification);
5. **initiate** (:class:`ProposalInitiator`): the detections left over are matched across cameras
   (:func:`~priortrack.tracking.association.associate`) into 3D proposals; a proposal seen by
   ``birth_views`` cameras starts a tentative person, confirmed once proposals follow it for
   ``birth_s`` seconds (each within :data:`FOLLOW_M` of the last); a confirmed person whose bone lengths
   (:func:`bone_lengths`, a signature; :func:`signature_gap`) and position fit a person who ended takes that
   person's id back, else a new one.

Two views alone triangulate anything that one epipolar geometry allows (a static false positive seen by
two cameras is a consistent "person"); a third view checks it, hence ``birth_views`` = 3 where the rig
has three cameras or more. A track, once born, continues on any number of views. A rig of one camera has
no triangulation: each leftover detection is placed at the depth its size says
(:mod:`~priortrack.tracking.single_view`) and confirmed as above; its people have no bone signature (the
placement has a nominal body's size), so one who leaves and comes back is a new id.

:meth:`SceneTracker.run` tracks a whole :class:`~priortrack.data.scene_detections.SceneDetections` and
gives a :class:`SceneAssociation`: which detection slot is whose, per frame and camera, and each person's
joints as the motion model has them. Each person's body is then tracked by a filter preset from their own
detections (:mod:`priortrack.tracking.people`), or every person's filter steps with the others and decides each
tick's detections again (:mod:`priortrack.tracking.reassociation`, with :func:`prediction_costs` and
:func:`gated_assignment`).
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from priortrack.data.detections import Detections
from priortrack.data.eval15 import EVAL15_MIRROR_PAIRS, EVAL15_PARENTS
from priortrack.data.scene_detections import SceneDetections
from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera
from priortrack.tracking import single_view
from priortrack.geometry.triangulation import dlt_normalised
from priortrack.tracking.association import (MAX_BODY_SCALE, PAIR_GATE_M, associate, body_scale, median_distance,
                                             normalised, pair_distances)
from priortrack.tracking.motion import JointKalman, View

log = logging.getLogger(__name__)

#: The χ² quantile (2 degrees of freedom, 99.9 %) a detection's median joint distance must be under.
GATE = 13.8
#: How each tick's detections are finally decided (:class:`SceneConfig`).
ASSOCIATIONS = ("auto", "joints", "filter")
#: A rig of this many cameras or fewer decides each tick through the people's filters by default (:class:`SceneConfig`).
FEW_VIEWS = 3
#: A tentative person's next proposal lies within this median joint distance (metres) of the last.
FOLLOW_M = 0.3
#: A returning person's bone lengths within this median relative difference of an ended person's are theirs.
REID_BONES = 0.1
#: … and their pelvis within this distance (metres) plus 1.5 m/s times the time away; the two signatures compared
#: over the bones both measured, at least this many of the 14.
REID_M, REID_MIN_BONES = 1.0, 7
#: A track whose bones' median is over this (twice an adult's, 0.25–0.3 m in the eval15 layout) is no one
#: (:func:`no_body`).
MAX_MEDIAN_BONE_M = 0.6


def signature_gap(new: np.ndarray, old: np.ndarray) -> float:
    """The median over the bones both signatures (14,) measure of |new − old| / old; inf where fewer than
    :data:`REID_MIN_BONES` are. A median, not a mean: a limb that two views mismatched (an arm's keypoints of one camera
    given to the other arm: a forearm of a metre) must not hide the other dozen bones."""
    both = np.isfinite(new) & np.isfinite(old)
    if both.sum() < REID_MIN_BONES:
        return np.inf
    return float(np.median(np.abs(new[both] - old[both]) / old[both]))


def no_body(signature: np.ndarray | None) -> bool:
    """Whether a track's signature (14,) (:attr:`Track.signature`) is no one's: the median of its bones, measured over
    at least :data:`REID_MIN_BONES` of them, over :data:`MAX_MEDIAN_BONE_M` (two cameras' detections of different
    people paired into one "person" place its joints metres apart; one mismatched limb does not move the median)."""
    if signature is None or np.isfinite(signature).sum() < REID_MIN_BONES:
        return False
    return bool(np.nanmedian(signature) > MAX_MEDIAN_BONE_M)


def bone_lengths(joints: np.ndarray) -> np.ndarray:
    """(..., 14) lengths, metres, of the eval15 bones (each joint to its parent) of joints (..., 15, 3)."""
    child = np.flatnonzero(EVAL15_PARENTS >= 0)
    return np.linalg.norm(joints[..., child, :] - joints[..., EVAL15_PARENTS[child], :], axis=-1)


@dataclass
class SceneConfig:
    """How the scene tracker decides (module docstring).

    Attributes:
        pair_gate_m: the cross-view pair gate, metres (:mod:`~priortrack.tracking.association`).
        gate: a detection's cost gate for a track (median squared Mahalanobis distance of its joints).
        birth_s: seconds of proposals that confirm a new person.
        birth_views: cameras a proposal needs to start a person (capped at the rig's camera count).
        death_s: seconds unseen after which a person's track ends.
        association: "joints": the scene tracker's decisions are kept and each person's filter runs on their own
            (in worker processes, side by side); "filter": each tick's detections are decided again through every
            person's own filter (:mod:`~priortrack.tracking.reassociation`), the people tracked in lockstep in this
            process; "auto" (the default, :meth:`decided_by`): "filter" on a rig of :data:`FEW_VIEWS` cameras or
            fewer, else "joints". Measured: on four cameras (``eval scenes``, one seed) both give the same scores
            (ukf-real, pf-lie: 0 switches, 0 false tracks, IDF1 1.000), "filter" in 1.4× the time (one process);
            on two and three of Shelf's real cameras (``eval shelf``, ukf-real) "filter" holds people the joint
            model loses (a joint seen by one camera drifts along its ray; a body does not): cameras 0, 1, 4 actor 0
            151 → 59 mm, 0, 1 actor 0 211 → 63, 1, 3, 4 75 → 58, the other subsets within a few mm
            (docs/results/2026-11-28-shelf.md).
    """

    pair_gate_m: float = PAIR_GATE_M
    gate: float = GATE
    birth_s: float = 0.1
    birth_views: int = 3
    death_s: float = 0.5
    association: str = "auto"

    def decided_by(self, cameras: int) -> str:
        """"joints" or "filter": the association a rig of ``cameras`` cameras gets (``association``, where "auto":
        "filter" on :data:`FEW_VIEWS` cameras or fewer)."""
        if self.association != "auto":
            return self.association
        return "filter" if cameras <= FEW_VIEWS else "joints"

    def __post_init__(self):
        for name in ("pair_gate_m", "gate", "birth_s", "death_s"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not np.isfinite(value) or value < 0:
                raise PriortrackError(f"scene setting {name} must be a number ≥ 0, got {value!r}")
        if isinstance(self.birth_views, bool) or not isinstance(self.birth_views, int) or self.birth_views < 2:
            raise PriortrackError(f"scene setting birth_views must be a whole number ≥ 2, got {self.birth_views!r}")
        if self.association not in ASSOCIATIONS:
            raise PriortrackError(f"scene setting association must be one of {', '.join(ASSOCIATIONS)}, "
                                  f"got {self.association!r}")


@dataclass
class Track:
    """One person: ``id``, the motion model, the frame first and last seen, the bone lengths (14,) of the
    frames where two cameras or more saw them, NaN for a bone whose ends two cameras did not both show (their median
    per bone is the person's signature: a detector that never gives the head still signs with the other 13), and,
    for a person just born, the proposals that confirmed them ({frame: ({camera: detection index}, joints (15, 3))})."""

    id: int
    motion: JointKalman
    first: int
    last_seen: int
    bones: list[np.ndarray] = field(default_factory=list, repr=False)
    birth: dict[int, tuple[dict[int, int], np.ndarray]] = field(default_factory=dict, repr=False)
    #: (frame, pelvis (3,)) where a person given a new id at birth started: they may yet prove to be someone who had
    #: ended (:meth:`ProposalInitiator.recognised`); None for a person who is who they were.
    born: tuple[int, np.ndarray] | None = field(default=None, repr=False)

    @property
    def signature(self) -> np.ndarray | None:
        """(14,) the median of each bone over the frames that measured it (NaN: none did); None where no bone was."""
        if not self.bones:
            return None
        bones = np.stack(self.bones).T                                                 # (14, frames)
        measured = np.isfinite(bones)
        if not measured.any():
            return None
        median = median_of_seen(bones, measured)
        return np.where(np.isfinite(median), median, np.nan)


def _mirrored() -> np.ndarray:
    """(15,) the eval15 joints with left and right exchanged (a detector's swap undone by indexing)."""
    order = np.arange(15)
    for a, b in EVAL15_MIRROR_PAIRS:
        order[a], order[b] = b, a
    return order


MIRRORED = _mirrored()


class PredictionAssociator:
    """Step 2 of the module docstring: each camera's detections to the live tracks. A detection's cost is
    the smaller of its own and its left/right mirror's (a detector's swap, common on a side view, would
    otherwise leave the person's detection to nobody or to a vaguer track), plus the spread penalty
    median_j log(det S_j / det R_j) ≥ 0: the log-likelihood's normaliser, so that of two tracks whose
    gates both hold a detection the sharper prediction wins, and a track whose prediction has spread far
    beyond the detections' noise (unseen for a while) takes none and ends (a person who comes back is
    born again and re-identified).

    **Across views** (:meth:`consistent`): the detections one track takes in different cameras must be one
    person's, their joints' rays meeting within the pair gate (:func:`~priortrack.tracking.association.pair_distances`,
    as a birth's) and their triangulation a body an adult could have
    (:func:`~priortrack.tracking.association.body_scale`); where two do not, the costlier (the farther from the
    track's prediction) is given back, until the rest agree. Two people in line with one camera overlap in its image,
    and a track of the farther one took the nearer one's detection there: its other camera's rays do not meet it (the
    nearer person's knee ray passes the farther one's ankle), and the nearer one's detections are left to make them a
    track (Shelf, cameras 1 and 3: a person entering behind another was absorbed, and the other's track lost)."""

    def __init__(self, gate: float = GATE, pair_gate: float = PAIR_GATE_M):
        self.gate, self.pair_gate = gate, pair_gate

    @staticmethod
    def costs(tracks: list[Track], view: View, xy: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(tracks, N) costs (class docstring) and whether the mirror gave each, from xy (N, J, 2) normalised
        points and confidence (N, J) (:func:`prediction_costs` of the tracks' predictions in ``view``)."""
        predictions = [track.motion.predicted(view) for track in tracks]
        sigma = np.array([track.motion.sigma_px for track in tracks]) / view.f
        return prediction_costs(np.stack([q[0] for q in predictions]), np.stack([q[2] for q in predictions]), sigma,
                                xy, confidence)

    def __call__(self, tracks: list[Track], views: list[View], xy: list[np.ndarray],
                 confidence: list[np.ndarray]) -> dict[int, dict[int, tuple[int, bool]]]:
        """{track id: {camera: (detection index, mirrored)}} for this frame."""
        assigned: dict[int, dict[int, tuple[int, bool]]] = {t.id: {} for t in tracks}
        if not tracks:
            return assigned
        paid: dict[tuple[int, int], float] = {}
        for c, view in enumerate(views):
            if not len(xy[c]):
                continue
            cost, mirror = self.costs(tracks, view, xy[c], confidence[c])
            for k, n in gated_assignment(cost, self.gate):
                assigned[tracks[k].id][c] = (n, bool(mirror[k, n]))
                paid[tracks[k].id, c] = float(cost[k, n])
        return {pid: self.consistent(chosen, views, xy, confidence, {c: paid[pid, c] for c in chosen})
                for pid, chosen in assigned.items()}

    def consistent(self, chosen: dict[int, tuple[int, bool]], views: list[View], xy: list[np.ndarray],
                   confidence: list[np.ndarray], cost: dict[int, float]) -> dict[int, tuple[int, bool]]:
        """One track's detections {camera: (index, mirrored)} with those that are not the same person as the
        others given back (class docstring); ``cost`` {camera: the detection's cost}."""
        chosen = dict(chosen)
        while len(chosen) >= 2:
            order = {c: MIRRORED if mirrored else slice(None) for c, (_, mirrored) in chosen.items()}
            points = {c: xy[c][n][order[c]] for c, (n, _) in chosen.items()}
            weight = {c: np.where(np.isfinite(points[c]).all(-1), confidence[c][n][order[c]], 0.0)
                      for c, (n, _) in chosen.items()}
            apart = [(a, b) for a, b in itertools.combinations(chosen, 2)
                     if self.pair_gate <= pair_distances(views[a].centre, views[a].rays(points[a])[None], weight[a][None],
                                                         views[b].centre, views[b].rays(points[b])[None],
                                                         weight[b][None])[0, 0] < np.inf]
            if not apart:
                joints = dlt_normalised([views[c] for c in chosen], np.stack(list(points.values())),
                                        np.stack(list(weight.values())))
                if not body_scale(joints) > MAX_BODY_SCALE:
                    break
                apart = list(itertools.combinations(chosen, 2))         # one body of no one: the costliest goes
            del chosen[max({c for pair in apart for c in pair}, key=cost.get)]
        return chosen


def prediction_costs(h: np.ndarray, HPH: np.ndarray, sigma: np.ndarray, xy: np.ndarray,
                     confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, N) costs of N detections for K predictions (:class:`PredictionAssociator`) and whether the mirror
    gave each: predicted points h (K, J, 2) with their spread HPH (K, J, 2, 2), each prediction's noise σ (K,)
    at confidence 1 (R = (σ / confidence)² I, in the units of h), detections xy (N, J, 2) and confidence (N, J);
    inf where a detection shares no joint with a prediction. Every prediction, detection and order at once:
    S (2, K, N, J, 2, 2) = HPH + R, its 2 × 2 inverse in closed form."""
    h, HPH = h[None, :, None], HPH[None, :, None]                                          # (1, K, 1, J, ·)
    sigma = np.asarray(sigma, dtype=float)[None, :, None, None]
    points = np.stack([xy, xy[:, MIRRORED]])[:, None]                                      # (2, 1, N, J, 2)
    c = np.stack([confidence, confidence[:, MIRRORED]])[:, None]                           # (2, 1, N, J)
    seen = np.isfinite(points).all(-1) & (c > 0) & np.isfinite(h).all(-1) & np.isfinite(HPH).all((-1, -2))
    r2 = (sigma / np.where(seen, c, 1.0)) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        a, b = HPH[..., 0, 0] + r2, HPH[..., 0, 1]
        d = HPH[..., 1, 1] + r2
        det = a * d - b * b
        e = points - h
        m = (d * e[..., 0] ** 2 - 2 * b * e[..., 0] * e[..., 1] + a * e[..., 1] ** 2) / det
        spread = np.log(det / r2 ** 2)
    both = median_of_seen(m, seen) + median_of_seen(spread, seen)                     # (2, K, N)
    return np.minimum(both[0], both[1]), both[1] < both[0]


def gated_assignment(cost: np.ndarray, gate: float) -> list[tuple[int, int]]:
    """The optimal assignment (Hungarian, :func:`scipy.optimize.linear_sum_assignment`) of K predictions to N
    detections by cost (K, N), each prediction with a "not this one" option at the ``gate``'s cost (no
    detection forced onto it): the (k, n) pairs assigned."""
    K, N = cost.shape
    padded = np.concatenate([np.where(cost < gate, cost, np.inf), np.full((K, K), np.inf)], axis=1)
    padded[:, N:][np.diag_indices(K)] = gate
    rows, cols = linear_sum_assignment(np.where(np.isfinite(padded), padded, 1e12))
    return [(int(k), int(n)) for k, n in zip(rows, cols) if n < N and np.isfinite(padded[k, n])]


class MissedFramesDeleter:
    """Step 4: the live tracks unseen for more than ``frames`` frames."""

    def __init__(self, frames: int):
        self.frames = frames

    def __call__(self, tracks: list[Track], frame: int) -> list[Track]:
        return [t for t in tracks if frame - t.last_seen > self.frames]


class ProposalInitiator:
    """Step 5: tentative people from the leftover detections' cross-view proposals, confirmed after
    ``frames`` frames; a confirmed person re-identified among the ended ones or given a new id. A new person's
    motion model is ``motion(joints (15, 3), velocity (15, 3) or None)`` (:class:`~priortrack.tracking.motion.JointKalman`
    by default; any object with its ``joints``, ``sigma_px``, ``predict``, ``predicted`` and ``update``)."""

    def __init__(self, frames: int, views: int, pair_gate: float, fps: float, motion=JointKalman):
        self.frames, self.views, self.pair_gate, self.fps, self.motion = frames, views, pair_gate, fps, motion
        self.tentative: list[dict] = []

    def __call__(self, scene: "SceneTracker", xy: list[np.ndarray], confidence: list[np.ndarray],
                 used: list[set[int]]) -> list[Track]:
        cameras = scene.cameras
        single = len(cameras) == 1
        left = [np.array([n for n in range(len(xy[c])) if n not in used[c]], dtype=int) for c in range(len(cameras))]
        if sum(len(a) for a in left) < (1 if single else 2):
            self.tentative = []
            return []
        points = [xy[c][a] for c, a in enumerate(left)]
        weights = [confidence[c][a] for c, a in enumerate(left)]
        if single:                      # one camera: each person placed at the depth their size says
            proposals = [p for n in range(len(points[0]))
                         if (p := single_view.proposal(scene.views[0], points[0][n], weights[0][n], n)) is not None]
        else:
            association = associate(cameras, points, weights, self.pair_gate, xy=points)
            proposals = [p for p in association.proposals if len(p.views) >= self.views]
        gap = self._gap(scene)
        followed, born = [], []
        for p in proposals:
            views = {c: int(left[c][n]) for c, n in p.views.items()}
            if any(gap(p.joints, t.motion.joints) < FOLLOW_M for t in scene.live):
                continue                                  # a live person's detections the gate let go
            previous = min(self.tentative, key=lambda s: gap(p.joints, s["joints"]), default=None)
            if previous is not None and gap(p.joints, previous["joints"]) < FOLLOW_M:
                self.tentative = [s for s in self.tentative if s is not previous]
                history, seen = previous["history"] + [p.joints], {**previous["views"], scene.frame: (views, p.joints)}
            else:
                history, seen = [p.joints], {scene.frame: (views, p.joints)}
            if len(history) >= self.frames:
                born.append(self._born(scene, history, seen))
            else:
                followed.append({"joints": p.joints, "history": history, "views": seen})
        self.tentative = followed
        return born

    @staticmethod
    def _gap(scene: "SceneTracker"):
        """The distance (a, b) → metres between a proposal's joints a (15, 3) and a person's b: the median joint
        distance; with one camera, a's placement moved along its rays to b's depth first (its lateral gap:
        :func:`~priortrack.tracking.single_view.at_depth`)."""
        if len(scene.cameras) > 1:
            return median_distance
        return lambda a, b: median_distance(single_view.at_depth(scene.views[0], a, b), b)

    def _born(self, scene: "SceneTracker", history: list[np.ndarray], views: dict[int, tuple]) -> Track:
        joints = history[-1]
        single = len(scene.cameras) == 1
        before = history[-2] if len(history) > 1 else None
        if single and before is not None:                   # one view: the last placement at this one's depth
            before = single_view.at_depth(scene.views[0], before, joints)
        velocity = None if before is None else (joints - before) * self.fps
        track = Track(-1, self.motion(joints, velocity), min(views), scene.frame, birth=views)
        # one view's placement has the nominal body's size: no signature
        track.bones = [] if single else [b for b in bone_lengths(np.stack(history)) if np.isfinite(b).any()]
        track.born = (min(views), track.motion.joints[0].copy())
        track.id = self._identity(scene, track)
        return track

    def _identity(self, scene: "SceneTracker", track: Track) -> int:
        """An ended person whose signature and position fit the new one (:meth:`_returning`), else a new id."""
        best = self._returning(scene, track)
        if best is None:
            scene.next_id += 1
            return scene.next_id - 1
        track.born = None
        return best.id

    def recognised(self, scene: "SceneTracker", track: Track) -> int | None:
        """The id of a person who had ended before ``track`` (given a new id at birth) started, and whose signature
        its bones, measured since, now fit (:meth:`_returning`); None where none does. A returning person's first
        frames may be two views' partial, mismatched detections (Shelf, cameras 1 and 4: five of eleven bones
        wrong, the median gap 2.2 at birth, 0.13 after 1 s, 0.08 after 2 s)."""
        best = self._returning(scene, track)
        if best is None:
            return None
        log.info("frame %d: person %d is person %d, back since frame %d", scene.frame, track.id, best.id,
                 track.born[0])
        track.born = None
        return best.id

    def _returning(self, scene: "SceneTracker", track: Track) -> Track | None:
        """Among the ended people last seen before ``track`` started (``track.born``), the one whose signature is
        nearest its own (:func:`signature_gap` under :data:`REID_BONES`) and whose pelvis, where last seen, lies
        within :data:`REID_M` plus 1.5 m/s times the time away of where the track started: taken out of the ended
        (their first frame and bones now the track's); None where none fits."""
        signature = track.signature
        start, pelvis = track.born
        best, best_gap = None, REID_BONES
        for old in scene.ended:
            if old.signature is None or signature is None or old.last_seen >= start:
                continue
            away = (start - old.last_seen) / self.fps
            if np.linalg.norm(old.motion.joints[0] - pelvis) > REID_M + 1.5 * away:
                continue
            gap = signature_gap(signature, old.signature)
            if gap < best_gap:
                best, best_gap = old, gap
        if best is not None:
            scene.ended.remove(best)
            track.first, track.bones = best.first, best.bones + track.bones
            log.info("frame %d: person %d is back (bone lengths %.0f%% from theirs)", scene.frame, best.id,
                     100 * best_gap)
        return best


def median_of_seen(values: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(…,) the median of values (…, J) over the seen entries of the last axis (inf where none)."""
    ordered = np.sort(np.where(seen, values, np.inf), axis=-1)
    k = seen.sum(axis=-1, keepdims=True)
    low = np.take_along_axis(ordered, np.maximum(k - 1, 0) // 2, axis=-1)[..., 0]
    high = np.take_along_axis(ordered, np.minimum(k // 2, values.shape[-1] - 1), axis=-1)[..., 0]
    return np.where(k[..., 0] > 0, (low + high) / 2, np.inf)


#: The keypoints a detection needs to count as someone's in :meth:`SceneAssociation.unclaimed`.
UNCLAIMED_KEYPOINTS = 8


@dataclass
class SceneAssociation:
    """What the scene tracker decided over a recording.

    Attributes:
        person_ids: (P,) each person's id, in order of first appearance.
        slots: (T, C, P) the detection slot of person p in camera c at frame t, −1 where none.
        joints: (T, P, 15, 3) each person's joints as the motion model has them, metres, NaN where the
            person is not tracked.
        frames: (T,) the detections' frame numbers.
        present: (T, P) where each person is in the scene: the frames a camera's detection is theirs, and the
            gaps between two such frames no longer than ``gap`` frames (the deleter's; after a person's last
            detection they are gone, though their track coasts until the deleter ends it).
    """

    person_ids: np.ndarray
    slots: np.ndarray
    joints: np.ndarray
    frames: np.ndarray
    gap: int = 0

    @classmethod
    def indexed(cls, scene: SceneDetections, index: int) -> "SceneAssociation":
        """One person, id ``index``: the detection at that index of each camera's list of people at each frame (the
        people a detector found, in the files' order; a detector that keeps each person at one index keeps them
        there), no scene tracker; −1 where a camera's frame has fewer people."""
        if isinstance(index, bool) or not isinstance(index, int) or index < 0:
            raise PriortrackError(f"a person's index in each frame's list is a whole number ≥ 0, got {index!r}")
        if index >= scene.keypoints.shape[2]:
            raise PriortrackError(f"{scene.source}: no frame lists {index + 1} people (at most "
                                  f"{scene.keypoints.shape[2]}; indices from 0)")
        there = np.isfinite(scene.keypoints[:, :, index, :, 0]).any(axis=-1).T        # (T, C)
        slots = np.where(there, index, -1)[..., None]
        joints = np.full((len(scene.frames), 1, 15, 3), np.nan)
        return cls(np.array([index]), slots, joints, np.asarray(scene.frames))

    def detections_of(self, scene: SceneDetections, p: int) -> Detections:
        """Person p's (index into ``person_ids``) detections in ``scene``: (C, T, K, 3) keypoints, NaN where no
        detection was theirs."""
        keypoints = np.full(scene.keypoints.shape[:2] + scene.keypoints.shape[3:], np.nan, dtype=np.float32)
        t, c = np.nonzero(self.slots[:, :, p] >= 0)
        keypoints[c, t] = scene.keypoints[c, t, self.slots[t, c, p]]
        return Detections(scene.layout, scene.camera_names, scene.frames, scene.fps,
                          f"{scene.source} (person {self.person_ids[p]})", keypoints=keypoints)

    def unclaimed(self, scene: SceneDetections, min_confidence: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
        """Per camera, the frames (C,) with a detection of someone (at least :data:`UNCLAIMED_KEYPOINTS` keypoints
        at ``min_confidence``) that is nobody's, and the first such detection: its frame index and the median of its
        keypoints (C, 3: t, x, y; NaN where none): a person only that camera sees (no birth without a second view),
        or a detector's false positive."""
        kp = scene.keypoints                                                           # (C, T, N, K, 3)
        found = np.isfinite(kp[..., 0]) & (np.nan_to_num(kp[..., 2]) >= min_confidence)
        someone = found.sum(axis=-1) >= UNCLAIMED_KEYPOINTS                             # (C, T, N)
        C, T, N = someone.shape
        claimed = np.zeros((C, T, N + 1), dtype=bool)                                  # slot −1 → column N
        t, c, p = np.nonzero(np.ones_like(self.slots, dtype=bool))
        claimed[c, t, np.where(self.slots[t, c, p] >= 0, self.slots[t, c, p], N)] = True
        nobodys = someone & ~claimed[..., :N]
        first = np.full((C, 3), np.nan)
        for camera in np.flatnonzero(nobodys.any(axis=(1, 2))):
            t, n = np.argwhere(nobodys[camera])[0]
            points = kp[camera, t, n][found[camera, t, n], :2]
            first[camera] = (t, *np.median(points, axis=0))
        return nobodys.any(axis=2).sum(axis=1), first

    @property
    def present(self) -> np.ndarray:
        seen = (self.slots >= 0).any(axis=1)                                          # (T, P)
        out = seen.copy()
        for p in range(seen.shape[1]):
            frames = np.flatnonzero(seen[:, p])
            for a, b in zip(frames[:-1], frames[1:]):
                if 1 < b - a <= self.gap + 1:
                    out[a:b, p] = True
        return out


class SceneTracker:
    """The scene tracker of the module docstring, composed of an ``associator``, a ``deleter`` and an
    ``initiator`` (the defaults built from ``config``; any object with the same call can replace them), and each
    person's ``motion`` model in the association (the default initiator's: a class or factory called with a new
    person's joints and velocity, :class:`~priortrack.tracking.motion.JointKalman` by default).

    Args:
        cameras: the C calibrated cameras (in the calibration's world).
        fps: the detections' frame rate.
        config: the settings (:class:`SceneConfig`).
    """

    def __init__(self, cameras: list[PinholeCamera], fps: float, config: SceneConfig | None = None,
                 associator=None, deleter=None, initiator=None, motion=JointKalman):
        if not 0 < fps < 1e4:
            raise PriortrackError(f"fps must be a positive frame rate, got {fps}")
        if not cameras:
            raise PriortrackError("a scene tracker needs a calibrated camera")
        self.cameras, self.fps, self.config = list(cameras), float(fps), config or SceneConfig()
        self.views = [View.of(c) for c in self.cameras]
        frames = lambda seconds: max(1, int(round(seconds * self.fps)))          # noqa: E731
        self.associator = associator or PredictionAssociator(self.config.gate, self.config.pair_gate_m)
        self.deleter = deleter or MissedFramesDeleter(frames(self.config.death_s))
        self.initiator = initiator or ProposalInitiator(frames(self.config.birth_s),
                                                        min(self.config.birth_views, len(self.cameras)),
                                                        self.config.pair_gate_m, self.fps, motion)
        self.live: list[Track] = []
        self.ended: list[Track] = []
        self.born: list[Track] = []
        self.frame, self.next_id = 0, 0
        #: The ids of tracks found to be no one (:func:`no_body`), left out of :meth:`run`'s association.
        self.dropped: set[int] = set()
        #: (new id, the id it proved to be, the frame it started): people recognised after their birth
        #: (:meth:`ProposalInitiator.recognised`), their frames since that start given the old id in :meth:`run`.
        self.recognised: list[tuple[int, int, int]] = []

    def step(self, xy: list[np.ndarray], confidence: list[np.ndarray]) -> dict[int, dict[int, int]]:
        """One frame (module docstring): per camera, its N_c detections' undistorted normalised points xy
        (N_c, 15, 2) (:func:`~priortrack.tracking.association.normalised`) and confidences (N_c, 15);
        returns {person id: {camera: detection index}} for the people tracked at this frame."""
        for track in self.live:
            track.motion.predict(1 / self.fps)
        decided = self.associator(self.live, self.views, xy, confidence)
        assigned = {pid: {c: n for c, (n, _) in views.items()} for pid, views in decided.items()}
        used: list[set[int]] = [set() for _ in self.cameras]
        judged = []                                  # tracks whose bone measurements reached a power of two
        for track in self.live:
            views = decided[track.id]
            order = {c: MIRRORED if mirrored else slice(None) for c, (_, mirrored) in views.items()}
            track.motion.update([self.views[c] for c in views], [xy[c][n][order[c]] for c, (n, _) in views.items()],
                                [confidence[c][n][order[c]] for c, (n, _) in views.items()])
            for c, (n, _) in views.items():
                used[c].add(n)
            if views:
                track.last_seen = self.frame
                if len(views) >= 2:
                    shown = sum(np.isfinite(xy[c][n][order[c]]).all(-1) & (confidence[c][n][order[c]] > 0)
                                for c, (n, _) in views.items())                 # (15,) cameras showing each joint
                    child = np.flatnonzero(EVAL15_PARENTS >= 0)
                    measured = (shown[child] >= 2) & (shown[EVAL15_PARENTS[child]] >= 2)
                    if measured.any():
                        track.bones.append(np.where(measured, bone_lengths(track.motion.joints), np.nan))
                        if len(track.bones) & (len(track.bones) - 1) == 0:
                            judged.append(track)
        for track in self.deleter(self.live, self.frame):
            self.live.remove(track)
            self.ended.append(track)
            log.info("frame %d: person %d unseen for %d frames: ended", self.frame, track.id,
                     self.frame - track.last_seen)
        # judged as their measurements double (a median over all of them every frame would cost a long run T²)
        for track in [t for t in judged if t in self.live and no_body(t.signature)]:
            self.live.remove(track)
            self.dropped.add(track.id)
            log.warning("frame %d: 'person' %d is no one: their bones measure %.1f m (median), detections of different "
                        "people paired across cameras; dropped from every frame", self.frame, track.id,
                        np.nanmedian(track.signature))
        recognise = getattr(self.initiator, "recognised", None)         # as their measurements double, too
        for track in [t for t in judged if t in self.live and t.born is not None and recognise is not None]:
            new, start = track.id, track.born[0]
            track.id = recognise(self, track)
            if track.id is None:
                track.id = new
            else:
                self.recognised.append((new, track.id, start))
                assigned[track.id] = assigned.pop(new)
        self.born = self.initiator(self, xy, confidence, used)
        for track in self.born:
            self.live.append(track)
            assigned[track.id] = track.birth[self.frame][0]
        self.frame += 1
        return {t.id: assigned.get(t.id, {}) for t in self.live}

    def run(self, uv: np.ndarray, confidence: np.ndarray, frames: np.ndarray) -> SceneAssociation:
        """Track a recording: uv (C, T, N, 15, 2) pixels (NaN-padded slots), confidence (C, T, N, 15)."""
        C, T = uv.shape[:2]
        if C != len(self.cameras):
            raise PriortrackError(f"detections of {C} cameras for {len(self.cameras)} calibrated cameras")
        xy = normalised(self.cameras, uv)
        per_frame, joints, slots = [], [], []
        for t in range(T):
            slots.append([np.flatnonzero(np.isfinite(uv[c, t]).any(axis=(-1, -2))) for c in range(C)])
            picked = self.step([xy[c][t][s] for c, s in enumerate(slots[t])],
                               [confidence[c, t][s] for c, s in enumerate(slots[t])])
            per_frame.append({pid: {c: int(slots[t][c][n]) for c, n in views.items()} for pid, views in picked.items()})
            joints.append({track.id: track.motion.joints.copy() for track in self.live})
            for track in self.born:                  # the frames that confirmed a new person are theirs too
                for f, (views, at) in track.birth.items():
                    per_frame[f].setdefault(track.id, {c: int(slots[f][c][n]) for c, n in views.items()})
                    joints[f].setdefault(track.id, at)
        for new, old, start in self.recognised:       # since their start, a recognised person's frames are theirs
            for table in [*per_frame[start:], *joints[start:]]:
                if new in table:
                    table[old] = table.pop(new)
        ids = sorted({pid for frame in per_frame for pid in frame} - self.dropped)
        out_slots = np.full((T, C, len(ids)), -1, dtype=int)
        out_joints = np.full((T, len(ids), 15, 3), np.nan)
        for t, (frame, at) in enumerate(zip(per_frame, joints)):
            for p, pid in enumerate(ids):
                for c, n in frame.get(pid, {}).items():
                    out_slots[t, c, p] = n
                if pid in at:
                    out_joints[t, p] = at[pid]
        return SceneAssociation(np.array(ids, dtype=int), out_slots, out_joints, np.asarray(frames),
                                self.deleter.frames if isinstance(self.deleter, MissedFramesDeleter) else 0)
