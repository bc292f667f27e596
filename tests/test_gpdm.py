"""GPDM and balanced GPDM: the objective, W, prediction, the contract, files, fill-in, bad input."""

import math

import numpy as np
import pytest
import torch
from scipy.optimize import minimize

from priortrack import PriortrackError, load_walkjog
from priortrack.data.bundled import load_bundled
from priortrack.experiments.reproductions import fill_in
from priortrack.priors.base import load_prior
from priortrack.priors.gpdm import GPDM, KAPPA, gpdm_objective
from priortrack.priors.spaces import AngleSpace
from priortrack.threads import torch_threads
from priortrack.viz.latent_plot import plot_latent


def tiny_walks():
    """Two short walks at 15 fps (subject 35): 2 × 20 frames."""
    return [m[:40:2] for m in load_walkjog().walks("train")[:2]]


@pytest.fixture(scope="module")
def model():
    return GPDM.fit(tiny_walks(), balanced=True, fps=15.0)


@pytest.fixture(scope="module")
def small_case():
    """A small float64 problem: 2 sequences (6 + 5 frames), D = 4, d = 2."""
    g = torch.Generator().manual_seed(0)
    t = torch.linspace(0, 3, 11, dtype=torch.float64)
    Y = torch.stack([torch.sin(t), torch.cos(2 * t), t, t ** 2 / 5], dim=1)
    Y = Y + 0.05 * torch.randn(Y.shape, generator=g, dtype=torch.float64)
    Y = Y - Y.mean(0)
    X = torch.randn(11, 2, generator=g, dtype=torch.float64)
    log_alpha = torch.log(torch.tensor([0.8, 1.3, 0.4, 50.0], dtype=torch.float64))
    log_beta = torch.log(torch.tensor([1.2, 0.7, 30.0], dtype=torch.float64))
    return X, log_alpha, log_beta, Y, [6, 5]


def numpy_objective(X, alpha, beta, Y, lengths, balanced, W=None, kappa=1e3):
    """The GPDM negative log posterior, written out directly (independent of the torch code)."""
    N, D = Y.shape
    d = X.shape[1]
    sq = ((X[:, None, :] - X[None, :, :]) ** 2).sum(-1)
    K_Y = beta[0] * np.exp(-beta[1] / 2 * sq) + np.eye(N) / beta[2]
    Kinv_Y = np.linalg.inv(K_Y)
    if W is None:
        W = np.sqrt(N / (np.einsum("nk,nm,mk->k", Y, Kinv_Y, Y) + 1 / kappa ** 2))
    first, ins, outs = [], [], []
    start = 0
    for n in lengths:
        first.append(start)
        ins += list(range(start, start + n - 1))
        outs += list(range(start + 1, start + n))
        start += n
    X_in, X_out = X[ins], X[outs]
    sq_in = ((X_in[:, None, :] - X_in[None, :, :]) ** 2).sum(-1)
    K_X = alpha[0] * np.exp(-alpha[1] / 2 * sq_in) + alpha[2] * X_in @ X_in.T + np.eye(len(ins)) / alpha[3]
    YW = Y * W
    L = (D / 2 * np.linalg.slogdet(K_Y)[1] + 0.5 * np.trace(Kinv_Y @ YW @ YW.T) - N * np.log(W).sum()
         + (W ** 2).sum() / (2 * kappa ** 2))
    lam = D / d if balanced else 1.0
    L += lam * (d / 2 * np.linalg.slogdet(K_X)[1] + 0.5 * np.trace(np.linalg.inv(K_X) @ X_out @ X_out.T))
    L += 0.5 * (X[first] ** 2).sum() + np.log(alpha).sum() + np.log(beta).sum()
    return L


# ---- the objective --------------------------------------------------------------------------

@pytest.mark.parametrize("balanced", [True, False])
def test_objective_matches_a_direct_numpy_evaluation(small_case, balanced):
    X, la, lb, Y, lengths = small_case
    ours = gpdm_objective(X, la, lb, Y, lengths, balanced).item()
    ref = numpy_objective(X.numpy(), la.exp().numpy(), lb.exp().numpy(), Y.numpy(), lengths, balanced)
    assert ours == pytest.approx(ref, rel=1e-11, abs=1e-9)


def test_objective_gradient_matches_finite_differences(small_case):
    X, la, lb, Y, lengths = small_case
    inputs = tuple(t.clone().requires_grad_(True) for t in (X, la, lb))
    assert torch.autograd.gradcheck(lambda X, a, b: gpdm_objective(X, a, b, Y, lengths, True), inputs,
                                    eps=1e-6, atol=1e-5, rtol=1e-4)


def test_W_closed_form_is_the_argmin_over_W(small_case):
    X, la, lb, Y, lengths = small_case

    def f(log_w):
        W = torch.tensor(np.exp(log_w), requires_grad=True)
        L = gpdm_objective(X, la, lb, Y, lengths, True, W=W)
        (g,) = torch.autograd.grad(L, W)
        return L.item(), (g * W).detach().numpy()

    numeric = np.exp(minimize(f, np.zeros(Y.shape[1]), jac=True, method="BFGS", options={"gtol": 1e-10}).x)
    N = Y.shape[0]
    K_Y = (lb[0].exp() * torch.exp(-lb[1].exp() / 2 * torch.cdist(X, X) ** 2) + torch.eye(N) / lb[2].exp())
    closed = torch.sqrt(N / ((Y * torch.linalg.solve(K_Y, Y)).sum(0) + KAPPA ** -2)).numpy()
    np.testing.assert_allclose(numeric, closed, rtol=1e-6)
    # And the objective without W (closed form inside) is that minimum.
    assert gpdm_objective(X, la, lb, Y, lengths, True).item() == pytest.approx(f(np.log(numeric))[0], rel=1e-12)


# ---- the fit and prediction -----------------------------------------------------------------

def test_fit_converges_to_a_stationary_point(model):
    summary = model.fit_summary
    assert summary["converged"], summary
    assert summary["iterations"] > 0 and np.isfinite(summary["objective"])
    assert model.recompute_objective() == pytest.approx(summary["objective"], rel=1e-9)
    assert model.objective == summary["objective"]
    assert model.kind == "bgpdm" and model.X.shape == (40, 3) and model.state_dim == 3


def test_reconstruction_interpolates_with_small_noise_and_variance_grows_away(model):
    # The fitted latents, a kernel short enough to interpolate (length scale 0.1) and small
    # noise (1e-8): μ_Y passes through the training poses and σ² is the noise there.
    log_beta = torch.log(torch.tensor([1.0, 100.0, 1e8], dtype=torch.float64))
    sharp = GPDM(model.space.angles, model.X, model.Y, model.mean_pose, model.lengths, model.log_alpha,
                 log_beta, True, model.fps)
    mu, var = sharp.reconstruct(sharp.X)
    torch.testing.assert_close(mu, sharp.Y + sharp.mean_pose, atol=1e-4, rtol=0)
    assert var.max() < 1e-6
    # Away from the data the variance grows towards β1 + 1/β3.
    direction = torch.tensor([1.0, 0.5, -0.5], dtype=torch.float64)
    ray = model.X[5] + torch.linspace(0, 10, 30, dtype=torch.float64)[:, None] * direction
    _, var_ray = model.reconstruct(ray)
    assert var_ray[-1] > 5 * var_ray[0] and var_ray[-1] > var_ray[10] > var_ray[0]
    assert var_ray[-1].item() == pytest.approx((model.beta[0] + 1 / model.beta[2]).item(), rel=1e-6)
    assert sharp.reconstruct(ray)[1][-1] > 1e6 * var.max()
    mu_d, var_d = model.dynamics(ray)
    assert mu_d.shape == (30, 3) and var_d[-1] > var_d[0]
    # The mean-only paths (no variance solve) give the same means.
    torch.testing.assert_close(model.pose_mean(ray), model.reconstruct(ray)[0], atol=0, rtol=0)
    torch.testing.assert_close(model.mean(ray), mu_d, atol=0, rtol=0)


def test_the_dynamics_noise_floor_bounds_the_fitted_noise(model):
    assert model.fit_summary["dynamics_noise_floor"] == 1e-4 and 1 / model.alpha[3] >= 1e-4 * (1 - 1e-12)
    loose = GPDM.fit(tiny_walks(), balanced=True, fps=15.0, dynamics_noise_floor=1e-2)
    assert loose.fit_summary["converged"] and loose.fit_summary["dynamics_noise_floor"] == 1e-2
    assert 1 / loose.alpha[3] >= 1e-2 * (1 - 1e-12) > 50 / model.alpha[3]
    assert loose.dynamics(loose.X_in)[1].min() >= 1e-2 * (1 - 1e-12)     # σ_X² holds the noise


def test_save_load_gives_identical_predictions(model, tmp_path):
    loaded = load_prior(model.save(tmp_path / "bgpdm.npz"))
    assert isinstance(loaded, GPDM) and loaded.kind == "bgpdm" and loaded.fit_summary == model.fit_summary
    x = model.X[::3] + 0.1
    for a, b in zip(model.reconstruct(x) + model.dynamics(x), loaded.reconstruct(x) + loaded.dynamics(x)):
        torch.testing.assert_close(a, b, atol=1e-12, rtol=0)
    torch.testing.assert_close(model.joints(x), loaded.joints(x), atol=1e-12, rtol=0)


def test_factors_do_not_depend_on_the_thread_count(model):
    """A model built (or loaded) on two threads has the factors, bit for bit, that it has on one:
    LAPACK's threaded Cholesky rounds by its thread count at a few hundred rows, so a model loaded
    in a worker of ``eval tracking --jobs`` would otherwise predict differently in the last digits
    (enough to move an L-BFGS path)."""
    g = torch.Generator().manual_seed(0)
    N = 400
    X = torch.randn(N, 3, generator=g, dtype=torch.float64)
    Y = torch.randn(N, model.D, generator=g, dtype=torch.float64)
    args = (model.space.angles, X, Y, model.mean_pose, [N // 2, N // 2], model.log_alpha, model.log_beta, True, 15.0)
    with torch_threads(1):
        one = GPDM(*args)
    with torch_threads(2):
        two = GPDM(*args)
    for name in ("L_Y", "A_Y", "W", "L_X", "A_X"):
        assert torch.equal(getattr(one, name), getattr(two, name)), name


def test_sample_is_seeded_and_matches_the_dynamics(model):
    x = model.X[[2, 15]]
    a = model.sample(x, torch.Generator().manual_seed(7))
    b = model.sample(x, torch.Generator().manual_seed(7))
    assert torch.equal(a, b)
    n = 20000
    draws = model.sample(x[:1].expand(n, -1).contiguous(), torch.Generator().manual_seed(1))
    mu, var = model.dynamics(x[:1])
    se = (var / n).sqrt()
    assert ((draws.mean(0) - mu[0]).abs() < 5 * se).all()
    assert ((draws.var(0) / var - 1).abs() < 5 * math.sqrt(2 / n)).all()
    # Annealed dynamics for the filters: variance σ_X²/λ in sample, log_prob and transition_covariance,
    # the learned dynamics and the model's arrays unchanged.
    hot = model.annealed(0.01)
    assert hot.X is model.X and model.annealing == 1.0
    draws = hot.sample(x[:1].expand(n, -1).contiguous(), torch.Generator().manual_seed(1))
    assert ((draws.var(0) / (var / 0.01) - 1).abs() < 5 * math.sqrt(2 / n)).all()
    torch.testing.assert_close(hot.transition_covariance(x[:1])[0], torch.eye(3, dtype=torch.float64) * var / 0.01)
    z = model.X[[3]]
    expected = torch.distributions.Normal(mu[0], (var / 0.01).sqrt()).log_prob(z[0]).sum()
    torch.testing.assert_close(hot.log_prob(z, x[:1])[0], expected)
    torch.testing.assert_close(hot.dynamics(x[:1])[1], var)
    with pytest.raises(PriortrackError, match=r"annealing must be in \(0, 1\]"):
        model.annealed(0.0)
    # float32 particles work and stay float32
    assert model.sample(x.float(), torch.Generator().manual_seed(7)).dtype == torch.float32
    assert model.mean(x.float()).dtype == torch.float32 and model.joints(x.float()).shape == (2, 15, 3)


def test_copies_of_a_row_share_its_transition_moments(model):
    """sample() evaluates μ_X and σ_X² once per run of equal consecutive rows (a resampled
    particle's copies): the draws equal μ_X(x) + σ_X(x) z computed row by row with the same
    normals, for rows with runs of copies, a copy after a different row, and none at all."""
    from priortrack.priors.gpdm import _runs
    from priortrack.randomness import standard_normal

    rows = model.X[[4, 4, 4, 9, 4, 4, 30, 31, 31]]
    first, run = _runs(rows)
    assert first.tolist() == [0, 3, 4, 6, 7] and run.tolist() == [0, 0, 0, 1, 2, 2, 3, 4, 4]
    assert torch.equal(rows[first][run], rows)
    for x in (rows, model.X[:7]):
        drawn = model.sample(x, torch.Generator().manual_seed(5))
        mu, var = model._transition(x)
        noise = standard_normal(mu.shape, torch.Generator().manual_seed(5), x)
        torch.testing.assert_close(drawn, mu + var.sqrt()[:, None] * noise, rtol=1e-12, atol=1e-12)


def test_variances_against_a_dense_solve_and_float32_means(model):
    """σ²(x) and σ_X²(x) (eq. 20 and the dynamics' analogue) against k(x, x) − k K⁻¹ kᵀ by a dense
    solve. The mean-only paths (pose_mean, mean) run in the rows' dtype: float32 rows give float32
    means within float32 rounding of the float64 ones; with the variance, everything is float64."""
    from priortrack.priors.gpdm import k_X, k_Y
    x = model.X[::4] + 0.05
    K_Y = k_Y(model.X, model.X, model.log_beta) + torch.eye(len(model.X), dtype=torch.float64) / model.beta[2]
    k = k_Y(x, model.X, model.log_beta)
    expected = model.beta[0] + 1 / model.beta[2] - (k * torch.linalg.solve(K_Y, k.T).T).sum(-1)
    # σ² is a difference of terms ~10⁴ times larger than itself
    torch.testing.assert_close(model.reconstruct(x)[1], expected, rtol=1e-7, atol=0)
    X_in = model.X_in
    K_X = k_X(X_in, X_in, model.log_alpha) + torch.eye(len(X_in), dtype=torch.float64) / model.alpha[3]
    k = k_X(x, X_in, model.log_alpha)
    expected = model.alpha[0] + model.alpha[2] * x.pow(2).sum(-1) + 1 / model.alpha[3] \
        - (k * torch.linalg.solve(K_X, k.T).T).sum(-1)
    torch.testing.assert_close(model.dynamics(x)[1], expected, rtol=1e-7, atol=0)
    x32 = x.float()
    mu_y, mu_x = model.pose_mean(x32), model.mean(x32)
    assert mu_y.dtype == mu_x.dtype == torch.float32
    # μ = k K⁻¹ Y sums terms far larger than itself (|K⁻¹ Y| reaches 10–100), so float32 rounds it
    # by about 1e-4: under 1e-3 rad of a pose angle and 5% of the transition's standard deviation.
    mu_y64, (mu_x64, var_x64) = model.pose_mean(x32.double()), model.dynamics(x32.double())
    assert float((mu_y.double() - mu_y64).abs().max()) < 1e-3
    assert float(((mu_x.double() - mu_x64).abs() / var_x64.sqrt()[:, None]).max()) < 0.05
    torch.testing.assert_close(model.reconstruct(x32)[0].double(), mu_y64, rtol=1e-6, atol=1e-6)


def test_predictions_in_row_blocks_equal_one_block(model, monkeypatch):
    """On the CPU, μ_Y, σ², μ_X and σ_X² of many rows are computed in blocks of BLOCK_ROWS rows
    (cache-sized): the same numbers as one block, with the rows in order and gradients through
    every block (the MAP tracker differentiates eq. 18)."""
    from priortrack.priors import gpdm
    x = (model.X[torch.arange(70) % len(model.X)] + 0.03 * torch.arange(70.0, dtype=torch.float64)[:, None] / 70)
    def predictions():
        return (*model.reconstruct(x), *model.dynamics(x), model.pose_mean(x.float()))

    whole = predictions()
    monkeypatch.setattr(gpdm, "BLOCK_ROWS", 16)
    for a, b in zip(whole, predictions(), strict=True):
        torch.testing.assert_close(b, a, rtol=1e-12, atol=1e-12)
    xg = x.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(model.reconstruction_energy(xg, model.pose_mean(x)).sum(), xg)
    monkeypatch.setattr(gpdm, "BLOCK_ROWS", 1024)
    xg1 = x.clone().requires_grad_(True)
    (grad1,) = torch.autograd.grad(model.reconstruction_energy(xg1, model.pose_mean(x)).sum(), xg1)
    torch.testing.assert_close(grad, grad1, rtol=1e-10, atol=1e-12)
    assert bool((grad.abs().sum(1) > 0).all())  # every block's rows have a gradient


def test_log_prob_is_the_gaussian_density_and_energies_agree(model):
    x, x_next = model.X[:5], model.X[1:6] + 0.01
    mu, var = model.dynamics(x)
    expected = torch.distributions.Normal(mu, var.sqrt()[:, None]).log_prob(x_next).sum(-1)
    torch.testing.assert_close(model.log_prob(x_next, x), expected)
    window = model.X[:4][:, None, :]                                   # (τ+1 = 4, P = 1, d)
    energy = model.dynamics_energy(window, annealing=0.5)
    torch.testing.assert_close(energy, -0.5 * model.log_prob(model.X[1:4], model.X[:3]).sum().reshape(1))
    # eq. 18 by hand
    y = model.Y[:3] + model.mean_pose + 0.01
    mu_y, var_y = model.reconstruct(model.X[:3])
    by_hand = (((y - mu_y) * model.W) ** 2).sum(-1) / (2 * var_y) + model.D / 2 * torch.log(var_y) \
        + 0.5 * model.X[:3].pow(2).sum(-1)
    torch.testing.assert_close(model.reconstruction_energy(model.X[:3], y), by_hand)


def test_contract_shapes_rollout_encode_and_grid(model, tmp_path):
    x0 = model.X[:2]
    path = model.rollout(x0, 5)
    assert path.shape == (6, 2, 3) and torch.equal(path[0], x0)
    torch.testing.assert_close(path[1], model.mean(x0))
    sampled = model.rollout(x0, 5, torch.Generator().manual_seed(0))
    assert sampled.shape == (6, 2, 3) and not torch.equal(sampled, path)
    assert model.initial(model.X[0], 10, torch.Generator().manual_seed(0)).shape == (10, 3)
    # encoding a training motion finds latents that reconstruct it about as well as the fit's own
    walk = tiny_walks()[0]
    x = model.encode(walk)
    err_encoded = (model.reconstruct(x)[0] - model.space.angles.encode(walk)).abs().mean()
    err_fit = (model.reconstruct(model.X[:20])[0] - model.space.angles.encode(walk)).abs().mean()
    assert x.shape == (20, 3) and err_encoded <= err_fit + 1e-6
    gx, gy, logvar = model.log_variance_grid(n=20)
    assert gx.shape == (20,) and gy.shape == (20,) and logvar.shape == (20, 20) and torch.isfinite(logvar).all()
    png = plot_latent(model, tmp_path / "latent.png")
    assert png.stat().st_size > 10_000
    with pytest.raises(PriortrackError, match=r"suffix must be one of .*\.pdf.*\.png"):
        plot_latent(model, tmp_path / "latent.txt")
    assert not (tmp_path / "latent.txt").exists()


# ---- balanced vs plain ----------------------------------------------------------------------

def _paths(model):
    return [model.X[s:e] for s, e in zip(np.cumsum([0] + model.lengths[:-1]), np.cumsum(model.lengths))]


def step_over_extent(model):
    """Mean consecutive latent step / latent extent (largest range over the latent dims)."""
    steps = torch.cat([(x[1:] - x[:-1]).norm(dim=1) for x in _paths(model)])
    return (steps.mean() / (model.X.max(0).values - model.X.min(0).values).max()).item()


def roughness(model):
    """Mean |second difference| / mean |first difference| of the latent paths."""
    paths = _paths(model)
    second = torch.cat([(x[2:] - 2 * x[1:-1] + x[:-2]).norm(dim=1) for x in paths])
    first = torch.cat([(x[1:] - x[:-1]).norm(dim=1) for x in paths])
    return (second.mean() / first.mean()).item()


def test_balanced_latent_paths_are_smoother_than_plain():
    walks = [load_walkjog().walks("train")[0][:60:2], load_bundled("cmu:07_01").resample(15.0)[:30]]
    balanced = GPDM.fit(walks, balanced=True, fps=15.0)
    plain = GPDM.fit(walks, balanced=False, fps=15.0)
    numbers = {name: (step_over_extent(m), roughness(m)) for name, m in (("balanced", balanced), ("plain", plain))}
    print("step/extent, roughness:", numbers)
    assert numbers["balanced"][0] < numbers["plain"][0]
    assert numbers["balanced"][1] < numbers["plain"][1]


# ---- fill-in --------------------------------------------------------------------------------

def test_spline_fill_error_against_a_hand_check():
    t = np.arange(50, dtype=float)
    y = np.stack([np.sin(t / 7), (t / 50) ** 3, np.cos(t / 5)], axis=1)
    missing = np.arange(5, 36)
    filled = fill_in.fill_spline(y, missing)
    # The cubic channel is reproduced exactly (not-a-knot spline through a cubic).
    np.testing.assert_allclose(filled[:, 1], y[missing, 1], atol=1e-12)
    # The error by hand: per missing frame, the RMS over channels, in degrees, then the mean.
    per_frame = [math.degrees(math.sqrt(sum((filled[i, c] - y[f, c]) ** 2 for c in range(3)) / 3))
                 for i, f in enumerate(missing)]
    assert fill_in.rms_degrees(filled, y[missing]) == pytest.approx(sum(per_frame) / len(per_frame), rel=1e-12)
    assert fill_in.rms_degrees(y[missing] + math.radians(2.0), y[missing]) == pytest.approx(2.0, rel=1e-12)


def test_fill_in_smoke_on_one_window(model):
    walk = load_walkjog().walks("train")[5]
    y = model.space.angles.encode(walk[:100:2]).numpy()               # 50 frames at 15 fps
    (a, missing), = fill_in.windows(len(y))[:1]
    assert a == 0 and missing[0] == 5 and len(missing) == 31
    train = [model.space.angles.encode(m).numpy() for m in tiny_walks()]
    short = np.concatenate([y[:3], y[-3:]])                           # a 6-frame window, 2 missing
    errors = {
        "spline": fill_in.rms_degrees(fill_in.fill_spline(y, missing), y[missing]),
        "gpdm": fill_in.rms_degrees(fill_in.fill_gpdm(model, y, missing), y[missing]),
        "knn": fill_in.rms_degrees(fill_in.fill_knn(short, np.array([2, 3]), train, k=3), short[[2, 3]]),
    }
    assert all(np.isfinite(v) and v > 0 for v in errors.values()), errors
    assert [w[0] for w in fill_in.windows(125)] == [(k * 75) // 11 for k in range(12)]


def test_the_papers_knn_is_least_squares_over_the_nearest_windows():
    """A window that is 0.3 A + 0.7 B of two training windows is filled exactly by the least-squares
    combination (the paper's KNN), not by the average (our window-KNN)."""
    rng = np.random.default_rng(0)
    A, B, C = (rng.normal(size=(12, 4)) for _ in range(3))
    y = 0.3 * A + 0.7 * B
    missing = np.arange(3, 9)
    filled = fill_in.fill_knn_least_squares(y, missing, [A, B, C], k=3)
    np.testing.assert_allclose(filled, y[missing], atol=1e-10)
    assert np.abs(fill_in.fill_knn(y, missing, [A, B, C], k=2) - y[missing]).max() > 0.1


def test_fill_floor_recovers_poses_between_training_frames(model):
    # Poses on the model's manifold between training frames: the floor (each pose's own eq.-18
    # latent, then μ_Y) reproduces them far better than the nearest training pose does.
    x = 0.5 * (model.X[:-1] + model.X[1:])[::2]
    y = model.reconstruct(x)[0].numpy()
    nearest = torch.cdist(torch.as_tensor(y) - model.mean_pose, model.Y).argmin(dim=1)
    nearest_error = fill_in.rms_degrees((model.Y[nearest] + model.mean_pose).numpy(), y)
    floor_error = fill_in.rms_degrees(fill_in.fill_floor(model, y), y)
    assert floor_error < 0.5 < 1.0 < nearest_error, (floor_error, nearest_error)


def test_torch_threads_is_scoped():
    before = torch.get_num_threads()
    with pytest.raises(RuntimeError), torch_threads(1):
        assert torch.get_num_threads() == 1
        raise RuntimeError
    assert torch.get_num_threads() == before


# ---- bad input ------------------------------------------------------------------------------

def test_bad_input_raises(model):
    walks = tiny_walks()
    with pytest.raises(PriortrackError, match="at least 10"):
        GPDM.fit([walks[0][:4], walks[1][:4]], fps=15.0)
    with pytest.raises(PriortrackError, match="at least 3"):
        GPDM.fit([walks[0], walks[1][:2]], fps=15.0)
    with pytest.raises(PriortrackError, match="latent dimension"):
        GPDM.fit(walks, d=0, fps=15.0)
    D = len(AngleSpace.fit(walks).channels)
    with pytest.raises(PriortrackError, match="latent dimension"):
        GPDM.fit(walks, d=D, fps=15.0)
    for floor in (0.0, 1.0, float("nan"), "1e-3"):
        with pytest.raises(PriortrackError, match="dynamics_noise_floor"):
            GPDM.fit(walks, fps=15.0, dynamics_noise_floor=floor)
    bad = walks[0].channels.copy()
    bad[3, 10] = np.nan
    with pytest.raises(PriortrackError, match="NaN"):
        GPDM.fit([type(walks[0])(walks[0].skeleton, bad, 15.0, "bad"), walks[1]], fps=15.0)
    with pytest.raises(PriortrackError, match="shape"):
        model.sample(torch.zeros(4, 2, dtype=torch.float64), torch.Generator().manual_seed(0))
    with pytest.raises(PriortrackError, match="shape"):
        model.log_prob(torch.zeros(4, 3), torch.zeros(4, 4))
    with pytest.raises(PriortrackError, match="x_next has 4 rows and x 3"):
        model.log_prob(torch.zeros(4, 3), torch.zeros(3, 3))
    with pytest.raises(PriortrackError, match="NaN"):
        model.mean(torch.full((2, 3), float("nan")))
    with pytest.raises(PriortrackError, match="shape"):
        model.dynamics_energy(torch.zeros(3, 3))
    with pytest.raises(PriortrackError, match="shape"):
        model.reconstruction_energy(torch.zeros(2, 3), torch.zeros(2, 5))
