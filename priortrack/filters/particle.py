"""The batched particle filter (sequential importance resampling) over any prior.

Per frame, for P particles s^i held as one tensor:

    predict   s_t^i ~ p(s_t | s_{t-1}^i)                      (prior + global motion)
    weight    log w_t^i = log w_{t-1}^i + log p(z_t | s_t^i)   (2D joint likelihood)
    normalise w_t^i = exp(log w_t^i − logsumexp_j log w_t^j),  ESS = 1 / Σ_i (w_t^i)²
    estimate  the weighted mean state (pose mean on the prior's manifold), and the best particle
    resample  when ESS < threshold · P (systematic by default), weights reset to 1/P.
    move      (``moves`` K > 0) after a resampling, K Metropolis–Hastings moves of each particle
              that leave the filtering distribution invariant (resample-move, :meth:`ParticleFilter.move`):
              a random walk of the pose, or Langevin moves (:mod:`~priortrack.filters.langevin`).

With ``proposal="guided"`` the prediction is drawn from a proposal that looks at the frame's detections
(:mod:`priortrack.filters.proposal`), s_t^i ~ q(s_t | s_{t-1}^i, z_t), and the weight adds
log p(s_t^i | s_{t-1}^i) − log q(s_t^i | s_{t-1}^i, z_t): the same filtering distribution, far fewer
particles wasted where the likelihood is much narrower than the prior's step.

A frame with no observed joint leaves the weights as they are (the prediction stands). If
every particle's likelihood is −inf, the weights are reset to uniform (flagged), never NaN.

With ``translation="marginalised"`` the body's translation is not sampled: each particle carries
a Gaussian over (t_t, t_{t-1}) (its mean in the state, its covariance in ``covariance``), predicted
and updated by a Kalman filter, and weighted by the predictive likelihood p(z_t | x_t, R_t, z_{1:t-1})
with t integrated out (:mod:`priortrack.filters.marginal_translation`).

On a one-camera rig whose run has the detector's feet and face (``forward``), each particle that faces the other way
than they show is turned to its reflected facing (:meth:`ParticleFilter._faced`;
:mod:`priortrack.geometry.facing`), a repair outside Bayes' rule as the unscented filter's.
"""

from __future__ import annotations

import contextlib
import math
import time
from functools import partial, wraps

import numpy as np
import torch

from priortrack.data.motion import Motion
from priortrack.device import resolve_device
from priortrack.errors import PriortrackError
from priortrack.filters.driver import SequentialFilter
from priortrack.filters.langevin import ACCEPTANCE, adapted, kept, langevin_moves
from priortrack.filters.backward_simulation import backward_indices, distinct
from priortrack.filters.marginal_translation import kalman_update, predict_covariance, smooth_translation
from priortrack.filters.proposal import GuidedProposal
from priortrack.filters.resampling import resampler
from priortrack.filters.cloud_smoother import cloud_rts
from priortrack.filters.posterior_linearisation import FRAMES_AT_ONCE
from priortrack.filters.smoothing import blockwise_spread, gaussian_joints
from priortrack.filters.snapshot import Snapshot
from priortrack.filters.step_store import Column, StepStore
from priortrack.filters.tempering import MAX_STAGES, annealing_exponent
from priortrack.filters.ukf import ALPHA, BETA, KAPPA, ManifoldSigmaPoints, unscented_form
from priortrack.geometry import so3
from priortrack.geometry.facing import UP, alone, facing_turns
from priortrack.models.protocols import GaussianTransition
from priortrack.models.tracking import TrackingModel
from priortrack.threads import torch_threads


#: The particles' dtypes, by name.
DTYPES = {"float64": torch.float64, "float32": torch.float32}

#: Trajectory-frames whose joints the particle smoother decodes at once (a whole run's M × W would not fit).
SMOOTH_JOINT_ROWS = 1 << 16

#: How the body's translation is handled (see ``ParticleFilter``'s ``translation``).
TRANSLATIONS = ("sampled", "marginalised")

#: Where the predicted particles are drawn from (see ``ParticleFilter``'s ``proposal``).
PROPOSALS = ("prior", "guided")
#: The resample-move kernels (``move``).
MOVES = ("random-walk", "langevin")
#: The random walk's acceptance band: its scale grows above it and shrinks below it between frames.
RANDOM_WALK_ACCEPTANCE = (0.2, 0.5)
#: Up to this many particles on the CPU a step runs on one torch thread (``threads=None``). Two idle cores:
#: at 1000 particles one thread is as fast as two (bench pf, lie: 133k against 121k particle-steps/s), at 3000
#: the same within noise, at 10⁴ two are 1.2–1.3× faster. With the other core busy (a second tracker, the test
#: suite), two threads took 10× as long as one: pf-lie on caliscope's 40 frames, 114 s against 11 s.
SINGLE_THREAD_PARTICLES = 4096


def _on_step_threads(method):
    """Run a filter method on the filter's step threads (:meth:`ParticleFilter.step_threads`)."""
    @wraps(method)
    def run(self, *args):
        with self.step_threads():
            return method(self, *args)
    return run


class ParticleFilter(SequentialFilter):
    """Sequential importance resampling with P particles.

    Args:
        model: the prior, global motion and likelihood to run.
        particles: P.
        resampling: "systematic", "stratified", "residual" or "multinomial".
        ess_threshold: resample when ESS < ess_threshold · P (default 1/2).
        dtype: "float64" (default) or "float32", the dtype of the particles and of everything
            computed from them (transition, joints, projection, likelihood); the log weights are
            kept in float64. float32 makes a step about 2× faster (``bench pf``); priors that need float64
            internally (the GPDM's kernel solves) still compute in it and return float32.
        translation: "sampled" (default: the translation drawn with the rest of the state, the
            bootstrap filter) or "marginalised" (integrated out by a Kalman filter per particle:
            :mod:`~priortrack.filters.marginal_translation`; a :class:`TrackingModel` with the
            Gaussian likelihood only). The particles' translations are then the Kalman means, and
            ``covariance`` (P, 6, 6) holds each particle's covariance of (t_t, t_{t-1}) (each
            Snapshot carries its particles' as ``translation_covariance``).
        moves: K, the Metropolis–Hastings moves of every particle after each resampling
            (0: none, the bootstrap filter; :meth:`move`).
        move: "random-walk" (default: the pose perturbed isotropically, the placements kept) or "langevin"
            (MALA in the guided proposal's coordinates, pose and rotation, preconditioned by its linearised
            posterior covariance; ``proposal="guided"``).
        move_scale: the moves' first step size: for the random walk a fraction of the size of the prior's own
            step this frame (adapted between frames towards an acceptance rate of 0.2–0.5); for Langevin moves
            τ (adapted towards 0.4–0.8).
        proposal: "prior" (default: the bootstrap filter's draw from the transition) or "guided" (the
            linearised optimal proposal, per component of the prior's step, mixed with the prior, exact weights:
            :mod:`~priortrack.filters.proposal`; a prior whose step is Gaussian or a mixture of Gaussians,
            ``step_components``, and a likelihood that projects; with fewer than two cameras, the prior's draw).
        defensive: the guided proposal's share of the prior itself, δ (default 0.1).
        inflation: the guided proposal's factor on its linearised covariance, γ (default 1).
        auxiliary: the guided draw fully adapted (default False): the parents resampled first by their weight times
            their linearised predictive density of the frame, the weights then p(y | s) p / (q λ̂) from uniform
            (Pitt & Shephard 1999; :meth:`~priortrack.filters.proposal.GuidedProposal.draw`); a frame the prior draws is
            unchanged. ``proposal="guided"`` only, without tempering.
        tempering: 0 (default) or the ESS share α ∈ (0, 1) of adaptive tempering within each frame
            (:meth:`tempered_update`, :mod:`~priortrack.filters.tempering`: from the draw to the posterior in stages
            that each keep an ESS of α P, the particles resampled and moved by ``max(moves, 1)`` random-walk moves
            between them, exact weights; a frame whose draw keeps α P in one update has no stage). The moves are
            then the stages' (none after the frame's resampling).
        seed: seeds the filter's own torch.Generator (on ``device``: a GPU draws other numbers than
            the CPU from the same seed).
        device: where the particles live and every step computes ("cpu", "cuda", "cuda:N";
            :func:`~priortrack.device.resolve_device`); the model follows the particles. Snapshots
            keep the particles there; their estimates are numpy arrays.
        threads: torch threads a step runs on; None (default): one on the CPU up to
            :data:`SINGLE_THREAD_PARTICLES` particles, torch's own count otherwise.
    """

    #: What the filter needs of a prior: nothing beyond the transition-model protocol.
    requires = None

    def __init__(self, model: TrackingModel, particles: int = 1000, resampling: str = "systematic",
                 ess_threshold: float = 0.5, dtype: str = "float64", translation: str = "sampled", moves: int = 0,
                 move: str = "random-walk", move_scale: float = 0.3, proposal: str = "prior", defensive: float = 0.1,
                 inflation: float = 1.0, auxiliary: bool = False, tempering: float = 0.0, seed: int = 0,
                 device: str = "cpu", threads: int | None = None):
        if particles < 1:
            raise PriortrackError(f"particles must be positive, got {particles}")
        if not 0.0 <= ess_threshold <= 1.0:
            raise PriortrackError(f"ess_threshold must be in [0, 1], got {ess_threshold}")
        if dtype not in DTYPES:
            raise PriortrackError(f"dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
        if translation not in TRANSLATIONS:
            raise PriortrackError(f"translation must be one of {', '.join(TRANSLATIONS)}, got {translation!r}")
        if translation == "marginalised" and not (isinstance(model, TrackingModel) and model.likelihood.linearisable):
            raise PriortrackError("translation = 'marginalised' integrates a body's translation out by a Kalman filter "
                                  "on the linearised likelihood: it needs a TrackingModel whose observation model is "
                                  "linearisable (a JointLikelihood without robust_nu, or a MultiViewLikelihood)")
        if moves < 0 or not 0 < move_scale <= 10:
            raise PriortrackError(f"moves must be at least 0 and move_scale in (0, 10]; got {moves} and {move_scale}")
        if proposal not in PROPOSALS:
            raise PriortrackError(f"proposal must be one of {', '.join(PROPOSALS)}, got {proposal!r}")
        if move not in MOVES or (move == "langevin" and proposal != "guided"):
            raise PriortrackError(f"move must be one of {', '.join(MOVES)}, the Langevin moves with proposal = "
                                  f"'guided' (they move in its coordinates); got {move!r} with {proposal!r}")
        if auxiliary and (proposal != "guided" or tempering):
            raise PriortrackError("auxiliary = true is the guided draw's first stage: it needs proposal = 'guided', and "
                                  "goes without tempering (whose stages start from q alone)")
        if not 0.0 <= tempering < 1.0:
            raise PriortrackError(f"tempering must be in [0, 1) (the ESS share each stage keeps; 0: none), got {tempering}")
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
            raise PriortrackError(f"threads must be a whole number ≥ 1 or None, got {threads!r}")
        self.moves, self.move_kind, self.move_step = int(moves), move, float(move_scale)
        #: The ESS share each tempering stage keeps (0: Bayes' rule in one update; :mod:`~priortrack.filters.tempering`).
        self.tempering = float(tempering)
        self.marginal = translation == "marginalised"
        #: The guided proposal (:mod:`~priortrack.filters.proposal`), or None: the prior's draw.
        self.proposal = GuidedProposal(model, self.marginal, defensive, inflation) if proposal == "guided" else None
        #: Whether the guided draw resamples its parents first by their predictive density (fully adapted).
        self.auxiliary = bool(auxiliary)
        self._log_ratio: torch.Tensor | None = None
        self.covariance: torch.Tensor | None = None
        self.model, self.P, self.ess_threshold = model, int(particles), float(ess_threshold)
        self.dtype = DTYPES[dtype]
        self.resample = resampler(resampling)
        self.device = resolve_device(device)
        if threads is None and self.device.type == "cpu" and self.P <= SINGLE_THREAD_PARTICLES:
            threads = 1
        #: Torch threads of a step (None: torch's count).
        self.threads = threads
        self.generator = torch.Generator(device=self.device).manual_seed(seed)
        self.states: torch.Tensor | None = None
        self.log_weights: torch.Tensor | None = None
        self.frame = 0
        #: Between :meth:`advance` and :meth:`correct`: the particles' states and covariances before the
        #: prediction; else None.
        self._parents: tuple | None = None
        self._observed: torch.Tensor | None = None
        self._predict_seconds = 0.0
        #: (T, C, 3) per tick and camera, the detector's forward direction in the image (its feet and face;
        #: :attr:`~priortrack.filters.ukf.UnscentedFilter.forward`, :meth:`_faced`); None: not used.
        self.forward: np.ndarray | None = None

    def initialise(self, motion: Motion, start: int = 1, translation_std: float = 0.0) -> None:
        """Particles around frame ``start`` of a motion (its first two frames); ``translation_std``
        (metres) is the start's own uncertainty in each of t_start and t_{start−1} (0: known exactly,
        as in the papers' experiments; an estimated start, such as a triangulation, has some)."""
        self.initialise_states(self.model.initial_states(motion, self.P, self.generator, start), start,
                               translation_std)

    def initialise_states(self, states: torch.Tensor, frame: int = 0, translation_std: float = 0.0) -> None:
        """Start from given particles (P, dim) (cast to the filter's dtype), equally weighted; with
        ``translation_std`` σ, the translations t_t, t_{t−1} are N(given, σ² I) each, independent:
        the Kalman covariance σ² I₆ where the translation is integrated out, else drawn."""
        if states.shape != (self.P, self.model.dim):
            raise PriortrackError(f"initial particles have shape {tuple(states.shape)}; expected ({self.P}, {self.model.dim})")
        if not 0 <= translation_std < 10:
            raise PriortrackError(f"translation_std must be in [0, 10) metres, got {translation_std}")
        self.states = states.to(device=self.device, dtype=self.dtype)
        if self.marginal:
            self.covariance = translation_std ** 2 * torch.eye(6, dtype=self.dtype, device=self.device).repeat(
                self.P, 1, 1)
        elif translation_std > 0:
            shift = torch.randn((self.P, 6), generator=self.generator, dtype=self.dtype, device=self.device) * translation_std
            self.states = self.model.shift_translation(self.states, shift)
        self.log_weights = torch.full((self.P,), -math.log(self.P), dtype=torch.float64, device=self.device)
        self.frame = frame

    def step(self, z) -> Snapshot:
        """Consume the observation z of the next frame (``model.observation_shape``, NaN where missing):
        :meth:`advance`, then :meth:`correct`."""
        z = self._checked(z)
        self.advance()
        return self.correct(z)

    def step_threads(self):
        """A context in which torch runs on the step's threads (:attr:`threads`)."""
        return contextlib.nullcontext() if self.threads is None else torch_threads(self.threads)

    @_on_step_threads
    def advance(self) -> None:
        """The prediction half of a step: every particle through the transition (the scene tracker reads
        :meth:`predicted_measurement` before :meth:`correct` weighs the particles with the frame). With the
        guided proposal the draw waits for the frame, in :meth:`correct`."""
        if self.states is None:
            raise PriortrackError("the filter is not initialised: call initialise(motion) first")
        self._parents = (self.states, self.covariance)
        self._observed, self._log_ratio, self._predict_seconds = None, None, 0.0
        if self.proposal is None:
            self._prior_draw(self.states)

    def _prior_draw(self, parents: torch.Tensor) -> None:
        """The predicted particles drawn from the transition p(s_t | s_t−1) of ``parents``."""
        t0 = time.perf_counter()
        if self.marginal:       # t_t = t̂_t, its covariance predicted in update (or below)
            self.states = self.model.predict(parents, self.generator, translation=False)
        else:                   # any model with predict(s, generator), not only a TrackingModel
            self.states = self.model.predict(parents, self.generator)
        self._observed = None
        self._predict_seconds += time.perf_counter() - t0

    def _guided_draw(self, z: torch.Tensor, parents: torch.Tensor,
                     covariance: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The predicted particles drawn from the guided proposal with the frame's (gated) z, and the
        log ratio of prior to proposal that their weights add. Returns the parents (P, A) and their translation
        covariances: with :attr:`auxiliary`, those the draw's first stage resampled (the weights then uniform)."""
        t0 = time.perf_counter()
        predicted_covariance = None
        if self.marginal:
            motion = self.model.global_motion
            predicted_covariance = predict_covariance(covariance, motion.sigma[:3], motion.velocity)
        self.states, self._log_ratio = self.proposal.draw(parents, torch.exp(self.log_weights), z, self.generator,
                                                          predicted_covariance, self.resample if self.auxiliary else None)
        a = self.proposal.ancestors
        if a is not None:
            parents, self.log_weights = parents[a], torch.full_like(self.log_weights, -math.log(self.P))
            if self.marginal:
                covariance = self.covariance = covariance[a]
        self._observed = None
        self._predict_seconds += time.perf_counter() - t0
        return parents, covariance

    @_on_step_threads
    def predicted_measurement(self) -> tuple[np.ndarray, np.ndarray]:
        """After :meth:`advance`: every observed point's predicted pixels (…, 2) and their covariance (…, 2, 2)
        (``observation_shape[:-1]``: (C, 15) for C cameras), the weighted mean and covariance of the predicted
        particles' projections, Σ_i w_i h_i and Σ_i w_i (h_i − h̄)(h_i − h̄)ᵀ (NaN where a particle's joint is
        behind the camera). Needs a model with a likelihood that projects (``likelihood.pixels``)."""
        if self._parents is None:
            raise PriortrackError("no prediction to read: call advance() first")
        if self.proposal is not None and self.states is self._parents[0]:
            # the guided draw waits for the frame: what the scene reads is the prior's prediction, drawn without
            # moving the generator on (a step in halves draws what the whole step draws)
            state = self.generator.get_state()
            self._prior_draw(self._parents[0])
            self.generator.set_state(state)
        pixels = getattr(getattr(self.model, "likelihood", None), "pixels", None)
        if pixels is None:
            raise PriortrackError(f"the {type(self.model).__name__} model's observations are not pixels: no "
                                  f"predicted measurement")
        h = pixels(self.predicted_joints()).to(torch.float64)                    # (P, m)
        h = h.reshape(len(h), -1, 2)
        w = torch.exp(self.log_weights)
        mean = torch.einsum("i,ikc->kc", w, h)
        r = h - mean
        covariance = torch.einsum("i,ikc,ikd->kcd", w, r, r)
        shape = tuple(self.model.observation_shape)[:-1]
        return mean.cpu().numpy().reshape(shape + (2,)), covariance.cpu().numpy().reshape(shape + (2, 2))

    def _checked(self, z) -> torch.Tensor:
        if self.states is None:
            raise PriortrackError("the filter is not initialised: call initialise(motion) first")
        z = torch.as_tensor(z, dtype=self.states.dtype, device=self.states.device)
        if z.shape != self.model.observation_shape:
            raise PriortrackError(f"observation has shape {tuple(z.shape)}; expected {self.model.observation_shape}")
        return z

    def predicted_joints(self) -> torch.Tensor:
        """The predicted particles' observed joints (P, …), computed once a step."""
        if self._observed is None:
            self._observed = self.model.observe(self.states)
        return self._observed

    @_on_step_threads
    def correct(self, z) -> Snapshot:
        """The update half of a step (after :meth:`advance`) with the frame's observation z: the weights,
        the estimate, resampling (and moves)."""
        z = self._checked(z)
        if self._parents is None:
            raise PriortrackError("no prediction to correct: call advance() first")
        (parents, parent_covariance), self._parents = self._parents, None
        timings, flags = {}, []
        gated, count = self.model.gate(z)
        if count:
            flags.append("outlier-gated")
            z = gated.to(z)
        if self.proposal is not None:
            if torch.isfinite(z).any():
                parents, parent_covariance = self._guided_draw(z, parents, parent_covariance)
            elif self.states is parents:
                self._prior_draw(parents)
        self._faced(z, flags)
        t1 = time.perf_counter()
        predicted = self.states
        if torch.isfinite(z).any():
            joints = (self.tempered_update(z, parents, parent_covariance, flags) if self.tempering
                      else self.update(z, flags))
        else:
            flags.append("no-observation")
            joints = self.predicted_joints()
            self.skip_update()
        self._observed = None
        weights = torch.exp(self.log_weights)
        ess = float(1.0 / (weights ** 2).sum())
        t2 = time.perf_counter()
        mean = self.model.mean(self.states, weights)
        estimate = self.model.observe(mean[None])[0]
        best = joints[int(torch.argmax(weights))].clone()          # not a view: it would hold every joint
        t3 = time.perf_counter()
        snapshot_states, snapshot_covariance, ancestors = self.states, self.covariance, None
        if ess < self.ess_threshold * self.P:
            ancestors = self.resample(weights, self.generator)
            self.select(ancestors)
            self.log_weights = torch.full_like(self.log_weights, -math.log(self.P))
            if self.moves and not self.tempering and torch.isfinite(z).any() and "weights-underflow" not in flags:
                rate = self.move(z, predicted[ancestors], parents[ancestors],
                                 None if parent_covariance is None else parent_covariance[ancestors])
                flags.append(f"moved:{rate:.2f}")
        t4 = time.perf_counter()
        timings.update(predict=self._predict_seconds, weight=t2 - t1, estimate=t3 - t2, resample=t4 - t3)
        self.frame += 1
        return Snapshot(self.frame, snapshot_states, weights, ess, ancestors, estimate.cpu().numpy(),
                        best.cpu().numpy(), joints, flags, timings, snapshot_covariance, mean=mean)

    def _faced(self, z: torch.Tensor, flags: list[str]) -> None:
        """After the frame's draw, before its weights: where one camera alone sees the person
        (:func:`~priortrack.geometry.facing.alone`), each particle whose own facing the detector's feet and face there
        (:attr:`forward`) show reversed, its trunk fitting its pixels, is turned to its reflected facing
        (:func:`~priortrack.geometry.facing.facing_turns`: both placements about the vertical through its mid-hips,
        the translation's Kalman covariance turned with them; flagged "facing-turned"); the particles that face as
        the feet show are kept. As the unscented filter's turn (:mod:`~priortrack.filters.ukf`, "The trunk's
        facing"), a repair outside Bayes' rule: a cloud wholly on the reversed facing has no particle to weigh up,
        and the transition forbids a turn of 150° in a tick. Only on a one-camera rig: with two or three cameras,
        turning where one of them alone saw the person cost pf-lie-real on Shelf (cameras 0, 1, 4 actor 1 79.1 →
        64.2 % PCP; 1, 3 actor 2 94.6 → 83.8 %; the unscented filter's turn did not); not after a guided draw that
        looked at the frame (its weights' ratio is the draw's) nor with tempering (whose stages weigh by the draw's
        density)."""
        tick = self.frame + 1
        cameras = getattr(getattr(self.model, "likelihood", None), "cameras", None)
        drawn_by_prior = self._log_ratio is None or not bool(self._log_ratio.any())
        if (self.forward is None or cameras is None or len(cameras) != 1 or tick >= len(self.forward) or self.tempering
                or not drawn_by_prior or not isinstance(self.model, TrackingModel) or z.numel() % 15):
            return
        observed = z.detach().cpu().double().numpy().reshape(len(cameras), 15, -1)
        c = alone(observed)
        if c is None:
            return
        joints = self.predicted_joints().detach().cpu().double().numpy()
        angles = facing_turns(joints, cameras[c], self.forward[tick][c], observed[c])
        turned = torch.as_tensor(angles != 0, device=self.device)
        if not bool(turned.any()):
            return
        angles = torch.as_tensor(angles, dtype=self.dtype, device=self.device)[turned]
        pivots = torch.as_tensor(joints[:, [9, 12]].mean(1), dtype=self.dtype, device=self.device)[turned]
        states = self.states.clone()
        states[turned] = self.model.turned(self.states[turned], angles, pivots)
        self.states = states
        if self.covariance is not None:
            R = so3.exp(angles[:, None] * torch.as_tensor(UP, dtype=self.dtype, device=self.device))
            B = torch.zeros((len(R), 6, 6), dtype=self.dtype, device=self.device)
            B[:, :3, :3], B[:, 3:, 3:] = R, R
            covariance = self.covariance.clone()
            covariance[turned] = B @ self.covariance[turned] @ B.transpose(-1, -2)
            self.covariance = covariance
        self._observed = None
        flags.append("facing-turned")

    def update(self, z: torch.Tensor, flags: list[str]) -> torch.Tensor:
        """Bayes' rule on the predicted particles: log w += log p(z | s), normalised.

        Returns the particles' observed joints (P, ...); appends "weights-underflow" to
        ``flags`` (and resets the weights to uniform) if every likelihood is −inf.
        """
        joints = self.predicted_joints()
        log_likelihood, pending = self.weigh(joints, z)
        joints = self.keep_update(pending, joints)
        if self._log_ratio is not None:      # the guided proposal's log p(s_t | s_t−1) − log q(s_t | s_t−1, z)
            log_likelihood = log_likelihood.to(torch.float64) + self._log_ratio
            self._log_ratio = None
        self.log_weights = self.normalised(self.log_weights + log_likelihood, flags)
        return joints

    def tempered_update(self, z: torch.Tensor, parents: torch.Tensor, parent_covariance: torch.Tensor | None,
                        flags: list[str]) -> torch.Tensor:
        """Bayes' rule on the predicted particles in stages (:mod:`~priortrack.filters.tempering`), from the draw's
        proposal q to the posterior through π_φ ∝ q^{1−φ} (p(s | s_{t−1}) p(z | s))^φ: log w += Δ_k (log p(z | s) +
        log p(s | s_{t−1}) − log q(s)) with Δ_k keeping an ESS of ``tempering`` · P, then (while Σ Δ_k < 1)
        resampling and ``max(moves, 1)`` random-walk moves invariant for π_{φ_k}, at most
        :data:`~priortrack.filters.tempering.MAX_STAGES` stages. From the prior's draw q = p, and π_φ ∝ p p(z | s)^φ.
        ``parents`` (P, A) the particles' states at t − 1, ``parent_covariance`` their translation covariances (None:
        sampled). Returns the particles' observed joints; appends "tempered:k" (k stages of moves) to ``flags``."""
        s, log_w, phi, stages = self.states, self.log_weights, 0.0, 0
        rows = torch.arange(self.P, device=s.device)                     # each particle's parent in the draw

        def log_ratio(candidate: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
            """log p(s | s_{t−1}) − log q(s) (0 without a guided proposal: its draw is the prior's)."""
            if self.proposal is None:
                return torch.zeros(len(candidate), dtype=torch.float64, device=candidate.device)
            log_q, log_p = self.proposal.log_density(candidate, rows)
            return log_p - log_q

        ratio = log_ratio(s, rows)
        while True:
            log_lik, pending = self.weigh(self.model.observe(s), z, parent_covariance)
            log_r = log_lik.to(torch.float64) + ratio
            finite = torch.isfinite(log_r)
            if not finite.any():
                log_w = self.normalised(log_w + log_r, flags)                       # "weights-underflow", uniform
                break
            log_r = torch.where(finite, log_r, log_r[finite].min() - 1e6)          # impossible particles die first
            delta = 1.0 - phi if stages == MAX_STAGES else annealing_exponent(log_r - log_r.max(), self.tempering,
                                                                               0.0, 1.0 - phi, log_w)
            log_w, phi = self.normalised(log_w + delta * log_r, flags), phi + delta
            if phi >= 1.0:
                break
            ancestors = self.resample(torch.exp(log_w), self.generator)
            s, rows = s[ancestors], rows[ancestors]
            parent_covariance = None if parent_covariance is None else parent_covariance[ancestors]
            log_w = torch.full_like(log_w, -math.log(self.P))
            target = self._target(z, parents[rows], parent_covariance, phi, rows if self.proposal is not None else None)
            s, _, rate = self._random_walk(target, s, parents[rows], max(self.moves, 1))
            self.move_step = adapted(self.move_step, rate, RANDOM_WALK_ACCEPTANCE)
            ratio = log_ratio(s, rows)
            stages += 1
        flags.append(f"tempered:{stages}")
        self._log_ratio = None                                                       # applied above
        self.states, self.log_weights, self._observed = s, log_w, None
        if self.marginal:
            self.covariance = parent_covariance
        return self.keep_update(pending, self.predicted_joints())

    def _target(self, z: torch.Tensor, parents: torch.Tensor, parent_covariance: torch.Tensor | None,
                phi: float = 1.0, rows: torch.Tensor | None = None):
        """log π_φ(s) = log p(s | s_{t−1}) + φ log p(z | s, z_{1:t−1}) of candidate states (P, A) with parents (P, A)
        (the translation integrated out as in :meth:`weigh`), and the Kalman update that goes with it. With ``rows``,
        the parents' indices in the guided proposal's last draw (:meth:`tempered_update`), log π_φ(s) =
        (1 − φ) log q(s) + φ (log p(s | s_{t−1}) + log p(z | s)), p and q as ``GuidedProposal.log_density`` gives them."""
        def target(candidate: torch.Tensor):
            log_likelihood, pending = self.weigh(self.model.observe(candidate), z, parent_covariance)
            log_likelihood = log_likelihood.to(torch.float64)
            if rows is None:
                return self.model.log_transition(candidate, parents).to(torch.float64) + phi * log_likelihood, pending
            log_q, log_p = self.proposal.log_density(candidate, rows)
            return (1.0 - phi) * log_q + phi * (log_p + log_likelihood), pending
        return target

    def weigh(self, joints: torch.Tensor, z: torch.Tensor,
              covariance: torch.Tensor | None = None) -> tuple[torch.Tensor, tuple | None]:
        """log p(z | s) (P,) of the particles' observed joints, and what :meth:`keep_update` needs.

        Sampled translation: the likelihood, and None. Marginalised: the predictive likelihood with
        t integrated out, and the Kalman update (shift, C⁺) it implies, not yet applied (the
        annealed filter weighs several layers and keeps the last one's), from the previous frame's
        translation covariances ``covariance`` (P, 6, 6) (default: the filter's own)."""
        if not self.marginal:
            return self.model.log_likelihood(joints, z), None
        motion = self.model.global_motion
        previous = self.covariance if covariance is None else covariance
        shift, C_post, log_likelihood = kalman_update(joints, previous, motion.sigma[:3], motion.velocity, z,
                                                      self.model.likelihood)
        return log_likelihood, (shift, C_post)

    def keep_update(self, pending: tuple | None, joints: torch.Tensor | None = None) -> torch.Tensor | None:
        """Apply :meth:`weigh`'s Kalman update (t̂ → the Kalman mean, C⁺ kept); returns the joints
        moved with it (unchanged for a sampled translation; None if none were given)."""
        if pending is None:
            return joints
        shift, self.covariance = pending
        self.states = self.model.shift_translation(self.states, shift)
        return None if joints is None else joints + shift[:, None, :3]

    def move(self, z: torch.Tensor, s: torch.Tensor, parents: torch.Tensor, parent_covariance: torch.Tensor | None) -> float:
        """Resample-move (Gilks & Berzuini, JRSS B 2001): ``moves`` Metropolis–Hastings moves of each
        resampled particle's pose, each leaving its share of the filtering distribution invariant,

            π(s_t) ∝ p(s_t | s_{t−1}) · p(z_t | s_t, z_{1:t−1}),

        the particle's parent s_{t−1} fixed and, with a marginalised translation, t integrated out of
        the likelihood as in the weights (the parent's Kalman covariance predicted again). The proposal
        s' = ``model.perturb(s, σ)`` (x ⊞ ε, the placements kept) is symmetric, σ = ``move_step`` ×
        ``model.pose_step(s, parents)``, the size of the prior's own step this frame; s' is kept if
        log u < log π(s') − log π(s), u ~ U(0, 1). ``move_step`` is then adapted for the next frame:
        × 1.5 above an acceptance of 0.5, ÷ 1.5 below 0.2. With ``move="langevin"`` the same π by
        :func:`~priortrack.filters.langevin.langevin_moves` instead, in the guided proposal's coordinates (pose and
        rotation), preconditioned by its linearised posterior covariance this frame (the prior's step covariance
        where the frame's draw was the prior's).

        Args: z the frame's observation; s (P, A) the resampled particles as predicted (before the
        Kalman update); parents (P, A) their states at t − 1; parent_covariance (P, 6, 6) their
        translation covariances at t − 1 (None: the translation is sampled). Sets ``states`` (and
        ``covariance``); returns the acceptance rate.
        """
        target = self._target(z, parents, parent_covariance)
        if self.move_kind == "langevin":
            proposal = self.proposal
            M = proposal.covariance if proposal.covariance is not None else proposal.prior_covariance(s)
            s, pending, rate = langevin_moves(target, proposal.retract, proposal.local, s, M, self.move_step,
                                              self.moves, self.generator)
            band = ACCEPTANCE
        else:
            s, pending, rate = self._random_walk(target, s, parents, self.moves)
            band = RANDOM_WALK_ACCEPTANCE
        self.move_step = adapted(self.move_step, rate, band)
        self.states = s
        self.keep_update(pending)
        return rate

    def _random_walk(self, target, s: torch.Tensor, parents: torch.Tensor,
                     moves: int) -> tuple[torch.Tensor, tuple | None, float]:
        """``moves`` random-walk moves (:meth:`move`) of the poses s (P, A) under ``target``: the moved states, their
        Kalman updates (None: the translation is sampled) and the acceptance rate."""
        scale = self.model.pose_step(s, parents)
        log_pi, pending = target(s)
        accepted = 0
        for _ in range(moves):
            proposal = self.model.perturb(s, self.move_step * scale, self.generator)
            log_pi_new, pending_new = target(proposal)
            u = torch.rand(len(s), generator=self.generator, dtype=torch.float64, device=s.device)
            keep = torch.log(u) < log_pi_new - log_pi                                      # NaN: rejected
            s = torch.where(keep[:, None], proposal, s)
            log_pi = torch.where(keep, log_pi_new, log_pi)
            pending = kept(keep, pending_new, pending)
            accepted += int(keep.sum())
        return s, pending, accepted / (moves * len(s))

    def select(self, ancestors: torch.Tensor) -> None:
        """Keep the particles ``ancestors`` (P,): their states and, marginalised, their covariances."""
        self.states = self.states[ancestors]
        if self.marginal:
            self.covariance = self.covariance[ancestors]

    def skip_update(self) -> None:
        """A frame without an update: a marginalised translation's covariance is only predicted."""
        if self.marginal:
            motion = self.model.global_motion
            self.covariance = predict_covariance(self.covariance, motion.sigma[:3], motion.velocity)

    def normalised(self, log_weights: torch.Tensor, flags: list[str]) -> torch.Tensor:
        """log w − logsumexp(log w) in float64; uniform (and flagged) if every entry is −inf or NaN."""
        log_weights = log_weights.to(torch.float64)
        total = torch.logsumexp(log_weights, 0)
        if not torch.isfinite(total):
            flags.append("weights-underflow")
            return torch.full_like(log_weights, -math.log(self.P))
        return log_weights - total

    def smooth_window(self, snapshots: list[Snapshot], observations, generator: torch.Generator,
                      trajectories: int, moves: int | None, method: str = "gaussian"
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The smoothed joints (W, J, 3) of these steps, their spread (W, J) and, for backward simulation, the
        number of distinct particles its trajectories pass through at each frame (W,) (:mod:`priortrack.filters.smoothing`).
        ``method`` "gaussian": the RTS recursion on each frame's cloud moments
        (:mod:`~priortrack.filters.cloud_smoother`; no trajectories to count). "backward": backward simulation, the
        mean of ``trajectories`` smoothed trajectories' joints; with ``moves`` K the MCMC backward kernel started on
        the genealogy, None the exact draw."""
        if not isinstance(self.model, TrackingModel):
            raise PriortrackError(f"smoothing decodes joints: it needs a TrackingModel, not {type(self.model).__name__}")
        if method == "gaussian":
            return self._gaussian_smoothed(snapshots)
        if not callable(getattr(self.model.prior, "log_prob", None)):
            raise PriortrackError(f"the {type(self.model.prior).__name__} prior has no transition density log_prob: "
                                  f"it cannot be smoothed by backward simulation")
        particles = Column(snapshots, "particles")       # each step read when reached (spilled ones from disk)
        log_weights = Column(snapshots, "weights", lambda w: torch.log(w.to(torch.float64)))
        first_covariance = snapshots[0].translation_covariance
        marginal = first_covariance is not None
        indices = backward_indices(partial(self.model.log_transition, translation=not marginal), particles,
                                   log_weights, trajectories, generator,
                                   None if moves is None else Column(snapshots, "ancestors"), moves or 0)
        states = torch.stack([p[i] for p, i in zip(particles, indices)], 1)               # (M, W, A)
        if marginal:
            tau = smooth_translation(self.model, states, first_covariance[indices[0]], observations)
            states = self.model.with_translation(states.flatten(0, 1), tau.flatten(0, 1)).reshape(states.shape)
        M, W = states.shape[:2]
        weights = torch.full((M,), 1.0 / M, dtype=torch.float64, device=states.device)

        def decode(frames: slice):
            window = states[:, frames]
            joints = self.model.observe(window.flatten(0, 1)).reshape(window.shape[:2] + (-1, 3))
            return joints, joints.mean(0), weights

        centre, spread = blockwise_spread(W, max(1, SMOOTH_JOINT_ROWS // M), decode)
        return centre, spread, distinct(indices).numpy()

    def _gaussian_smoothed(self, snapshots: list[Snapshot]) -> tuple[np.ndarray, np.ndarray, None]:
        """:meth:`smooth_window`'s "gaussian" method: the clouds smoothed, the spread over the smoothed Gaussians'
        sigma points at the unscented filter's α."""
        if not isinstance(self.model.prior, GaussianTransition):
            raise PriortrackError(f"the Gaussian particle smoother needs a prior with a Gaussian transition (a mean step "
                                  f"and a noise covariance); the {type(self.model.prior).__name__} prior has none: "
                                  f"smooth it by backward simulation (method 'backward', --particle-smoother backward)")
        form = unscented_form(self.model, robust=True)
        memory = snapshots.memory if isinstance(snapshots, StepStore) else None
        means, covariances = cloud_rts(form, Column(snapshots, "particles"), Column(snapshots, "weights"),
                                       Column(snapshots, "translation_covariance"), memory, self.model.mean)
        try:
            return *gaussian_joints(form, ManifoldSigmaPoints(form, ALPHA, BETA, KAPPA), means, covariances,
                                    FRAMES_AT_ONCE), None
        finally:
            covariances.close()
