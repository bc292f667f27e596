"""Rerun recordings of real detections tracked by :func:`priortrack.tracking.person.track_detections`.

In the calibration's world (its up axis): every camera as a pinhole with its image size, its
detections (radius and brightness by confidence; green over them, those the unscented filter's
validation gate held out, counted as ``gated/<camera>``) and the estimate's reprojection in its image, the
3D estimate skeleton (a smoothed run: the smoothed one, and the filter's own as "filtered") and the
particle cloud coloured by weight, and per-frame scalars: each
camera's median reprojection error, the ESS, the log-likelihood, the mismatch flag and the held-out ratio
(:mod:`~priortrack.tracking.held_out`; 3+ cameras).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from priortrack.geometry.frames import nearest_axis, up_vector
from priortrack.viz.recording import Recording

from priortrack.viz.logger import ESTIMATE_COLOR, step_events

DETECTION_COLOR, MISMATCH_COLOR = (60, 200, 255), (255, 0, 200)
FILTERED_COLOR = (150, 150, 150)
#: The detections the unscented filter's validation gate held out, drawn over their camera's detections (green:
#: apart from the detections' blue and the estimate's red).
GATED_COLOR = (40, 220, 40)
#: Their radius, image pixels: twice a detection's widest (8), so that a ring of green shows around it.
GATED_RADIUS = 16.0


def record_detections(result, path: str | Path) -> Path:
    """Write ``result`` (a DetectionTrack; the particle cloud at the ticks whose snapshots it kept) to the
    ``.rrd`` file ``path``."""
    snapshots = {s.frame: s for s in result.snapshots or []}
    steps = {s.frame: s for s in result.steps or []}
    with Recording(path, up=nearest_axis(result.up), up_vector=up_vector(result.up),
                   name=f"{result.filter} · detections",
                   colors=(ESTIMATE_COLOR, MISMATCH_COLOR, FILTERED_COLOR, DETECTION_COLOR, GATED_COLOR)) as rec:
        for name, camera in zip(result.camera_names, result.cameras):
            rec.camera(camera, name)
        for t, joints in enumerate(result.joints):
            rec.frame(int(result.frames[t]) if result.frames[t] >= 0 else t)
            if np.isfinite(joints).all():
                rec.skeleton("estimate", joints, color=MISMATCH_COLOR if result.mismatch[t] else ESTIMATE_COLOR)
            if result.filtered_joints is not None and np.isfinite(result.filtered_joints[t]).all():
                rec.skeleton("filtered", result.filtered_joints[t], color=FILTERED_COLOR)
            if t in snapshots:
                cloud = result.in_world(snapshots[t].joints.detach().cpu().numpy(), definitions=False)
                rec.cloud("estimate", cloud, snapshots[t].weights.detach().cpu().numpy())
            for c, (name, camera) in enumerate(zip(result.camera_names, result.cameras)):
                z = result.observations[t, c]
                rec.points_2d("detections", z[:, :2], DETECTION_COLOR, camera=name, confidence=z[:, 2])
                if result.gated[t, c].any():
                    rec.points_2d("gated", np.where(result.gated[t, c][:, None], z[:, :2], np.nan), GATED_COLOR,
                                  camera=name, radius=GATED_RADIUS)
                    rec.scalar(f"gated/{name}", float(result.gated[t, c].sum()))
                if np.isfinite(joints).all():
                    uv, _ = camera.project(torch.as_tensor(joints))
                    rec.points_2d("estimate", uv.numpy(), ESTIMATE_COLOR, camera=name)
                if np.isfinite(result.reprojection_by_tick[t, c]):
                    rec.scalar(f"reprojection_px/{name}", float(result.reprojection_by_tick[t, c]))
            step = steps.get(t)
            if step is not None and np.isfinite(result.ess[t]):           # particles (sigma points have no ESS)
                rec.scalar("ess_fraction", step.ess / step.points)
            rec.scalar("loglik", result.loglik[t])
            rec.scalar("mismatch", float(result.mismatch[t]))
            if np.isfinite(result.held_out_ratio[t]):
                rec.scalar("held_out_ratio", float(result.held_out_ratio[t]))
            observed = bool((np.isfinite(result.observations[t, ..., 0]) & (np.nan_to_num(result.observations[t, ..., 2]) > 0)).any())
            for text, level in step_events(int(result.frames[t]), step, bool(result.mismatch[t]), observed):
                rec.event(text, level)
    return Path(path)
