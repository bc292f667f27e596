"""A fixed orthonormal basis of each tangent plane of (S^2)^K, and coordinates in it.

For a unit vector mu in R^3 the basis (e1, e2) of T_mu S^2 is built deterministically:

    j  = argmin_i |mu_i|                 (the axis least aligned with mu; the first on ties),
    e1 = (e_j - mu_j mu) / |e_j - mu_j mu|   (e_j projected onto the tangent plane),
    e2 = mu x e1,

so (e1, e2, mu) is a right-handed orthonormal frame. Since |mu_j| <= 1/sqrt(3),
|e_j - mu_j mu|^2 = 1 - mu_j^2 >= 2/3 and the normalisation is always safe. The basis
depends only on mu (bit for bit), so a model that stores mu rebuilds the same basis.

Shapes follow :mod:`priortrack.geometry.sphere`: points (..., K, 3), bases (..., K, 2, 3)
(rows e1, e2), 2-D coordinates (..., K, 2).
"""

from __future__ import annotations

import torch

from priortrack.errors import PriortrackError

__all__ = ["tangent_basis", "to_coordinates", "from_coordinates"]


def tangent_basis(mu: torch.Tensor) -> torch.Tensor:
    """Orthonormal basis (rows e1, e2) of the tangent plane at every unit row of ``mu``.

    Args:
        mu: points (..., K, 3), unit rows.

    Returns:
        (..., K, 2, 3): for each sphere the rows e1, e2 defined in the module docstring.
    """
    if not isinstance(mu, torch.Tensor) or not mu.is_floating_point() or mu.dim() < 1 or mu.shape[-1] != 3:
        raise PriortrackError(f"mu: expected a floating-point tensor of shape (..., K, 3), "
                              f"got {getattr(mu, 'shape', type(mu).__name__)}")
    least_aligned = mu.abs().argmin(dim=-1, keepdim=True)
    axis = torch.zeros_like(mu).scatter_(-1, least_aligned, 1.0)
    e1 = axis - torch.gather(mu, -1, least_aligned) * mu
    e1 = e1 / torch.linalg.vector_norm(e1, dim=-1, keepdim=True)
    e2 = torch.linalg.cross(mu, e1, dim=-1)
    return torch.stack([e1, e2], dim=-2)


def to_coordinates(basis: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Coordinates (..., K, 2) of tangent vectors v (..., K, 3) in ``basis`` (..., K, 2, 3): c_i = e_i · v."""
    return (basis * v.unsqueeze(-2)).sum(dim=-1)


def from_coordinates(basis: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Tangent vectors (..., K, 3) = c_1 e1 + c_2 e2 from coordinates c (..., K, 2) in ``basis`` (..., K, 2, 3)."""
    return (basis * c.unsqueeze(-1)).sum(dim=-2)
