"""A pose prior composed with global motion and the 2D likelihood: what every filter runs.

The full filter state is s = [x, g_t, g_{t-1}] (P, S + 12): the prior's pose state x (S),
and the current and previous placements g = (t, ω) of :mod:`priortrack.priors.global_motion`.
Prediction draws x_t ~ prior(x_{t-1}) and g_t from the global motion model; the
observation model scores the world joints exp(ω_t)·joints(x_t) + t_t against the 2D detections.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.geometry import so3
from priortrack.geometry.facing import turned_placements
from priortrack.models.protocols import ObservationModel, TransitionModel
from priortrack.priors.global_motion import GlobalMotion, to_world

GLOBAL_DIM = 6


class TrackingModel:
    """prior × global motion × likelihood over full states (P, S + 12).

    The interface every filter uses (a linear-Gaussian model in the tests keeps it too):
    ``dim``, ``observation_shape``, ``predict``, ``mean_step``, ``observe`` (states → what
    the likelihood scores: world joints), ``log_likelihood(observed, z)``, ``mean``. Everything
    runs in the dtype of the states it is given.
    """

    def __init__(self, prior: TransitionModel, global_motion: GlobalMotion, likelihood: ObservationModel):
        self.prior, self.global_motion, self.likelihood = prior, global_motion, likelihood
        #: The state space that decodes joints: the prior's, with the tracked subject's body
        #: (bone lengths) once :meth:`initial_states` has seen the subject's known first frames.
        self.body = prior.space

    @classmethod
    def fitted(cls, prior: TransitionModel, motions: Sequence[Motion], likelihood: ObservationModel) -> TrackingModel:
        """The model with its global motion fitted to the placements of ``motions`` (the prior's
        training motions, at its frame rate): the one way every preset, benchmark and test assembles it."""
        return cls(prior, GlobalMotion.fit([prior.space.global_pose(m) for m in motions]), likelihood)

    @property
    def observation_shape(self) -> tuple[int, ...]:
        """The shape of one frame's observation: the observation model's."""
        return tuple(self.likelihood.observation_shape)

    @property
    def pose_dim(self) -> int:
        return self.prior.state_dim

    @property
    def dim(self) -> int:
        return self.prior.state_dim + 2 * GLOBAL_DIM

    def split(self, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """s (P, S + 12) → x (P, S), g_t (P, 6), g_{t-1} (P, 6)."""
        if s.dim() != 2 or s.shape[1] != self.dim:
            raise PriortrackError(f"filter state has shape {tuple(s.shape)}; expected (P, {self.dim})")
        S = self.pose_dim
        return s[:, :S], s[:, S:S + GLOBAL_DIM], s[:, S + GLOBAL_DIM:]

    def predict(self, s: torch.Tensor, generator: torch.Generator, translation: bool = True) -> torch.Tensor:
        """One draw of s_t per row of s_{t-1}; with ``translation=False`` the translation is not
        drawn but predicted, t_t = t̂_t (GlobalMotion: for a filter that integrates it out)."""
        x, g, g_prev = self.split(s)
        g_t = self.global_motion.sample(g, g_prev, generator, translation=translation)
        return torch.cat([self.prior.sample(x, generator), g_t, g], -1)

    def log_transition(self, s_next: torch.Tensor, s: torch.Tensor, translation: bool = True) -> torch.Tensor:
        """(P,) log p(x_t, g_t | s_{t-1}) of the new parts of s_next = [x_t, g_t, ·] (P, S + 12) given
        s = s_{t-1} (P, S + 12): prior.log_prob(x_t, x_{t-1}) + GlobalMotion.log_prob(g_t | g_{t-1},
        g_{t-2}) (without the translation's factor when ``translation=False``). s_next's copy of
        g_{t-1} is not compared with s's: a backward pass re-joins trajectories by this density."""
        x_next, g_next, _ = self.split(s_next)
        x, g, g_prev = self.split(s)
        return self.prior.log_prob(x_next, x) + self.global_motion.log_prob(g_next, g, g_prev, translation)

    def pose_step(self, s: torch.Tensor, parents: torch.Tensor) -> torch.Tensor:
        """(P, S + 12) states and their parents → (S + 12,) per coordinate, the RMS length per tangent
        dimension of the prior's step x_{t−1} → x_t in that coordinate's joint group (0 for the
        placements): the scale of the particle filter's resample-move proposals (:meth:`perturb`)."""
        space = self.prior.space
        x, x_prev = self.split(s)[0], self.split(parents)[0]
        dims = torch.as_tensor(space.tangent_dims, dtype=s.dtype, device=s.device)
        per_group = (space.group_norms_sq(space.boxminus(x, x_prev)).mean(0) / dims).sqrt()
        return torch.cat([per_group[torch.as_tensor(space.groups, device=s.device)], s.new_zeros(2 * GLOBAL_DIM)])

    def perturb(self, s: torch.Tensor, std: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """s (P, S + 12) with each pose moved to x ⊞ ε, ε isotropic tangent noise of std (S + 12,)'s pose
        part (equal within a joint group: a symmetric proposal), the placements kept."""
        space, S = self.prior.space, self.pose_dim
        x = s[:, :S]
        return torch.cat([space.boxplus(x, space.tangent_noise(x, std[:S].to(s), generator)), s[:, S:]], -1)

    def with_translation(self, s: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """s (P, S + 12) with t_t and t_{t-1} replaced by t[:, :3] and t[:, 3:] (P, 6)."""
        S = self.pose_dim
        out = s.clone()
        out[:, S:S + 3] = t[:, :3].to(s)
        out[:, S + GLOBAL_DIM:S + GLOBAL_DIM + 3] = t[:, 3:].to(s)
        return out

    def translation(self, s: torch.Tensor) -> torch.Tensor:
        """(P, S + 12) → (t_t, t_{t-1}) (P, 6)."""
        S = self.pose_dim
        return torch.cat([s[:, S:S + 3], s[:, S + GLOBAL_DIM:S + GLOBAL_DIM + 3]], -1)

    def shift_translation(self, s: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
        """s (P, S + 12) with t_t moved by shift[:, :3] and t_{t-1} by shift[:, 3:] (P, 6)."""
        return self.with_translation(s, self.translation(s) + shift.to(s))

    def turned(self, s: torch.Tensor, angles: torch.Tensor, pivots: torch.Tensor) -> torch.Tensor:
        """s (P, S + 12) with both placements g_t and g_{t−1} of each row turned by its angle (P,) about the world's
        up through its pivot (P, 3) (:func:`~priortrack.geometry.facing.turned_placements`), the pose kept."""
        S, out = self.pose_dim, s.clone()
        for g in (S, S + GLOBAL_DIM):
            out[:, g:g + GLOBAL_DIM] = turned_placements(s[:, g:g + GLOBAL_DIM], angles, pivots)
        return out

    def mean_step(self, s: torch.Tensor) -> torch.Tensor:
        """The deterministic mean step (the unscented filter's fx)."""
        x, g, g_prev = self.split(s)
        return torch.cat([self.prior.mean(x), self.global_motion.predict(g, g_prev), g], -1)

    def observe(self, s: torch.Tensor) -> torch.Tensor:
        """(P, S + 12) → (P, J, 3) world joints, metres, in s's dtype."""
        x, g, _ = self.split(s)
        return to_world(self.body.joints(x), g)

    def gate(self, z) -> tuple[torch.Tensor, int]:
        """One frame's data with the observation model's gross outliers made missing, and their count."""
        return self.likelihood.gate(z)

    def log_likelihood(self, joints: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """(P, J, 3) world joints, z (observation_shape, NaN = missing) → (P,) log p(z | joints)."""
        return self.likelihood.log_likelihood(joints, z)

    def initial_states(self, motion: Motion, n: int, generator: torch.Generator, start: int = 1) -> torch.Tensor:
        """(n, S + 12) states around frame ``start`` of a known motion (its first two frames by
        default, as in the papers' experiments): the pose drawn by ``prior.initial``, the
        placements g_start and g_{start-1} exact. Frames are counted at the prior's frame rate.

        The known frames also give the subject's body: from here on joints are decoded with its
        bone lengths (:meth:`StateSpace.for_body`), not the training subjects' (a 5% smaller
        subject seen through the prior's body would be placed 5% too far from the camera)."""
        motion = motion if motion.fps == self.prior.fps else motion.resample(self.prior.fps)
        if not 1 <= start < len(motion):
            raise PriortrackError(f"initial frame {start} is outside [1, {len(motion) - 1}]")
        self.body = self.prior.space.for_body(motion[start - 1:start + 1])
        x0 = self.prior.encode(motion[start:start + 1])[0]
        g = self.prior.space.global_pose(motion[start - 1:start + 1])
        x = self.prior.initial(x0, n, generator)
        return torch.cat([x, g[1].expand(n, -1).to(x), g[0].expand(n, -1).to(x)], -1)

    def mean(self, s: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        """Weighted mean state (S + 12,): the pose on the prior's manifold, translations
        averaged, rotations by their chordal mean argmin_R Σ_i w_i ‖R − R_i‖²_F. Since
        tr(A(q)ᵀ A(q_i)) = 4 (q·q_i)² − 1 for rotation matrices A of unit quaternions, that is the
        quaternion q maximising qᵀ (Σ_i w_i q_i q_iᵀ) q: the principal eigenvector of a 4 × 4 matrix
        (Markley, Cheng, Crassidis & Oshman, J. Guidance 30(4), 2007), computed in float64."""
        x, g, g_prev = self.split(s)
        w = (weights / weights.sum()).to(s)
        placements = torch.stack([g, g_prev])                                     # (2, P, 6)
        t = w @ placements[..., :3]                                               # (2, 3)
        q = so3.quaternion(placements[..., 3:]).to(torch.float64)                 # (2, P, 4)
        M = ((q * w.to(q)[:, None])[..., :, None] * q[..., None, :]).sum(1)       # (2, 4, 4), Σ_i w_i q_i q_iᵀ
        # (as a sum, not a (4, P) @ (P, 4) product: a GPU runs that GEMM on one tile, 7 ms at P = 10⁶)
        omega = so3.quaternion_log(torch.linalg.eigh(M)[1][..., -1]).to(s)        # (2, 3)
        return torch.cat([self.prior.space.mean(x, w), t[0], omega[0], t[1], omega[1]])
