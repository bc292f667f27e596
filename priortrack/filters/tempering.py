"""Tempering within a frame: Bayes' rule reached in stages when the likelihood is far sharper than the draw.

A particle filter that draws from the prior (one camera: the guided proposal's own draw there) and meets a sharp
likelihood keeps a handful of particles. Adaptive tempering (Neal, Stat. Comput. 11, 2001; Del Moral, Doucet &
Jasra, JRSS B 68, 2006; Jasra, Stephens, Doucet & Tsagaris, Scand. J. Stat. 38, 2011) goes from the prediction
to the posterior through the targets

    π_φ(s_t) ∝ p(s_t | s_{t−1}) · p(z_t | s_t)^φ,   0 = φ_0 < φ_1 < … < φ_n = 1,

each exponent's step Δ_k = φ_k − φ_{k−1} chosen by bisection so that the weights w_i ∝ w_i · p(z_t | s_i)^{Δ_k}
keep an effective sample size of a fixed share of the particles (:func:`annealing_exponent`); between stages the
particles are resampled and moved by Metropolis–Hastings moves that leave π_{φ_k} invariant (the particle filter's
random walk, :meth:`~priortrack.filters.particle.ParticleFilter.move`). From the guided proposal's draw q the path
starts at q instead, π_φ ∝ q^{1−φ} (p(s_t | s_{t−1}) p(z_t | s_t))^φ, and each stage's weight is (p · likelihood / q)^{Δ_k}
(:meth:`~priortrack.filters.particle.ParticleFilter.tempered_update`). Each stage's incremental weight is exact, so
the last stage's weighted particles target the filtering distribution, as a single update's do (an SMC sampler),
where the annealed particle filter's tempered weights (:mod:`~priortrack.filters.annealed`) do not. The annealed
filter shares the exponent's bisection.
"""

from __future__ import annotations

import torch

#: Bisection steps for the exponent (the survival rate is matched to about 2^-40 in it).
BISECTION_STEPS = 40
#: Stages of moves within one frame at most; the last applies what is left of the likelihood whatever the ESS.
MAX_STAGES = 8


def survival(log_lik: torch.Tensor, beta: float, log_weights: torch.Tensor | None = None) -> float:
    """α(β) = ESS / P of the weights ∝ w_i exp(β ℓ_i) for log-likelihoods ℓ (P,) and log weights ``log_weights`` (P,)
    (None: equal)."""
    log_w = beta * log_lik if log_weights is None else log_weights + beta * log_lik
    log_w = log_w - torch.logsumexp(log_w, 0)
    return float(torch.exp(-torch.logsumexp(2 * log_w, 0)) / len(log_lik))


def annealing_exponent(log_lik: torch.Tensor, target: float, lower: float = 0.0, upper: float = 1.0,
                       log_weights: torch.Tensor | None = None) -> float:
    """The β in [lower, upper] with α(β) = target (α falls as β grows), by bisection.

    Returns ``upper`` if even β = upper keeps more than the target alive (the likelihood is flat
    over the set), ``lower`` if β = lower already keeps fewer.
    """
    if survival(log_lik, upper, log_weights) >= target:
        return upper
    if survival(log_lik, lower, log_weights) <= target:
        return lower
    for _ in range(BISECTION_STEPS):
        middle = 0.5 * (lower + upper)
        if survival(log_lik, middle, log_weights) > target:
            lower = middle
        else:
            upper = middle
    return 0.5 * (lower + upper)
