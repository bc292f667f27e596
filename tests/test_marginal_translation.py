"""The translation integrated out of the particle filter (priortrack.filters.marginal_translation):
the 3 × 3 Kalman algebra against the textbook 2n × 2n formulas, the numba kernel against the torch
path, the camera's Jacobian against autograd, and the filter on a real walk."""

import numpy as np
import pytest
import torch

from priortrack import PriortrackError, load_walkjog
from priortrack.filters.marginal_translation import broadcast_product, kalman_update, predict_covariance
from priortrack.filters.particle import ParticleFilter
from priortrack.models.tracking import TrackingModel
from priortrack.observation import default_camera, synthesize
from priortrack.observation.likelihood import JointLikelihood
from priortrack.priors import Diffusion

from linear_gaussian import LinearGaussian
from priortrack.body.fk import joint_positions

SIGMA = torch.tensor([0.002, 0.003, 0.0025], dtype=torch.float64)
CONSTANT = torch.ones(3, dtype=torch.float64)                           # v: constant velocity


@pytest.fixture(scope="module")
def scene():
    """A walk's first frames, its camera, and P = 64 perturbed copies of one frame's joints."""
    motion = load_walkjog().test[1][:3]
    X = torch.as_tensor(joint_positions(motion, "eval15"))
    camera = default_camera(X.numpy())
    g = torch.Generator().manual_seed(0)
    joints = X[2] + 0.05 * torch.randn((64, 15, 3), generator=g, dtype=torch.float64)
    z, _ = camera.project(X[2] + 0.01 * torch.randn((15, 3), generator=g, dtype=torch.float64))
    z[[1, 4, 9]] = float("nan")                                         # missing joints are data
    # A covariance of (t_t, t_{t-1}) from a few steps of the filter's own recursion.
    C = torch.zeros(64, 6, 6, dtype=torch.float64)
    for _ in range(3):
        C = predict_covariance(C, SIGMA * (1 + torch.rand(64, 1, 1, generator=g, dtype=torch.float64)[:, 0]), CONSTANT)
    return camera, joints, z, C


def dense(camera, joints, C, z, sigma_px):
    """The textbook EKF step with the 2n × 2n innovation covariance S = H C⁻ Hᵀ + σ² I, H = [J, 0]."""
    C = predict_covariance(C, SIGMA, CONSTANT)
    seen = torch.isfinite(z).all(-1)
    uv, J, _ = camera.project_jacobian(joints[:, seen])
    r = (z[seen] - uv).reshape(len(joints), -1)                         # (P, 2n)
    H = torch.cat([J.reshape(len(joints), -1, 3), torch.zeros_like(J.reshape(len(joints), -1, 3))], -1)
    S = H @ C @ H.transpose(1, 2) + sigma_px ** 2 * torch.eye(H.shape[1], dtype=C.dtype)
    K = C @ H.transpose(1, 2) @ torch.linalg.inv(S)
    shift = (K @ r[..., None])[..., 0]
    C_post = C - K @ H @ C
    log_predictive = torch.distributions.MultivariateNormal(torch.zeros_like(r), S).log_prob(r)
    return shift, C_post, log_predictive


@pytest.mark.parametrize("path", ["kernel", "torch"])
def test_update_equals_the_textbook_kalman_step(scene, path):
    """Shift, posterior covariance and predictive likelihood equal the 2n × 2n formulas (float64)."""
    camera, joints, z, C = scene
    likelihood = JointLikelihood(camera, sigma_px=7.0)
    shift, C_post, log_predictive = kalman_update(joints.clone().requires_grad_(path == "torch"), C, SIGMA, CONSTANT,
                                                  z, likelihood)
    shift_ref, C_ref, log_predictive_ref = dense(camera, joints, C, z, 7.0)
    torch.testing.assert_close(shift.detach(), shift_ref, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(C_post.detach(), C_ref, rtol=1e-9, atol=1e-14)
    torch.testing.assert_close(log_predictive.detach(), log_predictive_ref, rtol=1e-10, atol=1e-8)
    assert bool((torch.linalg.eigvalsh(C_post.detach()[:, :3, :3]) > 0).all())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_kernel_matches_the_torch_path(scene, dtype):
    """float64: the kernel equals the torch path to rounding. float32: against the float64 result,
    the kernel's error is at most twice the float32 torch path's own (plus a float32 ulp)."""
    camera, joints64, z64, C64 = scene
    joints, z, C = joints64.to(dtype), z64.to(dtype), C64.to(dtype)
    likelihood = JointLikelihood(camera)
    v = torch.tensor([1.0, 0.7, 1.0])
    fused = kalman_update(joints, C, SIGMA, v, z, likelihood)
    reference = [x.detach() for x in kalman_update(joints.clone().requires_grad_(True), C, SIGMA, v, z, likelihood)]
    exact = kalman_update(joints64, C64, SIGMA, v, z64, likelihood)
    for a, b, c in zip(fused, reference, exact):
        assert a.dtype == b.dtype == dtype
        if dtype == torch.float64:
            torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-15 * float(b.abs().max()))
        else:
            ulp = 1.2e-7 * float(c.abs().max())
            assert float((a - c).abs().max()) <= 2 * float((b - c).abs().max()) + ulp


def test_joints_behind_the_camera_and_missing_ones_do_not_inform(scene):
    """A joint behind the camera leaves the update as if it were missing, and costs the
    likelihood's miss (the image diagonal) in the predictive density."""
    camera, joints, z, C = scene
    likelihood = JointLikelihood(camera)
    behind = joints.clone()
    behind[:, 0] = 2 * camera.center - behind[:, 0]                   # joint 0 mirrored through the camera centre
    only_rest = z.clone()
    only_rest[0] = float("nan")
    miss = likelihood.gaussian(torch.tensor(likelihood.miss_sq, dtype=torch.float64), 1)
    for path_grad in (False, True):
        a = kalman_update(behind.clone().requires_grad_(path_grad), C, SIGMA, CONSTANT, z, likelihood)
        b = kalman_update(behind.clone().requires_grad_(path_grad), C, SIGMA, CONSTANT, only_rest, likelihood)
        torch.testing.assert_close(a[0].detach(), b[0].detach())
        torch.testing.assert_close(a[1].detach(), b[1].detach())
        torch.testing.assert_close(a[2].detach(), b[2].detach() + miss)


def test_projection_jacobian_equals_autograd(scene):
    camera, joints, _, _ = scene
    X = joints[0].detach()
    _, J, in_front = camera.project_jacobian(X)
    auto = torch.autograd.functional.jacobian(lambda p: camera.project(p)[0], X)     # (15, 2, 15, 3)
    assert bool(in_front.all())
    torch.testing.assert_close(J, torch.stack([auto[j, :, j] for j in range(15)]), rtol=1e-10, atol=1e-9)
    # Integer points and numpy arrays are taken as float64; a wrong shape is named.
    whole = torch.round(X * 10)
    torch.testing.assert_close(camera.project_jacobian(whole.to(torch.int64))[1], camera.project_jacobian(whole)[1])
    torch.testing.assert_close(camera.project_jacobian(X.numpy())[1], J)
    with pytest.raises(PriortrackError, match=r"expected shape \(\.\.\., J, 3\)"):
        camera.project_jacobian(X[:, :2])


def test_covariance_prediction_is_F_C_Ft_plus_Q():
    g = torch.Generator().manual_seed(1)
    A = torch.randn(5, 6, 6, generator=g, dtype=torch.float64)
    C = A @ A.transpose(1, 2)
    F = torch.zeros(6, 6, dtype=torch.float64)
    F[:3, :3], F[:3, 3:], F[3:, :3] = 2 * torch.eye(3), -torch.eye(3), torch.eye(3)
    Q = torch.diag(torch.cat([SIGMA ** 2, torch.zeros(3, dtype=torch.float64)]))
    torch.testing.assert_close(predict_covariance(C, SIGMA, CONSTANT), F @ C @ F.T + Q)
    v = torch.tensor([1.0, 0.7, 1.0], dtype=torch.float64)                  # the height's velocity damped
    F[:3, :3], F[:3, 3:] = torch.eye(3) + torch.diag(v), -torch.diag(v)
    torch.testing.assert_close(predict_covariance(C, SIGMA, v), F @ C @ F.T + Q)


def _walk_filter(translation: str, seed: int, frames: int = 60, scenario: str = "clean"):
    walkjog = load_walkjog()
    train = list(walkjog.walks("train"))
    prior = Diffusion.fit(train, local=True)
    motion = walkjog.test[1][:frames]
    X = joint_positions(motion, "eval15")
    obs = synthesize(X, motion.fps, default_camera(X), scenario, seed=seed, sigma_px=5.0)
    model = TrackingModel.fitted(prior, train,
                          JointLikelihood(obs.camera))
    return ParticleFilter(model, 300, dtype="float32", translation=translation, seed=seed), obs, motion, X


def test_marginalised_translation_holds_the_depth_on_a_real_walk():
    """On a held-out walk the sampled translation's depth drifts (resampling cannot select it);
    integrated out, the pelvis stays closer to the truth, over three seeds (measured: 64 against
    90 mm; 84 against 169 mm while the global motion's tilt was second order and drifted too)."""
    errors = {}
    for translation in ("sampled", "marginalised"):
        root = []
        for seed in range(3):
            pf, obs, motion, X = _walk_filter(translation, seed)
            track = pf.run(obs.uv, motion)
            root.append(np.linalg.norm(track.estimates[2:, 0] - X[2:, 0], axis=-1).mean())
        errors[translation] = float(np.mean(root))
    assert errors["marginalised"] < 0.8 * errors["sampled"], errors


def test_the_trunk_keeps_its_lean_through_an_occlusion():
    """A lean towards the camera is nearly invisible (the depth makes up for the foreshortening), so
    with the whole rotation second order the estimate's pelvis-to-neck direction drifted (measured
    there: 7.2 / 13.2 / 11.0° mean error, up to 31°); with the tilt AR(1) about its training mean it
    stays near the truth's (measured: 3.4 / 4.6 / 4.0°, at most 10.8°). 90 frames, three seeds."""
    means, worst = [], []
    for seed in range(3):
        pf, obs, motion, X = _walk_filter("marginalised", seed, frames=90, scenario="occlusion")
        est, X = pf.run(obs.uv, motion).estimates[2:], np.asarray(X)[2:]
        up = [(P[:, 1] - P[:, 0]) / np.linalg.norm(P[:, 1] - P[:, 0], axis=1, keepdims=True) for P in (est, X)]
        angle = np.degrees(np.arccos(np.clip((up[0] * up[1]).sum(1), -1, 1)))
        means.append(angle.mean()), worst.append(angle.max())
    assert np.mean(means) < 6 and max(worst) < 20, (means, worst)


def test_unobserved_frames_predict_the_covariance_and_resampling_carries_it(monkeypatch):
    import priortrack.filters.particle as particle

    pf, obs, motion, _ = _walk_filter("marginalised", 0, frames=12)
    pf.initialise(motion)
    assert pf.covariance.shape == (300, 6, 6) and pf.covariance.dtype == torch.float32
    assert not pf.covariance.any()                                      # the known frames are exact
    for t in range(2, 6):
        pf.step(obs.uv[t])
    before = pf.covariance.clone()
    snap = pf.step(np.full((15, 2), np.nan))
    assert "no-observation" in snap.flags
    motion = pf.model.global_motion
    torch.testing.assert_close(pf.covariance, predict_covariance(before, motion.sigma[:3], motion.velocity))
    # A step that resamples: each particle's covariance goes with it.
    updated = {}

    def spy(*args):
        out = real(*args)
        updated["C"] = out[1]
        return out

    real = particle.kalman_update
    monkeypatch.setattr(particle, "kalman_update", spy)
    pf.ess_threshold = 1.0
    snap = pf.step(obs.uv[7])
    assert snap.ancestors is not None
    torch.testing.assert_close(pf.covariance, updated["C"][torch.as_tensor(snap.ancestors)])
    # The snapshot holds the covariances of its own (pre-resampling) particles.
    assert snap.translation_covariance is updated["C"] and snap.translation_covariance.shape == (300, 6, 6)
    sampled, obs, motion, _ = _walk_filter("sampled", 0, frames=4)
    sampled.initialise(motion)
    assert sampled.step(obs.uv[2]).translation_covariance is None


@pytest.mark.parametrize("grad", [False, True])
def test_mismatched_shapes_are_named_before_either_path(scene, grad):
    camera, joints, z, C = scene
    likelihood = JointLikelihood(camera)
    joints = joints.clone().requires_grad_(grad)
    for args in [(joints, C[:10], SIGMA, CONSTANT, z), (joints[:, :14], C, SIGMA, CONSTANT, z),
                 (joints[..., :2], C, SIGMA, CONSTANT, z), (joints, C, SIGMA, CONSTANT, z[:, :1])]:
        with pytest.raises(PriortrackError, match=r"expected \(P, J, 3\), \(P, 6, 6\) and \(J, 2\)"):
            kalman_update(*args, likelihood)


def test_bad_options_are_named():
    pf, obs, motion, _ = _walk_filter("marginalised", 0, frames=4)
    with pytest.raises(PriortrackError, match="translation must be one of sampled, marginalised"):
        ParticleFilter(pf.model, 10, translation="integrated")
    robust = TrackingModel(pf.model.prior, pf.model.global_motion, JointLikelihood(obs.camera, robust_nu=4.0))
    with pytest.raises(PriortrackError, match="linearisable"):
        ParticleFilter(robust, 10, translation="marginalised")
    with pytest.raises(PriortrackError, match="TrackingModel"):
        ParticleFilter(LinearGaussian(np.eye(2), np.eye(2), np.eye(2), np.eye(2)), 10, translation="marginalised")


def test_translation_spread_is_the_mixture_covariance_and_is_logged_as_an_ellipsoid(tmp_path):
    """Snapshot.translation_spread: Σ_i w_i (C_i + (t_i − t̄)(t_i − t̄)ᵀ) against a loop; the
    recording's ellipsoid has that covariance (R diag(h²) Rᵀ from the logged half-sizes and
    quaternion) and that centre."""
    import rerun as rr
    from scipy.spatial.transform import Rotation

    from priortrack.filters.snapshot import Snapshot
    from priortrack.viz.recording import Recording

    g = torch.Generator().manual_seed(3)
    P = 7
    particles = torch.randn(P, 20, generator=g, dtype=torch.float64)
    weights = torch.rand(P, generator=g, dtype=torch.float64)
    A = torch.randn(P, 6, 6, generator=g, dtype=torch.float64)
    covariance = 1e-3 * A @ A.transpose(1, 2)
    snap = Snapshot(3, particles, weights, 1.0, None, np.zeros((15, 3)), np.zeros((15, 3)), torch.zeros(P, 15, 3),
                    translation_covariance=covariance)
    mean, spread = snap.translation_spread()
    w = (weights / weights.sum()).numpy()
    t = particles[:, 8:11].numpy()                               # g_t's translation: columns −12..−9 of 20
    expected_mean = (w[:, None] * t).sum(0)
    expected = sum(w[i] * (covariance[i, :3, :3].numpy() + np.outer(t[i] - expected_mean, t[i] - expected_mean))
                   for i in range(P))
    np.testing.assert_allclose(mean, expected_mean, atol=1e-12)
    np.testing.assert_allclose(spread, expected, atol=1e-12)
    assert Snapshot(3, particles, weights, 1.0, None, np.zeros((15, 3)), np.zeros((15, 3)),
                    torch.zeros(P, 15, 3)).translation_spread() is None

    path = tmp_path / "ellipsoid.rrd"
    with Recording(path) as rec:
        rec.frame(0)
        rec.ellipsoid("estimate/translation", mean, spread)
    batches = [c.to_record_batch() for c in rr.chunk.RrdReader(str(path)).stream().to_chunks()
               if c.entity_path == "/world/estimate/translation"]
    assert len(batches) == 1
    column = {name: batches[0].column(name)[0].as_py() for name in batches[0].schema.names
              if name.startswith("Ellipsoids3D:")}
    h = np.array(column["Ellipsoids3D:half_sizes"][0])
    R = Rotation.from_quat(column["Ellipsoids3D:quaternions"][0]).as_matrix()
    np.testing.assert_allclose(R @ np.diag(h ** 2) @ R.T, spread, atol=1e-6 * np.abs(spread).max())
    np.testing.assert_allclose(column["Ellipsoids3D:centers"][0], mean, atol=1e-6)


def test_the_gpus_broadcast_product_is_matmul():
    """The GPU's small-matrix product (:func:`broadcast_product`, its Kalman update's every product) equals matmul on
    batches of the update's shapes, 3 × 3 by 3 × 1 and 6 × 3 by 3 × 6."""
    g = torch.Generator().manual_seed(0)
    for n, k, m in [(3, 3, 1), (3, 3, 3), (6, 3, 6)]:
        a = torch.randn(50, n, k, generator=g, dtype=torch.float64)
        b = torch.randn(50, k, m, generator=g, dtype=torch.float64)
        torch.testing.assert_close(broadcast_product(a, b), a @ b, rtol=1e-14, atol=1e-14)
