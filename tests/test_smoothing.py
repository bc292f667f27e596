"""Smoothing (issue 22): the unscented RTS smoother against the Kalman RTS smoother, backward
simulation against it too, NEES of smoothed estimates in their χ² band, fixed lag against the
whole-run smoother of the truncated run, and smoothing through a blackout on held-out walks."""

import numpy as np
import pytest
import torch
from scipy.stats import chi2

from linear_gaussian import LinearGaussian, kalman_rts
from priortrack import PriortrackError
from priortrack.filters.backward_simulation import backward_indices
from priortrack.filters.particle import ParticleFilter
from priortrack.filters.posterior_linearisation import posterior_linearisation
from priortrack.filters.smoothing import smooth
from priortrack.filters.step_store import StepStore, step_bytes
from priortrack.filters.ukf import ManifoldSigmaPoints, UnscentedFilter
from priortrack.filters.unscented_rts import unscented_rts

A = [[1, 1.0, 0], [0, 1, 0], [0, 0, 0.9]]
Q, H, R = np.diag([0.01, 0.04, 0.09]), [[1.0, 0, 0], [0, 0, 1.0]], np.diag([0.25, 0.16])
M0, P0 = np.zeros(3), np.diag([1.0, 0.5, 0.5])
STEPS = 20


def _simulate(seed: int, gap=slice(6, 11)) -> tuple[np.ndarray, np.ndarray]:
    """(STEPS, 3) true states after x_0 ~ N(M0, P0), and (STEPS, 2) observations, missing in ``gap``."""
    rng = np.random.default_rng(seed)
    x, truth, zs = rng.multivariate_normal(M0, P0), [], []
    for _ in range(STEPS):
        x = np.asarray(A) @ x + rng.multivariate_normal(np.zeros(3), Q)
        truth.append(x)
        zs.append(np.asarray(H) @ x + rng.multivariate_normal(np.zeros(2), R))
    zs = np.array(zs)
    zs[gap] = np.nan
    return np.array(truth), zs


def _unscented(model, zs):
    ukf = UnscentedFilter(model, gate_probability=0)
    ukf.initialise_states(M0, P0)
    snapshots = [ukf.step(z) for z in zs]
    filtered = [s.mean.numpy() for s in snapshots], [s.covariance.numpy() for s in snapshots]
    return filtered, unscented_rts(ukf.unscented, ukf.kf.points_fn, *filtered)


def test_the_unscented_rts_smoother_is_the_kalman_rts_smoother_on_a_linear_model():
    model = LinearGaussian(A, Q, H, R)
    _, zs = _simulate(0)
    (filtered_means, filtered_covariances), (means, covariances) = _unscented(model, zs)
    reference_means, reference_covariances = kalman_rts(model, M0, P0, zs)
    assert np.abs(np.array(means) - reference_means).max() < 1e-8
    assert np.abs(np.array(covariances) - reference_covariances).max() < 1e-8
    # the smoothed variance is never above the filtered one: P_filtered − P_smoothed ⪰ 0
    for P_f, P_s in zip(filtered_covariances, covariances):
        assert np.linalg.eigvalsh(P_f - P_s).min() > -1e-12
    # and only the last frame has nothing after it
    assert np.trace(filtered_covariances[8] - covariances[8]) > 0.1 * np.trace(filtered_covariances[8])


@pytest.mark.parametrize("iterations", [1, 3])
def test_posterior_linearisation_is_the_kalman_rts_smoother_on_a_linear_model(iterations):
    """Its regressions of a linear f and h are exact (no linearisation error): each iteration returns
    the RTS smoother's means and covariances, whatever the sigma points' spread."""
    model = LinearGaussian(A, Q, H, R)
    _, zs = _simulate(0)
    ukf = UnscentedFilter(model, gate_probability=0)
    ukf.initialise_states(M0, P0)
    snapshots = [ukf.step(z) for z in zs]
    filtered = [s.mean.numpy() for s in snapshots], [s.covariance.numpy() for s in snapshots]
    means, covariances = posterior_linearisation(ukf.unscented, ManifoldSigmaPoints(ukf.unscented, 0.1, 2.0, 0.0),
                                                 *filtered, zs, iterations)
    reference_means, reference_covariances = kalman_rts(model, M0, P0, zs)
    assert np.abs(np.array(means) - reference_means).max() < 1e-8
    assert np.abs(np.array(covariances) - reference_covariances).max() < 1e-8
    with pytest.raises(PriortrackError, match="iterations must be"):
        posterior_linearisation(ukf.unscented, ukf.kf.points_fn, *filtered, zs, -1)
    with pytest.raises(PriortrackError, match="19 frames of data for 20 filtered frames"):
        posterior_linearisation(ukf.unscented, ukf.kf.points_fn, *filtered, zs[1:])


def test_posterior_linearisation_smooths_the_data_the_filter_updated_with():
    """A 30σ outlier the filter's validation gate holds out: given the filter's decisions (its steps'
    ``held_out``) the smoother's means are those of the same data with that point missing, which is the
    Kalman RTS smoother's of it; given every pixel instead, the outlier pulls the smoothed means off."""
    model = LinearGaussian(A, Q, H, R)
    _, zs = _simulate(3)
    zs[14, 0] += 15.0
    ukf = UnscentedFilter(model)
    ukf.initialise_states(M0, P0)
    snapshots = [ukf.step(z) for z in zs]
    assert [t for t, s in enumerate(snapshots) if s.held_out is not None and s.held_out.any()] == [14]
    assert snapshots[14].held_out.tolist() == [True, False]
    filtered = [s.mean.numpy() for s in snapshots], [s.covariance.numpy() for s in snapshots]
    points = ManifoldSigmaPoints(ukf.unscented, 0.1, 2.0, 0.0)
    means, _ = posterior_linearisation(ukf.unscented, points, *filtered, zs,
                                       held_out=[s.held_out for s in snapshots], swapped=[None] * STEPS)
    missing = zs.copy()
    missing[14, 0] = np.nan
    reference, _ = kalman_rts(model, M0, P0, missing)
    assert np.abs(np.array(means) - reference).max() < 1e-8
    pulled, _ = posterior_linearisation(ukf.unscented, points, *filtered, zs)
    assert np.abs(np.array(pulled) - reference).max() > 0.5


def _sigma_cloud(m: np.ndarray, P: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """2n equally weighted points m ± √n L_j (L L^T = P): a cloud whose mean and covariance are exactly (m, P)."""
    offsets = np.sqrt(len(m)) * np.linalg.cholesky(P).T
    return torch.as_tensor(np.concatenate([m + offsets, m - offsets])), torch.full((2 * len(m),), 7.0, dtype=torch.float64)


def test_the_cloud_smoother_is_the_kalman_rts_smoother_on_clouds_of_the_kalman_filters_gaussians():
    """Clouds whose moments are the Kalman filter's (weights of any scale): their Gaussians are those moments and
    the unscented RTS over them is the Kalman RTS smoother, to rounding."""
    from linear_gaussian import kalman
    from priortrack.filters.cloud_smoother import cloud_gaussian, cloud_rts

    model = LinearGaussian(A, Q, H, R)
    _, zs = _simulate(0)
    filtered = [kalman(model, M0, P0, zs[:t + 1]) for t in range(STEPS)]
    clouds = [_sigma_cloud(m, P) for m, P in filtered]
    m, P = cloud_gaussian(model, *clouds[3])
    np.testing.assert_allclose(m, filtered[3][0], atol=1e-12)
    np.testing.assert_allclose(P, filtered[3][1], atol=1e-12)
    means, covariances = cloud_rts(model, *zip(*clouds), [None] * STEPS)
    reference_means, reference_covariances = kalman_rts(model, M0, P0, zs)
    assert np.abs(np.array(means) - reference_means).max() < 1e-8
    assert np.abs(covariances[:] - reference_covariances).max() < 1e-8


@pytest.fixture(scope="module")
def linear_particle_run():
    """The linear model, its observations (gap 6–10) and a 2,000-particle filter's steps through them."""
    model = LinearGaussian(A, Q, H, R)
    _, zs = _simulate(0)
    pf = ParticleFilter(model, 2000, seed=1)
    generator = torch.Generator().manual_seed(2)
    pf.initialise_states(torch.as_tensor(M0) + torch.randn((2000, 3), generator=generator, dtype=torch.float64)
                         @ torch.linalg.cholesky(torch.as_tensor(P0)).T)
    return model, zs, [pf.step(z) for z in zs]


def test_the_cloud_smoother_of_a_particle_filter_is_near_the_kalman_rts_smoother(linear_particle_run):
    """A 2,000-particle filter on the linear model, its clouds smoothed as Gaussians: the smoothed means 0.13 σ on
    average from the RTS means when measured (0.57 σ at most; the filter's own means 1.4 σ), the smoothed σ 0.99
    of the RTS σ on average."""
    from priortrack.filters.cloud_smoother import cloud_rts

    model, zs, snapshots = linear_particle_run
    means, covariances = cloud_rts(model, [s.particles for s in snapshots], [s.weights for s in snapshots],
                                   [None] * STEPS)
    reference_means, reference_covariances = kalman_rts(model, M0, P0, zs)
    sigma = np.sqrt(np.diagonal(reference_covariances, axis1=1, axis2=2))
    off = np.abs(np.array(means) - reference_means) / sigma
    assert off.mean() < 0.3 and off.max() < 1.0
    ratio = np.sqrt(np.diagonal(covariances[:], axis1=1, axis2=2)) / sigma
    assert 0.8 < ratio.mean() < 1.2


def test_smoothed_estimates_are_consistent():
    """NEES of the smoothed means over 100 runs: each step's run-average in the two-sided 99 % χ²(3 · 100)
    band on at least 90 % of the steps."""
    model = LinearGaussian(A, Q, H, R)
    runs = 100
    nees = np.zeros((runs, STEPS))
    for r in range(runs):
        truth, zs = _simulate(1000 + r)
        _, (means, covariances) = _unscented(model, zs)
        for t in range(STEPS):
            e = truth[t] - means[t]
            nees[r, t] = e @ np.linalg.solve(covariances[t], e)
    low, high = chi2.ppf([0.005, 0.995], 3 * runs) / runs
    averages = nees.mean(axis=0)
    assert np.mean((averages >= low) & (averages <= high)) >= 0.9


@pytest.mark.parametrize("moves", [None, 0, 10])
def test_backward_simulation_draws_the_smoothing_distribution(moves, linear_particle_run):
    """500 trajectories drawn from a 2,000-particle filter, exactly (None) or by the MCMC kernel from
    the genealogy (0 or 10 moves): their mean 0.17, 0.33, 0.22 σ on average from the RTS mean (at most
    0.9–1.3 σ; the filter's own mean is 1.4 σ away on average, 7 σ at most, inside and after the gap),
    their spread within 20 % of the RTS σ."""
    model, zs, snapshots = linear_particle_run
    indices = backward_indices(model.log_transition, [s.particles for s in snapshots],
                               [torch.log(s.weights) for s in snapshots], 500, torch.Generator().manual_seed(3),
                               None if moves is None else [s.ancestors for s in snapshots], moves or 0)
    trajectories = torch.stack([s.particles[i] for s, i in zip(snapshots, indices)], 1).numpy()
    means, covariances = kalman_rts(model, M0, P0, zs)
    sigma = np.sqrt(np.diagonal(covariances, axis1=1, axis2=2))
    filtered = np.array([(s.weights[:, None] * s.particles).sum(0).numpy() for s in snapshots])
    off, filtered_off = np.abs(trajectories.mean(0) - means) / sigma, np.abs(filtered - means) / sigma
    assert off.mean() < 0.35 and off.max() < 1.5
    assert filtered_off.mean() > 3 * off.mean()
    assert 0.8 < (trajectories.std(0) / sigma).mean() < 1.2


def _tracked(preset, scenario, tmp_path, frames=None):
    from priortrack.experiments.tracking import track

    run = track("cmu:07_10", preset, scenario, seed=0, frames=frames, keep_snapshots=True, cache=tmp_path)
    return run


def _filter(preset, run, tmp_path):
    from priortrack.tracking.presets import load_preset

    filt = load_preset(preset).build(run.observations.camera, seed=0, cache=tmp_path)
    return filt, filt.run(run.observations.uv, run.motion, keep_snapshots=True)


@pytest.mark.parametrize("preset", ["ukf-gpdm", "pf-gpdm"])
def test_smoothing_through_a_blackout_on_a_held_out_walk(preset, tmp_path):
    """07_10 is not in the GPDM's training walks. Through a one-gait-cycle blackout the smoothed
    joints are nearer the truth than the filtered ones (ukf-gpdm 0.70×, pf-gpdm 0.69× over the run,
    measured), and their spread is finite and positive."""
    from priortrack.body.fk import joint_positions

    run = _tracked(preset, "blackout:sigma_px=5", tmp_path)
    filt, track = _filter(preset, run, tmp_path)
    smoothed = smooth(filt, track, run.observations.uv)
    truth = joint_positions(run.motion, "eval15")
    error = {name: np.linalg.norm(e - truth, axis=-1).mean() for name, e in
             (("filtered", track.estimates), ("smoothed", smoothed.estimates))}
    assert error["smoothed"] < 0.8 * error["filtered"]
    assert np.isfinite(smoothed.spread).all() and smoothed.spread[2:].mean() > 0.001


def test_fixed_lag_releases_the_whole_run_smoother_of_the_frames_so_far(tmp_path):
    """The unscented smoother's estimate of frame t − L released at frame t uses nothing after t: it is
    the same when the run is cut at t; lag 0 is the filter; a lag past the end is the whole-run smoother.
    (It is not the whole-run smoother of the cut run: the posterior linearisation relinearises the
    window only, from the filter's posterior at its first frame.)"""
    from priortrack.filters.snapshot import KNOWN_FRAMES, Track

    run = _tracked("ukf-gpdm", "occlusion:sigma_px=5", tmp_path, frames=30)
    filt, track = _filter("ukf-gpdm", run, tmp_path)
    z = run.observations.uv
    lagged = smooth(filt, track, z, lag=4)
    for t in (10, 20):
        cut = Track(track.estimates[:t + 1], track.ess[:t + 1], track.flags[:t + 1], 0.0,
                    track.snapshots[:t + 1 - KNOWN_FRAMES])
        assert np.allclose(lagged.estimates[t - 4], smooth(filt, cut, z[:t + 1], lag=4).estimates[t - 4], atol=1e-9)
    assert np.allclose(smooth(filt, track, z, lag=0).estimates, track.estimates, atol=1e-9)
    assert np.allclose(smooth(filt, track, z, lag=100).estimates, smooth(filt, track, z).estimates)


def test_fixed_lag_smoothing_as_the_filter_runs(tmp_path):
    """A FixedLagSmoother fed by the run's on_step (pf-gpdm, lag 3), holding the last L + 1 steps only,
    releases what each window t − L … t smoothed from the run's kept steps gives, drawn in the same order
    from a generator of the same seed: the first frame of every window, then the rest of the last one."""
    from priortrack.filters.smoothing import MOVES, FixedLagSmoother
    from priortrack.filters.snapshot import KNOWN_FRAMES

    run = _tracked("pf-gpdm", "occlusion:sigma_px=5", tmp_path, frames=16)
    filt, _ = _filter("pf-gpdm", run, tmp_path)
    z = run.observations.uv
    online = FixedLagSmoother(filt, 3, trajectories=20, seed=5)
    track = filt.run(z, run.motion, keep_snapshots=True, on_step=lambda s: online.push(s, z[s.frame]))
    assert len(online.window) == 4
    lagged = online.result(track.estimates[:KNOWN_FRAMES])
    generator = torch.Generator().manual_seed(5)
    steps, data = track.snapshots, z[KNOWN_FRAMES:]
    windows = [filt.smooth_window(steps[t - 3:t + 1], data[t - 3:t + 1], generator, trajectories=20, moves=MOVES)
               for t in range(3, len(steps))]
    expected = np.concatenate([w[0][:1] for w in windows] + [windows[-1][0][1:]])
    assert np.allclose(lagged.estimates[KNOWN_FRAMES:], expected, atol=1e-12)
    assert np.array_equal(lagged.estimates, smooth(filt, track, z, trajectories=20, lag=3, seed=5).estimates)


def test_a_run_keeps_every_kth_snapshot_and_every_steps_record(tmp_path):
    run = _tracked("pf-gpdm", "clean", tmp_path, frames=12)
    filt, _ = _filter("pf-gpdm", run, tmp_path)
    seen = []
    track = filt.run(run.observations.uv, run.motion, keep_snapshots=True, snapshot_every=4, on_step=seen.append)
    assert filt.run(run.observations.uv, run.motion).snapshots is None
    assert [s.frame for s in track.snapshots] == [2, 6, 10] and [s.frame for s in seen] == list(range(2, 12))
    assert [r.frame for r in track.steps] == list(range(2, 12)) and all(r.points == 1000 for r in track.steps)
    assert [r.resampled for r in track.steps] == [s.ancestors is not None for s in seen]
    with pytest.raises(PriortrackError, match="snapshot_every must be"):
        filt.run(run.observations.uv, run.motion, keep_snapshots=True, snapshot_every=0)


@pytest.mark.parametrize("preset", ["pf-gpdm", "ukf-gpdm"])
def test_the_whole_run_smoother_needs_only_the_compact_steps(preset, tmp_path):
    """Snapshot.for_smoothing keeps what a smoother reads (no joints; a Gaussian filter's mean and
    covariance only): the whole run smoothed from those is the same to the bit."""
    from dataclasses import replace

    run = _tracked(preset, "occlusion:sigma_px=5", tmp_path, frames=14)
    filt, track = _filter(preset, run, tmp_path)
    compact = [s.for_smoothing() for s in track.snapshots]
    assert all(s.joints is None for s in compact)
    assert all((s.particles is None) == (preset == "ukf-gpdm") for s in compact)
    z = run.observations.uv
    full, lean = smooth(filt, track, z, trajectories=20), smooth(filt, replace(track, snapshots=compact), z, trajectories=20)
    np.testing.assert_array_equal(full.estimates, lean.estimates)
    np.testing.assert_array_equal(full.spread, lean.spread)
    # … and from a StepStore that spilled all but the first steps to disk (read back a frame at a time)
    store = StepStore(memory=3 * step_bytes(compact[0]))
    for snapshot in track.snapshots:
        store.append(snapshot)
    assert store.spilled == len(compact) - 3
    spilled = smooth(filt, replace(track, snapshots=store), z, trajectories=20)
    store.close()
    np.testing.assert_array_equal(full.estimates, spilled.estimates)
    np.testing.assert_array_equal(full.spread, spilled.spread)


def test_what_cannot_be_smoothed_says_why(tmp_path):
    run = _tracked("ukf-gpdm", "clean", tmp_path, frames=8)
    filt, track = _filter("ukf-gpdm", run, tmp_path)
    z = run.observations.uv
    with pytest.raises(PriortrackError, match="keep_snapshots=True"):
        smooth(filt, filt.run(z, run.motion), z)
    with pytest.raises(PriortrackError, match="lag must be"):
        smooth(filt, track, z, lag=-1)
    with pytest.raises(PriortrackError, match="trajectories must be"):
        smooth(filt, track, z, trajectories=0)
    with pytest.raises(PriortrackError, match="7 frames of observations for a run of 8"):
        smooth(filt, track, z[:7])
    with pytest.raises(PriortrackError, match="a particle smoother is one of gaussian, backward, got 'rts'"):
        smooth(filt, track, z, method="rts")
    apf, apf_track = _filter("apf-diffusion-local", run, tmp_path)
    with pytest.raises(PriortrackError, match="tempered"):
        smooth(apf, apf_track, z)
    tracker, tracker_track = _filter("map-gpdm", run, tmp_path)
    with pytest.raises(PriortrackError, match="MapTracker has no smoother"):
        smooth(tracker, tracker_track, z)


def test_the_unscented_smoother_works_a_block_of_frames_at_a_time(monkeypatch):
    """Posterior linearisation and the smoothed joints propagate FRAMES_AT_ONCE frames' sigma points at a
    time (a 10-minute recording's 18,000 × 125 at once took gigabytes): blocks of 7 frames give the whole
    run's numbers to rounding (measured 1.8e-12 m)."""
    from priortrack.experiments.tracking import track
    from priortrack.filters import posterior_linearisation

    whole = track("walkjog:35_29", "ukf-gpdm", "blackout:sigma_px=5", frames=60, smooth=True).smoothed
    monkeypatch.setattr(posterior_linearisation, "FRAMES_AT_ONCE", 7)
    blocks = track("walkjog:35_29", "ukf-gpdm", "blackout:sigma_px=5", frames=60, smooth=True).smoothed
    np.testing.assert_allclose(blocks.estimates, whole.estimates, rtol=0, atol=1e-9)
    np.testing.assert_allclose(blocks.spread, whole.spread, rtol=0, atol=1e-9)
