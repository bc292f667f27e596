"""Langevin (MALA) moves (issue 45, item 2): invariance of a Gaussian target, the gradient's pull, and the guided
particle filter with them against the Kalman filter."""

import numpy as np
import pytest
import torch

from priortrack import PriortrackError
from priortrack.filters.langevin import ACCEPTANCE, ADAPT, adapted, langevin_moves
from priortrack.filters.particle import ParticleFilter

from linear_gaussian import LinearGaussian, kalman

MU = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
SIGMA = torch.tensor([[1.0, 0.6, 0.0], [0.6, 2.0, -0.3], [0.0, -0.3, 0.5]], dtype=torch.float64)


def _gaussian(s):
    d = s - MU
    return -0.5 * (d * torch.linalg.solve(SIGMA, d.T).T).sum(-1), None


def _euclidean_moves(s, M, step, moves, seed):
    return langevin_moves(_gaussian, lambda s, v: s + v, lambda a, b: a - b, s, M, step, moves,
                          torch.Generator().manual_seed(seed))


def _draw(n, seed):
    g = torch.Generator().manual_seed(seed)
    return MU + torch.randn(n, 3, generator=g, dtype=torch.float64) @ torch.linalg.cholesky(SIGMA).T


def test_moves_keep_a_gaussian_target():
    """20,000 exact draws of N(μ, Σ), ten moves at τ = 1 preconditioned by the identity: the cloud keeps μ (within 4
    standard errors) and Σ (within 4 %), and most points moved. Without the Metropolis correction (the unadjusted
    Langevin step) the stationary covariance of this step is Σ inflated by up to 1 / (1 − τ² λ_max(Σ⁻¹) / 4),
    far outside the tolerance."""
    s = _draw(20_000, 0)
    moved, aux, rate = _euclidean_moves(s, torch.eye(3, dtype=torch.float64), 1.0, 10, 1)
    assert aux is None and 0.3 < rate < 1.0
    assert (moved != s).any(-1).float().mean() > 0.9
    se = torch.sqrt(torch.diagonal(SIGMA) / len(s))
    assert torch.all((moved.mean(0) - MU).abs() < 4 * se)
    np.testing.assert_allclose(torch.cov(moved.T).numpy(), SIGMA.numpy(), atol=0.04 * float(SIGMA.abs().max()))


def test_the_gradient_pulls_a_point_mass_to_the_target():
    """From 5,000 copies of one point 3 σ away, forty moves preconditioned by Σ reach the target's moments: the
    gradient's sign and the proposal's reverse density are right, or the cloud would stay or drift."""
    start = (MU + torch.tensor([3.0, -4.0, 2.0], dtype=torch.float64)).expand(5000, 3).clone()
    moved, _, rate = _euclidean_moves(start, SIGMA, 0.9, 40, 2)
    assert rate > 0.4
    se = torch.sqrt(torch.diagonal(SIGMA) / 1000)               # draws correlated over moves: a fifth as many
    assert torch.all((moved.mean(0) - MU).abs() < 4 * se), moved.mean(0)
    np.testing.assert_allclose(torch.cov(moved.T).numpy(), SIGMA.numpy(), atol=0.1 * float(SIGMA.abs().max()))


def test_companions_follow_the_accepted_states():
    """The target's companion tensors (the marginalised translation's Kalman update) are the accepted state's."""
    def target(s):
        log_pi, _ = _gaussian(s)
        return log_pi, (s * 2.0, s[:, :1] + 1.0)

    s = _draw(500, 3)
    moved, (double, plus), _ = langevin_moves(target, lambda s, v: s + v, lambda a, b: a - b, s,
                                              torch.eye(3, dtype=torch.float64), 1.0, 3, torch.Generator().manual_seed(4))
    torch.testing.assert_close(double, 2 * moved)
    torch.testing.assert_close(plus, moved[:, :1] + 1)


def test_the_step_adapts_towards_the_band():
    low, high = ACCEPTANCE
    assert adapted(0.5, high + 0.05) == pytest.approx(0.5 * ADAPT)
    assert adapted(0.5, low - 0.05) == pytest.approx(0.5 / ADAPT)
    assert adapted(0.5, (low + high) / 2) == 0.5


def test_a_guided_filter_with_langevin_moves_keeps_the_kalman_posterior():
    """A constant-velocity state under a sharp likelihood on its position and drift, six frames, 4000 particles
    resampled and moved (three Langevin moves) every frame, seeds 0–3: the observed coordinates' mean within a
    quarter of a posterior standard deviation of the Kalman filter's (the velocity's error reaches them through the
    step; measured ≤ 0.1) and their variances within 10 %; the unobserved velocity, which the
    moves cannot reach beyond one frame's step (its parent is fixed), on average within half a posterior standard
    deviation (measured: 0.39; the same filter without moves 1.17, its seeds' means spread over 1.5 sd). The moves
    were made and accepted often, and leave over 95 % of the particles distinct."""
    model = LinearGaussian([[1, 1.0, 0], [0, 1, 0], [0, 0, 0.9]], np.diag([0.04, 0.04, 0.09]),
                           [[1.0, 0, 0], [0, 0, 1.0]], np.diag([0.001, 0.002]))
    rng = np.random.default_rng(0)
    zs = rng.normal(0, 1, (6, 2))
    m0, P0 = np.array([0.5, -0.2, 1.0]), np.diag([0.3, 0.2, 0.5])
    m, P = kalman(model, m0, P0, zs)
    g = torch.Generator().manual_seed(2)
    start = torch.as_tensor(m0) + torch.randn(4000, 3, generator=g, dtype=torch.float64) @ torch.linalg.cholesky(
        torch.as_tensor(P0)).T
    velocities = []
    for seed in range(4):
        pf = ParticleFilter(model, 4000, ess_threshold=1.0, proposal="guided", moves=3, move="langevin",
                            move_scale=0.8, seed=seed)
        pf.initialise_states(start)
        snaps = [pf.step(z) for z in zs]
        rates = [float(f.split(":")[1]) for snap in snaps for f in snap.flags if f.startswith("moved:")]
        assert len(rates) == 6 and min(rates) > 0.3, rates
        s = pf.states.numpy()
        observed = [0, 2]
        sd = np.sqrt(np.diag(P)[observed])
        assert np.all(np.abs(s.mean(0)[observed] - m[observed]) < 0.25 * sd), (s.mean(0), m, sd)
        np.testing.assert_allclose(s[:, observed].var(0), np.diag(P)[observed], rtol=0.1)
        assert len(np.unique(s[:, 0])) > 0.95 * len(s)
        velocities.append(s[:, 1].mean())
    assert abs(np.mean(velocities) - m[1]) < 0.5 * np.sqrt(P[1, 1]), (velocities, m[1])


def test_langevin_moves_need_the_guided_proposal():
    model = LinearGaussian([[1.0]], [[0.1]], [[1.0]], [[0.1]])
    with pytest.raises(PriortrackError, match="move must be one of random-walk, langevin"):
        ParticleFilter(model, 10, moves=1, move="langevin")
    with pytest.raises(PriortrackError, match="move must be one of"):
        ParticleFilter(model, 10, moves=1, move="hmc", proposal="guided")
