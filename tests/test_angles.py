"""Joint angles from tracked joints (issue 60, item 5: "no joint angles (.mot)"): against a one-axis knee and elbow's
own channels, a pose built to known angles in an arbitrary world, and an OpenSim .mot that OpenSim reads."""

from pathlib import Path

import numpy as np
import pytest

import priortrack
from priortrack.body.angles import ANGLES, joint_angles
from priortrack.body.fk import joint_positions
from priortrack.cli.main import main
from priortrack.data.eval15 import EVAL15_NAMES

J = {n: i for i, n in enumerate(EVAL15_NAMES)}
MULTIPERSON = Path(__file__).parent / "data" / "pose2sim_multiperson"


def test_knee_and_elbow_flexion_are_a_one_axis_joints_own_angle():
    """CMU's ASF knees and elbows turn about one axis (tibia rx, radius rx): the geometric flexion is that channel."""
    walk = priortrack.load_motion("cmu:07_10")
    angles = joint_angles(joint_positions(walk))
    names = list(walk.skeleton.channel_names)
    for side in "lr":
        for angle, channel in (("knee_flexion", "tibia"), ("elbow_flexion", "radius")):
            own = np.degrees(walk.channels[:, names.index(f"{side}{channel}.rx")])
            np.testing.assert_allclose(angles[f"{angle}_{side}"], own, atol=1e-5)     # arccos near 0: 1e-6°
            assert own.max() > 40                                                     # a walk bends them


def _rotation(axis, degrees):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    a = np.radians(degrees)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def test_a_pose_built_to_known_angles_reads_them_back_in_any_world():
    """A body facing −z with y up (right = +x): the right thigh 30° forward, the left 20° out, the right knee 45°
    bent, the right arm 90° out, the left 60° forward, the left elbow 90°, the right foot 10° toes-up; then the whole
    body turned and moved arbitrarily (a Z-up world): every angle as built."""
    down, up, right, forward = np.array([0, -1.0, 0]), np.array([0, 1.0, 0]), np.array([1.0, 0, 0]), np.array([0, 0, -1.0])
    X = np.zeros((15, 3))
    X[J["pelvis"]] = [0, 1.0, 0]
    X[J["neck"]] = [0, 1.5, 0]
    X[J["head"]] = [0, 1.75, 0]
    for side, s in (("r", 1.0), ("l", -1.0)):
        X[J[side + "hip"]] = X[J["pelvis"]] + s * 0.1 * right
        X[J[side + "shoulder"]] = X[J["neck"]] + s * 0.2 * right
    thigh_r = _rotation(right, 30) @ down              # knee forward (−z): a turn of 30° about the right axis
    thigh_l = _rotation(forward, 20) @ down            # left knee out to the left (−x)
    X[J["rknee"]] = X[J["rhip"]] + 0.4 * thigh_r
    X[J["lknee"]] = X[J["lhip"]] + 0.4 * thigh_l
    X[J["rankle"]] = X[J["rknee"]] + 0.4 * (_rotation(right, -15) @ down)           # 45° from the thigh's line
    X[J["lankle"]] = X[J["lknee"]] + 0.4 * thigh_l
    arm_r, arm_l = right, _rotation(right, 60) @ down
    X[J["relbow"]], X[J["lelbow"]] = X[J["rshoulder"]] + 0.3 * arm_r, X[J["lshoulder"]] + 0.3 * arm_l
    X[J["rwrist"]] = X[J["relbow"]] + 0.25 * arm_r
    X[J["lwrist"]] = X[J["lelbow"]] + 0.25 * (_rotation(right, -90) @ arm_l)
    shank_r = X[J["rankle"]] - X[J["rknee"]]
    foot_r = _rotation(right, 10) @ _rotation(right, 90) @ (shank_r / np.linalg.norm(shank_r))    # square, then toes up
    heels = np.stack([X[J["lankle"]], X[J["rankle"]] - 0.05 * foot_r])[None]
    toes = np.stack([X[J["lankle"]] + 0.2 * forward, X[J["rankle"]] + 0.15 * foot_r])[None]
    R = _rotation([0.3, -1.0, 0.5], 77)
    move = lambda P: P @ R.T + [2.0, -1.0, 0.5]                                      # noqa: E731
    angles = joint_angles(move(X)[None], move(heels), move(toes))
    expected = {"hip_flexion_r": 30, "hip_adduction_r": 0, "hip_flexion_l": 0, "hip_adduction_l": -20,
                "knee_flexion_r": 45, "knee_flexion_l": 0, "ankle_dorsiflexion_r": 10, "shoulder_abduction_r": 90,
                "shoulder_flexion_l": 60, "shoulder_abduction_l": 0, "elbow_flexion_r": 0,
                "elbow_flexion_l": 90}
    assert set(angles) == {f"{a}_{s}" for a in ANGLES for s in "rl"}
    for name, value in expected.items():
        assert angles[name][0] == pytest.approx(value, abs=1e-5), name          # arccos at 0°: 1e-6°
    assert np.isnan(angles["shoulder_flexion_r"]).all()                # straight out to the side: no flexion
    assert np.isnan(joint_angles(X[None])["ankle_dorsiflexion_r"]).all()            # no feet: no ankle angle


def test_the_mot_is_read_by_opensim(tmp_path):
    """``--out s.mot`` on Pose2Sim's demo (each person's, at 60 fps): OpenSim's TimeSeriesTable reads its 14 angles
    in degrees at the frames' times; the participant's knees bend between 0 and 90°."""
    import opensim

    assert main(["track", "--detections", str(MULTIPERSON / "pose"), "--cameras",
                 str(MULTIPERSON / "calibration" / "Calib.qca.txt"), "--fps", "60", "--people", "all",
                 "--out", str(tmp_path / "s.mot")]) == 0
    table = opensim.TimeSeriesTable(str(tmp_path / "s_person1.mot"))
    assert table.getNumRows() == 100 and table.getTableMetaDataAsString("inDegrees") == "yes"
    assert list(table.getColumnLabels()) == [f"{a}_{s}" for a in ANGLES for s in "rl"]
    np.testing.assert_allclose(list(table.getIndependentColumn()), np.arange(100) / 60, atol=1e-12)
    knee = np.array([table.getDependentColumn("knee_flexion_r")[i] for i in range(100)])
    ankle = np.array([table.getDependentColumn("ankle_dorsiflexion_l")[i] for i in range(100)])
    assert (knee > 0).all() and (knee < 90).all() and np.isfinite(ankle).all()
