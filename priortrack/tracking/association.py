"""Cross-view association: which 2D people of one frame, in different cameras, are one person.

No identity is assumed: a detector's people come in no stable order and its per-camera ids agree with
no other camera's. Each person a of camera i and b of camera j are compared by their joints' rays:

    d_k(a, b) = |(C_j − C_i) · (r_ak × r_bk)| / ‖r_ak × r_bk‖,

the distance, in metres, between the ray from camera i's centre C_i through joint k of a (r_ak, the
undistorted pixel's direction in the world) and the ray through the same joint of b; where the
nearest points of the two rays lie behind a camera, or the rays are parallel, the joint does not
count. The pair's distance d(a, b) is the confidence-weighted median of d_k over the joints both
show (weights c_ak c_bk), where they share at least :data:`MIN_SHARED` joints; metres, so one gate
holds for any camera's resolution and distance (a pixel gate would not).

**Cycle-consistent grouping** (as 4D Association's Kruskal-style associater): the pairs under
:data:`PAIR_GATE_M`, nearest first, join groups (union–find) when the union holds at most one person
per camera and every pair of its members that shares enough joints is itself under the gate (complete
linkage) and the union's triangulated body is one an adult could have (:func:`body_scale` at most
:data:`MAX_BODY_SCALE`: two rays through two people's images can meet, far behind one of them, in a giant). Each
group is an equivalence class, so the matching is cycle-consistent by construction
(a ~ b and b ~ c in a group means a ~ c was checked too), without the spectral relaxation mvpose and
EasyMocap solve (their matchSVT) and its rounding.

**Proposals.** A group seen by two or more cameras is triangulated (confidence-weighted DLT of the
undistorted points, :func:`~priortrack.geometry.triangulation.dlt_normalised`) into a 3D proposal; two proposals whose
joints are within :data:`DUPLICATE_M` (median) are one person (a detector's split or doubled
detection): merged where their cameras differ, else the one with more views kept. A person seen by
one camera only stays a candidate, never a proposal: one view has no depth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.triangulation import dlt_normalised, undistort_normalised
from priortrack.tracking.motion import View

#: Joints two detections must both show for their rays to be compared.
MIN_SHARED = 4
#: Largest pair distance (median joint ray-to-ray distance, metres) of one person in two views.
PAIR_GATE_M = 0.15
#: Two proposals whose triangulated joints lie within this median distance (metres) are one person.
DUPLICATE_M = 0.2
#: A group of detections whose triangulated body measures, in median, more than this multiple of a nominal adult's
#: (:func:`body_scale`) is no one: a person 2.5 m tall is two people's detections paired.
MAX_BODY_SCALE = 1.5
#: … judged on at least this many of the body's eight measures.
MIN_BODY_MEASURES = 3
#: The standing height of the nominal adult, metres.
NOMINAL_HEIGHT_M = 1.7


@dataclass(frozen=True)
class Proposal:
    """One person seen by several cameras at one frame.

    Attributes:
        views: {camera index: person index in that camera's list}, two or more cameras.
        joints: (J, 3) triangulated joints, metres, NaN where fewer than two views show the joint.
        reprojection_px: (len(views),) median distance of each view's joints from the triangulated
            joints' projection, in ``views``' order: pixels of the undistorted image.
    """

    views: dict[int, int]
    joints: np.ndarray = field(repr=False)
    reprojection_px: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class Association:
    """One frame's association: ``proposals`` (several views each) and ``candidates``, the (camera,
    person) pairs seen by one camera only (or too few joints to compare)."""

    proposals: list[Proposal]
    candidates: list[tuple[int, int]]


def normalised(cameras: Sequence[PinholeCamera], uv: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Each camera's pixels (..., 2) as undistorted normalised coordinates (x, y) (NaN stays NaN)."""
    return [undistort_normalised(camera, np.asarray(points, dtype=np.float64)) for camera, points in zip(cameras, uv)]


def rays(cameras: Sequence[PinholeCamera], xy: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Each camera's joint rays from normalised coordinates xy (N_c, J, 2): unit directions Rᵀ (x, y, 1)
    in the world (N_c, J, 3), NaN where the joint is missing."""
    return [View.of(camera).rays(points) for camera, points in zip(cameras, xy)]


def pair_distances(centre_i: np.ndarray, rays_i: np.ndarray, conf_i: np.ndarray, centre_j: np.ndarray,
                   rays_j: np.ndarray, conf_j: np.ndarray) -> np.ndarray:
    """d(a, b) (N_i, N_j), metres (module docstring), inf where fewer than :data:`MIN_SHARED` joints
    compare. rays_* (N, J, 3) unit directions (NaN missing), conf_* (N, J) confidences."""
    a, b = rays_i[:, None], rays_j[None]                                  # (N_i, 1, J, 3), (1, N_j, J, 3)
    base = centre_j - centre_i
    n = np.cross(a, b)                                                    # (N_i, N_j, J, 3)
    sin = np.linalg.norm(n, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.abs(n @ base) / sin
        # the nearest points' ray parameters: s along a from C_i, u along b from C_j (both must be > 0)
        ab = (a * b).sum(-1)
        s = ((base * a).sum(-1) - ab * (base * b).sum(-1)) / (1 - ab ** 2)
        u = (ab * (base * a).sum(-1) - (base * b).sum(-1)) / (1 - ab ** 2)
    usable = np.isfinite(d) & (sin > 1e-6) & (s > 0) & (u > 0)
    w = np.where(usable, conf_i[:, None] * conf_j[None], 0.0)
    return _weighted_median(np.where(usable, d, np.inf), w, MIN_SHARED)


def _weighted_median(values: np.ndarray, weights: np.ndarray, least: int) -> np.ndarray:
    """The weighted median over the last axis of ``values`` (weights ≥ 0; entries of weight 0 ignored),
    inf where fewer than ``least`` entries have weight."""
    order = np.argsort(values, axis=-1)
    v = np.take_along_axis(values, order, -1)
    w = np.take_along_axis(weights, order, -1)
    cumulative = np.cumsum(w, axis=-1)
    total = cumulative[..., -1:]
    k = np.minimum((cumulative < 0.5 * total).sum(-1, keepdims=True), values.shape[-1] - 1)
    median = np.take_along_axis(v, k, -1)[..., 0]
    return np.where((weights > 0).sum(-1) >= least, median, np.inf)


class _Groups:
    """Union–find over (camera, person) nodes that keeps, per group, its members."""

    def __init__(self, nodes: list[tuple[int, int]]):
        self.parent = {n: n for n in nodes}
        self.members = {n: [n] for n in nodes}

    def root(self, n):
        while self.parent[n] != n:
            self.parent[n] = self.parent[self.parent[n]]
            n = self.parent[n]
        return n

    def join(self, a, b) -> None:
        a, b = self.root(a), self.root(b)
        self.parent[b] = a
        self.members[a] += self.members.pop(b)


def associate(cameras: Sequence[PinholeCamera], uv: Sequence[np.ndarray], confidence: Sequence[np.ndarray],
              pair_gate: float = PAIR_GATE_M, xy: Sequence[np.ndarray] | None = None) -> Association:
    """Group one frame's 2D people across cameras (module docstring).

    Args:
        cameras: C calibrated cameras.
        uv: per camera, (N_c, J, 2) pixels of its N_c people (NaN where missing).
        confidence: per camera, (N_c, J) confidences (0 where missing).
        pair_gate: the pair distance gate, metres.
        xy: the same points already undistorted and normalised (:func:`normalised`), or None.

    Returns:
        the proposals (two or more views, triangulated) and the candidates (one view).
    """
    if len(uv) != len(cameras) or len(confidence) != len(cameras):
        raise PriortrackError(f"{len(uv)} cameras' people and {len(confidence)} confidences for {len(cameras)} cameras")
    xy = normalised(cameras, uv) if xy is None else [np.asarray(p, dtype=np.float64) for p in xy]
    conf = [np.where(np.isfinite(p).all(-1), np.asarray(c, dtype=np.float64), 0.0) for p, c in zip(xy, confidence)]
    directions = rays(cameras, xy)
    centres = [c.center.double().numpy() for c in cameras]
    distance: dict[tuple, float] = {}
    for i in range(len(cameras)):
        for j in range(i + 1, len(cameras)):
            if not len(xy[i]) or not len(xy[j]):
                continue
            d = pair_distances(centres[i], directions[i], conf[i], centres[j], directions[j], conf[j])
            for a, b in zip(*np.nonzero(np.isfinite(d))):
                distance[(i, int(a)), (j, int(b))] = distance[(j, int(b)), (i, int(a))] = float(d[a, b])
    nodes = [(c, n) for c in range(len(cameras)) for n in range(len(xy[c]))]
    groups = _Groups(nodes)
    for (a, b), d in sorted(((pair, d) for pair, d in distance.items() if pair[0] < pair[1] and d < pair_gate),
                            key=lambda item: item[1]):
        ra, rb = groups.root(a), groups.root(b)
        if ra == rb:
            continue
        A, B = groups.members[ra], groups.members[rb]
        if {c for c, _ in A} & {c for c, _ in B}:
            continue                                        # one person per camera
        if (all(distance.get((x, y), 0.0) < pair_gate for x in A for y in B)
                and not body_scale(_triangulated(cameras, xy, conf, dict(sorted(A + B)))) > MAX_BODY_SCALE):
            groups.join(ra, rb)
    proposals, candidates = [], []
    for members in groups.members.values():
        if len(members) == 1:
            candidates.append(members[0])
        else:
            proposals.append(_proposal(cameras, xy, conf, dict(sorted(members))))
    proposals, extra = _merged_duplicates(cameras, xy, conf, proposals)
    return Association(sorted(proposals, key=lambda p: -len(p.views)), sorted(candidates + extra))


@lru_cache(maxsize=1)
def nominal_adult():
    """The nominal adult's body: the template (CMU 35's skeleton) scaled to :data:`NOMINAL_HEIGHT_M`."""
    from priortrack.body.ik import scaled_to_height
    from priortrack.data.bundled import cmu_skeleton

    return scaled_to_height(cmu_skeleton("35"), NOMINAL_HEIGHT_M)


@lru_cache(maxsize=1)
def nominal_measures() -> np.ndarray:
    """(15,) the :func:`nominal_adult`'s distance measuring each eval15 joint's bone
    (:func:`~priortrack.body.ik.measured_distances`: the trunk, the shoulders' and hips' widths, each limb's left and
    right averaged; 0 for the pelvis), metres, in the detector's definitions."""
    from priortrack.body.ik import rest_distances
    from priortrack.data.keypoints import detector_map

    return np.concatenate([[0.0], rest_distances(nominal_adult(), detector_map())])


def body_scale(joints: np.ndarray) -> float:
    """The median over the body's distinct measures (:data:`~priortrack.body.ik.BODY_MEASURES`: the trunk, head,
    shoulder and hip widths, upper arm, forearm, thigh, shin, a limb's sides averaged) that triangulated joints
    (15, 3) show of their ratio to the nominal adult's (:func:`nominal_measures`; an adult's 0.8–1.15), NaN where fewer
    than :data:`MIN_BODY_MEASURES` are shown."""
    from priortrack.body.ik import BODY_MEASURES, measured_distances

    index = np.array(list(BODY_MEASURES.values()))
    ratio = measured_distances(joints[None])[index - 1] / nominal_measures()[index]
    ratio = ratio[np.isfinite(ratio)]
    return float(np.median(ratio)) if len(ratio) >= MIN_BODY_MEASURES else float("nan")


def _triangulated(cameras: Sequence[PinholeCamera], xy, conf, views: dict[int, int]) -> np.ndarray:
    """(J, 3) the views' joints triangulated (confidence-weighted DLT on normalised points)."""
    points = np.stack([xy[c][n] for c, n in views.items()])                                 # (V, J, 2)
    weights = np.stack([conf[c][n] for c, n in views.items()])                              # (V, J)
    return dlt_normalised([cameras[c] for c in views], np.where(weights[..., None] > 0, points, np.nan), weights)


def _proposal(cameras: Sequence[PinholeCamera], xy, conf, views: dict[int, int]) -> Proposal:
    """The views' joints triangulated (:func:`_triangulated`) and each view's median reprojection error, in pixels of
    its focal length (the normalised error times √(fx fy))."""
    chosen = [cameras[c] for c in views]
    points = np.stack([xy[c][n] for c, n in views.items()])                                 # (V, J, 2)
    joints = _triangulated(cameras, xy, conf, views)
    errors = []
    for camera, p in zip(chosen, points):
        Xc = joints @ camera.R.double().numpy().T + camera.t.double().numpy()
        e = np.linalg.norm(Xc[:, :2] / Xc[:, 2:] - p, axis=-1) * np.sqrt(camera.fx * camera.fy)
        errors.append(float(np.median(e[np.isfinite(e)])) if np.isfinite(e).any() else np.nan)
    return Proposal(views, joints, np.array(errors))


def _merged_duplicates(cameras, xy, conf, proposals: list[Proposal]) -> tuple[list[Proposal], list[tuple[int, int]]]:
    """Proposals within :data:`DUPLICATE_M` of each other merged (disjoint cameras) or the smaller's views
    returned as candidates."""
    proposals = sorted(proposals, key=lambda p: -len(p.views))
    kept: list[Proposal] = []
    left: list[tuple[int, int]] = []
    for p in proposals:
        for i, q in enumerate(kept):
            if median_distance(p.joints, q.joints) < DUPLICATE_M:
                if set(p.views) & set(q.views):
                    left += list(p.views.items())
                else:
                    kept[i] = _proposal(cameras, xy, conf, dict(sorted({**q.views, **p.views}.items())))
                break
        else:
            kept.append(p)
    return kept, left


def median_distance(a: np.ndarray, b: np.ndarray) -> float:
    """The median distance between two sets of joints (J, 3) over the joints both have, inf where none."""
    gap = np.linalg.norm(a - b, axis=-1)
    gap = gap[np.isfinite(gap)]
    return float(np.median(gap)) if len(gap) else np.inf
