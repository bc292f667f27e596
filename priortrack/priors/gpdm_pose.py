"""The GPDM with the pose in the state, for the particle filters: Urtasun, Fleet & Fua's tracked state (CVPR 2006,
§4), its pose's offset from the latent manifold carried from frame to frame.

A particle of :class:`~priortrack.priors.gpdm.GPDM` alone is a latent position x, its pose the reconstruction mean
μ_Y(x): the poses it can reach are those of the latent manifold of the training walks, and where several cameras
pin a person's pose better than that, the manifold is the error's floor (pf-gpdm on held-out people through four
cameras, eval people: 2.5 / 2.2× per-frame triangulation, worst / mean, 100 % of frames flagged). Urtasun et al.
track the state (x_t, y_t), the pose y_t beside its latent position, held to the manifold by the GP's conditional
density (their eq. 18), not fixed on it. Here the pose's offset from the manifold, r_t = y_t − μ_Y(x_t), persists:
a person the prior never saw walks like the training walks but with a posture of their own, an offset that lasts.
It steps by the GP's own uncertainty plus the training poses' own step a frame:

    p(x_t, y_t | x_{t−1}, y_{t−1}) = N(x_t; μ_X(x_{t−1}), σ_X²(x_{t−1})/λ I_d) · N(y_t; μ_Y(x_t) + r_{t−1}, (σ²(x_t) + s²) W⁻²)

μ_X, σ_X² the dynamics (eqs. 16–17, annealed by λ as :meth:`~priortrack.priors.gpdm.GPDM.annealed`), μ_Y, σ² the
reconstruction (eqs. 19–20), W the data scales, r_{t−1} = y_{t−1} − μ_Y(x_{t−1}), and s² the mean squared W-scaled
step a frame of the training poses, |W(y_t − y_{t−1})|² / D (the maximum-likelihood variance of an isotropic
random walk on them: 0.030 on pf-gpdm's walks, against σ² ≈ 0.004 near the training latents). With r_{t−1} = 0 and
s² = 0 the pose's factor is the paper's eq. 18 (without its ½|x|², the latent prior the dynamics replace).

Measured (eval people, 4 cameras, 5 px, the auxiliary guided draw, held-out people, × per-frame DLT worst / mean):
the latent state alone 2.50 / 2.18 (10 px, the draw not auxiliary); the pose drawn afresh each frame about μ_Y(x_t)
(r = 0, s² = 0, the paper's density; no auxiliary) 1.33 / 1.02; the offset carried with σ²(x_t) alone 1.03 / 0.74,
losing part of a walk where the particles sat on the manifold and σ² (about 1° a frame) could not follow the person
(05_01: 20 mm, 1.8× DLT on one seed); with s² 0.97 / 0.57, every walk but 39_01 at 0.32–0.66 (39_01, flagged on
every tick, 1.25–1.65; the Lie presets 0.64–0.94 there). docs/results/2026-11-28-gpdm-pose-state.md.

The guided proposal (:mod:`priortrack.filters.proposal`) linearises the step as one Gaussian in (x, y): with
μ_Y(x_t) ≈ μ_Y(m) + J (x_t − m), m = μ_X(x_{t−1}), J = ∂μ_Y/∂x at m (:meth:`PoseStateGPDM.pose_jacobian`),

    Q = [[S, S Jᵀ], [J S, J S Jᵀ + (σ²(m) + s²) W⁻²]],   S = σ_X²(x_{t−1})/λ I_d;

the weights use the exact density above.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.priors.base import BuiltOnPrior, TransitionModel
from priortrack.priors.gpdm import GPDM, LatentSpace, k_Y
from priortrack.randomness import standard_normal


class LatentPoseSpace(LatentSpace):
    """States (x, y) ∈ R^(d + D): the latent position x, then the pose y (the GPDM's angle channels, radians, with
    the mean pose), Euclidean. Groups: "x0", … per latent dimension, then the angle space's joints. Joints decode
    from y alone; the body, the placement and the file arrays are the latent space's (its angle space's)."""

    def __init__(self, model: GPDM, angles):
        super().__init__(model, angles)
        self.group_names = self.group_names + angles.group_names
        self.groups = np.concatenate([self.groups, model.d + angles.groups])
        self.tangent_dims = np.concatenate([self.tangent_dims, angles.tangent_dims])

    def encode(self, motion: Motion) -> torch.Tensor:
        """(T, d + D): each frame's latent position (:meth:`~priortrack.priors.gpdm.GPDM.encode_poses`) and its pose."""
        y = self.angles.encode(motion)
        return torch.cat([self.model.encode_poses(y), y], -1)

    def joints(self, x: torch.Tensor) -> torch.Tensor:
        return self.angles.joints(x[..., self.model.d:])


class PoseStateGPDM(BuiltOnPrior):
    """The transition of (x, y) states (module docstring) built on a (balanced) GPDM ``gpdm`` (annealed or not).
    Its kind and frame rate are the GPDM's; its space :class:`LatentPoseSpace`. States (P, d + D)."""

    BASE, WHAT, SHARED = "gpdm", "a GPDM with the pose in its state", ("kind", "fps")

    def __init__(self, gpdm: GPDM):
        if not isinstance(gpdm, GPDM):
            raise PriortrackError(f"the pose state is a GPDM's (kinds 'gpdm', 'bgpdm'), not a {gpdm.kind} prior's")
        self.gpdm, self.d = gpdm, gpdm.d
        self.space = LatentPoseSpace(gpdm, gpdm.space.angles)
        steps = [(s[1:] - s[:-1]) * gpdm.W for s in gpdm.Y.split(gpdm.lengths) if len(s) > 1]
        #: s², the training poses' mean squared step a frame per W-scaled channel (float).
        self.step_variance = float(torch.cat(steps).pow(2).mean())

    # The state's checks, decoding and start are the base contract's, on this space.
    state_dim = TransitionModel.state_dim
    check_state, check_pair = TransitionModel.check_state, TransitionModel.check_pair
    joints, encode, initial = TransitionModel.joints, TransitionModel.encode, TransitionModel.initial
    step_weights, step_components = TransitionModel.step_weights, TransitionModel.step_components

    def _split(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return z[:, :self.d].contiguous(), z[:, self.d:]

    def _offset(self, z: torch.Tensor) -> torch.Tensor:
        """(P, D) float64 r = y − μ_Y(x) of states z (P, d + D)."""
        x, y = self._split(z)
        return y.to(torch.float64) - self.gpdm.pose_mean(x).to(torch.float64)

    def _pose_given(self, x_next: torch.Tensor, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The pose's mean μ_Y(x_t) + r_{t−1} (P, D) and W-scaled variance σ²(x_t) + s² (P,), float64, given x_t (P, d)
        and the previous states z (P, d + D): one reconstruction of x_t for both."""
        mu, var = self.gpdm.reconstruct(x_next)
        return mu.to(torch.float64) + self._offset(z), var.to(torch.float64) + self.step_variance

    def sample(self, z: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """(P, d + D) → (P, d + D): x_t from the GPDM's (annealed) dynamics, then y_t ~ N(μ_Y(x_t) + r_{t−1}, (σ²(x_t) + s²) W⁻²)."""
        z = self.check_state(z)
        x_next = self.gpdm.sample(self._split(z)[0], generator)
        mean, var = self._pose_given(x_next, z)
        noise = standard_normal(mean.shape, generator, mean)
        y_next = mean + (var.sqrt()[:, None] / self.gpdm.W.to(z.device)) * noise
        return torch.cat([x_next, y_next.to(z.dtype)], -1)

    def log_prob(self, z_next: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """(P,) ln N(x_t; μ_X, σ_X²/λ I_d) + ln N(y_t; μ_Y(x_t) + r_{t−1}, (σ²(x_t) + s²) W⁻²), float64."""
        z_next, z = self.check_pair(z_next, z)
        x_next, y_next = self._split(z_next)
        dynamics = self.gpdm.log_prob(x_next, self._split(z)[0]).to(torch.float64)
        mean, var = self._pose_given(x_next, z)
        W = self.gpdm.W.to(z.device)
        r = (y_next.to(torch.float64) - mean) * W
        return (dynamics - 0.5 * r.pow(2).sum(-1) / var - 0.5 * self.gpdm.D * torch.log(2 * math.pi * var)
                + torch.log(W).sum())

    def mean(self, z: torch.Tensor) -> torch.Tensor:
        """(P, d + D) → (m, μ_Y(m) + r_{t−1}), m = μ_X(x): the pose's mean given the mean latent step."""
        z = self.check_state(z)
        m = self.gpdm.mean(self._split(z)[0])
        return torch.cat([m, (self.gpdm.pose_mean(m).to(torch.float64) + self._offset(z)).to(z.dtype)], -1)

    def pose_jacobian(self, x: torch.Tensor) -> torch.Tensor:
        """(P, d) latent rows → (P, D, d) J = ∂μ_Y/∂x, float64. From μ_Y(x) = ȳ + Σ_n k_n(x) A_n with
        k_n = β1 exp(−β2/2 |x − X_n|²) (eq. 19), A = K_Y⁻¹ Y: J = −β2 Σ_n k_n A_n (x − X_n)ᵀ."""
        g = self.gpdm
        x = x.to(torch.float64)
        X, A = g.X.to(x.device), g.A_Y.to(x.device)
        k = k_Y(x, X, g.log_beta.to(x.device))                                 # (P, N)
        return -g.beta[1].item() * ((k @ A)[:, :, None] * x[:, None, :] - torch.einsum("pn,nD,nd->pDd", k, A, X))

    def transition_covariance(self, z: torch.Tensor) -> torch.Tensor:
        """(P, d + D) → (P, d + D, d + D) Q of the linearised step (module docstring), float64."""
        z = self.check_state(z)
        x = self._split(z)[0].to(torch.float64)
        m, S = self.gpdm.mean(x), self.gpdm.transition_covariance(x)            # μ_X, σ_X²/λ I_d (P, d, d)
        J = self.pose_jacobian(m)                                                # (P, D, d)
        var = self.gpdm.reconstruct(m)[1].to(torch.float64) + self.step_variance  # σ²(m) + s² (P,)
        SJt = S @ J.transpose(1, 2)                                              # (P, d, D)
        pose = J @ SJt + torch.diag_embed(var[:, None] / self.gpdm.W.to(z.device).pow(2))
        return torch.cat([torch.cat([S, SJt], 2), torch.cat([SJt.transpose(1, 2), pose], 2)], 1)
