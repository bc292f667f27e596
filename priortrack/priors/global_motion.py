"""Global motion: the body's placement in the world as a second-order Gauss–Markov model.

The placement g = (t, ω): translation t (3,) metres and rotation vector ω (3,) of the
world-from-body rotation, so that world joints are X = exp(ω) · B + t for body-frame joints
B from a pose prior (:meth:`StateSpace.joints`). As in the GPDM tracking paper, the next
placement is predicted at constant velocity and perturbed by Gaussian noise:

    t̂_t = 2 t_{t-1} − t_{t-2},             t_t = t̂_t + ε_t,           ε_t ~ N(0, diag σ_t²),
    R̂_t = R_{t-1} R_{t-2}ᵀ R_{t-1},        R_t = exp(η_t) R̂_t,        η_t ~ N(0, diag σ_ω²),

the rotation's constant-velocity step taken on SO(3) and its noise a world-frame rotation
vector. σ_t and σ_ω (per axis) are fitted by maximum likelihood to training placements.
Rotations are composed as unit quaternions (:func:`priortrack.geometry.so3.quaternion`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from priortrack.errors import PriortrackError
from priortrack.geometry import so3
from priortrack.kernels import cpu_kernel_applies
from priortrack.randomness import standard_normal
from priortrack.threads import split_rows

#: Smallest σ a fit may return (metres or radians per frame).
SIGMA_FLOOR = 1e-4


def to_world(body_joints: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """X = exp(ω) · B + t: body joints (P, J, 3) placed by g (P, 6) → world joints (P, J, 3).

    float32 on the CPU without gradients goes through the fused kernel of
    :mod:`priortrack.priors.placement_kernel` (the same formula, a few times faster at 10⁴ rows;
    its rows split among torch's threads by :func:`priortrack.threads.split_rows`)."""
    if body_joints.dim() != 3 or body_joints.shape[-1] != 3 or g.shape != (body_joints.shape[0], 6):
        raise PriortrackError(f"body joints {tuple(body_joints.shape)} and placements {tuple(g.shape)}: "
                              f"expected (P, J, 3) and (P, 6)")
    if cpu_kernel_applies(body_joints, g, dtype=torch.float32):
        from priortrack.priors.placement_kernel import place

        out = torch.empty(body_joints.shape, dtype=torch.float32)
        B, G, X = body_joints.detach().contiguous().numpy(), g.detach().contiguous().numpy(), out.numpy()
        split_rows(len(B), lambda r: place(B[r], G[r], X[r]))
        return out
    R = so3.exp(g[:, 3:])
    return torch.baddbmm(g[:, None, :3], body_joints, R.transpose(-1, -2))


class GlobalMotion:
    """Second-order Gauss–Markov model of the placement g = (t, ω).

    Attributes:
        sigma: (6,) σ of the translation noise along x, y, z (metres per frame) and of the
            rotation noise about x, y, z (radians per frame).
    """

    def __init__(self, sigma):
        self.sigma = torch.as_tensor(sigma, dtype=torch.float64)
        if self.sigma.shape != (6,) or not torch.all(self.sigma > 0):
            raise PriortrackError(f"global motion sigma must be 6 positive values, got {tuple(self.sigma.shape)}")

    @classmethod
    def fit(cls, placements: Sequence[torch.Tensor]) -> GlobalMotion:
        """Maximum-likelihood σ from training placements, each (T, 6) with T ≥ 3."""
        residuals = []
        for g in placements:
            if g.dim() != 2 or g.shape[1] != 6 or len(g) < 3:
                raise PriortrackError(f"placements need shape (T ≥ 3, 6), got {tuple(g.shape)}")
            residuals.append(cls.residual(g[2:], g[1:-1], g[:-2]))
        r = torch.cat(residuals)
        return cls(torch.clamp(r.pow(2).mean(dim=0).sqrt(), min=SIGMA_FLOOR))

    @staticmethod
    def _predicted(g1: torch.Tensor, g2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """t̂_t (P, 3) and R̂_t as a unit quaternion q̂ = q_1 q_2* q_1 (P, 4) from g_{t-1}, g_{t-2}."""
        q1 = so3.quaternion(g1[:, 3:])
        q2_inverse = so3.quaternion_conjugate(so3.quaternion(g2[:, 3:]))
        return 2 * g1[:, :3] - g2[:, :3], so3.quaternion_product(so3.quaternion_product(q1, q2_inverse), q1)

    @classmethod
    def predict(cls, g1: torch.Tensor, g2: torch.Tensor) -> torch.Tensor:
        """ĝ_t (P, 6) from g_{t-1}, g_{t-2} (P, 6): constant velocity in R³ and on SO(3)."""
        t_hat, q_hat = cls._predicted(g1, g2)
        return torch.cat([t_hat, so3.quaternion_log(q_hat)], dim=-1)

    @classmethod
    def residual(cls, g: torch.Tensor, g1: torch.Tensor, g2: torch.Tensor) -> torch.Tensor:
        """(ε, η) (P, 6): the noise that takes ĝ_t to g_t, η = log(R_t R̂_tᵀ)."""
        t_hat, q_hat = cls._predicted(g1, g2)
        eta = so3.quaternion_log(so3.quaternion_product(so3.quaternion(g[:, 3:]), so3.quaternion_conjugate(q_hat)))
        return torch.cat([g[:, :3] - t_hat, eta], dim=-1)

    def sample(self, g1: torch.Tensor, g2: torch.Tensor, generator: torch.Generator,
               translation: bool = True) -> torch.Tensor:
        """One draw of g_t (P, 6) per row of g_{t-1}, g_{t-2}; with ``translation=False`` only the
        rotation is drawn and t_t = t̂_t (for a filter that integrates the translation out).
        float32 on the CPU without gradients goes through the fused kernel of
        :mod:`priortrack.priors.global_motion_kernel` (the same draw from the same variates)."""
        if g1.dim() != 2 or g1.shape[1] != 6 or g2.shape != g1.shape:
            raise PriortrackError(f"placements g_(t-1) {tuple(g1.shape)} and g_(t-2) {tuple(g2.shape)}: "
                                  f"expected both (P, 6)")
        sigma = self.sigma.to(g1)
        sigma = sigma if translation else torch.cat([torch.zeros_like(sigma[:3]), sigma[3:]])
        if cpu_kernel_applies(g1, g2, dtype=torch.float32):
            from priortrack.priors.global_motion_kernel import sample

            noise = standard_normal((len(g1), 6), generator, g1)              # the variates _perturbed draws
            out = torch.empty(g1.shape, dtype=torch.float32)
            G1, G2, N, S, X = (g1.contiguous().numpy(), g2.contiguous().numpy(), noise.numpy(), sigma.numpy(),
                               out.numpy())
            split_rows(len(G1), lambda r: sample(G1[r], G2[r], N[r], S, X[r]))
            return out
        t_hat, q_hat = self._predicted(g1, g2)
        return self._perturbed(t_hat, q_hat, sigma, generator)

    @classmethod
    def perturb(cls, g: torch.Tensor, std: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """g (P, 6) with the model's kind of noise, per axis std (6,): t + ε, exp(η) R."""
        return cls._perturbed(g[:, :3], so3.quaternion(g[:, 3:]), std, generator)

    @staticmethod
    def _perturbed(t: torch.Tensor, q: torch.Tensor, std: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """(t + ε, log(exp(η) R)) for translations t (P, 3) and rotations R as quaternions q (P, 4),
        (ε, η) ~ N(0, diag std²) (P, 6)."""
        noise = standard_normal((len(t), 6), generator, t) * std
        rotation = so3.quaternion_product(so3.quaternion(noise[:, 3:]), q)
        return torch.cat([t + noise[:, :3], so3.quaternion_log(rotation)], dim=-1)

    def log_prob(self, g: torch.Tensor, g1: torch.Tensor, g2: torch.Tensor) -> torch.Tensor:
        """(P,) log p(g_t | g_{t-1}, g_{t-2}), the Gaussian density of the residual (ε, η)."""
        r = self.residual(g, g1, g2)
        var = (self.sigma ** 2).to(r)
        return (-0.5 * r * r / var - 0.5 * torch.log(2 * math.pi * var)).sum(dim=-1)
