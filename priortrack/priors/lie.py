"""The Lie-algebra kinematic prior (Simo-Serra, Torras, Moreno-Noguer 2015).

A pose x is the 14 eval15 bone directions, a point of (S²)ᴮ (B = 14); its velocity is the
tangent vector v_t = s · log_{x_t}(x_{t+1}) ∈ T_x (S²)ᴮ, s a scale (30, so that pose and
kinematics weigh alike). A training sample is a point (x, v) of the joint manifold.

**Tangent coordinates.** Component k has a mean pose μ_k ∈ (S²)ᴮ and, on each sphere b, the
fixed orthonormal basis E_kb (2×3, rows e1, e2) of T_μ S² built by
:func:`~priortrack.geometry.tangent_basis.tangent_basis`. A sample's coordinates at component
k are, per bone b, the four numbers

    z_kb = ( E_kb log_{μ_kb}(x_b) ,  E_kb Γ_{x_b→μ_kb}(v_b) ) = (a_kb, b_kb) ∈ R² × R²,

Γ the parallel transport along the minimising geodesic (:func:`~priortrack.geometry.sphere.transport`).

**Mixture.** p(x, v) = Σ_k α_k Π_b N(z_kb; (0, m_kb), Σ_kb), Σ_kb a 4×4 block coupling bone b's
pose and velocity coordinates (a covariance block-diagonal over bones); μ_k is the weighted
Karcher mean, so the pose part has mean 0 in its own coordinates.

**Conditioning** (closed form). With Σ_kb = [[Sxx, Sxv], [Svx, Svv]] (2×2 blocks),

    π_k(x) ∝ α_k Π_b N(a_kb; 0, Sxx_kb),
    b_kb | x ~ N(m_kb + R_kb a_kb, C_kb),   R = Svx Sxx⁻¹,   C = Svv − Svx Sxx⁻¹ Sxv,

and the velocity at x is v_b = Γ_{μ_kb→x_b}(E_kbᵀ b_kb). Everything per component (R, the
Cholesky factors of Sxx and C, their log-determinants) is computed once, when the mixture is
built, so a draw costs O(K) for π(x) and O(1) after that.

**Densities.** p(v | x) is the density of v in orthonormal coordinates of T_x (S²)ᴮ (2 per
bone); it does not depend on which orthonormal basis is used, since Γ is an isometry.
:meth:`LiePrior.log_prob` is the transition density of the contract, the density of the
step u = log_x(x_next) = v / s in those coordinates, as for the diffusion priors:

    log p(x_next | x) = log p(v = s · log_x(x_next) | x) + 2B ln s,

2B = 28 being the dimension of the velocity; :meth:`LiePrior.velocity_log_prob` gives
log p(v | x) itself.

**Sampling** (:meth:`LiePrior.sample`): per row, k ~ π(x) by the inverse CDF of one uniform,
z ~ N(0, I_2B), b = m_k + R_k a_k + L_c z (L_c the Cholesky factor of C_k), and
x_next = exp_x(Γ_{μ_k→x}(E_kᵀ b) / s). The rows go in blocks of :data:`SAMPLE_CHUNK`, held
"planar" (B, 3, n) so that every step is an elementwise operation along the rows. π(x) is
evaluated for all K components from c = μ·x and G x = L_xx⁻¹ E x (:meth:`GeodesicMixture._planar_logits`);
the rows are then sorted by component so that each component's affine terms take a few
operations over its own columns, and the rest (θ / sin θ, the transport, the exponential map)
is done once per block. In float32 on the CPU a block is instead one call of a fused numba
kernel (:mod:`priortrack.priors.lie_kernel`: the same draw from the same variates, to float32
rounding, about twice as fast as the torch operations); the torch path serves every other dtype
and device. Each block draws its uniforms and normals from a generator of its own, seeded from
the caller's generator in the calling thread; with torch set to T > 1 threads on the CPU, the
blocks are sampled by T single-threaded worker threads, so the draws do not depend on T. It runs
in the input's dtype (float32 is fine there) and on its device.
:meth:`LiePrior.mean` is exp_x(E[v | x] / s) with the mixture's mean velocity.

**Learning** (Figueiredo & Jain, PAMI 2002): component-wise EM with the minimum-message-length
weight update

    α_k ← max(0, Σ_i w_ik − N_p/2) / Σ_j max(0, Σ_i w_ij − N_p/2),

N_p = 14B parameters per component (2B for μ, 2B for m, 10B for the 4×4 blocks), from
``max_components`` components seeded at random training samples. A component whose weight
reaches 0 is annihilated. At convergence the smallest component is annihilated and EM run
again, down to one component; the configuration kept is the one with the least message length

    L = N_p/2 Σ_k ln(N α_k / 12) + k/2 ln(N/12) + k (N_p + 1)/2 − Σ_i ln p(x_i, v_i).
"""

from __future__ import annotations

import logging
import math
import queue
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from priortrack.body.normalise import BONE_CHILDREN
from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.geometry.sphere import clamped_cosine, karcher_mean, log_map, theta_over_sin, transport
from priortrack.geometry.tangent_basis import tangent_basis, to_coordinates
from priortrack.geometry.linalg import jittered_cholesky, whitening
from priortrack.priors.base import DEFAULT_FPS, TransitionModel, prepare_motions
from priortrack.priors.spaces import DirectionSpace
from priortrack.randomness import standard_normal
from priortrack.threads import block_pool

logger = logging.getLogger(__name__)

#: Default velocity scale s (the paper's 30).
DEFAULT_SCALE = 30.0
#: Parameters per bone of one component: 2 (pose mean) + 2 (velocity mean) + 10 (4×4 block).
PARAMETERS_PER_BONE = 14
#: Most rows per block of :meth:`GeodesicMixture.sample_next`. A block costs some 150 tensor operations
#: whatever its size, so it must be large enough to amortise their dispatch (a few µs each), and
#: small enough that its work set (about 1 kB a row in float32) stays in the last-level cache.
SAMPLE_CHUNK = 8192
#: Rows per sampling block on a GPU: there a block of 8192 rows is bound by its kernel launches (123 blocks
#: of ~30 components' terms made 10⁶ draws 164 ms on an H100), so the rows go in as few blocks as memory allows.
DEVICE_SAMPLE_CHUNK = 2 ** 20
#: Columns per slice in :meth:`GeodesicMixture._planar_logits`: the (B, 3K, n) products of a slice
#: stay in cache while the elementwise steps pass over them.
LOGIT_SLICE = 2048
#: Columns per slice on a GPU, where a slice's dozen operations are launch-bound below ~10⁴ columns: 65,536
#: columns of ~30 components' products take some 0.3 GB in float32.
DEVICE_LOGIT_SLICE = 2 ** 16
#: Floor on ln(π_k / max_j π_j) in the inverse CDF: e^−80 ≈ 1.8e−35 is still a normal float32
#: (subnormal arithmetic is some 100× slower), and a weight that small is never drawn anyway, since
#: it is below the resolution of a uniform of either dtype (2⁻²⁴, 2⁻⁵³).
LOG_WEIGHT_FLOOR = -80.0
_LOG_2PI = math.log(2 * math.pi)
#: The float32 cosine clamp of :func:`~priortrack.geometry.sphere.clamped_cosine`, for the fused kernel.
_C_MAX_32 = np.float32(1.0 - np.finfo(np.float32).eps / 2)


# ---------------------------------------------------------------------------------------------
# small numerical helpers
# ---------------------------------------------------------------------------------------------


def _cholesky(matrices: torch.Tensor, what: str) -> torch.Tensor:
    """Lower Cholesky factors of a batch of symmetric matrices (..., n, n): :func:`jittered_cholesky`
    with a jitter from 1e-12 to 1e-6 times the mean diagonal."""
    return jittered_cholesky(matrices, what, 1e-12, 1e-6)


def _block_diagonal(blocks: torch.Tensor) -> torch.Tensor:
    """(..., B, r, c) → (..., B r, B c), block b of the result on its diagonal."""
    *lead, b, r, c = blocks.shape
    eye = torch.eye(b, dtype=blocks.dtype, device=blocks.device)
    return torch.einsum("...brc,bd->...brdc", blocks, eye).reshape(*lead, b * r, b * c)


def _frame_matrix(mu: torch.Tensor) -> torch.Tensor:
    """(..., B, 3) means → (..., 3B, 3B) F, (x F)_b = (μ_b·x_b, e1_b·x_b, e2_b·x_b) for flat rows x (N, 3B)."""
    frame = torch.cat([mu.unsqueeze(-2), tangent_basis(mu)], dim=-2)                   # (..., B, 3, 3)
    return _block_diagonal(frame.transpose(-1, -2))


def _coordinates(x: torch.Tensor, v: torch.Tensor | None, frame: torch.Tensor, bones: int):
    """Tangent coordinates at one component of flat poses x and velocities v (N, 3B).

    With (c, E x) = x F per bone (:func:`_frame_matrix`), since E μ = 0:

        a = E log_μ(x) = (θ / sin θ) E x,
        b = E Γ_{x→μ}(v) = E v − (μ·v) / (1 + c) E x     (Γ_{x→μ}(v) = v − (μ·v)/(1 + c) (x + μ)).

    These equal E log_μ(x) and E Γ_{x→μ}(v) of :mod:`priortrack.geometry.sphere` except at the
    antipode x = −μ, where the logarithm is not unique and a = 0 here.

    Returns a (N, B, 2) and b (N, B, 2), or None for b when v is None.
    """
    n = x.shape[0]
    y = (x @ frame).view(n, bones, 3)
    c, ex = clamped_cosine(y[..., 0]), y[..., 1:]
    a = theta_over_sin(c).unsqueeze(-1) * ex
    if v is None:
        return a, None
    yv = (v @ frame).view(n, bones, 3)
    return a, yv[..., 1:] - (yv[..., 0] / (1 + c)).unsqueeze(-1) * ex


def _transport_matrices(mu: torch.Tensor, basis: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """T = E(x) Γ_{μ→x} E_μᵀ (..., B, 2, 2): the parallel transport from T_μ S² to T_x S² in the bases E_μ (``basis``,
    (..., B, 2, 3)) and E(x) (:func:`~priortrack.geometry.tangent_basis.tangent_basis`), for unit μ, x (..., B, 3)
    broadcasting. For a tangent v at μ and c = μ·x, Γ(v) = v − (x·v)/(1 + c) (μ + x), so that, E(x) x being 0,

        T = E(x) E_μᵀ − (E(x) μ)(E_μ x)ᵀ / (1 + c),

    a few 2 × 3 products instead of :func:`~priortrack.geometry.sphere.transport`'s checked general form (which
    rows within 0.25 rad of the antipode, where 1 + c vanishes, still take)."""
    E_x = tangent_basis(x)
    if bool((torch.linalg.vector_norm(mu + x, dim=-1) < 0.25).any()):                      # |μ + x| = 2 cos(θ/2)
        moved = transport(mu.unsqueeze(-2), x.unsqueeze(-2), basis)
        return E_x @ moved.transpose(-1, -2)
    c = (mu * x).sum(-1)[..., None, None]
    return (E_x @ basis.transpose(-1, -2)
            - (E_x @ mu.unsqueeze(-1)) @ (basis @ x.unsqueeze(-1)).transpose(-1, -2) / (1 + c))


def _columns(matrices: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """The c columns (..., r, 1) of a batch of matrices (..., r, c), so that Σ_j columns[j] X[..., j:j+1, :]
    is the product with a planar X (..., c, n)."""
    return matrices.unsqueeze(-1).unbind(-2)


def _fused(dtype: torch.dtype, device: torch.device) -> bool:
    """Whether draws in this dtype and on this device go through the fused kernel of
    :mod:`priortrack.priors.lie_kernel` (float32 on the CPU) rather than torch operations."""
    return dtype == torch.float32 and torch.device(device).type == "cpu"


def _inverse_cdf(logits: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Draws k (n,) ~ softmax(logits[:, i]) for logits (K, n) (overwritten), by the inverse CDF of u (n,) ∈ [0, 1).

    With w_k = exp(max(l_k − max_j l_j, :data:`LOG_WEIGHT_FLOOR`)) and W_k = Σ_{j≤k} w_j, the draw
    is the number of k with W_k < (1 − u) W_{K−1}: 1 − u ∈ (0, 1], so the threshold lies in
    (0, W_{K−1}] and k is drawn with probability w_k / W_{K−1}.
    """
    cdf = logits.sub_(logits.amax(dim=0)).clamp_(min=LOG_WEIGHT_FLOOR).exp_().cumsum_(dim=0)
    return (cdf < torch.rsub(u, 1).mul_(cdf[-1])).sum(dim=0)


def mirrored(directions: torch.Tensor) -> torch.Tensor:
    """(..., 14, 3) bone directions in the body frame → those of the mirror image: left and right bones
    swapped, the first (left-pointing) axis negated. The body frame stays a body frame: x = y × z, with
    z = (l − r) × (n − h) of the swapped hips (:mod:`priortrack.body.normalise`)."""
    names = [EVAL15_NAMES[c] for c in BONE_CHILDREN]
    other = {"l": "r", "r": "l"}
    swap = [names.index(other[n[0]] + n[1:]) if n[0] in other and other[n[0]] + n[1:] in names else b
            for b, n in enumerate(names)]
    flip = torch.tensor([-1.0, 1.0, 1.0], dtype=directions.dtype, device=directions.device)
    return directions[..., swap, :] * flip


# ---------------------------------------------------------------------------------------------
# the mixture
# ---------------------------------------------------------------------------------------------


@dataclass
class _Hot:
    """The mixture's constants for the sampling path, in one dtype and device. A batch of n
    poses is held "planar", as X (B, 3, n): X[b, j] the j-th coordinate of bone b of every pose.
    Products with X are written as sums over its 3 rows of (column of a matrix) × (row of X), so
    the matrices below are stored column by column, each column as a (…, r, 1) tensor.

    With s the velocity scale and, per component k and bone b, E (2×3), G = L_xx⁻¹ E,
    R, L_c (2×2), m (2,):

    - ``pi_w``: the 3 columns (B, 3K, 1) of the (3K × 3) matrix with rows μ_kb (k = 0…K−1), then
      the rows 1 and 2 of G_kb, so that Σ_j pi_w[j] X[:, j] gives c = μ·x and g = G x;
    - ``pi_c`` (K, 1): ln α_k − ½ Σ_b ln det Sxx_kb − B ln 2π;
    - ``affine[k]``, component k's (cond_b, cond_w columns 0…2, noise_b, noise_w columns 0…1):
      cond_b + Σ_j cond_w[j] x_j gives (Eᵀ R E x / s, c, x + μ) (B, 7, 1 each: the rows Eᵀ R E / s,
      μᵀ and I, the offset (0, 0, 0, 0, μ)), and noise_b + Σ_j noise_w[j] z_j gives Eᵀ (m + L_c z) / s
      (B, 3, 1 each: the columns of Eᵀ L_c / s and Eᵀ m / s).
    """

    pi_w: tuple[torch.Tensor, ...]
    pi_c: torch.Tensor
    affine: list[tuple[torch.Tensor, ...]]
    #: For float32 on the CPU, the constants of :func:`priortrack.priors.lie_kernel.sample_block`
    #: (float32 arrays: μ, G, pi_c, Eᵀ R E / s, Eᵀ L_c / s, Eᵀ m / s); else None.
    kernel: tuple[np.ndarray, ...] | None


class GeodesicMixture:
    """A geodesic Gaussian mixture on (S²)ᴮ × R²ᴮ with block-diagonal (per bone, 4×4) covariances.

    Poses are flat rows x (P, 3B) of B unit vectors, velocities v (P, 3B) tangent at x; see
    the module docstring for the coordinates and the conditional. Parameters are float64 on
    the CPU; the sampling path casts them once per dtype and device.

    Attributes:
        weights: (K,) α_k, positive, summing to 1.
        means: (K, B, 3) μ_k, unit rows.
        velocity_means: (K, B, 2) m_k in the coordinates of E_k.
        covariances: (K, B, 4, 4) Σ_kb over (a_1, a_2, b_1, b_2).
        basis: (K, B, 2, 3) E_k, from ``means``.
        regression: (K, B, 2, 2) R = Svx Sxx⁻¹.
        conditional_covariances: (K, B, 2, 2) C = Svv − Svx Sxx⁻¹ Sxv.
    """

    def __init__(self, weights, means, velocity_means, covariances):
        def as64(value):
            if isinstance(value, torch.Tensor):
                value = value.detach().cpu()
            return torch.as_tensor(np.asarray(value, dtype=np.float64))

        weights, means = as64(weights), as64(means)
        velocity_means, covariances = as64(velocity_means), as64(covariances)
        if weights.dim() != 1 or len(weights) == 0:
            raise PriortrackError(f"mixture weights have shape {tuple(weights.shape)}; expected (K,), K >= 1")
        k = len(weights)
        if means.dim() != 3 or means.shape[0] != k or means.shape[2] != 3:
            raise PriortrackError(f"mixture means have shape {tuple(means.shape)}; expected ({k}, B, 3)")
        b = means.shape[1]
        if velocity_means.shape != (k, b, 2):
            raise PriortrackError(f"velocity means have shape {tuple(velocity_means.shape)}; expected ({k}, {b}, 2)")
        if covariances.shape != (k, b, 4, 4):
            raise PriortrackError(f"covariances have shape {tuple(covariances.shape)}; expected ({k}, {b}, 4, 4)")
        for name, value in (("weights", weights), ("means", means), ("velocity means", velocity_means),
                            ("covariances", covariances)):
            if not bool(torch.isfinite(value).all()):
                raise PriortrackError(f"mixture {name} contain NaN or inf")
        if not bool((weights > 0).all()) or abs(float(weights.sum()) - 1.0) > 1e-9:
            raise PriortrackError("mixture weights must be positive and sum to 1")
        if not bool(((torch.linalg.vector_norm(means, dim=-1) - 1).abs() < 1e-9).all()):
            raise PriortrackError("mixture means must be unit vectors (points of (S²)ᴮ)")
        self.weights, self.means, self.velocity_means = weights, means, velocity_means
        self.covariances = 0.5 * (covariances + covariances.transpose(-1, -2))
        self.basis = tangent_basis(means)
        self._precompute()
        self._hot_cache: dict[tuple, _Hot] = {}

    @property
    def components(self) -> int:
        """K, the number of components."""
        return len(self.weights)

    @property
    def bones(self) -> int:
        """B, the number of spheres."""
        return self.means.shape[1]

    def _precompute(self) -> None:
        """Per component: R, C, the Cholesky factors of Sxx and C, and their block matrices."""
        cov = self.covariances
        sxx, sxv, svv = cov[..., :2, :2], cov[..., :2, 2:], cov[..., 2:, 2:]
        chol_xx = _cholesky(sxx, "a pose block Sxx of the mixture")
        self.regression = torch.cholesky_solve(sxv, chol_xx).transpose(-1, -2)        # Svx Sxx⁻¹
        cond = svv - self.regression @ sxv
        self.conditional_covariances = 0.5 * (cond + cond.transpose(-1, -2))
        chol_c = _cholesky(self.conditional_covariances, "a conditional covariance C of the mixture")
        self._chol_xx, self._chol_c = chol_xx, chol_c
        b = self.bones
        half_log_det_xx = torch.log(chol_xx.diagonal(dim1=-2, dim2=-1)).sum(dim=(-1, -2))
        half_log_det_c = torch.log(chol_c.diagonal(dim1=-2, dim2=-1)).sum(dim=(-1, -2))
        self._log_norm_x = torch.log(self.weights) - half_log_det_xx - b * _LOG_2PI   # (K,)
        self._log_norm_c = -half_log_det_c - b * _LOG_2PI                              # (K,)
        # Row-vector block matrices: (a_flat @ M)_b = M_b a_b for a_flat (N, 2B).
        self._frames = _frame_matrix(self.means)                                       # (K, 3B, 3B)
        self._white_xx = _block_diagonal(whitening(chol_xx).transpose(-1, -2))       # (K, 2B, 2B)
        self._white_c = _block_diagonal(whitening(chol_c).transpose(-1, -2))
        self._regress = _block_diagonal(self.regression.transpose(-1, -2))
        self._vel_flat = self.velocity_means.reshape(self.components, 2 * b)

    # ---- the accurate path (O(K) per row, any dtype; float64 for scoring) -------------------------
    def _component(self, x: torch.Tensor, v: torch.Tensor | None, k: int):
        """Component k at flat poses x (P, 3B) (and velocities v): ln α_k N(a; 0, Sxx) (P,), the
        conditional mean m + R a (P, 2B) and, if v is given, ln N(b; m + R a, C) (P,)."""
        b = self.bones
        a, bv = _coordinates(x, v, self._frames[k].to(x), b)
        a = a.reshape(-1, 2 * b)
        white = a @ self._white_xx[k].to(x)
        marginal = self._log_norm_x[k].to(x) - 0.5 * (white * white).sum(dim=-1)
        mean = self._vel_flat[k].to(x) + a @ self._regress[k].to(x)
        if v is None:
            return marginal, mean, None
        white = (bv.reshape(-1, 2 * b) - mean) @ self._white_c[k].to(x)
        return marginal, mean, self._log_norm_c[k].to(x) - 0.5 * (white * white).sum(dim=-1)

    def log_responsibilities(self, x: torch.Tensor) -> torch.Tensor:
        """ln π_k(x) (P, K) for flat poses x (P, 3B): π_k ∝ α_k Π_b N(a_kb; 0, Sxx_kb), Σ_k π_k = 1."""
        terms = torch.stack([self._component(x, None, k)[0] for k in range(self.components)], dim=-1)
        return terms - torch.logsumexp(terms, dim=-1, keepdim=True)

    def conditional(self, x: torch.Tensor):
        """p(v | x) component by component, for flat poses x (P, 3B).

        Returns:
            ln π (P, K); conditional means m_k + R_k a_k (P, K, B, 2) in the coordinates of E_k
            (the velocity transported to μ_k); conditional covariances C (K, B, 2, 2).
        """
        parts = [self._component(x, None, k) for k in range(self.components)]
        terms = torch.stack([p[0] for p in parts], dim=-1)
        means = torch.stack([p[1] for p in parts], dim=1).reshape(x.shape[0], self.components, self.bones, 2)
        return terms - torch.logsumexp(terms, dim=-1, keepdim=True), means, self.conditional_covariances.to(x)

    def velocity_log_prob(self, v: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """ln p(v | x) (P,) for flat velocities v (P, 3B) tangent at flat poses x (P, 3B):

            p(v | x) = Σ_k π_k(x) Π_b N(E_kb Γ_{x→μ_k}(v_b); m_kb + R_kb a_kb, C_kb).
        """
        parts = [self._component(x, v, k) for k in range(self.components)]
        marginal = torch.stack([p[0] for p in parts], dim=-1)
        joint = torch.stack([p[0] + p[2] for p in parts], dim=-1)
        return torch.logsumexp(joint, dim=-1) - torch.logsumexp(marginal, dim=-1)

    def velocity_moments(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The mean (P, 2B) and covariance (P, 2B, 2B) of v | x, for flat poses x (P, 3B), in the
        orthonormal coordinates E(x) of T_x (S²)ᴮ (:func:`~priortrack.geometry.tangent_basis.tangent_basis`
        at each bone direction of x). Component k's velocity in those coordinates is c_k = T_k b_k with
        T_kb = E(x_b) Γ_{μ_kb→x_b} E_kbᵀ (2×2, a rotation), so that, the mixture moment-matched,

            E[c | x] = Σ_k π_k T_k (m_k + R_k a_k),
            Cov[c | x] = Σ_k π_k (T_k C_k T_kᵀ + (c̄_k − c̄)(c̄_k − c̄)ᵀ),

        block-diagonal over bones within a component, full between them."""
        b, n = self.bones, x.shape[0]
        log_pi, c, blocks = self._transported(x)
        pi = torch.exp(log_pi)
        mean = torch.einsum("pk,pkbi->pbi", pi, c)
        within = torch.einsum("pk,pkbij->pbij", pi, blocks)
        spread = (c - mean[:, None]).reshape(n, self.components, 2 * b)
        covariance = _block_diagonal(within) + torch.einsum("pk,pki,pkj->pij", pi, spread, spread)
        return mean.reshape(n, 2 * b), 0.5 * (covariance + covariance.transpose(-1, -2))

    def _transported(self, x: torch.Tensor, covariances: bool = True, components: torch.Tensor | None = None):
        """Every component's conditional velocity in the coordinates E(x) of :meth:`velocity_moments`: ln π (P, K),
        the means c_k = T_k (m_k + R_k a_k) (P, K, B, 2) and the covariance blocks T_k C_k T_kᵀ (P, K, B, 2, 2)
        (None unless ``covariances``); with ``components`` (P, k) indices, those components of each row only
        (the transport, most of the cost, done for them alone)."""
        b, n = self.bones, x.shape[0]
        log_pi, means, cond = self.conditional(x)                                     # (P, K), (P, K, B, 2)
        mu, basis, cond = self.means.to(x)[None], self.basis.to(x)[None], cond[None]
        if components is not None:
            log_pi = torch.gather(log_pi, 1, components)
            means = torch.gather(means, 1, components[..., None, None].expand(-1, -1, b, 2))
            mu, basis, cond = mu[0][components], basis[0][components], cond[0][components]
        T = _transport_matrices(mu.reshape(len(mu), -1, b, 3), basis, x.reshape(n, 1, b, 3))      # (P, k, B, 2, 2)
        return log_pi, (T @ means[..., None])[..., 0], T @ cond @ T.transpose(-1, -2) if covariances else None

    def velocity_components(self, x: torch.Tensor, covariances: bool = True, components: torch.Tensor | None = None):
        """p(v | x) as the Gaussian mixture it is, in the coordinates E(x) of T_x (S²)ᴮ: ln π (P, K), the
        component means (P, K, 2B) and covariances (P, K, 2B, 2B), block-diagonal over bones (None unless
        ``covariances``: at P = 1000 and K = 30 they are 190 MB); with ``components`` (P, k), those of each row."""
        log_pi, c, blocks = self._transported(x, covariances, components)
        return (log_pi, c.reshape(x.shape[0], -1, 2 * self.bones), None if blocks is None else _block_diagonal(blocks))

    # ---- the sampling path (any dtype and device, planar, in blocks) ------------------------------
    def _hot(self, dtype: torch.dtype, device: torch.device, scale: float) -> _Hot:
        key = (dtype, str(device), float(scale))
        if key not in self._hot_cache:
            self._hot_cache[key] = self._build_hot(scale, dtype, device)
        return self._hot_cache[key]

    def _build_hot(self, scale: float, dtype: torch.dtype, device: torch.device) -> _Hot:
        """The :class:`_Hot` constants (computed in float64, then cast)."""
        basis, mu = self.basis, self.means
        k, b = self.components, self.bones
        g = whitening(self._chol_xx) @ basis                                           # (K, B, 2, 3)
        pi_w = torch.cat([mu, g[:, :, 0], g[:, :, 1]]).transpose(0, 1)                  # (B, 3K, 3)
        basis_t = basis.transpose(-1, -2)                                               # Eᵀ (K, B, 3, 2)
        regress = basis_t @ self.regression @ basis / scale                             # Eᵀ R E / s (K, B, 3, 3)
        eye = torch.eye(3, dtype=mu.dtype).expand(k, b, 3, 3)
        cond_w = torch.cat([regress, mu.unsqueeze(-2), eye], dim=-2)
        cond_b = torch.cat([torch.zeros(k, b, 4, dtype=mu.dtype), mu], dim=-1).unsqueeze(-1)
        noise_w = basis_t @ self._chol_c / scale
        noise_b = basis_t @ self.velocity_means.unsqueeze(-1) / scale

        def cast(t: torch.Tensor) -> torch.Tensor:
            return t.to(dtype=dtype, device=device).contiguous()

        affine = [(cast(cond_b[i]), *map(cast, _columns(cond_w[i])),
                   cast(noise_b[i]), *map(cast, _columns(noise_w[i]))) for i in range(k)]
        kernel = None
        if _fused(dtype, device):
            kernel = tuple(np.ascontiguousarray(t.numpy(), dtype=np.float32)
                           for t in (mu, g, self._log_norm_x, regress, noise_w, noise_b[..., 0]))
        return _Hot(tuple(map(cast, _columns(pi_w))), cast(self._log_norm_x.unsqueeze(-1)), affine, kernel)

    def _planar(self, x: torch.Tensor) -> torch.Tensor:
        """Flat poses (n, 3B) → planar (B, 3, n)."""
        return x.t().contiguous().view(self.bones, 3, x.shape[0])

    def _planar_logits(self, xp: torch.Tensor, hot: _Hot) -> torch.Tensor:
        """ln α_k N(a_k; 0, Sxx_k) (K, n) for planar poses X (B, 3, n), :data:`LOGIT_SLICE` columns at a time
        (:data:`DEVICE_LOGIT_SLICE` on a GPU).

        |L_xx⁻¹ a|² = (θ / sin θ)² |G x|², since a = (θ / sin θ) E x (E ⊥ μ) and G = L_xx⁻¹ E,
        with (θ / sin θ)² = arccos(c)² / (1 − c²), c clamped as in
        :func:`~priortrack.geometry.sphere.clamped_cosine`. 1 − c² loses relative precision as θ → 0, but there |G x|² ~ λ θ² and the error in the product stays
        below λ ε (λ the largest eigenvalue of Sxx⁻¹, ε the dtype's epsilon). G x is formed as such
        (not as the quadratic form xᵀ GᵀG x, whose rounding error is λ ε at every θ).
        """
        k, n = self.components, xp.shape[-1]
        quad = torch.empty(k, n, dtype=xp.dtype, device=xp.device)
        one = torch.ones((), dtype=xp.dtype, device=xp.device)
        pi_w0, pi_w1, pi_w2 = hot.pi_w
        width = LOGIT_SLICE if xp.device.type == "cpu" else DEVICE_LOGIT_SLICE
        for start in range(0, n, width):
            cols = slice(start, start + width)
            x0, x1, x2 = xp[..., cols].unsqueeze(2).unbind(1)                           # (B, 1, n') each
            y = pi_w0 * x0
            y.addcmul_(pi_w1, x1).addcmul_(pi_w2, x2)                                   # (B, 3K, n')
            c, g1, g2 = y.view(self.bones, 3, k, -1).unbind(1)
            q = g1 * g1
            q.addcmul_(g2, g2)
            clamped_cosine(c, inplace=True)
            q.div_(torch.addcmul(one, c, c, value=-1.0))
            q.mul_(c.acos_().square_())
            torch.sum(q, dim=0, out=quad[:, cols])
        return quad.mul_(-0.5).add_(hot.pi_c)

    def _affine_terms(self, xp: torch.Tensor, z: torch.Tensor | None, hot: _Hot, k: int,
                      lin: torch.Tensor, vel: torch.Tensor) -> None:
        """Component k's affine terms at planar poses X (B, 3, n) with normals z (B, 2, n), per bone:
        lin (B, 7, n) ← (Eᵀ R E x / s, c = μ·x, x + μ) and vel (B, 3, n) ← Eᵀ (m + L_c z) / s, or
        Eᵀ m / s for z None (the conditional mean)."""
        cond_b, cond_w0, cond_w1, cond_w2, noise_b, noise_w0, noise_w1 = hot.affine[k]
        x0, x1, x2 = xp.unsqueeze(2).unbind(1)                                         # (B, 1, n) each
        torch.addcmul(cond_b, cond_w0, x0, out=lin)
        lin.addcmul_(cond_w1, x1).addcmul_(cond_w2, x2)
        if z is None:
            vel.copy_(noise_b.expand_as(vel))
            return
        z0, z1 = z.unsqueeze(2).unbind(1)
        torch.addcmul(noise_b, noise_w0, z0, out=vel)
        vel.addcmul_(noise_w1, z1)

    @staticmethod
    def _planar_step(xp: torch.Tensor, lin: torch.Tensor, vel: torch.Tensor) -> torch.Tensor:
        """The step u = Γ_{μ→x}(V) (B, 3, n) at planar poses X (B, 3, n) from the affine terms of
        :meth:`_affine_terms`, written into vel:

            V = vel + (θ / sin θ) Eᵀ R E x / s = Eᵀ (m + R a + L_c z) / s   (a = (θ / sin θ) E x),
            Γ_{μ→x}(V) = V − (x·V) / (1 + c) (x + μ)   (V ⊥ μ).
        """
        c = clamped_cosine(lin[:, 3])
        vel.addcmul_(lin[:, :3], theta_over_sin(c).unsqueeze(1))
        x0, x1, x2 = xp.unbind(1)
        v0, v1, v2 = vel.unbind(1)
        along = x0 * v0
        along.addcmul_(x1, v1).addcmul_(x2, v2).div_(c.add_(1))
        return vel.addcmul_(lin[:, 4:], along.unsqueeze(1), value=-1.0)

    @staticmethod
    def _planar_exp(xp: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """exp_x(u) for planar poses X and tangent steps u (B, 3, n), renormalised to unit rows.

        exp_x(u)_b = cos|u_b| x_b + (sin|u_b| / |u_b|) u_b; sin t / (t + tiny) is exact for t > 0
        and multiplies u_b = 0 when t = 0.
        """
        u0, u1, u2 = u.unbind(1)
        t = u0 * u0
        t.addcmul_(u1, u1).addcmul_(u2, u2).sqrt_()
        out = xp * torch.cos(t).unsqueeze(1)
        out.addcmul_(u, torch.sin(t).div_(t.add_(torch.finfo(t.dtype).tiny)).unsqueeze(1))
        o0, o1, o2 = out.unbind(1)
        norm_sq = o0 * o0
        norm_sq.addcmul_(o1, o1).addcmul_(o2, o2)
        return out.mul_(norm_sq.rsqrt_().unsqueeze(1))

    def fast_log_responsibilities(self, x: torch.Tensor) -> torch.Tensor:
        """ln π_k(x) (P, K) for flat poses x (P, 3B), by the sampling path's formula (x's dtype)."""
        logits = self._planar_logits(self._planar(x), self._hot(x.dtype, x.device, 1.0))
        return (logits - torch.logsumexp(logits, dim=0)).T

    def _sample_block(self, x: torch.Tensor, u: torch.Tensor, z: torch.Tensor, hot: _Hot,
                      out: torch.Tensor) -> None:
        """x_next (n, 3B) into out for flat poses x (n, 3B), given uniforms u (n,) and normals z (B, 2, n).

        k ~ π(x) by :func:`_inverse_cdf`; the poses are sorted by k (stable) and take the columns of
        z in that order; each component's affine terms (:meth:`_affine_terms`) fill its columns, and
        the step and the exponential map are taken for the whole block.
        """
        b, n = self.bones, x.shape[0]
        xp = self._planar(x)
        comp = _inverse_cdf(self._planar_logits(xp, hot), u)
        order = torch.sort(comp, stable=True).indices
        xp = xp.view(3 * b, n).index_select(1, order).view(b, 3, n)
        lin = torch.empty(b, 7, n, dtype=x.dtype, device=x.device)
        vel = torch.empty(b, 3, n, dtype=x.dtype, device=x.device)
        begin = 0
        for k, count in enumerate(torch.bincount(comp, minlength=self.components).tolist()):
            if count:
                cols = slice(begin, begin + count)
                self._affine_terms(xp[..., cols], z[..., cols], hot, k, lin[..., cols], vel[..., cols])
                begin += count
        nxt = self._planar_exp(xp, self._planar_step(xp, lin, vel)).view(3 * b, n)
        out.index_copy_(0, order, nxt.t().contiguous())

    def _fused_block(self, x: torch.Tensor, u: torch.Tensor, z: torch.Tensor, hot: _Hot,
                     out: torch.Tensor) -> None:
        """:meth:`_sample_block` by :func:`priortrack.priors.lie_kernel.sample_block` (float32 on the
        CPU): the same draw from the same u and z, to float32 rounding."""
        from priortrack.priors.lie_kernel import sample_block

        n = x.shape[0]
        planar = np.empty((3 * self.bones, n), dtype=np.float32)
        logits = np.empty((self.components, n), dtype=np.float32)
        sample_block(x.detach().numpy(), u.numpy(), z.numpy(), *hot.kernel, _C_MAX_32, np.float32(LOG_WEIGHT_FLOOR),
                     out.numpy(), planar, logits)

    def sample_next(self, x: torch.Tensor, generator: torch.Generator, scale: float) -> torch.Tensor:
        """One draw x_next = exp_x(v / s), v ~ p(v | x), per row of flat poses x (P, 3B).

        The rows go in ⌈P / :data:`SAMPLE_CHUNK`⌉ blocks of equal size (:data:`DEVICE_SAMPLE_CHUNK` on a
        GPU; :meth:`_sample_block`, or :meth:`_fused_block` in float32 on the CPU). Each block draws its uniforms (one per row)
        and normals z ~ N(0, I) (B, 2, n) from a generator of its own, seeded by one 63-bit integer
        per block drawn from ``generator`` in the calling thread. On the CPU with torch set to
        T > 1 threads, min(T, blocks) single-threaded workers of
        :func:`priortrack.threads.block_pool` sample the blocks, variates included, side by side
        (the calling thread only waits, so the workers never queue for the GIL behind it); the
        result does not depend on T. Works in x's dtype and on its device.
        """
        hot = self._hot(x.dtype, x.device, scale)
        block = self._sample_block if hot.kernel is None else self._fused_block
        out = torch.empty_like(x)
        chunk = SAMPLE_CHUNK if x.device.type == "cpu" else DEVICE_SAMPLE_CHUNK
        count = -(-len(x) // chunk)                              # blocks of equal size, for balanced workers
        bounds = [len(x) * i // count for i in range(count + 1)]
        seeds = torch.randint(2 ** 63 - 1, (count,), generator=generator, device=generator.device).tolist()
        jobs: queue.SimpleQueue = queue.SimpleQueue()
        for start, stop, seed in zip(bounds[:-1], bounds[1:], seeds):
            jobs.put((start, stop, seed))

        def work() -> None:
            with torch.inference_mode():
                while True:
                    try:
                        start, stop, seed = jobs.get_nowait()
                    except queue.Empty:
                        return
                    own = torch.Generator(device=x.device).manual_seed(seed)
                    u = torch.rand(stop - start, generator=own, dtype=x.dtype, device=x.device)
                    z = standard_normal((self.bones, 2, stop - start), own, x)
                    block(x[start:stop], u, z, hot, out[start:stop])

        workers = min(torch.get_num_threads(), count) if x.device.type == "cpu" else 1
        if workers <= 1:
            work()
            return out
        pool = block_pool(workers)
        for future in [pool.submit(work) for _ in range(workers)]:
            future.result()
        return out

    def mean_next(self, x: torch.Tensor, scale: float) -> torch.Tensor:
        """exp_x(E[v | x] / s) (P, 3B) for flat poses x (P, 3B).

        E[v | x] = Σ_k π_k(x) Γ_{μ_k→x}(E_kᵀ (m_k + R_k a_k)), the mixture's mean velocity.
        """
        hot = self._hot(x.dtype, x.device, scale)
        b, n = self.bones, x.shape[0]
        xp = self._planar(x)
        weights = torch.softmax(self._planar_logits(xp, hot), dim=0)                    # (K, P)
        lin = torch.empty(b, 7, n, dtype=x.dtype, device=x.device)
        vel = torch.empty(b, 3, n, dtype=x.dtype, device=x.device)
        mean = torch.zeros_like(xp)
        for k in range(self.components):
            self._affine_terms(xp, None, hot, k, lin, vel)
            mean.addcmul_(self._planar_step(xp, lin, vel), weights[k])
        return self._planar_exp(xp, mean).view(3 * b, n).t().contiguous()

    # ---- learning --------------------------------------------------------------------------------
    @classmethod
    def fit(cls, x: torch.Tensor, v: torch.Tensor, max_components: int = 30, ridge: float = 1e-6,
            tol: float = 1e-5, max_sweeps: int = 300, seed: int = 0,
            progress: Callable[[int, float], None] | None = None) -> tuple[GeodesicMixture, dict]:
        """Component-wise EM with the MML criterion (module docstring) on samples x, v (N, B, 3).

        Args:
            x: poses (N, B, 3), unit rows; v: velocities (N, B, 3) tangent at x (already scaled).
            max_components: components at the start, seeded at distinct random samples.
            ridge: added to every diagonal entry of each 4×4 block (in the coordinates' units).
            tol: a configuration has converged when a sweep changes L by less than tol·|L|.
            max_sweeps: sweeps per configuration at most (a warning is logged when reached).
            seed: seeds the choice of the starting samples.
            progress: called as progress(sweep, L) after every sweep.

        Returns:
            The mixture with the least message length and ``{"message_length", "log_likelihood",
            "sweeps", "frames"}`` of that configuration (sweeps: all sweeps run).
        """
        x, v = torch.as_tensor(x, dtype=torch.float64), torch.as_tensor(v, dtype=torch.float64)
        if x.dim() != 3 or x.shape[-1] != 3 or v.shape != x.shape:
            raise PriortrackError(f"fit: x and v must both be (N, B, 3), got {tuple(x.shape)} and {tuple(v.shape)}")
        if not bool(torch.isfinite(x).all() and torch.isfinite(v).all()):
            raise PriortrackError("fit: x or v contains NaN or inf")
        if max_components < 1:
            raise PriortrackError(f"fit: max_components must be positive, got {max_components}")
        em = _MessageLengthEM(x.reshape(len(x), -1).contiguous(), v.reshape(len(v), -1).contiguous(),
                              x.shape[1], ridge, tol, max_sweeps, progress)
        params, info = em.run(max_components, seed)
        return cls(*params), info


class _MessageLengthEM:
    """Figueiredo & Jain's component-wise EM over flat samples x, v (N, 3B), float64."""

    def __init__(self, x, v, bones, ridge, tol, max_sweeps, progress):
        self.x, self.v, self.b = x, v, bones
        self.n = x.shape[0]
        self.n_par = PARAMETERS_PER_BONE * bones
        if self.n <= self.n_par:
            raise PriortrackError(f"too few frames to fit: {self.n} samples for {bones} bones; the mixture "
                                  f"needs more than N_p = {self.n_par} (the parameters of one component)")
        self.ridge, self.tol, self.max_sweeps, self.progress = ridge, tol, max_sweeps, progress
        self.sweeps = 0

    def run(self, max_components: int, seed: int):
        """EM to convergence, then annihilate the smallest component and repeat down to one;
        return the parameters (α, μ, m, Σ) of the configuration with the least L, and a summary."""
        b = self.b
        k0 = min(max_components, self.n)
        start = torch.as_tensor(np.random.default_rng(seed).choice(self.n, size=k0, replace=False))
        self.mu = self.x[start].reshape(k0, b, 3).clone()                              # (K, B, 3)
        self.vel = to_coordinates(tangent_basis(self.mu), self.v[start].reshape(k0, b, 3))  # (K, B, 2)
        # F&J's start: every component gets a tenth of the data's spread, isotropic within the
        # pose part and within the velocity part of each bone.
        x3, v3 = self.x.reshape(self.n, b, 3), self.v.reshape(self.n, b, 3)
        pose_var = (log_map(karcher_mean(x3), x3) ** 2).sum(dim=-1).mean(dim=0) / 2    # (B,)
        vel_var = (v3 ** 2).sum(dim=-1).mean(dim=0) / 2
        block = torch.diag_embed(torch.stack([pose_var, pose_var, vel_var, vel_var], dim=-1)) / 10
        self.cov = (block + self.ridge * torch.eye(4, dtype=torch.float64)).expand(k0, b, 4, 4).clone()
        self.alpha = torch.full((k0,), 1.0 / k0, dtype=torch.float64)
        self.alive = torch.ones(k0, dtype=torch.bool)
        self.log_dens = torch.stack([self._log_density(k, *self._coordinates(k)) for k in range(k0)], dim=-1)

        best = None
        while True:
            length, loglik = self._converge()
            alive = torch.nonzero(self.alive).flatten()
            logger.info("MML EM: %d components, message length %.6g", len(alive), length)
            if best is None or length < best[0]:
                best = (length, loglik, self._snapshot())
            if len(alive) == 1:
                break
            self._annihilate(int(alive[torch.argmin(self.alpha[alive])]))
        length, loglik, params = best
        return params, {"message_length": length, "log_likelihood": loglik, "sweeps": self.sweeps, "frames": self.n}

    def _snapshot(self):
        keep = self.alive
        return (self.alpha[keep] / self.alpha[keep].sum(), self.mu[keep].clone(), self.vel[keep].clone(),
                self.cov[keep].clone())

    def _annihilate(self, k: int) -> None:
        self.alive[k] = False
        self.alpha[k] = 0.0
        self.alpha /= self.alpha.sum()

    def _coordinates(self, k: int):
        """(a, b) (N, B, 2) of every sample at component k."""
        return _coordinates(self.x, self.v, _frame_matrix(self.mu[k]), self.b)

    def _log_density(self, k: int, a: torch.Tensor, bv: torch.Tensor) -> torch.Tensor:
        """ln N(z_ik; (0, m_k), Σ_k) (N,) from the coordinates (a, b) at component k."""
        d = torch.cat([a, bv - self.vel[k]], dim=-1).reshape(self.n, 4 * self.b)
        factor = _cholesky(self.cov[k], f"covariance of component {k}")                 # (B, 4, 4)
        white = d @ _block_diagonal(whitening(factor).transpose(-1, -2))
        half_log_det = torch.log(factor.diagonal(dim1=-2, dim2=-1)).sum()
        return -0.5 * (white * white).sum(dim=-1) - half_log_det - 2 * self.b * _LOG_2PI

    def _message_length(self) -> tuple[float, float]:
        alpha = self.alpha[self.alive]
        loglik = float(torch.logsumexp(torch.log(alpha) + self.log_dens[:, self.alive], dim=-1).sum())
        k, n, n_par = len(alpha), self.n, self.n_par
        length = (n_par / 2 * float(torch.log(n * alpha / 12).sum()) + k / 2 * math.log(n / 12)
                  + k * (n_par + 1) / 2 - loglik)
        return length, loglik

    def _converge(self) -> tuple[float, float]:
        """CEM² sweeps until L changes by less than tol·|L| in a sweep that annihilated nothing."""
        previous = None
        for _ in range(self.max_sweeps):
            killed = self._sweep()
            self.sweeps += 1
            length, loglik = self._message_length()
            if self.progress is not None:
                self.progress(self.sweeps, length)
            if not killed and previous is not None and abs(previous - length) < self.tol * abs(length):
                return length, loglik
            previous = length
        logger.warning("MML EM: no convergence in %d sweeps (last message length %.6g)", self.max_sweeps, length)
        return length, loglik

    def _sweep(self) -> bool:
        """One pass of component-wise EM over the live components; True if one was annihilated."""
        killed = False
        for k in torch.nonzero(self.alive).flatten().tolist():
            alive = self.alive
            joint = torch.log(self.alpha[alive]) + self.log_dens[:, alive]
            w = torch.exp(torch.log(self.alpha[k]) + self.log_dens[:, k] - torch.logsumexp(joint, dim=-1))
            self.alpha[k] = max(0.0, float(w.sum()) - self.n_par / 2) / self.n
            if self.alpha[k] == 0:
                self._annihilate(k)
                killed = True
                continue
            self.alpha /= self.alpha.sum()
            self._m_step(k, w)
        return killed

    def _m_step(self, k: int, w: torch.Tensor) -> None:
        """μ_k: weighted Karcher mean; m_k, Σ_k: weighted moments of the coordinates (+ ridge I)."""
        self._karcher(k, w)
        a, bv = self._coordinates(k)
        total = w.sum()
        self.vel[k] = (w[:, None, None] * bv).sum(dim=0) / total
        d = torch.cat([a, bv - self.vel[k]], dim=-1)                                   # (N, B, 4)
        cov = torch.einsum("n,nbi,nbj->bij", w, d, d) / total
        self.cov[k] = cov + self.ridge * torch.eye(4, dtype=torch.float64)
        self.log_dens[:, k] = self._log_density(k, a, bv)

    def _karcher(self, k: int, w: torch.Tensor) -> None:
        """μ_k ← the weighted Karcher mean of the poses (:func:`~priortrack.geometry.sphere.karcher_mean`).
        Samples whose weight is below 1e-12 of the largest are left out (their pull on the mean
        is below that fraction too)."""
        keep = w > 1e-12 * w.max()
        self.mu[k] = karcher_mean(self.x[keep].reshape(-1, self.b, 3), weights=w[keep])


# ---------------------------------------------------------------------------------------------
# the transition model
# ---------------------------------------------------------------------------------------------


class LiePrior(TransitionModel):
    """The Lie-algebra kinematic prior as a transition model on :class:`DirectionSpace` states (P, 42).

    Attributes:
        mixture: the :class:`GeodesicMixture` over (x, v), B = 14.
        scale: s, v = s · log_x(x_next).
        message_length: L of the chosen configuration (NaN if not fitted here).
        log_likelihood: Σ_i ln p(x_i, v_i) over the training samples at that configuration.
        train_frames: N, the training samples (pairs of consecutive frames) used.
    """

    kind = "lie"

    def __init__(self, space: DirectionSpace, mixture: GeodesicMixture, scale: float = DEFAULT_SCALE,
                 fps: float = DEFAULT_FPS, message_length: float = float("nan"),
                 log_likelihood: float = float("nan"), train_frames: int = 0):
        if not isinstance(space, DirectionSpace):
            raise PriortrackError("the Lie prior lives on the bone-direction space (DirectionSpace)")
        if mixture.bones * 3 != space.dim:
            raise PriortrackError(f"mixture has {mixture.bones} bones; the direction space has {space.dim // 3}")
        if not scale > 0:
            raise PriortrackError(f"scale must be positive, got {scale}")
        self.space, self.mixture, self.scale, self.fps = space, mixture, float(scale), float(fps)
        self.message_length, self.log_likelihood = float(message_length), float(log_likelihood)
        self.objective = self.message_length
        self.train_frames = int(train_frames)

    @property
    def clusters(self) -> int:
        """K, the number of mixture components."""
        return self.mixture.components

    @classmethod
    def fit(cls, motions: Sequence[Motion], fps: float = DEFAULT_FPS, scale: float = DEFAULT_SCALE,
            max_components: int = 30, subsample: int | None = None, seed: int = 0,
            progress: Callable[[int, float], None] | None = None, ridge: float = 1e-6,
            tol: float = 1e-5, paces: Sequence[float] = (1.0,), mirror: bool = False, restarts: int = 1) -> LiePrior:
        """Learn the prior from motions (resampled to ``fps``) by MML EM (module docstring).

        Samples are the pairs (x_t, v_t = s log_{x_t}(x_{t+1})) within each motion; with
        ``subsample`` set, that many of them drawn without replacement (seeded by ``seed``,
        which also seeds the starting components). ``progress(sweep, message_length)``.
        ``paces``: each motion is also learned played at these speeds (time-warped before the
        velocities are taken: pace p samples it at fps / p and plays it at fps), so that a walk
        slower or faster than the training walks is not outside the conditional's reach.
        ``mirror``: each motion is also learned mirrored left for right (:func:`mirrored`), so that one
        person's asymmetries (a longer left stride, one arm swinging wider) are not taken for walking's.
        ``restarts``: EM run from that many starts (seeds ``seed``, ``seed + 1``, …), the mixture of the least
        message length kept. EM stops at a local optimum that depends on its start: on 07_01, 07_02 and 35's
        walks, seeds 0, 2 and 3 reach message length −87,549 and a held-out walk's velocity log-density −33.0,
        seeds 1 and 4 −77,940 / −77,750 and −52.6 / −53.4 (local diffusion: −55.3); the least message length
        picks the better one (tests/test_lie.py, docs/results/2026-11-27-processors.md).
        """
        if isinstance(restarts, bool) or not isinstance(restarts, int) or restarts < 1:
            raise PriortrackError(f"restarts must be a whole number ≥ 1, got {restarts!r}")
        if not paces or any(not (isinstance(p, (int, float)) and 0.2 <= p <= 5) for p in paces):
            raise PriortrackError(f"paces must be speeds in [0.2, 5], got {paces!r}")
        motions = [m.played_at(p) for m in prepare_motions(motions, fps, min_frames=2) for p in paces]
        space = DirectionSpace.fit(motions)
        xs, vs = [], []
        for m in motions:
            encoded = space.encode(m).reshape(len(m), -1, 3)
            for frames in (encoded, mirrored(encoded)) if mirror else (encoded,):
                xs.append(frames[:-1])
                vs.append(scale * log_map(frames[:-1], frames[1:]))
        x, v = torch.cat(xs), torch.cat(vs)
        if subsample is not None:
            if subsample < 1:
                raise PriortrackError(f"subsample must be a positive count, got {subsample}")
            if subsample < len(x):
                rng = np.random.default_rng((seed, 1))                                # apart from the EM's start
                keep = np.sort(rng.choice(len(x), size=subsample, replace=False))
                x, v = x[keep], v[keep]
        fits = [GeodesicMixture.fit(x, v, max_components=max_components, ridge=ridge, tol=tol, seed=seed + r,
                                    progress=progress) for r in range(restarts)]
        mixture, info = min(fits, key=lambda fit: fit[1]["message_length"])
        logger.info("Lie prior: %d clusters from %d samples (message length %.6g, %d sweeps)",
                    mixture.components, info["frames"], info["message_length"], info["sweeps"])
        return cls(space, mixture, scale, fps, info["message_length"], info["log_likelihood"], info["frames"])

    def sample(self, x, generator):
        """(P, 42) → (P, 42): x_next = exp_x(v / s), v ~ p(v | x) (k ~ π(x), then the Gaussian conditional)."""
        x = self.check_state(x)
        return self.mixture.sample_next(x.contiguous(), generator, self.scale)

    def velocity_log_prob(self, x_next, x) -> torch.Tensor:
        """(P, 42), (P, 42) → (P,) ln p(v | x) at v = s · log_x(x_next), in orthonormal coordinates of T_x."""
        x_next, x = self.check_pair(x_next, x)
        v = self.scale * self.space.boxminus(x_next, x)
        return self.mixture.velocity_log_prob(v.contiguous(), x.contiguous())

    def log_prob(self, x_next, x) -> torch.Tensor:
        """(P, 42), (P, 42) → (P,) ln p(x_next | x) = ln p(v = s log_x(x_next) | x) + 2B ln s,
        the density of the step log_x(x_next) in orthonormal tangent coordinates (as the diffusions)."""
        return self.velocity_log_prob(x_next, x) + 2 * self.mixture.bones * math.log(self.scale)

    def transition_covariance(self, x) -> torch.Tensor:
        """(P, 42) → (P, 28, 28) the covariance of the step u = log_x(x_next) = v / s in the tangent
        coordinates of :meth:`DirectionSpace.local` at each x: the mixture's conditional moment-matched
        to one Gaussian (:meth:`GeodesicMixture.velocity_moments`), divided by s². With :meth:`mean`
        (the same moments' mean) it is the Gaussian transition the unscented filter runs (``ukf-lie``)."""
        x = self.check_state(x)
        return self.mixture.velocity_moments(x.contiguous())[1] / self.scale ** 2

    def step_weights(self, x) -> torch.Tensor:
        """(P, 42) → ln π_k(x) (P, K), the weights of :meth:`step_components` (without their means)."""
        return self.mixture.log_responsibilities(self.check_state(x).contiguous())

    def step_components(self, x, covariances: bool = True, components: torch.Tensor | None = None):
        """(P, 42) → the transition as the mixture of Gaussian steps u = log_x(x_next) = v / s it is, in the tangent
        coordinates of :meth:`DirectionSpace.local` at each x: ln π_k(x) (P, K), means (P, K, 28), covariances
        (P, K, 28, 28) (None unless ``covariances``) (:meth:`GeodesicMixture.velocity_components` over s and s²);
        with ``components`` (P, k) indices, those of each row only."""
        log_pi, means, cov = self.mixture.velocity_components(self.check_state(x).contiguous(), covariances, components)
        return log_pi, means / self.scale, None if cov is None else cov / self.scale ** 2

    def responsibilities(self, x) -> torch.Tensor:
        """(P, 42) → (P, K) π_k(x), summing to 1 over k."""
        return torch.exp(self.mixture.log_responsibilities(self.check_state(x).contiguous()))

    def mean(self, x):
        """(P, 42) → (P, 42) exp_x(E[v | x] / s), E[v | x] the mixture's mean velocity at x."""
        return self.mixture.mean_next(self.check_state(x).contiguous(), self.scale)

    def _arrays(self):
        m = self.mixture
        return {"lie.weights": m.weights.numpy(), "lie.means": m.means.numpy(),
                "lie.velocity_means": m.velocity_means.numpy(), "lie.covariances": m.covariances.numpy()}

    def _header(self):
        return {"scale": self.scale, "clusters": self.clusters, "message_length": self.message_length,
                "log_likelihood": self.log_likelihood, "train_frames": self.train_frames,
                "preprocessing": {"fps": self.fps, "space": type(self.space).__name__}}

    @classmethod
    def _restore(cls, arrays, header):
        mixture = GeodesicMixture(arrays["lie.weights"], arrays["lie.means"], arrays["lie.velocity_means"],
                                  arrays["lie.covariances"])
        return cls(DirectionSpace.from_arrays(arrays), mixture, header["scale"], header["fps"],
                   header["message_length"], header["log_likelihood"], header["train_frames"])
