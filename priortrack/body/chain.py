"""The skeleton as URDF text and as a pytorch-kinematics chain.

Each skeleton joint j becomes a run of URDF joints from its parent's link:
a fixed joint carrying the rest offset o_j, prismatic joints along the parent's x, y, z for
its translation channels, then one revolute joint per rotation slot about the slot's axis
(``R_{a1}·R_{a2}·R_{a3}``), ending in a link named after the skeleton joint. A 3-dof ball
joint is thus three revolute joints through dummy links, as ASF dofs are.
"""

from __future__ import annotations

import os

import numpy as np
import torch

from priortrack.data.skeleton import SLOTS, Skeleton


def _steps(skeleton: Skeleton):
    """The URDF joints of the skeleton, parents first.

    Yields (joint name, type, parent link, child link, origin xyz (3,), axis (3,) or None).
    Joint names of moving joints are the channel names (``lfemur.rx``).
    """
    for j, name in enumerate(skeleton.names):
        parent = "world" if j == 0 else skeleton.names[skeleton.parents[j]]
        previous = f"{name}__offset"
        yield f"{name}__offset", "fixed", parent, previous, skeleton.offsets[j], None
        moves = [("prismatic", np.eye(3)[a], c) for a, c in enumerate(skeleton.trans_channels[j]) if c >= 0]
        moves += [("revolute", skeleton.rot_axes[j, k], skeleton.rot_channels[j, k])
                  for k in range(SLOTS) if skeleton.rot_channels[j, k] >= 0]
        for i, (kind, axis, channel) in enumerate(moves):
            link = name if i == len(moves) - 1 else f"{name}__{i}"
            yield skeleton.channel_names[channel], kind, previous, link, np.zeros(3), axis
            previous = link
        if not moves:
            yield f"{name}__frame", "fixed", previous, name, np.zeros(3), None


def _numbers(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def to_urdf(skeleton: Skeleton) -> str:
    """URDF text of the skeleton (links named after joints, dummy links between dofs)."""
    parts = [f'<?xml version="1.0"?>\n<robot name="{skeleton.name}">\n  <link name="world"/>\n']
    for name, kind, parent, child, xyz, axis in _steps(skeleton):
        parts.append(f'  <link name="{child}"/>\n  <joint name="{name}" type="{kind}">\n'
                     f'    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
                     f'    <origin xyz="{_numbers(xyz)}" rpy="0 0 0"/>\n')
        if axis is not None:
            parts.append(f'    <axis xyz="{_numbers(axis)}"/>\n'
                         '    <limit lower="-1e9" upper="1e9" effort="0" velocity="0"/>\n')
        parts.append("  </joint>\n")
    parts.append("</robot>\n")
    return "".join(parts)


def _import_pk():
    """Import pytorch-kinematics (it imports matplotlib: keep its cache somewhere writable)."""
    os.environ.setdefault("MPLCONFIGDIR", os.path.join(os.path.expanduser("~"), ".cache", "priortrack-mpl"))
    import pytorch_kinematics as pk

    return pk


class KinematicChain:
    """A pytorch-kinematics chain of the skeleton, the joints of :func:`to_urdf` built
    programmatically in ``dtype`` (pytorch-kinematics' URDF parser rounds to float32).

    ``positions(channels)`` runs pytorch-kinematics' ``forward_kinematics_tensor``: an
    implementation independent of :mod:`priortrack.body.fk`, to check and time it against.
    """

    def __init__(self, skeleton: Skeleton, device: str | torch.device = "cpu", dtype=torch.float64):
        pk = _import_pk()
        self.skeleton = skeleton
        frames = {"world": pk.Frame("world", link=pk.Link("world"), joint=pk.Joint("world", dtype=dtype))}
        for name, kind, parent, child, xyz, axis in _steps(skeleton):
            offset = pk.Transform3d(pos=torch.as_tensor(xyz, dtype=dtype), dtype=dtype)
            joint = pk.Joint(name, offset=offset, joint_type=kind, dtype=dtype,
                             axis=None if axis is None else torch.as_tensor(axis, dtype=dtype))
            frames[child] = pk.Frame(child, link=pk.Link(child), joint=joint)
            frames[parent].add_child(frames[child])
        self.chain = pk.Chain(frames["world"], dtype=dtype).to(dtype=dtype, device=device)
        self.dtype, self.device = dtype, torch.device(device)
        names = self.chain.get_joint_parameter_names()
        self.channel_index = torch.as_tensor([skeleton.channel_names.index(n) for n in names], device=self.device)
        self.frame_index = self.chain.get_frame_indices(*skeleton.names)

    def joint_values(self, channels) -> torch.Tensor:
        """(B, C) channels → (B, n) pytorch-kinematics joint values in its order."""
        channels = torch.as_tensor(channels, dtype=self.dtype, device=self.device)
        return channels[:, self.channel_index]

    def positions_from_values(self, th: torch.Tensor) -> torch.Tensor:
        """(B, n) joint values → (B, J, 3) skeleton joint positions, metres."""
        transforms = self.chain.forward_kinematics_tensor(th)      # (frames, B, 4, 4)
        return transforms[self.frame_index, :, :3, 3].transpose(0, 1)

    def positions(self, channels) -> torch.Tensor:
        """(B, C) channels → (B, J, 3) joint positions, metres."""
        return self.positions_from_values(self.joint_values(channels))
