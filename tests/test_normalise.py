"""eval15 layout, pose normalisation and bone directions on real mocap."""

import numpy as np
import pytest
import torch

from priortrack import PriortrackError, load_motion
from priortrack.body.layout import EVAL15_NAMES, eval15_indices
from priortrack.body.normalise import (BONE_CHILDREN, NormalisedPose, body_frame, body_positions,
                                       denormalise, normalise)
from priortrack.data.bvh import read_bvh, write_bvh
from priortrack.body.fk import joint_positions


@pytest.fixture(scope="module")
def walk():
    return load_motion("cmu:07_01")


def test_eval15_from_cmu_names(walk):
    names = [walk.skeleton.names[j] for j in eval15_indices(walk.skeleton)]
    assert names == ["root", "lowerneck", "head_end", "lhumerus", "lradius", "lwrist", "rhumerus",
                     "rradius", "rwrist", "lfemur", "ltibia", "lfoot", "rfemur", "rtibia", "rfoot"]
    p = joint_positions(walk, "eval15")
    assert p.shape == (len(walk), 15, 3)
    # Anatomy: head above neck above pelvis, ankles lowest, thigh and shin 0.3 to 0.5 m.
    y = p[..., 1]
    assert np.all(y[:, 2] > y[:, 1]) and np.all(y[:, 1] > y[:, 0]) and np.all(y[:, 11] < y[:, 10])
    thigh = np.linalg.norm(p[:, 10] - p[:, 9], axis=-1)
    assert np.all((thigh > 0.3) & (thigh < 0.5))


def test_eval15_from_bvh_names_cmu_bvh_and_mixamo(tmp_path, walk):
    write_bvh(walk[:5], tmp_path / "walk.bvh")
    back = read_bvh(tmp_path / "walk.bvh")
    np.testing.assert_allclose(joint_positions(back, "eval15"), joint_positions(walk[:5], "eval15"), atol=1e-6)
    joints = ["Hips", "Spine", "Neck", "Head", "LeftArm", "LeftForeArm", "LeftHand", "RightArm",
              "RightForeArm", "RightHand", "LeftUpLeg", "LeftLeg", "LeftFoot", "RightUpLeg", "RightLeg", "RightFoot"]
    text = "HIERARCHY\nROOT mixamorig:Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n"
    for name in joints[1:]:
        text += f" JOINT mixamorig:{name}\n {{\n  OFFSET 0 1 0\n  CHANNELS 0\n"
        if name == "Head":
            text += "  End Site\n  {\n   OFFSET 0 10 0\n  }\n"
        text += " }\n"
    text += "}\nMOTION\nFrames: 1\nFrame Time: 0.0333333\n0 0 0\n"
    (tmp_path / "mixamo.bvh").write_text(text)
    sk = read_bvh(tmp_path / "mixamo.bvh").skeleton
    names = [sk.names[j] for j in eval15_indices(sk)]
    assert names[:4] == ["mixamorig:Hips", "mixamorig:Neck", "mixamorig:Head_end", "mixamorig:LeftArm"]
    assert names[-1] == "mixamorig:RightFoot"


def test_positions_to_directions_and_back_exact(walk):
    for motion in (walk, load_motion("cmu:131_04")[::10], load_motion("cmu:01_01")[::25]):
        p = torch.as_tensor(joint_positions(motion, "eval15"))
        pose = normalise(p)
        assert pose.directions.shape == (len(motion), 14, 3) and pose.lengths.shape == (len(motion), 14)
        assert (torch.linalg.vector_norm(pose.directions, dim=-1) - 1).abs().max() < 1e-12
        assert (denormalise(pose) - p).abs().max() < 1e-9


def test_body_frame_definition(walk):
    p = torch.as_tensor(joint_positions(walk, "eval15"))
    h, R = body_frame(p)
    assert (R @ R.transpose(-1, -2) - torch.eye(3, dtype=R.dtype)).abs().max() < 1e-12
    assert (torch.linalg.det(R) - 1).abs().max() < 1e-12
    b = torch.einsum("tij,tkj->tki", R, p - h[:, None])
    lhip, rhip, neck = (EVAL15_NAMES.index(n) for n in ("lhip", "rhip", "neck"))
    # Hip centre at the origin, neck on +y, both hips and the neck in the plane z = 0, left hip at +x.
    assert (b[:, lhip] + b[:, rhip]).abs().max() < 1e-12
    assert b[:, neck, [0, 2]].abs().max() < 1e-12 and (b[:, neck, 1] > 0).all()
    assert b[:, [lhip, rhip, neck], 2].abs().max() < 1e-12 and (b[:, lhip, 0] > 0).all()
    # The head is above the neck along the body's y axis.
    assert (b[:, EVAL15_NAMES.index("head"), 1] > b[:, neck, 1]).all()


def test_directions_invariant_to_global_rigid_motion(walk):
    p = torch.as_tensor(joint_positions(walk, "eval15")[::7])
    angle = 1.1
    Q = torch.tensor([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    moved = p @ Q.T + torch.tensor([2.0, 0.1, -3.0], dtype=torch.float64)
    a, b = normalise(p), normalise(moved)
    assert (a.directions - b.directions).abs().max() < 1e-12
    assert (a.lengths - b.lengths).abs().max() < 1e-12


def test_body_positions_put_hip_centre_at_origin(walk):
    pose = normalise(torch.as_tensor(joint_positions(walk, "eval15")[:20]))
    b = body_positions(pose.directions, pose.lengths)
    assert (b[:, 9] + b[:, 12]).abs().max() < 1e-12
    assert len(BONE_CHILDREN) == 14


def test_bad_input():
    with pytest.raises(PriortrackError, match=r"expected \(\.\.\., 15, 3\)"):
        normalise(torch.zeros(4, 14, 3))
    bad = torch.zeros(2, 15, 3)
    with pytest.raises(PriortrackError, match="degenerate"):
        normalise(bad)
    nan = torch.ones(1, 15, 3)
    nan[0, 3, 1] = float("nan")
    with pytest.raises(PriortrackError, match="NaN"):
        normalise(nan)
    with pytest.raises(PriortrackError, match="directions"):
        denormalise(NormalisedPose(torch.zeros(3), torch.eye(3), torch.zeros(13, 3), torch.zeros(13)))
