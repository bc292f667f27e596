"""The observation model of real detections: a product over cameras of per-joint robust 2D terms,
each weighted by its detection confidence (as HuMoR and SLAHMR weight their 2D terms).

One frame's data z is (C, J, 3): per camera c and joint j the pixels (u, v) and the detector's
confidence w_cj (NaN pixels or w = 0: not seen). With d_cj the pixel miss of the projected joint
through camera c (lens distortion included) and ℓ the per-joint log density of
:class:`~priortrack.observation.likelihood.JointLikelihood` (Student-t with ν degrees of freedom, the
default on real data, or Gaussian), scale σ:

    log p(z | X) = Σ_c Σ_j w_cj ℓ(|d_cj|²).

A joint behind camera c counts as a miss of that image's diagonal. With a ``joint_map`` M (J × J,
rows summing to one: :func:`priortrack.data.keypoints.detector_map`), the body's joints X are
compared in the detector's definitions, M X.

**Linearisation** (for the particle filter's Kalman update of the translation,
:mod:`priortrack.filters.marginal_translation`): at the predicted joints, with J_cj = ∂u/∂X,
r_cj = z_cj − û_cj and the iteratively-reweighted-least-squares weight of each term,

    W_cj = w_cj (ν + 2) / (ν σ² + |r_cj|²)   (Student-t),   W_cj = w_cj / σ²   (Gaussian),

A = Σ J_cjᵀ W_cj J_cj and b = Σ J_cjᵀ W_cj r_cj: the Gauss–Newton (for the Student-t, the
Gaussian-scale-mixture) approximation of the log-likelihood around the predicted translation.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera
from priortrack.observation.likelihood import JointLikelihood, check_noise, outside

#: σ (pixels) and ν of the real-data default: a Student-t with heavy tails for detector errors.
DEFAULT_SIGMA_PX, DEFAULT_NU = 5.0, 4.0


class MultiViewLikelihood:
    """Σ_c Σ_j w_cj ℓ(|d_cj|²) over C cameras (module docstring).

    Args:
        cameras: the C calibrated cameras, in the order of z's first axis.
        sigma_px: σ in pixels.
        robust_nu: ν of the Student-t; None for a Gaussian.
        joints: J, the joints per camera (15 for eval15).
        joint_map: M (J, J) taking the body's joints to the observations' definitions; None for the identity.
    """

    #: The particle filter may integrate the translation out under this model (:meth:`linearised`).
    linearisable = True

    def __init__(self, cameras: Sequence[PinholeCamera], sigma_px: float = DEFAULT_SIGMA_PX,
                 robust_nu: float | None = DEFAULT_NU, joints: int = 15, joint_map=None):
        if not cameras:
            raise PriortrackError("a multi-view likelihood needs at least one camera")
        check_noise(sigma_px, robust_nu)
        self.joint_map = None if joint_map is None else torch.as_tensor(joint_map, dtype=torch.float64)
        if self.joint_map is not None and (self.joint_map.shape != (joints, joints) or
                                           not torch.allclose(self.joint_map.sum(dim=1), torch.ones(joints, dtype=torch.float64))):
            raise PriortrackError(f"joint_map must be ({joints}, {joints}) with rows summing to one")
        self.views = [JointLikelihood(c, sigma_px, robust_nu) for c in cameras]
        self.cameras = list(cameras)
        self.sigma_px, self.robust_nu = float(sigma_px), robust_nu
        self.observation_shape = (len(cameras), int(joints), 3)

    def _split(self, joints: torch.Tensor, z) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """z → pixels (C, J, 2) and weights (C, J) (0 where not seen), checked against joints (P, J, 3)."""
        z = torch.as_tensor(z, dtype=joints.dtype, device=joints.device)
        if z.shape != self.observation_shape or joints.dim() != 3 or joints.shape[1:] != (z.shape[1], 3):
            raise PriortrackError(f"joints {tuple(joints.shape)} and observation {tuple(z.shape)}: expected (P, "
                                  f"{self.observation_shape[1]}, 3) and {self.observation_shape}")
        uv, w = z[..., :2], z[..., 2]
        seen = torch.isfinite(uv).all(dim=-1) & torch.isfinite(w) & (w > 0)
        return torch.where(seen[..., None], uv, 0.0), torch.where(seen, w, 0.0), seen

    def _mapped(self, joints: torch.Tensor) -> torch.Tensor:
        """M X (P, J, 3): the joints in the observations' definitions."""
        if self.joint_map is None:
            return joints
        return torch.einsum("ij,pjk->pik", self.joint_map.to(joints), joints)

    def gate(self, z) -> tuple[torch.Tensor, int]:
        """One frame's z (C, J, 3) with the gross outliers made missing (confidence 0), and their count:
        a detection more than one image diagonal outside its camera's image (validation gate)."""
        z = torch.as_tensor(z, dtype=torch.float64).clone()
        if tuple(z.shape) != self.observation_shape:
            raise PriortrackError(f"observation {tuple(z.shape)}: expected {self.observation_shape}")
        count = 0
        for c, view in enumerate(self.views):
            far = outside(z[c, :, :2], view.camera)
            z[c, far] = torch.tensor([float("nan"), float("nan"), 0.0], dtype=torch.float64, device=z.device)
            count += int(far.sum())
        return z, count

    def pixels(self, joints: torch.Tensor) -> torch.Tensor:
        """The measurement a Gaussian filter predicts: (N, J, 3) body joints → (N, 2CJ) pixels of M X in
        every camera (NaN behind a camera)."""
        mapped = self._mapped(joints)
        return torch.cat([view.camera.project(mapped)[0].reshape(joints.shape[0], -1) for view in self.views], -1)

    def measurement(self, z) -> tuple[torch.Tensor, torch.Tensor]:
        """One frame's z (C, J, 3) → the measured pixels (2CJ,) (NaN: not seen) and their variances
        σ² / w_cj (2CJ,): a detection's confidence weighs it as in the log-likelihood."""
        z = torch.as_tensor(z, dtype=torch.float64)
        if tuple(z.shape) != self.observation_shape:
            raise PriortrackError(f"observation {tuple(z.shape)}: expected {self.observation_shape}")
        w = z[..., 2]
        seen = torch.isfinite(z[..., :2]).all(dim=-1) & torch.isfinite(w) & (w > 0)
        values = torch.where(seen[..., None], z[..., :2], float("nan")).reshape(-1)
        variances = (self.sigma_px ** 2 / torch.where(seen, w, 1.0))[..., None].expand(-1, -1, 2).reshape(-1)
        return values, variances

    def log_likelihood(self, joints: torch.Tensor, z) -> torch.Tensor:
        """(P, J, 3) world joints, z (C, J, 3) → (P,) log p(z | joints)."""
        uv, w, seen = self._split(joints, z)
        joints = self._mapped(joints)
        total = torch.zeros(joints.shape[0], dtype=joints.dtype, device=joints.device)
        for c, view in enumerate(self.views):
            index = seen[c].nonzero()[:, 0]
            if not len(index):
                continue
            predicted, in_front = view.camera.project(joints.index_select(1, index))
            d = predicted - uv[c, index]
            d_sq = torch.where(in_front, (d * d).sum(dim=-1), view.miss_sq)
            total = total + (view.per_joint(d_sq) * w[c, index]).sum(dim=-1)
        return total

    def linearised(self, joints: torch.Tensor, z) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """A (P, 3, 3), b (P, 3) and log p(z | joints) (P,) at the given (predicted) joints (module
        docstring); a joint behind a camera adds nothing to A and b."""
        uv, w, seen = self._split(joints, z)
        joints = self._mapped(joints)
        P = joints.shape[0]
        A = torch.zeros((P, 3, 3), dtype=joints.dtype, device=joints.device)
        b = torch.zeros((P, 3), dtype=joints.dtype, device=joints.device)
        log_p = torch.zeros(P, dtype=joints.dtype, device=joints.device)
        var = self.sigma_px ** 2
        for c, view in enumerate(self.views):
            index = seen[c].nonzero()[:, 0]
            if not len(index):
                continue
            predicted, J, in_front = view.camera.project_jacobian(joints.index_select(1, index))
            r = torch.where(in_front[..., None], uv[c, index] - predicted, 0.0)
            d_sq = torch.where(in_front, (r * r).sum(dim=-1), view.miss_sq)
            log_p = log_p + (view.per_joint(d_sq) * w[c, index]).sum(dim=-1)
            weight = w[c, index] * ((self.robust_nu + 2) / (self.robust_nu * var + d_sq) if self.robust_nu is not None
                                    else torch.full_like(d_sq, 1 / var))
            weight = torch.where(in_front, weight, 0.0)
            J = torch.where(in_front[..., None, None], J, 0.0)
            A = A + torch.einsum("pj,pjki,pjkl->pil", weight, J, J)
            b = b + torch.einsum("pj,pjki,pjk->pi", weight, J, r)
        return A, b, log_p
