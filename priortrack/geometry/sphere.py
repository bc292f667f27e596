"""Geometry on the product of unit 2-spheres (S^2)^K.

A human pose is K bone directions, one unit vector in R^3 per bone, so a pose is a
point of the product manifold (S^2)^K. Conventions used by every function here:

* a point is a tensor of shape (..., K, 3) whose rows are unit vectors;
* a tangent vector at a point x has the same shape, each row orthogonal to the
  matching row of x;
* leading batch dimensions broadcast (as in ``torch``), and results come back in the
  dtype and on the device of the inputs;
* the metric is the product metric, so everything acts sphere by sphere (row by row),
  and the product distance is sqrt(sum_k theta_k^2).

Inputs are NOT checked for unit norm or tangency (these functions sit on the
filter's hot path): callers must pass unit vectors as points and tangent vectors as
tangent vectors. Shapes and dtypes are checked; bad ones raise
:class:`~priortrack.errors.PriortrackError` naming the argument.
"""

from __future__ import annotations

import logging
import math
import numbers
from typing import Any

import torch

from priortrack.errors import PriortrackError

__all__ = [
    "clamped_cosine",
    "distance",
    "exp_map",
    "karcher_mean",
    "log_map",
    "project_to_tangent",
    "sphere_angles",
    "theta_over_sin",
    "transport",
]

logger = logging.getLogger(__name__)


# ---------------------------------------------------------------------------
# Input checks
# ---------------------------------------------------------------------------


def _check_rows(name: str, value: Any, shape: str = "(..., K, 3)", min_dim: int = 2) -> None:
    """Raise unless ``value`` is a floating tensor of >= ``min_dim`` dims ending in 3."""
    if not isinstance(value, torch.Tensor):
        raise PriortrackError(
            f"{name}: expected a torch.Tensor of shape {shape}, got {type(value).__name__}"
        )
    if not value.is_floating_point():
        raise PriortrackError(
            f"{name}: expected a floating-point tensor of shape {shape}, got dtype {value.dtype}"
        )
    if value.dim() < min_dim or value.shape[-1] != 3:
        raise PriortrackError(f"{name}: expected shape {shape}, got {tuple(value.shape)}")


def _check_broadcast(**tensors: torch.Tensor) -> None:
    """Raise unless the named tensors broadcast together."""
    try:
        torch.broadcast_shapes(*(tensor.shape for tensor in tensors.values()))
    except RuntimeError:
        names = " and ".join(tensors)
        got = ", ".join(f"{name} {tuple(tensor.shape)}" for name, tensor in tensors.items())
        raise PriortrackError(
            f"{names}: expected shapes (..., K, 3) that broadcast together, got {got}"
        ) from None


def _normalised_weights(weights: Any, count: int, points: torch.Tensor) -> torch.Tensor:
    """Return ``weights`` (N,) as a tensor like ``points`` summing to one, or raise."""
    if weights is None:
        return torch.full((count,), 1.0 / count, dtype=points.dtype, device=points.device)
    try:
        weights = torch.as_tensor(weights, dtype=points.dtype, device=points.device)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise PriortrackError(
            f"weights: expected a numeric array of shape (N,) = ({count},), "
            f"could not convert ({exc})"
        ) from None
    if weights.shape != (count,):
        raise PriortrackError(
            f"weights: expected shape (N,) = ({count},) to match x, got {tuple(weights.shape)}"
        )
    if not bool(torch.isfinite(weights).all()):
        raise PriortrackError(
            f"weights: expected finite values of shape ({count},), found NaN or inf"
        )
    if bool((weights < 0).any()):
        raise PriortrackError(
            f"weights: expected non-negative values of shape ({count},), "
            f"got minimum {float(weights.min())}"
        )
    total = weights.sum()
    if not bool(total > 0):
        raise PriortrackError(
            f"weights: expected shape ({count},) with a positive sum, got all zero"
        )
    return weights / total


# ---------------------------------------------------------------------------
# Unchecked kernels (shared by the public functions and the Karcher loop)
# ---------------------------------------------------------------------------


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Row-wise inner product a·b, keeping the last dimension: (..., 1)."""
    return (a * b).sum(dim=-1, keepdim=True)


def _taylor_threshold(dtype: torch.dtype) -> float:
    """Squared angle below which the Taylor branches are used: sqrt(eps) of ``dtype``.

    For t^2 < sqrt(eps) the first omitted Taylor terms (order t^6) are far below eps,
    so the series is exact to working precision there.
    """
    return torch.finfo(dtype).eps ** 0.5


def _tangent_part(x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """u - (x·u) x, row-wise."""
    return u - _dot(x, u) * x


def _chord_projection(x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Return (w, cos) with w = y - (x·y) x (..., K, 3) and cos = x·y (..., K, 1).

    For unit x, y - (x·y) x is also the projection of y - x and of y + x onto the
    tangent plane at x. Projecting whichever of those two chords is short (y - x when
    x·y >= 0, y + x otherwise) avoids the cancellation the direct formula suffers near
    y = x and y = -x, so w keeps full relative precision at every angle, and it is
    exactly zero when y == x or y == -x.
    """
    cos = _dot(x, y)
    chord = torch.where(cos >= 0, y - x, y + x)
    return _tangent_part(x, chord), cos


def _antipodal_mask(sin_sq: torch.Tensor, cos: torch.Tensor) -> torch.Tensor:
    """True where y = -x to working precision: |w|^2 below the smallest normal float, x·y <= 0."""
    return (sin_sq < torch.finfo(sin_sq.dtype).tiny) & (cos <= 0)


def _antipodal_direction(x: torch.Tensor) -> torch.Tensor:
    """Deterministic unit tangent at x: normalise(x × e_j), e_j the axis least aligned with x.

    j = argmin_i |x_i| (the first such index on ties). Since |x_j| <= 1/sqrt(3),
    |x × e_j| = sqrt(1 - x_j^2) >= sqrt(2/3), so the normalisation is always safe.
    """
    least_aligned = x.abs().argmin(dim=-1, keepdim=True)
    axis = torch.zeros_like(x).scatter_(-1, least_aligned, 1.0)
    direction = torch.linalg.cross(x, axis, dim=-1)
    return direction / torch.linalg.vector_norm(direction, dim=-1, keepdim=True)


def _exp(x: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Unchecked :func:`exp_map`."""
    angle_sq = _dot(v, v)
    small = angle_sq < _taylor_threshold(angle_sq.dtype)
    # sqrt only of values bounded away from 0, so the unused branch has a finite gradient.
    safe_angle = torch.sqrt(torch.where(small, torch.ones_like(angle_sq), angle_sq))
    cos_angle = torch.where(small, 1 - angle_sq / 2 + angle_sq**2 / 24, torch.cos(safe_angle))
    sinc_angle = torch.where(
        small, 1 - angle_sq / 6 + angle_sq**2 / 120, torch.sin(safe_angle) / safe_angle
    )
    return cos_angle * x + sinc_angle * v


def _log(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Unchecked :func:`log_map`."""
    w, cos = _chord_projection(x, y)
    sin_sq = _dot(w, w)
    near = (sin_sq < _taylor_threshold(sin_sq.dtype)) & (cos > 0)
    antipodal = _antipodal_mask(sin_sq, cos)
    regular = ~(near | antipodal)
    safe_sin = torch.sqrt(torch.where(regular, sin_sq, torch.ones_like(sin_sq)))
    angle = torch.atan2(safe_sin, cos)
    # theta / sin(theta) = 1 + s^2/6 + 3 s^4/40 + O(s^6) with s = sin(theta) = |w|.
    scale = torch.where(near, 1 + sin_sq / 6 + 3 * sin_sq**2 / 40, angle / safe_sin)
    return torch.where(antipodal, math.pi * _antipodal_direction(x), scale * w)


# ---------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------


def project_to_tangent(x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Orthogonal projection of ambient vectors onto the tangent space at x.

    Per sphere k: P_x(u)_k = u_k - (x_k·u_k) x_k.

    Args:
        x: base point (..., K, 3), unit rows.
        u: ambient vectors (..., K, 3), broadcastable with ``x``.

    Returns:
        Tangent vectors at x, shape broadcast(x, u).
    """
    _check_rows("x", x)
    _check_rows("u", u)
    _check_broadcast(x=x, u=u)
    return _tangent_part(x, u)


def exp_map(x: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Riemannian exponential map of (S^2)^K.

    Per sphere k, with t = |v_k|:

        exp_x(v)_k = cos(t) x_k + (sin(t)/t) v_k

    which follows the great circle from x_k in direction v_k for arc length t.
    For t^2 < sqrt(eps) cos(t) and sin(t)/t are evaluated by their Taylor series
    (1 - t^2/2 + t^4/24 and 1 - t^2/6 + t^4/120), so the result keeps working
    precision near v = 0 (where exp_x(v) = x + v + O(|v|^2)), is never NaN, and is
    differentiable at v = 0 with Jacobian d exp_x(v)/dv = I.

    Args:
        x: base point (..., K, 3), unit rows.
        v: tangent vector at x (..., K, 3), broadcastable with ``x``.

    Returns:
        Point of shape broadcast(x, v).
    """
    _check_rows("x", x)
    _check_rows("v", v)
    _check_broadcast(x=x, v=v)
    return _exp(x, v)


def log_map(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Riemannian logarithm of (S^2)^K: the tangent vector at x pointing to y.

    Per sphere k:

        w_k = y_k - (x_k·y_k) x_k,
        theta_k = atan2(|x_k × y_k|, x_k·y_k)   (|x_k × y_k| = |w_k| for unit x_k),
        log_x(y)_k = theta_k w_k / |w_k|,

    so |log_x(y)_k| = theta_k in [0, pi] and exp_x(log_x(y)) = y.

    * Near y_k = x_k the factor theta/|w| = theta/sin(theta) uses its Taylor series
      1 + s^2/6 + 3 s^4/40 (s = |w|), so the result is accurate to working precision,
      exactly 0 when y_k == x_k, and has a finite gradient there.
    * w is computed from the short chord (y - x or y + x, see below), so it keeps full
      relative precision right up to y_k = -x_k.
    * Antipodal rows, y_k = -x_k (|w_k|^2 below the smallest normal float and
      x_k·y_k <= 0): every direction is a minimising geodesic, so the log is not
      unique. This function returns pi u_k with the deterministic unit tangent

          u_k = (x_k × e_j) / |x_k × e_j|,   j = argmin_i |x_k,i| (first on ties),

      the cross product of x_k with the coordinate axis least aligned with it.
      :func:`transport` follows the same geodesic.

    Args:
        x: base point (..., K, 3), unit rows.
        y: target point (..., K, 3), unit rows, broadcastable with ``x``.

    Returns:
        Tangent vector at x, shape broadcast(x, y).
    """
    _check_rows("x", x)
    _check_rows("y", y)
    _check_broadcast(x=x, y=y)
    return _log(x, y)


def sphere_angles(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Per-sphere geodesic distance (great-circle angle) between x and y.

    Per sphere k: theta_k = atan2(|x_k × y_k|, x_k·y_k) in [0, pi], evaluated as
    atan2(|w_k|, x_k·y_k) with w_k = y_k - (x_k·y_k) x_k from the short chord (as in
    :func:`log_map`), which is accurate at all angles, unlike arccos(x·y).
    Equals |log_x(y)_k|.

    Args:
        x: points (..., K, 3), unit rows.
        y: points (..., K, 3), unit rows, broadcastable with ``x``.

    Returns:
        Angles in radians, shape broadcast(x, y)[:-1], i.e. (..., K).
    """
    _check_rows("x", x)
    _check_rows("y", y)
    _check_broadcast(x=x, y=y)
    w, cos = _chord_projection(x, y)
    return torch.atan2(torch.linalg.vector_norm(w, dim=-1), cos.squeeze(-1))


def distance(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Geodesic distance on the product manifold (S^2)^K.

        d(x, y) = sqrt(sum_k theta_k^2),   theta_k = :func:`sphere_angles`(x, y)_k.

    Args:
        x: points (..., K, 3), unit rows.
        y: points (..., K, 3), unit rows, broadcastable with ``x``.

    Returns:
        Distances of shape broadcast(x, y)[:-2], i.e. (...).
    """
    return torch.linalg.vector_norm(sphere_angles(x, y), dim=-1)


def transport(x: torch.Tensor, y: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Parallel transport of v from T_x to T_y along the minimising geodesic, per sphere.

    Per sphere k, with theta = theta_k > 0 the closed form is

        P(v) = v - (log_x(y)·v) / theta^2 (log_x(y) + log_y(x)),

    the identity when x_k == y_k. Substituting log_x(y) = theta w/|w| and
    log_y(x) = theta (x - c y)/|w|, with c = x·y, w = y - c x and |w|^2 = 1 - c^2,
    gives for tangent v the form that is evaluated:

        P(v) = v - (w·v) (x + k w),   k = 1/(1 + c) = (1 - c)/|w|^2,

    where k uses 1/(1 + c) for c >= 0 and (1 - c)/|w|^2 for c < 0, and w is the
    short-chord projection of :func:`log_map`. Nothing cancels, so this is accurate
    from theta = 0 (where it is exactly v - (w·v) x = v for tangent v) right up to
    the antipode. For antipodal rows (y_k = -x_k, same test as :func:`log_map`) the
    transport follows the geodesic that :func:`log_map` picks, in direction u_k:
    P(v) = v - 2 (u_k·v) u_k (the component along u_k flips, the one along x_k × u_k
    is kept). Norms and inner products are preserved.

    Args:
        x: start point (..., K, 3), unit rows.
        y: end point (..., K, 3), unit rows.
        v: tangent vector at x (..., K, 3). ``x``, ``y`` and ``v`` must broadcast.

    Returns:
        Tangent vector at y, shape broadcast(x, y, v).
    """
    _check_rows("x", x)
    _check_rows("y", y)
    _check_rows("v", v)
    _check_broadcast(x=x, y=y, v=v)
    w, cos = _chord_projection(x, y)
    sin_sq = _dot(w, w)
    antipodal = _antipodal_mask(sin_sq, cos)
    # Each branch of k only ever divides by a quantity bounded away from 0 (1 + c >= 1,
    # or |w|^2 >= tiny), so the unused branch has no inf/NaN gradient either.
    use_sin = (cos < 0) & ~antipodal
    safe_sin_sq = torch.where(use_sin, sin_sq, torch.ones_like(sin_sq))
    k = torch.where(use_sin, (1 - cos) / safe_sin_sq, 1 / (1 + cos.clamp(min=0)))
    along_geodesic = v - _dot(w, v) * (x + k * w)
    flip_direction = _antipodal_direction(x)
    flipped = v - 2 * _dot(flip_direction, v) * flip_direction
    return torch.where(antipodal, flipped, along_geodesic)


def clamped_cosine(c: torch.Tensor, inplace: bool = False) -> torch.Tensor:
    """c clamped to [−c_max, c_max], c_max the largest float below 1 in c's dtype (in place if
    ``inplace``)."""
    c_max = 1.0 - torch.finfo(c.dtype).eps / 2
    return c.clamp_(-c_max, c_max) if inplace else c.clamp(-c_max, c_max)


def theta_over_sin(c: torch.Tensor) -> torch.Tensor:
    """θ / sin θ for θ = arccos(c), c = μ·x the cosine of the geodesic angle, elementwise.

    c must be clamped by :func:`clamped_cosine`, so that sin²θ, evaluated as (1 − c)(1 + c) (no
    cancellation: 1 − c is exact near c = 1), is positive and the ratio tends smoothly to 1
    at θ = 0. θ and sin θ come from the same rounded c, so the ratio is accurate to a few
    ulps even where c itself carries rounding.
    """
    return torch.acos(c) / torch.sqrt((1 - c) * (1 + c))


def _mean_step(mean: torch.Tensor, rows: torch.Tensor, weights: torch.Tensor,
               dtype: torch.dtype) -> torch.Tensor | None:
    """Σ_i w_i log_μ(x_i) for B spheres at once, or None if some x_i is 90° or more from μ.

    With c_i = μ·x_i and θ_i = arccos c_i, log_μ(x_i) = θ_i / sin θ_i · (x_i − c_i μ), so

        Σ_i w_i log_μ(x_i) = Σ_i a_i x_i − (Σ_i a_i c_i) μ,   a_i = w_i θ_i / sin θ_i,

    two batched products and one scalar function of c per point (:func:`theta_over_sin`),
    instead of :func:`_log`'s row-wise vector algebra. θ/sin θ is a smooth function of c on
    (0, 1] (1 + (1 − c)/3 + … near c = 1), so the sum is accurate to rounding in absolute terms.
    For c ≤ 0 (θ ≥ 90°) that absolute accuracy is lost as θ → π, so the caller falls back to
    :func:`_log`'s short-chord form.

    Args:
        mean: μ (B, 3), unit rows, float64.
        rows: points as columns (B, 3, N), unit columns, float64.
        weights: w (N,), summing to one, float64.
        dtype: the dtype θ/sin θ is evaluated in (the points' own): its relative rounding moves
            the step by about that much of the points' mean angle, far below the tolerance
            for that dtype, and float32 is four times faster than float64. c and the sums stay
            float64.

    Returns:
        The step (B, 3), float64, or None.
    """
    cos = torch.bmm(mean[:, None, :], rows).squeeze(1)                           # (B, N)
    if not bool((cos > 0).all()):
        return None
    a = theta_over_sin(clamped_cosine(cos.to(dtype))).to(torch.float64).mul_(weights)
    return torch.bmm(rows, a[:, :, None]).squeeze(-1) - (a * cos).sum(-1, keepdim=True) * mean


def karcher_mean(
    x: torch.Tensor,
    weights: Any = None,
    tol: float | None = None,
    max_iter: int = 100,
) -> torch.Tensor:
    """Weighted Karcher (Frechet) mean of N points of (S^2)^K.

    Minimises sum_i w_i d(mu, x_i)^2 by the fixed-point iteration

        mu <- exp_mu( sum_i w_i log_mu(x_i) ),

    whose fixed points satisfy the first-order condition sum_i w_i log_mu(x_i) = 0.
    Weights are normalised to sum to one. The iteration starts, per sphere, at the
    normalised weighted Euclidean mean sum_i w_i x_i / |sum_i w_i x_i|, or at the
    highest-weight point (the first on ties) where that sum has norm below sqrt(eps).
    It stops after the first step whose product-space norm sqrt(sum_k |step_k|^2) is
    below ``tol`` for every batch element (that step is applied), or after
    ``max_iter`` steps, logging a warning. The iterate is renormalised to unit rows
    after every step. ``tol`` must exceed the dtype's rounding level; the default is
    max(1e-12, 10 eps) of x's dtype: 1e-12 in float64, 1.2e-6 in float32. The iteration
    runs in float64 whatever x's dtype (a float32 sum over 10⁴ points rounds to more than
    float32's eps, and the step would never fall below it). The mean is unique and the iteration
    converges when the points lie in a geodesic ball of radius below pi/2 on every
    sphere.

    Args:
        x: points (N, ..., K, 3), unit rows; the mean is over the first dimension.
        weights: non-negative weights (N,), not all zero; ``None`` means uniform.
        tol: convergence threshold on the step norm, radians (> 0); None for the default.
        max_iter: maximum number of iterations (>= 1).

    Returns:
        The mean, shape (..., K, 3), in the dtype and on the device of ``x``.
    """
    _check_rows("x", x, shape="(N, ..., K, 3)", min_dim=3)
    count = x.shape[0]
    if count == 0:
        raise PriortrackError("x: expected shape (N, ..., K, 3) with N >= 1, got N = 0")
    if tol is None:
        tol = max(1e-12, 10 * torch.finfo(x.dtype).eps)
    if not tol > 0:
        raise PriortrackError(f"tol: expected a positive step-norm threshold, got {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, numbers.Integral) or max_iter < 1:
        raise PriortrackError(f"max_iter: expected a positive integer, got {max_iter!r}")
    dtype = x.dtype
    # Sums over many points carry rounding of about sqrt(N) eps: accumulate in float64, on the
    # points batch-last (B, 3, N), B = the (..., K) spheres (one copy does both).
    rows = x.reshape(count, -1, 3).permute(1, 2, 0).to(torch.float64, memory_format=torch.contiguous_format)
    flat_weights = _normalised_weights(weights, count, rows)
    mean_shape = x.shape[1:]

    euclidean = torch.matmul(rows, flat_weights).reshape(mean_shape)
    norm = torch.linalg.vector_norm(euclidean, dim=-1, keepdim=True)
    degenerate = norm < torch.finfo(torch.float64).eps ** 0.5
    heaviest = x[int(torch.argmax(flat_weights))].to(torch.float64)
    mean = torch.where(degenerate, heaviest, euclidean / torch.where(degenerate, 1.0, norm))

    points = None                                       # x in float64, only if a step needs _log
    for _ in range(max_iter):
        step = _mean_step(mean.reshape(-1, 3), rows, flat_weights, dtype)
        if step is None:
            points = x.to(torch.float64) if points is None else points
            step = torch.tensordot(flat_weights, _log(mean, points), dims=1)
        else:
            step = step.reshape(mean_shape)
        # log_map and exp_map assume unit rows; renormalising keeps rounding in the
        # iterate's norm from feeding back into the step and growing.
        mean = _exp(mean, step)
        mean = mean / torch.linalg.vector_norm(mean, dim=-1, keepdim=True)
        step_norm = float(torch.linalg.vector_norm(step.flatten(-2), dim=-1).max())
        if step_norm < tol:
            return mean.to(dtype)
    logger.warning(
        "karcher_mean: no convergence after %d iterations (last step norm %.3g >= tol %.3g)",
        max_iter,
        step_norm,
        tol,
    )
    return mean.to(dtype)
