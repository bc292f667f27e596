"""Sliding-window MAP tracking with a GPDM prior (Urtasun, Fleet & Fua, CVPR 2006, Algorithm 1).

The state of frame j is φ_j = (G_j, y_j, x_j): the placement G = g = (t, ω) of
:mod:`priortrack.priors.global_motion`, the pose y (D,) (the GPDM's angle channels, radians)
and its latent position x (d,). At frame t the window holds the newest τ + 1 states
φ_{t−τ..t} (fewer in the first frames: the known initial frames are never free); every
older state is frozen. The tracker minimises eq. 21 over the window,

    E = Σ_j −ln p(z_j | G_j, y_j)                          image: the 2D joint likelihood of the
                                                             eval15 joints of y_j placed by G_j
      + Σ_j [ |W(y_j − μ_Y(x_j))|² / (2σ²(x_j)) + D/2 ln σ²(x_j) + ½|x_j|² ]     eq. 18, per pose
      − Σ_j ln p(G_j | G_{j−1}, G_{j−2})                    global motion (GlobalMotion.log_prob)
      + λ Σ_j −ln N(x_j; μ_X(x_{j−1}), σ_X²(x_{j−1}) I_d)    GPDM dynamics, annealed (λ = 0.5)

with j over the window's frames; the history terms reach back to the frozen states before the
window (G_{t−τ−2}, G_{t−τ−1}, x_{t−τ−1}), which condition the window on the past. Missing
joints (NaN in the observation) drop out of the image term; a frame with nothing seen
has no image term, so the dynamics, the reconstruction and the global model carry its state
(through a total occlusion the prediction carries the track).

Each new frame (Algorithm 1):

1. shift the window and initialise the new state by mean prediction: x_t = μ_X(x_{t−1}),
   y_t = μ_Y(x_t), G_t = Ĝ_t (GlobalMotion.predict);
2. ``rounds`` times: (a) minimise E over the window's latent positions with the poses fixed
   (the reconstruction and dynamics terms), (b) minimise E over the full states (G, y, x).

Fast mode: y = μ_Y(x) (no separate pose), the state is (G, x), and one minimisation over
(G, x) per frame; its reconstruction term is then D/2 ln σ²(x) + ½|x|².

Each minimisation is L-BFGS-B (scipy) on the flattened free variables, float64, the gradient
by torch autograd, at most ``iterations`` iterations. The variables are scaled by the prior's
own spreads (u = (v − v₀)/s with s the global-motion σ for G, σ_X(x_{j−1}) for x_j and
σ(x_j)/w_k for channel k of y_j): unscaled, the millimetre-scale placement noise and the radian
poses leave the problem so ill-conditioned that 100 iterations do not converge; scaled, about
20–60 do. The window is a few hundred numbers: the tracker runs on the CPU, on one torch thread.

The estimate of frame t is the newest state's world joints as soon as frame t is consumed (an
online estimate; later refinements of that state inside the window serve the following frames,
not its own reported estimate).
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch
from scipy.optimize import minimize

from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.filters.driver import SequentialFilter
from priortrack.filters.snapshot import Snapshot
from priortrack.models.tracking import TrackingModel
from priortrack.priors.global_motion import to_world
from priortrack.models.protocols import LatentTransition
from priortrack.threads import torch_threads

log = logging.getLogger(__name__)

MODES = ("full", "fast")
#: The terms of eq. 21.
TERMS = ("image", "reconstruction", "global", "dynamics")
#: L-BFGS-B stops early when the largest gradient entry, in the scaled variables, is below this
#: (a move of one prior standard deviation changes E by less than 0.01 nats) ...
GTOL = 1e-2
#: ... or when one iteration lowers E by less than this, relative (scipy's ``ftol``; |E| is
#: 10²–10³ nats, so about 10⁻³ nats). The tightest pair tried (ftol 1e-10, gtol 1e-6) changed the
#: MPJPE of 28 frames of a held-out walk by 0.4 mm (70.3 against 70.7) for twice the evaluations.
FTOL = 1e-6


class MapTracker(SequentialFilter):
    """Sliding-window MAP tracker for a (balanced) GPDM prior (module docstring: eq. 21, Algorithm 1).

    Args:
        model: the GPDM prior, global motion and 2D likelihood (``model.prior`` must keep the
            :class:`~priortrack.models.protocols.LatentTransition` protocol: kinds "gpdm", "bgpdm").
        window: τ, the window holds τ + 1 states (τ = 2 in the paper).
        annealing: λ, the exponent on the GPDM dynamics density (0.5 in the paper). Our fits put
            the dynamics noise on its floor (σ_X² = 10⁻⁴), so λ = 0.5 ties the latent path tightly
            to the learned flow: on the held-out walk 35_29 (B-GPDM of 35_01–03 at 30 fps, 5 px
            noise, σ = 10 px) the full mode's MPJPE was 165 mm with λ = 0.5 and 75 mm with 0.05.
        mode: "full" (states (G, y, x)) or "fast" (y = μ_Y(x), states (G, x)).
        iterations: at most this many L-BFGS-B iterations per minimisation.
        rounds: alternations of (a) latents, (b) full states per frame (full mode).

    MAP tracking draws nothing, so it takes no seed (like the unscented filter): the same input
    gives the same track.

    State after :meth:`initialise` / :meth:`step`: ``g`` (K_g, 6) and ``x`` (K_x, d) the newest
    placements and latents (the frozen history first, the window's free states last), ``y``
    (n, D) the poses of the n ≤ τ + 1 free states (full mode; None in fast mode).
    """

    #: What the tracker needs of a prior (priortrack.priors.registry): a GPDM's latent space.
    requires = "latent"

    def __init__(self, model: TrackingModel, window: int = 2, annealing: float = 0.5, mode: str = "full",
                 iterations: int = 50, rounds: int = 1):
        if not isinstance(model.prior, LatentTransition):
            raise PriortrackError(f"the MAP tracker needs a GPDM prior (kinds 'gpdm', 'bgpdm'); got a "
                                  f"{getattr(model.prior, 'kind', type(model.prior).__name__)!r} prior")
        if mode not in MODES:
            raise PriortrackError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
        for name, value in (("window", window), ("iterations", iterations), ("rounds", rounds)):
            if not isinstance(value, int | np.integer) or value < 1:
                raise PriortrackError(f"{name} must be a positive integer, got {value!r}")
        if not isinstance(annealing, int | float | np.floating) or not annealing >= 0:
            raise PriortrackError(f"annealing must be a non-negative number, got {annealing!r}")
        self.model, self.prior = model, model.prior
        self.angles = model.body.angles
        self.tau, self.annealing, self.mode = int(window), float(annealing), mode
        self.iterations, self.rounds = int(iterations), int(rounds)
        self.g: torch.Tensor | None = None
        self.x: torch.Tensor | None = None
        self.y: torch.Tensor | None = None
        self.observations: list[torch.Tensor] = []
        self.frame = 0

    # ---- the window ------------------------------------------------------------------------
    @property
    def free(self) -> int:
        """n, the number of free states at the end of the window (≤ τ + 1)."""
        return len(self.observations)

    def initialise(self, motion: Motion, start: int = 1) -> None:
        """Freeze the known frames ``start − 1`` (its placement) and ``start`` (placement and
        latent) of a motion (at the prior's frame rate); the next :meth:`step` consumes frame
        ``start + 1``. Poses decode to joints with the motion's own skeleton from here on
        (``TrackingModel.initial_states`` sets ``model.body``)."""
        # One initial state is the known pose itself: the generator's draw is discarded.
        s = self.model.initial_states(motion, 1, torch.Generator(), start).to(torch.float64)
        self.angles = self.model.body.angles                  # poses decode with the subject's bones
        x, g, g_prev = self.model.split(s)
        self.g, self.x = torch.cat([g_prev, g]), x
        self.y = None if self.mode == "fast" else x.new_zeros(0, self.prior.D)
        self.observations = []
        self.frame = start

    def energy_terms(self, g: torch.Tensor, y: torch.Tensor | None, x: torch.Tensor,
                     terms: tuple[str, ...] = TERMS) -> dict[str, torch.Tensor]:
        """The terms of eq. 21 (scalars, differentiable) for the window's n free states.

        Args:
            g: (n, 6) placements. y: (n, D) poses in radians, or None for y = μ_Y(x) (fast mode).
            x: (n, d) latent positions. The frozen history (the two placements and the latent
                before the free states) and the window's observations are the tracker's own.
            terms: which of ``TERMS`` to evaluate (all by default).

        Returns:
            {"image": −Σ ln p(z_j | G_j, y_j), "reconstruction": Σ eq. 18,
             "global": −Σ ln p(G_j | G_{j−1}, G_{j−2}),
             "dynamics": λ · −Σ ln N(x_j; μ_X(x_{j−1}), σ_X²(x_{j−1}) I)}, restricted to ``terms``.
        """
        n = self.free
        if n == 0:
            raise PriortrackError("the window has no free state yet: call step(z) first")
        if g.shape != (n, 6) or x.shape != (n, self.prior.d) or (y is not None and y.shape != (n, self.prior.D)):
            raise PriortrackError(f"window states g {tuple(g.shape)}, x {tuple(x.shape)}"
                                  f"{'' if y is None else f', y {tuple(y.shape)}'}: expected n = {n} rows of "
                                  f"6, {self.prior.d}{'' if y is None else f' and {self.prior.D}'}")
        unknown = set(terms) - set(TERMS)
        if unknown:
            raise PriortrackError(f"unknown energy terms {sorted(unknown)}; terms: {', '.join(TERMS)}")
        poses = self.prior.pose_mean(x) if y is None else y
        out = {}
        if "image" in terms:
            world = to_world(self.angles.joints(poses), g)                               # (n, 15, 3)
            out["image"] = -sum(self.model.log_likelihood(world[k:k + 1], z)[0] for k, z in enumerate(self.observations))
        if "reconstruction" in terms:
            out["reconstruction"] = self.prior.reconstruction_energy(x, poses).sum()
        if "global" in terms:
            g_all = torch.cat([self.g[:-n], g])                                           # (n + 2, 6)
            out["global"] = -self.model.global_motion.log_prob(g_all[2:], g_all[1:-1], g_all[:-2]).sum()
        if "dynamics" in terms:
            x_all = torch.cat([self.x[:-n], x])                                           # (n + 1, d)
            out["dynamics"] = self.prior.dynamics_energy(x_all[:, None, :], self.annealing).sum()
        return out

    def energy(self, g: torch.Tensor, y: torch.Tensor | None, x: torch.Tensor,
               terms: tuple[str, ...] = TERMS) -> torch.Tensor:
        """E of eq. 21 (or the sum of the chosen ``terms``): the sum of :meth:`energy_terms`."""
        return sum(self.energy_terms(g, y, x, terms).values())

    def _scales(self) -> dict[str, torch.Tensor]:
        """Per-variable scales of the free states from the prior terms (a diagonal preconditioner):
        σ of the global motion for g (n, 6), σ_X(x_{j−1}) for x_j (n, d), σ(x_j)/w_k for channel k
        of y_j (n, D), at the current values."""
        n = self.free
        x_prev, x = self.x[-n - 1:-1], self.x[-n:]
        with torch.no_grad():
            scales = {"g": self.model.global_motion.sigma.expand(n, -1),
                      "x": self.prior.dynamics(x_prev)[1].sqrt()[:, None].expand(n, self.prior.d)}
            if self.y is not None:
                scales["y"] = self.prior.reconstruct(x)[1].sqrt()[:, None] / self.prior.W
        return scales

    def _minimise(self, free: tuple[str, ...], terms: tuple[str, ...] = TERMS) -> float:
        """Minimise E over the named parts ("g", "y", "x") of the free states, the others fixed,
        by L-BFGS-B (at most ``iterations`` iterations) in the scaled variables u = (v − v₀)/s
        (:meth:`_scales`); ``terms`` are the terms that depend on those parts (the others are
        constant). Stores the result and returns the minimised sum of ``terms``."""
        n = self.free
        values = {"g": self.g[-n:], "x": self.x[-n:], "y": self.y}
        scales = self._scales()
        shapes = [values[k].shape for k in free]
        sizes = [int(np.prod(s)) for s in shapes]

        def unpack(u: torch.Tensor) -> dict[str, torch.Tensor]:
            parts = torch.split(u, sizes)
            return {**values, **{k: values[k] + scales[k] * part.reshape(s) for k, part, s in zip(free, parts, shapes)}}

        def f(u_np: np.ndarray):
            u = torch.from_numpy(u_np).requires_grad_(True)
            v = unpack(u)
            E = self.energy(v["g"], v["y"], v["x"], terms)
            (grad,) = torch.autograd.grad(E, u)
            return E.item(), grad.numpy()

        result = minimize(f, np.zeros(sum(sizes)), jac=True, method="L-BFGS-B",
                          options={"maxiter": self.iterations, "gtol": GTOL, "ftol": FTOL})
        if not np.isfinite(result.fun):
            raise PriortrackError(f"the window energy is not finite ({result.fun}) at frame {self.frame + 1}")
        v = unpack(torch.from_numpy(result.x))
        self.g = torch.cat([self.g[:-n], v["g"]])
        self.x = torch.cat([self.x[:-n], v["x"]])
        self.y = v["y"]
        return float(result.fun)

    def _shift(self, z: torch.Tensor) -> None:
        """Append the mean prediction of the next state (x = μ_X(x_{t−1}), y = μ_Y(x),
        G = Ĝ) and its observation; freeze the oldest free state if the window would exceed τ + 1."""
        x_new = self.prior.mean(self.x[-1:])
        g_new = self.model.global_motion.predict(self.g[-1:], self.g[-2:-1])
        self.x, self.g = torch.cat([self.x, x_new]), torch.cat([self.g, g_new])
        self.observations.append(z)
        if self.y is not None:
            self.y = torch.cat([self.y, self.prior.pose_mean(x_new)])
        if self.free > self.tau + 1:
            self.observations.pop(0)
            if self.y is not None:
                self.y = self.y[1:]
        n = self.free
        self.x, self.g = self.x[-(n + 1):], self.g[-(n + 2):]

    # ---- the filter interface ----------------------------------------------------------------
    def step(self, z) -> Snapshot:
        """Consume the observation z of the next frame (``model.observation_shape``, NaN where missing).

        Returns a :class:`Snapshot` whose ``particles`` are the window's free states as
        tracking-model rows [x_j, g_j, g_{j−1}] (n ≤ τ + 1, oldest first, the newest last),
        ``weights`` ones, ``ess`` NaN (a MAP window is not a weighted sample), ``ancestors``
        None, ``estimate`` and ``best`` the newest state's world eval15 joints (from y in full
        mode, from μ_Y(x) in fast mode), ``joints`` (n, 15, 3) the window's world joints, and
        ``timings`` "predict", "latents" (step a), "states" (step b), "estimate" in seconds.
        """
        if self.g is None:
            raise PriortrackError("the tracker is not initialised: call initialise(motion) first")
        z = torch.as_tensor(np.asarray(z, dtype=np.float64))
        if z.shape != self.model.observation_shape:
            raise PriortrackError(f"observation has shape {tuple(z.shape)}; expected {self.model.observation_shape}")
        z, gated = self.model.gate(z)
        flags = ([] if torch.isfinite(z).any() else ["no-observation"]) + (["outlier-gated"] if gated else [])
        # The window holds a few hundred numbers: extra threads only add synchronisation (on 2 busy
        # cores a frame took 4.1 s with torch's default 2 threads and 0.78 s with one).
        with torch_threads(1):
            t0 = time.perf_counter()
            self._shift(z)
            t1 = time.perf_counter()
            latents = states = 0.0
            if self.mode == "fast":
                energy = self._minimise(("g", "x"))
                states = time.perf_counter() - t1
            else:
                for _ in range(self.rounds):
                    ta = time.perf_counter()
                    self._minimise(("x",), ("reconstruction", "dynamics"))
                    tb = time.perf_counter()
                    energy = self._minimise(("g", "y", "x"))
                    latents, states = latents + tb - ta, states + time.perf_counter() - tb
        t2 = time.perf_counter()
        n = self.free
        g, x = self.g[-n:], self.x[-n:]
        with torch.no_grad():
            poses = self.prior.pose_mean(x) if self.y is None else self.y
            joints = to_world(self.angles.joints(poses), g)
        particles = torch.cat([x, g, self.g[-n - 1:-1]], dim=1)
        estimate = joints[-1].numpy()
        self.frame += 1
        log.debug("MAP frame %d: E = %.6g over %d states", self.frame, energy, n)
        timings = {"predict": t1 - t0, "latents": latents, "states": states, "estimate": time.perf_counter() - t2}
        return Snapshot(self.frame, particles, torch.ones(n, dtype=torch.float64), float("nan"), None,
                        estimate, estimate.copy(), joints, flags, timings)
