"""The 2D joint likelihood p(z_t | X) of a filter, with missing entries ignored.

For predicted 3D joints X (P, 15, 3) projected by the camera to û (P, 15, 2), and an
observation z (15, 2) with NaN where a joint was not seen, with d_j = z_j − û_j over the
observed joints j:

- Gaussian (the GPDM paper, σ_e = 10 px by default):
  log p = Σ_j [ −|d_j|² / (2σ²) − log(2π σ²) ];
- robust, a bivariate Student-t with ν degrees of freedom, scale σ:
  log p = Σ_j [ log Γ((ν+2)/2) − log Γ(ν/2) − log(ν π σ²) − (ν+2)/2 · log(1 + |d_j|²/(ν σ²)) ].

A predicted joint behind the camera cannot explain a detection: its |d_j|² is taken as
the squared image diagonal, the largest plausible miss. A frame with no observed joint
gives log p = 0 for every particle (no update).

**What counts as observed** (every observation model, every filter): a joint is observed only if
both its coordinates (and, with several cameras, its confidence, > 0) are finite; anything else
is missing, never half-used. A detection more than one image diagonal outside its image is a gross
outlier: :meth:`JointLikelihood.gate` makes it missing and the filters flag the frame
"outlier-gated".
"""

from __future__ import annotations

import math

import torch

from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera

DEFAULT_SIGMA_PX = 10.0


#: The pixel noise scales a likelihood accepts: below, every weight underflows; above, no image informs.
SIGMA_RANGE_PX = (1e-2, 1e4)
#: The Student-t degrees of freedom it accepts (above, it is the Gaussian: say robust_nu = None).
NU_RANGE = (0.1, 1e6)


def check_noise(sigma_px, robust_nu) -> None:
    """Raise a PriortrackError unless σ (pixels) and ν (or None) are numbers in their ranges."""
    low, high = SIGMA_RANGE_PX
    if isinstance(sigma_px, bool) or not isinstance(sigma_px, (int, float)) or not low <= sigma_px <= high:
        raise PriortrackError(f"sigma_px must be a number of pixels in [{low:g}, {high:g}], got {sigma_px!r}")
    low, high = NU_RANGE
    if robust_nu is not None and (isinstance(robust_nu, bool) or not isinstance(robust_nu, (int, float))
                                  or not low <= robust_nu <= high):
        raise PriortrackError(f"robust_nu must be a number in [{low:g}, {high:g}] (or None for a Gaussian), "
                              f"got {robust_nu!r}")


def outside(uv: torch.Tensor, camera: PinholeCamera) -> torch.Tensor:
    """(..., 2) pixels → (...) bool: finite and more than one image diagonal outside the image."""
    margin = math.hypot(camera.width, camera.height)
    u, v = uv[..., 0], uv[..., 1]
    return torch.isfinite(uv).all(dim=-1) & ((u < -margin) | (u > camera.width + margin) | (v < -margin)
                                             | (v > camera.height + margin))


class JointLikelihood:
    """Batched 2D joint likelihood through a pinhole camera.

    Args:
        camera: the camera that produced the observations.
        sigma_px: σ, the detection noise standard deviation (Gaussian) or scale (Student-t).
        robust_nu: ν of the Student-t; None for the Gaussian.
    """

    def __init__(self, camera: PinholeCamera, sigma_px: float = DEFAULT_SIGMA_PX, robust_nu: float | None = None):
        check_noise(sigma_px, robust_nu)
        self.camera, self.sigma_px, self.robust_nu = camera, float(sigma_px), robust_nu
        #: One frame's data: (J, 2) pixels of the 15 eval15 joints.
        self.observation_shape = (15, 2)
        #: |d_j|² of a predicted joint behind the camera: the squared image diagonal.
        self.miss_sq = float(camera.width ** 2 + camera.height ** 2)

    @property
    def cameras(self) -> list[PinholeCamera]:
        """The one camera as a list, as :class:`~priortrack.observation.multiview.MultiViewLikelihood` holds its
        cameras: what a caller iterates over either way."""
        return [self.camera]

    def gate(self, z) -> tuple[torch.Tensor, int]:
        """One frame's z (J, 2) with the gross outliers made missing, and their count: a detection more
        than one image diagonal outside the image is no pixel of this camera (validation gate)."""
        z = torch.as_tensor(z, dtype=torch.float64).clone()
        far = outside(z, self.camera)
        z[far] = float("nan")
        return z, int(far.sum())

    def pixels(self, joints: torch.Tensor) -> torch.Tensor:
        """The measurement a Gaussian filter predicts: (N, J, 3) joints → (N, 2J) pixels (NaN behind the camera)."""
        uv, _ = self.camera.project(joints)
        return uv.reshape(joints.shape[0], -1)

    def measurement(self, z) -> tuple[torch.Tensor, torch.Tensor]:
        """One frame's z (J, 2) → the measured pixels (2J,) (NaN: not seen) and their variances σ² (2J,).
        A joint is observed only if both its coordinates are finite (never half-used)."""
        z = torch.as_tensor(z, dtype=torch.float64)
        values = torch.where(torch.isfinite(z).all(dim=-1, keepdim=True), z, float("nan")).reshape(-1)
        return values, torch.full_like(values, self.sigma_px ** 2)

    @property
    def linearisable(self) -> bool:
        """Whether the particle filter may integrate the translation out (:meth:`linearised`): the
        Gaussian only, whose predictive likelihood is then exact up to the linearisation."""
        return self.robust_nu is None

    def linearised(self, joints: torch.Tensor, z) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """At the (predicted) joints (P, J, 3), z (J, 2): A = Σ_j J_jᵀ J_j / σ² (P, 3, 3),
        b = Σ_j J_jᵀ r_j / σ² (P, 3) over the observed joints in front of the camera (J_j = ∂u/∂X,
        r_j = z_j − û_j), and log p(z | joints) (P,) (Gaussian; a joint behind the camera counts
        as a miss of the image diagonal and adds nothing to A and b)."""
        z = torch.as_tensor(z, dtype=joints.dtype, device=joints.device)
        seen = torch.isfinite(z).all(dim=-1).nonzero()[:, 0]
        uv, J, in_front = self.camera.project_jacobian(joints.index_select(1, seen))   # (P, n, 2), (P, n, 2, 3)
        d = torch.where(in_front[..., None], z[seen] - uv, 0.0)
        d_sq = torch.where(in_front, (d * d).sum(dim=-1), self.miss_sq).sum(dim=-1)
        r = d.reshape(len(joints), -1, 1)                                                # (P, 2n, 1)
        J = torch.where(in_front[..., None, None], J, 0.0).reshape(len(joints), -1, 3)  # (P, 2n, 3)
        inv_var = 1.0 / self.sigma_px ** 2
        return J.transpose(1, 2) @ J * inv_var, (J.transpose(1, 2) @ r)[..., 0] * inv_var, self.gaussian(d_sq, len(seen))

    def log_likelihood(self, joints: torch.Tensor, z) -> torch.Tensor:
        """(P, 15, 3) predicted joints (metres, world), z (15, 2) pixels with NaN → (P,)."""
        z = torch.as_tensor(z, dtype=joints.dtype, device=joints.device)
        if joints.dim() != 3 or joints.shape[1:] != z.shape[:1] + (3,) or z.shape[-1:] != (2,):
            raise PriortrackError(f"joints {tuple(joints.shape)} and observation {tuple(z.shape)}: "
                                  f"expected (P, J, 3) and (J, 2)")
        seen = torch.isfinite(z).all(dim=-1).nonzero()[:, 0]                  # observed joints
        if not len(seen):
            return torch.zeros(joints.shape[0], dtype=joints.dtype, device=joints.device)
        uv, in_front = self.camera.project(joints.index_select(1, seen))
        d = uv - z[seen]
        d_sq = torch.addcmul(d[..., 0] * d[..., 0], d[..., 1], d[..., 1])
        d_sq = torch.where(in_front, d_sq, self.miss_sq)
        if self.robust_nu is None:      # the Gaussian's sum over joints, taken before its affine map
            return self.gaussian(d_sq.sum(dim=-1), len(seen))
        return self.per_joint(d_sq).sum(dim=-1)

    def gaussian(self, d_sq: torch.Tensor, joints: int) -> torch.Tensor:
        """Σ_j [−|d_j|² / (2σ²) − log(2π σ²)] over ``joints`` joints from their summed |d_j|²."""
        var = self.sigma_px ** 2
        return -0.5 / var * d_sq - joints * math.log(2 * math.pi * var)

    def per_joint(self, d_sq: torch.Tensor) -> torch.Tensor:
        """Log density of each observed joint from its squared pixel miss |d_j|² (any shape)."""
        if self.robust_nu is None:
            return self.gaussian(d_sq, 1)
        var, nu = self.sigma_px ** 2, self.robust_nu
        const = math.lgamma((nu + 2) / 2) - math.lgamma(nu / 2) - math.log(nu * math.pi * var)
        return const - 0.5 * (nu + 2) * torch.log1p(d_sq / (nu * var))
