"""Batched forward kinematics in torch: channels (B, C) → joint positions (B, J, 3).

For every joint (see :mod:`priortrack.data.skeleton`)

    L_j = Π_k R_{a_k}(θ_k),   G_j = G_parent · L_j,   p_j = p_parent + G_parent · (o_j + T_j).

A joint's axes are taken as signed columns of an orthonormal frame C built from them:
a_k = σ_k C e_k, the first axis the first column, the second (orthogonal to it) the second,
their cross product the third (an ASF bone's axis matrix up to signs; the coordinate axes of a
BVH joint in its channel order). Then R_{a_k}(θ) = C R_k(σ_k θ) Cᵀ, R_k the rotation about
coordinate axis k, and carrying H_j = G_j C_j instead of G_j,

    H_j = H_parent · (C_parentᵀ C_j) · R_0(σ_0 θ_0) R_1(σ_1 θ_1) R_2(σ_2 θ_2),
    p_j = p_parent + H_parent · (C_parentᵀ (o_j + T_j)),           G_j = H_j C_jᵀ,

a constant 3×3 product and, per angle, a plane rotation of two columns of H,
(h_p, h_q) ← (c h_p + s h_q, c h_q − s h_p) with (p, q) = (k + 1, k + 2) mod 3,
c = cos σθ, s = sin σθ. Axes that are not such a triad (a repeated axis, non-orthogonal
axes) start a new frame: the joint becomes a chain of such segments at zero offset.

The tree of segments is walked one depth level at a time, the segments of a level sorted by
their number of angles, so that one batched product places all children, one applies all
frame changes and four multiply-adds apply the k-th rotation of every segment that has one.
Tensors are batch-last, a matrix as its columns (3, 3, B), so that every elementwise
operation runs over the contiguous batch.

Positions on the CPU in float32 or float64 (no rotations asked, no gradient needed) are computed
instead by the fused kernel of :mod:`priortrack.body.fk_kernel`, joint by joint in one pass over
the rows (about 5× this path's speed at 10⁴ float32 rows; for the unscented filter's 125 float64
sigma points, the torch path's per-operation overhead is most of its time), and on a CUDA GPU by
the Triton kernel of :mod:`priortrack.body.fk_triton`, the same recursion (where Triton imports);
this path is their reference in the tests.
"""

from __future__ import annotations

import logging

import numpy as np
import torch

from priortrack.body.layout import layout_indices
from priortrack.data.motion import Motion
from priortrack.data.skeleton import SLOTS, Skeleton, check_channels
from priortrack.errors import PriortrackError
from priortrack.threads import split_rows

log = logging.getLogger(__name__)

#: An axis within this (max-norm) of a signed frame column rotates about that column.
_ALIGNED = 1e-12


def _frame_from(first: np.ndarray, second: np.ndarray | None) -> np.ndarray:
    """The orthonormal frame (det +1) [first, second, first × second]; any unit vector
    orthogonal to ``first`` where ``second`` is None or not orthogonal to it."""
    if second is None or abs(second @ first) >= _ALIGNED:
        second = np.cross(first, np.eye(3)[np.argmin(np.abs(first))])
        second = second / np.linalg.norm(second)
    return np.stack([first, second, np.cross(first, second)], axis=1)


def _segments(skeleton: Skeleton, j: int) -> list[tuple[np.ndarray, list[tuple[int, float]]]]:
    """Joint j's segments [(frame C (3, 3), [(channel, σ_k)] with a_k = σ_k C e_k)]."""
    used = [k for k in range(SLOTS) if skeleton.rot_channels[j, k] >= 0]
    axes = [skeleton.rot_axes[j, k] for k in used]
    segments: list[tuple[np.ndarray, list]] = []
    for k, a in enumerate(axes):
        channel = int(skeleton.rot_channels[j, used[k]])
        if segments and len(segments[-1][1]) < 3:
            frame, slots = segments[-1]
            column = frame[:, len(slots)]
            sign = 1.0 if np.abs(a - column).max() < _ALIGNED else -1.0 if np.abs(a + column).max() < _ALIGNED else 0.0
            if sign:
                slots.append((channel, sign))
                continue
        segments.append((_frame_from(a, axes[k + 1] if k + 1 < len(axes) else None), [(channel, 1.0)]))
    return segments


class ForwardKinematics:
    """Forward kinematics of one skeleton on one device and dtype.

    Example::

        fk = ForwardKinematics(skeleton, dtype=torch.float32)
        positions = fk(channels)          # (B, C) → (B, J, 3), metres
        positions, G = fk(channels, rotations=True)   # G: (B, J, 3, 3) global rotations
    """

    def __init__(self, skeleton: Skeleton, device: str | torch.device = "cpu",
                 dtype: torch.dtype = torch.float64):
        self.skeleton = skeleton
        self.device = torch.device(device)
        self.dtype = dtype
        as_t = lambda a, **kw: torch.as_tensor(a, device=self.device, **kw)  # noqa: E731
        J = skeleton.num_joints
        # Nodes (segments), parents first: parent node (-1: the world), offset in the parent's
        # frame, the joint whose translation channels it adds (-1: none), C_parentᵀ C, angles.
        parent, offset, translated, A_T, slots = [], [], [], [], []
        frames = np.zeros((J, 3, 3))
        first, last = np.zeros(J, dtype=int), np.zeros(J, dtype=int)
        for j in range(J):
            C = frames[skeleton.parents[j]] if j else np.eye(3)
            first[j] = len(parent)
            for k, (frame, angles) in enumerate(_segments(skeleton, j) or [(C, [])]):
                parent.append(len(parent) - 1 if k else last[skeleton.parents[j]] if j else -1)
                offset.append(np.zeros(3) if k else C.T @ skeleton.offsets[j])
                translated.append(j if not k and np.any(skeleton.trans_channels[j] >= 0) else -1)
                A_T.append((C.T @ frame).T)
                slots.append(angles)
                C = frame
            frames[j], last[j] = C, len(parent) - 1
        depth = np.zeros(len(parent), dtype=int)
        for v, u in enumerate(parent):
            depth[v] = depth[u] + 1 if u >= 0 else 0
        has_children = np.isin(np.arange(len(parent)), parent)
        # Levels: rotating nodes first (most angles first), then those that pass their parent's
        # H to children, then the other leaves (positions only). Angle rows by level, then k,
        # then node; a rotating node with fewer than k + 1 angles gets θ = 0 there (σ = 0 times
        # its own first angle, so that a NaN stays in its joint), an exact identity (c = 1,
        # s = 0), so every step turns all the level's rotating nodes.
        place, row = np.zeros(len(parent), dtype=int), np.zeros(len(parent), dtype=int)
        frame_row = np.zeros(len(parent), dtype=int)          # the row of the H each node uses
        slot_channel, slot_sign = [], []
        self._levels = []
        kept_before = 0
        for d in range(depth.max() + 1):
            nodes = sorted(np.flatnonzero(depth == d), key=lambda v: (-len(slots[v]), not has_children[v]))
            row[nodes] = np.sum(depth < d)
            place[nodes] = np.arange(len(nodes))
            up = place[[parent[v] for v in nodes]] if d else np.zeros(len(nodes), dtype=int)
            r = sum(bool(slots[v]) for v in nodes)
            kept = r + sum(not slots[v] and (has_children[v] or not d) for v in nodes)
            for i, v in enumerate(nodes):
                frame_row[v] = kept_before + i if i < kept else frame_row[parent[v]]
            kept_before += kept
            steps = []
            for k in range(max((len(slots[v]) for v in nodes), default=0)):
                steps.append((len(slot_channel), (k + 1) % 3, (k + 2) % 3))
                slot_channel += [slots[v][min(k, len(slots[v]) - 1)][0] for v in nodes[:r]]
                slot_sign += [slots[v][k][1] if k < len(slots[v]) else 0.0 for v in nodes[:r]]
            self._levels.append({
                # the parents' places in the level above: a slice where consecutive
                "parents": slice(up[0], up[0] + len(up)) if np.all(np.diff(up) == 1) else as_t(up),
                "offsets": as_t(np.array([offset[v] for v in nodes])[:, None, :], dtype=dtype),  # (n, 1, 3)
                "A_T": as_t(np.array([A_T[v] for v in nodes[:r]]).reshape(-1, 3, 3), dtype=dtype),
                "steps": steps,                     # per k: (first angle row, p, q)
                "kept": kept,                       # nodes whose H is kept (rotating, then passing)
                # (place, joint, C_parentᵀ) of the nodes that add a joint's translation channels
                "translated": [(as_t([i]), translated[v], as_t(frames[skeleton.parents[translated[v]]].T.copy()
                                                            if translated[v] else np.eye(3), dtype=dtype))
                               for i, v in enumerate(nodes) if translated[v] >= 0],
            })
        self._frames = as_t(frames, dtype=dtype)                                  # C_j (J, 3, 3)
        self._slot_channel = as_t(np.array(slot_channel, dtype=np.int64))
        self._slot_sign = as_t(np.array(slot_sign)[:, None], dtype=dtype)        # (N, 1)
        self._trans_index = as_t(np.maximum(skeleton.trans_channels, 0))          # (J, 3)
        self._trans_used = as_t((skeleton.trans_channels >= 0)[:, :, None], dtype=dtype)   # (J, 3, 1)
        self._position_node = as_t(row[first] + place[first])                      # (J,) rows of all nodes
        self._frame_node = as_t(frame_row[last])                                   # (J,) rows of kept H
        # positions in one pass: on the CPU the numba kernel of priortrack.body.fk_kernel, on these arrays;
        # on a CUDA GPU the Triton kernel of priortrack.body.fk_triton, where Triton imports
        self._kernel = self._gpu = None
        if self.dtype in (torch.float32, torch.float64) and self.device.type == "cpu":
            real = np.float32 if self.dtype == torch.float32 else np.float64
            self._kernel = (skeleton.parents.astype(np.int64), skeleton.offsets.astype(real),
                            skeleton.rot_axes.astype(real), skeleton.rot_channels.astype(np.int64),
                            skeleton.trans_channels.astype(np.int64))
        elif self.dtype in (torch.float32, torch.float64) and self.device.type == "cuda":
            try:
                from priortrack.body import fk_triton
            except ImportError:
                log.info("Triton does not import: forward kinematics on %s takes the torch path", self.device)
            else:
                self._gpu = fk_triton.Skeleton(skeleton, self.device, self.dtype)
        self._wanted: dict[bytes, torch.Tensor] = {}       # the GPU kernel's joint indices, per selection

    def _as_batch(self, channels) -> torch.Tensor:
        channels = torch.as_tensor(channels, dtype=self.dtype, device=self.device)
        check_channels(channels, self.skeleton)
        if channels.dim() != 2:
            raise PriortrackError(f"channels has shape {tuple(channels.shape)}; expected (B, "
                                  f"{self.skeleton.num_channels}) or ({self.skeleton.num_channels},)")
        return channels

    def _world(self, channels: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """Every node's position (nodes, 3, B) and, per level, the kept H as columns
        (kept, 3, 3, B), level by level."""
        B = channels.shape[0]
        theta = channels.T.index_select(0, self._slot_channel) * self._slot_sign   # (N, B)
        cos, sin = torch.cos(theta)[:, None], torch.sin(theta)[:, None]          # (N, 1, B)
        H = torch.eye(3, dtype=self.dtype, device=self.device).view(1, 3, 3, 1).expand(1, 3, 3, B)
        p = torch.zeros(1, 3, B, dtype=self.dtype, device=self.device)
        positions, frames = [], []
        for level in self._levels:
            up = level["parents"]
            if isinstance(up, slice):
                H_parent, p_parent = H[up], p[up]
            else:
                H_parent, p_parent = H.index_select(0, up), p.index_select(0, up)
            n = len(H_parent)
            p = torch.baddbmm(p_parent.reshape(n, 1, -1), level["offsets"], H_parent.reshape(n, 3, -1)).view(n, 3, B)
            for i, j, frame_T in level["translated"]:
                T = frame_T @ (channels.T[self._trans_index[j]] * self._trans_used[j])   # C_parentᵀ T_j (3, B)
                p = p.index_add(0, i, (H_parent[i] * T[:, None, :]).sum(1))
            r, kept = len(level["A_T"]), level["kept"]
            if r:
                columns = list(torch.bmm(level["A_T"], H_parent[:r].reshape(r, 3, -1)).view(r, 3, 3, B).unbind(1))
                for start, p_, q in level["steps"]:
                    c, s = cos[start:start + r], sin[start:start + r]
                    columns[p_], columns[q] = torch.addcmul(columns[p_] * c, columns[q], s), \
                        torch.addcmul(columns[q] * c, columns[p_], s, value=-1.0)
                H = torch.stack(columns, 1)
                H = torch.cat([H, H_parent[r:kept]]) if r < kept else H
            else:
                H = H_parent[:kept]
            positions.append(p)
            frames.append(H.expand(kept, 3, 3, B))
        return torch.cat(positions), frames

    def _chosen(self, joints) -> np.ndarray:
        J = self.skeleton.num_joints
        chosen = np.arange(J) if joints is None else np.asarray(joints, dtype=int).reshape(-1)
        if len(chosen) and not 0 <= chosen.min() <= chosen.max() < J:
            raise PriortrackError(f"joints {chosen.tolist()} outside the skeleton's {J} joints")
        return chosen

    def _rotations(self, frames: list[torch.Tensor], chosen: np.ndarray) -> torch.Tensor:
        """G_j = H_j C_jᵀ (B, K, 3, 3) of the chosen joints."""
        H = torch.cat(frames).index_select(0, self._frame_node[chosen])
        return torch.einsum("jmib,jkm->bjik", H, self._frames[chosen])

    def __call__(self, channels, rotations: bool = False, joints=None):
        """Joint positions (B, J, 3) in metres (and global rotations (B, J, 3, 3) if asked).

        Args:
            channels: (B, C) or (C,) tensor or array, translations in metres, rotations in
                radians, in ``skeleton.channel_names`` order.
            joints: indices (K,) of the joints to return, (B, K, 3) (default all).
        """
        single = torch.as_tensor(channels).dim() == 1
        channels = self._as_batch(channels[None] if single else channels)
        chosen = self._chosen(joints)
        if not rotations and not channels.requires_grad and (self._kernel is not None or self._gpu is not None):
            positions = self._fused(channels, chosen)
            return positions[0] if single else positions
        p, frames = self._world(channels)
        positions = p.index_select(0, self._position_node[torch.as_tensor(chosen)]).permute(2, 0, 1).contiguous()
        if single:
            positions = positions[0]
        if not rotations:
            return positions
        G = self._rotations(frames, chosen)
        return positions, (G[0] if single else G)

    def _fused(self, channels: torch.Tensor, chosen: np.ndarray) -> torch.Tensor:
        """Positions (B, K, 3) of the ``chosen`` joints in one pass (float32 or float64), equal to the torch path
        to the dtype's rounding: on a CUDA GPU by :func:`priortrack.body.fk_triton.positions`; on the CPU by
        :func:`priortrack.body.fk_kernel.positions`, with torch on T > 1 threads the rows split among T workers
        (:func:`priortrack.threads.split_rows`)."""
        if self._gpu is not None:
            key = chosen.tobytes()
            if key not in self._wanted:
                self._wanted[key] = torch.as_tensor(chosen, dtype=torch.int64, device=self.device)
            from priortrack.body.fk_triton import positions as on_gpu

            return on_gpu(channels, self._gpu, self._wanted[key])
        from priortrack.body.fk_kernel import positions

        out = torch.empty(channels.shape[0], len(chosen), 3, dtype=self.dtype)
        rows, wanted, result = channels.contiguous().numpy(), chosen.astype(np.int64), out.numpy()
        split_rows(len(rows), lambda r: positions(rows[r], *self._kernel, wanted, result[r]))
        return out


def forward_kinematics(skeleton: Skeleton, channels, device=None, dtype=torch.float64):
    """One-shot FK: (B, C) or (C,) channels → (B, J, 3) or (J, 3) positions, metres."""
    return ForwardKinematics(skeleton, device=device or "cpu", dtype=dtype)(channels)


#: Frames :func:`joint_positions` carries through the kinematics at a time (every node's transforms of a
#: ten-minute run's 18,000 frames at once held 117 MB).
FK_FRAMES = 1000


def joint_positions(motion: Motion, layout: str = "eval15", device: str | torch.device = "cpu") -> np.ndarray:
    """(T, J, 3) float64 positions, metres, in the motion's world frame, of the joints of ``layout``
    ("eval15" or "full", :mod:`priortrack.body.layout`) in every frame of ``motion``, FK_FRAMES at a time."""
    index = layout_indices(motion.skeleton, layout)
    fk = ForwardKinematics(motion.skeleton, device=device)
    out = np.empty((len(motion.channels), len(index), 3))
    for start in range(0, len(motion.channels), FK_FRAMES):
        out[start:start + FK_FRAMES] = fk(motion.channels[start:start + FK_FRAMES])[:, index].cpu().numpy()
    return out
