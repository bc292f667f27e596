"""Filter consistency over many runs on a linear-Gaussian model (issue 21, item 12): the normalised
estimation error squared (NEES) of the particle and unscented filters, and the normalised innovation
squared (NIS) of the unscented filter, within their χ² bands.

For R independent runs, at each step the run-average of NEES = eᵀ P⁻¹ e (e the true state minus
the estimate, P the filter's covariance) times R is χ²(nR) if the filter is consistent, and the
run-average of NIS = νᵀ S⁻¹ ν times R is χ²(mR). A step's average is accepted inside the two-sided 99 %
band; at least 90 % of the steps must be (a few fall outside by chance, an inconsistent filter
leaves most outside).
"""

import numpy as np
import pytest
import torch
from scipy.stats import chi2

from linear_gaussian import LinearGaussian
from priortrack.filters.particle import ParticleFilter
from priortrack.filters.ukf import UnscentedFilter

RUNS, STEPS = 60, 15
A = [[1, 1.0, 0], [0, 1, 0], [0, 0, 0.9]]
Q, H, R = np.diag([0.01, 0.04, 0.09]), [[1.0, 0, 0], [0, 0, 1.0]], np.diag([0.25, 0.16])
M0, P0 = np.zeros(3), np.diag([1.0, 0.5, 0.5])


def _simulate(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(STEPS + 1, 3) true states from x_0 ~ N(M0, P0) and (STEPS, 2) observations."""
    rng = np.random.default_rng(seed)
    x = [rng.multivariate_normal(M0, P0)]
    zs = []
    for _ in range(STEPS):
        x.append(np.asarray(A) @ x[-1] + rng.multivariate_normal(np.zeros(3), Q))
        zs.append(np.asarray(H) @ x[-1] + rng.multivariate_normal(np.zeros(2), R))
    return np.array(x), np.array(zs)


def _within_band(averages: np.ndarray, dof: int) -> float:
    low, high = chi2.ppf([0.005, 0.995], dof * RUNS) / RUNS
    return float(np.mean((averages >= low) & (averages <= high)))


@pytest.mark.parametrize("assumed_R, consistent", [(1.0, True), (0.1, False)])
def test_the_unscented_filter_is_consistent(assumed_R, consistent):
    """The filter as modelled is consistent; told the noise is 10× smaller than it is, it is not (the
    test's power)."""
    model = LinearGaussian(A, Q, H, assumed_R * R)
    nees, nis = np.zeros((RUNS, STEPS)), np.zeros((RUNS, STEPS))
    for r in range(RUNS):
        truth, zs = _simulate(r)
        ukf = UnscentedFilter(model)
        ukf.initialise_states(M0, P0)
        for t, z in enumerate(zs):
            snapshot = ukf.step(z)
            e = truth[t + 1] - snapshot.mean.numpy()
            nees[r, t] = e @ np.linalg.solve(snapshot.covariance.numpy(), e)
            nis[r, t] = ukf.kf.y @ np.linalg.solve(ukf.kf.S, ukf.kf.y)
    if consistent:
        assert _within_band(nees.mean(axis=0), 3) >= 0.9 and _within_band(nis.mean(axis=0), 2) >= 0.9
    else:
        assert _within_band(nees.mean(axis=0), 3) < 0.5 and _within_band(nis.mean(axis=0), 2) < 0.5


def test_the_particle_filter_is_consistent():
    """NEES of the weighted particle mean and covariance (2,000 particles, resampling at ESS < P/2)."""
    model = LinearGaussian(A, Q, H, R)
    nees = np.zeros((RUNS, STEPS))
    for r in range(RUNS):
        truth, zs = _simulate(r)
        pf = ParticleFilter(model, 2000, seed=100 + r)
        generator = torch.Generator().manual_seed(200 + r)
        start = torch.as_tensor(M0) + torch.randn((2000, 3), generator=generator, dtype=torch.float64) @ \
            torch.linalg.cholesky(torch.as_tensor(P0)).T
        pf.initialise_states(start)
        for t, z in enumerate(zs):
            snapshot = pf.step(z)
            w = snapshot.weights.double() / snapshot.weights.sum()
            mean = w @ snapshot.particles.double()
            centred = snapshot.particles.double() - mean
            covariance = (centred * w[:, None]).T @ centred
            e = truth[t + 1] - mean.numpy()
            nees[r, t] = e @ np.linalg.solve(covariance.numpy(), e)
    assert _within_band(nees.mean(axis=0), 3) >= 0.9


@pytest.mark.parametrize("noise_scale, consistent", [(1.0, True), (4.0, False)])
def test_the_unscented_filter_is_consistent_on_the_tracking_model(tmp_path, noise_scale, consistent):
    """NEES of the UKF on the full tracking model (ukf-diffusion-local: joint angles, translation,
    rotations; pinhole projection), against truth simulated from that model itself: s_0 ~ N(s̄_0,
    P_0) in tangent coordinates, s_t drawn by the model's own transition, the preset's σ_px noise on
    the projections (n = 62 tangent coordinates). With 4× the noise the filter assumes, it is not
    consistent (the test's power)."""
    from priortrack.data.bundled import load_bundled
    from priortrack.tracking.presets import load_preset
    from priortrack.observation.synthetic import default_camera
    from priortrack.body.fk import joint_positions

    motion = load_bundled("cmu:07_10")[:10]
    camera = default_camera(joint_positions(motion, "eval15"))
    ukf = load_preset("ukf-diffusion-local").build(camera, seed=0, cache=tmp_path)
    model, unscented = ukf.model, ukf.unscented
    sigma_px = noise_scale * float(model.likelihood.sigma_px)
    s0 = model.initial_states(motion, 1, torch.Generator())[0]
    P0 = unscented.process_covariance(s0)
    L0 = torch.linalg.cholesky(P0)
    runs, steps, n = 40, 12, unscented.tangent_dim
    nees = np.zeros((runs, steps))
    for r in range(runs):
        generator = torch.Generator().manual_seed(r)
        s = unscented.boxplus(s0[None], (L0 @ torch.randn(n, generator=generator, dtype=torch.float64))[None])
        ukf.initialise_states(s0, P0)
        for t in range(steps):
            s = model.predict(s, generator)
            uv = model.likelihood.pixels(model.observe(s))[0].reshape(-1, 2)
            z = uv + sigma_px * torch.randn(uv.shape, generator=generator, dtype=torch.float64)
            snapshot = ukf.step(z.numpy())
            e = unscented.boxminus(s, snapshot.mean)[0].numpy()
            nees[r, t] = e @ np.linalg.solve(snapshot.covariance.numpy(), e)
    low, high = chi2.ppf([0.005, 0.995], n * runs) / runs
    averages = nees.mean(axis=0)
    assert n == 62
    assert (np.mean((averages >= low) & (averages <= high)) >= 0.9) == consistent


@pytest.mark.parametrize("particles, consistent", [(20_000, True), (1_000, False)])
def test_the_particle_filter_is_consistent_on_the_tracking_model(tmp_path, particles, consistent):
    """NEES of the particle filter on a full tracking model (pf-gpdm's: GPDM latent x ∈ R³ and the
    placement g_t, the translation sampled) against truth simulated from that model: 20,000
    particles stay in the χ² band; 1,000 drift above it within ten frames (their weighted covariance
    understates the error: sample impoverishment, the test's power). Measured: 7.6–10.0 against the
    band [7.1, 11.1] with 20,000; up to 23 with 1,000."""
    from dataclasses import replace

    from priortrack.body.fk import joint_positions
    from priortrack.data.bundled import load_bundled
    from priortrack.tracking.presets import load_preset
    from priortrack.observation.synthetic import default_camera

    motion = load_bundled("cmu:07_10")[:10]
    camera = default_camera(joint_positions(motion, "eval15"))
    preset = load_preset("pf-gpdm")
    preset = replace(preset, filter_options={**preset.filter_options, "translation": "sampled",
                                             "particles": particles, "dtype": "float64"})
    pf = preset.build(camera, seed=0, cache=tmp_path)
    model = pf.model
    sigma_px = float(model.likelihood.sigma_px)
    runs, steps, n = 30, 10, model.pose_dim + 6
    nees = np.zeros((runs, steps))
    for r in range(runs):
        generator = torch.Generator().manual_seed(r)
        start = model.initial_states(motion, particles, generator).double()
        s = start[torch.randint(particles, (1,), generator=generator)]            # the truth: one of the start's draws
        pf.generator.manual_seed(100 + r)
        pf.initialise_states(start)
        for t in range(steps):
            s = model.predict(s, generator)
            uv = model.likelihood.pixels(model.observe(s))[0].reshape(-1, 2)
            snapshot = pf.step((uv + sigma_px * torch.randn(uv.shape, generator=generator, dtype=torch.float64)).numpy())
            w = snapshot.weights.double() / snapshot.weights.double().sum()
            X = snapshot.particles.double()[:, :n]                                 # x and g_t = (t, ω)
            mean = w @ X
            covariance = ((X - mean) * w[:, None]).T @ (X - mean)
            e = (s[0, :n] - mean).numpy()
            nees[r, t] = e @ np.linalg.solve(covariance.numpy(), e)
    low, high = chi2.ppf([0.005, 0.995], n * runs) / runs
    averages = nees.mean(axis=0)
    assert n == 9
    if consistent:
        assert np.mean((averages >= low) & (averages <= high)) >= 0.9
    else:
        assert averages[-3:].min() > high
