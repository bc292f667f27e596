"""The unscented Kalman filter: exact against the Kalman filter on a linear-Gaussian model,
calibrated (NEES), batched = filterpy's per-point loop on a real prior, tracking mocap."""

import numpy as np
import pytest
import torch
from scipy.stats import chi2

from priortrack import PriortrackError, load_walkjog
from priortrack.experiments.metrics import mpjpe
from priortrack.models.tracking import TrackingModel
from priortrack.filters.ukf import EIGEN_FLOOR, UnscentedFilter, UnscentedTracking
from priortrack.observation import default_camera, synthesize
from priortrack.observation.likelihood import JointLikelihood
from priortrack.priors import GPDM, Diffusion
from priortrack.priors.global_motion import GlobalMotion
from priortrack.priors.lie import LiePrior
from priortrack.priors.spaces import AngleSpace

from linear_gaussian import LinearGaussian, kalman, thread_counts
from priortrack.body.fk import joint_positions


@pytest.fixture
def linear():
    A = [[1, 1.0, 0], [0, 1, 0], [0, 0, 0.9]]
    return LinearGaussian(A, np.diag([0.01, 0.04, 0.09]), [[1.0, 0, 0], [0, 0, 1.0]], np.diag([0.25, 0.16]))


@pytest.fixture(scope="module")
def walks():
    w = load_walkjog()
    return list(w.walks("train")), w.test[1]


def tracking_model(prior, train, motion, scenario="clean", **likelihood):
    X = joint_positions(motion, "eval15")
    obs = synthesize(X, motion.fps, default_camera(X), scenario, seed=0)
    gm = GlobalMotion.fit([prior.space.global_pose(m) for m in train])
    return TrackingModel(prior, gm, JointLikelihood(obs.camera, **likelihood)), obs, X


# ---- linear-Gaussian: the Kalman filter exactly ----------------------------------------------------

@pytest.mark.parametrize("alpha, beta, kappa", [(0.5, 2.0, 0.0), (1.0, 2.0, 0.0), (1e-3, 2.0, 0.0), (1.0, 0.0, 2.0)])
def test_equals_the_kalman_filter_on_a_linear_model(linear, alpha, beta, kappa):
    rng = np.random.default_rng(0)
    zs = rng.normal(0, 1, (8, 2))
    zs[3, 0] = np.nan                                   # one missing coordinate
    zs[5] = np.nan                                      # nothing observed
    m0, P0 = np.array([0.5, -0.2, 1.0]), np.array([[0.3, 0.1, 0.0], [0.1, 0.2, 0.05], [0.0, 0.05, 0.5]])
    ukf = UnscentedFilter(linear, alpha, beta, kappa)
    ukf.initialise_states(m0, P0)
    for t, z in enumerate(zs):
        snap = ukf.step(z)
        m, P = kalman(linear, m0, P0, zs[:t + 1])
        np.testing.assert_allclose(ukf.mean.numpy(), m, rtol=0, atol=1e-8)
        np.testing.assert_allclose(ukf.covariance.numpy(), P, rtol=0, atol=1e-8)
        assert snap.flags == (["no-observation"] if t == 5 else [])
    n = 3
    assert snap.particles.shape == (2 * n + 1, n) and snap.ess == 2 * n + 1 and snap.ancestors is None
    assert float(snap.weights.sum()) == pytest.approx(1.0)
    np.testing.assert_allclose(snap.weights.numpy() @ snap.particles.numpy(), ukf.mean.numpy(), atol=1e-12)
    np.testing.assert_allclose(snap.estimate, linear.H.numpy() @ ukf.mean.numpy())


def test_nees_is_inside_its_chi_square_band(linear):
    """50 runs × 100 steps of the linear model (10 % of coordinates missing): at each step the NEES
    e_tᵀ P_t⁻¹ e_t averaged over the runs lies in its 95 % band, 50 · NEES̄ ~ χ²(50 · 3), at ≥ 90 %
    of the steps (95 % expected), and so does its average over all steps."""
    runs, steps, n = 50, 100, 3
    rng = np.random.default_rng(1)
    g = torch.Generator().manual_seed(1)
    m0, P0 = np.zeros(n), np.diag([0.5, 0.2, 0.5])
    LR = np.linalg.cholesky(linear.R.numpy())
    nees = np.zeros((runs, steps))
    for r in range(runs):
        s = torch.as_tensor(m0 + np.linalg.cholesky(P0) @ rng.normal(size=n))[None]
        ukf = UnscentedFilter(linear)
        ukf.initialise_states(m0, P0)
        for t in range(steps):
            s = linear.predict(s, g)
            z = linear.H.numpy() @ s[0].numpy() + LR @ rng.normal(size=2)
            z[rng.random(2) < 0.1] = np.nan
            ukf.step(z)
            e = s[0].numpy() - ukf.mean.numpy()
            nees[r, t] = e @ np.linalg.solve(ukf.covariance.numpy(), e)
    lo, hi = chi2.ppf([0.025, 0.975], runs * n) / runs
    average = nees.mean(axis=0)
    inside = np.mean((average > lo) & (average < hi))
    assert inside >= 0.9, (inside, lo, hi)
    assert lo < average.mean() < hi, (average.mean(), lo, hi)


def test_a_broken_covariance_is_repaired_and_flagged(linear):
    m0 = np.array([0.5, -0.2, 1.0])
    broken = np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, -0.5]])      # eigenvalues 3, −1, −0.5
    ukf = UnscentedFilter(linear)
    ukf.initialise_states(m0, broken)
    z = np.array([0.3, 0.7])
    snap = ukf.step(z)
    assert "covariance-repaired" in snap.flags
    w, V = np.linalg.eigh(broken)
    repaired = (V * np.maximum(w, EIGEN_FLOOR * w.max())) @ V.T                 # the documented repair
    m, P = kalman(linear, m0, repaired, [z])
    np.testing.assert_allclose(ukf.mean.numpy(), m, atol=1e-8)
    np.testing.assert_allclose(ukf.covariance.numpy(), P, atol=1e-8)
    assert np.linalg.eigvalsh(ukf.covariance.numpy()).min() > 0
    assert "covariance-repaired" not in ukf.step(z).flags


def test_a_covariance_singular_to_rounding_is_repaired_before_a_scaled_factorisation_fails():
    """A cloud collapsed in one coordinate: a variance of 1e−40 there, a pivot numpy's Cholesky accepts, and whose sign
    the next factorisation, of a multiple of P (the sigma points' (λ + n) P) after other arithmetic, need not keep
    (pf-lie-general's smoothed cloud on the Pose2Sim trial: smallest eigenvalue −5e−40, scipy failed). The repair
    floors it."""
    import scipy.linalg

    from priortrack.filters.ukf import repaired_covariance

    P = np.zeros((3, 3))
    P[:2, :2] = [[2.0, 0.5], [0.5, 1.0]]
    P[2, 2] = 1e-40
    np.linalg.cholesky(P)
    fixed, repaired = repaired_covariance(P)
    assert repaired and np.linalg.eigvalsh(fixed).min() >= 0.5 * EIGEN_FLOOR * np.linalg.eigvalsh(P).max()
    scipy.linalg.cholesky(10.0 * fixed)
    np.testing.assert_allclose(fixed, P, atol=1e-8)                         # a floor, nothing else moved
    well = np.diag([3.0, 2.0, 1.0])
    assert repaired_covariance(well)[1] is False and np.array_equal(repaired_covariance(well)[0], well)


class HalfBlind(LinearGaussian):
    """The linear model whose first measured coordinate is undefined (NaN) for states with s_0 > 0,
    as a joint behind the camera has no projection."""

    def measure(self, s):
        z = super().measure(s)
        z[s[:, 0] > 0, 0] = np.nan
        return z


def test_a_coordinate_some_sigma_point_cannot_predict_is_left_out(linear):
    model = HalfBlind(linear.A, linear.Q, linear.H, linear.R)
    m0, P0 = np.array([0.0, 0.1, 1.0]), np.diag([0.3, 0.2, 0.5])       # sigma points on both sides of 0
    ukf = UnscentedFilter(model)
    ukf.initialise_states(m0, P0)
    z = np.array([0.4, 0.9])
    snap = ukf.step(z)
    assert snap.flags == ["behind-camera"]
    m, P = kalman(linear, m0, P0, [np.array([np.nan, 0.9])])
    np.testing.assert_allclose(ukf.mean.numpy(), m, atol=1e-8)
    np.testing.assert_allclose(ukf.covariance.numpy(), P, atol=1e-8)


def test_bad_input_is_refused(linear):
    ukf = UnscentedFilter(linear)
    with pytest.raises(PriortrackError, match="not initialised"):
        ukf.step(np.zeros(2))
    ukf.initialise_states(np.zeros(3), np.eye(3))
    with pytest.raises(PriortrackError, match=r"expected \(2,\)"):
        ukf.step(np.zeros((15, 2)))
    with pytest.raises(PriortrackError, match=r"expected \(3,\) and \(3, 3\)"):
        ukf.initialise_states(np.zeros(4), np.eye(3))
    with pytest.raises(PriortrackError, match="NaN"):
        ukf.initialise_states(np.zeros(3), np.full((3, 3), np.nan))
    with pytest.raises(PriortrackError, match="Bare lacks tangent_dim, observation_shape, measurement_block, mean_step, measure"):
        UnscentedFilter(object.__new__(type("Bare", (), {"dim": 3})))


# ---- tangent coordinates ----------------------------------------------------------------------------

@pytest.mark.parametrize("space", ["angles", "directions"])
def test_tangent_coordinates_invert_and_transport_isometrically(walks, space):
    train, motion = walks
    prior = Diffusion.fit(train[:2], local=True, space=space)
    model, _, _ = tracking_model(prior, train[:2], motion[:20])
    form = UnscentedTracking(model)
    g = torch.Generator().manual_seed(0)
    states = model.initial_states(motion, 6, g)
    states[:, -6:] = model.global_motion.sample(states[:, -12:-6], states[:, -6:], g)       # g_{t-1} ≠ g_t
    base = states[0]
    v = form.boxminus(states, base)
    assert v.shape == (6, form.tangent_dim) and float(v[0].abs().max()) < 1e-12
    np.testing.assert_allclose(form.boxplus(base.expand(6, -1), v).numpy(), states.numpy(), atol=1e-10)
    T = form.transport(base, states[1])
    np.testing.assert_allclose((T @ T.T).numpy(), np.eye(form.tangent_dim), atol=1e-12)
    mean = form.sigma_mean(states, torch.full((6,), 1 / 6, dtype=torch.float64))
    assert float(form.boxminus(states, mean).sum(0).abs().max()) < 1e-10        # Σ_i (s_i ⊟ m) = 0


@pytest.mark.parametrize("space", ["angles", "directions"])
def test_diffusion_noise_covariance_is_that_of_its_steps(walks, space):
    """transition_covariance(x) against the covariance of sampled steps x_t ⊟ x in the UKF's tangent
    coordinates (20,000 draws: 3 % relative on the diagonal, 0.03 σ² off it)."""
    train, motion = walks
    prior = Diffusion.fit(train[:2], local=True, space=space)
    model, _, _ = tracking_model(prior, train[:2], motion[:20])
    form = UnscentedTracking(model)
    x = prior.encode(motion[:1])
    steps = form.space.local(prior.sample(x.expand(20000, -1), torch.Generator().manual_seed(0)), x[0])
    Q = prior.transition_covariance(x)[0].numpy()
    empirical = np.cov(steps.numpy().T)
    scale = np.sqrt(np.outer(np.diag(Q), np.diag(Q)))
    np.testing.assert_allclose(np.diag(empirical) / np.diag(Q), 1.0, atol=0.06)
    assert np.abs((empirical - Q) / scale).max() < 0.06
    assert Q.shape == (form.space.tangent_dim, form.space.tangent_dim)


@pytest.mark.parametrize("defensive", [False, True])
def test_lie_transition_is_its_mixture_moment_matched(walks, defensive):
    """ukf-lie's Gaussian (issue 31): the Lie prior's (or its defensive mixture's) mean step and
    transition_covariance(x) against 200,000 sampled steps in the UKF's tangent coordinates at x:
    the moment-matched mixture, not one component (a walk pose where several components share the
    responsibility). Mean within 0.03 of the largest step coordinate, covariance within 3 % of its largest entry."""
    from priortrack.priors.defensive import DefensiveMixture

    train, motion = walks
    prior = LiePrior.fit(train[:4], seed=0)
    if defensive:
        prior = DefensiveMixture(prior, Diffusion.fit(train[:4], local=True, space="directions"), 0.1)
    space = prior.space
    x = prior.encode(motion[40:41]).double()
    steps = space.local(prior.sample(x.expand(200000, -1).contiguous(), torch.Generator().manual_seed(0)), x[0])
    mean_step = space.local(prior.mean(x), x[0])[0]
    Q = prior.transition_covariance(x)[0]
    assert Q.shape == (28, 28)
    assert float((steps.mean(0) - mean_step).abs().max()) < 0.03 * float(mean_step.abs().max())
    assert float((torch.cov(steps.T) - Q).abs().max()) < 0.03 * float(Q.abs().max())
    assert float(torch.linalg.eigvalsh(Q).min()) > 0


# ---- real priors -----------------------------------------------------------------------------------

@pytest.mark.parametrize("space", ["angles", "directions"])
def test_batched_equals_filterpys_per_point_loop(walks, space):
    train, motion = walks
    prior = Diffusion.fit(train[:2], local=True, space=space)
    model, obs, _ = tracking_model(prior, train[:2], motion[:8], "noise")
    obs.uv[3, :5] = np.nan                                             # five joints unseen
    batched, looped = UnscentedFilter(model), UnscentedFilter(model, batched=False)
    for f in (batched, looped):
        f.initialise(motion)
    for t in range(2, 5):
        a, b = batched.step(obs.uv[t]), looped.step(obs.uv[t])
        assert a.flags == b.flags == []
        np.testing.assert_allclose(batched.mean.numpy(), looped.mean.numpy(), rtol=0, atol=1e-10)
        np.testing.assert_allclose(batched.covariance.numpy(), looped.covariance.numpy(), rtol=0, atol=1e-10)
    assert batched.covariance.shape == (prior.space.tangent_dims.sum() + 12,) * 2


@pytest.mark.parametrize("space", ["angles", "directions"])
def test_tracks_a_walk_better_than_holding_the_first_pose(walks, space):
    """Clean observations of 38 frames of the held-out walk 35_29: the mean per-joint error is under
    a fifth of that of the first pose held still (measured: 58 mm (angles), 65 mm (directions)
    against 674 mm; the particle filter with 2000 particles: 72 mm)."""
    train, motion = walks
    motion = motion[:40]
    prior = Diffusion.fit(train if space == "angles" else train[:6], local=True, space=space)
    model, obs, X = tracking_model(prior, train, motion)
    track = UnscentedFilter(model).run(obs.uv, motion)
    filtered = mpjpe(track.estimates[2:], X[2:]).mean()
    still = mpjpe(np.repeat(X[1:2], len(X) - 2, 0), X[2:]).mean()
    assert filtered < 0.2 * still, (filtered, still)
    assert np.isfinite(track.estimates).all() and not any(track.flags)


def test_gpdm_prior_noise_is_its_dynamics_variance(walks):
    """A GPDM built (not fitted) on a walk's whitened PCA: Q(x) = σ_X²(x) I, and the UKF runs on it."""
    train, motion = walks
    angles = AngleSpace.fit(train[:1])
    Y = angles.encode(train[0])
    mean = Y.mean(0)
    U, _, _ = torch.linalg.svd(Y - mean, full_matrices=False)
    X = np.sqrt(len(Y)) * U[:, :3]
    prior = GPDM(angles, X, Y - mean, mean, [len(Y)], np.log([1.0, 1.0, 1.0, 100.0]), np.log([1.0, 1.0, 100.0]), True)
    x = X[:4]
    var = prior.dynamics(x)[1]
    np.testing.assert_allclose(prior.transition_covariance(x).numpy(), var[:, None, None].numpy() * np.eye(3))
    model, obs, _ = tracking_model(prior, train[:1], motion[:6])
    ukf = UnscentedFilter(model)
    ukf.initialise(motion)
    for t in range(2, 6):
        ukf.step(obs.uv[t])
    assert ukf.covariance.shape == (15, 15) and np.isfinite(ukf.mean.numpy()).all()


def test_robust_likelihood_is_refused(walks):
    train, motion = walks
    prior = Diffusion.fit(train[:2], local=True)
    model, _, _ = tracking_model(prior, train[:2], motion[:10], robust_nu=4.0)
    with pytest.raises(PriortrackError, match="Student-t"):
        UnscentedFilter(model)


def test_a_step_runs_on_one_thread_and_gives_the_count_back(linear):
    """The step's small operations run on STEP_THREADS torch threads (splitting them cost 2.8× on two
    idle cores); the caller's thread count is restored after it, also when the step refuses its input."""
    from priortrack.filters.ukf import STEP_THREADS

    ukf = UnscentedFilter(linear)
    ukf.initialise_states(np.zeros(3), np.eye(3))
    with thread_counts(linear, "measure") as seen:
        ukf.step(np.zeros(linear.observation_shape))
        assert seen and set(seen) == {STEP_THREADS} and torch.get_num_threads() == 2
        with pytest.raises(PriortrackError, match="observation has shape"):
            ukf.step(np.zeros(7))
        assert torch.get_num_threads() == 2


def test_bench_ukf_on_several_cameras_and_its_bad_arguments():
    """bench ukf --cameras 3: the multi-view step, batched and through filterpy's loop, the same means; a
    camera count outside [1, 8] refused by name."""
    from priortrack.experiments.benchmarks.ukf import bench_ukf

    result = bench_ukf(repeats=1, cameras=3)
    assert result["cameras"] == 3 and result["sigma_points"] == 125 and result["max_abs_mean_diff"] < 1e-9
    with pytest.raises(PriortrackError, match=r"cameras in \[1, 8\] \(got 1, 1, 9\)"):
        bench_ukf(repeats=1, cameras=9)


def test_swap_correction_exchanges_a_pair_only_where_the_exchange_lies_nearer_the_prediction():
    """swap_corrected against its closed form: sigma points whose pixels sit at ẑ (no spread) and R = σ² I,
    so d² = |z − ẑ|² / σ². One camera, eval15: the wrists detected swapped are exchanged back (with their
    noise); the knees as labelled are kept; an elbow pair with one side missing is left alone; the same
    in the second camera's order."""
    from priortrack.data.eval15 import EVAL15_MIRROR_PAIRS
    from priortrack.filters.ukf import exchange, predicted_points, swap_corrected

    rng = np.random.default_rng(0)
    J, b, C = 15, 2, 2
    z_hat = rng.uniform(0, 1000, size=(C, J, b))
    predicted = np.repeat(z_hat.reshape(1, -1), 3, axis=0)                   # 3 sigma points, all at ẑ
    Wm = Wc = np.full(3, 1 / 3)

    def points(sigmas):                                                      # every point's ẑ (K, b), P (K, b, b)
        return predicted_points(sigmas.reshape(len(sigmas), -1, b), Wm, Wc)

    z = z_hat + rng.normal(0, 2.0, size=z_hat.shape)
    z[1, [5, 8]] = z[1, [8, 5]]                                              # camera 2's wrists swapped
    z[1, 4] = np.nan                                                         # its left elbow missing
    variances = np.repeat(rng.uniform(4, 9, size=(C, J)), b, axis=1).ravel()
    variances_swapped = variances.reshape(C, J, b).copy()
    variances_swapped[1, [5, 8]] = variances_swapped[1, [8, 5]]
    gate = 13.8                                                              # χ²₂ at p = 0.001
    corrected, R, exchanged = swap_corrected(z.ravel(), np.diag(variances), *points(predicted), EVAL15_MIRROR_PAIRS, J, b,
                                             gate)
    expected = z.copy()
    expected[1, [5, 8]] = expected[1, [8, 5]]
    assert exchanged.tolist() == [J + 5, J + 8]                             # camera 2's left wrist, its right
    np.testing.assert_array_equal(corrected, expected.ravel())
    np.testing.assert_array_equal(np.diag(R), variances_swapped.ravel())
    assert np.count_nonzero(R - np.diag(np.diag(R))) == 0
    # the smoother repeats the filter's exchanges from the points alone
    again, R_again = exchange(z.ravel(), np.diag(variances), exchanged, b)
    np.testing.assert_array_equal(again, corrected)
    np.testing.assert_array_equal(R_again, R)
    unchanged, _, none = swap_corrected(expected.ravel(), np.diag(variances), *points(predicted), EVAL15_MIRROR_PAIRS, J, b, gate)
    assert len(none) == 0
    np.testing.assert_array_equal(unchanged, expected.ravel())
    # a lost limb: the right wrist predicted 80 px off, the detections as labelled; the exchange would be
    # nearer in sum (the left wrist detected beside the wrong prediction) but fails the gate at the left wrist
    lost = z_hat.copy()
    lost[0, 8] = z_hat[0, 5] + [3.0, 0.0]                                   # right wrist predicted on the left one
    predicted_lost = np.repeat(lost.reshape(1, -1), 3, axis=0)
    held, _, none = swap_corrected(expected.ravel(), np.diag(variances), *points(predicted_lost), EVAL15_MIRROR_PAIRS, J, b, gate)
    assert len(none) == 0
    np.testing.assert_array_equal(held, expected.ravel())
    # no gate, no exchange
    _, _, none = swap_corrected(z.ravel(), np.diag(variances), *points(predicted), EVAL15_MIRROR_PAIRS, J, b, np.inf)
    assert len(none) == 0


def test_the_placements_kernels_are_the_torch_path(monkeypatch):
    """⊞, ⊟ and the signed mean of the unscented filter's placements on float64 CPU tensors, by the fused kernels
    (priortrack.filters.placements_kernel): the torch path's results to 1e-12, for rotations from 1e-7 to 3 rad and
    the unscented weights' negative W_0; a gradient or float32 takes the torch path."""
    from priortrack.filters import ukf

    rng = np.random.default_rng(5)
    g = rng.normal(size=(125, 12)) * 0.05 + rng.normal(size=(1, 12))
    for k in (3, 9):
        axis = rng.normal(size=(125, 3))
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        g[:, k:k + 3] = axis * np.geomspace(1e-7, 3.0, 125)[:, None]
    g[1:, 3:6] = g[0, 3:6] + rng.normal(size=(124, 3)) * 0.02            # sigma points about the first, for the mean
    g = torch.as_tensor(g)
    v = torch.as_tensor(rng.normal(size=(125, 12)) * 0.1)
    w = torch.full((125,), 4.0 / 124, dtype=torch.float64)
    w[0] = -3.0                                                            # Σ w = 1, W_0 < 0
    kernel = (ukf.placements_plus(g, v), ukf.placements_minus(g, g[7]), ukf.placements_mean(g, w))
    monkeypatch.setattr(ukf, "cpu_kernel_applies", lambda *tensors, dtype=None: False)
    reference = (ukf.placements_plus(g, v), ukf.placements_minus(g, g[7]), ukf.placements_mean(g, w))
    for a, b in zip(kernel, reference):
        assert a.dtype == torch.float64 and a.shape == b.shape
        np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=0, atol=1e-12)
    monkeypatch.undo()
    assert not ukf._in_kernel(g.float(), v.float()) and not ukf._in_kernel(g.clone().requires_grad_(True), v)


def test_an_elbow_drifted_into_the_trunk_is_moved_to_its_other_depth_branch(walks):
    """A one-camera elbow on the branch through the chest (Shelf, cameras 0, 1, 4: actor 2's akimbo right elbow, seen
    only by the camera at their right, sat on the trunk's axis 0.35–0.5 m from the truth for 3 s): the update takes it
    towards its reflection about the shoulder (the same pixel, the same upper arm), the trunk held. Measured: 0.043 m
    from that branch after one step against 0.113 without the repair, its pixel 1.4 px from the detection, the trunk's
    joints within 0.015 m of the unrepaired step's."""
    from priortrack.geometry.depth_branches import inside_trunk, reflected

    train, motion = walks
    prior = Diffusion.fit(train[:2], local=True, space="angles")
    model, obs, _ = tracking_model(prior, train[:2], motion[:8])
    start = UnscentedFilter(model)
    start.initialise(motion)
    s = start.mean.numpy()

    def joints(state):
        return model.observe(torch.as_tensor(state)[None])[0].numpy()

    moved = []                                                    # the pose coordinates moving the right elbow alone
    for i in range(model.pose_dim):
        d = s.copy()
        d[i] += 1e-3
        moved.append(np.linalg.norm(joints(d) - joints(s), axis=-1))
    moved = np.array(moved)
    arm = np.flatnonzero((moved[:, 7] > 1e-5) & (moved[:, [0, 1, 3, 4, 6]].max(1) < 1e-9))
    centre = obs.camera.center.double().numpy()
    rng = np.random.default_rng(0)
    for _ in range(5000):                                         # a shoulder turned to put the elbow in the chest
        inside = s.copy()
        inside[arm] += rng.uniform(-np.pi, np.pi, len(arm))
        J = joints(inside)
        other = J.copy()
        other[7] = reflected(J[7], centre, J[6])
        if inside_trunk(J, 7) and not inside_trunk(other, 7):
            break
    else:
        pytest.fail("no pose with the right elbow inside the trunk")
    z = obs.camera.project(torch.from_numpy(J))[0].numpy()        # the pixels of that pose: both branches fit them
    after, flags = {}, {}
    for repair in (True, False):
        f = UnscentedFilter(model, branches=repair)
        f.initialise(motion)
        f.kf.x = inside.copy()
        flags[repair] = f.step(z).flags
        after[repair] = joints(f.mean.numpy())
    assert "branch-repaired" in flags[True] and "branch-repaired" not in flags[False]
    to_branch = {k: np.linalg.norm(after[k][7] - other[7]) for k in after}
    assert to_branch[True] < 0.5 * to_branch[False], to_branch
    pixel = obs.camera.project(torch.from_numpy(after[True][7:8]))[0].numpy()[0]
    assert np.linalg.norm(pixel - z[7]) < 2.0
    trunk = [0, 1, 3, 6, 9, 12]
    assert np.linalg.norm(after[True][trunk] - after[False][trunk], axis=-1).max() < 0.02
