"""Inverse kinematics: 3D eval15 joint positions (a triangulation, another tool's output) → a Motion.

**The body.** A template skeleton (CMU subject 35's by default, whose channel layout every bundled
prior uses) is fitted to the measured bone lengths: each of the 14 eval15 bones (joint j to its
parent p) is scaled by s = ℓ_measured / ℓ_template, applied to the rest offsets of the skeleton
joints on the path from p to j (a detector's hips, shoulders and head are not CMU's: scaling the
chain to the detector's distances makes the fitted body use the detector's joint definitions).

**The pose.** The channels θ (T, C) minimise, over the frames at once,

    Σ_t Σ_j m_tj |FK(θ_t)_j − X_tj|² + λ Σ_t |θ_t^rot|²,

m_tj = 0 where X_tj is NaN, λ = ``REGULARISATION`` (a small pull to the rest pose that fixes the
dofs the 15 joints do not see: wrist and foot twists, fingers), by L-BFGS in float64. The start
puts the root at the pelvis and turns it about the vertical to the best of ``HEADINGS`` headings.
The world is Y-up, as the mocap the priors learned from (turn a Z-up calibration's world first:
:func:`priortrack.geometry.frames.to_y_up`).
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

#: λ, the weight (m² per rad²) of the pull of the rotation channels to zero.
REGULARISATION = 1e-4
#: Root headings tried for the start.
HEADINGS = 12
#: L-BFGS iterations of the fit.
ITERATIONS = 200


def bone_lengths(X: np.ndarray) -> np.ndarray:
    """(14,) median length of each eval15 bone (joint j = 1…14 to its parent) over frames X (T, 15, 3),
    NaN frames left out; left and right bones averaged (a detector's sides differ by noise only)."""
    X = np.asarray(X, dtype=np.float64)
    lengths = np.nanmedian(np.linalg.norm(X[:, 1:] - X[:, EVAL15_PARENTS[1:]], axis=-1), axis=0)
    for left, right in ((3, 6), (4, 7), (5, 8), (9, 12), (10, 13), (11, 14)):
        both = np.nanmean(lengths[[left - 1, right - 1]])
        lengths[[left - 1, right - 1]] = both
    if not np.isfinite(lengths).all():
        missing = [j for j in range(1, 15) if not np.isfinite(lengths[j - 1])]
        raise PriortrackError(f"bone lengths: eval15 joints {missing} are never measured with their parents")
    return lengths


def fitted_skeleton(template: Skeleton, lengths: np.ndarray) -> Skeleton:
    """The template with each eval15 bone's chain of rest offsets scaled to ``lengths`` (14,) metres."""
    index = eval15_indices(template)
    offsets = template.offsets.copy()
    points = ForwardKinematics(template, dtype=torch.float64)(np.zeros(template.num_channels)).numpy()   # rest pose
    rest = points[index]
    for j in range(1, 15):
        parent = EVAL15_PARENTS[j]
        measured = float(np.linalg.norm(rest[j] - rest[parent]))
        if measured < 1e-9:
            raise PriortrackError(f"skeleton {template.name!r}: eval15 bone {j} has zero length")
        # The skeleton joints from j up to the parent's point (a sibling chain may start there:
        # CMU's clavicles and neck both start at the thorax's end).
        chain, k = [], int(index[j])
        while k > 0 and np.linalg.norm(points[k] - rest[parent]) > 1e-9:
            chain.append(k)
            k = int(template.parents[k])
        if np.linalg.norm(points[k] - rest[parent]) > 1e-9:
            raise PriortrackError(f"skeleton {template.name!r}: eval15 joint {j} is not below its parent")
        offsets[chain] *= lengths[j - 1] / measured
    return replace(template, offsets=offsets, name=f"{template.name}-fitted")


def inverse_kinematics(X: np.ndarray, fps: float, template: Skeleton | None = None, name: str = "ik",
                       lengths: np.ndarray | None = None) -> Motion:
    """A Motion whose eval15 joints best match X (T, 15, 3) metres in a Y-up world (NaN = unknown),
    on the template (default: CMU subject 35) scaled to ``lengths`` (14,) (default: :func:`bone_lengths`
    of X)."""
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
    skeleton = fitted_skeleton(template, bone_lengths(X) if lengths is None else np.asarray(lengths, dtype=float))
    channels = _fit(skeleton, X, seen)
    return Motion(skeleton, channels, float(fps), name)


def _fit(skeleton: Skeleton, X: np.ndarray, seen: np.ndarray) -> np.ndarray:
    T = len(X)
    fk = ForwardKinematics(skeleton, dtype=torch.float64)
    index = eval15_indices(skeleton)
    target = torch.as_tensor(np.where(seen[..., None], X, 0.0))
    mask = torch.as_tensor(seen, dtype=torch.float64)[..., None]
    rotation = torch.ones(skeleton.num_channels, dtype=torch.bool)
    rotation[torch.as_tensor(skeleton.trans_channels[skeleton.trans_channels >= 0])] = False
    root_t = skeleton.trans_channels[0]
    heading_slot = int(np.argmax(np.abs(skeleton.rot_axes[0, :, 1])))           # the root's turn about y
    heading_channel = int(skeleton.rot_channels[0, heading_slot])

    def loss(theta: torch.Tensor) -> torch.Tensor:
        joints = fk(theta, joints=index)
        return ((joints - target) ** 2 * mask).sum() + REGULARISATION * (theta[:, rotation] ** 2).sum()

    def start(heading: float) -> torch.Tensor:
        theta = torch.zeros((T, skeleton.num_channels), dtype=torch.float64)
        pelvis = np.where(seen[:, :1], X[:, :1], np.nanmean(X, axis=1, keepdims=True))[:, 0]
        rest = fk(torch.zeros(skeleton.num_channels, dtype=torch.float64), joints=index[:1])[0]
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
