"""What a filter runs on, as small protocols: filters are written against these, never against a
concrete prior, space or likelihood.

Shapes: P rows (particles, sigma points), S the ambient width of a state, n ≤ S its tangent
(intrinsic) dimension, J joints, C cameras.

- :class:`StateSpace`: where a prior's states live, with the manifold operations a filter needs:
  ``retract(x, c) = x ⊞ c`` and ``local(y, x) = y ⊟ x`` in n tangent coordinates, the change of
  those coordinates between base points, and the mean of weighted points (weights ≥ 0: particles;
  any sign: unscented weights).
- :class:`TransitionModel`: p(x_t | x_{t-1}) of a prior (sample, log_prob, mean step).
  :class:`GaussianTransition` adds one Gaussian noise covariance (what the unscented filter needs);
  :class:`LatentTransition` is the GPDM's interface that the sliding-window MAP tracker uses.
- :class:`ObservationModel`: the batched log-likelihood of predicted 3D joints against one
  frame's data (any number of cameras; NaN entries are missing).
- :class:`FilterModel`: the whole state-space model a filter steps (the tracking model of
  :mod:`priortrack.models.tracking`, or a linear-Gaussian model in the tests).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch


@runtime_checkable
class StateSpace(Protocol):
    dim: int
    tangent_dim: int
    manifold: bool

    def retract(self, x: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        """x (N, S) ⊞ c (N, n) → (N, S)."""

    def local(self, y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """y (N, S) ⊟ x (S,) (or one x per row, (N, S)) → (N, n), tangent coordinates at x."""

    def coordinate_transport(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """(n, n) map from tangent coordinates at a (S,) to those at b (S,)."""

    def mean(self, x: torch.Tensor, weights: torch.Tensor | None = None) -> torch.Tensor:
        """(S,) mean of points x (N, S) under non-negative weights (N,)."""

    def signed_mean(self, x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """(S,) fixed point of m ← m ⊞ Σ_i w_i (x_i ⊟ m) for weights w (N,) summing to 1, any sign."""

    def joints(self, x: torch.Tensor) -> torch.Tensor:
        """(..., S) → (..., 15, 3) joints in metres, in the space's body frame."""


@runtime_checkable
class TransitionModel(Protocol):
    kind: str
    space: StateSpace
    fps: float

    def sample(self, x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """(P, S) → (P, S), one draw of x_t ~ p(x_t | x_{t-1}) per row."""

    def log_prob(self, x_next: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """(P, S), (P, S) → (P,) log p(x_next | x)."""

    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """(P, S) → (P, S), the mean step."""


@runtime_checkable
class GaussianTransition(TransitionModel, Protocol):
    def transition_covariance(self, x: torch.Tensor) -> torch.Tensor:
        """(n, n) covariance Q(x) of x_t ⊟ mean(x) at a state x (S,), in tangent coordinates."""


@runtime_checkable
class LatentTransition(TransitionModel, Protocol):
    """A GPDM: latent x ∈ R^d, the pose map y = μ_Y(x) with its W-weighted energy, and the dynamics."""

    d: int
    D: int
    #: (D,) the per-channel scales of the reconstruction GP.
    W: torch.Tensor

    def reconstruct(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(P, d) → μ_Y(x) (P, D) and σ_Y²(x) (P,)."""

    def dynamics(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(P, d) → μ_X(x) (P, d) and σ_X²(x) (P,)."""

    def reconstruction_energy(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor: ...

    def dynamics_energy(self, window: torch.Tensor, annealing: float = 0.5) -> torch.Tensor: ...

    def pose_mean(self, x: torch.Tensor) -> torch.Tensor: ...


@runtime_checkable
class ObservationModel(Protocol):
    #: The shape of one frame's data, e.g. (J, 2) for one camera.
    observation_shape: tuple[int, ...]

    def log_likelihood(self, joints: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """(P, J, 3) world joints, one frame's data z (observation_shape, NaN = missing) → (P,)."""

    def gate(self, z) -> tuple[torch.Tensor, int]:
        """One frame's data with its gross outliers made missing, and their count."""


@runtime_checkable
class FilterModel(Protocol):
    #: Width of a state row, and the shape of one frame's observation.
    dim: int
    observation_shape: tuple[int, ...]

    def predict(self, s: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """(P, dim) → (P, dim), one draw of the next state per row."""

    def observe(self, s: torch.Tensor) -> torch.Tensor:
        """(P, dim) → what the observation model scores (world joints (P, J, 3))."""

    def log_likelihood(self, observed: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """(P,) log p(z | state) from :meth:`observe`'s output."""

    def mean(self, s: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        """(dim,) the weighted mean state, on the state's manifold."""

    def gate(self, z) -> tuple[torch.Tensor, int]:
        """One frame's data with its gross outliers made missing (validation gate), and their count."""
