"""SO(3) maps, the heading/tilt split, the global motion model and world placement on real mocap."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from priortrack import PriortrackError, load_motion
from priortrack.geometry import so3
from priortrack.priors.global_motion import GlobalMotion, to_world
from priortrack.priors.spaces import AngleSpace, DirectionSpace
from priortrack.body.fk import joint_positions


def _rotvecs(n=500, seed=0, max_angle=math.pi - 1e-6):
    g = torch.Generator().manual_seed(seed)
    w = torch.randn(n, 3, generator=g, dtype=torch.float64)
    return w / w.norm(dim=-1, keepdim=True) * torch.rand(n, 1, generator=g, dtype=torch.float64) * max_angle


def test_so3_exp_matches_scipy_and_log_inverts_it():
    w = torch.cat([_rotvecs(), 1e-10 * _rotvecs(5, 1), torch.zeros(1, 3)])
    R = so3.exp(w)
    np.testing.assert_allclose(R.numpy(), Rotation.from_rotvec(w.numpy()).as_matrix(), atol=1e-14)
    torch.testing.assert_close(so3.log(R), w, rtol=0, atol=1e-9)


def test_quaternion_product_composes_rotations_as_matrices_do():
    """q(ω₁) q(ω₂) is the rotation exp(ω₁) exp(ω₂) (matrix product, scipy's quaternions agree),
    batched and broadcast against a single quaternion; conjugation inverts."""
    w1, w2 = _rotvecs(300, 3), _rotvecs(300, 4)
    q1, q2 = so3.quaternion(w1), so3.quaternion(w2)
    product = so3.quaternion_product(q1, q2)
    torch.testing.assert_close(so3.exp(so3.quaternion_log(product)), so3.exp(w1) @ so3.exp(w2), rtol=0, atol=1e-12)
    expected = (Rotation.from_rotvec(w1.numpy()) * Rotation.from_rotvec(w2.numpy())).as_matrix()
    np.testing.assert_allclose(so3.exp(so3.quaternion_log(product)).numpy(), expected, atol=1e-12)
    single = so3.quaternion_product(q1[0], q2.reshape(30, 10, 4))
    assert single.shape == (30, 10, 4)
    torch.testing.assert_close(single.reshape(300, 4), so3.quaternion_product(q1[:1].expand(300, 4), q2))
    identity = so3.quaternion_product(q1, so3.quaternion_conjugate(q1))
    torch.testing.assert_close(identity, torch.tensor([1.0, 0, 0, 0], dtype=torch.float64).expand(300, 4),
                               rtol=0, atol=1e-15)
    with pytest.raises(PriortrackError, match=r"quaternion has shape \(300, 3\); expected \(\.\.\., 4\)"):
        so3.quaternion_product(q1, w2)


def test_float32_placement_by_the_fused_kernel_matches_float64():
    """float32 to_world on the CPU goes through one fused kernel (priortrack.priors.placement_kernel);
    the torch path (other dtypes, devices, gradients) is its reference. Rotations of every size
    (zero, below the Taylor switch at θ² = 1e-8, up to π): within 5e-6 m of the float64 placement
    of joints a metre or two out, and no further than twice the torch path's own float32 error."""
    g = torch.cat([torch.randn(600, 3, dtype=torch.float64), torch.cat([_rotvecs(400, 5),
                                                                        1e-5 * _rotvecs(100, 6),
                                                                        torch.zeros(100, 3)])], dim=1)
    body = torch.randn(600, 15, 3, dtype=torch.float64)
    exact = to_world(body, g)
    fused = to_world(body.float(), g.float())
    torch32 = to_world(body.float().requires_grad_(), g.float()).detach()           # the torch path
    assert fused.dtype == torch.float32 and fused.shape == (600, 15, 3)
    error, error32 = ((x.double() - exact).abs().max().item() for x in (fused, torch32))
    assert error < 5e-6 and error < 2 * error32 + 1e-7, (error, error32)


@pytest.mark.parametrize("translation", [True, False])
def test_float32_draw_by_the_fused_kernel_matches_float64(translation):
    """float32 GlobalMotion.sample on the CPU is one fused kernel (priortrack.priors.global_motion_kernel)
    fed the same normal variates as the torch path (a reverting tilt): rotations of every size (zero, below the Taylor
    switch, up to 2.5 rad), the kernel's draw within 2e-5 of the float64 one and no further than twice
    the torch float32 path's own error; with translation=False, t_t = t_{t-1} + v (t_{t-1} − t_{t-2})
    exactly (the height's velocity damped)."""
    model = GlobalMotion(torch.tensor([0.01, 0.02, 0.015, 0.05, 0.1, 0.08]), tilt_mean=[0.05, -0.1],
                         tilt_decay=[0.9, 0.7], height_decay=0.6)
    rotations = torch.cat([_rotvecs(400, 7, max_angle=2.5), 1e-5 * _rotvecs(100, 8), torch.zeros(100, 3)])
    g1 = torch.cat([torch.randn(600, 3, dtype=torch.float64), rotations], dim=1)
    g2 = g1 + 0.05 * torch.randn(600, 6, dtype=torch.float64)
    draw = {name: model.sample(a, b, torch.Generator().manual_seed(3), translation=translation)
            for name, (a, b) in {"exact": (g1, g2), "fused": (g1.float(), g2.float()),
                                 "torch32": (g1.float().requires_grad_(), g2.float())}.items()}
    assert draw["fused"].dtype == torch.float32
    error, error32 = ((draw[k].detach().double() - draw["exact"]).abs().max().item() for k in ("fused", "torch32"))
    assert error < 2e-5 and error <= 2 * error32 + 1e-6, (error, error32)
    if not translation:
        v = torch.tensor([1.0, 0.6, 1.0], dtype=torch.float64)
        torch.testing.assert_close(draw["exact"][:, :3], g1[:, :3] + v * (g1[:, :3] - g2[:, :3]), rtol=0, atol=1e-15)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_placement_of_mismatched_shapes_is_a_clear_error(dtype):
    """Both paths (the float32 kernel would otherwise read past a short g) name the two shapes."""
    body = torch.zeros(4, 15, 3, dtype=dtype)
    for b, g in [(body, torch.zeros(4, 5, dtype=dtype)), (body, torch.zeros(3, 6, dtype=dtype)),
                 (body[0], torch.zeros(4, 6, dtype=dtype)), (body[..., :2], torch.zeros(4, 6, dtype=dtype))]:
        with pytest.raises(PriortrackError, match=r"expected \(P, J, 3\) and \(P, 6\)"):
            to_world(b, g)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_draw_from_mismatched_placements_is_a_clear_error(dtype):
    """Both paths (the float32 kernel would otherwise read past a short g_(t-2)) name the shapes."""
    model = GlobalMotion(torch.full((6,), 0.01))
    g = torch.zeros(4, 6, dtype=dtype)
    for a, b in [(g, g[:3]), (g[:, :5], g[:, :5]), (g[0], g[0])]:
        with pytest.raises(PriortrackError, match=r"expected both \(P, 6\)"):
            model.sample(a, b, torch.Generator())


def test_so3_log_near_pi_gives_the_same_rotation():
    axis = torch.tensor([[0.6, 0.0, 0.8]], dtype=torch.float64)
    for angle in (math.pi, math.pi - 1e-9, math.pi - 1e-4):
        R = so3.exp(angle * axis)
        w = so3.log(R)
        assert w.norm().item() == pytest.approx(angle, abs=1e-7)
        torch.testing.assert_close(so3.exp(w), R, rtol=0, atol=1e-12)


def test_heading_tilt_split_matches_scipy_and_joins_back():
    """R = exp(ψ e_y) exp(τ_x e_x + τ_z e_z) (scipy composes the same), the split joins back, and
    q, −q give the same tilt and headings 2π apart."""
    q = so3.quaternion(_rotvecs(500, 9, max_angle=3.0))
    psi, tau = so3.heading_tilt(q)
    R = Rotation.from_rotvec(np.outer(psi.numpy(), [0, 1, 0])) * Rotation.from_rotvec(
        np.stack([tau[:, 0].numpy(), np.zeros(500), tau[:, 1].numpy()], -1))
    np.testing.assert_allclose(R.as_matrix(), so3.exp(so3.quaternion_log(q)).numpy(), atol=1e-12)
    joined = so3.from_heading_tilt(psi, tau)
    torch.testing.assert_close(so3.exp(so3.quaternion_log(joined)), so3.exp(so3.quaternion_log(q)), rtol=0, atol=1e-12)
    psi_neg, tau_neg = so3.heading_tilt(-q)
    torch.testing.assert_close(tau_neg, tau, rtol=0, atol=1e-12)
    torch.testing.assert_close((psi_neg - psi).abs(), torch.full_like(psi, 2 * math.pi), rtol=0, atol=1e-9)
    with pytest.raises(PriortrackError, match=r"heading \(500,\) and tilt \(500, 3\)"):
        so3.from_heading_tilt(psi, torch.zeros(500, 3, dtype=torch.float64))


def test_left_jacobian_is_the_derivative_of_exp():
    """exp(ω + δ) = exp(J_l(ω) δ) exp(ω) + O(|δ|²), for rotations up to 3 rad and below the Taylor switch."""
    w = torch.cat([_rotvecs(300, 10, max_angle=3.0), 1e-6 * _rotvecs(20, 11)])
    for h in (1e-5, 1e-6):
        d = h * torch.randn(len(w), 3, generator=torch.Generator().manual_seed(12), dtype=torch.float64)
        step = (so3.left_jacobian(w) @ d[..., None])[..., 0]
        assert (so3.exp(w + d) - so3.exp(step) @ so3.exp(w)).abs().max() < 10 * h ** 2


def _placements(t, psi, tau):
    return torch.cat([t, so3.quaternion_log(so3.from_heading_tilt(psi, tau))], -1)


def test_position_and_heading_are_second_order_and_the_tilt_reverts():
    """t on the ground plane and ψ continue at constant velocity (ψ across ±π too), the height's
    velocity is damped by b; the tilt steps to μ + a (τ_{t-1} − μ)."""
    f64 = dict(dtype=torch.float64)
    k = torch.arange(3, **f64)[:, None]
    t = torch.tensor([1.0, 0.9, -2.0], **f64) + k * torch.tensor([0.04, 0.02, 0.01], **f64)      # (3 frames, 3)
    psi = torch.tensor([3.1, 3.1, -0.2], **f64) + k * torch.tensor([0.03, -0.05, 0.1], **f64)    # (3 frames, 3 rows)
    tau = torch.tensor([[0.05, -0.02], [0.1, 0.07], [-0.3, 0.0]], **f64)
    model = GlobalMotion(torch.full((6,), 0.01), tilt_mean=[0.02, -0.01], tilt_decay=[0.9, 0.5], height_decay=0.5)
    g = [_placements(t[i].expand(3, 3), psi[i], tau) for i in range(3)]
    mean, decay = model.tilt_mean, model.tilt_decay
    t_next = t[2] - torch.tensor([0.0, 0.01, 0.0], **f64)                 # the height rises 0.02 → 0.01 a frame
    expected = _placements(t_next.expand(3, 3), psi[2], mean + decay * (tau - mean))
    torch.testing.assert_close(model.predict(g[1], g[0]), expected, rtol=0, atol=1e-12)
    torch.testing.assert_close(model.residual(expected, g[1], g[0]), torch.zeros(3, 6, **f64), rtol=0, atol=1e-12)


def test_fit_recovers_a_known_process_and_its_draws_have_the_model_moments():
    """On placements simulated from known (σ, μ, a), the fit recovers them; the rollouts' tilt has
    the AR(1) stationary law N(μ, σ_τ²/(1 − a²))."""
    truth = GlobalMotion(torch.tensor([0.003, 0.002, 0.004, 0.01, 0.02, 0.015]),
                         tilt_mean=[0.05, -0.03], tilt_decay=[0.9, 0.8], height_decay=0.7)
    gen = torch.Generator().manual_seed(1)
    g = torch.zeros(400, 16, 6, dtype=torch.float64)                               # 400 frames of 16 sequences
    g[1] = g[0] = _placements(torch.zeros(16, 3, dtype=torch.float64), torch.zeros(16, dtype=torch.float64),
                              truth.tilt_mean.expand(16, 2))
    for i in range(2, 400):
        g[i] = truth.sample(g[i - 1], g[i - 2], gen)
    fitted = GlobalMotion.fit(list(g.transpose(0, 1)))
    torch.testing.assert_close(fitted.sigma, truth.sigma, rtol=0.03, atol=0)
    torch.testing.assert_close(fitted.tilt_decay, truth.tilt_decay, rtol=0, atol=0.03)
    torch.testing.assert_close(fitted.tilt_mean, truth.tilt_mean, rtol=0, atol=0.01)
    torch.testing.assert_close(fitted.velocity, truth.velocity, rtol=0, atol=0.03)
    tau = so3.heading_tilt(so3.quaternion(g[100:, :, 3:].reshape(-1, 3)))[1]
    stationary = truth.sigma[3::2] / (1 - truth.tilt_decay ** 2).sqrt()
    torch.testing.assert_close(tau.mean(0), truth.tilt_mean, rtol=0, atol=0.01)
    torch.testing.assert_close(tau.std(0), stationary, rtol=0.1, atol=0)


def test_fit_is_the_ml_estimate_on_a_real_walk():
    """On a real walk the fitted tilt is stationary (a < 1) and the fit beats other σ, a, μ; draws'
    residuals have std σ."""
    walk = load_motion("cmu:07_01").resample(30)
    g = AngleSpace.fit([walk]).global_pose(walk)
    model = GlobalMotion.fit([g])
    r = model.residual(g[2:], g[1:-1], g[:-2])
    torch.testing.assert_close(model.sigma, r.pow(2).mean(0).sqrt())
    assert torch.all(model.tilt_decay < 1) and 0.3 < model.velocity[1] < 0.95      # the pelvis's bob: b ≈ 0.7
    b = float(model.velocity[1])
    worse = [GlobalMotion(model.sigma * 3, model.tilt_mean, model.tilt_decay, b),
             GlobalMotion(model.sigma, model.tilt_mean, torch.ones(2), b),
             GlobalMotion(model.sigma, model.tilt_mean + 0.05, model.tilt_decay, b),
             GlobalMotion(model.sigma, model.tilt_mean, model.tilt_decay, 1.0)]
    best = model.log_prob(g[2:], g[1:-1], g[:-2]).mean()
    assert all(best > m.log_prob(g[2:], g[1:-1], g[:-2]).mean() for m in worse)
    n = 20000
    g1, g2 = g[10].expand(n, 6), g[9].expand(n, 6)
    draws = model.sample(g1, g2, torch.Generator().manual_seed(0))
    torch.testing.assert_close(model.residual(draws, g1, g2).std(dim=0), model.sigma, rtol=0.03, atol=0)


def test_rotation_covariance_is_the_world_frame_spread_of_the_draws():
    """η = log(R_t R̂_tᵀ) of draws (small σ, so first order holds) has covariance rotation_covariance(ĝ),
    at headings all round and tilts up to 0.5 rad."""
    model = GlobalMotion(torch.tensor([0.01, 0.01, 0.01, 0.002, 0.003, 0.001]))
    n = 40000
    for psi, tau in [(0.3, (0.0, 0.0)), (2.5, (0.4, -0.2)), (-1.7, (-0.1, 0.5))]:
        g1 = _placements(torch.zeros(1, 3, dtype=torch.float64), torch.tensor([psi], dtype=torch.float64),
                         torch.tensor([tau], dtype=torch.float64)).expand(n, 6)
        draws = model.sample(g1, g1, torch.Generator().manual_seed(4))
        eta = so3.log(so3.exp(draws[:, 3:]) @ so3.exp(g1[:, 3:]).transpose(-1, -2))
        empirical = eta.T @ eta / n
        expected = model.rotation_covariance(g1[:1])[0]
        assert (empirical - expected).abs().max() < 0.03 * expected.diagonal().max(), (empirical, expected)


@pytest.mark.parametrize("space_class", [AngleSpace, DirectionSpace])
def test_world_joints_from_body_joints_and_placement(space_class):
    walk = load_motion("cmu:35_01").resample(30)
    space = space_class.fit([walk])
    x, g = space.encode(walk), space.global_pose(walk)
    world = to_world(space.joints(x), g)
    truth = torch.as_tensor(joint_positions(walk, "eval15"))
    if space_class is AngleSpace:
        assert (world - truth).abs().max() < 1e-9
    else:
        # Directions decode with the training mean bone lengths: exact up to length changes.
        assert (world - truth).abs().max() < 0.02


def test_bad_input():
    with pytest.raises(PriortrackError, match=r"sigma must be 6 finite value\(s\), got \[1.0, 2.0\]"):
        GlobalMotion([1.0, 2.0])
    with pytest.raises(PriortrackError, match="sigma must be 6 positive"):
        GlobalMotion([1.0, 2.0, 0.0, 1.0, 1.0, 1.0])
    with pytest.raises(PriortrackError, match="height_decay must be numbers, got 'x'"):
        GlobalMotion(torch.ones(6), height_decay="x")
    with pytest.raises(PriortrackError, match=r"height_decay must be 1 finite value\(s\), got nan"):
        GlobalMotion(torch.ones(6), height_decay=float("nan"))
    with pytest.raises(PriortrackError, match=r"T ≥ 3, 6"):
        GlobalMotion.fit([torch.zeros(2, 6)])
    with pytest.raises(PriortrackError, match="NaN or inf"):
        GlobalMotion.fit([torch.full((5, 6), float("nan"))])
    with pytest.raises(PriortrackError, match=r"tilt_decay must be 2 values in \[0, 1\], got \[1.5, 0.5\]"):
        GlobalMotion(torch.ones(6), tilt_decay=[1.5, 0.5])
    with pytest.raises(PriortrackError, match=r"height_decay must lie in \[0, 1\]"):
        GlobalMotion(torch.ones(6), height_decay=1.2)
    with pytest.raises(PriortrackError, match="tilt_mean must be 2 finite"):
        GlobalMotion(torch.ones(6), tilt_mean=[0.0, 0.0, 0.0])
    with pytest.raises(PriortrackError, match="rotation vector"):
        so3.exp(torch.zeros(4, 2))
    with pytest.raises(PriortrackError, match=r"rotation vector has shape \(4, 2\)"):
        so3.left_jacobian(torch.zeros(4, 2))
    with pytest.raises(PriortrackError, match=r"quaternion has shape \(4, 3\)"):
        so3.heading_tilt(torch.zeros(4, 3))
