"""State spaces of the pose priors: what a state vector means and how to move in it.

A prior's state is a row of a ``(P, S)`` tensor. The space says how to decode it into
``eval15`` joints, how to step (⊞) and difference (⊟) on it, and how to average states,
so that filters can take means on the manifold rather than in the embedding:

- :class:`AngleSpace`: the skeleton's joint angles (root channels excluded: global motion is
  modelled apart), Euclidean, x ⊞ v = x + v;
- :class:`DirectionSpace`: the 14 ``eval15`` bone directions in the normalised body frame,
  a point of (S²)¹⁴ stored as 42 numbers, x ⊞ v = exp_x(v), y ⊟ x = log_x(y).

Coordinates are grouped by joint (a bone's dofs, a bone direction's three numbers); a group
has ``tangent_dims[g]`` intrinsic dimensions (a bone's dof count, or 2 on a sphere).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import torch

from priortrack.body.fk import ForwardKinematics
from priortrack.body.layout import EVAL15_NAMES, eval15_indices
from priortrack.body.normalise import BONE_CHILDREN, body_positions, normalise
from priortrack.data.skeleton import Skeleton
from priortrack.data.motion import CONSTANT_CHANNEL_STD, Motion
from priortrack.errors import PriortrackError
from priortrack.geometry import so3
from priortrack.geometry.manifold_mean import signed_mean
from priortrack.geometry.sphere import exp_map, karcher_mean, log_map, project_to_tangent, transport
from priortrack.geometry.tangent_basis import from_coordinates, tangent_basis, to_coordinates
from priortrack.randomness import standard_normal
from priortrack.body.fk import FK_FRAMES, joint_positions

#: How far a bone direction's norm may be from 1 in a state of :class:`DirectionSpace` (float32
#: rounding after many exp-map steps stays far below it).
UNIT_TOLERANCE = 1e-3
#: Rows per block of that check.
CHECK_BLOCK = 32768

class StateSpace(ABC):
    """The contract every state space keeps. Shapes: states (..., S), joints (..., 15, 3)."""

    #: True where states live on a manifold embedded in R^S (then ⊞/⊟ are not + and −).
    manifold: bool = False
    #: (S,) group (joint) of each coordinate; group_names (G,); tangent_dims (G,).
    groups: np.ndarray
    group_names: tuple[str, ...]
    tangent_dims: np.ndarray

    @property
    def dim(self) -> int:
        """S, the width of a state row."""
        return len(self.groups)

    @abstractmethod
    def encode(self, motion: Motion) -> torch.Tensor:
        """(T, S) float64 states of a motion's frames."""

    @abstractmethod
    def joints(self, x: torch.Tensor) -> torch.Tensor:
        """(..., S) states → (..., 15, 3) eval15 joints in metres, in the space's body frame."""

    def pose_joints(self, motion: Motion) -> torch.Tensor:
        """(T, 15, 3) the motion's own poses in this space's body frame (the frame of
        :meth:`joints`): the joints of its encoded states, which decode exactly where the
        states are the pose itself (angles; bone directions with the subject's lengths,
        :meth:`for_body`)."""
        return self.joints(self.encode(motion))

    def check_points(self, x: torch.Tensor, name: str) -> None:
        """Raise a PriortrackError unless the finite (P, S) rows x are points of the space
        (every row of R^S is, so the base accepts them all)."""

    def global_pose(self, motion: Motion) -> torch.Tensor:
        """(T, 6) global placement g = (t, ω) of a motion's frames: world joints are
        exp(ω) · joints(x) + t (:func:`priortrack.priors.global_motion.to_world`)."""
        raise PriortrackError(f"{type(self).__name__} has no global placement")

    def for_body(self, motion: Motion) -> StateSpace:
        """The same space decoding joints with the body (bone lengths) of ``motion``'s subject.
        A space without body dimensions returns itself."""
        return self

    @abstractmethod
    def boxplus(self, x: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """x ⊞ v: the state reached from x (..., S) by the tangent step v (..., S)."""

    @abstractmethod
    def boxminus(self, y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """y ⊟ x: the tangent step (..., S) at x that reaches y."""

    @property
    def tangent_dim(self) -> int:
        """n, the intrinsic dimension: the number of tangent coordinates of a state."""
        return int(np.sum(self.tangent_dims))

    @abstractmethod
    def retract(self, x: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        """x (N, S) ⊞ c (N, n): the state reached by the tangent coordinates c at x."""

    @abstractmethod
    def local(self, y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """y (N, S) ⊟ x (S,) (or one x per row, (N, S)) → (N, n), in the tangent coordinates at x."""

    @abstractmethod
    def coordinate_transport(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """(n, n) map from tangent coordinates at state a (S,) to those at b (S,)."""

    @abstractmethod
    def signed_mean(self, x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """(S,) mean of states x (N, S) for weights w (N,) summing to 1 of any sign (the unscented
        weights): :func:`~priortrack.geometry.manifold_mean.signed_mean` in this space."""

    @abstractmethod
    def tangent_noise(self, x: torch.Tensor, std: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """Isotropic Gaussian tangent steps at x (P, S), std (S,) per coordinate (equal within a group)."""

    @abstractmethod
    def mean(self, x: torch.Tensor, weights: torch.Tensor | None = None) -> torch.Tensor:
        """Weighted mean (S,) of states (N, S) taken in the space (Karcher mean on a manifold)."""

    @abstractmethod
    def to_arrays(self) -> dict[str, np.ndarray]:
        """Everything needed to rebuild the space, as plain arrays (npz without pickle)."""

    def group_norms_sq(self, v: torch.Tensor) -> torch.Tensor:
        """(..., S) tangent steps → (..., G) squared norm of each group's part."""
        index = torch.as_tensor(self.groups, device=v.device)
        out = torch.zeros(v.shape[:-1] + (len(self.group_names),), dtype=v.dtype, device=v.device)
        return out.index_add_(-1, index, v * v)


class EuclideanSpace(StateSpace):
    """A state space that is R^S itself: x ⊞ v = x + v, y ⊟ x = y − x, the mean is the mean."""

    def boxplus(self, x, v):
        return x + v

    def boxminus(self, y, x):
        return y - x

    def retract(self, x, c):
        return x + c

    def local(self, y, x):
        return y - x

    def coordinate_transport(self, a, b):
        """The identity (S, S): a Euclidean space's coordinates are the same at every point."""
        return torch.eye(self.dim, dtype=a.dtype, device=a.device)

    def signed_mean(self, x, w):
        """Σ_i w_i x_i: x (N, S), w (N,) → (S,)."""
        return w @ x

    def tangent_noise(self, x, std, generator):
        return standard_normal(x.shape, generator, x) * std

    def mean(self, x, weights=None):
        if weights is None:
            return x.mean(dim=0)
        return weights.to(x) @ x / weights.sum()


class AngleSpace(EuclideanSpace):
    """Joint angles of one skeleton layout, in radians.

    ``channels`` (D,) indexes the skeleton's channel vector: every non-root channel that
    moves in training. The rest are fixed: root channels at zero (pelvis at the origin,
    identity orientation), constant channels at their training value (``reference``, (C,)),
    or, on a person's body (:meth:`for_body`), at that person's own.
    """

    def __init__(self, skeleton: Skeleton, channels: np.ndarray, reference: np.ndarray):
        self.skeleton = skeleton
        self.channels = np.asarray(channels, dtype=int)
        self.reference = np.asarray(reference, dtype=float)
        joint_of = [skeleton.channel_names[c].split(".", 1)[0] for c in self.channels]
        self.group_names = tuple(dict.fromkeys(joint_of))
        self.groups = np.array([self.group_names.index(j) for j in joint_of])
        self.tangent_dims = np.bincount(self.groups, minlength=len(self.group_names))
        # FK of the eval15 joints only needs their ancestors, read straight from a state row.
        pruned, self._eval15 = skeleton.pruned(eval15_indices(skeleton))
        self._state_skeleton, self._fixed = _driven_by_state(pruned, self.channels, self.reference)
        self._fk: dict[tuple, tuple[ForwardKinematics, torch.Tensor]] = {}

    @classmethod
    def fit(cls, motions: Sequence[Motion]) -> AngleSpace:
        """The modelled channels and reference pose of a training set (one channel layout)."""
        skeleton = motions[0].skeleton
        for m in motions[1:]:
            if m.skeleton.channel_names != skeleton.channel_names:
                raise PriortrackError(f"motion {m.name!r} has other channels than {motions[0].name!r}: "
                                      f"an angle prior needs one skeleton layout (same ASF bones and dofs)")
        values = np.concatenate([m.channels for m in motions])
        root = set(skeleton.root_channels.tolist())
        spread = np.array([_unwrapped(values[:, c]).std() for c in range(skeleton.num_channels)])
        channels = [c for c in range(skeleton.num_channels) if c not in root and spread[c] > CONSTANT_CHANNEL_STD]
        reference = np.where(spread > CONSTANT_CHANNEL_STD, 0.0, values.mean(axis=0))
        reference[list(root)] = 0.0
        return cls(skeleton, np.array(channels), reference)

    def encode(self, motion: Motion) -> torch.Tensor:
        """(T, D) angles of the modelled channels, unwrapped in time, the clip's mean in (−π, π]."""
        if motion.skeleton.channel_names != self.skeleton.channel_names:
            raise PriortrackError(f"motion {motion.name!r}: its skeleton's channels differ from the prior's "
                                  f"({self.skeleton.name!r}); angle priors need the same layout")
        return torch.as_tensor(_unwrapped(motion.channels[:, self.channels]))

    def channels_of(self, x: torch.Tensor) -> torch.Tensor:
        """(..., D) states → (..., C) full channel vectors (root at zero)."""
        full = torch.as_tensor(self.reference, dtype=x.dtype, device=x.device).expand(x.shape[:-1] + (len(self.reference),))
        full = full.clone()
        full[..., torch.as_tensor(self.channels, device=x.device)] = x
        return full

    def joints(self, x: torch.Tensor) -> torch.Tensor:
        """Joints with the root at the origin and unrotated (its rest offset removed)."""
        if x.shape[-1:] != (self.dim,):
            raise PriortrackError(f"angle states have shape {tuple(x.shape)}; expected (..., {self.dim})")
        key = (x.device, x.dtype)
        if key not in self._fk:
            self._fk[key] = (ForwardKinematics(self._state_skeleton, device=x.device, dtype=x.dtype),
                             torch.as_tensor(self._fixed, dtype=x.dtype, device=x.device))
        fk, fixed = self._fk[key]
        flat = x.reshape(-1, self.dim)
        if len(fixed):
            flat = torch.cat([flat, fixed.expand(len(flat), -1)], dim=1)
        return fk(flat, joints=self._eval15).reshape(x.shape[:-1] + (len(EVAL15_NAMES), 3))

    def global_pose(self, motion: Motion) -> torch.Tensor:
        """t = the root's world position (rest offset + translation channels), ω = log of its rotation."""
        channels = torch.as_tensor(motion.channels)
        root = motion.skeleton.trans_channels[0]
        t = torch.as_tensor(motion.skeleton.offsets[0]).expand(len(motion), 3).clone()
        t[:, root >= 0] += channels[:, root[root >= 0]]
        return torch.cat([t, so3.log(torch.as_tensor(motion.skeleton.local_rotations(motion.channels, joints=[0])[:, 0]))], dim=-1)

    def for_body(self, motion: Motion) -> AngleSpace:
        """The same channels on ``motion``'s skeleton (same channel layout), the constant ones (neither modelled nor
        the root's) at the motion's own values (their mean over its frames): the person's posture where the training
        motions have none (a tracker's start holds it at the one measured over the trial:
        :func:`~priortrack.body.ik.own_posture`)."""
        if motion.skeleton.channel_names != self.skeleton.channel_names:
            raise PriortrackError(f"motion {motion.name!r}: its skeleton's channels differ from the prior's "
                                  f"({self.skeleton.name!r}); angle priors need the same layout")
        constant = np.ones(len(self.reference), dtype=bool)
        constant[self.channels] = False
        constant[motion.skeleton.root_channels] = False
        reference = self.reference.copy()
        reference[constant] = _unwrapped(motion.channels[:, constant]).mean(axis=0)
        return AngleSpace(motion.skeleton, self.channels, reference)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {**self.skeleton.to_arrays(), "space.channels": self.channels, "space.reference": self.reference}

    @classmethod
    def from_arrays(cls, arrays) -> AngleSpace:
        return cls(Skeleton.from_arrays(arrays), arrays["space.channels"], arrays["space.reference"])


class DirectionSpace(StateSpace):
    """The 14 eval15 bone directions in the normalised body frame: (S²)¹⁴ as 42 numbers.

    ``lengths`` (14,) are the bone lengths used to decode joints (the training mean).
    """

    manifold = True

    def __init__(self, lengths: np.ndarray):
        self.lengths = np.asarray(lengths, dtype=float)
        self.group_names = tuple(EVAL15_NAMES[c] for c in BONE_CHILDREN)
        self.groups = np.repeat(np.arange(len(BONE_CHILDREN)), 3)
        self.tangent_dims = np.full(len(BONE_CHILDREN), 2)

    @classmethod
    def fit(cls, motions: Sequence[Motion]) -> DirectionSpace:
        lengths = torch.cat([normalise(joint_positions(m, "eval15")).lengths for m in motions])
        return cls(lengths.mean(dim=0).numpy())

    def encode(self, motion: Motion) -> torch.Tensor:
        """(T, 42) each frame's bone directions in its body frame, FK_FRAMES frames at a time (a frame's
        directions are its own: the same values; a ten-minute run's joints and body frames are not held at once)."""
        x = torch.empty((len(motion), 3 * len(BONE_CHILDREN)), dtype=torch.float64)
        for start in range(0, len(motion), FK_FRAMES):
            block = motion[start:start + FK_FRAMES]
            x[start:start + len(block)] = normalise(joint_positions(block, "eval15")).directions.reshape(len(block), -1)
        return x

    def for_body(self, motion: Motion) -> DirectionSpace:
        """Bone lengths of ``motion``'s subject (the mean over its frames)."""
        return DirectionSpace(normalise(joint_positions(motion, "eval15")).lengths.mean(dim=0).numpy())

    def global_pose(self, motion: Motion) -> torch.Tensor:
        """t = the hip centre, ω = log of the body frame's world-from-body rotation Rᵀ."""
        pose = normalise(joint_positions(motion, "eval15"))
        return torch.cat([pose.origin, so3.log(pose.rotation.transpose(-1, -2))], dim=-1)

    def _spheres(self, x: torch.Tensor) -> torch.Tensor:
        return x.reshape(x.shape[:-1] + (len(BONE_CHILDREN), 3))

    def check_points(self, x, name):
        """Every bone direction of x (P, 42) must be a unit vector, to ``UNIT_TOLERANCE``: the exp
        and log maps, the mixture's tangent bases and the decoded bones all assume it."""
        if x.numel():
            # |d|² from strided columns, in blocks of rows so that the temporaries stay small: at 200,000
            # rows one pass cost 17–32 ms (page faults on its temporaries), blocks 7–16 ms; at 10,000
            # rows 0.3 ms either way. It runs on every sampling step.
            ranges = torch.stack([torch.stack(torch.aminmax(b[:, 0::3] ** 2 + b[:, 1::3] ** 2 + b[:, 2::3] ** 2))
                                  for b in x.detach().split(CHECK_BLOCK)])
            low, high = float(ranges[:, 0].min().sqrt()), float(ranges[:, 1].max().sqrt())
            if low < 1 - UNIT_TOLERANCE or high > 1 + UNIT_TOLERANCE:
                raise PriortrackError(f"{name} is not on the spheres: its bone directions have norms in "
                                      f"[{low:.6g}, {high:.6g}], not 1 (±{UNIT_TOLERANCE:g})")

    def joints(self, x):
        d = self._spheres(x)
        return body_positions(d, torch.as_tensor(self.lengths, dtype=x.dtype, device=x.device).expand(d.shape[:-1]))

    def boxplus(self, x, v):
        return exp_map(self._spheres(x), self._spheres(v)).reshape(x.shape)

    def boxminus(self, y, x):
        return log_map(self._spheres(x), self._spheres(y)).reshape(y.shape)

    def retract(self, x, c):
        """x ⊞ c = exp_x(E(x)ᵀ c): x (N, 3K), c (N, 2K) → (N, 3K), with E(x) (K, 2, 3) the
        :func:`~priortrack.geometry.tangent_basis.tangent_basis` at each bone direction."""
        K = len(BONE_CHILDREN)
        v = from_coordinates(tangent_basis(self._spheres(x)), c.reshape(c.shape[:-1] + (K, 2)))
        return self.boxplus(x, v.reshape(x.shape))

    def local(self, y, x):
        """y ⊟ x = E(x) log_x(y): y (N, 3K), x (3K,) (or one per row, (N, 3K)) → (N, 2K)."""
        v = self.boxminus(y, x.expand_as(y))
        c = to_coordinates(tangent_basis(self._spheres(x)), self._spheres(v))
        return c.reshape(y.shape[:-1] + (self.tangent_dim,))

    def coordinate_transport(self, a, b):
        """(2K, 2K) block-diagonal: on bone k the rotation T_k[i, j] = e_i(b_k) · Γ_{a_k→b_k} e_j(a_k),
        Γ the parallel transport along the geodesic."""
        pa, pb = self._spheres(a), self._spheres(b)
        moved = transport(pa[:, None], pb[:, None], tangent_basis(pa))           # (K, 2, 3): Γ e_j(a)
        return torch.block_diag(*(tangent_basis(pb) @ moved.transpose(-1, -2)))

    def signed_mean(self, x, w):
        """Fixed point of m ← exp_m(Σ_i w_i log_m(x_i)) from x_0: x (N, 3K), w (N,) → (3K,). Each bone
        direction is renormalised at the end: where the iteration does not converge (sigma points
        spread over a hemisphere, the unscented weights' W_0 ≪ 0) its last iterate had drifted off
        the sphere (norms 0.73 seen), and every later step would have refused the state."""
        mean = signed_mean(x[0], w, lambda m: self.boxminus(x, m.expand_as(x)),
                           lambda m, v: self.boxplus(m[None], v[None])[0])
        spheres = self._spheres(mean)
        return (spheres / torch.linalg.vector_norm(spheres, dim=-1, keepdim=True)).reshape(mean.shape)

    def tangent_noise(self, x, std, generator):
        ambient = standard_normal(x.shape, generator, x) * std
        return project_to_tangent(self._spheres(x), self._spheres(ambient)).reshape(x.shape)

    def mean(self, x, weights=None):
        return karcher_mean(self._spheres(x), weights=weights).reshape(-1)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"space.lengths": self.lengths}

    @classmethod
    def from_arrays(cls, arrays) -> DirectionSpace:
        return cls(arrays["space.lengths"])


def _driven_by_state(skeleton: Skeleton, channels: np.ndarray, reference: np.ndarray) -> tuple[Skeleton, np.ndarray]:
    """``skeleton`` with its channels renumbered to read a row [x, f]: the state x (D,), whose
    column i is channel ``channels[i]``, then the fixed values f (F,) (returned) of the other
    channels it uses. Fixed channels at exactly zero are dropped (a zero angle or translation
    moves nothing) and the root's rest offset is zeroed, so the root sits at the origin."""
    C = skeleton.num_channels
    used = np.concatenate([skeleton.rot_channels.ravel(), skeleton.trans_channels.ravel()])
    modelled = set(int(c) for c in channels)
    fixed = np.array([c for c in np.unique(used[used >= 0]) if c not in modelled and reference[c] != 0.0], dtype=int)
    column = -np.ones(C + 1, dtype=int)                     # column[-1] = -1 keeps unused slots unused
    column[channels] = np.arange(len(channels))
    column[fixed] = len(channels) + np.arange(len(fixed))
    rot_channels, trans_channels = column[skeleton.rot_channels], column[skeleton.trans_channels]
    offsets = skeleton.offsets.copy()
    offsets[0] = 0.0
    names = tuple(skeleton.channel_names[c] for c in (*channels, *fixed))
    state_skeleton = replace(skeleton, offsets=offsets, rot_channels=rot_channels, trans_channels=trans_channels,
                             rot_axes=np.where((rot_channels >= 0)[..., None], skeleton.rot_axes, 0.0),
                             channel_names=names)
    return state_skeleton, reference[fixed]


def _unwrapped(angles: np.ndarray) -> np.ndarray:
    """Unwrap (T, ...) angles along time, then shift each channel by 2πk so its mean is in (−π, π]."""
    angles = np.unwrap(angles, axis=0)
    return angles - 2 * np.pi * np.round(angles.mean(axis=0) / (2 * np.pi))


SPACES = {"angles": AngleSpace, "directions": DirectionSpace}
