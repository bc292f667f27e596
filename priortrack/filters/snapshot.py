"""What a filter step returns (:class:`Snapshot`) and what a run collects (:class:`Track`)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import torch

from priortrack.models.tracking import GLOBAL_DIM


#: Frames a run starts from (pose and placement known), before the first filtered one.
KNOWN_FRAMES = 2


@dataclass
class Snapshot:
    """One filter step, for a notebook to look at or a recording to log. Every filter fills the
    weighted point set (particles and weights; the unscented filter's sigma points and their mean
    weights; the MAP tracker's window of states); a Gaussian filter also gives its ``mean`` and
    ``covariance``.

    Attributes:
        frame: index of the observation this step consumed.
        particles: (P, dim) states after the update, before resampling (particles, sigma points
            or the window's states), in the filter model's layout.
        weights: (P,) normalised weights of ``particles``.
        ess: effective sample size 1 / Σ w².
        ancestors: (P,) indices into ``particles`` of the resampled set, None if not resampled.
        estimate: (J, 3) joints (eval15: J = 15) of the filter's estimate (of its weighted mean
            state), metres, in the filter model's frame: the world of a synthetic run; for
            ``track_detections``, its Y-up working frame (``DetectionTrack.in_world`` maps points of
            a snapshot, ``estimate``, ``best`` and ``joints``, into the calibration's world).
        best: (J, 3) joints of the highest-weight particle.
        joints: (P, J, 3) joints of every particle (for clouds coloured by weight).
        (For a model other than a tracking model: what its ``observe`` returns.)
        flags: what was unusual: "no-observation" (nothing seen, prediction stands),
            "weights-underflow" (every likelihood −inf: weights reset), "covariance-repaired".
        timings: seconds spent per phase ("predict", "weight", "resample", "estimate").
        translation_covariance: (P, 6, 6) each particle's covariance of (t_t, t_{t-1}), metres²,
            aligned with ``particles``, when the filter integrates the translation out
            (``ParticleFilter(translation="marginalised")``): the particles' translations are
            then Kalman means, and the depth spread lives here, not in the cloud. None otherwise.

    :meth:`for_smoothing` gives the step with only what a smoother reads: ``joints``, and a Gaussian
    filter's ``particles`` and ``weights``, are None there.
    """

    frame: int
    particles: torch.Tensor
    weights: torch.Tensor
    ess: float
    ancestors: torch.Tensor | None
    estimate: np.ndarray
    best: np.ndarray
    joints: torch.Tensor
    flags: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    translation_covariance: torch.Tensor | None = None
    #: (dim,) the estimate's state and, for a Gaussian filter, (n, n) its covariance in the
    #: tangent coordinates at it; None where the filter has none.
    mean: torch.Tensor | None = None
    covariance: torch.Tensor | None = None
    #: (points,) bool: the observed points (a joint in one camera, in the observation's order:
    #: cameras, joints) the unscented filter's validation gate held out; None for other filters.
    held_out: np.ndarray | None = None
    #: (k,) int: the points (indices in the observation's order) the unscented filter exchanged with
    #: their mirror partner before its update (a detector's left/right swap undone); None where none.
    swapped: np.ndarray | None = None

    def for_smoothing(self) -> "Snapshot":
        """This step with only what a smoother reads of it (:mod:`priortrack.filters.smoothing`): a
        particle set's states, weights, ancestors and translation covariances, or a Gaussian filter's
        mean and covariance (its sigma points dropped); no joints. A whole run's smoother keeps one a
        frame: ukf-real's step shrinks from about 140 kB to 31 kB, a particle filter's by its joints."""
        gaussian = self.covariance is not None
        return replace(self, particles=None if gaussian else self.particles,
                       weights=None if gaussian else self.weights, joints=None)

    def translation_spread(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The weighted mean t̄ (3,) and covariance (3, 3), metres, of the body's translation t_t
        over a particle set whose translations are integrated out (``translation_covariance``
        set; None otherwise): by the law of total covariance, Σ_i w_i (C_i + (t_i − t̄)(t_i − t̄)ᵀ)
        with t_i the Kalman means (g_t's translation in the tracking model's state layout
        [x, g_t, g_{t-1}]) and C_i their covariances."""
        if self.translation_covariance is None:
            return None
        w = self.weights.detach().cpu().to(torch.float64)
        w = w / w.sum()
        g_t = self.particles[:, -2 * GLOBAL_DIM:-GLOBAL_DIM]
        t = g_t[:, :3].detach().cpu().to(torch.float64)
        mean = w @ t
        centred = t - mean
        C = self.translation_covariance[:, :3, :3].detach().cpu().to(torch.float64)
        covariance = torch.einsum("p,pij->ij", w, C) + (centred * w[:, None]).T @ centred
        return mean.numpy(), covariance.numpy()


@dataclass(frozen=True, slots=True)
class StepRecord:
    """What a run keeps of every step, whether or not it keeps the step's :class:`Snapshot` (a few
    numbers a frame, so that a long run's memory does not grow with its point sets: about 120 bytes).

    Attributes:
        frame: index of the observation the step consumed.
        ess: the step's effective sample size (the unscented filter: its sigma-point count).
        points: particles (or sigma points, or window states) in the step's set.
        resampled: whether the particle set was resampled after the step.
        flags: the step's flags (:class:`Snapshot`).
        held_out: (points,) bool, the observed points (cameras × joints, in the observation's order) the
            unscented filter's validation gate held out; None for other filters, or a step that held none out.
    """

    frame: int
    ess: float
    points: int
    resampled: bool
    flags: tuple[str, ...]
    held_out: np.ndarray | None = None

    @classmethod
    def of(cls, snapshot: Snapshot) -> "StepRecord":
        held_out = None if snapshot.held_out is None or not snapshot.held_out.any() else \
            np.array(snapshot.held_out, dtype=bool)
        return cls(snapshot.frame, float(snapshot.ess), len(snapshot.weights), snapshot.ancestors is not None,
                   tuple(snapshot.flags), held_out)


@dataclass
class Track:
    """A whole run: per-frame estimates (T, J, 3), ESS (T,), flags and timings; ``steps`` the
    :class:`StepRecord` of every filtered frame; ``snapshots`` the steps' snapshots where the run
    kept them (every one, or every k-th: ``SequentialFilter.run``'s ``snapshot_every``).

    Frames before the filter started (the known initial frames) hold the given poses.
    """

    estimates: np.ndarray
    ess: np.ndarray
    flags: list[list[str]]
    seconds: float
    snapshots: list[Snapshot] | None = None
    steps: list[StepRecord] = field(default_factory=list)
    #: The run was interrupted (Ctrl-C): it holds the frames tracked until then, fewer than it was given.
    interrupted: bool = False

    @property
    def seconds_per_frame(self) -> float:
        """Run time per filtered frame (every frame after the two known ones; a MAP tracker or a
        UKF has no ESS to count them by)."""
        return self.seconds / max(len(self.estimates) - KNOWN_FRAMES, 1)
