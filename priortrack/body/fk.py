"""Batched forward kinematics in torch: channels (B, C) → joint positions (B, J, 3).

For every joint (see :mod:`priortrack.body.skeleton`)

    L_j = Π_k R_{a_k}(θ_k),   R_a(θ) = I + sin θ [a]_× + (1 − cos θ) [a]_×²   (Rodrigues),
    G_j = G_parent · L_j,     p_j = p_parent + G_parent · (o_j + T_j).

All joints' local rotations are built at once; the tree is then walked one depth level at a
time, so a skeleton of depth D costs D batched 3×3 products, whatever the batch size.
"""

from __future__ import annotations

import numpy as np
import torch

from priortrack.body.skeleton import SLOTS, Skeleton, check_channels
from priortrack.errors import PriortrackError


def _cross_matrix(a: np.ndarray) -> np.ndarray:
    """(..., 3) → (..., 3, 3) the matrix [a]_× with [a]_× v = a × v."""
    K = np.zeros(a.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -a[..., 2], a[..., 1]
    K[..., 1, 0], K[..., 1, 2] = a[..., 2], -a[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -a[..., 1], a[..., 0]
    return K


def _matmul3(A: torch.Tensor, B: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) @ (..., 3, 3) as three broadcast multiply-adds: on CPU much faster than
    a batched matmul for millions of 3×3 products."""
    return A[..., :, 0:1] * B[..., 0:1, :] + A[..., :, 1:2] * B[..., 1:2, :] + A[..., :, 2:3] * B[..., 2:3, :]


class ForwardKinematics:
    """Forward kinematics of one skeleton on one device and dtype.

    Example::

        fk = ForwardKinematics(skeleton, dtype=torch.float32)
        positions = fk(channels)          # (B, C) → (B, J, 3), metres
        positions, G = fk(channels, rotations=True)   # G: (B, J, 3, 3) global rotations

    Internally tensors are joint-major, (J, B, 3, 3), so that gathering the parents of a
    depth level copies contiguous blocks.
    """

    def __init__(self, skeleton: Skeleton, device: str | torch.device = "cpu",
                 dtype: torch.dtype = torch.float64):
        self.skeleton = skeleton
        self.device = torch.device(device)
        self.dtype = dtype
        as_t = lambda a, **kw: torch.as_tensor(a, device=self.device, **kw)  # noqa: E731
        J = skeleton.num_joints
        used = skeleton.rot_channels >= 0
        # Every used rotation slot, joint-major: its channel and [a]×, [a]×² of its axis.
        self._slot_channel = as_t(skeleton.rot_channels[used])
        K = _cross_matrix(skeleton.rot_axes[used])[:, None]            # (N, 1, 3, 3)
        self._K, self._K2 = as_t(K, dtype=dtype), as_t(K @ K, dtype=dtype)
        # L_j = Π_k E_{slot(j, k)}: for slot position k, which joints have it and where.
        slot_id = -np.ones_like(skeleton.rot_channels)
        slot_id[used] = np.arange(used.sum())
        self._rotating = as_t(np.flatnonzero(used[:, 0]))
        self._slots = [(as_t(np.flatnonzero(used[used[:, 0], k])), as_t(slot_id[used[:, k], k]))
                       for k in range(SLOTS)]
        self._offsets = as_t(skeleton.offsets[:, None, :], dtype=dtype)   # (J, 1, 3)
        trans = skeleton.trans_channels
        self._translated = as_t(np.flatnonzero(np.any(trans >= 0, axis=1)))
        self._trans_index = as_t(np.where(trans < 0, skeleton.num_channels, trans)[np.any(trans >= 0, axis=1)])
        depth = np.zeros(J, dtype=int)
        for j in range(1, J):
            depth[j] = depth[skeleton.parents[j]] + 1
        # Joints grouped by depth; each level's parents indexed within the previous level.
        self._levels: list[tuple[torch.Tensor, torch.Tensor]] = []
        order: list[int] = []
        previous: list[int] = []
        for d in range(depth.max() + 1):
            joints = [int(j) for j in np.flatnonzero(depth == d)]
            parent_pos = [previous.index(skeleton.parents[j]) for j in joints] if d else []
            self._levels.append((as_t(joints), as_t(parent_pos, dtype=torch.long)))
            order += joints
            previous = joints
        self._inverse_order = as_t(np.argsort(order))

    def _local(self, channels: torch.Tensor) -> torch.Tensor:
        """(B, C) → (J, B, 3, 3) local rotations, R_a(θ) = I + sin θ [a]× + (1 − cos θ) [a]×²."""
        B = channels.shape[0]
        theta = channels[:, self._slot_channel].T[..., None, None]        # (N, B, 1, 1)
        E = torch.sin(theta) * self._K + (1.0 - torch.cos(theta)) * self._K2
        E.diagonal(dim1=-2, dim2=-1).add_(1.0)
        L = torch.eye(3, dtype=self.dtype, device=self.device).repeat(self.skeleton.num_joints, B, 1, 1)
        rotating = E[self._slots[0][1]]
        for joints, slots in self._slots[1:]:
            rotating[joints] = _matmul3(rotating[joints], E[slots])
        L[self._rotating] = rotating
        return L

    def local_rotations(self, channels) -> torch.Tensor:
        """(B, C) channels → (B, J, 3, 3) local rotations L_j."""
        channels = self._as_batch(channels)
        return self._local(channels).transpose(0, 1)

    def _as_batch(self, channels) -> torch.Tensor:
        channels = torch.as_tensor(channels, dtype=self.dtype, device=self.device)
        check_channels(channels, self.skeleton)
        if channels.dim() != 2:
            raise PriortrackError(f"channels has shape {tuple(channels.shape)}; expected (B, "
                                  f"{self.skeleton.num_channels}) or ({self.skeleton.num_channels},)")
        return channels

    def __call__(self, channels, rotations: bool = False):
        """Joint positions (B, J, 3) in metres (and global rotations (B, J, 3, 3) if asked).

        Args:
            channels: (B, C) or (C,) tensor or array, translations in metres, rotations in
                radians, in ``skeleton.channel_names`` order.
        """
        single = torch.as_tensor(channels).dim() == 1
        channels = self._as_batch(channels[None] if single else channels)
        B = channels.shape[0]
        L = self._local(channels)
        t = self._offsets.expand(-1, B, -1)
        if len(self._translated):
            padded = torch.nn.functional.pad(channels, (0, 1))
            t = t.clone()
            t[self._translated] += padded[:, self._trans_index.reshape(-1)].T.reshape(-1, 3, B).transpose(1, 2)
        joints, _ = self._levels[0]
        G_level, p_level = L[joints], t[joints]
        G_parts, p_parts = [G_level], [p_level]
        for joints, parent_pos in self._levels[1:]:
            G_parent = G_level[parent_pos]
            p_level = p_level[parent_pos] + (G_parent * t[joints][..., None, :]).sum(-1)
            G_level = _matmul3(G_parent, L[joints])
            G_parts.append(G_level)
            p_parts.append(p_level)
        positions = torch.cat(p_parts)[self._inverse_order].transpose(0, 1)
        if single:
            positions = positions[0]
        if not rotations:
            return positions
        G = torch.cat(G_parts)[self._inverse_order].transpose(0, 1)
        return positions, (G[0] if single else G)


def forward_kinematics(skeleton: Skeleton, channels, device=None, dtype=torch.float64):
    """One-shot FK: (B, C) or (C,) channels → (B, J, 3) or (J, 3) positions, metres."""
    return ForwardKinematics(skeleton, device=device or "cpu", dtype=dtype)(channels)
