"""The articulated skeleton: a tree of joints, their rest offsets and their channels.

One representation serves ASF and BVH. Joint ``j`` sits at

    p_j = p_parent + G_parent · (o_j + T_j),        G_j = G_parent · L_j,

with ``o_j`` the rest offset (metres, in the parent's rest frame, which for ASF and BVH
is the world frame of the rest pose), ``T_j`` the joint's translation channels along the
parent's axes (only the root has them in practice) and the local rotation

    L_j = R_{a_1}(θ_1) · R_{a_2}(θ_2) · R_{a_3}(θ_3),

a product of rotations about unit axes ``a_k`` (leftmost first), each angle read from one
channel of the pose vector. An ASF bone with axis matrix C and dofs rz ry rx gives
C·Rz·Ry·Rx·Cᵀ = R_{C·z} · R_{C·y} · R_{C·x}, so its axes are the columns of C; a BVH
joint's axes are the coordinate axes in its channel order. Unused slots have a zero axis.

A pose is one vector of channels ``(C,)``: root translation in metres and every rotation
in radians, in the order of ``channel_names``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from priortrack.errors import PriortrackError

#: Rotation slots per joint (three Euler angles at most).
SLOTS = 3
#: A human body, generously: no bone longer, no rest pose wider (its bounding box's diagonal), no
#: root further from the origin in any frame (metres). Small bodies are not refused (toy skeletons).
MAX_BONE_M, MAX_EXTENT_M, MAX_ROOT_M = 1.5, 4.0, 1000.0


def check_body(skeleton: "Skeleton", where: str) -> None:
    """Refuse an absurd body (:data:`MAX_BONE_M`, :data:`MAX_EXTENT_M`): a bone metres long or a
    rest pose kilometres across, as a file in another unit, or a corrupted one, gives. The message
    names the bone and the unit read."""
    lengths = np.linalg.norm(skeleton.offsets[1:], axis=1)
    unit = f"(lengths read in units of {skeleton.length_unit:g} m; is the file in another unit?)"
    if len(lengths) and lengths.max() > MAX_BONE_M:
        j = 1 + int(np.argmax(lengths))
        raise PriortrackError(f"{where}: bone {skeleton.names[j]!r} is {lengths.max():.3g} m long, more than a "
                              f"human body's {MAX_BONE_M} m {unit}")
    rest = np.zeros((skeleton.num_joints, 3))
    for j in range(1, skeleton.num_joints):
        rest[j] = rest[skeleton.parents[j]] + skeleton.offsets[j]
    extent = float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0)))
    if extent > MAX_EXTENT_M:
        raise PriortrackError(f"{where}: the body at rest spans {extent:.3g} m, more than a human's "
                              f"{MAX_EXTENT_M} m {unit}")


def check_root(skeleton: "Skeleton", channels: np.ndarray, where: str) -> None:
    """Refuse a motion whose root leaves :data:`MAX_ROOT_M` of the origin (channels (T, C), metres)."""
    columns = skeleton.trans_channels[0][skeleton.trans_channels[0] >= 0]
    if len(columns) and len(channels):
        far = np.abs(channels[:, columns]).max(axis=1)
        if far.max() > MAX_ROOT_M:
            t = int(np.argmax(far))
            raise PriortrackError(f"{where}: frame {t} puts the root {far[t]:.3g} m from the origin (more than "
                                  f"{MAX_ROOT_M:g} m: a corrupted value, or a file in another unit)")


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A joint tree with per-joint channels.

    Attributes:
        name: where the skeleton came from (file stem).
        names: (J,) joint names; parents come before children.
        parents: (J,) int, parent index, -1 for the root (index 0).
        offsets: (J, 3) rest offset o_j from the parent, metres.
        rot_axes: (J, 3, 3) unit rotation axis a_k for slot k (zero where unused).
        rot_channels: (J, 3) int, channel index of slot k's angle, -1 where unused.
        trans_channels: (J, 3) int, channel index of the translation along the parent's
            x, y, z axes, -1 where unused.
        channel_names: (C,) names such as ``root.tx`` or ``lfemur.rz``.
        source: ``"asf"`` or ``"bvh"``.
        length_unit: metres per length unit of the source file (ASF ``:units length``,
            BVH offsets), to convert translation channels read from or written to files.
        angle_unit: radians per angle unit of the source file (π/180 for degrees).
    """

    name: str
    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    rot_axes: np.ndarray
    rot_channels: np.ndarray
    trans_channels: np.ndarray
    channel_names: tuple[str, ...]
    source: str
    length_unit: float = 1.0
    angle_unit: float = np.pi / 180.0

    def __post_init__(self) -> None:
        J = len(self.names)
        C = len(self.channel_names)
        if J == 0:
            raise PriortrackError(f"skeleton {self.name!r} has no joints")
        expected = {
            "parents": (J,),
            "offsets": (J, 3),
            "rot_axes": (J, SLOTS, 3),
            "rot_channels": (J, SLOTS),
            "trans_channels": (J, 3),
        }
        for field, shape in expected.items():
            if getattr(self, field).shape != shape:
                raise PriortrackError(
                    f"skeleton {self.name!r}: {field} has shape {getattr(self, field).shape}, expected {shape}"
                )
        if self.parents[0] != -1 or np.any(self.parents[1:] >= np.arange(1, J)) or np.any(self.parents[1:] < 0):
            raise PriortrackError(f"skeleton {self.name!r}: joints must be ordered parents first with one root at 0")
        used = np.concatenate([self.rot_channels.ravel(), self.trans_channels.ravel()])
        used = used[used >= 0]
        if len(np.unique(used)) != len(used) or (len(used) and (used.max() >= C)):
            raise PriortrackError(f"skeleton {self.name!r}: channel indices must be distinct and < {C}")

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @property
    def num_channels(self) -> int:
        return len(self.channel_names)

    @property
    def root_channels(self) -> np.ndarray:
        """(K,) the root's rotation and translation channels, ascending."""
        root = np.concatenate([self.rot_channels[0], self.trans_channels[0]])
        return np.unique(root[root >= 0])

    def index(self, joint: str) -> int:
        """Index of a joint by name; a clear error listing the names if absent."""
        try:
            return self.names.index(joint)
        except ValueError:
            raise PriortrackError(
                f"skeleton {self.name!r} has no joint {joint!r}; joints: {', '.join(self.names)}"
            ) from None

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.flatnonzero(self.parents == j)]

    def bone_lengths(self) -> np.ndarray:
        """(J,) rest distance from each joint to its parent, metres (0 for the root)."""
        lengths = np.linalg.norm(self.offsets, axis=1)
        lengths[0] = 0.0
        return lengths

    def channel_scale(self) -> np.ndarray:
        """(C,) factor from file units to metres/radians for each channel."""
        scale = np.full(self.num_channels, self.angle_unit)
        translations = self.trans_channels[self.trans_channels >= 0]
        scale[translations] = self.length_unit
        return scale

    def local_rotations(self, channels, joints=None) -> np.ndarray:
        """(T, C) channels → (T, K, 3, 3) float64 local rotations
        L_j = R_{a_1}(θ_1) · R_{a_2}(θ_2) · R_{a_3}(θ_3) of the joints ``joints`` (K,) (all by default),
        each R_a(θ) = I + sin θ [a]ₓ + (1 − cos θ) [a]ₓ² (Rodrigues); unused slots give I."""
        channels = np.asarray(channels, dtype=np.float64)
        check_channels(channels, self)
        chosen = np.arange(self.num_joints) if joints is None else np.asarray(joints, dtype=int).reshape(-1)
        if len(chosen) and not 0 <= chosen.min() <= chosen.max() < self.num_joints:
            raise PriortrackError(f"joints {chosen.tolist()} outside the skeleton {self.name!r}'s "
                                  f"{self.num_joints} joints")
        frames = channels.reshape(-1, self.num_channels)
        L = np.broadcast_to(np.eye(3), (len(frames), len(chosen), 3, 3)).copy()
        for slot in range(SLOTS):
            index = self.rot_channels[chosen, slot]                                   # (K,)
            a = self.rot_axes[chosen, slot]                                           # (K, 3)
            theta = np.where(index >= 0, frames[:, np.maximum(index, 0)], 0.0)        # (T, K)
            cross = np.zeros((len(chosen), 3, 3))
            cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -a[:, 2], a[:, 1], -a[:, 0]
            cross -= cross.transpose(0, 2, 1)
            R = (np.eye(3) + np.sin(theta)[..., None, None] * cross
                 + (1 - np.cos(theta))[..., None, None] * (cross @ cross))
            L = L @ R
        return L.reshape(channels.shape[:-1] + (len(chosen), 3, 3))

    def pruned(self, keep) -> tuple[Skeleton, np.ndarray]:
        """The smallest skeleton that places the joints ``keep``: their ancestors only, and no
        rotation slots on joints that end up leaves (a joint's own rotation moves only its
        descendants). Channels keep their indices, so the same pose vectors drive it.

        Returns the skeleton and the (len(keep),) indices of ``keep`` in it.
        """
        needed = set()
        for j in np.asarray(keep, dtype=int):
            while j >= 0 and j not in needed:
                needed.add(int(j))
                j = self.parents[j]
        joints = np.array(sorted(needed))
        new_index = -np.ones(self.num_joints, dtype=int)
        new_index[joints] = np.arange(len(joints))
        parents = np.where(self.parents[joints] >= 0, new_index[self.parents[joints]], -1)
        leaf = ~np.isin(np.arange(len(joints)), parents)
        rot_channels = self.rot_channels[joints].copy()
        rot_axes = self.rot_axes[joints].copy()
        rot_channels[leaf], rot_axes[leaf] = -1, 0.0
        skeleton = replace(self, names=tuple(self.names[j] for j in joints), parents=parents,
                           offsets=self.offsets[joints], rot_axes=rot_axes, rot_channels=rot_channels,
                           trans_channels=self.trans_channels[joints])
        return skeleton, new_index[np.asarray(keep, dtype=int)]

    def to_arrays(self, prefix: str = "skeleton.") -> dict[str, np.ndarray]:
        """The skeleton as plain arrays (strings as unicode arrays): storable in npz without pickle."""
        arrays = {name: getattr(self, name) for name in _ARRAY_FIELDS}
        arrays["names"] = np.array(self.names)
        arrays["channel_names"] = np.array(self.channel_names)
        arrays["info"] = np.array([self.name, self.source])
        arrays["units"] = np.array([self.length_unit, self.angle_unit])
        return {prefix + k: np.asarray(v) for k, v in arrays.items()}

    @classmethod
    def from_arrays(cls, arrays, prefix: str = "skeleton.") -> Skeleton:
        """Inverse of :meth:`to_arrays`; a missing array is a PriortrackError naming it."""
        try:
            get = {k: arrays[prefix + k] for k in (*_ARRAY_FIELDS, "names", "channel_names", "info", "units")}
        except KeyError as exc:
            raise PriortrackError(f"stored skeleton lacks the array {exc.args[0]!r}") from None
        return cls(name=str(get["info"][0]), names=tuple(str(n) for n in get["names"]),
                   parents=get["parents"].astype(int), offsets=get["offsets"].astype(float),
                   rot_axes=get["rot_axes"].astype(float), rot_channels=get["rot_channels"].astype(int),
                   trans_channels=get["trans_channels"].astype(int),
                   channel_names=tuple(str(n) for n in get["channel_names"]), source=str(get["info"][1]),
                   length_unit=float(get["units"][0]), angle_unit=float(get["units"][1]))


_ARRAY_FIELDS = ("parents", "offsets", "rot_axes", "rot_channels", "trans_channels")


def check_channels(channels, skeleton: Skeleton, argument: str = "channels") -> None:
    """Raise a PriortrackError unless ``channels`` is (..., C) for this skeleton."""
    shape = tuple(channels.shape)
    if len(shape) < 1 or shape[-1] != skeleton.num_channels:
        raise PriortrackError(
            f"{argument} has shape {shape}; expected (..., {skeleton.num_channels}) "
            f"channels for skeleton {skeleton.name!r}"
        )
