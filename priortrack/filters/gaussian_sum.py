"""The Gaussian-sum unscented filter: one unscented filter per retained component of a mixture transition
(the Lie prior's geodesic mixture, with its defensive diffusion where a preset mixes one in): ``ukf-lie``.

The unscented filter runs one Gaussian transition; on the Lie prior it runs the mixture moment-matched to one
(``ukf-lie-defensive``), whose covariance spans every component's mean step at once. Here the transition is kept
as the mixture it is (:mod:`priortrack.priors.component`),

    p(x_t | x_{t−1}) = Σ_k π_k(x_{t−1}) N(x_t ⊟ x_{t−1}; ū_k(x_{t−1}), Q_k(x_{t−1})),

and the posterior is a Gaussian sum Σ_h w_h N(m_h, P_h) over hypotheses h (each P_h in tangent coordinates at its
mean m_h). One step (Alspach & Sorenson 1972's Gaussian-sum filter; the merging by last component is the
generalised pseudo-Bayesian filter of order 2: Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to
Tracking*, §11.6):

1. **Branch.** Each hypothesis h goes on with its ``branch`` most probable components at its mean, those with
   π_k(m_h) ≥ ``min_share`` (the most probable always): a child (h, k) of weight w_h π_k(m_h). π_k is taken at
   the mean, not averaged over N(m_h, P_h).
2. **Step.** Each child is one :class:`~priortrack.filters.ukf.UnscentedFilter` step with component k's Gaussian
   transition (mean step x ⊞ ū_k(x) through the sigma points, Q_k at the mean), the validation gate, the swap
   correction and the reacquisition of the unscented filter included, and is reweighted by its predictive
   density of the frame (:attr:`UnscentedFilter.log_evidence`: N(z; ẑ, S) on the points it took, each point its
   gate held out counted at the gate boundary's density, so that children gating different points compare):

       w_hk ∝ w_h π_k(m_h) p_hk(z_t | z_1:t−1).

3. **Merge.** Children of one component are moment-matched into one hypothesis (:func:`merged`: their weighted
   Karcher mean, each covariance carried to it, plus the spread of the means); the ``hypotheses`` heaviest are
   kept and renormalised.

The estimate is the whole sum moment-matched (:func:`merged` over every hypothesis): ``mean``, ``covariance``, the
Snapshot's sigma points and the estimate are that Gaussian's, as the unscented filter's are; the smoother
(:meth:`UnscentedFilter.smooth_window`) runs on them with the mixture moment-matched to one Gaussian transition.
The flags, held-out and swapped points are the heaviest child's. Cost: one unscented step per child, at most
``hypotheses`` × ``branch`` a frame.

**Two models** (``moment_matched``, ``ukf-lie-defensive``): a defensive mixture's two parts as the components, the
learned prior moment-matched to one Gaussian and the diffusion (:class:`~priortrack.priors.defensive.DefensivePair`);
with two hypotheses and both branches, four unscented steps a frame. Moment-matched into one Gaussian transition,
the diffusion's share is ε whatever the frames say, and on a motion the walks never showed the filter trusts the
walks; as two models the evidence moves the weight onto the diffusion where the learned step does not explain the
detections (Shelf's actor 1, at work on the shelf, not walking, all five cameras: PCP 86.5 → 92.9 %, 86 → 60 mm;
a soccer kick through four cameras: 17.5 → 14.4 mm).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import torch
from scipy.special import logsumexp

from priortrack.errors import PriortrackError
from priortrack.filters.snapshot import Snapshot
from priortrack.filters.ukf import ALPHA, BETA, GATE_PROBABILITY, KAPPA, UnscentedFilter, repaired_covariance
from priortrack.models.tracking import TrackingModel
from priortrack.priors.component import ComponentTransition
from priortrack.priors.defensive import DefensivePair

log = logging.getLogger(__name__)

#: Hypotheses kept after each step's merge (the heaviest).
HYPOTHESES = 4
#: Components each hypothesis goes on with: at most this many, its most probable at its mean …
BRANCH = 3
#: … of those, the ones with π_k(m_h) at least this (the most probable always).
MIN_SHARE = 0.05


@dataclass
class Hypothesis:
    """One Gaussian of the sum: ln w (normalised over the sum), the mean x (A,), P (n, n) in tangent
    coordinates at x, and the validation gate's counters (:class:`UnscentedFilter`'s ``gated_frames``, ``lost_frames``)."""

    log_weight: float
    x: np.ndarray
    P: np.ndarray
    gated_frames: int
    lost_frames: np.ndarray


def merged(unscented, means: np.ndarray, covariances: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Moment matching on the state manifold: H Gaussians (means (H, A), covariances (H, n, n) each at its mean),
    weights (H,) summing to 1 → the mean m̄ (A,), the weighted Karcher mean (``sigma_mean``), and

        P̄ = Σ_h w_h (Γ_h P_h Γ_hᵀ + d_h d_hᵀ),   d_h = m_h ⊟ m̄,

    Γ_h the change of tangent coordinates from m_h to m̄ (``transport``) (n, n)."""
    if len(weights) == 1:
        return means[0].copy(), covariances[0].copy()
    m = unscented.sigma_mean(torch.from_numpy(means), torch.from_numpy(weights)).numpy()
    d = unscented.boxminus(torch.from_numpy(means), torch.from_numpy(m)).numpy()
    P = np.zeros_like(covariances[0])
    for w, mean, cov, dh in zip(weights, means, covariances, d):
        G = unscented.transport(torch.from_numpy(mean), torch.from_numpy(m)).numpy()
        P += w * (G @ cov @ G.T + np.outer(dh, dh))
    return m, P


class GaussianSumFilter(UnscentedFilter):
    """The Gaussian-sum unscented filter over a mixture transition (module docstring).

    Args:
        model: a TrackingModel whose prior's transition is a mixture (``step_weights``, ``step_components``: the
            Lie prior, alone or in a defensive mixture); or any model keeping ``UNSCENTED_INTERFACE`` with
            ``step_weights(s)`` (ln π_k at full states s (H, A) → (H, K)) and ``component_model()`` (a new model of
            that interface running one component, chosen by setting its ``k``: the linear mixture of the tests).
        alpha, beta, kappa, gate_probability, reacquire, swaps, branches: every member's (:class:`UnscentedFilter`).
        hypotheses: the Gaussians kept after each step.
        branch, min_share: the components each hypothesis goes on with (module docstring, step 1).
        moment_matched: with a defensive mixture, run its two parts as the components, the learned prior
            moment-matched to one Gaussian and the diffusion (:class:`~priortrack.priors.defensive.DefensivePair`;
            module docstring), instead of the learned prior's own components beside the diffusion.

    Attributes:
        hypotheses_: the sum after the last step (:class:`Hypothesis`, heaviest first).
    """

    #: What the filter needs of a prior (priortrack.priors.registry): a mixture of Gaussian steps.
    requires = "mixture"

    def __init__(self, model, alpha: float = ALPHA, beta: float = BETA, kappa: float = KAPPA,
                 hypotheses: int = HYPOTHESES, branch: int = BRANCH, min_share: float = MIN_SHARE,
                 gate_probability: float = GATE_PROBABILITY, reacquire: bool = True, swaps: bool = True,
                 branches: bool = True, moment_matched: bool = False):
        if isinstance(model, TrackingModel):
            mixture = DefensivePair(model.prior) if moment_matched else model.prior
            ComponentTransition(mixture)                                    # a mixture, or a clear error
        elif moment_matched:
            raise PriortrackError("moment_matched runs a TrackingModel's defensive mixture as two Gaussian steps; "
                                  f"{type(model).__name__} is not a TrackingModel")
        elif not (hasattr(model, "step_weights") and hasattr(model, "component_model")):
            raise PriortrackError(f"the Gaussian-sum filter runs a TrackingModel whose prior is a mixture, or a model "
                                  f"with step_weights and component_model; {type(model).__name__} has neither")
        for name, value in (("hypotheses", hypotheses), ("branch", branch)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise PriortrackError(f"{name} must be a whole number ≥ 1, got {value!r}")
        if isinstance(min_share, bool) or not isinstance(min_share, (int, float)) or not 0 <= min_share < 1:
            raise PriortrackError(f"min_share must be in [0, 1), got {min_share!r}")
        super().__init__(model, alpha, beta, kappa, True, gate_probability, reacquire, swaps, branches)
        self.max_hypotheses, self.branch, self.min_share = hypotheses, branch, float(min_share)
        #: The mixture whose Gaussian steps the members run (a TrackingModel's prior, or its :class:`DefensivePair`).
        self.mixture = mixture if isinstance(model, TrackingModel) else None
        self._member_options = {"alpha": alpha, "beta": beta, "kappa": kappa, "gate_probability": gate_probability,
                                "reacquire": reacquire, "swaps": swaps, "branches": branches}
        self.hypotheses_: list[Hypothesis] = []
        #: Unscented filters on one component each, reused from step to step, with the transition whose ``k`` chooses
        #: that component (:meth:`_member`).
        self._members: list[tuple[object, UnscentedFilter]] = []
        #: Between :meth:`advance` and :meth:`correct`: each child's ln w_h π_k(m_h), k and its filter.
        self._children: list[tuple[float, int, UnscentedFilter]] = []

    def initialise_states(self, mean, covariance, frame: int = 0) -> None:
        """Start from one Gaussian: a mean state (A,) and a covariance (n, n) in tangent coordinates at it."""
        super().initialise_states(mean, covariance, frame)
        self._members = []                          # their models take the subject's body as it is now
        self.hypotheses_ = [Hypothesis(0.0, self.kf.x.copy(), self.kf.P.copy(), 0, self.lost_frames.copy())]

    def _member(self, i: int, k: int) -> UnscentedFilter:
        """The i-th member filter (made on first use: an unscented filter on a :class:`ComponentTransition`, or on
        the model's ``component_model()``), set to run component k."""
        while len(self._members) <= i:
            base = self.model
            if isinstance(base, TrackingModel):
                component = ComponentTransition(self.mixture)
                model = TrackingModel(component, base.global_motion, base.likelihood)
                model.body = base.body
            else:
                component = model = base.component_model()
            member = UnscentedFilter(model, **self._member_options)
            member.initialised = True
            self._members.append((component, member))
        component, member = self._members[i]
        component.k = k
        return member

    def _advance(self) -> None:
        if not self.initialised:
            raise PriortrackError("the filter is not initialised: call initialise(motion) first")
        t0 = time.perf_counter()
        log_pi = self._step_weights(torch.from_numpy(np.stack([h.x for h in self.hypotheses_])))   # (H, K)
        children = []
        for h, lp in zip(self.hypotheses_, log_pi):
            order = np.argsort(-lp)[:self.branch]
            for rank, k in enumerate(order):
                if rank and np.exp(lp[k]) < self.min_share:
                    break
                member = self._member(len(children), int(k))
                member.kf.x, member.kf.P = h.x.copy(), h.P.copy()
                member.gated_frames, member.lost_frames, member.frame = h.gated_frames, h.lost_frames.copy(), self.frame
                member.forward = self.forward                    # the feet and face, each member turned alone
                member.floor = self.floor                        # and each on the floor
                member._advance()
                children.append((h.log_weight + float(lp[k]), int(k), member))
        self._children = children
        self._advanced, self._measured = True, None
        self._predict_seconds = time.perf_counter() - t0

    def _step_weights(self, s: torch.Tensor) -> np.ndarray:
        """ln π_k (H, K) at full states s (H, A): the prior's at their poses (a TrackingModel), else the model's."""
        if isinstance(self.model, TrackingModel):
            return self.mixture.step_weights(s[:, :self.model.pose_dim]).to(torch.float64).numpy()
        return self.model.step_weights(s).to(torch.float64).numpy()

    def predicted_measurement(self) -> tuple[np.ndarray, np.ndarray]:
        """After :meth:`advance`: the predicted pixels ẑ (…, 2) and their covariance (…, 2, 2) of the sum, each
        point's children's (:meth:`UnscentedFilter.predicted_measurement`) moment-matched with the children's
        weights before the frame (w_h π_k(m_h))."""
        if not self._advanced:
            raise PriortrackError("no prediction to read: call advance() first")
        log_w = np.array([c[0] for c in self._children])
        w = np.exp(log_w - logsumexp(log_w))
        parts = [member.predicted_measurement() for _, _, member in self._children]
        z = np.stack([p[0] for p in parts])                                              # (H, …, 2)
        z_bar = np.einsum("h,h...->...", w, z)
        d = z - z_bar
        P = np.einsum("h,h...->...", w, np.stack([p[1] for p in parts]) + d[..., :, None] * d[..., None, :])
        return z_bar, P

    def _correct(self, z: np.ndarray) -> Snapshot:
        if not self._advanced:
            raise PriortrackError("no prediction to correct: call advance() first")
        t1 = time.perf_counter()
        flags = [member._corrected(z) for _, _, member in self._children]
        prior = np.array([c[0] for c in self._children])
        log_w = prior + np.array([member.log_evidence for _, _, member in self._children])
        components = np.array([k for _, k, _ in self._children])
        merged_ = []
        for k in np.unique(components):
            group = np.flatnonzero(components == k)
            total = logsumexp(log_w[group])
            members = [self._children[i][2] for i in group]
            m, P = merged(self.unscented, np.stack([f.kf.x for f in members]), np.stack([f.kf.P for f in members]),
                          np.exp(log_w[group] - total))
            heaviest = members[int(np.argmax(log_w[group]))]
            merged_.append(Hypothesis(total, m, repaired_covariance(P)[0], heaviest.gated_frames,
                                      heaviest.lost_frames.copy()))
        kept = sorted(merged_, key=lambda h: -h.log_weight)[:self.max_hypotheses]
        norm = logsumexp([h.log_weight for h in kept])
        for h in kept:
            h.log_weight -= norm
        self.hypotheses_ = kept
        best = int(np.argmax(log_w))
        log.debug("frame %d: %d children, %d Gaussians kept, the heaviest (component %d) weighing %.3f", self.frame + 1,
                  len(self._children), len(kept), int(components[best]), float(np.exp(kept[0].log_weight)))
        self.log_evidence = float(logsumexp(log_w) - logsumexp(prior))
        self.held_out, self.swapped = self._children[best][2].held_out, self._children[best][2].swapped
        kf = self.kf
        x, P = merged(self.unscented, np.stack([h.x for h in kept]), np.stack([h.P for h in kept]),
                      np.exp([h.log_weight for h in kept]))
        kf.x, (kf.P, repaired) = x, repaired_covariance(P)
        self._advanced, self._children = False, []
        step_flags = list(flags[best]) + (["covariance-repaired"] if repaired and "covariance-repaired" not in flags[best]
                                          else [])
        return self._snapshot(step_flags, {"predict": self._predict_seconds, "weight": time.perf_counter() - t1})
