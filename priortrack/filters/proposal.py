"""The guided proposal: a particle filter's draw that looks at the frame's detections, with exact weights.

The bootstrap filter draws s_t^i ~ p(s_t | s_{t−1}^i) and weighs by p(y_t | s_t^i) alone: with several
calibrated cameras the likelihood is far narrower than a learned prior's step, and the cloud collapses
onto the few particles that landed near the data. The guided proposal draws from the linearised optimal
proposal instead (Doucet, Godsill & Andrieu, Stat. Comput. 10, 2000, §II.D.2; van der Merwe, Doucet,
de Freitas & Wan 2000, the unscented particle filter), mixed with the prior itself. The prior's step is a mixture of
Gaussians in tangent coordinates (``step_components``: the Lie mixture's K components, one for a Gaussian transition),
π_k(x_{t−1}) N(d_k(x_{t−1}), Q_k), and each component is linearised once, not per particle:

    m_i = f(s_{t−1}^i)                          each particle's mean step (``mean_step``); the chart of its draw
    m̄ = the weighted mean of the m_i             where the model is linearised
    H = ∂h(m̄ ⊞ δ)/∂δ |_{δ=0}                   the pixels' Jacobian at m̄, central differences, shared
    R = diag(σ²/c_j) / ρ_j,  ρ_j = (ν + b)/(ν + d²_j)   (a Student-t likelihood as a scale mixture of
                                                  Gaussians, its weight ρ_j at the prediction: d²_j the
                                                  point's squared distance from h(m̄) under the moment-matched
                                                  step's S; ρ = 1 for a Gaussian likelihood)
    Q_k = component k's covariance at m̄ (pose) ⊕ the global motion's (rotation, sampled translation)
    S_k = H Q_k Hᵀ + H_t C̄ H_tᵀ + R,  K_k = Q_k Hᵀ S_k⁻¹,  Σ_k = Q_k − K_k S_k K_kᵀ      (once per component)
    r_ik = y − h(m_i) − H o_ik,  o_ik = d_k(x_i) − Σ_j π_j d_j(x_i)   component k's innovation, its mean's offset
                                                  from m_i taken through H (h evaluated once per particle)
    μ_ik = o_ik + K_k r_ik,   q̃_ik ∝ π_ik N(r_ik; 0, S_k)               over the particle's TOP_COMPONENTS likeliest k
    q_i(s) = (1 − δ) Σ_k q̃_ik N(s ⊟ m_i; μ_ik, γ Σ_k) + δ p(s | s_{t−1}^i)

with δ the defensive share (``defensive``) and γ the inflation of the covariance (``inflation``, default 1). An
inflated proposal costs particles exponentially in the dimension: drawing N(0, γΣ) for a target N(0, Σ) keeps
an effective share (√(2γ − 1)/γ)^d of them, 0.1 % for γ = 2 in the d ≈ 50 tangent coordinates of a pose, 49 % for
γ = 1.2 (measured on the real-format bench: γ = 2 left pf-diffusion-local at 20.8 / 13.9 mm on held-out 07 / 05,
γ = 1 at 17.4 / 10.0); robustness to the linearisation comes from the defensive share instead. A frame that
fewer than :data:`MIN_VIEWS` cameras see is drawn from the prior alone (the bootstrap filter's draw, ratio 0):
one view leaves the depth along each ray to the prior and the body's size, a limb tilted towards the camera
and one tilted away project alike, and a Gaussian linearised at the cloud's mean keeps one of the two
(on the one-camera lab bench the guided draw was worse than the prior's on two of three held-out people). The
weights stay exact (Doucet et al. 2000, eq. 4): the filter adds

    log p(y_t | s_t^i) + log p(s_t^i | s_{t−1}^i) − log q_i(s_t^i)

to log w_{t−1}^i, and since q_i ≥ δ p(· | s_{t−1}^i) the ratio p / q is at most 1/δ (Hesterberg's defensive
importance sampling, Technometrics 37, 1995): a proposal that misses a mode the prior holds cannot blow a
weight up. On a linear model with δ = 0 and γ = 1 it is the optimal proposal, and the incremental weight is the
predictive likelihood: N(y; H f(s_{t−1}), H Q Hᵀ + R) for a Gaussian transition, Σ_k π_k N(y; H f_k(s_{t−1}),
H Q_k Hᵀ + R) for a mixture (tests/test_proposal.py). The per-component proposal matters where the mixture's
components disagree: a single Gaussian moment-matched to them draws between them, where the prior is thin
(pf-lie on held-out 39_01: 92 mm and a median ESS of 9 of 1000 with one Gaussian, 48 mm and 15 per component).

Even so the weights vary with the parents: the incremental weight of the optimal proposal is the parent's predictive
likelihood λ_i = p(y_t | s_{t−1}^i), which differs from parent to parent (on a synthetic ring of four cameras with local
diffusion, 5 px: an ESS of 81–100 of 1000 a step). The draw computes λ̂_i = Σ_k π_ik N(r_ik; 0, S_k) anyway (the
component choice's normaliser); with a first stage (``auxiliary``, the fully adapted auxiliary particle filter, Pitt &
Shephard 1999) the parents are resampled by w_i λ̂_i before the draw and the ratio divided by λ̂ of each child's
ancestor, still exact for any λ̂ > 0; on a linear model the weights come out equal (ESS 806 on that ring).

Where the translation is integrated out (``translation="marginalised"``) it is not drawn: each particle's t_t
is the mean step's, as in the bootstrap draw, its uncertainty enters S through the predicted Kalman covariance
C̄ (the particles' mean), and log p(s | s_{t−1}) is the density of the pose and rotation only. The density of
the Gaussian branch is that of the tangent step s ⊟ m_i, as the priors' ``log_prob`` is of the step from
s_{t−1}: on the spheres the two differ from densities on the manifold by the exponential map's Jacobian,
1 − θ²/6 per bone (1e−4 for a frame's step of θ = 0.025 rad). The rotation's Gaussian is over world-frame
perturbations η, the global motion's density over heading and tilt: their volumes agree to first order.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from priortrack.errors import PriortrackError
from priortrack.geometry.linalg import jittered_cholesky, whitening
from priortrack.models.tracking import GLOBAL_DIM, TrackingModel

log = logging.getLogger(__name__)

#: The central difference's step (tangent units: radians, metres) of the pixels' Jacobian.
JACOBIAN_STEP = 1e-5
#: Cameras that must see a frame for the guided draw (fewer: the prior's own).
MIN_VIEWS = 2
#: The components of a mixture transition kept per particle (its likeliest under π(x_{t−1})).
TOP_COMPONENTS = 4


def _factor(K: torch.Tensor) -> torch.Tensor | None:
    """Lower Cholesky factors (..., n, n) of symmetric matrices K (:func:`~priortrack.geometry.linalg.jittered_cholesky`,
    a jitter of 1e-12 to 1e-6 of the mean diagonal where needed); None where K is not finite or not positive definite
    even so."""
    if not bool(torch.isfinite(K).all()):
        return None
    try:
        return jittered_cholesky(K, "a guided proposal's matrix", 1e-12, 1e-6)
    except PriortrackError:
        return None


def _log_normal(factors: torch.Tensor, component: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
    """log N(r_i; 0, L_k L_kᵀ) (N,) of residuals r (N, d), row i under the Cholesky factor ``factors`` (K, d, d) of its
    ``component`` (N,) k: ‖L_k⁻¹ r_i‖² with L_k⁻¹ formed once (:func:`whitening`), one product per component present."""
    white_k = whitening(factors)
    out = torch.empty(len(residual), dtype=residual.dtype, device=residual.device)
    for k in torch.unique(component).tolist():
        rows = component == k
        white = residual[rows] @ white_k[k].T
        out[rows] = -0.5 * (white * white).sum(-1) - torch.log(torch.diagonal(factors[k])).sum()
    return out - 0.5 * residual.shape[1] * math.log(2 * math.pi)


@dataclass(frozen=True)
class _Draw:
    """What :meth:`GuidedProposal.log_density` needs of the last draw: the parents (P, A), their mean steps m (P, A),
    each kept component's updated mean μ (P, keep, f), index (P, keep) and log share (P, keep), and the Cholesky
    factors of the components' γ Σ_k (K, f, f); all but the parents None where the draw was the prior's."""

    parents: torch.Tensor
    m: torch.Tensor | None = None
    mu: torch.Tensor | None = None
    component: torch.Tensor | None = None
    log_choice: torch.Tensor | None = None
    factors: torch.Tensor | None = None


class GuidedProposal:
    """q(s_t | s_{t−1}, y_t) of the module docstring for a model in the unscented filter's form.

    Args:
        model: a :class:`TrackingModel` (its prior's step a mixture of Gaussians, ``step_components``: the Lie
            mixture, or any prior with ``transition_covariance``) or a model keeping the unscented filter's
            interface and ``predict`` / ``log_transition`` (optionally ``step_components``: the linear test models).
        marginal: the translation is integrated out by the particle filter (not drawn).
        defensive: δ ∈ [0, 1), the prior's share of the proposal.
        inflation: γ ≥ 1, the factor on the linearised posterior covariance Σ.
    """

    def __init__(self, model, marginal: bool = False, defensive: float = 0.1, inflation: float = 1.0):
        from priortrack.filters.ukf import unscented_form

        if not 0.0 <= defensive < 1.0:
            raise PriortrackError(f"the guided proposal's defensive share must be in [0, 1), got {defensive}")
        if not 1.0 <= inflation <= 100.0:
            raise PriortrackError(f"the guided proposal's inflation must be in [1, 100], got {inflation}")
        self.model, self.form = model, unscented_form(model, robust=True)
        self.marginal, self.defensive, self.inflation = bool(marginal), float(defensive), float(inflation)
        n = self.form.tangent_dim
        if isinstance(model, TrackingModel):
            pose = model.prior.space.tangent_dim
            translation, rotation = list(range(pose, pose + 3)), list(range(pose + 3, pose + GLOBAL_DIM))
            drawn = list(range(pose)) + rotation + ([] if marginal else translation)
            self.nuisance = translation if marginal else []
            self.robust_nu = model.likelihood.robust_nu
        else:
            drawn, self.nuisance, self.robust_nu = list(range(n)), [], None
        #: The tangent coordinates the proposal draws (pose, rotation, and the translation where it is sampled).
        self.drawn = torch.tensor(sorted(drawn))
        self.tangent_dim = n
        #: The last auxiliary draw's ancestors (P,) (:meth:`draw` with a first stage), or None.
        self.ancestors: torch.Tensor | None = None
        #: The last frame's linearised posterior covariance (f, f) in the drawn coordinates, Σ_k Σ_k weighted by the
        #: share of particles drawn from component k (None: that frame's draw was the prior's).
        self.covariance: torch.Tensor | None = None
        self._last: _Draw | None = None

    def retract(self, s: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """s (P, A) ⊞ v (P, f): the states reached by steps v in the drawn coordinates (0 elsewhere)."""
        return self.form.boxplus(s, self._embedded(v).to(s.dtype))

    def local(self, s: torch.Tensor, base: torch.Tensor) -> torch.Tensor:
        """s (P, A) ⊟ base (P, A) → (P, f), the drawn coordinates in the chart at base."""
        return self.form.boxminus(s, base)[:, self.drawn.to(s.device)]

    def prior_covariance(self, s: torch.Tensor) -> torch.Tensor:
        """The transition's covariance Q (f, f) in the drawn coordinates at the mean of the states s (P, A)."""
        m_bar = self.model.mean(s.to(torch.float64), torch.full((len(s),), 1.0 / len(s), dtype=torch.float64,
                                                                 device=s.device))
        drawn = self.drawn.to(s.device)
        return self.form.process_covariance(m_bar).to(torch.float64)[drawn][:, drawn]

    def _embedded(self, v: torch.Tensor) -> torch.Tensor:
        """(P, f) drawn coordinates → (P, n) tangent vectors, 0 elsewhere."""
        out = v.new_zeros((len(v), self.tangent_dim))
        out[:, self.drawn.to(v.device)] = v
        return out

    def _jacobian(self, base: torch.Tensor, columns: torch.Tensor, seen: torch.Tensor) -> torch.Tensor:
        """(m, len(columns)) ∂h/∂δ at ``base`` (A,) in float64, the seen rows of h, by central differences."""
        e = torch.eye(self.tangent_dim, dtype=torch.float64, device=base.device)[columns] * JACOBIAN_STEP
        steps = torch.cat([e, -e])
        h = self.form.measure(self.form.boxplus(base.expand(len(steps), -1), steps.to(base)))[:, seen]
        half = len(columns)
        return ((h[:half] - h[half:]) / (2 * JACOBIAN_STEP)).T.to(torch.float64)

    def draw(self, parents: torch.Tensor, weights: torch.Tensor, z, generator: torch.Generator,
             translation_covariance: torch.Tensor | None = None,
             first_stage: Callable[[torch.Tensor, torch.Generator], torch.Tensor] | None = None
             ) -> tuple[torch.Tensor, torch.Tensor]:
        """Draw s_t^i ~ q_i for every parent (P, A) (weights (P,) their normalised weights, z the frame's gated
        observation; ``translation_covariance`` (P, 6, 6) the predicted covariances of (t_t, t_{t−1}) where the
        translation is integrated out). Returns the states (P, A) and log p(s_t | s_{t−1}) − log q(s_t | s_{t−1}, y)
        (P,) in float64. A frame that fewer than :data:`MIN_VIEWS` cameras see is the prior's own draw (ratio 0); a
        point that the cloud's mean puts behind a camera is left out of the linearisation (its Jacobian is none), and
        a frame with no point left is the prior's draw too.

        With ``first_stage`` (a resampler: normalised weights (P,), generator → ancestors (P,)) the draw is the
        fully adapted auxiliary one (Pitt & Shephard, JASA 94, 1999): the parents are first resampled by
        w_i λ̂_i, λ̂_i = Σ_k π_ik N(r_ik; 0, S_k) their predictive density of the frame under the linearisation,
        each child drawn from its ancestor a_i's q, and the ratio returned is p / (q λ̂_{a_i}) (the weights to add
        it to are then uniform): on a linear model the weights come out equal. :attr:`ancestors` holds a (None
        without a first stage or when the frame is the prior's draw)."""
        form, dtype, device, f64 = self.form, parents.dtype, parents.device, torch.float64
        P = len(parents)
        self.ancestors = None
        if self.views(z) < MIN_VIEWS:
            return self._the_priors(parents, generator)
        y, variances = form.measurement(z)
        y, variances = y.to(device), variances.to(device)
        variances = torch.diagonal(variances) if variances.dim() == 2 else variances
        m = form.mean_step(parents)
        seen = torch.isfinite(y)
        w = (weights / weights.sum()).to(f64)
        m_bar = self.model.mean(m.to(f64), w)
        drawn = self.drawn.to(device)
        f = len(drawn)
        H = self._jacobian(m_bar, drawn, seen)
        front = torch.isfinite(H).all(dim=1)        # a point the cloud's mean puts behind a camera: not linearised
        if not bool(front.all()):
            seen = seen.clone()
            seen[seen.nonzero()[:, 0][~front]] = False
            H = H[front]
        if not bool(seen.any()):
            return self._the_priors(parents, generator)
        y, variances = y[seen], variances[seen].to(f64)
        log_pi, offsets, index, Q, moment = self._components(parents, m, m_bar)
        keep = log_pi.shape[1]
        nuisance = torch.zeros((len(y), len(y)), dtype=f64, device=device)
        if self.nuisance:
            C = (w[:, None, None] * translation_covariance[:, :3, :3].to(f64)).sum(0)
            H_t = self._jacobian(m_bar, torch.tensor(self.nuisance, device=device), seen)
            nuisance = H_t @ C @ H_t.T
        R = self._robust_variances(y - form.measure(m_bar[None])[0, seen].to(f64), H @ moment @ H.T + nuisance,
                                   variances)
        # every component's Kalman update, once: S_k, its Cholesky factor, the gain and the proposal's factor
        S = H @ Q @ H.T + nuisance + torch.diag(R)                                  # (K, m, m)
        L_S = _factor(S)
        if L_S is None:
            return self._the_priors(parents, generator, "its innovation covariance")
        gain = torch.linalg.solve(S, H @ Q).transpose(-1, -2)                        # Q_k Hᵀ S_k⁻¹ (K, f, m)
        Sigma = Q - gain @ S @ gain.transpose(-1, -2)
        Sigma = 0.5 * (Sigma + Sigma.transpose(-1, -2))
        L_q = _factor(self.inflation * Sigma)
        if L_q is None:
            return self._the_priors(parents, generator, "its covariance")
        # each particle's kept components: innovation, predictive density, updated mean (in the chart at m_i)
        innovation = torch.nan_to_num(y - form.measure(m)[:, seen].to(f64), nan=0.0)  # behind a camera: no pull
        component = index.reshape(-1)
        particle = torch.arange(P, device=device).repeat_interleave(keep)
        offset = offsets.reshape(-1, f)
        r = innovation[particle] - offset @ H.T                                      # (P keep, m)
        mu = torch.empty_like(offset)
        for k in torch.unique(component).tolist():
            rows = component == k
            mu[rows] = offset[rows] + r[rows] @ gain[k].T
        log_choice = (log_pi.reshape(-1) + _log_normal(L_S, component, r)).reshape(P, keep)
        log_lambda = torch.logsumexp(log_choice, 1)                                 # log λ̂_i
        log_first = torch.zeros(P, dtype=f64, device=device)
        if first_stage is not None:
            a = first_stage(torch.softmax(torch.log(w) + log_lambda, 0), generator)
            parents, m, log_choice, log_lambda, self.ancestors = parents[a], m[a], log_choice[a], log_lambda[a], a
            mu, component = mu.reshape(P, keep, -1)[a].reshape(P * keep, -1), component.reshape(P, keep)[a].reshape(-1)
            log_first = log_lambda
        log_choice = log_choice - log_lambda[:, None]
        u = torch.rand((P, 1), generator=generator, device=device, dtype=f64)
        slot = torch.clamp((torch.cumsum(torch.exp(log_choice), 1) < u).sum(1), max=keep - 1)
        chosen = torch.arange(P, device=device) * keep + slot
        share = torch.bincount(component[chosen], minlength=len(Sigma)).to(f64) / P
        self.covariance = (share[:, None, None] * Sigma).sum(0)
        prior_rows = torch.rand(P, generator=generator, device=device, dtype=f64) < self.defensive
        v = torch.randn((P, f), generator=generator, device=device, dtype=f64)
        for k in torch.unique(component[chosen]).tolist():
            rows = component[chosen] == k
            v[rows] = mu[chosen[rows]] + v[rows] @ L_q[k].T
        s = form.boxplus(m, self._embedded(v).to(dtype))
        if bool(prior_rows.any()):
            s[prior_rows] = self._prior_draw(parents[prior_rows], generator)
        self._last = _Draw(parents, m, mu.reshape(P, keep, f), component.reshape(P, keep), log_choice, L_q)
        log_q, log_prior = self.log_density(s, torch.arange(P, device=device))
        return s, log_prior - log_q - log_first

    def log_density(self, s: torch.Tensor, rows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """log q_i(s) and log p(s | s_{t−1}^i) (P,) in float64 of states s (P, A) under the last draw's proposal of its
        parents ``rows`` (P,) (each state's parent's index in that draw; a tempered update moves the states and
        evaluates them again): q_i(s) = (1 − δ) Σ_k q̃_ik N(s ⊟ m_i; μ_ik, γ Σ_k) + δ p(s | s_{t−1}^i) over the kept
        components. A frame drawn from the prior: q = p."""
        last = self._last
        if last is None:
            raise PriortrackError("the guided proposal has drawn nothing yet")
        parents = last.parents[rows]
        log_prior = self._log_transition(s, parents).to(torch.float64)
        if last.mu is None:
            return log_prior, log_prior
        P, keep, f = last.mu[rows].shape
        v = self.form.boxminus(s, last.m[rows]).to(torch.float64)[:, self.drawn.to(s.device)]
        particle = torch.arange(P, device=s.device).repeat_interleave(keep)
        white = _log_normal(last.factors, last.component[rows].reshape(-1), v[particle] - last.mu[rows].reshape(-1, f))
        log_gauss = torch.logsumexp(last.log_choice[rows] + white.reshape(P, keep), 1)
        log_q = log_gauss if self.defensive == 0 else torch.logaddexp(
            math.log1p(-self.defensive) + log_gauss, math.log(self.defensive) + log_prior)
        return log_q, log_prior

    def _components(self, parents: torch.Tensor, m: torch.Tensor, m_bar: torch.Tensor):
        """The transition's Gaussian steps (``step_weights`` and ``step_components`` of a tracking model's prior, or of
        the model itself), the :data:`TOP_COMPONENTS` likeliest of each particle: ln π (P, k) (normalised over every
        component), their means' offsets from the particle's mean step m (P, k, f) in the drawn coordinates (0
        beyond the pose), the components' indices (P, k), every component's covariance (K, f, f) at m̄ (its pose
        block the component's, the rest the model's Q) and the moment-matched Q (f, f) at m̄. A model without
        ``step_components``: one component, Q."""
        f64, device = torch.float64, parents.device
        drawn = self.drawn.to(device)
        Q = self.form.process_covariance(m_bar).to(f64)[drawn][:, drawn]
        P, f = len(parents), len(drawn)
        if isinstance(self.model, TrackingModel):
            S, prior = self.model.pose_dim, self.model.prior
            weights, components = prior.step_weights, prior.step_components
            x, m_bar = parents[:, :S], m_bar[:S]
            mean = prior.space.local(m[:, :S], x).to(f64)                           # Σ_k π_k d_k, from the mean step
        else:
            components = getattr(self.model, "step_components", None)
            if components is None:
                return (torch.zeros((P, 1), dtype=f64, device=device), torch.zeros((P, 1, f), dtype=f64, device=device),
                        torch.zeros((P, 1), dtype=torch.long, device=device), Q[None], Q)

            def weights(states):
                return components(states, covariances=False)[0]

            x, mean = parents, self.form.boxminus(m, parents).to(f64)
        log_pi = weights(x).to(f64)
        log_pi = log_pi - torch.logsumexp(log_pi, 1, keepdim=True)
        log_pi, index = log_pi.topk(min(TOP_COMPONENTS, log_pi.shape[1]), dim=1)
        offsets = components(x, covariances=False, components=index)[1].to(f64) - mean[:, None]
        covariances = components(m_bar[None])[2][0].to(f64)                          # (K, n_x, n_x)
        n_x = offsets.shape[-1]
        Q_k = Q.expand(len(covariances), f, f).clone()
        Q_k[:, :n_x, :n_x] = covariances
        offsets = torch.cat([offsets, offsets.new_zeros(offsets.shape[:2] + (f - n_x,))], -1)
        return log_pi, offsets, index, Q_k, Q

    def views(self, z) -> float:
        """The cameras that see something in the frame z: a tracking model's (C, J, 3) cameras with a detection
        (finite pixels, confidence > 0), 1 for a one-camera likelihood, inf for a model without cameras (every measurement one view)."""
        if not isinstance(self.model, TrackingModel):
            return math.inf
        z = torch.as_tensor(z)
        if z.dim() < 3:
            return 1
        seen = torch.isfinite(z[..., :2]).all(-1) & ((z[..., 2] > 0) if z.shape[-1] > 2 else True)
        return int(seen.any(-1).sum())

    def _robust_variances(self, r: torch.Tensor, S: torch.Tensor, variances: torch.Tensor) -> torch.Tensor:
        """The measurement variances (m,) divided by the Student-t's weight ρ_j at the prediction, point by point
        (blocks of ``measurement_block``): d²_j = r_jᵀ (S + R)_jj⁻¹ r_j, r the innovation at m̄ (NaN: ρ = 1)."""
        if self.robust_nu is None:
            return variances
        b = self.form.measurement_block
        blocks = (S.reshape(-1, b, len(S) // b, b).diagonal(dim1=0, dim2=2).permute(2, 0, 1)
                  + torch.diag_embed(variances.reshape(-1, b)))
        r = r.reshape(-1, b)
        d2 = torch.nan_to_num((r[:, None, :] @ torch.linalg.solve(blocks, r[..., None]))[:, 0, 0], nan=0.0).clamp(min=0)
        rho = (self.robust_nu + b) / (self.robust_nu + d2)
        return (variances.reshape(-1, b) / rho[:, None]).reshape(-1)

    def _the_priors(self, parents: torch.Tensor, generator: torch.Generator,
                    failed: str | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The frame drawn from the prior (the bootstrap filter's draw: states (P, A), log ratio 0 (P,)): too few
        views, no point to linearise, or (``failed``) a linearisation whose matrix is not positive definite (a cloud
        whose mean puts a joint at a camera's plane: a Jacobian of 10¹¹, logged)."""
        if failed is not None:
            log.debug("the guided proposal's %s is not positive definite: the frame is drawn from the prior", failed)
        self.covariance, self._last = None, _Draw(parents)
        return self._prior_draw(parents, generator), torch.zeros(len(parents), dtype=torch.float64, device=parents.device)

    def _prior_draw(self, parents: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        if isinstance(self.model, TrackingModel):
            return self.model.predict(parents, generator, translation=not self.marginal)
        return self.model.predict(parents, generator)

    def _log_transition(self, s: torch.Tensor, parents: torch.Tensor) -> torch.Tensor:
        if isinstance(self.model, TrackingModel):
            return self.model.log_transition(s, parents, translation=not self.marginal)
        return self.model.log_transition(s, parents)
