"""Who is who, decided again through each person's own filter: every person's filter preset steps in lockstep
with the others, and each tick's detections go to the people whose filter predicts them.

The scene tracker (:mod:`priortrack.tracking.scene`) finds the people: who is born where, who ends, who
comes back, with a constant-velocity model of each joint. Each person's filter is then prepared from the
detections it gave them (:func:`~priortrack.tracking.person.prepared`: their body, their start), and every
person's filter runs together, tick by tick (the prior's ticks, :func:`~priortrack.tracking.person.schedule`):

1. **predict**: every running filter advances (its prior's transition; ``advance``);
2. **its prediction of the detections**: each observed point's predicted pixels ẑ (C, 15, 2) and their
   spread P_zz (C, 15, 2, 2) (``predicted_measurement``: the unscented transform of the sigma points, or
   the particle cloud's weighted moments), through the lens, as the filter's own likelihood projects;
3. **associate**: in each camera, the detections of the tick's frame to the people the scene tracker has
   in the scene there and whose filter runs, by the scene tracker's cost (the median over joints of the
   Mahalanobis distance with S = P_zz + R, R = (σ_px / confidence)² I in pixels, plus the spread penalty,
   the mirror's where smaller: :func:`~priortrack.tracking.scene.prediction_costs`) and its optimal
   assignment with a "not this person" option at the gate (:func:`~priortrack.tracking.scene.gated_assignment`); a
   person whose filter takes nothing in a camera keeps the scene tracker's detection there if no filter took it (a
   filter that lost its person, its prediction covering none of their detections, would otherwise be given none and
   never come back: Shelf, cameras 1 and 2, ukf-real, an entering person at 735 mm, with it 69), but only where the
   filter's prediction is in that camera's view (the median of its predicted points within the image widened by
   :data:`IN_VIEW_MARGIN` of it each side): a filter metres off, predicting its person outside the picture or behind
   the camera, is given no detection the joint model's track of someone else took (Shelf, cameras 0, 1, 4: a
   person's filter, given a detection now and then while it drifted 6 m out of the room, was handed them at 800 and
   100,000 px);
4. **update**: each filter corrects with the detections it was given (``correct``; as detected: a swap is
   the filter's own to undo);
5. **a second track of one person**: a filter that starts within the association's ``DUPLICATE_M`` (median over
   the joints) of an older person's filter, or two filters whose estimates stay that near for :data:`DUPLICATE_S`,
   follow one person (the joint model's track of someone followed a person entering beside them, and a new track was
   born on the first: both filters then share the first one's detections, their identity flips from frame to frame,
   or the older one is pushed onto the newcomer); the later started is given no more detections and ends as the
   scene tracker ends an unseen person.

The detections of a person whose filter has not started yet (their start ticks), or who is not among the
people tracked, stay theirs and are offered to nobody else. Frames the prior's ticks skip (60 fps data, a
30 fps prior) keep the scene tracker's decisions; their detections are not the filters' anyway.

σ_px is the detections' noise as the scene tracker has it (:data:`~priortrack.tracking.motion.SIGMA_PX`), not the
filter's own: the same detections, the same noise. With ukf-real's σ = 5 px, one camera of Pose2Sim's demo that sees
the synthetic person 20–30 px off the other cameras' consensus was left out of that person's association from the
first tick on (the filter, no longer corrected by it, drifted further from it).

A filter that cannot predict its detections (the MAP tracker, :func:`predicts`) leaves the scene tracker's decisions
as they are (:func:`~priortrack.tracking.people.track_scene` runs each person on their own then).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable

import numpy as np

from priortrack.data.scene_detections import SceneDetections
from priortrack.filters.snapshot import KNOWN_FRAMES
from priortrack.geometry.facing import image_forward
from priortrack.tracking.association import DUPLICATE_M, median_distance
from priortrack.tracking.motion import SIGMA_PX
from priortrack.tracking.person import PersonRun
from priortrack.tracking.presets import Preset, filter_class
from priortrack.tracking.scene import GATE, SceneAssociation, gated_assignment, prediction_costs

log = logging.getLogger(__name__)

#: Two people's filters whose estimates stay within DUPLICATE_M this long (seconds) follow one person.
DUPLICATE_S = 0.5
#: How far beyond its image (a fraction of its width and height, each side) a camera's view reaches for the
#: scene tracker's detection kept by a filter that took none (module docstring, 3).
IN_VIEW_MARGIN = 0.25


def predicts(preset: Preset) -> bool:
    """Whether the preset's filter steps in halves with a prediction of its detections in between (the particle
    and unscented filters; not the MAP tracker)."""
    return all(hasattr(filter_class(preset.filter_kind), name) for name in ("advance", "predicted_measurement",
                                                                             "correct"))


def detection_costs(person: PersonRun, uv: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C, N) the cost of each of a frame's detections, uv (C, N, 15, 2) and confidence (C, N, 15), for the
    person, from their filter's prediction (after ``advance``; module docstring, 3); inf where a slot holds
    no detection. And (C,) whether the prediction is in each camera's view: the median of its predicted points
    inside the image, widened by a quarter of it each side (module docstring, 3)."""
    mean, covariance = person.filt.predicted_measurement()
    costs = np.stack([prediction_costs(mean[c][None], covariance[c][None], np.array([SIGMA_PX]), uv[c],
                                       confidence[c])[0][0] for c in range(len(uv))])
    cameras = person.filt.model.likelihood.cameras
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)                  # a camera the prediction is behind: NaN
        centre = np.nanmedian(mean, axis=1)                                                   # (C, 2)
    size = np.array([[camera.width, camera.height] for camera in cameras], dtype=float)
    in_view = (np.abs(centre - size / 2) <= (0.5 + IN_VIEW_MARGIN) * size).all(axis=1)
    return costs, in_view


def assigned(costs: dict[int, np.ndarray], slots: np.ndarray, gate: float,
             in_view: dict[int, np.ndarray] | None = None) -> np.ndarray:
    """A frame's slots (C, P) with those of the people deciding (``costs``' keys, each with (C, N) costs of the
    frame's N slots) decided by the optimal assignment; the slots the others hold are offered to nobody; a deciding
    person given nothing in a camera keeps their slot there where no one else took it and their prediction is in
    that camera's view (``in_view``: (C,) bool per deciding person; None: everywhere; module docstring, 3)."""
    deciding = list(costs)
    out = slots.copy()
    out[:, deciding] = -1
    for c in range(len(slots)):
        held = {int(n) for q, n in enumerate(slots[c]) if n >= 0 and q not in costs}
        cost = np.stack([costs[p][c] for p in deciding])
        offered = np.array([n for n in np.flatnonzero(np.isfinite(cost).any(axis=0)) if n not in held], dtype=int)
        if len(offered):
            for i, n in gated_assignment(cost[:, offered], gate):
                out[c, deciding[i]] = offered[n]
        for p in deciding:                       # what no filter took stays the scene tracker's
            if out[c, p] < 0 <= slots[c, p] and slots[c, p] not in out[c] and (in_view is None or in_view[p][c]):
                out[c, p] = slots[c, p]
    return out


def observation(uv: np.ndarray, confidence: np.ndarray, slots: np.ndarray) -> np.ndarray:
    """z (C, 15, 3) of a frame's detections uv (C, N, 15, 2), confidence (C, N, 15) given slots (C,) (−1:
    none), as :class:`~priortrack.observation.ticks.TickObservations` reads a person's frame."""
    z = np.full((len(slots), 15, 3), np.nan)
    z[..., 2] = 0.0
    for c, n in enumerate(slots):
        if n >= 0:
            z[c, :, :2], z[c, :, 2] = uv[c, n], confidence[c, n]
    return z


def detected_forward(scene: SceneDetections, f: int, slots: np.ndarray, min_confidence: float) -> np.ndarray:
    """(C, 3) the forward direction in each camera's image of frame f's detections ``slots`` (C,) (−1: none, 0)
    from their feet and face (:func:`~priortrack.geometry.facing.image_forward`): what a filter turns a person one
    camera alone sees by (:attr:`~priortrack.filters.ukf.UnscentedFilter.forward`)."""
    keypoints = np.full((len(slots),) + scene.keypoints.shape[-2:], np.nan)
    for c, n in enumerate(slots):
        if n >= 0:
            keypoints[c] = scene.keypoints[c, f, n]
    return image_forward(keypoints, scene.keypoint_names, min_confidence)


def reassociated(scene: SceneDetections, association: SceneAssociation, people: dict[int, PersonRun],
                 index: np.ndarray, min_confidence: float, gate: float = GATE,
                 progress: Callable[[int, int], None] | None = None,
                 interruptible: bool = False) -> tuple[SceneAssociation, dict]:
    """Every person's filter run in lockstep in this process (module docstring).

    Args:
        scene: the detections, every person in every file.
        association: the scene tracker's decisions (which slot is whose, who is in the scene when).
        people: {p (index into ``association.person_ids``): the person's prepared run}; each run's ticks are
            the last of ``index``'s (it starts at its own first tick).
        index: (K,) the detection frame of each of the prior's ticks (−1: none).
        min_confidence: keypoints below it are missing (as the runs' observations read them).
        gate: the assignment's gate (the scene tracker's).
        progress: called as progress(tick, ticks).
        interruptible: Ctrl-C ends every run at the tick reached (as
            :meth:`~priortrack.filters.driver.SequentialFilter.run` does one).

    Returns the association with the ticked frames' slots decided again, and {p: the filter's run
    (:class:`~priortrack.filters.snapshot.Track`)}; each person's run has its observations (``z``) and
    detections replaced by those its filter consumed (:meth:`~priortrack.tracking.person.PersonRun.observe`).
    """
    uv, confidence = scene.eval15(min_confidence)                          # (C, T, N, 15, 2), (C, T, N, 15)
    K = len(index)
    slots = association.slots.copy()                                        # (T, C, P)
    present = association.present
    first = {p: K - len(run.index) for p, run in people.items()}
    runs = {p: run.filt.started(run.known, len(run.z), run.config.keep_snapshots, None, run.config.snapshot_every,
                                run.on_step, **run.initial) for p, run in people.items()}
    changed, ended, together = 0, set(), {}
    needed = max(1, int(round(DUPLICATE_S * next(iter(people.values())).prior.fps))) if people else 1
    try:
        for k in range(K):
            running = [p for p in people if k >= first[p] + KNOWN_FRAMES]
            f = int(index[k])
            ended |= _born_on_someone([p for p in running if p not in ended], k, runs, first, association.person_ids)
            for p in ended:                                     # a second track of someone: nobody's detections
                slots[max(f, 0):, :, p] = -1
            if f < 0:                                                       # a tick without a frame
                for p in running:
                    runs[p].record(people[p].filt.step(np.full((len(uv), 15, 3), np.nan)))
            else:
                for p in running:
                    people[p].filt.advance()
                judged = {p: detection_costs(people[p], uv[:, f], confidence[:, f]) for p in running
                          if present[f, p] and p not in ended}
                costs = {p: cost for p, (cost, _) in judged.items()}
                if costs:
                    decided = assigned(costs, slots[f], gate, {p: view for p, (_, view) in judged.items()})
                    changed += int((decided != slots[f]).any(axis=0).sum())
                    slots[f] = decided
                for p in running:
                    forward = getattr(people[p].filt, "forward", None)
                    if forward is not None:                         # the feet and face of the detections it takes
                        forward[k - first[p]] = detected_forward(scene, f, slots[f, :, p], min_confidence)
                    runs[p].record(people[p].filt.correct(observation(uv[:, f], confidence[:, f], slots[f, :, p])))
            ended |= _duplicates([p for p in running if p not in ended], runs, first, together, needed,
                                 association.person_ids)
            if progress:
                progress(k, K)
    except KeyboardInterrupt:
        if not interruptible or not any(run.done > KNOWN_FRAMES for run in runs.values()):
            raise
        log.warning("interrupted: %d of %d ticks tracked; the runs end there", k, K)
    log.info("the filters' association: %d person-frames decided otherwise than the scene tracker's", changed)
    out = SceneAssociation(association.person_ids, slots, association.joints, association.frames, association.gap)
    for p, run in people.items():
        run.observe(out.detections_of(scene, p))
    return out, {p: run.result() for p, run in runs.items()}


def _born_on_someone(running: list[int], k: int, runs: dict, first: dict[int, int], ids: np.ndarray) -> set[int]:
    """The people whose filter starts at tick ``k`` where an older person's filter already is: their start within
    :data:`~priortrack.tracking.association.DUPLICATE_M` (median over the joints) of that filter's latest estimate
    (module docstring, 5: a second track of one person, found before the two compete for one person's detections)."""
    out = set()
    for p in running:
        if k != first[p] + KNOWN_FRAMES:
            continue
        start = runs[p].estimates[KNOWN_FRAMES - 1]
        for q in running:
            if first[q] < first[p] and median_distance(start, runs[q].estimates[runs[q].done - 1]) < DUPLICATE_M:
                out.add(p)
                log.info("person %d starts where person %d's filter is: a second track of one person, given no "
                         "detections", ids[p], ids[q])
                break
    return out


def _duplicates(running: list[int], runs: dict, first: dict[int, int], together: dict, needed: int,
                ids: np.ndarray) -> set[int]:
    """The people whose filter has followed another's person for ``needed`` ticks running (their latest estimates
    within :data:`~priortrack.tracking.association.DUPLICATE_M`, median over the joints; ``together`` counts each
    pair's ticks, updated here): of each such pair the later started, a second track of one person (module
    docstring, 5)."""
    out = set()
    for i, p in enumerate(running):
        for q in running[i + 1:]:
            near = median_distance(runs[p].estimates[runs[p].done - 1], runs[q].estimates[runs[q].done - 1]) < DUPLICATE_M
            together[p, q] = together.get((p, q), 0) + 1 if near else 0
            if together[p, q] >= needed:
                later = max((p, q), key=lambda r: (first[r], r))
                out.add(later)
                log.info("person %d has followed person %d's detections for %d ticks: a second track of one person, "
                         "given no more detections", ids[later], ids[p + q - later], needed)
    return out
