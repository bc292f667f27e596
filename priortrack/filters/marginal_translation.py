"""The body's translation integrated out of the particle filter by a Kalman filter per particle
(a Rao–Blackwellised, or marginalised, particle filter: Schön, Gustafsson & Nordlund, IEEE TSP
53(7), 2005), with the projection linearised as in the extended Kalman filter.

Why: one camera sees the depth only through the size of the skeleton's image, a few pixels per
decimetre at 5 m. A sampled translation t_t = 2 t_{t−1} − t_{t−2} + ε (σ_t ≈ 2.5 mm per frame)
differs so little between particles that resampling cannot select the right depth; the cloud's
depth velocity drifts as a random walk, by tens of centimetres a second. Integrating t out lets
every frame's weak depth evidence accumulate in each particle's Gaussian instead.

Per particle, τ = (t_t, t_{t−1}) ∈ R⁶ has mean μ (the translations held in the particle's
state) and covariance C (6 × 6). The second-order model (t_t = t_{t−1} + V (t_{t−1} − t_{t−2}) + ε,
V = diag v the velocity's decay, :class:`~priortrack.priors.global_motion.GlobalMotion`) is linear:

    predict   μ⁻ = F μ,  C⁻ = F C Fᵀ + Q,   F = [[I + V, −V], [I, 0]],  Q = diag(σ_t², 0).

Given the particle's pose and rotation (drawn from the prior), the world joints X_j(t) = R B_j + t
are linear in t. Linearised at the predicted t̂ = μ⁻[:3], û_j(t) ≈ û_j + J_j (t − t̂), with
J_j = ∂û/∂X (2 × 3) at X_j(t̂) and r_j = z_j − û_j over the observed joints, and with P = C⁻[:3, :3],

    A = Σ_j J_jᵀ J_j / σ_e²,   b = Σ_j J_jᵀ r_j / σ_e²,   y = (I + A P)⁻¹ b,

(the observation model's ``linearised``: over every camera's joints, each with its own weight, for
:class:`~priortrack.observation.multiview.MultiViewLikelihood`)
    update    μ⁺ = μ⁻ + C⁻[:, :3] y,   C⁺ = C⁻ − C⁻[:, :3] (I + A P)⁻¹ A C⁻[:3, :],

the Kalman update written with 3 × 3 matrices (Jᵀ (J P Jᵀ + σ_e² I)⁻¹ = (I + A P)⁻¹ Jᵀ / σ_e²).
The particle's weight is the predictive likelihood of z with t integrated out,

    log N(r; 0, J P Jᵀ + σ_e² I) = log p(z | t̂) + ½ bᵀ P y − ½ log det(I + A P),

log p(z | t̂) the Gaussian likelihood at the predicted translation (matrix determinant lemma
and Woodbury). The rotation and the pose are still sampled: only t is integrated.

On the CPU the update is one fused numba kernel (:mod:`priortrack.filters.kalman_kernel`, the
same equations; its rows split among torch's threads by :func:`priortrack.threads.split_rows`);
the torch code below serves several cameras, other devices and gradients: N⁻¹ by the adjugate, as in the
kernel, and on a GPU the small products as broadcasts (:func:`broadcast_product`), faster there than cuBLAS's
batched products and LU factorisations of 10⁶ tiny matrices.
"""

from __future__ import annotations

import torch

from priortrack.errors import PriortrackError
from priortrack.geometry.camera import MIN_DEPTH
from priortrack.kernels import cpu_kernel_applies
from priortrack.observation.likelihood import JointLikelihood
from priortrack.threads import split_rows


def predict_covariance(C: torch.Tensor, sigma: torch.Tensor, velocity: torch.Tensor) -> torch.Tensor:
    """C⁻ = F C Fᵀ + Q (P, 6, 6) from C (P, 6, 6), σ_t (3,) and the velocity's decay v (3,; ones:
    constant velocity) (module docstring)."""
    v = velocity.to(C)
    t, t_prev = C[:, :3], C[:, 3:]                                     # rows of τ = (t_t, t_{t-1})
    rows = torch.cat([t + v[:, None] * (t - t_prev), t], dim=1)       # F C
    t, t_prev = rows[..., :3], rows[..., 3:]
    out = torch.cat([t + v * (t - t_prev), t], dim=2)                 # (F C) Fᵀ
    out[:, range(3), range(3)] += (sigma ** 2).to(C)
    return out


def kalman_update(joints: torch.Tensor, C: torch.Tensor, sigma: torch.Tensor, velocity: torch.Tensor, z: torch.Tensor,
                  likelihood) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The prediction and update of τ for one observed frame, and the particles' log predictive likelihood.

    Args:
        joints: (P, J, 3) world joints placed at the predicted translation t̂ = μ⁻[:3].
        C: (P, 6, 6) the previous frame's covariance of τ (predicted here: C⁻ = F C Fᵀ + Q).
        sigma: (3,) σ_t.
        velocity: (3,) v, the velocity's decay in F (ones: constant velocity).
        z: one frame's observation (``likelihood.observation_shape``, at least one joint seen).
        likelihood: an observation model with ``linearised`` (a Gaussian :class:`JointLikelihood`:
            one camera, z (J, 2); a :class:`MultiViewLikelihood`: z (C, J, 3)).

    Returns:
        the shift μ⁺ − μ⁻ (P, 6), the updated covariance C⁺ (P, 6, 6), and
        log p(z | t̂) + ½ bᵀ P y − ½ log det N (P,), the log predictive likelihood with t
        integrated out (p(z | t̂) as ``likelihood`` scores it: a joint behind the camera counts as
        a miss of the image diagonal there, and does not inform the update).
    """
    single = isinstance(likelihood, JointLikelihood)
    frame = "(J, 2)" if single else str(tuple(likelihood.observation_shape))
    if joints.dim() != 3 or joints.shape[2] != 3 or C.shape != (len(joints), 6, 6) or \
            (single and tuple(z.shape) != (joints.shape[1], 2)):
        raise PriortrackError(f"joints {tuple(joints.shape)}, covariances {tuple(C.shape)} and observation "
                              f"{tuple(z.shape)}: expected (P, J, 3), (P, 6, 6) and {frame}")
    if single and cpu_kernel_applies(joints, C) and not likelihood.camera.distorted:
        # The fused kernel: one ideal pinhole, the Gaussian.
        seen = torch.isfinite(z).all(dim=-1).nonzero()[:, 0]
        joints, z = joints.index_select(1, seen), z[seen]
        inv_var = 1.0 / likelihood.sigma_px ** 2
        from priortrack.filters.kalman_kernel import update

        # in float64 whatever the particles' dtype (as the torch path below: float32 loses C⁺ at sharp pixels)
        f64 = torch.float64
        P, p = likelihood.camera.projection(joints.device, f64)
        shift, C_post = torch.empty(C.shape[:2], dtype=f64), torch.empty(C.shape, dtype=f64)
        correction, d_sq = torch.empty(C.shape[:1], dtype=f64), torch.empty(C.shape[:1], dtype=f64)
        X, Z, C_prev, Pn, pn = (joints.detach().to(f64).contiguous().numpy(), z.to(f64).contiguous().numpy(),
                                C.detach().to(f64).contiguous().numpy(), P.numpy(), p.numpy())
        sigma_sq = (sigma ** 2).to(f64).numpy()
        v = velocity.to(f64).numpy()
        out = (shift.numpy(), C_post.numpy(), correction.numpy(), d_sq.numpy())
        split_rows(len(X), lambda r: update(X[r], Z, Pn, pn, inv_var, MIN_DEPTH, likelihood.miss_sq, C_prev[r],
                                            sigma_sq, v, *(a[r] for a in out)))
        return (shift.to(C.dtype), C_post.to(C.dtype),
                (likelihood.gaussian(d_sq, len(seen)) + correction).to(C.dtype))
    dtype = C.dtype
    C = predict_covariance(C, sigma, velocity).double()
    A, b, log_p = likelihood.linearised(joints, z)
    # in float64 whatever the particles' dtype: N = I + A P reaches 1e8 where the pixels are sharp (σ = 0.01 px),
    # and C − C A N⁻¹ C loses every digit of float32 there (negative variances, then NaN states)
    A, b = A.double(), b.double()
    P = C[:, :3, :3]
    N = torch.eye(3, dtype=C.dtype, device=C.device) + _product(A, P)
    N_inv, det = _inverse_3x3(N)                                                       # det N > 0
    y = _product(N_inv, b[..., None])[..., 0]
    gain = C[:, :, :3]                                                                 # C⁻[:, :3]
    shift = _product(gain, y[..., None])[..., 0]
    C_post = C - _product(_product(gain, _product(N_inv, A)), C[:, :3, :])
    correction = 0.5 * (b * _product(P, y[..., None])[..., 0]).sum(-1) - 0.5 * torch.log(det.abs())
    return shift.to(dtype), C_post.to(dtype), log_p + correction.to(log_p.dtype)


def _product(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a @ b of batches of small matrices (…, n, k) @ (…, k, m): on a GPU as one broadcast product and sum
    (cuBLAS's batched products of 10⁶ 3 × 3 matrices cost more than the arithmetic: the weight phase of 10⁶
    particles 41 → 25 ms on an H100), on the CPU as matmul (the broadcast's temporaries made the update 2.5×
    slower at 10³ particles)."""
    return a @ b if a.device.type == "cpu" else broadcast_product(a, b)


def broadcast_product(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a @ b (…, n, k) @ (…, k, m) as Σ_j a[…, :, j, None] b[…, None, j, :]: one elementwise product and a sum."""
    return (a[..., :, :, None] * b[..., None, :, :]).sum(-2)


def _inverse_3x3(N: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """N⁻¹ (…, 3, 3) by the adjugate, and det N (…,): column i of N⁻¹ is the cross product of N's other two
    rows (in cyclic order) over det N, as in the CPU kernel."""
    r0, r1, r2 = N[..., 0, :], N[..., 1, :], N[..., 2, :]
    adjugate = torch.stack([torch.linalg.cross(r1, r2), torch.linalg.cross(r2, r0), torch.linalg.cross(r0, r1)], -1)
    det = (r0 * adjugate[..., 0]).sum(-1)
    return adjugate / det[..., None, None], det


def transition_matrix(velocity: torch.Tensor) -> torch.Tensor:
    """F (6, 6) = [[I + V, −V], [I, 0]] of τ = (t_t, t_{t−1}), V = diag v (module docstring)."""
    V = torch.diag(velocity)
    eye = torch.eye(3, dtype=velocity.dtype, device=velocity.device)
    return torch.cat([torch.cat([eye + V, -V], 1), torch.cat([eye, torch.zeros_like(eye)], 1)])


def smooth_translation(model, states: torch.Tensor, covariance: torch.Tensor, observations) -> torch.Tensor:
    """The Rao–Blackwellised translation of drawn trajectories: for each trajectory's poses and
    rotations, the Kalman filter of τ (module docstring) forward over the frames, then the
    Rauch–Tung–Striebel smoother backward,

        τ^s_k = μ_k + G_k (τ^s_{k+1} − F μ_k),   G_k = C_k Fᵀ (F C_k Fᵀ + Q)⁺

    (a pseudo-inverse: a start known exactly has C = 0 and no gain).

    Args:
        model: the TrackingModel.
        states: (M, W, S + 12) trajectories; their first frame's translations are that frame's
            Kalman means μ_0, the later frames' are replaced.
        covariance: (M, 6, 6) C_0 of the first frame.
        observations: (W, *observation_shape), the frames' data (gated as the filter gates them).

    Returns:
        (M, W, 6) the smoothed τ_k = (t_k, t_{k−1}).
    """
    motion = model.global_motion
    sigma, velocity = motion.sigma[:3].to(states), motion.velocity.to(states)
    F = transition_matrix(velocity)
    mu, C = model.translation(states[:, 0]), covariance.to(states)
    means, covariances = [mu], [C]
    for k in range(1, states.shape[1]):
        mu = mu @ F.T
        z = torch.as_tensor(observations[k], dtype=states.dtype, device=states.device)
        z = model.gate(z)[0].to(z)
        if torch.isfinite(z).any():
            joints = model.observe(model.with_translation(states[:, k], mu))
            shift, C, _ = kalman_update(joints, C, sigma, velocity, z, model.likelihood)
            mu = mu + shift
        else:
            C = predict_covariance(C, sigma, velocity)
        means.append(mu)
        covariances.append(C)
    smoothed = [means[-1]]
    for mu, C in zip(reversed(means[:-1]), reversed(covariances[:-1])):
        gain = C @ F.T @ torch.linalg.pinv(predict_covariance(C, sigma, velocity), hermitian=True)
        smoothed.append(mu + (gain @ (smoothed[-1] - mu @ F.T)[..., None])[..., 0])
    return torch.stack(smoothed[::-1], 1)
