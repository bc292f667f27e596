"""Inverse kinematics: 3D eval15 joint positions (a triangulation, another tool's output) → a Motion.

**Joint definitions.** The targets may follow a detector's definitions (pelvis = mid-hips, neck =
mid-shoulders: :func:`priortrack.data.keypoints.detector_map`, M); the body's own eval15 joints X are
then compared through M X. Without M, the targets are the body's eval15 joints themselves.

**The body.** A template skeleton (CMU subject 35's by default, whose channel layout every bundled
prior uses) is scaled to the targets: each eval15 bone (joint j to its parent) gets the factor
s = d_measured / d_template of the distance that measures it in the targets' definitions (medians
over frames; a limb's two sides averaged unless they differ beyond the noise of their medians, :func:`person_lengths`;
d_template the bone's own side, so that a template's own asymmetry, CMU 35's upper arms 3 % apart, is not carried to
someone else): upper arm, forearm, thigh and shin for the limbs, the
shoulder and hip widths for the neck→shoulder and pelvis→hip bones, mid-hips to mid-shoulders for the
trunk, mid-shoulders to the head for the head. The factor scales the rest offsets of the skeleton
joints on the bone's path (CMU's clavicles and neck both start at the thorax's end). A bone no frame
measures (a seated person's legs) takes the median factor of the measured ones.

**The pose.** The channels θ (T, C) minimise, over the frames at once,

    Σ_t Σ_j m_tj |(M FK(θ_t))_j − X_tj|² + λ Σ_t Σ_c w_c (θ_tc − θ̄_c)² + μ Σ_t |θ_t − θ_{t−1}|²,

m_tj = 0 where X_tj is NaN, λ = ``REGULARISATION`` a small pull to rest over the rotation channels c,
μ = ``SMOOTHNESS`` (consecutive frames alike: a joint missing in one frame follows its neighbours, and
the root does not jump where a frame lacks a limb). The pull fixes the dofs the 15 joints do not see
(wrist and foot twists, fingers) and chooses among the poses that fit them equally: w_c = 1, θ̄_c = 0;
or, given a prior's pose spread (:class:`PoseSpread`), below the root w_c = 1 / max(σ_c, ``SPREAD_FLOOR``)²
and θ̄_c its training motions' mean (on the channels they never move, CMU 35's clavicles, the person's own where
measured: :func:`own_posture`). A tracker's start takes the latter wherever its preset names
training motions: on a prior of joint angles a converged fit otherwise traded a back twist for clavicle
angles of a radian, which the walking priors' state leaves out (CMU 35's clavicles never move), and a
walk's track went from 6 to 22 mm; from one camera it chooses a limb's depth branch
(:func:`priortrack.tracking.person.pose_spread`). Solved by
Levenberg–Marquardt in float64 (:class:`_LevenbergMarquardt`; 200 iterations of torch's L-BFGS, used
before, stopped short of convergence and cost an import of torch's compiler stack). The start puts
the root at the pelvis and turns it about the vertical to the best of ``HEADINGS`` headings.
The world is Y-up, as the mocap the priors learned from (turn a Z-up calibration's world first:
:func:`priortrack.geometry.frames.to_y_up`).

**From one camera** (:func:`inverse_kinematics_2d`): the data term is the confidence-weighted
squared pixel error of the projected joints, scaled by (depth / f)² to metres at the subject; the
body is the template scaled to a given standing height; the start's root sits on the ray through
the detected pelvis at the depth where the body's size matches its image (f × neck-to-ankles
length / its length in pixels; for a body whose legs are never seen, the least such depth over the upper
body's lengths, which foreshortening can only lengthen). A pixel fixes a joint to its ray, so each limb has
two depth branches at the elbow or knee and two at the wrist or ankle (:mod:`priortrack.geometry.depth_branches`):
the fit from rest lands on whichever its start is nearest, so the fit is then started again from each limb's
other three branches (:meth:`OneCameraFit.over_branches`) and the least objective kept. A tracker's start
weighs the pixels by its robust likelihood's Student-t as well (:meth:`OneCameraFit.reweight`), so that a
detector's outlier does not bend the start.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np
import scipy.linalg
import torch

from priortrack.body.fk import ForwardKinematics
from priortrack.body.layout import eval15_indices
from priortrack.data.eval15 import EVAL15_PARENTS
from priortrack.data.motion import CONSTANT_CHANNEL_STD, Motion
from priortrack.data.skeleton import Skeleton
from priortrack.errors import PriortrackError
from priortrack.geometry.depth_branches import LIMBS, limb_branches
from priortrack.threads import torch_threads

log = logging.getLogger(__name__)

#: λ, the weight (m² per rad², or per σ_c²) of the pull of the rotation channels to rest.
REGULARISATION = 1e-4
#: The least spread σ_c (radians) of a channel in the pull to a prior's poses: the channels its training motions
#: never move (CMU 35's clavicles) are held there, not fixed.
SPREAD_FLOOR = 0.05
#: The spread σ_c (radians) of a person's own posture on the channels a prior's motions never move (CMU 35's
#: clavicles), in :func:`own_posture`'s fits: people's shoulder girdles rest some 10° apart.
OWN_POSTURE_SPREAD = 0.2
#: :func:`own_posture` fits at most this many windows of this many consecutive ticks.
POSTURE_WINDOWS, POSTURE_TICKS = 8, 8
#: μ, the weight (m² per unit of channel change) of the difference between consecutive frames.
SMOOTHNESS = 1e-2
#: Root headings tried for the start.
HEADINGS = 12
#: Rounds of reweighting of a robust one-camera fit (:meth:`OneCameraFit.reweight`).
REWEIGHTS = 3
#: torch threads of a fit: its tensors are small (a frame's ~30 joints × T), and with a second process on a
#: 2-core machine two threads took 40–308 s for a 120-frame fit that one thread does in 4–5 s (both threads
#: spin-waiting for a core the other process holds).
IK_THREADS = 1
#: Frames fitted together at most by :func:`inverse_kinematics`: a longer motion is fitted in consecutive
#: chunks (20 s at 30 fps), so that its memory does not grow with the motion (1,800 frames at once held
#: 590 MB, in chunks 517 MB); the smoothness term is not carried across a chunk's edge.
CHUNK = 600


#: eval15 bone (child joint) → the distance (a pair of joints, or of joint pairs' midpoints) that
#: measures it, with its mirror; by eval15 index.
_MEASURES = {
    1: (((9, 12), (3, 6)), None),                     # trunk: mid-hips to mid-shoulders
    2: (((3, 6), (2,)), None),                        # head: mid-shoulders to the head
    3: (((3,), (6,)), None), 6: (((3,), (6,)), None),  # shoulder width
    9: (((9,), (12,)), None), 12: (((9,), (12,)), None),  # hip width
    4: (((3,), (4,)), ((6,), (7,))), 7: (((3,), (4,)), ((6,), (7,))),        # upper arms
    5: (((4,), (5,)), ((7,), (8,))), 8: (((4,), (5,)), ((7,), (8,))),        # forearms
    10: (((9,), (10,)), ((12,), (13,))), 13: (((9,), (10,)), ((12,), (13,))),  # thighs
    11: (((10,), (11,)), ((13,), (14,))), 14: (((10,), (11,)), ((13,), (14,))),  # shins
}


def _distance(X: np.ndarray, pair) -> np.ndarray:
    a, b = (X[..., list(ends), :].mean(axis=-2) for ends in pair)
    return np.linalg.norm(a - b, axis=-1)


#: The eval15 joints whose bones are on the right: their own distance is the mirror pair of :data:`_MEASURES`.
_RIGHT = (7, 8, 13, 14)


def measured_distances(X: np.ndarray, own_side: bool = False) -> np.ndarray:
    """(14,) the median over frames X (T, 15, 3) of the distance measuring each eval15 bone (left and
    right averaged; with ``own_side``, each limb bone's own side alone), NaN frames left out; NaN for a bone no
    frame measures."""
    X = np.asarray(X, dtype=np.float64)
    out = np.full(14, np.nan)
    for j, (pair, mirror) in _MEASURES.items():
        if mirror is None:
            values = _distance(X, pair)
        elif own_side:
            values = _distance(X, mirror if j in _RIGHT else pair)
        else:
            values = np.concatenate([_distance(X, pair), _distance(X, mirror)])
        if np.isfinite(values).any():
            out[j - 1] = np.nanmedian(values)
    return out


def _median_error(values: np.ndarray) -> float:
    """The standard error of the median of a series (T,) (NaN left out): 1.2533 σ / √n_eff, σ = 1.4826 MAD, and
    n_eff = n (1 − ρ) / (1 + ρ) for the lag-1 autocorrelation ρ of consecutive measured frames (a detector's errors
    persist from frame to frame: Shelf's 0.55–0.87); inf with fewer than 3 values."""
    seen = values[np.isfinite(values)]
    if len(seen) < 3:
        return np.inf
    sigma = 1.4826 * np.median(np.abs(seen - np.median(seen)))
    pairs = np.isfinite(values[1:]) & np.isfinite(values[:-1])
    rho = 0.0
    if pairs.sum() > 2 and sigma > 0:
        a, b = values[:-1][pairs], values[1:][pairs]
        rho = float(np.clip(np.corrcoef(a, b)[0, 1], 0.0, 0.99)) if a.std() > 0 and b.std() > 0 else 0.0
    n_eff = max(len(seen) * (1 - rho) / (1 + rho), 1.0)
    return 1.2533 * sigma / np.sqrt(n_eff)


def person_lengths(X: np.ndarray) -> np.ndarray:
    """(14,) each eval15 bone's length for a person seen in X (T, 15, 3): :func:`measured_distances`' medians, left
    and right averaged, except a limb whose two sides' medians differ by more than twice their difference's standard
    error (:func:`_median_error`): it takes each side's own (a person's sides may differ; the noise of one side's
    median must not split them)."""
    X = np.asarray(X, dtype=np.float64)
    out = measured_distances(X)
    for j, (pair, mirror) in _MEASURES.items():
        if mirror is None or j in _RIGHT:
            continue
        left, right = _distance(X, pair), _distance(X, mirror)
        if not (np.isfinite(left).any() and np.isfinite(right).any()):
            continue
        gap = abs(np.nanmedian(left) - np.nanmedian(right))
        if gap > 2 * np.hypot(_median_error(left), _median_error(right)):
            out[j - 1], out[_RIGHT[(4, 5, 10, 11).index(j)] - 1] = np.nanmedian(left), np.nanmedian(right)
    return out


#: The body's distinct measures (module docstring), each named, by the eval15 joint whose bone it scales.
BODY_MEASURES = {"trunk": 1, "head": 2, "shoulder_width": 3, "hip_width": 9, "upper_arm": 4, "forearm": 5,
                 "thigh": 10, "shin": 11}


def _rest(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """The skeleton's joints in its rest pose (all channels 0), (N, 3), and its eval15 joints (15, 3)."""
    points = ForwardKinematics(skeleton, dtype=torch.float64)(np.zeros(skeleton.num_channels)).numpy()
    return points, points[eval15_indices(skeleton)]


def unmeasured_measures(X: np.ndarray) -> list[str]:
    """The names of :data:`BODY_MEASURES` that no frame of X (T, 15, 3) measures (:func:`fitted_skeleton`
    gives them the template's proportions)."""
    return _unmeasured(measured_distances(X))


def _unmeasured(distances: np.ndarray) -> list[str]:
    """The names of :data:`BODY_MEASURES` whose distance (of :func:`measured_distances`' 14) is NaN."""
    return [name for name, j in BODY_MEASURES.items() if not np.isfinite(distances[j - 1])]


def rest_distances(skeleton: Skeleton, joint_map: np.ndarray | None = None, own_side: bool = False) -> np.ndarray:
    """(14,) :func:`measured_distances` of the skeleton's rest pose, in the targets' definitions (``joint_map`` M
    applied)."""
    M = np.eye(15) if joint_map is None else np.asarray(joint_map, dtype=np.float64)
    return measured_distances((M @ _rest(skeleton)[1])[None], own_side)


def body_measures(skeleton: Skeleton, joint_map: np.ndarray | None = None) -> dict[str, float]:
    """{measure: metres} of :data:`BODY_MEASURES` on the skeleton's rest pose, in the targets'
    definitions (``joint_map`` M applied): the body a tracker fitted, as a person would measure it (a limb's
    left and right averaged; :func:`limb_sides` gives each)."""
    distances = rest_distances(skeleton, joint_map)
    return {name: float(distances[j - 1]) for name, j in BODY_MEASURES.items()}


#: The limb measures of :data:`BODY_MEASURES`, by their left and right eval15 joints.
LIMB_SIDES = {"upper_arm": (4, 7), "forearm": (5, 8), "thigh": (10, 13), "shin": (11, 14)}


def limb_sides(skeleton: Skeleton, joint_map: np.ndarray | None = None) -> dict[str, list[float]]:
    """{limb: [left, right] metres} of the skeleton's rest pose (:data:`LIMB_SIDES`), in the targets' definitions."""
    distances = rest_distances(skeleton, joint_map, own_side=True)
    return {name: [float(distances[a - 1]), float(distances[b - 1])] for name, (a, b) in LIMB_SIDES.items()}


def fitted_skeleton(template: Skeleton, X: np.ndarray, joint_map: np.ndarray | None = None) -> Skeleton:
    """The template scaled so that its distances (module docstring) match those of the targets X
    (T, 15, 3), both in the targets' definitions (``joint_map`` M applied to the template). A bone no
    frame measures (legs under a desk, seen by one camera or none) is scaled as the measured ones are (their
    median ratio to the template's: its proportions), logged; none measured is refused."""
    index = eval15_indices(template)
    offsets = template.offsets.copy()
    points, rest = _rest(template)
    M = np.eye(15) if joint_map is None else np.asarray(joint_map, dtype=np.float64)
    measured = person_lengths(X)                                      # each side's length …
    scale = measured / measured_distances((M @ rest)[None], own_side=True)   # … given to that side of the template
    unmeasured = ~np.isfinite(scale)
    if unmeasured.all():
        raise PriortrackError("body size: no bone is measured (no frame has both ends of any eval15 bone)")
    if unmeasured.any():
        scale[unmeasured] = np.median(scale[~unmeasured])
        log.info("body size: %s never measured; scaled ×%.3f as the measured bones are (the template's "
                 "proportions)", ", ".join(_unmeasured(measured)), scale[unmeasured][0])
    for j in range(1, 15):
        parent = EVAL15_PARENTS[j]
        chain, k = [], int(index[j])
        while k > 0 and np.linalg.norm(points[k] - rest[parent]) > 1e-9:
            chain.append(k)
            k = int(template.parents[k])
        if np.linalg.norm(points[k] - rest[parent]) > 1e-9:
            raise PriortrackError(f"skeleton {template.name!r}: eval15 joint {j} is not below its parent")
        offsets[chain] *= scale[j - 1]
    return replace(template, offsets=offsets, name=f"{template.name}-fitted")


def inverse_kinematics(X: np.ndarray, fps: float, template: Skeleton | None = None, name: str = "ik",
                       joint_map: np.ndarray | None = None, skeleton: Skeleton | None = None,
                       pose: PoseSpread | None = None, weights: np.ndarray | None = None) -> Motion:
    """A Motion whose eval15 joints (through ``joint_map`` M, if given) best match X (T, 15, 3) metres in
    a Y-up world (NaN = unknown), each joint's squared error times its weight (``weights`` (T, 15), None: 1; m_tj of
    the module docstring), on ``skeleton``, or else the template (default: CMU subject 35)
    scaled to X (:func:`fitted_skeleton`); the pull to rest is ``pose``'s, if given (module docstring)."""
    if template is None:
        from priortrack.data.bundled import cmu_skeleton

        template = cmu_skeleton("35")
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 3 or X.shape[1:] != (15, 3) or len(X) < 1:
        raise PriortrackError(f"inverse kinematics: joints have shape {X.shape}; expected (T, 15, 3)")
    if np.isinf(X).any():
        raise PriortrackError("inverse kinematics: joints contain inf")
    if weights is not None and (np.shape(weights) != X.shape[:2] or not np.all(np.isfinite(weights))
                                or np.any(np.asarray(weights) < 0)):
        raise PriortrackError(f"inverse kinematics: weights must be finite, non-negative and of shape {X.shape[:2]} "
                              f"(one per joint and frame), got shape {np.shape(weights)}")
    seen = np.isfinite(X).all(axis=-1)
    if (seen.sum(axis=1) < 6).any():
        raise PriortrackError(f"inverse kinematics: frames {np.flatnonzero(seen.sum(axis=1) < 6).tolist()} have "
                              f"fewer than 6 known joints")
    M = np.eye(15) if joint_map is None else np.asarray(joint_map, dtype=np.float64)
    skeleton = skeleton or fitted_skeleton(template, X, M)
    pelvis = X[:, 0].copy()                      # where it is unseen, the mean of the joints seen (those rows only)
    pelvis[~seen[:, 0]] = np.nanmean(X[~seen[:, 0]], axis=1)
    channels = np.empty((len(X), skeleton.num_channels))
    for start in range(0, len(X), CHUNK):
        part = slice(start, min(start + CHUNK, len(X)))
        channels[part] = _fit(skeleton, part.stop - part.start,
                              _joint_residuals(X[part], None if weights is None else weights[part]), pelvis[part], M, pose)
    return Motion(skeleton, channels, float(fps), name)


def refit_to_joints(X: np.ndarray, theta: np.ndarray, skeleton: Skeleton, joint_map: np.ndarray | None = None,
                    pose: PoseSpread | None = None) -> np.ndarray:
    """Channels (T, C) of ``skeleton`` whose eval15 joints (through ``joint_map`` M) best match X (T, 15, 3)
    (NaN = unknown), from channels ``theta`` (T, C) near them: :func:`inverse_kinematics`'s objective without
    its search for a start (one chunk: T ≤ ``CHUNK``)."""
    X = np.asarray(X, dtype=np.float64)
    M = np.eye(15) if joint_map is None else np.asarray(joint_map, dtype=np.float64)
    return _fit(skeleton, len(X), _joint_residuals(X), X[:, 0], M, pose, theta)


def _joint_residuals(X: np.ndarray, weights: np.ndarray | None = None):
    """The residual closure (joints, frames) → r of joint targets X (F, 15, 3), NaN rows left out, each row times the
    square root of its weight (``weights`` (F, 15), None: 1)."""
    seen = np.isfinite(X).all(axis=-1)
    target = torch.as_tensor(np.where(seen[..., None], X, 0.0))
    mask = torch.as_tensor(np.where(seen, 1.0 if weights is None else np.sqrt(weights), 0.0))[..., None]
    return lambda joints, frames: ((joints - target[frames]) * mask[frames]).flatten(-2)


def check_height(height: float) -> None:
    """A person's standing height in metres, or a PriortrackError naming what it must be."""
    if not isinstance(height, (int, float)) or isinstance(height, bool) or not 0.5 < height < 2.6:
        raise PriortrackError(f"height must be a person's standing height in metres (0.5–2.6), got {height}")


def scaled_to_height(template: Skeleton, height: float) -> Skeleton:
    """The template scaled uniformly so that its rest pose's head top stands ``height`` metres above its
    lower ankle (a detector's ankle, not the sole: about 5 cm short of the standing height)."""
    check_height(height)
    return replace(template, offsets=template.offsets * (height - ANKLE_HEIGHT) / (stature(template) - ANKLE_HEIGHT),
                   name=f"{template.name}-{height:g}m")


def stature(skeleton: Skeleton) -> float:
    """The skeleton's standing height, metres: its rest pose's head top above its lower ankle, and the ankle's
    :data:`ANKLE_HEIGHT` above the floor (what :func:`scaled_to_height` scales to)."""
    rest = ForwardKinematics(skeleton, dtype=torch.float64)(np.zeros(skeleton.num_channels))[
        eval15_indices(skeleton)].numpy()
    return float(rest[2, 1] - min(rest[11, 1], rest[14, 1]) + ANKLE_HEIGHT)


#: Height of a detector's ankle point above the floor, metres.
ANKLE_HEIGHT = 0.07


def inverse_kinematics_2d(uv: np.ndarray, weights: np.ndarray, camera, fps: float, skeleton: Skeleton,
                          joint_map: np.ndarray | None = None, name: str = "ik",
                          pose: PoseSpread | None = None, robust: tuple[float, float] | None = None) -> Motion:
    """A Motion of ``skeleton`` whose eval15 joints (through ``joint_map`` M) project through ``camera``
    (a Y-up world) onto uv (T, 15, 2) pixels, weighted by ``weights`` (T, 15) (0 = unseen); the pull to rest
    is ``pose``'s, if given: :class:`OneCameraFit` from the rest pose; with ``robust`` = (σ px, ν), reweighted
    :data:`REWEIGHTS` times by that Student-t (:meth:`OneCameraFit.reweight`); then over the limbs' depth branches."""
    fit = OneCameraFit(uv, weights, camera, skeleton, joint_map, pose)
    theta = fit.fit()
    if robust is not None:
        for _ in range(REWEIGHTS):
            fit.reweight(theta, *robust)
            theta = fit.fit(theta)
    return Motion(skeleton, fit.over_branches(theta), float(fps), name)


class OneCameraFit:
    """The one-camera problem of :func:`inverse_kinematics_2d` (module docstring): uv (T, 15, 2) pixels through
    ``camera`` (a Y-up world), weighted by ``weights`` (T, 15) (0 = unseen), on ``skeleton`` through ``joint_map``
    M, pulled to ``pose``'s spread; :meth:`fit` from rest or from given channels, :meth:`cost` its objective."""

    def __init__(self, uv: np.ndarray, weights: np.ndarray, camera, skeleton: Skeleton,
                 joint_map: np.ndarray | None = None, pose: PoseSpread | None = None):
        uv, weights = np.asarray(uv, dtype=np.float64), np.asarray(weights, dtype=np.float64)
        seen = np.isfinite(uv).all(axis=-1) & (weights > 0)
        if uv.ndim != 3 or uv.shape[1:] != (15, 2) or weights.shape != uv.shape[:2]:
            raise PriortrackError(f"inverse kinematics: pixels {uv.shape} and weights {weights.shape}; expected "
                                  f"(T, 15, 2) and (T, 15)")
        if (seen.sum(axis=1) < 6).any():
            raise PriortrackError(f"inverse kinematics from one camera: frames "
                                  f"{np.flatnonzero(seen.sum(axis=1) < 6).tolist()} have fewer than 6 detected joints")
        self.M = np.eye(15) if joint_map is None else np.asarray(joint_map, dtype=np.float64)
        self.skeleton, self.camera, self.pose = skeleton, camera, pose
        index = eval15_indices(skeleton)
        rest = self.M @ ForwardKinematics(skeleton, dtype=torch.float64)(np.zeros(skeleton.num_channels))[index].numpy()
        depth = camera.fx * _metres_per_pixel(rest, uv, seen)
        K = camera.K.double().numpy()
        R, t = camera.R.double().numpy(), camera.t.double().numpy()
        centre = np.where(seen[:, :1], uv[:, 0], np.nanmean(np.where(seen[..., None], uv, np.nan), axis=1))
        ray = np.linalg.solve(K, np.concatenate([centre, np.ones((len(uv), 1))], axis=1).T).T          # (T, 3)
        self.pelvis = (ray * depth - t) @ R                                          # R^T (X_c − t), per row
        self.target = torch.as_tensor(np.where(seen[..., None], uv, 0.0))
        self.confidence = torch.as_tensor(np.where(seen, weights, 0.0))
        self.rho = torch.ones_like(self.confidence)
        scale = (depth / camera.fx) ** 2

        def residuals(joints: torch.Tensor, frames: slice) -> torch.Tensor:
            w = (self.confidence[frames] * self.rho[frames])[..., None] * scale
            return (self.pixel_errors(joints, frames) * w.sqrt()).flatten(-2)

        self.problem = _LevenbergMarquardt(skeleton, len(uv), residuals, self.M, pose)

    def pixel_errors(self, joints: torch.Tensor, frames: slice = slice(None)) -> torch.Tensor:
        """(..., F, 15, 2) the projected joints (..., F, 15, 3) of the frames ``frames`` less their pixels (0 behind
        the camera; unseen joints are cancelled by their zero weight)."""
        projected, _ = self.camera.project(joints)
        return torch.where(torch.isfinite(projected), projected - self.target[frames], 0.0)

    def reweight(self, theta: np.ndarray, sigma_px: float, nu: float) -> None:
        """Each joint's weight times the Student-t's ρ_tj = (ν + 2) / (ν + ‖e_tj‖² / σ²) at the pixel errors e_tj of
        channels θ (T, C), as the tracker's robust likelihood weighs a point (iteratively reweighted least
        squares): a detector's outlier 50–150 px off bends the start's pose less towards it."""
        e = self.pixel_errors(torch.as_tensor(self.joints(theta)))
        self.rho = (nu + 2) / (nu + (e ** 2).sum(-1) / sigma_px ** 2)

    def fit(self, theta: np.ndarray | None = None) -> np.ndarray:
        """Channels θ (T, C) minimising the objective, from ``theta`` (T, C) or else from the rest pose at the
        pelvis's ray (:meth:`_LevenbergMarquardt.start`)."""
        with torch_threads(IK_THREADS):
            return self.problem.fit(self.pelvis, theta)

    def cost(self, theta: np.ndarray) -> float:
        """The objective (module docstring) at channels θ (T, C)."""
        with torch_threads(IK_THREADS):
            return self.problem.objective(theta, self.problem.data(theta))

    def joints(self, theta: np.ndarray) -> np.ndarray:
        """(T, 15, 3) the joints M FK(θ) that the pixels are compared with, in the camera's world."""
        return self.problem.joints(np.asarray(theta, dtype=np.float64)).numpy()

    def over_branches(self, theta: np.ndarray) -> np.ndarray:
        """The channels (T, C) of the least objective over the limbs' depth branches, from a fit θ (T, C): limb
        by limb (:data:`~priortrack.geometry.depth_branches.LIMBS`), each of its other three branches
        (:func:`~priortrack.geometry.depth_branches.limb_branches` of M FK(θ)) as 3D targets
        (:func:`refit_to_joints` from θ), the one-camera fit from there, and θ ← the best of them where it lowers
        the objective. From rest, the fit lands on whichever branch the pull meets first: on two held-out walks
        through one real camera's view a start 125 and 105 mm off root-relative, 98 and 72 mm after this."""
        centre = self.camera.center.double().numpy()
        cost = self.cost(theta)
        for limb in LIMBS:
            for targets in limb_branches(self.joints(theta), centre, limb):
                trial = self.fit(refit_to_joints(targets, theta, self.skeleton, self.M, self.pose))
                trial_cost = self.cost(trial)
                if trial_cost < cost:
                    theta, cost = trial, trial_cost
        return theta


#: The image lengths that give a body's depth from one camera, as eval15 joint pairs: neck to mid-ankles; else,
#: for a body whose legs are never seen, the upper body's (shoulder width, neck to head, upper arms, forearms).
_FULL_LENGTH = ((1,), (11, 14))
_UPPER_LENGTHS = (((3,), (6,)), ((1,), (2,)), ((3,), (4,)), ((6,), (7,)), ((4,), (5,)), ((7,), (8,)))


def _metres_per_pixel(rest: np.ndarray, uv: np.ndarray, seen: np.ndarray) -> float:
    """depth / f of a body whose rest joints are ``rest`` (15, 3) seen at uv (T, 15, 2) (``seen`` (T, 15)):
    the median over frames of L / ℓ, L a length on the body, ℓ its image. Neck to mid-ankles where the frames
    show it. Else each frame's least L / ℓ over the upper body's lengths: a length turned away from the image
    plane looks shorter, ℓ = (f / depth) L cos φ, so each ratio bounds depth / f from above and the least is
    the tightest (arms along the image plane, shoulders facing the camera)."""
    def ratios(pair) -> np.ndarray:
        a, b = (list(ends) for ends in pair)
        shown = seen[:, a + b].all(axis=1)
        image = np.linalg.norm(uv[:, a].mean(axis=1) - uv[:, b].mean(axis=1), axis=-1)
        body = np.linalg.norm(rest[a].mean(axis=0) - rest[b].mean(axis=0))
        return np.divide(body, image, out=np.full(len(image), np.nan), where=shown & (image >= 1))

    full = ratios(_FULL_LENGTH)
    if np.isfinite(full).any():
        return float(np.nanmedian(full))
    upper = np.stack([ratios(pair) for pair in _UPPER_LENGTHS], axis=1)               # (T, 6)
    least = np.where(np.isfinite(upper), upper, np.inf).min(axis=1)                  # inf: no length in the frame
    if np.isinf(least).all():
        raise PriortrackError("inverse kinematics from one camera: neither the neck and both ankles nor any length "
                              "of the upper body (shoulders, neck to head, arms) is ever seen: no depth for the body")
    return float(np.median(least[np.isfinite(least)]))


@dataclass(frozen=True)
class PoseSpread:
    """θ̄ (C,) and σ (C,): the mean and standard deviation of each channel over a prior's training motions,
    in the channel layout they share with the skeleton fitted (CMU subject 35's for every bundled prior)."""

    mean: np.ndarray
    std: np.ndarray

    @classmethod
    def of(cls, motions) -> PoseSpread:
        """The spread of ``motions`` (a non-empty sequence of Motions with one channel layout)."""
        layouts = {m.skeleton.channel_names for m in motions}
        if len(layouts) != 1:
            raise PriortrackError(f"pose spread: the motions have {len(layouts)} channel layouts; expected one")
        channels = np.concatenate([m.channels for m in motions])
        return cls(channels.mean(axis=0), channels.std(axis=0))


def own_posture(X: np.ndarray, fps: float, skeleton: Skeleton, pose: PoseSpread,
                joint_map: np.ndarray | None = None, source: str = "own posture") -> PoseSpread:
    """``pose`` with the person's own posture where its motions have none: on the channels they never move (σ_c
    below :data:`~priortrack.data.motion.CONSTANT_CHANNEL_STD`: CMU 35's clavicles), the median over the fitted
    frames of those channels, fitted by :func:`inverse_kinematics` to the joints X (T, 15, 3) (through
    ``joint_map``) with them pulled only at :data:`OWN_POSTURE_SPREAD`, over at most :data:`POSTURE_WINDOWS`
    windows of :data:`POSTURE_TICKS` consecutive ticks that see every joint, spread over the trial. The start's
    fit then holds them there, as it holds the others near the motions' mean; an angle prior keeps them as the
    start leaves them (:meth:`~priortrack.priors.spaces.AngleSpace.for_body`). Held at CMU 35's, subject 39's
    shoulders were out of reach: the angle presets tracked their walk at 1.2–1.7× per-frame triangulation,
    flagged on every tick. From one window's fit (the start's) rather than the median over the trial's, Shelf's
    people came out with clavicles turned 60–130°. ``pose`` itself where no window sees every joint. Logged under
    ``source`` (whose person it is)."""
    never = np.zeros(skeleton.num_channels, dtype=bool)
    never[moving_channels(skeleton, eval15_indices(skeleton))] = True          # those a fit can measure …
    never &= pose.std < CONSTANT_CHANNEL_STD                                    # … that the motions never move
    never[skeleton.root_channels] = False
    every = np.isfinite(X).all(axis=-1).all(axis=-1)
    runs = np.convolve(every, np.ones(POSTURE_TICKS), mode="valid") == POSTURE_TICKS     # a window from tick t
    starts = np.flatnonzero(runs)
    if not never.any() or not len(starts):
        log.info("%s: %s", source, "no posture of its own to measure" if not never.any() else
                 f"no {POSTURE_TICKS} consecutive ticks see every joint; the motions' posture kept")
        return pose
    starts = starts[np.unique(np.linspace(0, len(starts) - 1, POSTURE_WINDOWS).round().astype(int))]
    loose = replace(pose, std=np.where(never, OWN_POSTURE_SPREAD, pose.std))
    values = np.concatenate([inverse_kinematics(X[t:t + POSTURE_TICKS], fps, joint_map=joint_map, skeleton=skeleton,
                                                pose=loose).channels[:, never] for t in starts])
    own = np.median(values, axis=0)
    ticks = len(np.unique(starts[:, None] + np.arange(POSTURE_TICKS)))
    log.info("%s: its own posture over %d ticks: %s", source, ticks, ", ".join(
        f"{name} {np.degrees(v):+.0f}°" for name, v in zip(np.asarray(skeleton.channel_names)[never], own)))
    mean = pose.mean.copy()
    mean[never] = own
    return replace(pose, mean=mean)


def pull(skeleton: Skeleton, pose: PoseSpread | None) -> tuple[np.ndarray, np.ndarray]:
    """The pull to rest's weights λ w_c (C,) and centres θ̄_c (C,) (module docstring): λ and 0 on every
    rotation channel; with ``pose``, λ / max(σ_c, ``SPREAD_FLOOR``)² and θ̄_c on those below the root."""
    rotation = np.ones(skeleton.num_channels, dtype=bool)
    rotation[skeleton.trans_channels[skeleton.trans_channels >= 0]] = False
    weights, centre = np.where(rotation, REGULARISATION, 0.0), np.zeros(skeleton.num_channels)
    if pose is None:
        return weights, centre
    if pose.mean.shape != (skeleton.num_channels,):
        raise PriortrackError(f"pose spread of {pose.mean.shape[0]} channels for skeleton {skeleton.name!r}'s "
                              f"{skeleton.num_channels}")
    body = rotation.copy()
    body[skeleton.rot_channels[0][skeleton.rot_channels[0] >= 0]] = False
    weights[body] = REGULARISATION / np.maximum(pose.std[body], SPREAD_FLOOR) ** 2
    centre[body] = pose.mean[body]
    return weights, centre


def _fit(skeleton: Skeleton, T: int, residuals, pelvis: np.ndarray, M: np.ndarray,
         pose: PoseSpread | None, theta: np.ndarray | None = None) -> np.ndarray:
    """Channels θ (T, C) minimising |r(M FK(θ))|² + the regularisation and smoothness (module docstring),
    from ``theta`` (T, C) if given, else from the root at ``pelvis`` (T, 3) turned to the best of HEADINGS
    headings, on IK_THREADS torch threads.
    ``residuals(joints, frames)`` maps joints (..., F, 15, 3) of the frames ``frames`` (a slice of the T) to their
    data residuals r (..., F, R)."""
    with torch_threads(IK_THREADS):
        return _LevenbergMarquardt(skeleton, T, residuals, M, pose).fit(pelvis, theta)


class _LevenbergMarquardt:
    """The fit of :func:`_fit` by Levenberg–Marquardt over the channels that move an eval15 joint. The others
    stay at 0, as before under L-BFGS: they move no joint, and their term of the objective is the pull alone
    (its optimum 0, or θ̄_c with a pose spread).

    With J_t (R, K) the Jacobian of frame t's residuals r_t over those K channels (forward differences:
    K + 1 FK rows a frame, ``JACOBIAN_FRAMES`` frames at a time), each step solves

        (A + ν D) δ = −g,   A = blockdiag(J_tᵀ J_t) + λ I_rot + μ L ⊗ I_K,   g = Jᵀ r + λ θ_rot + μ L θ,

    D = diag A + ``DAMPING_FLOOR`` × its mean, L the (T, T) path Laplacian of the smoothness (1 at the ends, 2
    inside, −1 beside): A is banded with bandwidth K (unknowns frame by frame), one banded Cholesky a step. A
    step that lowers the objective is taken and ν shrinks; else ν grows. Stops after a step that lowers the
    objective by less than ``TOLERANCE`` per data residual, or after ``MAX_STEPS``."""

    #: Forward-difference step of the Jacobian, radians or metres.
    STEP = 1e-7
    #: A step lowering the objective by less than this per data residual ((0.1 mm)², m²) ends the fit: on a
    #: tracked 12 s balance (359 ticks) 0.8 s, and 100 steps move its joints by 0.05 mm RMS more in 2.6 s.
    TOLERANCE = 1e-8
    #: Start of the damping ν, and the damping past which no step is tried.
    DAMPING, MAX_DAMPING = 1.0, 1e10
    #: The damping's scale is diag A plus this fraction of its mean: with diag A alone, steps ran along the
    #: directions the targets barely fix (a twist held by the pull to rest only) into worse minima (a tracked
    #: 12 s balance: 0.86 against 0.69; a caliscope start from ν = 10⁻³: 0.19 against 0.041).
    DAMPING_FLOOR = 0.3
    #: Levenberg–Marquardt steps at most.
    MAX_STEPS = 100
    #: Frames whose Jacobian is taken at once (their K + 1 = 45 shifted copies through the FK): a whole 600-frame
    #: chunk at once held 134 MB more than its fit otherwise needs.
    JACOBIAN_FRAMES = 100

    def __init__(self, skeleton: Skeleton, T: int, residuals, M: np.ndarray, pose: PoseSpread | None):
        self.skeleton, self.T, self.residuals = skeleton, T, residuals
        self.fk = ForwardKinematics(skeleton, dtype=torch.float64)
        self.index = eval15_indices(skeleton)
        self.M = torch.as_tensor(M)
        self.moving = moving_channels(skeleton, self.index)
        self.weights, self.centre = pull(skeleton, pose)                        # (C,) λ w_c, θ̄_c
        self.lam = self.weights[self.moving]

    def joints(self, theta: np.ndarray) -> torch.Tensor:
        """M FK(θ) (..., F, 15, 3) of channels θ (..., F, C)."""
        joints = self.fk(torch.as_tensor(theta.reshape(-1, theta.shape[-1])), joints=self.index)
        return torch.einsum("ij,bjk->bik", self.M, joints).reshape(*theta.shape[:-1], 15, 3)

    def data(self, theta: np.ndarray, frames: slice = slice(None)) -> np.ndarray:
        """r (..., F, R) of channels θ (..., F, C) of the frames ``frames``."""
        return self.residuals(self.joints(theta), frames).numpy()

    def objective(self, theta: np.ndarray, r: np.ndarray) -> float:
        return float((r ** 2).sum() + (self.weights * (theta - self.centre) ** 2).sum()
                     + SMOOTHNESS * ((theta[1:] - theta[:-1]) ** 2).sum())

    def start(self, pelvis: np.ndarray) -> np.ndarray:
        """θ (T, C) of the best of HEADINGS root headings, the root at ``pelvis``."""
        skeleton = self.skeleton
        heading_slot = int(np.argmax(np.abs(skeleton.rot_axes[0, :, 1])))           # the root's turn about y
        heading_channel = int(skeleton.rot_channels[0, heading_slot])
        rest = (self.M.numpy() @ self.fk(np.zeros(skeleton.num_channels), joints=self.index).numpy())[0]
        theta = np.zeros((HEADINGS, self.T, skeleton.num_channels))
        theta[..., skeleton.trans_channels[0]] = pelvis - rest
        if heading_channel >= 0:
            theta[..., heading_channel] = (2 * math.pi * np.arange(HEADINGS) / HEADINGS)[:, None]
        r = self.data(theta)
        return theta[int(np.argmin([self.objective(th, rh) for th, rh in zip(theta, r)]))]

    def normal_equations(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """r (T, R) at θ, and each frame's J_tᵀ J_t (T, K, K) and J_tᵀ r_t (T, K), J_t (R, K) over the moving
        channels by forward differences, ``JACOBIAN_FRAMES`` frames at a time (their K + 1 shifted copies)."""
        K = len(self.moving)
        r, JJ, Jr = None, np.empty((self.T, K, K)), np.empty((self.T, K))
        for start in range(0, self.T, self.JACOBIAN_FRAMES):
            frames = slice(start, min(start + self.JACOBIAN_FRAMES, self.T))
            shifted = np.repeat(theta[None, frames], K + 1, axis=0)                 # (K + 1, F, C)
            shifted[np.arange(1, K + 1), :, self.moving] += self.STEP
            rows = self.data(shifted, frames)
            J = np.moveaxis((rows[1:] - rows[0]) / self.STEP, 0, -1)              # (F, R, K)
            if r is None:
                r = np.empty((self.T, rows.shape[-1]))
            r[frames] = rows[0]
            JJ[frames] = np.einsum("trk,trl->tkl", J, J)
            Jr[frames] = np.einsum("trk,tr->tk", J, rows[0])
        return r, JJ, Jr

    def solve(self, blocks: np.ndarray, g: np.ndarray, nu: float) -> tuple[np.ndarray, float]:
        """δ (T, K) of (A + ν D) δ = −g, A from its diagonal blocks (T, K, K) and the smoothness, and the
        decrease of the objective that the Gauss–Newton model predicts for it, −gᵀδ + ν δᵀ D δ."""
        T, K = g.shape
        degree = np.full(T, 2.0)
        degree[[0, -1]] = 1.0 if T > 1 else 0.0
        bands = np.zeros((K + 1, T * K))                                          # lower banded storage
        for d in range(K):
            bands[d].reshape(T, K)[:, :K - d] = np.diagonal(blocks, offset=-d, axis1=1, axis2=2)
        bands[0] += (SMOOTHNESS * degree[:, None]).repeat(K, axis=1).ravel()
        diagonal = bands[0] + self.DAMPING_FLOOR * bands[0].mean()
        bands[0] += nu * diagonal
        bands[K, :(T - 1) * K] = -SMOOTHNESS
        delta = scipy.linalg.solveh_banded(bands, -g.ravel(), lower=True)
        return delta.reshape(T, K), float(-g.ravel() @ delta + nu * (delta * diagonal) @ delta)

    def fit(self, pelvis: np.ndarray, theta: np.ndarray | None = None) -> np.ndarray:
        """θ (T, C) from ``theta`` (T, C), else from :meth:`start` at ``pelvis``: Nielsen's damping update
        (ν × max(1/3, 1 − (2ρ − 1)³) on a step whose actual decrease is ρ > 0 times the predicted one; else ν
        doubles its last growth) from ν = ``DAMPING``."""
        theta = self.start(pelvis) if theta is None else np.array(theta, dtype=np.float64)
        moving, K = self.moving, len(self.moving)
        nu, growth = self.DAMPING, 2.0
        cost = self.objective(theta, self.data(theta))
        for _ in range(self.MAX_STEPS):
            r, blocks, Jr = self.normal_equations(theta)
            x = theta[:, moving]
            smooth = np.zeros_like(x)
            smooth[1:] += x[1:] - x[:-1]
            smooth[:-1] += x[:-1] - x[1:]
            g = Jr + self.lam * (x - self.centre[moving]) + SMOOTHNESS * smooth
            blocks[:, np.arange(K), np.arange(K)] += self.lam
            while nu < self.MAX_DAMPING:
                delta, predicted = self.solve(blocks, g, nu)
                trial = theta.copy()
                trial[:, moving] += delta
                trial_cost = self.objective(trial, self.data(trial))
                rho = (cost - trial_cost) / predicted if predicted > 0 else -1.0
                if rho > 0:
                    nu, growth = nu * max(1 / 3, 1 - (2 * rho - 1) ** 3), 2.0
                    break
                nu, growth = nu * growth, growth * 2
            else:
                break                                   # no step lowers the objective: converged to the Jacobian's precision
            decrease, theta, cost = cost - trial_cost, trial, trial_cost
            if decrease < self.TOLERANCE * r.size:
                break
        return theta


def moving_channels(skeleton: Skeleton, joints: np.ndarray) -> np.ndarray:
    """(K,) ascending channels that move one of ``joints``: those of the smallest skeleton placing them
    (:meth:`~priortrack.data.skeleton.Skeleton.pruned`: their ancestors' rotations and translations, the
    joints' own translations; channels keep their indices)."""
    pruned, _ = skeleton.pruned(joints)
    channels = np.concatenate([pruned.rot_channels.ravel(), pruned.trans_channels.ravel()])
    return np.unique(channels[channels >= 0])
