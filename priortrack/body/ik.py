"""Inverse kinematics: 3D eval15 joint positions (a triangulation, another tool's output) → a Motion.

**Joint definitions.** The targets may follow a detector's definitions (pelvis = mid-hips, neck =
mid-shoulders: :func:`priortrack.data.keypoints.detector_map`, M); the body's own eval15 joints X are
then compared through M X. Without M, the targets are the body's eval15 joints themselves.

**The body.** A template skeleton (CMU subject 35's by default, whose channel layout every bundled
prior uses) is scaled to the targets: each eval15 bone (joint j to its parent) gets the factor
s = d_measured / d_template of the distance that measures it in the targets' definitions (medians
over frames; left and right averaged): upper arm, forearm, thigh and shin for the limbs, the
shoulder and hip widths for the neck→shoulder and pelvis→hip bones, mid-hips to mid-shoulders for the
trunk, mid-shoulders to the head for the head. The factor scales the rest offsets of the skeleton
joints on the bone's path (CMU's clavicles and neck both start at the thorax's end).

**The pose.** The channels θ (T, C) minimise, over the frames at once,

    Σ_t Σ_j m_tj |(M FK(θ_t))_j − X_tj|² + λ Σ_t |θ_t^rot|² + μ Σ_t |θ_t − θ_{t−1}|²,

m_tj = 0 where X_tj is NaN, λ = ``REGULARISATION`` (a small pull to the rest pose that fixes the
dofs the 15 joints do not see: wrist and foot twists, fingers) and μ = ``SMOOTHNESS`` (consecutive
frames alike: a joint missing in one frame follows its neighbours, and the root does not jump
where a frame lacks a limb), by L-BFGS in float64. The start
puts the root at the pelvis and turns it about the vertical to the best of ``HEADINGS`` headings.
The world is Y-up, as the mocap the priors learned from (turn a Z-up calibration's world first:
:func:`priortrack.geometry.frames.to_y_up`).

**From one camera** (:func:`inverse_kinematics_2d`): the data term is the confidence-weighted
squared pixel error of the projected joints, scaled by (depth / f)² to metres at the subject; the
body is the template scaled to a given standing height; the start's root sits on the ray through
the detected pelvis at the depth where the body's size matches its image (f × neck-to-ankles
length / its length in pixels).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import torch

from priortrack.body.fk import ForwardKinematics
from priortrack.body.layout import eval15_indices
from priortrack.data.eval15 import EVAL15_PARENTS
from priortrack.data.motion import Motion
from priortrack.data.skeleton import Skeleton
from priortrack.errors import PriortrackError
from priortrack.threads import torch_threads

#: λ, the weight (m² per rad²) of the pull of the rotation channels to zero.
REGULARISATION = 1e-4
#: μ, the weight (m² per unit of channel change) of the difference between consecutive frames.
SMOOTHNESS = 1e-2
#: Root headings tried for the start.
HEADINGS = 12
#: L-BFGS iterations of the fit.
ITERATIONS = 200
#: torch threads of a fit: its tensors are small (a frame's ~30 joints × T), and with a second process on a
#: 2-core machine two threads took 40–308 s for a 120-frame fit that one thread does in 4–5 s (both threads
#: spin-waiting for a core the other process holds).
IK_THREADS = 1
#: Frames fitted together at most by :func:`inverse_kinematics`: a longer motion is fitted in consecutive
#: chunks (20 s at 30 fps), so that its memory does not grow with the motion (1,800 frames at once held
#: 590 MB, in chunks 517 MB); the smoothness term is not carried across a chunk's edge.
CHUNK = 600


#: eval15 bone (child joint) → the distance (a pair of joints, or of joint pairs' midpoints) that
#: measures it, with its mirror; by eval15 index.
_MEASURES = {
    1: (((9, 12), (3, 6)), None),                     # trunk: mid-hips to mid-shoulders
    2: (((3, 6), (2,)), None),                        # head: mid-shoulders to the head
    3: (((3,), (6,)), None), 6: (((3,), (6,)), None),  # shoulder width
    9: (((9,), (12,)), None), 12: (((9,), (12,)), None),  # hip width
    4: (((3,), (4,)), ((6,), (7,))), 7: (((3,), (4,)), ((6,), (7,))),        # upper arms
    5: (((4,), (5,)), ((7,), (8,))), 8: (((4,), (5,)), ((7,), (8,))),        # forearms
    10: (((9,), (10,)), ((12,), (13,))), 13: (((9,), (10,)), ((12,), (13,))),  # thighs
    11: (((10,), (11,)), ((13,), (14,))), 14: (((10,), (11,)), ((13,), (14,))),  # shins
}


def _distance(X: np.ndarray, pair) -> np.ndarray:
    a, b = (X[..., list(ends), :].mean(axis=-2) for ends in pair)
    return np.linalg.norm(a - b, axis=-1)


def measured_distances(X: np.ndarray) -> np.ndarray:
    """(14,) the median over frames X (T, 15, 3) of the distance measuring each eval15 bone (left and
    right averaged), NaN frames left out."""
    X = np.asarray(X, dtype=np.float64)
    out = np.empty(14)
    for j, (pair, mirror) in _MEASURES.items():
        values = _distance(X, pair) if mirror is None else np.concatenate([_distance(X, pair), _distance(X, mirror)])
        out[j - 1] = np.nanmedian(values) if np.isfinite(values).any() else np.nan
    if not np.isfinite(out).all():
        missing = [j for j in range(1, 15) if not np.isfinite(out[j - 1])]
        raise PriortrackError(f"body size: the distances measuring eval15 joints {missing} are never measured")
    return out


#: The body's distinct measures (module docstring), each named, by the eval15 joint whose bone it scales.
BODY_MEASURES = {"trunk": 1, "head": 2, "shoulder_width": 3, "hip_width": 9, "upper_arm": 4, "forearm": 5,
                 "thigh": 10, "shin": 11}


def _rest(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """The skeleton's joints in its rest pose (all channels 0), (N, 3), and its eval15 joints (15, 3)."""
    points = ForwardKinematics(skeleton, dtype=torch.float64)(np.zeros(skeleton.num_channels)).numpy()
    return points, points[eval15_indices(skeleton)]


def body_measures(skeleton: Skeleton, joint_map: np.ndarray | None = None) -> dict[str, float]:
    """{measure: metres} of :data:`BODY_MEASURES` on the skeleton's rest pose, in the targets'
    definitions (``joint_map`` M applied): the body a tracker fitted, as a person would measure it."""
    M = np.eye(15) if joint_map is None else np.asarray(joint_map, dtype=np.float64)
    distances = measured_distances((M @ _rest(skeleton)[1])[None])
    return {name: float(distances[j - 1]) for name, j in BODY_MEASURES.items()}


def fitted_skeleton(template: Skeleton, X: np.ndarray, joint_map: np.ndarray | None = None) -> Skeleton:
    """The template scaled so that its distances (module docstring) match those of the targets X
    (T, 15, 3), both in the targets' definitions (``joint_map`` M applied to the template)."""
    index = eval15_indices(template)
    offsets = template.offsets.copy()
    points, rest = _rest(template)
    M = np.eye(15) if joint_map is None else np.asarray(joint_map, dtype=np.float64)
    scale = measured_distances(X) / measured_distances((M @ rest)[None])
    for j in range(1, 15):
        parent = EVAL15_PARENTS[j]
        chain, k = [], int(index[j])
        while k > 0 and np.linalg.norm(points[k] - rest[parent]) > 1e-9:
            chain.append(k)
            k = int(template.parents[k])
        if np.linalg.norm(points[k] - rest[parent]) > 1e-9:
            raise PriortrackError(f"skeleton {template.name!r}: eval15 joint {j} is not below its parent")
        offsets[chain] *= scale[j - 1]
    return replace(template, offsets=offsets, name=f"{template.name}-fitted")


def inverse_kinematics(X: np.ndarray, fps: float, template: Skeleton | None = None, name: str = "ik",
                       joint_map: np.ndarray | None = None, skeleton: Skeleton | None = None) -> Motion:
    """A Motion whose eval15 joints (through ``joint_map`` M, if given) best match X (T, 15, 3) metres in
    a Y-up world (NaN = unknown), on ``skeleton``, or else the template (default: CMU subject 35)
    scaled to X (:func:`fitted_skeleton`)."""
    if template is None:
        from priortrack.data.bundled import cmu_skeleton

        template = cmu_skeleton("35")
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 3 or X.shape[1:] != (15, 3) or len(X) < 1:
        raise PriortrackError(f"inverse kinematics: joints have shape {X.shape}; expected (T, 15, 3)")
    if np.isinf(X).any():
        raise PriortrackError("inverse kinematics: joints contain inf")
    seen = np.isfinite(X).all(axis=-1)
    if (seen.sum(axis=1) < 6).any():
        raise PriortrackError(f"inverse kinematics: frames {np.flatnonzero(seen.sum(axis=1) < 6).tolist()} have "
                              f"fewer than 6 known joints")
    M = np.eye(15) if joint_map is None else np.asarray(joint_map, dtype=np.float64)
    skeleton = skeleton or fitted_skeleton(template, X, M)
    target = torch.as_tensor(np.where(seen[..., None], X, 0.0))
    mask = torch.as_tensor(seen, dtype=torch.float64)[..., None]
    pelvis = np.where(seen[:, :1, None], X[:, :1], np.nanmean(X, axis=1, keepdims=True))[:, 0]
    parts = [slice(start, min(start + CHUNK, len(X))) for start in range(0, len(X), CHUNK)]
    channels = np.concatenate([
        _fit(skeleton, part.stop - part.start,
             lambda joints, part=part: ((joints - target[part]) ** 2 * mask[part]).sum(), pelvis[part], M)
        for part in parts])
    return Motion(skeleton, channels, float(fps), name)


def scaled_to_height(template: Skeleton, height: float) -> Skeleton:
    """The template scaled uniformly so that its rest pose's head top stands ``height`` metres above its
    lower ankle (a detector's ankle, not the sole: about 5 cm short of the standing height)."""
    if not 0.5 < height < 2.6:
        raise PriortrackError(f"height must be a person's standing height in metres (0.5–2.6), got {height}")
    rest = ForwardKinematics(template, dtype=torch.float64)(np.zeros(template.num_channels))[
        eval15_indices(template)].numpy()
    measured = rest[2, 1] - min(rest[11, 1], rest[14, 1])
    return replace(template, offsets=template.offsets * (height - ANKLE_HEIGHT) / measured,
                   name=f"{template.name}-{height:g}m")


#: Height of a detector's ankle point above the floor, metres.
ANKLE_HEIGHT = 0.07


def inverse_kinematics_2d(uv: np.ndarray, weights: np.ndarray, camera, fps: float, skeleton: Skeleton,
                          joint_map: np.ndarray | None = None, name: str = "ik") -> Motion:
    """A Motion of ``skeleton`` whose eval15 joints (through ``joint_map`` M) project through ``camera``
    (a Y-up world) onto uv (T, 15, 2) pixels, weighted by ``weights`` (T, 15) (0 = unseen)."""
    uv, weights = np.asarray(uv, dtype=np.float64), np.asarray(weights, dtype=np.float64)
    seen = np.isfinite(uv).all(axis=-1) & (weights > 0)
    if uv.ndim != 3 or uv.shape[1:] != (15, 2) or weights.shape != uv.shape[:2]:
        raise PriortrackError(f"inverse kinematics: pixels {uv.shape} and weights {weights.shape}; expected "
                              f"(T, 15, 2) and (T, 15)")
    if (seen.sum(axis=1) < 8).any():
        raise PriortrackError(f"inverse kinematics from one camera: frames {np.flatnonzero(seen.sum(axis=1) < 8).tolist()}"
                              f" have fewer than 8 detected joints")
    M = np.eye(15) if joint_map is None else np.asarray(joint_map, dtype=np.float64)
    index = eval15_indices(skeleton)
    rest = M @ ForwardKinematics(skeleton, dtype=torch.float64)(np.zeros(skeleton.num_channels))[index].numpy()
    size_3d = np.linalg.norm(rest[1] - (rest[11] + rest[14]) / 2)                # neck to mid-ankles, metres
    ankles = np.where(seen[:, [11, 14]].all(axis=1)[:, None], uv[:, [11, 14]].mean(axis=1), np.nan)
    size_px = np.nanmedian(np.linalg.norm(uv[:, 1] - ankles, axis=-1))
    if not np.isfinite(size_px) or size_px < 1:
        raise PriortrackError("inverse kinematics from one camera: the neck and both ankles are never seen together")
    depth = camera.fx * size_3d / size_px
    K = camera.K.double().numpy()
    R, t = camera.R.double().numpy(), camera.t.double().numpy()
    centre = np.where(seen[:, :1], uv[:, 0], np.nanmean(np.where(seen[..., None], uv, np.nan), axis=1))
    ray = np.linalg.solve(K, np.concatenate([centre, np.ones((len(uv), 1))], axis=1).T).T          # (T, 3)
    pelvis = (ray * depth - t) @ R                                                 # R^T (X_c − t), per row
    target = torch.as_tensor(np.where(seen[..., None], uv, 0.0))
    w = torch.as_tensor(np.where(seen, weights, 0.0))[..., None] * (depth / camera.fx) ** 2

    def data(joints: torch.Tensor) -> torch.Tensor:
        projected, _ = camera.project(joints)
        return (torch.where(torch.isfinite(projected), projected - target, 0.0) ** 2 * w).sum()

    channels = _fit(skeleton, len(uv), data, pelvis, M)
    return Motion(skeleton, channels, float(fps), name)


def _fit(skeleton: Skeleton, T: int, data, pelvis: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Channels (T, C) minimising data(M FK(θ)) + the regularisation and smoothness (module docstring),
    from the root at ``pelvis`` (T, 3) turned to the best of HEADINGS headings, on IK_THREADS torch threads."""
    with torch_threads(IK_THREADS):
        return _fit_threads(skeleton, T, data, pelvis, M)


def _fit_threads(skeleton: Skeleton, T: int, data, pelvis: np.ndarray, M: np.ndarray) -> np.ndarray:
    fk = ForwardKinematics(skeleton, dtype=torch.float64)
    index = eval15_indices(skeleton)
    rotation = torch.ones(skeleton.num_channels, dtype=torch.bool)
    rotation[torch.as_tensor(skeleton.trans_channels[skeleton.trans_channels >= 0])] = False
    root_t = skeleton.trans_channels[0]
    heading_slot = int(np.argmax(np.abs(skeleton.rot_axes[0, :, 1])))           # the root's turn about y
    heading_channel = int(skeleton.rot_channels[0, heading_slot])

    M = torch.as_tensor(M)

    def loss(theta: torch.Tensor) -> torch.Tensor:
        joints = torch.einsum("ij,tjk->tik", M, fk(theta, joints=index))
        return (data(joints) + REGULARISATION * (theta[:, rotation] ** 2).sum()
                + SMOOTHNESS * ((theta[1:] - theta[:-1]) ** 2).sum())

    def start(heading: float) -> torch.Tensor:
        theta = torch.zeros((T, skeleton.num_channels), dtype=torch.float64)
        rest = (M @ fk(torch.zeros(skeleton.num_channels, dtype=torch.float64), joints=index))[0]
        theta[:, torch.as_tensor(root_t)] = torch.as_tensor(pelvis) - rest
        if heading_channel >= 0:
            theta[:, heading_channel] = heading
        return theta

    with torch.no_grad():
        candidates = [start(2 * math.pi * k / HEADINGS) for k in range(HEADINGS)]
        best = min(candidates, key=lambda th: float(loss(th)))
    theta = best.clone().requires_grad_(True)
    optimiser = torch.optim.LBFGS([theta], max_iter=ITERATIONS, tolerance_grad=1e-10, tolerance_change=1e-14,
                                  history_size=20, line_search_fn="strong_wolfe")

    def closure():
        optimiser.zero_grad()
        value = loss(theta)
        value.backward()
        return value

    optimiser.step(closure)
    return theta.detach().numpy()
