"""Pose normalisation and bone directions, as in the Lie-algebra prior (Simo-Serra et al. 2015).

The body frame of an ``eval15`` pose: origin h at the hip centre, second axis y along the
hip-centre-to-neck line, third axis z the normal of the plane through both hips and the neck,
first axis x = y × z:

    y = (n − h)/|n − h|,   z = (l − r) × (n − h) / |…|,   x = y × z,

so that for an upright person x points to their left, y up and z forward. A pose in that
frame is b_i = R (p_i − h) with R = [x; y; z] (rows). Its 14 bones (each ``eval15`` joint to
its parent) give unit directions d_i = (b_i − b_parent)/ℓ_i on S² and lengths ℓ_i; these
(with h and R) give the positions back exactly, the pelvis at −(ℓ_lhip d_lhip + ℓ_rhip d_rhip)/2.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from priortrack.data.eval15 import EVAL15_NAMES, EVAL15_PARENTS
from priortrack.errors import PriortrackError

PELVIS, NECK, LHIP, RHIP = (EVAL15_NAMES.index(n) for n in ("pelvis", "neck", "lhip", "rhip"))
#: The 14 bones, as child joint indices 1..14 of eval15 (bone k is joint k + 1 to its parent).
BONE_CHILDREN = tuple(range(1, len(EVAL15_NAMES)))
BONE_PARENTS = tuple(int(EVAL15_PARENTS[j]) for j in BONE_CHILDREN)
_EPS = 1e-9


@dataclass
class NormalisedPose:
    """An ``eval15`` pose split into global placement and body-frame shape.

    Attributes:
        origin: (..., 3) hip centre h in world coordinates, metres.
        rotation: (..., 3, 3) R, world → body frame (rows x, y, z of the body frame).
        directions: (..., 14, 3) unit bone directions in the body frame, points of (S²)¹⁴.
        lengths: (..., 14) bone lengths, metres.
    """

    origin: torch.Tensor
    rotation: torch.Tensor
    directions: torch.Tensor
    lengths: torch.Tensor


def _unit(v: torch.Tensor, what: str) -> torch.Tensor:
    norm = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
    if torch.any(norm < _EPS):
        raise PriortrackError(f"positions: {what} is degenerate (zero length) in at least one frame")
    return v / norm


def _check(positions) -> torch.Tensor:
    positions = torch.as_tensor(positions)
    if positions.dim() < 2 or positions.shape[-2:] != (len(EVAL15_NAMES), 3):
        raise PriortrackError(f"positions has shape {tuple(positions.shape)}; expected (..., 15, 3) eval15 joints")
    if not torch.all(torch.isfinite(positions)):
        raise PriortrackError("positions contains NaN or inf")
    return positions


def body_frame(positions) -> tuple[torch.Tensor, torch.Tensor]:
    """Origin h (..., 3) and rotation R (..., 3, 3) of the body frame of eval15 ``positions`` (..., 15, 3)."""
    positions = _check(positions)
    left, right, neck = positions[..., LHIP, :], positions[..., RHIP, :], positions[..., NECK, :]
    h = 0.5 * (left + right)
    y = _unit(neck - h, "the hip-centre-to-neck line")
    z = _unit(torch.linalg.cross(left - right, neck - h), "the plane through the hips and the neck")
    x = torch.linalg.cross(y, z)
    return h, torch.stack([x, y, z], dim=-2)


def normalise(positions) -> NormalisedPose:
    """Split eval15 ``positions`` (..., 15, 3) into origin, rotation, bone directions and lengths."""
    h, R = body_frame(positions)
    positions = torch.as_tensor(positions)
    bones = positions[..., BONE_CHILDREN, :] - positions[..., BONE_PARENTS, :]
    bones = torch.einsum("...ij,...kj->...ki", R, bones)
    lengths = torch.linalg.vector_norm(bones, dim=-1)
    return NormalisedPose(h, R, _unit(bones, "a bone"), lengths)


def body_positions(directions, lengths) -> torch.Tensor:
    """(..., 15, 3) eval15 positions in the body frame from directions (..., 14, 3) and lengths (..., 14)."""
    directions, lengths = torch.as_tensor(directions), torch.as_tensor(lengths)
    if directions.shape[-2:] != (len(BONE_CHILDREN), 3) or lengths.shape != directions.shape[:-1]:
        raise PriortrackError(f"directions {tuple(directions.shape)} and lengths {tuple(lengths.shape)}: "
                              f"expected (..., 14, 3) and (..., 14)")
    bones = lengths[..., None] * directions
    joints: list[torch.Tensor | None] = [None] * len(EVAL15_NAMES)
    joints[PELVIS] = -0.5 * (bones[..., LHIP - 1, :] + bones[..., RHIP - 1, :])
    for k, (child, parent) in enumerate(zip(BONE_CHILDREN, BONE_PARENTS)):
        joints[child] = joints[parent] + bones[..., k, :]
    return torch.stack(joints, dim=-2)


def denormalise(pose: NormalisedPose) -> torch.Tensor:
    """(..., 15, 3) world positions p_i = h + Rᵀ b_i from a :class:`NormalisedPose`."""
    b = body_positions(pose.directions, pose.lengths)
    return pose.origin[..., None, :] + torch.einsum("...ji,...kj->...ki", pose.rotation, b)
