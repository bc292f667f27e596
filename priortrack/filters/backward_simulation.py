"""Forward-filtering backward-simulation (Godsill, Doucet & West, JASA 99, 2004): smoothed
trajectories drawn from a particle filter's stored particle sets.

Given the filter's weighted sets {s_t^i, w_t^i}, t = 0 … T − 1, each of M trajectories is drawn
backwards:

    i_{T−1} ~ Categorical(w_{T−1}),
    i_t ~ Categorical(w_t^i p(s_{t+1}^{i_{t+1}} | s_t^i)),   i = 1 … N,

so that (s_0^{i_0}, …, s_{T−1}^{i_{T−1}}) is a draw from the particle approximation of
p(s_0, …, s_{T−1} | z_0, …, z_{T−1}). Each step weighs every one of the M trajectories against
every one of the N particles: M × N transition log-densities, evaluated as one batch (in chunks
of at most ``PAIRS_PER_BATCH`` pairs) by the model's ``log_transition(next, prev)``.

**MCMC backward kernel** (Dau & Chopin, *On backward smoothing algorithms*, Ann. Statist. 51(5),
2023). The exact draw costs O(M N) densities a frame, a hundred times a bootstrap filter's own
step at M = 100. But the particle j at t + 1 was drawn from its ancestor a_j: given the particles
at t and s_{t+1}^j, the index a_j is already distributed as Categorical(w_t^i p(s_{t+1}^j | s_t^i))
when resampling happened at t (for multinomial resampling exactly; for systematic nearly). So
i_t starts at the genealogy's ancestor and K independent Metropolis–Hastings moves keep that law:

    propose i' ~ Categorical(w_t),   accept with min(1, p(s_{t+1} | s_t^{i'}) / p(s_{t+1} | s_t^{i_t})),

(the w_t of target and proposal cancel): (K + 1) M densities a frame. Where the transition is
narrow next to the cloud (the 50 joint angles of the diffusion priors) nearly every proposal is
refused and the trajectories follow the genealogy, which the exact draw would do as well: going
back, they coalesce into few distinct paths, and ``distinct`` reports it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

from priortrack.errors import PriortrackError

#: The most (trajectory, particle) pairs whose transition log-densities are held at once.
PAIRS_PER_BATCH = 1 << 18


def _draw(log_weights: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """One index per row of log-weights (M, N) (any scale; a row of −inf draws uniformly)."""
    log_weights = torch.where(torch.isfinite(log_weights.max(dim=1, keepdim=True).values), log_weights,
                              torch.zeros_like(log_weights))
    probabilities = torch.softmax(log_weights.to(torch.float64), dim=1)
    return torch.multinomial(probabilities, 1, generator=generator)[:, 0]


def backward_indices(log_transition: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
                     particles: Sequence[torch.Tensor], log_weights: Sequence[torch.Tensor], trajectories: int,
                     generator: torch.Generator, ancestors: Sequence[torch.Tensor | None] | None = None,
                     moves: int = 0) -> torch.Tensor:
    """The particle of each smoothed trajectory at each frame (module docstring).

    Args:
        log_transition: log p(next | prev) of rows next (B, A) and prev (B, A) → (B,).
        particles: T sets (N_t, A), the filter's states after each update (before resampling).
        log_weights: T vectors (N_t,), their normalised log-weights.
        trajectories: M.
        generator: the draws' torch.Generator.
        ancestors: with the MCMC kernel, T vectors: ancestors[t] (N_{t+1},) the index in
            ``particles[t]`` of each particle of ``particles[t + 1]``'s parent (None: no resampling
            at t, the parent of j is j); the last entry is not used. None: the exact draw.
        moves: K, the Metropolis–Hastings moves per frame of the MCMC kernel.

    Returns:
        (T, M) indices i_t into ``particles[t]``.
    """
    if len(particles) != len(log_weights) or not particles:
        raise PriortrackError(f"{len(particles)} particle sets and {len(log_weights)} weight vectors: "
                              f"expected as many, at least one")
    if trajectories < 1:
        raise PriortrackError(f"trajectories must be positive, got {trajectories}")
    M = int(trajectories)
    indices = [_draw(log_weights[-1].expand(M, -1), generator)]
    for t in range(len(particles) - 2, -1, -1):
        if ancestors is not None:
            indices.append(_metropolis(log_transition, particles[t], log_weights[t], particles[t + 1][indices[-1]],
                                       _parents(ancestors[t], indices[-1]), moves, generator))
            continue
        candidates, following = particles[t], particles[t + 1][indices[-1]]
        N = len(candidates)
        rows = max(1, PAIRS_PER_BATCH // N)
        log_density = torch.cat([
            log_transition(following[m:m + rows].repeat_interleave(N, dim=0),
                           candidates.repeat(len(following[m:m + rows]), 1)).reshape(-1, N)
            for m in range(0, M, rows)])
        indices.append(_draw(log_weights[t].to(log_density) + log_density, generator))
    return torch.stack(indices[::-1])


def _parents(ancestors: torch.Tensor | None, children: torch.Tensor) -> torch.Tensor:
    """The genealogy's parent indices of the particles ``children`` (M,) (themselves where no
    resampling happened)."""
    return children.clone() if ancestors is None else ancestors.to(children.device)[children].long()


def _metropolis(log_transition, candidates: torch.Tensor, log_weights: torch.Tensor, following: torch.Tensor,
                start: torch.Tensor, moves: int, generator: torch.Generator) -> torch.Tensor:
    """K independent Metropolis–Hastings moves (module docstring) from ``start`` (M,), targeting
    Categorical(w_t^i p(following_m | candidates_i)) for each of the M rows of ``following``. The
    proposals do not depend on the chain's state, so all K M of them are drawn and their densities
    evaluated as one batch with the start's; the accept steps then run on those numbers."""
    M = len(start)
    proposals = torch.multinomial(torch.exp(log_weights.to(torch.float64)), M * moves, replacement=True,
                                  generator=generator).reshape(moves, M) if moves else start.new_empty((0, M))
    chosen = torch.cat([start[None], proposals])                                    # (K + 1, M)
    density = log_transition(following.repeat(moves + 1, 1), candidates[chosen.flatten()]).reshape(moves + 1, M)
    density = density.to(torch.float64)
    u = torch.log(torch.rand((moves, M), generator=generator, dtype=torch.float64, device=generator.device))
    current, current_density = start, density[0]
    for k in range(moves):
        accept = (u[k] < density[k + 1] - current_density) | ~torch.isfinite(current_density)
        current = torch.where(accept, proposals[k], current)
        current_density = torch.where(accept, density[k + 1], current_density)
    return current


def distinct(indices: torch.Tensor) -> torch.Tensor:
    """(T,) the number of distinct particles among the M trajectories at each frame, from indices (T, M)."""
    return torch.tensor([len(torch.unique(row)) for row in indices])
