"""A defensive mixture transition: a learned prior with a fraction ε of local diffusion.

    p(x_t | x_{t−1}) = (1 − ε) p_learned(x_t | x_{t−1}) + ε p_diffusion(x_t | x_{t−1}),

both on the same state space (the learned prior's: bone directions for the Lie prior, joint angles
for a diffusion). A particle filter draws each particle's step from the learned prior with
probability 1 − ε and from the diffusion otherwise, and scores it by the mixture's density above
(``log_prob``: a log-sum-exp), so it is the transition model of the mixture, not a heuristic
jitter. (Hesterberg's defensive importance sampling; the same idea keeps a learned proposal from
losing a motion it has no component for.)

Why: the Lie prior's conditional p(v | x) is narrow in pace. A walk at 0.6× the training pace fell
outside it and the particle filter lost it (07_10: 178 mm; 35_29: 250 mm); with ε = 0.1 a tenth
of the particles can follow any small step and the ones that fit the data survive (63 and 62 mm),
while the normal pace stays where it was (43 → 38 mm on 35_29, 61 → 63 on 07_10).
"""

from __future__ import annotations

import math

import torch

from priortrack.errors import PriortrackError


class DefensiveMixture:
    """(1 − ε) ``learned`` + ε ``fallback`` (module docstring). Everything but the transition
    (``space``, ``encode``, ``joints``, ``initial``, ``mean``, …) is the learned prior's.

    Args:
        learned: the prior (a TransitionModel).
        fallback: a diffusion on the same state space (same state width).
        epsilon: ε in (0, 1).
    """

    def __init__(self, learned, fallback, epsilon: float):
        if isinstance(epsilon, bool) or not isinstance(epsilon, (int, float)) or not 0 < epsilon < 1:
            raise PriortrackError(f"the defensive fraction must be in (0, 1), got {epsilon!r}")
        if fallback.state_dim != learned.state_dim:
            raise PriortrackError(f"the defensive diffusion's states have {fallback.state_dim} numbers, the "
                                  f"{learned.kind} prior's {learned.state_dim}: they must share a state space")
        self.learned, self.fallback, self.epsilon = learned, fallback, float(epsilon)

    #: What is the learned prior's (the state space and the start); the transition's own methods
    #: (a mean step, a covariance) are not: the mixture has none a Gaussian filter could use.
    SHARED = ("kind", "space", "fps", "state_dim", "encode", "joints", "initial", "check_state", "check_pair")

    def __getattr__(self, name: str):
        if name not in self.SHARED:
            raise AttributeError(f"a defensive mixture has no {name!r}")
        return getattr(self.learned, name)

    def sample(self, x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """(P, S) → (P, S): each row's step from the fallback with probability ε, else from the learned prior."""
        learned, fallback = self.learned.sample(x, generator), self.fallback.sample(x, generator).to(x.dtype)
        chosen = torch.rand(len(x), generator=generator, device=x.device) < self.epsilon
        return torch.where(chosen[:, None], fallback, learned)

    def log_prob(self, x_next: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """(P,) ln[(1 − ε) p_learned + ε p_fallback], in float64."""
        return torch.logaddexp(math.log1p(-self.epsilon) + self.learned.log_prob(x_next, x).to(torch.float64),
                               math.log(self.epsilon) + self.fallback.log_prob(x_next, x).to(torch.float64))
