"""Global motion: the body's placement in the world as a Gauss–Markov model.

The placement g = (t, ω): translation t (3,) metres and rotation vector ω (3,) of the
world-from-body rotation, so that world joints are X = exp(ω) · B + t for body-frame joints
B from a pose prior (:meth:`StateSpace.joints`). The rotation splits into heading ψ about the
world vertical and tilt τ = (τ_x, τ_z) about a horizontal axis of the heading frame,
R = exp(ψ e_y) exp(τ_x e_x + τ_z e_z) (:func:`priortrack.geometry.so3.heading_tilt`). As in the
GPDM tracking paper, the root position and heading are second order with Gaussian noise: on the
ground plane and in heading constant velocity, in height a damped velocity (the pelvis bobs about
a level height, its vertical velocity mean free); the tilt is first order and mean reverting (AR(1)):

    t_t = t_{t-1} + v ⊙ (t_{t-1} − t_{t-2}) + ε_t,          ε_t ~ N(0, diag σ_t²),  v = (1, b, 1),
    ψ_t = ψ_{t-1} + (ψ_{t-1} − ψ_{t-2}) + η_ψ,             η_ψ ~ N(0, σ_ψ²),
    τ_t = μ + a ⊙ (τ_{t-1} − μ) + η_τ,                     η_τ ~ N(0, diag σ_τ²),

with σ_t, σ_ψ, σ_τ, the tilt's mean μ and decay a ∈ [0, 1] and the height's velocity decay
b ∈ [0, 1] fitted by maximum likelihood to training placements. Why the height's velocity decays:
constant velocity extrapolates the pelvis's bob, so through a blackout of 1.1 s the body sank
300–430 mm below the floor (map-gpdm and pf-gpdm on 07_10 and 07_11); walks give b ≈ 0.74.
Why the tilt is not second order: an upright body's lean is stationary (within a few degrees on
walks), and a constant-velocity model lets its angular velocity random walk. Seen by one camera, a lean towards or away from it is nearly invisible (the translation's
depth makes up for the foreshortening), so a particle filter with the Lie prior drifted into
leans of 15–25° and placed the body 5 % too near (07_11, occlusion, 4 seeds: world MPJPE
225 → 143 mm, root-relative 153 → 73 mm with this model).
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


def _parameter(name: str, value, shape: tuple[int, ...]) -> torch.Tensor:
    """``value`` as a finite float64 tensor of ``shape``, or a ``PriortrackError`` naming ``name``."""
    try:
        t = torch.as_tensor(value, dtype=torch.float64)
    except (TypeError, ValueError, RuntimeError):
        raise PriortrackError(f"global motion {name} must be numbers, got {value!r}") from None
    if t.shape != shape or not torch.all(torch.isfinite(t)):
        raise PriortrackError(f"global motion {name} must be {shape[0] if shape else 1} finite value(s), "
                              f"got {t.tolist()}")
    return t


class GlobalMotion:
    """The placement model above: g_t given g_{t-1}, g_{t-2}.

    Attributes:
        sigma: (6,) σ of the translation noise along x, y, z (metres per frame), then of the
            rotation noise about x, y, z: σ_τx (tilt), σ_ψ (heading), σ_τz (tilt) (radians per frame).
        tilt_mean: (2,) μ, the tilt (τ_x, τ_z) the process reverts to (radians).
        tilt_decay: (2,) a ∈ [0, 1], the tilt's AR(1) coefficients (1: a random walk).
        velocity: (3,) v = (1, b, 1), the translation velocity's decay per frame along x, y, z
            (b ∈ [0, 1] the height's; 1: constant velocity).
    """

    def __init__(self, sigma, tilt_mean=(0.0, 0.0), tilt_decay=(1.0, 1.0), height_decay=1.0):
        self.sigma = _parameter("sigma", sigma, (6,))
        self.tilt_mean = _parameter("tilt_mean", tilt_mean, (2,))
        self.tilt_decay = _parameter("tilt_decay", tilt_decay, (2,))
        b = _parameter("height_decay", height_decay, ())
        if not torch.all(self.sigma > 0):
            raise PriortrackError(f"global motion sigma must be 6 positive values, got {self.sigma.tolist()}")
        if not torch.all((self.tilt_decay >= 0) & (self.tilt_decay <= 1)):
            raise PriortrackError(f"global motion tilt_decay must be 2 values in [0, 1], got {self.tilt_decay.tolist()}")
        if not 0 <= float(b) <= 1:
            raise PriortrackError(f"global motion height_decay must lie in [0, 1], got {float(b)}")
        self.velocity = torch.tensor([1.0, float(b), 1.0], dtype=torch.float64)

    @classmethod
    def fit(cls, placements: Sequence[torch.Tensor]) -> GlobalMotion:
        """Maximum-likelihood parameters from training placements, each (T, 6) with T ≥ 3.

        (μ, a, σ_τ) per tilt coordinate are the least-squares AR(1) fit τ_t ≈ c + a τ_{t-1} over
        frames 2.. of every sequence (the conditional ML estimate), a clamped to [0, 1] and
        μ = c / (1 − a) (the tilts' mean where a = 1); b the least-squares fit of the height's
        velocity, Δy_t ≈ b Δy_{t-1}, clamped to [0, 1]; σ_t, σ_ψ the RMS of the model's residuals.
        σ's are floored at ``SIGMA_FLOOR``."""
        g, g1, g2 = [], [], []
        for p in placements:
            if p.dim() != 2 or p.shape[1] != 6 or len(p) < 3:
                raise PriortrackError(f"placements need shape (T ≥ 3, 6), got {tuple(p.shape)}")
            if not torch.all(torch.isfinite(p)):
                raise PriortrackError("placements contain NaN or inf")
            g.append(p[2:])
            g1.append(p[1:-1])
            g2.append(p[:-2])
        g, g1, g2 = (torch.cat(x).to(torch.float64) for x in (g, g1, g2))
        tau, tau1 = _split(g)[2], _split(g1)[2]
        d, d1 = tau - tau.mean(0), tau1 - tau1.mean(0)
        decay = _lag_one(d, d1)
        intercept = tau.mean(0) - decay * tau1.mean(0)
        mean = torch.where(decay < 1 - 1e-9, intercept / torch.clamp(1 - decay, min=1e-9), tau.mean(0))
        height = float(_lag_one(g[:, 1] - g1[:, 1], g1[:, 1] - g2[:, 1]))                 # Δy_t on Δy_{t-1}
        sigma = cls(torch.ones(6), mean, decay, height).residual(g, g1, g2).pow(2).mean(dim=0).sqrt()   # σ not in it
        return cls(torch.clamp(sigma, min=SIGMA_FLOOR), mean, decay, height)

    def _predicted(self, g1: torch.Tensor, g2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """t̂_t (P, 3), ψ̂_t (P,) and τ̂_t (P, 2) from g_{t-1}, g_{t-2} (P, 6)."""
        t1, psi1, tau1 = _split(g1)
        t2, psi2, _ = _split(g2)
        mean, decay = self.tilt_mean.to(g1), self.tilt_decay.to(g1)
        return t1 + self.velocity.to(g1) * (t1 - t2), psi1 + so3.wrap_angle(psi1 - psi2), mean + decay * (tau1 - mean)

    def predict(self, g1: torch.Tensor, g2: torch.Tensor) -> torch.Tensor:
        """ĝ_t (P, 6) from g_{t-1}, g_{t-2} (P, 6): the mean of the model's step."""
        t_hat, psi_hat, tau_hat = self._predicted(g1, g2)
        return _joined(t_hat, psi_hat, tau_hat)

    def residual(self, g: torch.Tensor, g1: torch.Tensor, g2: torch.Tensor) -> torch.Tensor:
        """(ε, η_τx, η_ψ, η_τz) (P, 6): the noise that takes ĝ_t to g_t (the heading's wrapped to [−π, π))."""
        t_hat, psi_hat, tau_hat = self._predicted(g1, g2)
        t, psi, tau = _split(g)
        eta_tau = tau - tau_hat
        return torch.cat([t - t_hat, eta_tau[:, :1], so3.wrap_angle(psi - psi_hat)[:, None], eta_tau[:, 1:]], dim=-1)

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
            tilt = torch.stack([self.tilt_mean, self.tilt_decay]).to(torch.float32)
            G1, G2, N, S, A, V, X = (g1.contiguous().numpy(), g2.contiguous().numpy(), noise.numpy(), sigma.numpy(),
                                     tilt.numpy(), self.velocity.to(torch.float32).numpy(), out.numpy())
            split_rows(len(G1), lambda r: sample(G1[r], G2[r], N[r], S, A, V, X[r]))
            return out
        return _perturbed(*self._predicted(g1, g2), sigma, generator)

    @staticmethod
    def perturb(g: torch.Tensor, std: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """g (P, 6) with the model's kind of noise, per coordinate std (6,) as ``sigma``: t + ε,
        the heading + η_ψ and the tilt + η_τ."""
        return _perturbed(*_split(g), std, generator)

    def log_prob(self, g: torch.Tensor, g1: torch.Tensor, g2: torch.Tensor, translation: bool = True) -> torch.Tensor:
        """(P,) log p(g_t | g_{t-1}, g_{t-2}), the Gaussian density of the residual; with
        ``translation=False`` the rotation's factor only, log p(τ_x, ψ, τ_z | g_{t-1}, g_{t-2}) (for a
        filter that integrates the translation out).

        The density is over (t, τ_x, ψ, τ_z), whose map to (t, ω) is smooth and one to one away
        from an upside-down body, so it ranks placements as the model does."""
        r = self.residual(g, g1, g2)
        var = (self.sigma ** 2).to(r)
        terms = -0.5 * r * r / var - 0.5 * torch.log(2 * math.pi * var)
        return (terms if translation else terms[..., 3:]).sum(dim=-1)

    def rotation_covariance(self, g: torch.Tensor) -> torch.Tensor:
        """(P, 3, 3) covariance of the rotation noise at placements g (P, 6) as a world-frame
        perturbation η (R_t = exp(η) R̂_t, to first order): the heading's noise turns about e_y,
        the tilt's about Y(ψ) J_l(τ) e_x and Y(ψ) J_l(τ) e_z (J_l SO(3)'s left Jacobian), so
        Σ = M diag(σ_τx², σ_ψ², σ_τz²) Mᵀ with M = [Y J_l e_x, e_y, Y J_l e_z]."""
        _, psi, tau = _split(g)
        tilt = torch.stack([tau[:, 0], torch.zeros_like(psi), tau[:, 1]], -1)
        e_y = g.new_tensor([0.0, 1.0, 0.0])
        M = so3.exp(psi[:, None] * e_y) @ so3.left_jacobian(tilt)
        M[:, :, 1] = e_y
        return M @ torch.diag_embed(self.sigma[3:].to(g) ** 2) @ M.transpose(-1, -2)


def _lag_one(x: torch.Tensor, x_prev: torch.Tensor) -> torch.Tensor:
    """The least-squares coefficient of x ≈ c x_prev through the origin, per column of (N, ...)
    series, clamped to [0, 1]: Σ x x_prev / Σ x_prev²."""
    return torch.clamp((x * x_prev).sum(0) / torch.clamp((x_prev * x_prev).sum(0), min=1e-30), 0.0, 1.0)


def _split(g: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Placements (P, 6) → translation (P, 3), heading ψ (P,), tilt τ (P, 2)."""
    psi, tau = so3.heading_tilt(so3.quaternion(g[:, 3:]))
    return g[:, :3], psi, tau


def _joined(t: torch.Tensor, psi: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
    """Translation (P, 3), heading (P,), tilt (P, 2) → placements (P, 6)."""
    return torch.cat([t, so3.quaternion_log(so3.from_heading_tilt(psi, tau))], dim=-1)


def _perturbed(t: torch.Tensor, psi: torch.Tensor, tau: torch.Tensor, std: torch.Tensor,
               generator: torch.Generator) -> torch.Tensor:
    """(t + ε, ψ + η_ψ, τ + η_τ) as placements (P, 6), with (ε, η_τx, η_ψ, η_τz) ~ N(0, diag std²)
    drawn as one (P, 6) block of standard normals (the fused kernel reads the same block)."""
    noise = standard_normal((len(t), 6), generator, t) * std
    return _joined(t + noise[:, :3], psi + noise[:, 4], tau + noise[:, 3::2])
