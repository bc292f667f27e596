"""One camera's people: each 2D person placed in 3D at the depth their size in the image says, so that the scene
tracker can start and follow several people where the rig is a single camera.

With one view a person has no triangulation, but a body has a size. A detection's bones b (each eval15 joint to its
parent, in the detector's definitions) that it shows have lengths ℓ_b in undistorted normalised image points (units of
the focal length); a nominal adult's (:func:`nominal_bones`) are L_b metres. Over the bones
of :data:`UPRIGHT_BONES` it shows (mid-hips to mid-shoulders, thighs, shins: a standing or walking person's, nearly
parallel to the image plane of a camera that is not looking straight down), or every bone it shows where fewer than
two of those are, the depth is

    d = Σ_b L_b / Σ_b ℓ_b                                                               (metres),

and every joint j is placed on its ray at that depth, X_c,j = d (x_j, y_j, 1), X_j = Rᵀ (X_c,j − t): a flat body
the size of an adult. Foreshortened bones make ℓ_b short and d long, and a child is placed too far; the association
compares projections, which d does not change, and each person's own filter then finds their depth from their body
(``--height``). Comparing a one-view proposal with a track or another proposal, the proposal is first moved along its
rays to the other's depth (:func:`at_depth`): two placements of one person differ there by their lateral gap only.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from priortrack.data.eval15 import EVAL15_MIRROR_PAIRS, EVAL15_PARENTS
from priortrack.tracking.association import Proposal, nominal_adult
from priortrack.tracking.motion import View


@lru_cache(maxsize=1)
def nominal_bones() -> np.ndarray:
    """(15,) the :func:`~priortrack.tracking.association.nominal_adult`'s bone of each eval15 joint (its distance to its parent; 0 for the pelvis), metres, in
    the detector's definitions, left and right averaged: what a detection's bones ℓ_b are compared with (not
    :func:`~priortrack.tracking.association.nominal_measures`, whose shoulders and hips are the widths)."""
    from priortrack.body.fk import joint_positions
    from priortrack.data.keypoints import detector_map
    from priortrack.data.motion import Motion

    skeleton = nominal_adult()
    rest = detector_map() @ joint_positions(Motion(skeleton, np.zeros((1, skeleton.num_channels)), 30.0, "rest"),
                                            "eval15")[0]
    bones = np.r_[0.0, np.linalg.norm(rest[1:] - rest[EVAL15_PARENTS[1:]], axis=-1)]
    for a, b in EVAL15_MIRROR_PAIRS:
        bones[[a, b]] = bones[[a, b]].mean()
    return bones


#: The eval15 joints whose bone (to their parent) is upright in a standing person: the trunk, thighs and shins.
UPRIGHT_BONES = (1, 10, 11, 13, 14)
#: Bones a detection must show to be placed.
MIN_BONES = 3


def placed_depth(xy: np.ndarray, confidence: np.ndarray) -> float | None:
    """d of the module docstring for one detection's normalised points xy (15, 2) and confidences (15,); None where it
    shows fewer than :data:`MIN_BONES` bones."""
    seen = np.isfinite(xy).all(axis=-1) & (confidence > 0)
    child = np.flatnonzero(EVAL15_PARENTS >= 0)
    shown = child[seen[child] & seen[EVAL15_PARENTS[child]]]
    if len(shown) < MIN_BONES:
        return None
    upright = [j for j in shown if j in UPRIGHT_BONES]
    bones = upright if len(upright) >= 2 else list(shown)
    length = np.linalg.norm(xy[bones] - xy[EVAL15_PARENTS[bones]], axis=-1).sum()
    return float(nominal_bones()[bones].sum() / length) if length > 0 else None


def on_rays(view: View, xy: np.ndarray, depth: float) -> np.ndarray:
    """(15, 3) world points at ``depth`` (metres, along the optical axis) on the rays of normalised points xy (15, 2)
    (NaN stays NaN)."""
    Xc = depth * np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
    return (Xc - view.t) @ view.R


def proposal(view: View, xy: np.ndarray, confidence: np.ndarray, n: int) -> Proposal | None:
    """Detection n of the one camera (its normalised points xy (15, 2), confidences (15,)) placed in 3D (module
    docstring) as a one-view proposal; None where too few bones show."""
    depth = placed_depth(xy, confidence)
    if depth is None:
        return None
    seen = np.isfinite(xy).all(axis=-1) & (confidence > 0)
    return Proposal({0: n}, np.where(seen[:, None], on_rays(view, xy, depth), np.nan), np.zeros(1))


def at_depth(view: View, joints: np.ndarray, other: np.ndarray) -> np.ndarray:
    """(15, 3) a one-view placement ``joints`` (15, 3) moved along its rays to the median depth of ``other`` (15, 3) in
    the view (module docstring)."""
    own, theirs = ((points @ view.R.T + view.t)[:, 2] for points in (joints, other))
    scale = np.nanmedian(theirs) / np.nanmedian(own)
    return ((joints @ view.R.T + view.t) * scale - view.t) @ view.R
