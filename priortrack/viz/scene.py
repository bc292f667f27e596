"""Rerun recordings of a scene tracked by :func:`priortrack.tracking.people.track_scene`.

In the calibration's world: every camera as a pinhole with its image size; each person's skeleton in
their own colour with a label (``person <id>``) at ``world/person<id>``; in each camera's image, the
detections the scene tracker gave each person, in that person's colour, the detections it gave nobody
in grey (``unassigned``: false positives, people seen by one camera), each person's estimate
reprojected, and the association (``association/person<id>``: a segment from each joint of a detection to
the same joint of the estimate of the person it was given to); each person's particle cloud coloured by weight
(``person<id>/cloud``, at the ticks whose snapshots their run kept) and per-frame scalars per person: each camera's
median reprojection error, the ESS fraction (particles), the log-likelihood, the mismatch flag and the held-out ratio
(these in the person's colour); each person's events (resampling, the filter's flags, mismatch), prefixed
``person <id>:``. A mismatch tick draws the person's skeleton in the mismatch colour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from priortrack.data.keypoints import to_eval15
from priortrack.geometry.frames import nearest_axis, up_vector
from priortrack.viz.logger import step_events
from priortrack.viz.real import MISMATCH_COLOR
from priortrack.viz.recording import Recording

#: One colour per person, in order of their ids (repeating past ten).
PERSON_COLORS = ((230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180),
                 (70, 240, 240), (240, 50, 230), (210, 245, 60), (0, 128, 128), (170, 110, 40))
UNASSIGNED_COLOR = (150, 150, 150)


def person_color(person_id: int) -> tuple[int, int, int]:
    return PERSON_COLORS[int(person_id) % len(PERSON_COLORS)]


def _own_step(rec: Recording, scene, p: int, t: int, snapshots: dict, steps: dict) -> None:
    """Person p's own run at the scene's tick t: their particle cloud (``snapshots`` {tick: snapshot} of their run,
    where kept), ESS fraction and events (``steps`` {tick: step record})."""
    result, pid = scene.people[p], int(scene.person_ids[p])
    k = t - int(scene.starts[p]) if scene.starts is not None else -1
    if not 0 <= k < len(result.joints):
        return
    if k in snapshots:
        cloud = result.in_world(snapshots[k].joints.detach().cpu().numpy(), definitions=False)
        rec.cloud(f"person{pid}", cloud, snapshots[k].weights.detach().cpu().numpy())
    step = steps.get(k)
    if step is not None and np.isfinite(result.ess[k]):                  # particles (sigma points have no ESS)
        rec.scalar(f"ess_fraction/person{pid}", step.ess / step.points, person_color(pid))
    for text, level in step_events(int(result.frames[k]), step, bool(result.mismatch[k])):
        rec.event(f"person {pid}: {text}", level)


def record_scene(scene, path: str | Path, min_confidence: float = 0.3) -> Path:
    """Write ``scene`` (a SceneTrack) to the ``.rrd`` file ``path``."""
    first = scene.people[0]
    names, cameras = first.camera_names, first.cameras
    slots = scene.association.slots                                          # (T_frames, C, P_all)
    columns = [int(np.flatnonzero(scene.association.person_ids == pid)[0]) for pid in scene.person_ids]
    colors = [person_color(pid) for pid in scene.person_ids] + [MISMATCH_COLOR, UNASSIGNED_COLOR]
    own = [({s.frame: s for s in r.snapshots or []}, {s.frame: s for s in r.steps or []}) for r in scene.people]
    with Recording(path, up=nearest_axis(first.up), up_vector=up_vector(first.up),
                   name=f"{first.filter} · scene of {len(scene.person_ids)}", colors=colors) as rec:
        for name, camera in zip(names, cameras):
            rec.camera(camera, name)
        for t, frame in enumerate(scene.frames):
            rec.frame(int(frame) if frame >= 0 else t)
            estimates = {}                                                   # {(person id, camera): uv (15, 2)}
            for p, pid in enumerate(scene.person_ids):
                joints = scene.joints[t, p]
                if not np.isfinite(joints).all():
                    continue
                color = MISMATCH_COLOR if scene.mismatch[t, p] else person_color(pid)
                rec.skeleton(f"person{pid}", joints, color=color, label=f"person {pid}")
                for name, camera in zip(names, cameras):
                    uv = camera.project(torch.as_tensor(joints))[0].numpy()
                    estimates[pid, name] = uv
                    rec.points_2d(f"estimate/person{pid}", uv, person_color(pid), camera=name, radius=2.0)
                _own_step(rec, scene, p, t, *own[p])
                rec.scalar(f"loglik/person{pid}", scene.loglik[t, p], person_color(pid))
                rec.scalar(f"mismatch/person{pid}", float(scene.mismatch[t, p]), person_color(pid))
                if np.isfinite(scene.held_out_ratio[t, p]):
                    rec.scalar(f"held_out_ratio/person{pid}", float(scene.held_out_ratio[t, p]), person_color(pid))
            f = scene.index[t]
            if f < 0:
                continue
            for c, name in enumerate(names):
                keypoints = scene.detections.keypoints[c, f]                    # (N, K, 3)
                uv, confidence = to_eval15(keypoints, scene.detections.keypoint_names, min_confidence)
                owned = {int(slots[f, c, q]): pid for q, pid in zip(columns, scene.person_ids) if slots[f, c, q] >= 0}
                for n in range(len(keypoints)):
                    if not np.isfinite(uv[n]).any():
                        continue
                    pid = owned.get(n)
                    rec.points_2d("unassigned" if pid is None else f"detections/person{pid}", uv[n],
                                  UNASSIGNED_COLOR if pid is None else person_color(pid), camera=name,
                                  confidence=confidence[n])
                    if (pid, name) in estimates:
                        rec.links_2d(f"association/person{pid}", uv[n], estimates[pid, name], person_color(pid),
                                     camera=name, label=f"person {pid}")
                        miss = np.linalg.norm(uv[n] - estimates[pid, name], axis=-1)
                        if np.isfinite(miss).any():
                            rec.scalar(f"reprojection_px/person{pid}/{name}", float(np.nanmedian(miss)))
    return Path(path)
