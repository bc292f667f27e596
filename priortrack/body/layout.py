"""Joint layouts: the 15-joint evaluation layout ``eval15`` and the skeleton's ``full`` set.

``eval15`` is HumanEva's 15-joint set: pelvis, neck (the top of the thorax, where the neck
and both clavicles meet: HumanEva's upper-torso joint, so "thorax" and "neck" are one
joint here), head (top of the head), shoulders, elbows, wrists, hips, knees, ankles. Its 14
bones (each joint to its parent) are the bone directions of the Lie-algebra prior.
"""

from __future__ import annotations

import numpy as np

from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.data.skeleton import Skeleton
from priortrack.errors import PriortrackError

# Skeleton joint names that stand for each eval15 joint, first match wins (lower case,
# any "prefix:" removed). CMU ASF names a joint after the bone that starts there; CMU's
# BVH conversions and Mixamo use Hips/LeftUpLeg/...; "<name>_end" is an end site.
_CANDIDATES = {
    "pelvis": ("root", "hips", "pelvis"),
    "neck": ("lowerneck", "neck"),
    "head": ("head_end", "headtop_end", "head_top", "head"),
    "lshoulder": ("lhumerus", "leftarm", "l_upperarm", "leftupperarm"),
    "lelbow": ("lradius", "leftforearm", "l_forearm", "leftlowerarm"),
    "lwrist": ("lwrist", "lefthand", "l_hand"),
    "rshoulder": ("rhumerus", "rightarm", "r_upperarm", "rightupperarm"),
    "relbow": ("rradius", "rightforearm", "r_forearm", "rightlowerarm"),
    "rwrist": ("rwrist", "righthand", "r_hand"),
    "lhip": ("lfemur", "leftupleg", "l_thigh", "leftupperleg", "lefthip"),
    "lknee": ("ltibia", "leftleg", "l_calf", "leftlowerleg", "leftknee"),
    "lankle": ("lfoot", "leftfoot", "l_foot", "leftankle"),
    "rhip": ("rfemur", "rightupleg", "r_thigh", "rightupperleg", "righthip"),
    "rknee": ("rtibia", "rightleg", "r_calf", "rightlowerleg", "rightknee"),
    "rankle": ("rfoot", "rightfoot", "r_foot", "rightankle"),
}

LAYOUTS = ("eval15", "full")


def _plain(name: str) -> str:
    return name.rsplit(":", 1)[-1].lower()


def eval15_indices(skeleton: Skeleton) -> np.ndarray:
    """(15,) indices of the skeleton's joints that make up ``eval15``, in EVAL15_NAMES order."""
    lookup = {_plain(n): j for j, n in enumerate(skeleton.names)}
    indices = []
    for joint in EVAL15_NAMES:
        found = next((lookup[c] for c in _CANDIDATES[joint] if c in lookup), None)
        if found is None:
            raise PriortrackError(
                f"skeleton {skeleton.name!r} has no joint for eval15 {joint!r} "
                f"(looked for {', '.join(_CANDIDATES[joint])})"
            )
        indices.append(found)
    return np.array(indices)


def layout_indices(skeleton: Skeleton, layout: str) -> np.ndarray:
    """Indices of the skeleton's joints in ``layout`` ("eval15" or "full")."""
    if layout == "eval15":
        return eval15_indices(skeleton)
    if layout == "full":
        return np.arange(skeleton.num_joints)
    raise PriortrackError(f"unknown layout {layout!r}; layouts: {', '.join(LAYOUTS)}")


def layout_names(skeleton: Skeleton, layout: str) -> tuple[str, ...]:
    """Joint names of ``layout`` for this skeleton."""
    if layout == "eval15":
        return EVAL15_NAMES
    return tuple(skeleton.names[j] for j in layout_indices(skeleton, layout))
