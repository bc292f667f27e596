"""Gaussian diffusion baselines: x_t = x_{t-1} ⊞ ε, ε ~ N(0, diag σ²).

One σ for every coordinate (``diffusion-global``) or one per joint (``diffusion-local``),
in joint-angle space (⊞ = +) or on the sphere product of bone directions (⊞ = exp map,
ε an isotropic Gaussian in each bone's 2-D tangent plane). Maximum likelihood on the
training steps v_t = x_{t+1} ⊟ x_t, for group g with n_g tangent dimensions:

    σ_g² = Σ_t |v_{t,g}|² / (N n_g)   (local),     σ² = Σ_t |v_t|² / (N Σ_g n_g)   (global).

log p(x_t | x_{t-1}) = Σ_g [ −|v_g|²/(2σ_g²) − (n_g/2) log(2π σ_g²) ], the density of the step
in tangent coordinates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.priors.base import DEFAULT_FPS, TransitionModel, prepare_motions
from priortrack.priors.spaces import SPACES, StateSpace

#: Smallest σ a fit may return (radians): a joint that never moved in training still diffuses.
SIGMA_FLOOR = 1e-4


class Diffusion(TransitionModel):
    """A Gaussian random walk in a state space.

    Attributes:
        sigma: (G,) standard deviation per joint group (all equal for ``diffusion-global``).
    """

    def __init__(self, space: StateSpace, sigma, local: bool, fps: float = DEFAULT_FPS, objective: float = float("nan")):
        self.space, self.fps, self.local = space, float(fps), bool(local)
        self.kind = "diffusion-local" if local else "diffusion-global"
        self.sigma = torch.as_tensor(np.asarray(sigma, dtype=float))
        if self.sigma.shape != (len(space.group_names),) or not torch.all(self.sigma > 0):
            raise PriortrackError(f"diffusion sigma must be ({len(space.group_names)},) positive values")
        self.objective = objective
        self._std = self.sigma[torch.as_tensor(space.groups)]          # (S,)
        self._dims = torch.as_tensor(space.tangent_dims, dtype=torch.float64)

    @classmethod
    def fit(cls, motions: Sequence[Motion], local: bool = True, space: str = "angles",
            fps: float = DEFAULT_FPS) -> Diffusion:
        """Maximum-likelihood σ from the frame-to-frame steps of ``motions``."""
        if space not in SPACES:
            raise PriortrackError(f"unknown space {space!r}; spaces: {', '.join(SPACES)}")
        motions = prepare_motions(motions, fps, min_frames=2)
        state_space = SPACES[space].fit(motions)
        sq = torch.zeros(len(state_space.group_names), dtype=torch.float64)
        steps = 0
        for m in motions:
            x = state_space.encode(m)
            sq += state_space.group_norms_sq(state_space.boxminus(x[1:], x[:-1])).sum(dim=0)
            steps += len(x) - 1
        dims = torch.as_tensor(state_space.tangent_dims, dtype=torch.float64)
        var = sq / (steps * dims) if local else (sq.sum() / (steps * dims.sum())).expand_as(sq)
        sigma = torch.clamp(var.sqrt(), min=SIGMA_FLOOR)
        model = cls(state_space, sigma.numpy(), local, fps)
        model.objective = float(-sum(model.log_prob(x[1:], x[:-1]).sum() for x in map(state_space.encode, motions)) / steps)
        return model

    def to(self, device) -> Diffusion:
        self.sigma, self._std, self._dims = (t.to(device) for t in (self.sigma, self._std, self._dims))
        return self

    def _std_for(self, x):
        return self._std.to(device=x.device, dtype=x.dtype)

    def sample(self, x, generator):
        x = self.check_state(x)
        return self.space.boxplus(x, self.space.tangent_noise(x, self._std_for(x), generator))

    def log_prob(self, x_next, x):
        x_next, x = self.check_pair(x_next, x)
        sq = self.space.group_norms_sq(self.space.boxminus(x_next, x))            # (P, G)
        var = (self.sigma ** 2).to(device=x.device, dtype=x.dtype)
        dims = self._dims.to(device=x.device, dtype=x.dtype)
        return (-0.5 * sq / var - 0.5 * dims * torch.log(2 * math.pi * var)).sum(dim=-1)

    def mean(self, x):
        return self.check_state(x).clone()

    def transition_covariance(self, x) -> torch.Tensor:
        """(P, S) states → (P, n, n) covariance of the step ε in tangent coordinates at each state:
        diag(σ_g² of each coordinate's group), the same at every state. n = Σ_g n_g: the state's
        own coordinates in a Euclidean space; on the spheres 2 orthonormal coordinates per bone,
        bone by bone (the step is isotropic in each tangent plane, so any orthonormal basis)."""
        x = self.check_state(x)
        space = self.space
        groups = np.repeat(np.arange(len(space.group_names)), space.tangent_dims) if space.manifold else space.groups
        var = (self.sigma ** 2)[torch.as_tensor(groups, device=self.sigma.device)].to(device=x.device, dtype=x.dtype)
        return torch.diag_embed(var).expand(x.shape[0], -1, -1)

    def _arrays(self):
        return {"sigma": self.sigma.cpu().numpy()}

    def _header(self):
        return {"local": self.local, "objective": self.objective,
                "preprocessing": {"fps": self.fps, "space": type(self.space).__name__}}

    @classmethod
    def _restore(cls, arrays, header):
        space = next(s for s in SPACES.values() if s.__name__ == header["space"]).from_arrays(arrays)
        return cls(space, arrays["sigma"], header["local"], header["fps"], header["objective"])
