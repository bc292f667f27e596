"""The sliding-window MAP tracker (GPDM prior): eq. 21 against a direct evaluation, tracking a
walk from noisy 2D joints, a total occlusion carried by the prediction, and bad input."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from priortrack import PriortrackError, load_walkjog
from priortrack.data.motion import Motion
from priortrack.experiments.metrics import mpjpe, mpjpe_root_relative
from priortrack.filters.map_tracker import MapTracker
from priortrack.threads import torch_threads
from priortrack.models.tracking import TrackingModel
from priortrack.observation import default_camera, synthesize
from priortrack.observation.likelihood import JointLikelihood
from priortrack.priors import GPDM, Diffusion
from priortrack.priors.global_motion import to_world
from priortrack.body.fk import joint_positions

FPS = 15.0
SIGMA_PX = 5.0
FRAMES = 20                      # tracked clip: frames 0, 1 known, 18 tracked
BLACKOUT = (5, 15)               # frames [5, 15) see nothing: 10 frames, 0.67 s
ITERATIONS = 10                  # L-BFGS-B iterations per minimisation (tests stay fast)


def at_15fps(motion: Motion, frames: int) -> Motion:
    """Every other frame of a 30-fps clip, relabelled 15 fps (no resampling arithmetic)."""
    return Motion(motion.skeleton, motion.channels[:2 * frames:2], FPS, motion.name)


@pytest.fixture(scope="module")
def setting():
    """A B-GPDM of two short subject-35 walks (2 × 20 frames at 15 fps), their global motion,
    and the first walk's first 20 frames with noisy 2D joints (fitted on one thread: the fit's
    small torch operations run several times slower on two busy cores)."""
    walks = load_walkjog().walks("train")[:2]
    train = [at_15fps(m, 20) for m in walks]
    with torch_threads(1):
        prior = GPDM.fit(train, balanced=True, fps=FPS)
    motion = at_15fps(walks[0], FRAMES)
    X = joint_positions(motion, "eval15")
    camera = default_camera(X)
    noisy = synthesize(X, FPS, camera, "noise", seed=0, sigma_px=SIGMA_PX)
    blackout = synthesize(X, FPS, camera, "blackout", seed=0, sigma_px=SIGMA_PX,
                          start_s=BLACKOUT[0] / FPS, length_s=(BLACKOUT[1] - BLACKOUT[0]) / FPS)
    model = TrackingModel.fitted(prior, [at_15fps(m, 45) for m in walks], JointLikelihood(camera, sigma_px=SIGMA_PX))
    return prior, model, motion, X, noisy.uv, blackout.uv


@pytest.fixture(scope="module")
def tracks(setting):
    """Fast-mode tracks of the clip with every frame observed and through the blackout."""
    _, model, motion, _, noisy, blackout = setting
    return {name: MapTracker(model, mode="fast", iterations=ITERATIONS).run(uv, motion, keep_snapshots=True)
            for name, uv in (("seen", noisy), ("blackout", blackout))}


# ---- eq. 21 ------------------------------------------------------------------------------------

def direct_energy(tracker, g, y, x, camera, sigma_px):
    """Eq. 21 for the window's n free states, written out from the model's parts."""
    prior, n = tracker.prior, len(g)
    g_all, x_all = torch.cat([tracker.g[:-n], g]), torch.cat([tracker.x[:-n], x])
    body = tracker.model.body.angles.joints(y).numpy()      # (n, 15, 3), the tracked subject's bones
    world = np.einsum("nij,nkj->nki", Rotation.from_rotvec(g[:, 3:].numpy()).as_matrix(), body) + g[:, None, :3].numpy()
    image = 0.0
    for j, z in enumerate(tracker.observations):
        seen = np.isfinite(z.numpy()).all(-1)
        uv, _ = camera.project(world[j][seen])
        d_sq = ((uv - z.numpy()[seen]) ** 2).sum(-1)
        image += (d_sq / (2 * sigma_px ** 2) + math.log(2 * math.pi * sigma_px ** 2)).sum()
    mu, var = prior.reconstruct(x)
    reconstruction = ((prior.W ** 2 * (y - mu) ** 2).sum(-1) / (2 * var) + prior.D / 2 * var.log()
                      + 0.5 * (x ** 2).sum(-1)).sum()
    glob = -sum(tracker.model.global_motion.log_prob(g_all[j + 2:j + 3], g_all[j + 1:j + 2], g_all[j:j + 1])
                for j in range(n))
    mu_X, var_X = prior.dynamics(x_all[:-1])
    dynamics = tracker.annealing * ((x_all[1:] - mu_X).pow(2).sum(-1) / (2 * var_X)
                                    + prior.d / 2 * torch.log(2 * math.pi * var_X)).sum()
    return {"image": image, "reconstruction": float(reconstruction), "global": float(glob), "dynamics": float(dynamics)}


def test_energy_terms_match_a_direct_evaluation(setting):
    prior, model, motion, _, noisy, _ = setting
    tracker = MapTracker(model, window=2, annealing=0.5, iterations=2)
    tracker.initialise(motion)
    tracker.step(noisy[2])
    tracker.step(np.full((15, 2), np.nan))           # an all-missing frame inside the window
    tracker.step(noisy[4])
    n = tracker.free
    assert n == 3 and len(tracker.g) == 5 and len(tracker.x) == 4
    gen = torch.Generator().manual_seed(1)
    noise = lambda *shape: torch.randn(*shape, generator=gen, dtype=torch.float64)  # noqa: E731
    g = tracker.g[-n:] + 0.02 * noise(n, 6)
    x = tracker.x[-n:] + 0.1 * noise(n, prior.d)
    y = tracker.y + 0.05 * noise(n, prior.D)
    ours = {k: float(v) for k, v in tracker.energy_terms(g, y, x).items()}
    ref = direct_energy(tracker, g, y, x, model.likelihood.camera, SIGMA_PX)
    for term in ref:
        assert ours[term] == pytest.approx(ref[term], rel=1e-10, abs=1e-8), term
    assert float(tracker.energy(g, y, x)) == pytest.approx(sum(ref.values()), rel=1e-10)
    latent_terms = ("reconstruction", "dynamics")                   # what step (a) minimises
    assert float(tracker.energy(g, y, x, latent_terms)) == pytest.approx(sum(ref[k] for k in latent_terms), rel=1e-10)
    # Fast mode: y = μ_Y(x), so the reconstruction term is D/2 ln σ²(x) + ½|x|².
    mu, var = prior.reconstruct(x)
    fast = tracker.energy_terms(g, None, x)
    expected = float((prior.D / 2 * var.log() + 0.5 * (x ** 2).sum(-1)).sum())
    assert float(fast["reconstruction"]) == pytest.approx(expected, rel=1e-12)
    assert float(fast["image"]) == pytest.approx(direct_energy(tracker, g, mu, x, model.likelihood.camera,
                                                               SIGMA_PX)["image"], rel=1e-10)
    # The gradient the optimiser follows is the energy's: along random directions, against central differences
    # extrapolated to h → 0 (Richardson: error O(h⁴)). Element-wise gradcheck at one eps was draw-dependent: its
    # truncation error (eps 1e-4) or rounding (1e-6) passed 1e-5 of these energies (~10⁴) for some seeds.
    with torch_threads(1):
        gv, xv = g.clone().requires_grad_(True), x.clone().requires_grad_(True)
        tracker.energy(gv, None, xv).backward()
        for _ in range(3):
            dg, dx = noise(*g.shape), noise(*x.shape)
            slope = float((gv.grad * dg).sum() + (xv.grad * dx).sum())

            def central(h: float) -> float:
                return float(tracker.energy(g + h * dg, None, x + h * dx) - tracker.energy(g - h * dg, None, x - h * dx)) / (2 * h)

            assert (4 * central(5e-5) - central(1e-4)) / 3 == pytest.approx(slope, rel=1e-6, abs=1e-6)


# ---- tracking ----------------------------------------------------------------------------------

def test_tracks_a_walk_from_noisy_joints(setting, tracks):
    _, model, _, X, _, _ = setting
    track = tracks["seen"]
    still = np.repeat(X[1:2], len(X) - 2, 0)
    err, err_rr = mpjpe(track.estimates[2:], X[2:]), mpjpe_root_relative(track.estimates[2:], X[2:])
    # Measured: 50 mm world, 17 mm root-relative; holding frame 1 still: 797 mm and 84 mm.
    assert err.mean() < 0.15 * mpjpe(still, X[2:]).mean()
    assert err_rr.mean() < 0.5 * mpjpe_root_relative(still, X[2:]).mean()
    assert np.array_equal(track.estimates[:2], X[:2]) and np.isnan(track.ess).all()
    assert all(not f for f in track.flags)
    # Snapshots: the window's states as tracking-model rows; in fast mode their joints are the estimate.
    snap = track.snapshots[-1]
    assert snap.particles.shape == (3, model.dim) and torch.equal(snap.weights, torch.ones(3, dtype=torch.float64))
    assert math.isnan(snap.ess) and snap.ancestors is None and snap.frame == FRAMES - 1
    np.testing.assert_allclose(model.observe(snap.particles).numpy(), snap.joints.numpy(), atol=1e-12)
    np.testing.assert_array_equal(snap.estimate, snap.joints[-1].numpy())
    np.testing.assert_array_equal(track.estimates[-1], snap.estimate)
    assert set(snap.timings) == {"predict", "latents", "states", "estimate"}
    assert track.snapshots[0].particles.shape == (1, model.dim)      # the window fills up


def test_blackout_is_carried_by_the_prediction(setting, tracks):
    _, _, _, X, _, uv = setting
    track, seen = tracks["blackout"], tracks["seen"]
    f0, f1 = BLACKOUT
    assert np.isnan(uv[f0:f1]).all() and np.isfinite(uv[f0 - 1]).any() and np.isfinite(uv[f1]).any()
    assert np.isfinite(track.estimates).all()
    assert [t for t, f in enumerate(track.flags) if "no-observation" in f] == list(range(f0, f1))
    # Online and deterministic: before the blackout the track is the fully seen run's, to the bit.
    np.testing.assert_array_equal(track.estimates[:f0], seen.estimates[:f0])
    err = mpjpe(track.estimates, X)
    still = mpjpe(np.repeat(X[1:2], len(X), 0), X)
    # Measured: 29 → 126 mm through the blackout (holding frame 1 still: 257 → 1094 mm); over the
    # last 3 frames, seen again, 98 mm (the fully seen run: 85 mm).
    assert err[f0:f1].max() < 300 and np.all(err[f0:f1] < 0.5 * still[f0:f1])
    assert err[-3:].mean() < err[f1 - 1]
    assert err[-3:].mean() < mpjpe(seen.estimates[-3:], X[-3:]).mean() + 40


def test_full_mode_tracks_the_pose_and_estimates_from_y(setting, tracks):
    prior, model, motion, X, noisy, _ = setting
    frames = 8
    tracker = MapTracker(model, mode="full", iterations=ITERATIONS)
    track = tracker.run(noisy[:frames], motion[:frames], keep_snapshots=True)
    err_full = mpjpe(track.estimates[2:], X[2:frames])
    err_fast = mpjpe(tracks["seen"].estimates[2:frames], X[2:frames])
    assert err_full.mean() < 1.5 * err_fast.mean() + 10             # measured: 16.3 and 16.0 mm
    # The estimate is the newest pose y placed by G, not the reconstruction mean of its latent.
    assert tracker.y.shape == (3, prior.D)
    snap = track.snapshots[-1]
    expected = to_world(model.body.angles.joints(tracker.y[-1:]), tracker.g[-1:])[0].numpy()
    np.testing.assert_allclose(snap.estimate, expected, atol=1e-12)
    from_latent = model.observe(snap.particles[-1:])[0].numpy()
    assert np.abs(from_latent - expected).max() > 1e-4


# ---- bad input ---------------------------------------------------------------------------------

def test_bad_input_raises(setting):
    _, model, motion, _, noisy, _ = setting
    with pytest.raises(PriortrackError, match="GPDM prior"):
        MapTracker(TrackingModel(Diffusion.fit([motion]), model.global_motion, model.likelihood))
    with pytest.raises(PriortrackError, match="mode"):
        MapTracker(model, mode="slow")
    for bad in ({"window": 0}, {"iterations": 0}, {"rounds": 1.5}, {"annealing": -1.0}):
        with pytest.raises(PriortrackError, match=next(iter(bad))):
            MapTracker(model, **bad)
    tracker = MapTracker(model, iterations=2)
    with pytest.raises(PriortrackError, match="not initialised"):
        tracker.step(noisy[2])
    tracker.initialise(motion)
    with pytest.raises(PriortrackError, match="no free state"):
        tracker.energy_terms(tracker.g[:0], None, tracker.x[:0])
    tracker.step(noisy[2])
    with pytest.raises(PriortrackError, match="unknown energy terms"):
        tracker.energy_terms(tracker.g[-1:], None, tracker.x[-1:], ("image", "prior"))
    with pytest.raises(PriortrackError, match=r"window states g \(2, 6\)"):
        tracker.energy_terms(tracker.g[-2:], None, tracker.x[-1:])
    with pytest.raises(PriortrackError, match=r"observation has shape \(8, 2\)"):
        tracker.step(noisy[2, :8])
    with pytest.raises(PriortrackError, match=r"expected \(T ≥ 3, 15, 2\)"):
        tracker.run(noisy[:, :, :1], motion)
