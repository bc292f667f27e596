"""The 15-joint evaluation layout ``eval15`` (HumanEva's joints): names and tree.

pelvis, neck (the top of the thorax, where the neck and both clavicles meet), head (top of the
head), shoulders, elbows, wrists, hips, knees, ankles. Its 14 bones (each joint to its parent) are
the bone directions of the Lie-algebra prior. Mocap skeletons map onto it in
:mod:`priortrack.body.layout`, detector keypoints in :mod:`priortrack.data.keypoints`.
"""

import numpy as np

EVAL15_NAMES = (
    "pelvis", "neck", "head",
    "lshoulder", "lelbow", "lwrist",
    "rshoulder", "relbow", "rwrist",
    "lhip", "lknee", "lankle",
    "rhip", "rknee", "rankle",
)
#: (6, 2) eval15's left and right joints (shoulders, elbows, wrists, hips, knees, ankles): what a detector swaps.
EVAL15_MIRROR_PAIRS = np.array([(3, 6), (4, 7), (5, 8), (9, 12), (10, 13), (11, 14)])
#: (15,) parent of each eval15 joint, -1 for the pelvis.
EVAL15_PARENTS = np.array([-1, 0, 1, 1, 3, 4, 1, 6, 7, 0, 9, 10, 0, 12, 13])
#: Each eval15 joint's marker name in Pose2Sim's TRC files and its OpenSim marker sets (HALPE_26's names: ``Hip`` the
#: mid-hips, ``Neck`` the mid-shoulders, ``Head`` the head top), in :data:`EVAL15_NAMES`' order.
EVAL15_MARKER_NAMES = (
    "Hip", "Neck", "Head",
    "LShoulder", "LElbow", "LWrist",
    "RShoulder", "RElbow", "RWrist",
    "LHip", "LKnee", "LAnkle",
    "RHip", "RKnee", "RAnkle",
)
