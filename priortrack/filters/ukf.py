"""The unscented Kalman filter: filterpy's UnscentedKalmanFilter with its sigma points
propagated as one batch and states on manifolds handled in tangent coordinates.

**Model.** For the full state s = [x, g_t, g_{t-1}] of a :class:`TrackingModel`:

    s_t = f(s_{t-1}) ⊞ w_t,  w_t ~ N(0, Q),    f = TrackingModel.mean_step (prior mean, the
                                               placement's mean step GlobalMotion.predict, the copy g_t → g_{t-1}),
    z_t = h(s_t) + v_t,      v_t ~ N(0, R),    h = the pixels of the projected world joints (15 · 2),

    Q = blockdiag(prior.transition_covariance(x̄), diag σ_t², Σ_ω(ḡ_t), ε I_6),   R = σ_px² I,

Q taken at the current mean state s̄ = [x̄, ḡ_t, ḡ_{t-1}], σ_t the translation's part of
GlobalMotion.sigma, Σ_ω(ḡ_t) the heading and tilt noise as a world-frame rotation
(GlobalMotion.rotation_covariance), and ε =
``COPY_JITTER`` on g_{t-1}, whose transition is an exact copy (zero noise): the jitter only keeps Q
positive definite, it adds 10 µm / 10 µrad of spread. A frame's missing observations (NaN) drop
their rows of z and of R (and their columns of R).

**Tangent coordinates.** A state is stored in A numbers (the ambient row, as every filter holds
it); its covariance P lives in the tangent space at the mean, in n numbers:

- the pose, in the prior's space: Euclidean (joint angles, a GPDM latent; n = S, ⊞ = +) or the
  bone directions on (S²)¹⁴ (n = 28 < 42: on each bone the two coordinates in the
  :func:`~priortrack.geometry.tangent_basis.tangent_basis` E(x) at the base point,
  x ⊞ c = x ⊞_space Eᵀc = exp_x(Eᵀc) and y ⊟ x = E (y ⊟_space x) = E log_x(y));
- each placement g = (t, ω): the translation Euclidean, the rotation with world-frame (left)
  perturbations, R ⊞ η = exp(η) R and R_a ⊟ R_b = log(R_a R_bᵀ), as Σ_ω's η;

so n = n_x + 12 ≤ A = S + 12. filterpy's sigma-point machinery needs n = A, so it runs on the
tangent coordinates: our sigma-point object draws filterpy's scaled offsets ξ_i on 0 ∈ Rⁿ and
maps them onto the manifold; the state's mean, residual and add are passed to filterpy as its
``x_mean_fn``, ``residual_x`` and ``state_add`` hooks; the state's unscented transform and the
cross-covariance are ours (filterpy sizes both by the sigma points' width, A), vectorised.
There is no rank deficiency to manage: P is n × n and positive definite.

**One step** (Van der Merwe's scaled sigma points, α, β, κ; λ = α²(n + κ) − n; weights Wm, Wc):

    ξ_0 = 0, ξ_{±k} = ±(row k of the upper Cholesky factor of (n + λ) P)    (filterpy)
    χ_i = s̄ ⊞ ξ_i                                                          (2n + 1 points, one batch)
    predict  χ'_i = f(χ_i) in one batch; s̄' = their mean, the fixed point of
             m ← m ⊞ Σ_i Wm_i (χ'_i ⊟ m) started at χ'_0 (one step in a Euclidean space; the
             Karcher iteration with signed weights on a manifold);
             P' = Σ_i Wc_i (χ'_i ⊟ s̄')(χ'_i ⊟ s̄')ᵀ + Q
    update   χ_i redrawn from (s̄', P'); Z_i = h(χ_i) in one batch; ẑ = Σ Wm_i Z_i;
             S = Σ Wc_i (Z_i − ẑ)(Z_i − ẑ)ᵀ + R;  C = Σ Wc_i (χ_i ⊟ s̄')(Z_i − ẑ)ᵀ;  K = C S⁻¹;
             s̄ = s̄' ⊞ K (z − ẑ);  P = Γ (P' − K S Kᵀ) Γᵀ

with Γ the change of tangent coordinates from s̄' to the new s̄: on the spheres the parallel
transport of the basis at s̄' into the basis at s̄ (a 2 × 2 rotation per bone), the identity
elsewhere (world-frame rotation perturbations need none). filterpy's own ``predict`` and
``update`` run every step; ``batched=False`` runs f through filterpy's per-sigma-point loop
(``UnscentedKalmanFilter.compute_process_sigmas``) and h one sigma point per call (the pattern
of filterpy's update loop), the reference that :mod:`priortrack.experiments.benchmarks.ukf` times.

**Care.** A frame without any observation skips the update (the prediction stands; flagged
"no-observation"). A covariance that is not positive definite (an update's P' − K S Kᵀ losing
definiteness to rounding, or a broken one handed in) is symmetrised and its eigenvalues floored
at ``EIGEN_FLOOR`` × its largest (flagged "covariance-repaired"); a non-finite one is an error,
never a NaN estimate. An observed joint that some sigma point puts behind the camera (no
projection) is left out of that frame's update (flagged "behind-camera").

**Validation gate** (Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking*, §5.7).
One gross detection, or a few frames of them, pulls a Kalman update far off, and a single
camera cannot tell afterwards whether the body moved or bent: the filter settles in a wrong 3D
pose that reprojects well and never comes back (a 400 px jump of one frame left ukf-diffusion-local
300–500 mm off for 50 frames). So each observed point k (a joint in one camera: its
``measurement_block`` coordinates) is tested against the predicted measurement before the update:

    d²_k = (z_k − ẑ_k)ᵀ S_kk⁻¹ (z_k − ẑ_k),   S_kk its block of S,

and left out of the update when d²_k > χ²_b(1 − p_gate), the quantile at which a point the model
predicts correctly is rejected with probability p_gate (flagged "innovation-gated"). Gated
frames add no information, so P grows by Q each frame and S with it: a filter that lost the
body widens its own gate. Should every observed point still fail the gate ``GATE_PATIENCE``
frames in a row, the next frame is taken ungated (flagged "gate-reopened"): the data win over a
prediction that no longer explains any of them. The same holds for one joint: where it is seen by
two cameras or more and fails the gate in every one of them ``GATE_PATIENCE`` frames in a row (the
views agree with each other, not with the estimate: a lost limb, not one detector's mistake, which
the other cameras would not repeat), the following frames take that joint ungated until the gate
accepts it again (flagged "joint-reacquired"; ukf-lie-defensive had held caliscope's right wrist out for 67 frames running,
300–460 px off in every webcam). Not for a latent prior (``reacquire = false``, ukf-gpdm): its few
latent coordinates move every joint together, and a joint taken against it drags the body (caliscope
under ukf-gpdm: median 34 → 114 px in the camera left out).

**A detector's left/right swaps** (OpenPose's, MediaPipe's: a person seen from behind, legs crossing) are
undone before the gate, camera by camera: for each left/right pair of joints (shoulders, elbows, wrists,
hips, knees, ankles) seen in a camera, the two detections are exchanged where the labels fail the gate
at one of the two joints, the exchanged association passes it at both, and lies nearer the prediction,
d²(z_r; l) + d²(z_l; r) < d²(z_l; l) + d²(z_r; r) with d² the gate's distance (each detection with its
own noise R): the more likely of the two hypotheses (flagged "swap-corrected"; ``swaps = false`` in a
preset keeps the labels). Plain nearest association, without the gate's two conditions, relabelled
detections wherever a learned prior had lost a wrist (caliscope under ukf-lie-defensive, the camera left
out: 26.0 → 30.3 px median, 55 → 94 px p90); no gate (p_gate = 0), no exchange.
Without it a swapped pair is either held out by the gate (its frame's information in that camera lost)
or, where the two joints project close together, taken as labelled and pulls both joints across.

**The branch no body takes.** A joint one camera sees is free along that camera's ray, and the update moves the
state along it wherever the covariance says: an elbow seen only by a camera at the person's side can drift through
the chest onto its other depth branch (the same pixel, the same upper arm) and stay there
(:mod:`priortrack.geometry.depth_branches`; Shelf, cameras 0, 1, 4: actor 2's right elbow, 0.35–0.5 m off for 3 s).
After each update, an elbow of the mean inside the trunk and seen by one camera is observed at its reflection about
the shoulder, its wrist as little moved as the forearm allows, the trunk's joints where they are, by a second
unscented update with σ = ``BRANCH_SIGMA_M`` (1 cm: the target is as certain as the pixel and the bone lengths that
place it; 5 cm moved the elbow a quarter of the way a step, and without the trunk held the update moved the body
instead of the arm). Constraining the estimate by a pseudo-measurement is Simon's "perfect measurement" (D. Simon,
*Kalman filtering with state constraints: a survey of linear and nonlinear algorithms*, IET CTA 2010) with a
little noise; one step takes the elbow most of the way (the arm's rotation is nonlinear), the next finishes it.
``branches = false`` in a preset leaves the estimate where the update puts it.

**The trunk's facing.** One camera fixes the hips and shoulders to their rays, and their line across the body
reflected across the camera's vertical plane keeps its pixels: the body turned about the vertical through the
mid-hips, facing the other side of the picture (the Necker reversal, :mod:`priortrack.geometry.facing`). A filter
meeting a person side-on may follow the wrong one for seconds (Shelf, each camera alone: the trunk more than 90° from
the truth's in up to 132 frames of an actor, 325–417 mm off root-relative there). Where the run has the detector's
feet and face (:attr:`UnscentedFilter.forward`, per tick and camera), each step in which one camera alone sees the
person (another camera seeing any joint holds a depth the turn would contradict: on Shelf's pairs, turning wherever
one camera alone saw the trunk cost cameras 0, 4 actor 1 6 points of PCP) and their trunk fits its pixels there
turns the predicted mean (both placements; the pose kept, the covariance as it is, the sigma points redrawn) to the
reflected facing where the feet and face point that way, before the update fits the limbs to their pixels
(flagged "facing-turned"). ``branches = false`` turns this off too.

**A foot on the floor.** With one camera the body's depth rests on its size in the image, so on how well the
template's proportions match the detector's keypoints (a body 4 % small is placed 4 % near: 0.2 m at 5 m). Where
the run knows the floor (:attr:`UnscentedFilter.floor`, the working frame's y of it; one-camera rigs whose
calibration has its origin on the floor), each update is followed by a second one observing the mean's lower ankle
at :data:`~priortrack.body.ik.ANKLE_HEIGHT` above it, σ = ``FLOOR_SIGMA_M`` (1 cm), on sigma points redrawn from
the posterior, its gain kept on the placements' translations (the floor places the body, the pixels shape it;
flagged "floor-contact"). A step whose predicted lower ankle is more than ``FLOOR_GATE_M`` (0.3 m) from it (a jump,
a foot on a step) takes none. With σ = 5 cm the pixels, which place a body by its image size, held it where they
had (Pose2Sim's demo, camera 1 alone: 196 → 195 mm world; 1 cm: 158).

Only a Gaussian filter: a robust (Student-t) likelihood has no R, and the Lie prior's transition
(a mixture) has no single noise covariance; both are refused with a PriortrackError (use the
particle filter).
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter, unscented_transform
from scipy.stats import chi2

from priortrack.body.ik import ANKLE_HEIGHT
from priortrack.data.eval15 import EVAL15_MIRROR_PAIRS
from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.filters import placements_kernel
from priortrack.filters.driver import SequentialFilter
from priortrack.filters.snapshot import Snapshot
from priortrack.geometry import so3
from priortrack.geometry.depth_branches import ELBOWS, trunk_repairs
from priortrack.geometry.facing import alone, facing_turns
from priortrack.geometry.manifold_mean import MEAN_MAX_STEPS, MEAN_TOL, signed_mean
from priortrack.kernels import cpu_kernel_applies
from priortrack.models.protocols import GaussianTransition
from priortrack.models.tracking import GLOBAL_DIM, TrackingModel
from priortrack.threads import blas_threads, torch_threads

log = logging.getLogger(__name__)

#: Variance (m², rad²) added to the zero noise of the copy g_{t-1} ← g_t.
COPY_JITTER = 1e-10
#: Eigenvalues of a repaired covariance are at least this times its largest.
EIGEN_FLOOR = 1e-9
#: Van der Merwe's sigma-point parameters (defaults): spread α, prior knowledge β, κ.
ALPHA, BETA, KAPPA = 0.5, 2.0, 0.0
#: Probability that the validation gate rejects a point the model predicts correctly (module docstring).
GATE_PROBABILITY = 1e-4
#: Consecutive frames whose every observed point (or every camera's detection of one joint) fails the gate
#: before one is taken ungated.
GATE_PATIENCE = 3
#: eval15's ankles.
ANKLES = (11, 14)
#: σ (m) of an elbow's pseudo-observation at its other depth branch (module docstring, "The branch no body takes").
BRANCH_SIGMA_M = 0.01
#: σ (m) of the lower ankle's pseudo-observation on the floor (as certain as an elbow's branch: a constraint, Simon's
#: "perfect measurement" with a little noise), and how far above or below it a predicted lower ankle is off the floor
#: (a jump, a step: no update; module docstring, "A foot on the floor").
FLOOR_SIGMA_M, FLOOR_GATE_M = 0.01, 0.3
#: torch and BLAS threads a step runs on (:meth:`UnscentedFilter.step`).
STEP_THREADS = 1
#: What the filter needs of a model that is not a TrackingModel (the linear-Gaussian test model keeps it).
UNSCENTED_INTERFACE = ("dim", "tangent_dim", "observation_shape", "measurement_block", "mean_step", "measure", "observe",
                       "process_covariance", "measurement", "gate", "boxplus", "boxminus", "sigma_mean", "transport")


def _in_kernel(*tensors: torch.Tensor) -> bool:
    """Whether the placements' ⊞, ⊟ and mean take the fused kernels (:mod:`~priortrack.filters.placements_kernel`):
    float64 CPU tensors without gradients, the states of a batch (N, 12)."""
    return cpu_kernel_applies(*tensors, dtype=torch.float64) and tensors[0].dim() == 2


def _placements(g: torch.Tensor) -> torch.Tensor:
    """(..., 12) → (..., 2, 6): the two placements (g_t, g_{t-1}) of a state, each (t, ω)."""
    return g.reshape(g.shape[:-1] + (2, GLOBAL_DIM))


def placements_plus(g: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """(t, ω) ⊞ (δt, η) = (t + δt, log(exp(η) exp(ω))) on both placements: g (N, 12), v (N, 12) → (N, 12).
    The rotations are composed as unit quaternions (:mod:`priortrack.geometry.so3`): a third of the
    operations of the matrices' exp, product and log, the same rotation vector to rounding."""
    if _in_kernel(g, v):
        out = np.empty(tuple(g.shape))
        placements_kernel.plus(g.contiguous().numpy(), v.contiguous().numpy(), out)
        return torch.from_numpy(out)
    g, v = _placements(g), _placements(v)
    q = so3.quaternion_product(so3.quaternion(v[..., 3:]), so3.quaternion(g[..., 3:]))
    return torch.cat([g[..., :3] + v[..., :3], so3.quaternion_log(q)], -1).flatten(-2)


def placements_minus(g: torch.Tensor, base: torch.Tensor) -> torch.Tensor:
    """g ⊟ base = (t − t_b, log(exp(ω) exp(ω_b)ᵀ)) on both placements: g (N, 12), base (12,) (or one per row,
    (N, 12)) → (N, 12), the rotations composed as unit quaternions (as :func:`placements_plus`)."""
    if base.dim() == 1 and _in_kernel(g, base):
        out = np.empty(tuple(g.shape))
        placements_kernel.minus(g.contiguous().numpy(), base.contiguous().numpy(), out)
        return torch.from_numpy(out)
    g, base = _placements(g), _placements(base)
    q = so3.quaternion_product(so3.quaternion(g[..., 3:]), so3.quaternion_conjugate(so3.quaternion(base[..., 3:])))
    return torch.cat([g[..., :3] - base[..., :3], so3.quaternion_log(q)], -1).flatten(-2)


def placements_mean(g: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Mean (12,) of both placements of states g (N, 12): the translations' Σ w_i t_i and the
    rotations' :func:`signed_mean` with R ⊞ η = exp(η) R, R_i ⊟ M = log(R_i Mᵀ), the rotations as unit
    quaternions q_i (computed once; q ⊟ m = log(q m*))."""
    if _in_kernel(g, w):
        out = np.empty(2 * GLOBAL_DIM)
        if placements_kernel.signed_mean(g.contiguous().numpy(), w.contiguous().numpy(), MEAN_TOL, MEAN_MAX_STEPS,
                                         out) < 0:
            log.warning("signed mean of the placements: no convergence in %d steps", MEAN_MAX_STEPS)
        return torch.from_numpy(out)
    g = _placements(g)
    q = so3.quaternion(g[..., 3:])                                                 # (N, 2, 4)
    m = signed_mean(q[0], w, lambda m: so3.quaternion_log(so3.quaternion_product(q, so3.quaternion_conjugate(m))).flatten(-2),
                    lambda m, eta: so3.quaternion_product(so3.quaternion(eta.reshape(2, 3)), m))
    return torch.cat([torch.einsum("n,nkc->kc", w, g[..., :3]), so3.quaternion_log(m)], -1).flatten()


# ---- a tracking model as the unscented filter sees it ---------------------------------------------

class UnscentedTracking:
    """A :class:`TrackingModel` in the form the unscented filter needs (``UNSCENTED_INTERFACE``):
    tangent coordinates of full states (⊞, ⊟, the change of coordinates between base points), the
    noise-free measurement h and the noise covariances Q and R (module docstring).

    Shapes: states (N, A), A = S + 12; tangent vectors (N, n), n = n_x + 12; measurements (N, m),
    m = 2 · joints · cameras, the (u, v) of one joint in one camera adjacent.
    """

    #: Coordinates of one observed point (a joint's u, v in one camera): what the gate tests together.
    measurement_block = 2

    def __init__(self, model: TrackingModel):
        prior = model.prior
        if not isinstance(prior, GaussianTransition):
            raise PriortrackError(f"the unscented filter needs a prior with a Gaussian transition (a mean step and a "
                                  f"noise covariance); the {prior.kind!r} prior ({type(prior).__name__}) has none: "
                                  f"use the particle filter")
        self.model, self.space = model, prior.space
        self.dim, self.tangent_dim = model.dim, self.space.tangent_dim + 2 * GLOBAL_DIM
        self.observation_shape = model.observation_shape
        self.mean_step, self.observe = model.mean_step, model.observe
        #: The left/right joint pairs of an observed point's joints that a detector may swap (eval15's; None
        #: for another layout).
        self.mirror_pairs = EVAL15_MIRROR_PAIRS if len(self.observation_shape) >= 2 and self.observation_shape[-2] == 15 else None

    def boxplus(self, s: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """s (N, A) ⊞ v (N, n) → (N, A)."""
        S, n = self.model.pose_dim, self.space.tangent_dim
        return torch.cat([self.space.retract(s[:, :S], v[:, :n]), placements_plus(s[:, S:], v[:, n:])], -1)

    def boxminus(self, s: torch.Tensor, base: torch.Tensor) -> torch.Tensor:
        """s (N, A) ⊟ base (A,) (or one base per row, (N, A)) → (N, n), in the tangent coordinates at base."""
        S = self.model.pose_dim
        return torch.cat([self.space.local(s[:, :S], base[..., :S]), placements_minus(s[:, S:], base[..., S:])], -1)

    def sigma_mean(self, s: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """Mean (A,) of states s (N, A) for weights w (N,) summing to 1 (any sign): on each factor
        of the product manifold the fixed point of m ← m ⊞ Σ_i w_i (s_i ⊟ m) (:func:`signed_mean`;
        one step, the weighted sum, where ⊞ = +)."""
        S = self.model.pose_dim
        return torch.cat([self.space.signed_mean(s[:, :S], w), placements_mean(s[:, S:], w)])

    def transport(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """(n, n) map from tangent coordinates at state a (A,) to those at b (A,)."""
        S = self.model.pose_dim
        eye = torch.eye(2 * GLOBAL_DIM, dtype=a.dtype, device=a.device)
        return torch.block_diag(self.space.coordinate_transport(a[:S], b[:S]), eye)

    def measure(self, s: torch.Tensor) -> torch.Tensor:
        """h: states (N, A) → (N, m) pixels (u, v of each joint, in every camera), NaN where behind a camera."""
        return self.model.likelihood.pixels(self.model.observe(s))

    def gate(self, z) -> tuple[torch.Tensor, int]:
        """One frame's data with the gross outliers made missing, and their count (the observation model's)."""
        return self.model.gate(z)

    def trunk_repairs(self, s: np.ndarray, taken: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """The elbows of the state s (A,) to move to their other depth branch, (elbow, target (3,)) each
        (:func:`~priortrack.geometry.depth_branches.trunk_repairs`), given the measured coordinates an update took
        (m,) bool; none for joints other than eval15's."""
        cameras = getattr(self.model.likelihood, "cameras", None)
        if self.mirror_pairs is None or cameras is None or taken.size != 30 * len(cameras):
            return []
        seen = taken.reshape(len(cameras), 15, 2).all(-1)
        if not (seen[:, list(ELBOWS)].sum(axis=0) == 1).any():          # no elbow one camera alone sees: no FK
            return []
        joints = self.observe(torch.from_numpy(s)[None])[0].cpu().numpy()
        centres = np.stack([camera.center.double().cpu().numpy() for camera in cameras])
        return trunk_repairs(joints, seen, centres)

    def facing_turned(self, s: np.ndarray, z: np.ndarray, forward: np.ndarray) -> tuple[np.ndarray, float] | None:
        """The state s (A,) turned to the trunk's other facing where one camera alone sees the person in z (C, 15, ·)
        (:func:`~priortrack.geometry.facing.alone`) and the detector's forward direction there, ``forward`` (C, 3)
        (:func:`~priortrack.geometry.facing.image_forward`), says it faces that way, its trunk fitting its pixels there
        (:func:`~priortrack.geometry.facing.facing_turns`): both placements g_t, g_{t−1} turned about the vertical
        through the mid-hips (:meth:`~priortrack.models.tracking.TrackingModel.turned`), the pose kept; and the turn's
        angle. None otherwise, and for joints other than eval15's."""
        cameras = getattr(self.model.likelihood, "cameras", None)
        if self.mirror_pairs is None or cameras is None or z.size % (15 * len(cameras)) or len(forward) != len(cameras):
            return None
        z = z.reshape(len(cameras), 15, -1)
        c = alone(z)
        if c is None:
            return None
        joints = self.observe(torch.from_numpy(s)[None])[0].cpu().numpy()
        angle = float(facing_turns(joints[None], cameras[c], forward[c], z[c])[0])
        if angle == 0.0:
            return None
        pivot = torch.from_numpy(joints[[9, 12]].mean(0))[None]
        turned = self.model.turned(torch.from_numpy(s)[None], torch.tensor([angle], dtype=torch.float64), pivot)
        return turned[0].numpy(), angle

    def measurement(self, z) -> tuple[torch.Tensor, torch.Tensor]:
        """One frame's data → the measured pixels (m,) (NaN: not seen) and R (m, m), diagonal."""
        values, variances = self.model.likelihood.measurement(z)
        return values, torch.diag(variances)

    def process_covariance(self, s: torch.Tensor) -> torch.Tensor:
        """Q (n, n) at the state s (A,): blockdiag(prior noise at x, diag σ_t², the rotation noise at
        g_t as a world-frame perturbation (GlobalMotion.rotation_covariance), COPY_JITTER I_6)."""
        x, g, _ = self.model.split(s[None])
        motion = self.model.global_motion
        jitter = torch.full((GLOBAL_DIM,), COPY_JITTER, dtype=s.dtype, device=s.device)
        return torch.block_diag(self.model.prior.transition_covariance(x)[0], torch.diag(motion.sigma[:3].to(s) ** 2),
                                motion.rotation_covariance(g)[0], torch.diag(jitter))


def unscented_form(model, robust: bool = False):
    """The model as the unscented filter uses it: a TrackingModel wrapped in
    :class:`UnscentedTracking`; any other model must itself keep ``UNSCENTED_INTERFACE``. A robust
    (Student-t) likelihood is refused unless ``robust`` (the guided proposal weighs its points itself:
    :mod:`priortrack.filters.proposal`)."""
    if isinstance(model, TrackingModel):
        nu = model.likelihood.robust_nu
        if nu is not None and not robust:
            raise PriortrackError(f"the unscented filter needs a Gaussian likelihood (R = σ_px² I); this one is a "
                                  f"Student-t (robust_nu={nu:g}), which has no measurement covariance: use the "
                                  f"particle filter, or an observation model without robust_nu")
        return UnscentedTracking(model)
    missing = [name for name in UNSCENTED_INTERFACE if not hasattr(model, name)]
    if missing:
        raise PriortrackError(f"the unscented filter needs a TrackingModel or a model with {', '.join(UNSCENTED_INTERFACE)}; "
                              f"{type(model).__name__} lacks {', '.join(missing)}")
    return model


# ---- filterpy, batched ------------------------------------------------------------------------------

def repaired_covariance(P: np.ndarray) -> tuple[np.ndarray, bool]:
    """(n, n) → (the symmetrised P, False) if it is positive definite with every Cholesky pivot at least
    EIGEN_FLOOR × its largest diagonal entry, else (V max(Λ, EIGEN_FLOOR · λ_max) Vᵀ from its eigendecomposition
    V Λ Vᵀ, True). The pivots' floor: a particle cloud collapsed in a coordinate leaves a pivot of about 1e−40 there,
    which one factorisation accepts and the next, of a multiple of P, need not (a smoothed cloud of pf-lie-general on
    the Pose2Sim trial, 40 × 40, smallest eigenvalue −5e−40). A non-finite P raises a PriortrackError."""
    if not np.isfinite(P).all():
        raise PriortrackError("the unscented filter's covariance is not finite (NaN or inf)")
    P = (P + P.T) / 2
    try:
        if (np.diagonal(np.linalg.cholesky(P)) ** 2).min() >= EIGEN_FLOOR * P.diagonal().max():
            return P, False
    except np.linalg.LinAlgError:
        pass
    w, V = np.linalg.eigh(P)
    floor = EIGEN_FLOOR * max(float(w.max()), np.finfo(float).tiny)
    log.debug("covariance repaired: smallest eigenvalue %.3g floored at %.3g", w.min(), floor)
    return (V * np.maximum(w, floor)) @ V.T, True


def diagonal_blocks(M: np.ndarray, b: int) -> np.ndarray:
    """The K diagonal b × b blocks (K, b, b) of M (K b, K b): one observed point's coordinates each."""
    K = len(M) // b
    return M.reshape(K, b, K, b).diagonal(axis1=0, axis2=2).transpose(2, 0, 1)


def block_distances(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """d²_k = ν_kᵀ S_k⁻¹ ν_k (K,) of innovations ν (K, b) with covariances S (K, b, b): what the
    validation gate tests."""
    return np.einsum("kc,kc->k", nu, np.linalg.solve(S, nu[..., None])[..., 0])


def predicted_points(Z: np.ndarray, Wm: np.ndarray, Wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The predicted measurement of each point from the sigma points' Z (N, K, b): its mean ẑ_k = Σ_i Wm_i Z_ik
    (K, b) and covariance Σ_i Wc_i (Z_ik − ẑ_k)(Z_ik − ẑ_k)ᵀ (K, b, b)."""
    z_hat = np.einsum("i,ikc->kc", Wm, Z)
    r = Z - z_hat
    return z_hat, np.einsum("i,ikc,ikd->kcd", Wc, r, r)


def gate_threshold(gate_probability: float, b: int) -> float:
    """The validation gate's bound on d² for points of ``b`` coordinates: χ²_b(1 − p_gate), inf for p_gate = 0
    (no gate)."""
    return float(chi2.isf(gate_probability, b)) if gate_probability > 0 else np.inf


def swap_corrected(z: np.ndarray, R: np.ndarray, z_hat: np.ndarray, P: np.ndarray, pairs: np.ndarray, joints: int,
                   b: int, threshold: float) -> tuple[np.ndarray, np.ndarray, int]:
    """A detector's left/right swaps undone, camera by camera (module docstring): for a mirror pair (l, r)
    (``pairs`` (p, 2), joint indices of a camera's ``joints``) seen in a camera, its two detections are
    exchanged where d²(z_r; l) + d²(z_l; r) < d²(z_l; l) + d²(z_r; r), d²(z; k) = (z − ẑ_k)ᵀ (P_k + R_z)⁻¹
    (z − ẑ_k) with ẑ_k, P_k the predicted measurement of joint k's point (``z_hat`` (K, b) and ``P`` (K, b, b)
    of every point, :func:`predicted_points`; NaN where unpredictable) and R_z the detection's own noise (the nearer
    association of the two detections to the two joints), and only where the labels fail the gate
    (d² > ``threshold``) at one of the two joints and the exchanged association passes it at both: a
    prediction that lost a limb is not a reason to relabel what the detector saw. z (m,) points of ``b``
    coordinates in cameras × joints order (NaN: not seen), R (m, m) diagonal. Returns z and R with the
    pairs exchanged, and the exchanged points (k,) (both of each pair, indices in cameras × joints order;
    empty where none)."""
    cameras = len(z) // (b * joints)
    left = (np.arange(cameras)[:, None] * joints + pairs[:, 0]).ravel()
    right = (np.arange(cameras)[:, None] * joints + pairs[:, 1]).ravel()
    points = np.isfinite(z).reshape(-1, b).all(axis=1) & np.isfinite(z_hat).all(axis=1) & np.isfinite(P).all(axis=(1, 2))
    seen = points[left] & points[right]
    left, right = left[seen], right[seen]
    if not len(left):
        return z, R, np.zeros(0, dtype=int)
    both = np.concatenate([left, right])
    columns = (both[:, None] * b + np.arange(b)).ravel()
    z_hat, P = z_hat[both], P[both]
    noise = diagonal_blocks(R[np.ix_(columns, columns)], b)
    observed = z[columns].reshape(-1, b)
    n = len(left)
    L, Rt = slice(0, n), slice(n, 2 * n)
    labelled = np.stack([block_distances(observed[L] - z_hat[L], P[L] + noise[L]),
                         block_distances(observed[Rt] - z_hat[Rt], P[Rt] + noise[Rt])])             # (2, n)
    exchanged = np.stack([block_distances(observed[Rt] - z_hat[L], P[L] + noise[Rt]),
                          block_distances(observed[L] - z_hat[Rt], P[Rt] + noise[L])])
    swap = ((exchanged.sum(axis=0) < labelled.sum(axis=0)) & (labelled > threshold).any(axis=0)
            & (exchanged <= threshold).all(axis=0))
    if not swap.any():
        return z, R, np.zeros(0, dtype=int)
    exchanged = np.concatenate([left[swap], right[swap]])
    return *exchange(z, R, exchanged, b), exchanged


def exchange(z: np.ndarray, R: np.ndarray, points: np.ndarray, b: int) -> tuple[np.ndarray, np.ndarray]:
    """z (m,) and R (m, m) (diagonal) with the points ``points`` (2k,) exchanged pairwise, the i-th with the
    (k + i)-th (points of ``b`` coordinates, as :func:`swap_corrected` gives them); copies."""
    k = len(points) // 2
    a = (points[:k, None] * b + np.arange(b)).ravel()
    c = (points[k:, None] * b + np.arange(b)).ravel()
    z, R = z.copy(), R.copy()
    z[a], z[c] = z[c], z[a]
    R[a, a], R[c, c] = R[c, c], R[a, a]
    return z, R


class ManifoldSigmaPoints:
    """filterpy's sigma-point object (duck-typed) for states whose tangent dimension n differs from
    their width A: filterpy's ``MerweScaledSigmaPoints(n, α, β, κ)`` gives the weights and the
    offsets ξ_i on 0 ∈ Rⁿ (its Cholesky square root); the points are s̄ ⊞ ξ_i, one batch."""

    def __init__(self, model, alpha: float, beta: float, kappa: float):
        self.model = model
        self.offsets = MerweScaledSigmaPoints(model.tangent_dim, alpha, beta, kappa)
        self.Wm, self.Wc = self.offsets.Wm, self.offsets.Wc

    def num_sigmas(self) -> int:
        return self.offsets.num_sigmas()

    def offsets_at(self, P: np.ndarray) -> np.ndarray:
        """Covariance P (n, n) → the offsets ξ_i (2n + 1, n) of the sigma points, on 0 ∈ Rⁿ."""
        return self.offsets.sigma_points(np.zeros(self.model.tangent_dim), P)

    def sigma_points(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Mean x (A,), covariance P (n, n) → sigma points x ⊞ ξ_i (2n + 1, A)."""
        xi = torch.from_numpy(self.offsets_at(P))
        base = torch.from_numpy(x).expand(len(xi), -1)
        return self.model.boxplus(base, xi).numpy()


class _Rows:
    """filterpy's hx for precomputed measurements: filterpy's update calls hx once per sigma point,
    in order, so the i-th call returns row i."""

    def __init__(self, rows: np.ndarray):
        self.rows, self.next = rows, 0

    def __call__(self, _sigma_point: np.ndarray) -> np.ndarray:
        row = self.rows[self.next]
        self.next += 1
        return row


class BatchedUKF(UnscentedKalmanFilter):
    """filterpy's UnscentedKalmanFilter on tangent coordinates (x (A,), P and Q (n, n)) with f run on
    all sigma points as one batch (``batched``) or by filterpy's own per-point loop.

    Overrides ``compute_process_sigmas`` (the batch) and ``cross_variance`` (vectorised, with the
    manifold residual); :meth:`transform_states` is the unscented transform passed to ``predict``.
    ``repairs`` counts covariance repairs (read and reset by the caller).
    """

    def __init__(self, model, points: ManifoldSigmaPoints, batched: bool):
        self.model, self.batched, self.repairs = model, bool(batched), 0
        super().__init__(dim_x=model.dim, dim_z=int(np.prod(model.observation_shape)), dt=1.0, hx=None,
                         fx=self.fx_point, points=points, x_mean_fn=self.state_mean,
                         residual_x=self.state_residual, state_add=self.state_add)
        self.P = np.eye(model.tangent_dim)
        self.Q = np.eye(model.tangent_dim)

    # the state's mean, residual and add (filterpy's hooks), batched over rows
    def state_mean(self, sigmas: np.ndarray, Wm: np.ndarray) -> np.ndarray:
        """Mean (A,) of points (N, A) with weights Wm (N,) summing to 1 (any sign)."""
        return self.model.sigma_mean(torch.from_numpy(sigmas), torch.from_numpy(Wm)).numpy()

    def state_residual(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """a (N, A) or (A,) ⊟ b (A,) → (N, n) or (n,)."""
        rows = torch.from_numpy(np.atleast_2d(a))
        r = self.model.boxminus(rows, torch.from_numpy(b)).numpy()
        return r if a.ndim == 2 else r[0]

    def state_add(self, x: np.ndarray, dx: np.ndarray) -> np.ndarray:
        """x (A,) ⊞ dx (n,) → (A,)."""
        return self.model.boxplus(torch.from_numpy(x)[None], torch.from_numpy(dx)[None])[0].numpy()

    # f, h
    def fx_point(self, s: np.ndarray, dt: float) -> np.ndarray:
        """f of one sigma point (A,) (filterpy's per-point signature; dt is one frame)."""
        return self.model.mean_step(torch.from_numpy(s)[None])[0].numpy()

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        """χ'_i = f(s̄ ⊞ ξ_i): one batch, or filterpy's per-point loop when not ``batched``."""
        if not self.batched:
            return super().compute_process_sigmas(dt, fx, **fx_args)
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = self.model.mean_step(torch.from_numpy(sigmas)).numpy()

    def measure(self, sigmas: np.ndarray) -> np.ndarray:
        """h of sigma points (N, A) → (N, m): one batch, or one point per call when not ``batched``."""
        if self.batched:
            return self.model.measure(torch.from_numpy(sigmas)).numpy()
        return np.stack([self.model.measure(torch.from_numpy(s)[None])[0].numpy() for s in sigmas])

    # the unscented transform of states and the cross-covariance (filterpy's assume n = A)
    def transform_states(self, sigmas, Wm, Wc, noise_cov, mean_fn, residual_fn):
        """filterpy's UT signature: (mean (A,), Σ Wc_i r_i r_iᵀ + Q (n, n), repaired if need be),
        r_i = χ_i ⊟ mean."""
        x = mean_fn(sigmas, Wm)
        r = residual_fn(sigmas, x)
        P, repaired = repaired_covariance((r.T * Wc) @ r + noise_cov)
        self.repairs += repaired
        return x, P

    def cross_variance(self, x, z, sigmas_f, sigmas_h):
        """C = Σ_i Wc_i (χ_i ⊟ x)(Z_i − z)ᵀ: (n, m)."""
        return (self.state_residual(sigmas_f, x).T * self.Wc) @ (sigmas_h - z)


class UnscentedFilter(SequentialFilter):
    """The unscented Kalman filter over a prior with a Gaussian transition (module docstring).

    Args:
        model: a TrackingModel (its prior must have ``transition_covariance``: the diffusion and
            GPDM priors, not the Lie prior; its likelihood Gaussian), or any model keeping
            ``UNSCENTED_INTERFACE``.
        alpha, beta, kappa: Van der Merwe's sigma-point parameters (filterpy's).
        batched: f and h on all sigma points as one batch (True) or per point (filterpy's loop).
        gate_probability: p_gate of the validation gate (module docstring); 0 turns the gate off.
        reacquire: take a joint every camera has seen away from the estimate too long ungated (module
            docstring); off for a latent prior, which cannot move one joint alone (ukf-gpdm).
        swaps: undo a detector's left/right swaps before the gate (module docstring).
        branches: move an elbow one camera sees off its branch through the chest, and turn a person one camera
            alone sees to the facing their feet and face show (module docstring, "The branch no body takes", "The
            trunk's facing").

    It runs on the CPU in float64 (filterpy works in numpy): the model's tensors must be there.

    Attributes:
        kf: the :class:`BatchedUKF` (filterpy's state: ``kf.x`` (A,), ``kf.P`` (n, n)).
    """

    #: What the filter needs of a prior (priortrack.priors.registry): one Gaussian transition.
    requires = "gaussian"

    def __init__(self, model, alpha: float = ALPHA, beta: float = BETA, kappa: float = KAPPA, batched: bool = True,
                 gate_probability: float = GATE_PROBABILITY, reacquire: bool = True, swaps: bool = True,
                 branches: bool = True):
        if not alpha > 0:
            raise PriortrackError(f"alpha must be positive, got {alpha}")
        if not 0 <= gate_probability < 1:
            raise PriortrackError(f"gate_probability must be in [0, 1), got {gate_probability}")
        self.model = model
        self.unscented = unscented_form(model)
        n = self.unscented.tangent_dim
        if not n + kappa > 0:
            raise PriortrackError(f"kappa must exceed −n = {-n}, got {kappa}")
        self.kf = BatchedUKF(self.unscented, ManifoldSigmaPoints(self.unscented, alpha, beta, kappa), batched)
        self.gate_probability, self.reacquire, self.swaps = gate_probability, bool(reacquire), bool(swaps)
        self.branches = bool(branches)
        #: The gate's bound on a point's d² (inf without a gate).
        self.threshold = gate_threshold(gate_probability, self.unscented.measurement_block)
        self.initialised = False
        self.frame, self.gated_frames = 0, 0
        #: Between :meth:`advance` and :meth:`correct`: True, and h of the predicted sigma points (2n + 1, m) once
        #: read (:meth:`_sigma_measurements`).
        self._advanced, self._measured = False, None
        self._predict_seconds = 0.0
        #: (J,) per joint (an observation (…, J, coordinates); a flat one's points are J), the frames
        #: running in which every camera seeing it rejected it.
        shape = tuple(self.unscented.observation_shape)
        joints = shape[-2] if len(shape) >= 2 else int(np.prod(shape)) // self.unscented.measurement_block
        self.lost_frames = np.zeros(joints, dtype=int)
        #: (points,) the observed points (a joint in one camera, the observation's order) the last
        #: step's validation gate held out; None where the step had nothing to gate.
        self.held_out: np.ndarray | None = None
        #: (k,) the points the last step exchanged with their mirror partner (a detector's swap undone);
        #: None where it exchanged none.
        self.swapped: np.ndarray | None = None
        #: ln p(z_t | z_1:t−1) of the last update, the Gaussian predictive density N(z; ẑ, S) of the points it
        #: took, each point the gate held out counted at the density of the gate's boundary (its
        #: b-dimensional N at d² = χ²_b(1 − p_gate)): what a bank of these filters weighs its members by
        #: (:mod:`priortrack.filters.gaussian_sum`). 0 for a step without observations.
        self.log_evidence = 0.0
        #: (T, C, 3) per tick of the run (tick t is the step that makes frame t) and camera, the detector's forward
        #: direction in the image (:func:`~priortrack.geometry.facing.image_forward`: its feet and face), which
        #: turns a person one camera alone sees to their other facing (module docstring, "The trunk's facing");
        #: None: not used. Set by whoever feeds the filter real detections (:func:`~priortrack.tracking.person.prepared`).
        self.forward: np.ndarray | None = None
        #: The floor's height (the working frame's y) where one camera alone sees the person and the calibration says
        #: where the floor is: each update is followed by one observing the lower ankle on it (module docstring, "A foot
        #: on the floor"); None: not used. Set by :func:`~priortrack.tracking.person.prepared`.
        self.floor: float | None = None

    @property
    def mean(self) -> torch.Tensor:
        """The state estimate s̄ (A,)."""
        return torch.from_numpy(self.kf.x.copy())

    @property
    def covariance(self) -> torch.Tensor:
        """P (n, n), in the tangent coordinates at the mean."""
        return torch.from_numpy(self.kf.P.copy())

    def initialise(self, motion: Motion, start: int = 1) -> None:
        """Start at frame ``start`` of a known motion (pose, g_start, g_{start-1} exact) with the
        covariance of one transition from it, Q(s_start)."""
        s0 = self.model.initial_states(motion, 1, torch.Generator(), start)[0]
        self.initialise_states(s0, self.unscented.process_covariance(s0), start)

    def initialise_states(self, mean, covariance, frame: int = 0) -> None:
        """Start from a mean state (A,) and a covariance (n, n) in tangent coordinates at it."""
        A, n = self.unscented.dim, self.unscented.tangent_dim
        mean = torch.as_tensor(mean, dtype=torch.float64).cpu().numpy().copy()
        covariance = torch.as_tensor(covariance, dtype=torch.float64).cpu().numpy().copy()
        if mean.shape != (A,) or covariance.shape != (n, n):
            raise PriortrackError(f"initial mean {mean.shape} and covariance {covariance.shape}: expected ({A},) and ({n}, {n})")
        if not (np.isfinite(mean).all() and np.isfinite(covariance).all()):
            raise PriortrackError("initial mean or covariance contains NaN or inf")
        self.kf.x, self.kf.P = mean, covariance
        self.initialised, self.frame, self.gated_frames = True, frame, 0
        self.lost_frames[:] = 0

    def step(self, z) -> Snapshot:
        """Consume the observation z of the next frame (``observation_shape``, NaN where missing):
        :meth:`advance`, then :meth:`correct`.

        Returns a Snapshot whose particles are the posterior's 2n + 1 sigma points, weights their
        mean weights Wm (which may be negative), ess their count (they are not a weighted
        sample), estimate and best the observed joints of the mean state (the central sigma
        point), ancestors None; timings "predict", "weight" (the update), "estimate".

        The step runs on one torch thread and one BLAS thread (:data:`STEP_THREADS`): its operations are
        on 2n + 1 points and matrices of a few hundred rows, too small to split. Two torch threads cost
        2.8× the step's time on two idle cores (ukf-real, 4 cameras: 39.7 against 14.1 ms a step); with
        the other core busy, two BLAS threads made filterpy's inverse of S (150 × 150, 5 cameras) take
        130 ms instead of about 1.
        """
        z = self._checked(z)
        with torch_threads(STEP_THREADS), blas_threads(STEP_THREADS):
            self._advance()
            return self._correct(z)

    def advance(self) -> None:
        """The prediction half of a step: the sigma points through the transition, x̄⁻ and P⁻ (the
        scene tracker reads :meth:`predicted_measurement` before :meth:`correct` consumes the frame)."""
        with torch_threads(STEP_THREADS), blas_threads(STEP_THREADS):
            self._advance()

    def correct(self, z) -> Snapshot:
        """The update half of a step (after :meth:`advance`), with the frame's observation z; returns
        :meth:`step`'s Snapshot."""
        z = self._checked(z)
        with torch_threads(STEP_THREADS), blas_threads(STEP_THREADS):
            return self._correct(z)

    def predicted_measurement(self) -> tuple[np.ndarray, np.ndarray]:
        """After :meth:`advance`: every observed point's predicted pixels ẑ (…, 2) and their covariance
        P_zz (…, 2, 2) (``observation_shape[:-1]``: (C, 15) for C cameras; NaN where a sigma point is behind
        the camera), the unscented transform of the predicted sigma points (:func:`predicted_points`)."""
        if not self._advanced:
            raise PriortrackError("no prediction to read: call advance() first")
        measured = self._sigma_measurements()
        z_hat, P = predicted_points(measured.reshape(len(measured), -1, 2), self.kf.Wm, self.kf.Wc)
        shape = tuple(self.unscented.observation_shape)[:-1]
        return z_hat.reshape(shape + (2,)), P.reshape(shape + (2, 2))

    def _checked(self, z) -> np.ndarray:
        if not self.initialised:
            raise PriortrackError("the filter is not initialised: call initialise(motion) first")
        z = np.asarray(z, dtype=float)
        if z.shape != tuple(self.unscented.observation_shape):
            raise PriortrackError(f"observation has shape {z.shape}; expected {tuple(self.unscented.observation_shape)}")
        return z

    def _advance(self) -> None:
        if not self.initialised:
            raise PriortrackError("the filter is not initialised: call initialise(motion) first")
        kf = self.kf
        kf.repairs, self.held_out, self.swapped = 0, None, None
        t0 = time.perf_counter()
        kf.P, repaired = repaired_covariance(kf.P)
        kf.repairs += repaired
        kf.Q = self.unscented.process_covariance(torch.from_numpy(kf.x)).numpy()
        kf.predict(UT=kf.transform_states)
        self._advanced, self._measured = True, None
        self._predict_seconds = time.perf_counter() - t0

    def _sigma_measurements(self) -> np.ndarray:
        """h of each predicted sigma point (2n + 1, m), computed once a step where it is read (a frame without
        observations and without a reader of the prediction needs none)."""
        if self._measured is None:
            self._measured = self.kf.measure(self.kf.sigmas_f)
        return self._measured

    def _correct(self, z: np.ndarray) -> Snapshot:
        t1 = time.perf_counter()
        flags = self._corrected(z)
        return self._snapshot(flags, {"predict": self._predict_seconds, "weight": time.perf_counter() - t1})

    def _corrected(self, z: np.ndarray) -> list[str]:
        """The update half of a step without its Snapshot: the observation model's outlier gate, the
        measurement update (``kf.x``, ``kf.P``, :attr:`log_evidence`); returns the step's flags."""
        if not self._advanced:
            raise PriortrackError("no prediction to correct: call advance() first")
        kf, flags = self.kf, []
        self._faced(z, flags)
        gated, count = self.unscented.gate(z)
        if count:
            flags.append("outlier-gated")
            z = gated.numpy()
        values, R = self.unscented.measurement(torch.as_tensor(z, dtype=torch.float64))
        self._update(values.numpy(), R.numpy(), flags)
        self._on_the_floor(flags)
        self._advanced, self._measured = False, None
        if kf.repairs:
            flags.append("covariance-repaired")
        return flags

    def _snapshot(self, flags: list[str], timings: dict[str, float]) -> Snapshot:
        """:meth:`step`'s Snapshot of the filter's state (``kf.x``, ``kf.P``) after a step's update; ``timings``
        gains "estimate"."""
        kf, t2 = self.kf, time.perf_counter()
        sigmas = torch.from_numpy(kf.points_fn.sigma_points(kf.x, kf.P))
        estimate = self.unscented.observe(torch.from_numpy(kf.x)[None])[0]
        joints = self.unscented.observe(sigmas)
        t3 = time.perf_counter()
        self.frame += 1
        return Snapshot(self.frame, sigmas, torch.from_numpy(kf.Wm.copy()), float(len(sigmas)), None,
                        estimate.cpu().numpy(), estimate.cpu().numpy(), joints, flags,
                        {**timings, "estimate": t3 - t2},
                        mean=self.mean, covariance=self.covariance, held_out=self.held_out,
                        swapped=self.swapped)

    def _update(self, z: np.ndarray, R: np.ndarray, flags: list[str]) -> None:
        """The measurement update with z (m,) and R (m, m) on the observed coordinates that every sigma
        point can predict; then P in the coordinates at the new mean (Γ), repaired if need be. Sets
        :attr:`log_evidence`."""
        kf = self.kf
        self.log_evidence = 0.0
        seen = np.isfinite(z)
        if not seen.any():
            flags.append("no-observation")
            kf.update(None)
            return
        predicted = self._sigma_measurements()
        usable = seen & np.isfinite(predicted).all(axis=0)
        if (seen & ~usable).any():
            flags.append("behind-camera")
        if not usable.any():
            flags.append("no-observation")
            kf.update(None)
            return
        kept = usable
        if self.gate_probability:
            b = self.unscented.measurement_block
            z_hat, P = predicted_points(predicted.reshape(len(predicted), -1, b), kf.Wm, kf.Wc)   # every point's
            pairs = getattr(self.unscented, "mirror_pairs", None)
            if self.swaps and pairs is not None:
                z, R, swapped = swap_corrected(z, R, z_hat, P, pairs, len(self.lost_frames), b, self.threshold)
                if len(swapped):
                    flags.append("swap-corrected")
                    self.swapped = swapped
            kept = self._validated(z, R, z_hat, P, usable, flags)
        self.held_out = (usable & ~kept).reshape(-1, self.unscented.measurement_block).any(axis=1)
        usable = kept
        if not usable.any():
            kf.update(None)
            return
        self._updated(z[usable], R[np.ix_(usable, usable)], predicted[:, usable])
        self.log_evidence += float(kf.log_likelihood)
        self._off_the_trunk(usable, flags)

    def _updated(self, z: np.ndarray, R: np.ndarray, rows: np.ndarray) -> None:
        """filterpy's update of (``kf.x``, ``kf.P``) with z (k,), R (k, k) and h of ``kf.sigmas_f`` (2n + 1, k); then P
        in the coordinates at the new mean (Γ), repaired if need be."""
        kf = self.kf
        x_prior = kf.x.copy()
        kf.update(z, R=R, UT=unscented_transform, hx=_Rows(rows))
        gamma = self.unscented.transport(torch.from_numpy(x_prior), torch.from_numpy(kf.x)).numpy()
        kf.P, repaired = repaired_covariance(gamma @ kf.P @ gamma.T)
        kf.repairs += repaired

    def _faced(self, z: np.ndarray, flags: list[str]) -> None:
        """Before the update of frame ``self.frame + 1``: the predicted mean turned to the trunk's other facing where
        one camera alone sees the person and the detector's feet and face say so (:attr:`forward`;
        :meth:`UnscentedTracking.facing_turned`), its sigma points redrawn about it with the same covariance (flagged
        "facing-turned"; module docstring, "The trunk's facing")."""
        tick = self.frame + 1
        turn = getattr(self.unscented, "facing_turned", None)
        if turn is None or self.forward is None or not self.branches or tick >= len(self.forward):
            return
        turned = turn(self.kf.x, z, self.forward[tick])
        if turned is None:
            return
        kf = self.kf
        kf.x = turned[0]
        kf.sigmas_f = kf.points_fn.sigma_points(kf.x, kf.P)
        self._measured = None
        flags.append("facing-turned")
        log.debug("frame %d: the trunk turned %.0f° to the facing the detector's feet and face show", tick,
                  np.degrees(turned[1]))

    def _off_the_trunk(self, taken: np.ndarray, flags: list[str]) -> None:
        """After an update that took the coordinates ``taken`` (m,): each elbow of the mean inside the trunk and seen
        by one camera observed at its other depth branch, its wrist moved as little as the forearm allows and the
        trunk where it is (:meth:`UnscentedTracking.trunk_repairs`), σ = :data:`BRANCH_SIGMA_M` per coordinate, by a
        second update on sigma points redrawn from the posterior (flagged "branch-repaired"; module docstring). Its
        evidence is not the data's: :attr:`log_evidence` keeps the first."""
        repairs = getattr(self.unscented, "trunk_repairs", None)
        repairs = repairs(self.kf.x, taken) if repairs is not None and self.branches else []
        if not repairs:
            return
        kf = self.kf
        joints = [joint for joint, _ in repairs]
        kf.sigmas_f = kf.points_fn.sigma_points(kf.x, kf.P)
        rows = self.unscented.observe(torch.from_numpy(kf.sigmas_f))[:, joints].reshape(len(kf.sigmas_f), -1)
        rows = rows.cpu().numpy()
        target = np.concatenate([point for _, point in repairs])
        log.debug("frame %d: an elbow inside the trunk observed at its other depth branch (joints %s, %s m away)",
                  self.frame + 1, joints, np.round(np.linalg.norm((rows[0] - target).reshape(-1, 3), axis=-1), 3))
        self._updated(target, BRANCH_SIGMA_M ** 2 * np.eye(len(target)), rows)
        flags.append("branch-repaired")

    def _on_the_floor(self, flags: list[str]) -> None:
        """After the update: the mean's lower ankle observed :data:`ANKLE_HEIGHT` above :attr:`floor`, σ =
        :data:`FLOOR_SIGMA_M`, on sigma points redrawn from the posterior, the gain K = C / S (C the cross-covariance
        of the state's tangent coordinates with the ankle's height, S its predicted variance plus σ²) kept on the two
        placements' translations only (the floor places the body; the pixels shape it), P ← P − K Cᵀ − C Kᵀ + S K Kᵀ
        (the covariance of that gain); none where the predicted height is more than :data:`FLOOR_GATE_M` from the target
        (flagged "floor-contact"; module docstring). :attr:`log_evidence` keeps the data's."""
        if self.floor is None or self.unscented.mirror_pairs is None:
            return
        kf = self.kf
        x = torch.from_numpy(kf.x)
        sigmas = torch.from_numpy(kf.points_fn.sigma_points(kf.x, kf.P))
        lower = ANKLES[int(self.unscented.observe(x[None])[0, list(ANKLES), 1].argmin())]
        height = self.unscented.observe(sigmas)[:, lower, 1].cpu().numpy()          # (2n + 1,)
        predicted = float(kf.Wm @ height)
        e = height - predicted
        S = float(kf.Wc @ e ** 2) + FLOOR_SIGMA_M ** 2
        innovation = self.floor + ANKLE_HEIGHT - predicted
        if abs(innovation) > FLOOR_GATE_M:
            return
        C = self.unscented.boxminus(sigmas, x).numpy().T @ (kf.Wc * e)              # (n,)
        translations = np.zeros(self.unscented.tangent_dim, dtype=bool)             # g_t's and g_{t−1}'s t: (t, ω) each
        translations[-2 * GLOBAL_DIM:] = np.tile(np.arange(GLOBAL_DIM) < 3, 2)
        K = np.where(translations, C / S, 0.0)
        moved = self.unscented.boxplus(x[None], torch.from_numpy(K * innovation)[None])[0]
        P = kf.P - np.outer(K, C) - np.outer(C, K) + S * np.outer(K, K)
        gamma = self.unscented.transport(x, moved).numpy()
        kf.x = moved.numpy()
        kf.P, repaired = repaired_covariance(gamma @ P @ gamma.T)
        kf.repairs += repaired
        flags.append("floor-contact")

    def _validated(self, z: np.ndarray, R: np.ndarray, z_hat: np.ndarray, P: np.ndarray, usable: np.ndarray,
                   flags: list[str]) -> np.ndarray:
        """The validation gate (module docstring): ``usable`` (m,) without the points whose
        d²_k = ν_kᵀ S_kk⁻¹ ν_k exceeds χ²_b(1 − p_gate), ν = z − ẑ, S_kk = P_k + R_kk, with every point's
        predicted measurement ẑ (K, b) and its covariance P (K, b, b) (:func:`predicted_points`)."""
        b = self.unscented.measurement_block
        columns = np.flatnonzero(usable)
        points = columns.reshape(-1, b)[:, 0] // b
        S = P[points] + diagonal_blocks(R[np.ix_(columns, columns)], b)
        d2 = block_distances(z[columns].reshape(-1, b) - z_hat[points], S)
        rejected = d2 > self.threshold
        if self.reacquire:
            rejected &= ~self._reacquired(points, rejected, flags)
        if not rejected.any():
            self.gated_frames = 0
            return usable
        if rejected.all():
            self.gated_frames += 1
            if self.gated_frames > GATE_PATIENCE:
                self.gated_frames = 0
                flags.append("gate-reopened")
                return usable
        else:
            self.gated_frames = 0
        flags.append("innovation-gated")
        log.debug("frame %d: %d of %d observed points outside the validation gate", self.frame + 1,
                  int(rejected.sum()), len(rejected))
        kept = usable.copy()
        kept[columns.reshape(-1, b)[rejected].ravel()] = False
        self.log_evidence += float(np.sum(-0.5 * self.threshold - 0.5 * b * np.log(2 * np.pi)
                                          - 0.5 * np.linalg.slogdet(S[rejected])[1]))
        return kept

    def _reacquired(self, points: np.ndarray, rejected: np.ndarray, flags: list[str]) -> np.ndarray:
        """(K,) bool: the tested points (indices ``points`` (K,) in cameras × joints order) of the joints
        this frame takes ungated (module docstring: seen by two cameras or more, rejected in every one of
        them for more than ``GATE_PATIENCE`` frames running, until the gate takes it again); counts each
        joint's run of such frames."""
        J = len(self.lost_frames)
        joint = points % J
        seen = np.bincount(joint, minlength=J)
        lost = (seen >= 2) & (np.bincount(joint, weights=rejected, minlength=J) == seen)
        self.lost_frames = np.where(lost, self.lost_frames + 1, 0)
        again = self.lost_frames > GATE_PATIENCE
        if not again.any():
            return np.zeros(len(points), dtype=bool)
        flags.append("joint-reacquired")
        log.debug("frame %d: joints %s taken ungated after %d frames held out in every camera", self.frame + 1,
                  np.flatnonzero(again).tolist(), GATE_PATIENCE)
        return again[joint]

    def smooth_window(self, snapshots: list[Snapshot], observations, generator: torch.Generator,
                      **_particle_options) -> tuple[np.ndarray, np.ndarray, None]:
        """The iterated posterior-linearisation smoother over these steps and their observations (W, …)
        (:mod:`priortrack.filters.posterior_linearisation`, its sigma points at ``SMOOTHER_ALPHA``; the
        generator and the particle smoother's options are not needed): the joints of each smoothed
        mean (W, J, 3) and their spread over the smoothed Gaussian's sigma points, at the filter's α
        (W, J) (and no trajectories to count). Steps in a :class:`~priortrack.filters.step_store.StepStore`
        lend the smoother their memory budget for its own per-frame matrices too."""
        from priortrack.filters.posterior_linearisation import (FRAMES_AT_ONCE, SMOOTHER_ALPHA,
                                                                posterior_linearisation)
        from priortrack.filters.smoothing import gaussian_joints
        from priortrack.filters.step_store import Column, StepStore

        points = self.kf.points_fn
        local = ManifoldSigmaPoints(self.unscented, SMOOTHER_ALPHA, points.offsets.beta, points.offsets.kappa)
        means, covariances = posterior_linearisation(self.unscented, local, Column(snapshots, "mean", torch.Tensor.numpy),
                                                     Column(snapshots, "covariance", torch.Tensor.numpy), observations,
                                                     held_out=Column(snapshots, "held_out"),
                                                     swapped=Column(snapshots, "swapped"),
                                                     memory=snapshots.memory if isinstance(snapshots, StepStore) else None)
        try:
            return *gaussian_joints(self.unscented, points, means, covariances, FRAMES_AT_ONCE), None
        finally:
            covariances.close()
