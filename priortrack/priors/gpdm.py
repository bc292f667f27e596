"""Gaussian process dynamical models (Wang, Fleet, Hertzmann, PAMI 2008) and the balanced
GPDM (Urtasun, Fleet, Fua, CVPR 2006) as a transition model over a low-dimensional latent space.

Training poses Y (N, D) are the angle channels of :class:`~priortrack.priors.spaces.AngleSpace`
with their mean subtracted; every frame has a latent position, a row of X (N, d). Two GPs:

- reconstruction, Y ← X, kernel k_Y(x, x') = β1 exp(−β2/2 |x − x'|²) + δ(x, x')/β3, with a scale
  w_k per data dimension (W = diag(w_1..w_D));
- dynamics, X_out ← X_in, kernel k_X(x, x') = α1 exp(−α2/2 |x − x'|²) + α3 xᵀx' + δ(x, x')/α4,
  where X_in holds every frame but each sequence's last and X_out every frame but each
  sequence's first (no transition crosses a sequence boundary); each sequence's first frame
  has an N(0, I) prior.

Learning minimises the negative log posterior (constants dropped)

    L = D/2 ln|K_Y| + ½ tr(K_Y⁻¹ Y W² Yᵀ) − N ln|W| + Σ_k w_k²/(2κ²)
        + λ [ d/2 ln|K_X| + ½ tr(K_X⁻¹ X_out X_outᵀ) ] + ½ Σ_seq x_1ᵀx_1 + Σ_i ln α_i + Σ_i ln β_i

with the half-normal prior of scale κ = 10³ on each w_k, whose argmin over W is the closed form
w_k² = N / (Y_kᵀ K_Y⁻¹ Y_k + 1/κ²), recomputed inside the objective; the hyperparameter priors
are ∏ θ⁻¹; λ = 1 for the GPDM and λ = D/d for the balanced GPDM (B-GPDM).

That objective has no lower bound: (1) scaling X by s (with α1, α2, α4, β2 following) lowers it
by about λ d (N − S) ln(1/s), so the latent points collapse; (2) scaling K_Y by c and W by 1/√c
leaves it unchanged but for the κ term, which drifts c towards 0; (3) an exactly predictable
latent path sends the dynamics noise 1/α4 to 0, and squeezing the latent points onto a line that
each sequence runs along at constant speed makes the path exactly linear. The learning problem
solved here is bounded:

- the latent positions are whitened: mean free, covariance I_d (as the whitened-PCA start), so
  neither their scale nor their spread over the d dimensions can collapse; the optimiser moves
  X̃ and X = m + (X̃ − m) C⁻ᵀ with m the mean of X̃ and C Cᵀ the covariance of X̃;
- β1 = 1 is fixed (W carries the scale of the data, so W-scaled data have variance ≈ 1);
- every log hyperparameter lies in [ln 10⁻⁶, ln 10⁶] (as Wang's reference code clamps them), and:
  1/β3 ≥ 10⁻⁴ β1 (reconstruction noise at least 10⁻⁴ of the W-scaled data variance);
  1/α4 ≥ 10⁻⁴ (dynamics noise std at least 1 % of the unit latent std, ~3 % of a 30-fps latent
  step; ``GPDM.fit(dynamics_noise_floor=…)`` sets another floor); α2, β2 ≥ 10⁻² (RBF length
  scales at most 10 latent std: beyond the latent extent an RBF is a polynomial and only drifts).

L is continuous on that compact set, so a minimum exists. The balanced fit ends with the dynamics
noise on its floor (an active bound, the only one it needs) and a smooth closed latent cycle for
walking. Floors tried on the bench problem: 10⁻⁶ (no convergence in 4000 iterations, the RBF
drifting towards a polynomial), 10⁻³ and 10⁻² (the latent unrolled into a helix or a line along
time, the RBF switched off).
L-BFGS-B stops when an iteration lowers L by less than ``FTOL`` relative (1e-7: 0.01 nat at
|L| ≈ 10⁵, and on the 300-frame bench L then lies within ~15 nats of its value 1200 iterations
later, far inside the posterior's own spread of ~(N d)/2 nats) or the largest projected gradient
entry is below ``GTOL``; ``converged`` records that it did so within ``MAXITER`` iterations.

Prediction (Urtasun et al. eqs. 19–20), for latent rows x (P, d):

    μ_Y(x) = mean + Yᵀ K_Y⁻¹ k_Y(x),   σ²(x) = k_Y(x, x) − k_Y(x)ᵀ K_Y⁻¹ k_Y(x)   (W-scaled units),
    μ_X(x) = X_outᵀ K_X⁻¹ k_X(x),      σ_X²(x) = k_X(x, x) − k_X(x)ᵀ K_X⁻¹ k_X(x),

where k(x, x) includes the noise term (the prediction of a new noisy pose / next latent state).
The transition model is x_t ~ N(μ_X(x_{t−1}), σ_X²(x_{t−1}) I_d).
"""

from __future__ import annotations

import contextlib
import copy
import itertools
import logging
import math
import time
from collections.abc import Callable, Sequence
from numbers import Real

import numpy as np
import torch
from scipy.optimize import minimize

try:
    from threadpoolctl import threadpool_limits
except ImportError:  # optional: only a speed-up
    threadpool_limits = None

from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.geometry.linalg import jittered_cholesky
from priortrack.priors.base import DEFAULT_FPS, TransitionModel, prepare_motions
from priortrack.priors.spaces import AngleSpace, EuclideanSpace
from priortrack.randomness import standard_normal
from priortrack.threads import torch_threads

log = logging.getLogger(__name__)

#: Scale of the half-normal prior on each w_k.
KAPPA = 1e3
#: Every hyperparameter lies in [1/HYPER_BOUND, HYPER_BOUND].
HYPER_BOUND = 1e6
#: 1/β3 ≥ NOISE_FLOOR_Y · β1: the reconstruction noise floor relative to the data variance.
NOISE_FLOOR_Y = 1e-4
#: 1/α4 ≥ NOISE_FLOOR_X: the dynamics noise floor relative to the unit latent variance.
NOISE_FLOOR_X = 1e-4
#: Latent rows per block of a prediction on the CPU (:func:`_in_blocks`): a block's (rows, N)
#: float64 kernel matrix, 0.8 MB at N = 100, fits a 1 MiB L2 cache. The dynamics of 10⁴ particles
#: (N = 100, 2 threads) took 14 ms in blocks of 1024 against 20–27 ms in one (500: 17, 2000: 15–17).
BLOCK_ROWS = 1024
#: α2, β2 ≥ INV_WIDTH_MIN: RBF length scales at most 1/√INV_WIDTH_MIN latent standard deviations.
INV_WIDTH_MIN = 1e-2
#: β1, fixed (W carries the data scale).
BETA1 = 1.0
#: L-BFGS-B stopping tolerances: relative decrease of L in one iteration, largest projected gradient entry.
FTOL = 1e-7
GTOL = 1e-5
#: Iteration cap of a fit (a fit that reaches it is recorded as not converged).
MAXITER = 3000
#: Cholesky jitter: none first; on failure this times the mean diagonal, then ×10 per failure.
JITTER_START = 1e-8
JITTER_TRIES = 10
#: Fewest training frames a fit accepts.
MIN_FRAMES = 10
#: Initial hyperparameters: α = (α1, α2, α3, α4), β = (β1, β2, β3).
ALPHA_INIT = (1.0, 1.0, 1.0, 100.0)
BETA_INIT = (BETA1, 1.0, 100.0)
#: Standard deviation of the seeded perturbation added to the whitened-PCA latent positions.
INIT_JITTER = 1e-3


# ---- the objective -----------------------------------------------------------------------------

def cholesky(K: torch.Tensor) -> torch.Tensor:
    """Lower Cholesky factor of a kernel matrix (n, n): :func:`jittered_cholesky` from
    JITTER_START × its mean diagonal, ×10 on each failure (JITTER_TRIES tries)."""
    n = K.shape[-1]
    return jittered_cholesky(K, f"kernel matrix ({n}×{n})", JITTER_START, JITTER_START * 10 ** (JITTER_TRIES - 1))


def rbf(A: torch.Tensor, B: torch.Tensor, log_amplitude: torch.Tensor, inv_width: torch.Tensor) -> torch.Tensor:
    """(n, d), (m, d) → (n, m) exp(ln a − w/2 |a − b|²), the exponent from one matrix product of
    augmented rows [w a, −w/2 |a|², 1, ln a] · [b, 1, −w/2 |b|², 1]."""
    half = -0.5 * inv_width
    ones_A, ones_B = A.new_ones(A.shape[0], 1), B.new_ones(B.shape[0], 1)
    left = torch.cat([inv_width * A, half * A.pow(2).sum(-1, keepdim=True), ones_A, log_amplitude * ones_A], dim=1)
    right = torch.cat([B, ones_B, half * B.pow(2).sum(-1, keepdim=True), ones_B], dim=1)
    return torch.exp(left @ right.T)


def k_Y(A: torch.Tensor, B: torch.Tensor, log_beta: torch.Tensor) -> torch.Tensor:
    """Reconstruction kernel without its noise term, β1 exp(−β2/2 |a − b|²): (n, m)."""
    return rbf(A, B, log_beta[0], log_beta[1].exp())


def k_X(A: torch.Tensor, B: torch.Tensor, log_alpha: torch.Tensor) -> torch.Tensor:
    """Dynamics kernel without its noise term, α1 exp(−α2/2 |a − b|²) + α3 aᵀb: (n, m)."""
    return torch.addmm(rbf(A, B, log_alpha[0], log_alpha[1].exp()), log_alpha[2].exp() * A, B.T)


def _in_blocks(predict: Callable, x: torch.Tensor, variance: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
    """``predict(x, variance)`` → (mean (P, ·), variance (P,) or None) applied to blocks of
    ``BLOCK_ROWS`` rows of x (P, d) on the CPU, the results joined: the same numbers, but each
    block's (rows, N) kernel matrix and solve stay in a core's cache instead of streaming through
    memory once per operation. One block on other devices, where launches cost more than memory."""
    if x.device.type != "cpu" or len(x) <= BLOCK_ROWS:
        return predict(x, variance)
    blocks = [predict(block, variance) for block in x.split(BLOCK_ROWS)]
    mean = torch.cat([m for m, _ in blocks])
    return mean, (torch.cat([v for _, v in blocks]) if variance else None)


def _runs(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Runs of equal consecutive rows of x (P, d): the index of each run's first row (R,) and
    each row's run (P,), so that x[first][run] equals x."""
    new = torch.ones(len(x), dtype=torch.bool, device=x.device)
    new[1:] = (x[1:] != x[:-1]).any(dim=1)
    return new.nonzero().squeeze(1), torch.cumsum(new, 0) - 1


def transition_rows(lengths: Sequence[int], device=None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Row indices of the concatenated sequences: (first (S,), X_in (N−S,), X_out (N−S,))."""
    ends = np.cumsum(lengths)
    starts = ends - np.asarray(lengths)
    inp = np.concatenate([np.arange(s, e - 1) for s, e in zip(starts, ends)])
    as_tensor = lambda a: torch.as_tensor(a, dtype=torch.long, device=device)  # noqa: E731
    return as_tensor(starts), as_tensor(inp), as_tensor(inp + 1)


def closed_form_W(q: torch.Tensor, N: int, kappa: float = KAPPA) -> torch.Tensor:
    """w_k = √(N / (q_k + 1/κ²)) with q_k = Y_kᵀ K_Y⁻¹ Y_k: (D,) → (D,), the argmin of L over W."""
    return torch.sqrt(N / (q + kappa ** -2))


class _LogdetQuad(torch.autograd.Function):
    """(S (n, n) symmetric, s² scalar, B (n, m)) → (ln|K|, q (m,)) for K = S + s² I, with
    q_k = B_kᵀ K⁻¹ B_k, by one Cholesky factorisation K = L Lᵀ. Backward, with a_k = K⁻¹ B_k:
    ∂ln|K|/∂K = K⁻¹ (``cholesky_inverse`` of the factor), ∂q_k/∂K = −a_k a_kᵀ, ∂q_k/∂B_k = 2 a_k,
    and ∂/∂s² = tr(∂/∂K). (Four times cheaper than differentiating through the factorisation.)"""

    @staticmethod
    def forward(ctx, S, noise, B):
        K = S.clone()
        K.diagonal().add_(noise)
        L = cholesky(K)
        A = torch.cholesky_solve(B, L)
        ctx.save_for_backward(L, A)
        return 2 * torch.log(L.diagonal()).sum(), (B * A).sum(0)

    @staticmethod
    def backward(ctx, g_logdet, g_q):
        L, A = ctx.saved_tensors
        Ag = A * g_q
        gK = torch.cholesky_inverse(L).mul_(g_logdet).sub_(Ag @ A.T)
        return gK, gK.diagonal().sum(), 2 * Ag


def gpdm_objective(X: torch.Tensor, log_alpha: torch.Tensor, log_beta: torch.Tensor, Y: torch.Tensor,
                   lengths: Sequence[int], balanced: bool = True, W: torch.Tensor | None = None,
                   kappa: float = KAPPA) -> torch.Tensor:
    """The negative log posterior L of the module docstring, a scalar (differentiable).

    Args:
        X: (N, d) latent positions. log_alpha: (4,) ln α. log_beta: (3,) ln β.
        Y: (N, D) training poses, mean subtracted. lengths: frames per sequence, summing to N.
        balanced: λ = D/d if True, else 1.
        W: (D,) data scales; None uses the closed form (then L is minimal over W).
    """
    N, D = Y.shape
    d = X.shape[1]
    first, inp, out = transition_rows(lengths, X.device)
    logdet_Y, q = _LogdetQuad.apply(k_Y(X, X, log_beta), torch.exp(-log_beta[2]), Y)   # q_k = Y_kᵀ K_Y⁻¹ Y_k
    w2 = closed_form_W(q, N, kappa) ** 2 if W is None else W ** 2
    reconstruction = (0.5 * D * logdet_Y + 0.5 * (w2 * q).sum()
                      - 0.5 * N * torch.log(w2).sum() + 0.5 * w2.sum() / kappa ** 2)
    X_in, X_out = X[inp], X[out]
    logdet_X, q_X = _LogdetQuad.apply(k_X(X_in, X_in, log_alpha), torch.exp(-log_alpha[3]), X_out)
    dynamics = 0.5 * d * logdet_X + 0.5 * q_X.sum()
    lam = D / d if balanced else 1.0
    return reconstruction + lam * dynamics + 0.5 * X[first].pow(2).sum() + log_alpha.sum() + log_beta.sum()


def _single_blas_thread():
    """A context limiting numpy/scipy's BLAS to one thread (a no-op without threadpoolctl): L-BFGS-B's
    BLAS threads otherwise spin between its steps and starve torch's (a 3–4× slower fit on 2 cores)."""
    return contextlib.nullcontext() if threadpool_limits is None else threadpool_limits(1, user_api="blas")


def _optimise(Y: torch.Tensor, lengths: Sequence[int], X0: torch.Tensor, balanced: bool,
              progress: Callable[[int, float], None] | None,
              noise_floor_x: float = NOISE_FLOOR_X) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict]:
    """Minimise L over (X, ln α, ln β2, ln β3) with L-BFGS-B (module docstring: bounds, whitened
    latents, tolerances; 1/α4 ≥ ``noise_floor_x``). Returns X (N, d), ln α (4,), ln β (3,) and the
    fit summary."""
    N, d = X0.shape
    log_bound = math.log(HYPER_BOUND)
    log_beta1 = torch.tensor([math.log(BETA1)], dtype=torch.float64)

    def unpack(p: torch.Tensor):
        X_tilde = p[:N * d].reshape(N, d)
        centre = X_tilde.mean(0)
        Z = X_tilde - centre
        C = torch.linalg.cholesky(Z.T @ Z / N)                                    # Z's covariance = C Cᵀ
        X = centre + torch.linalg.solve_triangular(C, Z.T, upper=False).T
        return X, p[N * d:N * d + 4], torch.cat([log_beta1, p[N * d + 4:]])

    def f(p_np: np.ndarray):
        p = torch.from_numpy(p_np).requires_grad_(True)
        L = gpdm_objective(*unpack(p), Y, lengths, balanced)
        (grad,) = torch.autograd.grad(L, p)
        return L.item(), grad.numpy()

    log_alpha0 = np.log(ALPHA_INIT)
    log_alpha0[3] = min(log_alpha0[3], -math.log(noise_floor_x))             # the start inside the bound
    p0 = np.concatenate([X0.reshape(-1).numpy(), log_alpha0, np.log(BETA_INIT[1:])])
    log_width = math.log(INV_WIDTH_MIN)
    bounds = ([(None, None)] * (N * d) + [(-log_bound, log_bound), (log_width, log_bound), (-log_bound, log_bound),
                                          (-log_bound, -math.log(noise_floor_x))]
              + [(log_width, log_bound), (-log_bound, -math.log(NOISE_FLOOR_Y * BETA1))])
    counter = itertools.count(1)

    def callback(intermediate_result):
        progress(next(counter), float(intermediate_result.fun))

    with _single_blas_thread():
        result = minimize(f, p0, jac=True, method="L-BFGS-B", bounds=bounds,
                          callback=None if progress is None else callback,
                          options={"ftol": FTOL, "gtol": GTOL, "maxiter": MAXITER, "maxfun": 2 * MAXITER})
    X, log_alpha, log_beta = (t.detach().clone() for t in unpack(torch.from_numpy(result.x)))
    summary = {"iterations": int(result.nit), "evaluations": int(result.nfev), "objective": float(result.fun),
               "converged": bool(result.success), "message": str(result.message)}
    return X, log_alpha, log_beta, summary


# ---- the model ---------------------------------------------------------------------------------

class LatentSpace(EuclideanSpace):
    """The GPDM's state space: the latent R^d, Euclidean (⊞ = +, ⊟ = −), one group per latent
    dimension ("x0", "x1", …). Decoding goes through the reconstruction mean μ_Y(x) and the
    angle space of the training motions."""

    def __init__(self, model: GPDM, angles: AngleSpace):
        self.model, self.angles = model, angles
        self.group_names = tuple(f"x{i}" for i in range(model.d))
        self.groups = np.arange(model.d)
        self.tangent_dims = np.ones(model.d, dtype=int)

    def encode(self, motion: Motion) -> torch.Tensor:
        """(T, d) latent positions of a motion's frames (:meth:`GPDM.encode_poses`)."""
        return self.model.encode_poses(self.angles.encode(motion))

    def joints(self, x: torch.Tensor) -> torch.Tensor:
        flat = x.reshape(-1, self.dim)
        return self.angles.joints(self.model.pose_mean(flat)).reshape(x.shape[:-1] + (15, 3))

    def pose_joints(self, motion: Motion) -> torch.Tensor:
        """(T, 15, 3) the motion's own poses through the angle space, not μ_Y of their latents
        (a reconstruction, off by the model's error)."""
        return self.angles.pose_joints(motion)

    def for_body(self, motion: Motion) -> LatentSpace:
        return type(self)(self.model, self.angles.for_body(motion))

    def to_arrays(self) -> dict[str, np.ndarray]:
        return self.angles.to_arrays()

    def global_pose(self, motion: Motion) -> torch.Tensor:
        return self.angles.global_pose(motion)


class GPDM(TransitionModel):
    """A (balanced) GPDM over latent states x (P, d).

    Attributes:
        X: (N, d) training latent positions. Y: (N, D) training poses (radians, mean subtracted).
        mean_pose: (D,) the subtracted mean. lengths: frames of each training sequence.
        log_alpha: (4,) ln α. log_beta: (3,) ln β. W: (D,) data scales.
        balanced: λ = D/d (``bgpdm``) or 1 (``gpdm``). fit_summary: iterations, evaluations,
        objective, converged, message, seconds. objective: the fit's final L (NaN if not fitted),
        as every prior reports one.
    """

    def __init__(self, angles: AngleSpace, X, Y, mean_pose, lengths: Sequence[int], log_alpha, log_beta,
                 balanced: bool, fps: float = DEFAULT_FPS, W=None, fit_summary: dict | None = None):
        as64 = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64)).clone()  # noqa: E731
        self.X, self.Y, self.mean_pose = as64(X), as64(Y), as64(mean_pose)
        self.log_alpha, self.log_beta = as64(log_alpha), as64(log_beta)
        self.lengths = [int(n) for n in lengths]
        N, D = self.Y.shape
        if self.X.dim() != 2 or self.X.shape[0] != N or sum(self.lengths) != N or self.mean_pose.shape != (D,):
            raise PriortrackError(f"GPDM arrays disagree: X {tuple(self.X.shape)}, Y {tuple(self.Y.shape)}, "
                                  f"mean {tuple(self.mean_pose.shape)}, sequence lengths sum {sum(self.lengths)}")
        if self.log_alpha.shape != (4,) or self.log_beta.shape != (3,):
            raise PriortrackError("GPDM hyperparameters must be ln α (4,) and ln β (3,)")
        self.balanced, self.fps = bool(balanced), float(fps)
        self.kind = "bgpdm" if balanced else "gpdm"
        self.d, self.D = self.X.shape[1], D
        self.alpha, self.beta = self.log_alpha.exp(), self.log_beta.exp()
        self.fit_summary = dict(fit_summary or {})
        self.objective = float(self.fit_summary.get("objective", float("nan")))
        #: λ of :meth:`annealed`; 1 is the transition as learned.
        self.annealing = 1.0

        first, inp, out = transition_rows(self.lengths)
        self.X_in, self.X_out = self.X[inp], self.X[out]
        # Factorised on one thread: LAPACK's threaded Cholesky rounds by its thread count, and a
        # model loaded in another process (``eval tracking --jobs``) must predict bit for bit alike.
        with torch_threads(1):
            self.L_Y = cholesky(k_Y(self.X, self.X, self.log_beta) + torch.eye(N, dtype=torch.float64) / self.beta[2])
            self.A_Y = torch.cholesky_solve(self.Y, self.L_Y)                      # K_Y⁻¹ Y (N, D)
            self.W = closed_form_W((self.Y * self.A_Y).sum(0), N) if W is None else as64(W)
            K_X = k_X(self.X_in, self.X_in, self.log_alpha) + torch.eye(len(inp), dtype=torch.float64) / self.alpha[3]
            self.L_X = cholesky(K_X)
            self.A_X = torch.cholesky_solve(self.X_out, self.L_X)                  # K_X⁻¹ X_out (N−S, d)
        self._device_cache: dict[str, dict[str, torch.Tensor]] = {}
        self.space = LatentSpace(self, angles)

    # ---- learning --------------------------------------------------------------------------
    @classmethod
    def fit(cls, motions: Sequence[Motion], balanced: bool = True, d: int = 3, fps: float = DEFAULT_FPS,
            seed: int = 0, dynamics_noise_floor: float = NOISE_FLOOR_X,
            progress: Callable[[int, float], None] | None = None) -> GPDM:
        """Learn a GPDM (``balanced=False``) or B-GPDM from training motions (one sequence each).

        Motions are resampled to ``fps``; X starts at the whitened PCA of Y (unit variance per
        latent dimension) plus N(0, 10⁻⁶) noise drawn with ``seed`` (so that repeated frames get
        distinct latents); ``progress(iteration, L)`` is called after every L-BFGS-B iteration.
        ``dynamics_noise_floor`` is the lower bound on the dynamics noise 1/α4 (module docstring),
        in (10⁻⁶, 1): the fits end on it, so it sets how sure the learned dynamics are of the next
        latent position (recorded in ``fit_summary``).
        """
        start = time.perf_counter()
        motions = prepare_motions(motions, fps, min_frames=3)
        angles = AngleSpace.fit(motions)
        sequences = [angles.encode(m) for m in motions]
        Y = torch.cat(sequences)
        N, D = Y.shape
        if N < MIN_FRAMES:
            raise PriortrackError(f"a GPDM needs at least {MIN_FRAMES} training frames; got {N} at {fps:g} fps")
        if not isinstance(d, int | np.integer) or not 1 <= d < D:
            raise PriortrackError(f"latent dimension d must be an integer in [1, {D}) for {D} pose channels; got {d!r}")
        if not isinstance(dynamics_noise_floor, Real) or not 1 / HYPER_BOUND < dynamics_noise_floor < 1:
            raise PriortrackError(f"dynamics_noise_floor must lie in ({1 / HYPER_BOUND:g}, 1); got {dynamics_noise_floor!r}")
        mean_pose = Y.mean(0)
        Y = Y - mean_pose
        U, _, _ = torch.linalg.svd(Y, full_matrices=False)
        generator = torch.Generator().manual_seed(int(seed))
        X0 = math.sqrt(N) * U[:, :d] + INIT_JITTER * torch.randn(N, d, generator=generator, dtype=torch.float64)
        lengths = [len(s) for s in sequences]
        X, log_alpha, log_beta, summary = _optimise(Y, lengths, X0, balanced, progress, float(dynamics_noise_floor))
        summary.update(dynamics_noise_floor=float(dynamics_noise_floor), seconds=time.perf_counter() - start)
        log.info("%s fit: N=%d D=%d d=%d, %d iterations, L=%.6g, converged=%s (%s), %.1f s",
                 "bgpdm" if balanced else "gpdm", N, D, d, summary["iterations"], summary["objective"],
                 summary["converged"], summary["message"], summary["seconds"])
        return cls(angles, X, Y, mean_pose, lengths, log_alpha, log_beta, balanced, fps, fit_summary=summary)

    def recompute_objective(self) -> float:
        """L evaluated afresh at the model's own X, α, β (closed-form W)."""
        with torch.no_grad():
            return float(gpdm_objective(self.X, self.log_alpha, self.log_beta, self.Y, self.lengths, self.balanced))

    # ---- prediction ------------------------------------------------------------------------
    def _on(self, device, dtype=torch.float64) -> dict[str, torch.Tensor]:
        """The arrays that prediction needs, on ``device`` in ``dtype`` (cached)."""
        key = (str(device), dtype)
        if key not in self._device_cache:
            names = ("X", "X_in", "L_Y", "A_Y", "L_X", "A_X", "mean_pose", "W", "alpha", "beta",
                     "log_alpha", "log_beta")
            self._device_cache[key] = {n: getattr(self, n).to(device=device, dtype=dtype) for n in names}
        return self._device_cache[key]

    def _latent(self, x, name: str = "x") -> torch.Tensor:
        """Check (P, d) latent rows; returned in their working dtype (:meth:`_working`)."""
        return self._working(self.check_state(x, name))

    @staticmethod
    def _working(x: torch.Tensor) -> torch.Tensor:
        """Checked latent rows in float32 if they are float32, else in float64, on their device."""
        return x if x.dtype == torch.float32 else x.to(torch.float64)

    def _reconstruct(self, x: torch.Tensor, variance: bool = True) -> tuple[torch.Tensor, torch.Tensor | None]:
        """μ_Y(x) (eq. 19) and σ²(x) (eq. 20) in float64, or μ_Y(x) alone in x's dtype (float32 or
        float64, from :meth:`_latent`) when ``variance`` is False. σ² is a difference of numbers
        far larger than itself (float32 kernel rows would cost it ~20%), and costs a triangular
        solve against the (N, N) factor, as much as the rest together. Row blocks: :func:`_in_blocks`."""
        return _in_blocks(self._reconstruct_block, x, variance)

    def _reconstruct_block(self, x: torch.Tensor, variance: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        x = x.to(torch.float64) if variance else x
        t = self._on(x.device, x.dtype)
        k = k_Y(x, t["X"], t["log_beta"])                                       # (P, N)
        mu = t["mean_pose"] + k @ t["A_Y"]
        if not variance:
            return mu, None
        v = torch.linalg.solve_triangular(t["L_Y"], k.T, upper=False)           # L_Y⁻¹ k_Y(x)
        noise = 1.0 / t["beta"][2]
        var = t["beta"][0] + noise - v.pow(2).sum(0)
        return mu, torch.clamp(var, min=noise)

    def _dynamics(self, x: torch.Tensor, variance: bool = True) -> tuple[torch.Tensor, torch.Tensor | None]:
        """μ_X(x) and σ_X²(x) in float64, or μ_X(x) alone in x's dtype when ``variance`` is False
        (as :meth:`_reconstruct`)."""
        return _in_blocks(self._dynamics_block, x, variance)

    def _dynamics_block(self, x: torch.Tensor, variance: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        x = x.to(torch.float64) if variance else x
        t = self._on(x.device, x.dtype)
        k = k_X(x, t["X_in"], t["log_alpha"])                                   # (P, N−S)
        mu = k @ t["A_X"]
        if not variance:
            return mu, None
        v = torch.linalg.solve_triangular(t["L_X"], k.T, upper=False)
        noise = 1.0 / t["alpha"][3]
        var = t["alpha"][0] + t["alpha"][2] * x.pow(2).sum(-1) + noise - v.pow(2).sum(0)
        return mu, torch.clamp(var, min=noise)

    def reconstruct(self, x) -> tuple[torch.Tensor, torch.Tensor]:
        """Latent rows x (P, d) → (μ_Y(x) (P, D) radians including the mean pose, σ²(x) (P,) in
        W-scaled units: channel k's variance is σ²(x)/w_k²), eqs. 19–20; in x's dtype."""
        x = torch.as_tensor(x)
        mu, var = self._reconstruct(self._latent(x))
        return mu.to(x.dtype), var.to(x.dtype)

    def pose_mean(self, x) -> torch.Tensor:
        """Latent rows x (P, d) → μ_Y(x) (P, D) radians including the mean pose (eq. 19), without
        the variance; in x's dtype."""
        x = torch.as_tensor(x)
        return self._reconstruct(self._latent(x), variance=False)[0].to(x.dtype)

    def dynamics(self, x) -> tuple[torch.Tensor, torch.Tensor]:
        """Latent rows x (P, d) → (μ_X(x) (P, d), σ_X²(x) (P,)): the next state's mean and the
        variance of each of its coordinates; in x's dtype."""
        x = torch.as_tensor(x)
        mu, var = self._dynamics(self._latent(x))
        return mu.to(x.dtype), var.to(x.dtype)

    def annealed(self, annealing: float) -> GPDM:
        """This model with its transition raised to the power λ = ``annealing`` and renormalised,

            p(x_t | x_{t−1})^λ ∝ N(x_t; μ_X(x_{t−1}), σ_X²(x_{t−1})/λ I_d),

        the dynamics annealing of Urtasun et al. (their λ weighs the dynamics term of the tracking
        energy, eq. 21), here for the filters that draw from the prior: :meth:`sample`,
        :meth:`log_prob` and :meth:`transition_covariance` use σ_X²/λ; :meth:`dynamics` stays the
        learned model, and the MAP tracker takes its λ itself. λ ∈ (0, 1]; a tracking-time
        setting, not saved with the model. Shares this model's arrays."""
        if not 0.0 < annealing <= 1.0:
            raise PriortrackError(f"GPDM dynamics annealing must be in (0, 1], got {annealing!r}")
        model = copy.copy(self)
        model.annealing = float(annealing)
        return model

    def _transition(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """μ_X(x) and the transition's variance σ_X²(x)/λ (P,), float64."""
        mu, var = self._dynamics(x)
        return mu, var / self.annealing

    # ---- the transition-model contract -----------------------------------------------------
    def sample(self, x, generator: torch.Generator) -> torch.Tensor:
        """(P, d) → (P, d): x_t ~ N(μ_X(x), σ_X²(x)/λ I_d) per row (λ = 1 unless :meth:`annealed`),
        noise drawn from ``generator``.

        A row equal to the row before it shares that row's μ_X and σ_X² (:func:`_runs`): the
        copies of a resampled particle sit side by side, and after a resampling step half or
        more of the rows are such copies, so the (P × N) kernel rows and the triangular solve
        are taken over the distinct rows only."""
        x = torch.as_tensor(x)
        latent = self._latent(x)
        first, run = _runs(latent)
        mu, var = self._transition(latent[first])
        mu, var = mu[run], var[run]
        noise = standard_normal(mu.shape, generator, x)
        return (mu + var.sqrt()[:, None] * noise.to(torch.float64)).to(x.dtype)

    def log_prob(self, x_next, x) -> torch.Tensor:
        """(P, d), (P, d) → (P,) ln N(x_next; μ_X(x), σ_X²(x)/λ I_d)."""
        x_next, x = self.check_pair(x_next, x)
        mu, var = self._transition(self._working(x))
        x_next = x_next.to(torch.float64)
        lp = -0.5 * (x_next - mu).pow(2).sum(-1) / var - 0.5 * self.d * torch.log(2 * math.pi * var)
        return lp.to(x.dtype)

    def mean(self, x) -> torch.Tensor:
        """(P, d) → (P, d) μ_X(x)."""
        x = torch.as_tensor(x)
        return self._dynamics(self._latent(x), variance=False)[0].to(x.dtype)

    def transition_covariance(self, x) -> torch.Tensor:
        """(P, d) → (P, d, d) σ_X²(x)/λ I_d, the covariance of x_t given x_{t−1} = x (the latent
        space is Euclidean: its tangent coordinates are the latent coordinates)."""
        x = torch.as_tensor(x)
        var = self._transition(self._latent(x))[1].to(x.dtype)
        return var[:, None, None] * torch.eye(self.d, dtype=var.dtype, device=var.device)

    def rollout(self, x0, steps: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """From x0 (P, d) (or (d,)), ``steps`` transitions: the mean path if ``generator`` is None,
        else sampled. Returns (steps + 1, P, d), x0 first."""
        x = torch.as_tensor(x0)
        x = x.reshape(1, -1) if x.dim() == 1 else x
        path = [self.check_state(x, "x0")]
        for _ in range(int(steps)):
            path.append(self.mean(path[-1]) if generator is None else self.sample(path[-1], generator))
        return torch.stack(path)

    # ---- energies (Urtasun et al. eqs. 18, 21) ---------------------------------------------
    def reconstruction_energy(self, x, y) -> torch.Tensor:
        """Eq. 18 per row: −ln p(y | x) = |W(y − μ_Y(x))|² / (2σ²(x)) + D_o/2 ln σ²(x) + ½|x|² (constants
        dropped), x (P, d), y (P, D) radians (with the mean pose); NaN entries of y are missing
        channels and drop out (D_o counts the observed channels of a row). Returns (P,) float64,
        differentiable in x."""
        x = self._latent(x).to(torch.float64)
        y = torch.as_tensor(y, dtype=torch.float64, device=x.device)
        if y.shape != (x.shape[0], self.D):
            raise PriortrackError(f"y has shape {tuple(y.shape)}; expected ({x.shape[0]}, {self.D})")
        mu, var = self._reconstruct(x)
        observed = torch.isfinite(y)
        r = torch.where(observed, (y - mu) * self._on(x.device)["W"], torch.zeros_like(mu))
        return r.pow(2).sum(-1) / (2 * var) + 0.5 * observed.sum(-1) * torch.log(var) + 0.5 * x.pow(2).sum(-1)

    def dynamics_energy(self, window, annealing: float = 0.5) -> torch.Tensor:
        """−annealing · ln p(X' | model) of windows X' (τ+1, P, d): the sum over t = 1..τ of
        −ln N(x_t; μ_X(x_{t−1}), σ_X²(x_{t−1}) I_d) (each step predicted from the training set),
        times the annealing exponent (0.5 when tracking). Returns (P,) float64, differentiable."""
        window = torch.as_tensor(window)
        if window.dim() != 3 or window.shape[-1] != self.d or window.shape[0] < 2:
            raise PriortrackError(f"window has shape {tuple(window.shape)}; expected (τ+1 ≥ 2, P, {self.d})")
        prev = self._latent(window[:-1].reshape(-1, self.d), "window").to(torch.float64)
        nxt = window[1:].reshape(-1, self.d).to(torch.float64)
        mu, var = self._dynamics(prev)
        nll = 0.5 * (nxt - mu).pow(2).sum(-1) / var + 0.5 * self.d * torch.log(2 * math.pi * var)
        return annealing * nll.reshape(window.shape[0] - 1, -1).sum(0)

    def map_latents(self, y, x0, dynamics: float = 0.0, maxiter: int = MAXITER) -> torch.Tensor:
        """MAP latent positions (T, d) of a pose sequence y (T, D) (radians, NaN = missing), from
        x0 (T, d): minimises Σ_t reconstruction_energy(x_t, y_t) + dynamics_energy(X', dynamics)
        (frames independent when ``dynamics`` is 0) with L-BFGS-B (the fit's tolerances, at most
        ``maxiter`` iterations)."""
        y = torch.as_tensor(y, dtype=torch.float64)
        x0 = self._latent(x0, "x0").to(torch.float64)
        T = x0.shape[0]
        if y.shape != (T, self.D):
            raise PriortrackError(f"y has shape {tuple(y.shape)}; expected ({T}, {self.D})")

        def f(p_np: np.ndarray):
            x = torch.from_numpy(p_np).reshape(T, self.d).requires_grad_(True)
            E = self.reconstruction_energy(x, y).sum()
            if dynamics and T > 1:
                E = E + self.dynamics_energy(x[:, None, :], annealing=dynamics).sum()
            (grad,) = torch.autograd.grad(E, x)
            return E.item(), grad.reshape(-1).numpy()

        with _single_blas_thread():
            result = minimize(f, x0.reshape(-1).numpy(), jac=True, method="L-BFGS-B",
                              options={"ftol": FTOL, "gtol": GTOL, "maxiter": maxiter})
        return torch.from_numpy(result.x).reshape(T, self.d)

    def encode_poses(self, y) -> torch.Tensor:
        """(T, D) poses in radians (with the mean pose) → (T, d) latent positions: each frame starts
        at the latent of the training pose nearest in W-scaled distance and moves to the minimum
        of its eq.-18 reconstruction energy."""
        y = torch.as_tensor(y, dtype=torch.float64)
        if y.dim() != 2 or y.shape[1] != self.D:
            raise PriortrackError(f"poses have shape {tuple(y.shape)}; expected (T, {self.D})")
        nearest = torch.cdist((y - self.mean_pose) * self.W, self.Y * self.W).argmin(dim=1)
        return self.map_latents(y, self.X[nearest])

    def log_variance_grid(self, n: int = 60, margin: float = 0.2) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """ln σ²(x) of the reconstruction on an n × n grid over latent dims 0 and 1 (the others at
        their training mean), spanning the training latents' range ± ``margin`` × that range.
        Returns grid_x (n,), grid_y (n,), logvar (n, n) with logvar[i, j] at (grid_x[j], grid_y[i])."""
        if self.d < 2:
            raise PriortrackError("a log-variance grid needs a latent space of at least 2 dimensions")
        lo, hi = self.X[:, :2].min(0).values, self.X[:, :2].max(0).values
        pad = margin * (hi - lo)
        gx = torch.linspace(float(lo[0] - pad[0]), float(hi[0] + pad[0]), n, dtype=torch.float64)
        gy = torch.linspace(float(lo[1] - pad[1]), float(hi[1] + pad[1]), n, dtype=torch.float64)
        points = self.X.mean(0).expand(n * n, -1).clone()
        yy, xx = torch.meshgrid(gy, gx, indexing="ij")
        points[:, 0], points[:, 1] = xx.reshape(-1), yy.reshape(-1)
        return gx, gy, torch.log(self._reconstruct(points)[1]).reshape(n, n)

    # ---- files -----------------------------------------------------------------------------
    def _arrays(self):
        return {"gpdm.X": self.X.numpy(), "gpdm.Y": self.Y.numpy(), "gpdm.mean_pose": self.mean_pose.numpy(),
                "gpdm.lengths": np.asarray(self.lengths, dtype=np.int64), "gpdm.log_alpha": self.log_alpha.numpy(),
                "gpdm.log_beta": self.log_beta.numpy(), "gpdm.W": self.W.numpy()}

    def _header(self):
        return {"balanced": self.balanced, "d": self.d, "fit": self.fit_summary,
                "preprocessing": {"fps": self.fps, "space": "AngleSpace"}}

    @classmethod
    def _restore(cls, arrays, header):
        return cls(AngleSpace.from_arrays(arrays), arrays["gpdm.X"], arrays["gpdm.Y"], arrays["gpdm.mean_pose"],
                   arrays["gpdm.lengths"], arrays["gpdm.log_alpha"], arrays["gpdm.log_beta"], header["balanced"],
                   header["fps"], W=arrays["gpdm.W"], fit_summary=header["fit"])
