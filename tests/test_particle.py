"""The particle filter against the Kalman filter on a linear-Gaussian model, and on mocap."""

import math

import numpy as np
import pytest
import torch

from priortrack import PriortrackError, load_walkjog
from priortrack.experiments.metrics import mpjpe
from priortrack.filters.particle import ParticleFilter
from priortrack.models.tracking import TrackingModel
from priortrack.observation import default_camera, synthesize
from priortrack.observation.likelihood import JointLikelihood
from priortrack.priors import Diffusion
from priortrack.priors.global_motion import GlobalMotion

from linear_gaussian import LinearGaussian, kalman, thread_counts
from priortrack.body.fk import joint_positions


@pytest.fixture
def linear():
    dt = 1.0
    A = [[1, dt, 0], [0, 1, 0], [0, 0, 0.9]]
    Q = np.diag([0.01, 0.04, 0.09])
    H = [[1.0, 0, 0], [0, 0, 1.0]]
    R = np.diag([0.25, 0.16])
    return LinearGaussian(A, Q, H, R)


def test_particle_posterior_matches_kalman(linear):
    rng = np.random.default_rng(0)
    zs = rng.normal(0, 1, (6, 2))
    zs[3, 0] = np.nan                                   # a missing entry is data
    m0, P0 = np.array([0.5, -0.2, 1.0]), np.diag([0.3, 0.2, 0.5])
    m, P = kalman(linear, m0, P0, zs)
    n = 40000
    pf = ParticleFilter(linear, n, ess_threshold=1.0, seed=1)
    g = torch.Generator().manual_seed(2)
    start = torch.as_tensor(m0) + torch.randn(n, 3, generator=g, dtype=torch.float64) @ torch.linalg.cholesky(torch.as_tensor(P0)).T
    pf.initialise_states(start)
    for z in zs:
        snap = pf.step(z)
    w = snap.weights.numpy()
    s = snap.particles.numpy()
    mean = w @ s
    cov = (w[:, None] * (s - mean)).T @ (s - mean)
    se = np.sqrt(np.diag(P) / snap.ess)
    assert np.all(np.abs(mean - m) < 5 * se), (mean, m, se)
    np.testing.assert_allclose(cov, P, atol=0.06 * np.abs(P).max())


@pytest.mark.parametrize("forget_the_prior", [False, True])
def test_resample_move_keeps_the_kalman_posterior(linear, forget_the_prior):
    """Metropolis–Hastings moves after every resampling (issue 31) leave the filtering distribution
    invariant: the moved, equally weighted particles match the Kalman posterior (mean within 0.05 σ,
    variances within 6 %). A move that forgot the transition density (the second case) is pulled
    towards the likelihood alone: measured 0.3–0.7 σ off and 1.5–5× the variance."""
    rng = np.random.default_rng(0)
    A, Q, H, R = (m.numpy() for m in (linear.A, linear.Q, linear.H, linear.R))
    state, zs = np.array([0.5, -0.2, 1.0]), []
    for _ in range(8):                                   # data drawn from the model itself
        state = A @ state + rng.multivariate_normal(np.zeros(3), Q)
        zs.append(H @ state + rng.multivariate_normal(np.zeros(2), R))
    m0, P0 = np.array([0.5, -0.2, 1.0]), np.diag([0.3, 0.2, 0.5])
    m, P = kalman(linear, m0, P0, np.array(zs))
    if forget_the_prior:
        linear.log_transition = lambda s_next, s: torch.zeros(len(s_next), dtype=s_next.dtype)
    n = 40000
    pf = ParticleFilter(linear, n, ess_threshold=1.0, moves=4, seed=1)
    g = torch.Generator().manual_seed(2)
    start = torch.as_tensor(m0) + torch.randn(n, 3, generator=g, dtype=torch.float64) @ torch.linalg.cholesky(torch.as_tensor(P0)).T
    pf.initialise_states(start)
    rates = []
    for z in zs:
        snap = pf.step(z)
        rates += [float(f.split(":")[1]) for f in snap.flags if f.startswith("moved:")]
    assert len(rates) == len(zs) and all(0.1 < r < 0.9 for r in rates), rates
    s = pf.states.numpy()                                # after the last step's resampling and moves
    assert len(np.unique(s[:, 0])) > 0.5 * n             # the moves made the resampled copies distinct
    sd = np.sqrt(np.diag(P))
    close = np.all(np.abs(s.mean(0) - m) < 0.05 * sd) and np.all(np.abs(s.var(0) / sd ** 2 - 1) < 0.06)
    assert close != forget_the_prior, (s.mean(0), m, s.var(0), sd ** 2)
    with pytest.raises(PriortrackError, match="moves must be at least 0"):
        ParticleFilter(linear, 10, moves=-1)


def test_all_missing_frame_keeps_the_prediction_and_weights(linear):
    pf = ParticleFilter(linear, 500, ess_threshold=0.0, seed=0)     # never resample
    pf.initialise_states(torch.zeros(500, 3, dtype=torch.float64))
    pf.step(np.array([0.3, 0.1]))
    before = pf.log_weights.clone()
    snap = pf.step(np.array([np.nan, np.nan]))
    assert "no-observation" in snap.flags and snap.ancestors is None
    assert torch.equal(pf.log_weights, before)


def test_underflowing_weights_are_reset_not_nan(linear):
    pf = ParticleFilter(linear, 200, seed=0)
    pf.initialise_states(torch.zeros(200, 3, dtype=torch.float64))
    far = linear.log_likelihood
    linear.log_likelihood = lambda p, z: torch.full((len(p),), -math.inf, dtype=p.dtype)
    snap = pf.step(np.array([1e6, 1e6]))
    linear.log_likelihood = far
    assert "weights-underflow" in snap.flags
    assert torch.isfinite(snap.weights).all() and snap.ess == pytest.approx(200)


def test_bad_observation_shape_and_uninitialised(linear):
    pf = ParticleFilter(linear, 10)
    with pytest.raises(PriortrackError, match="not initialised"):
        pf.step(np.zeros(2))
    pf.initialise_states(torch.zeros(10, 3, dtype=torch.float64))
    with pytest.raises(PriortrackError, match=r"expected \(2,\)"):
        pf.step(np.zeros(3))
    with pytest.raises(PriortrackError, match="particles"):
        ParticleFilter(linear, 0)
    with pytest.raises(PriortrackError, match="dtype must be one of float64, float32"):
        ParticleFilter(linear, 10, dtype="float16")


@pytest.mark.parametrize("dtype, translation", [("float64", "sampled"), ("float32", "marginalised")])
def test_tracks_a_walk_better_than_holding_the_first_pose(dtype, translation):
    walkjog = load_walkjog()
    train = list(walkjog.walks("train"))
    prior = Diffusion.fit(train, local=True)
    motion = walkjog.test[1][:40]
    X = joint_positions(motion, "eval15")
    obs = synthesize(X, motion.fps, default_camera(X), "clean", seed=0)
    model = TrackingModel.fitted(prior, train,
                          JointLikelihood(obs.camera))
    pf = ParticleFilter(model, 300, dtype=dtype, translation=translation, seed=0)
    track = pf.run(obs.uv, motion)
    assert pf.states.dtype == getattr(torch, dtype) and pf.log_weights.dtype == torch.float64
    filtered = mpjpe(track.estimates[2:], X[2:]).mean()
    still = mpjpe(np.repeat(X[1:2], len(X) - 2, 0), X[2:]).mean()
    assert filtered < 0.5 * still
    assert np.isnan(track.ess[:2]).all() and np.all(track.ess[2:] >= 1)


def test_mean_state_averages_placements_on_so3():
    """TrackingModel.mean: translations by their weighted mean; rotations by the chordal mean, so
    that rotations of ±θ about one axis with equal weights average to the identity, and a set of
    copies of one rotation averages to it."""
    walkjog = load_walkjog()
    prior = Diffusion.fit(list(walkjog.walks("train"))[:2], local=True)
    model = TrackingModel(prior, GlobalMotion(torch.full((6,), 0.01)), JointLikelihood(default_camera(
        joint_positions(walkjog.test[1][:3], "eval15"))))
    S = prior.state_dim
    s = torch.zeros(4, S + 12, dtype=torch.float64)
    s[:, S:S + 3] = torch.tensor([[0.0, 1, 2], [2, 3, 4], [1, 1, 1], [5, 5, 5]])
    s[:, S + 3:S + 6] = torch.tensor([[0.0, 0.4, 0], [0, -0.4, 0], [0, 0.4, 0], [0, -0.4, 0]])
    s[:, S + 9:S + 12] = torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64)
    w = torch.tensor([1.0, 1.0, 1.0, 1.0])
    mean = model.mean(s, w)
    torch.testing.assert_close(mean[S:S + 3], s[:, S:S + 3].mean(0))
    torch.testing.assert_close(mean[S + 3:S + 6], torch.zeros(3, dtype=torch.float64), atol=1e-12, rtol=0)
    torch.testing.assert_close(mean[S + 9:S + 12], torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64),
                               atol=1e-12, rtol=0)


def test_mean_rotation_is_the_chordal_mean_by_svd():
    """The quaternion eigenvector (TrackingModel.mean) against the other closed form of the same
    chordal mean: Σ w_i R_i projected onto SO(3) by SVD (Moakher 2002), for spread rotation sets."""
    from priortrack.geometry import so3

    walkjog = load_walkjog()
    prior = Diffusion.fit(list(walkjog.walks("train"))[:2], local=True)
    model = TrackingModel(prior, GlobalMotion(torch.full((6,), 0.01)), JointLikelihood(default_camera(
        joint_positions(walkjog.test[1][:3], "eval15"))))
    S = prior.state_dim
    g = torch.Generator().manual_seed(4)
    for spread in (0.05, 0.5, 1.2):
        s = torch.zeros(500, S + 12, dtype=torch.float64)
        centre = torch.randn(1, 3, generator=g, dtype=torch.float64)
        for k in (S + 3, S + 9):
            s[:, k:k + 3] = so3.log(so3.exp(spread * torch.randn(500, 3, generator=g, dtype=torch.float64))
                                    @ so3.exp(centre))
        w = torch.rand(500, generator=g, dtype=torch.float64)
        mean = model.mean(s, w)
        for k in (S + 3, S + 9):
            U, _, Vh = torch.linalg.svd(torch.einsum("p,pij->ij", w / w.sum(), so3.exp(s[:, k:k + 3])))
            D = torch.diag(torch.tensor([1.0, 1.0, float(torch.sign(torch.linalg.det(U @ Vh)))], dtype=torch.float64))
            torch.testing.assert_close(so3.exp(mean[None, k:k + 3])[0], U @ D @ Vh, rtol=0, atol=1e-10)


@pytest.mark.parametrize("particles, threads, expected", [(1000, None, 1), (10000, None, 2), (1000, 2, 2), (10000, 1, 1)])
def test_a_step_runs_on_one_thread_where_the_particles_are_few(linear, particles, threads, expected):
    """Up to SINGLE_THREAD_PARTICLES on the CPU a step runs on one torch thread (two took 10× as long with the
    other core busy), more on torch's count; ``threads`` chooses; the caller's count is given back."""
    with thread_counts(linear, "observe") as seen:
        pf = ParticleFilter(linear, particles, threads=threads)
        pf.initialise_states(torch.zeros(particles, 3, dtype=torch.float64))
        pf.step(np.zeros(2))
        assert seen and set(seen) == {expected} and torch.get_num_threads() == 2


def test_threads_must_be_a_count(linear):
    with pytest.raises(PriortrackError, match="threads must be a whole number"):
        ParticleFilter(linear, 10, threads=0)
