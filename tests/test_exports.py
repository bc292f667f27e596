"""The exports read by the tools that read them: a tracked run's .trc by OpenSim (its own
TRCFileAdapter, as OpenSim 4.6 ships it) and its .bvh by Blender's BVH importer (bpy 4.x), each
with the conventions docs/formats.md states: TRC Y-up in metres, (X, Y, Z) = (Y, Z, X) of a Z-up
world; BVH Y-up in centimetres, imported at scale 0.01 into Blender's Z-up world."""

from pathlib import Path

import numpy as np
import pytest

from priortrack.body.fk import ForwardKinematics
from priortrack.cli.main import main
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.bvh import read_bvh
from priortrack.data.eval15 import EVAL15_MARKER_NAMES


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """The real Pose2Sim trial (Z-up world) tracked by pf-lie, written as .npz, .trc and .bvh."""
    folder = tmp_path_factory.mktemp("exports")
    assert main(["track", "--detections", str(POSE2SIM_DIR / "pose"), "--cameras", str(POSE2SIM_DIR / "Calib.toml"),
                 "--keypoints", "body25b", "--fps", "60", "--filter", "pf-lie", "--out", str(folder / "r.npz"),
                 "--out", str(folder / "r.trc"), "--out", str(folder / "r.bvh")]) == 0
    with np.load(folder / "r.npz") as z:
        return folder, z["joints"], [str(n) for n in z["joint_names"]], z["frames"]


def test_opensim_reads_the_trc_y_up_in_metres(run):
    import opensim

    folder, joints, names, frames = run
    table = opensim.TimeSeriesTableVec3(str(folder / "r.trc"))
    # the detections' 60 fps frames (every one, the last half a tick after the filter's last), OpenSim's names
    assert table.getNumRows() == len(joints) == 12 and frames.tolist() == list(range(12))
    labels = list(table.getColumnLabels())                           # the 15 joints, then the detector's others
    assert labels[:15] == list(EVAL15_MARKER_NAMES) and labels[15:] == ["Nose", "LEye", "REye", "LEar", "REar",
                                                                        "LBigToe", "LSmallToe", "LHeel", "RBigToe",
                                                                        "RSmallToe", "RHeel"]
    assert table.getTableMetaDataAsString("Units") == "m" and float(table.getTableMetaDataAsString("DataRate")) == 60
    np.testing.assert_allclose(list(table.getIndependentColumn()), np.arange(len(joints)) / 60, atol=1e-12)
    markers = np.array([[[table.getRowAtIndex(t)[j].get(k) for k in range(3)] for j in range(len(labels))]
                        for t in range(len(joints))])
    heels, ankles_ = markers[:, [labels.index("LHeel"), labels.index("RHeel")]], markers[:, [11, 14]]
    assert (np.linalg.norm(heels - ankles_, axis=-1) < 0.15).all()                   # each heel by its ankle
    markers = markers[:, :15]
    np.testing.assert_allclose(markers, joints[..., [1, 2, 0]], atol=1e-12)      # Pose2Sim's zup2yup
    head, ankles = names.index("head"), [names.index("lankle"), names.index("rankle")]
    assert (markers[:, head, 1] - markers[:, ankles, 1].max(axis=1) > 1.3).all()  # Y is OpenSim's vertical


def test_blender_imports_the_bvh_at_scale_0_01_to_our_joints(run):
    """Blender's importer (scale 0.01: the file is in centimetres; BVH's Y up turned to Blender's Z
    up) puts every bone's head where our reader's kinematics put the joint, in the calibration's Z-up
    world, to 1e-6 m; the tracked head stands 1.3 m above the ankles along Blender's Z."""
    import bpy

    folder, joints, names, _ = run
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_anim.bvh(filepath=str(folder / "r.bvh"), global_scale=0.01, axis_forward="-Z", axis_up="Y")
    armature = bpy.context.selected_objects[0]
    motion = read_bvh(folder / "r.bvh")
    ours = ForwardKinematics(motion.skeleton)(motion.channels).double().numpy()     # (T, J, 3) Y-up metres
    bones = [b.name for b in armature.pose.bones]                  # every joint but the end sites
    assert sorted(bones) == sorted(n for n in motion.skeleton.names if not n.endswith("_end"))
    index = [motion.skeleton.names.index(b) for b in bones]
    for t in range(len(ours)):
        bpy.context.scene.frame_set(t + 1)
        heads = np.array([list(armature.matrix_world @ armature.pose.bones[b].head) for b in bones])
        np.testing.assert_allclose(heads, ours[t][index][:, [0, 2, 1]] * [1, -1, 1], atol=1e-6)
        np.testing.assert_allclose(heads.mean(axis=0)[:2], joints[t].mean(axis=0)[:2], atol=0.1)  # where we tracked
        assert np.ptp(heads[:, 2]) > 1.3 > max(np.ptp(heads[:, 0]), np.ptp(heads[:, 1]))          # standing along Z


def test_opensims_inverse_kinematics_runs_on_our_trc_as_on_pose2sims(tmp_path):
    """Issue 60, item 5 ("checked by OpenSim itself: its IK on our TRC"): Pose2Sim's own model, BODY_25B marker set
    and IK tasks (tests/data/opensim_pose2sim, unscaled) run on our TRC of Pose2Sim's demo participant (`--people
    id:1 --smooth --lowpass 6`) and on Pose2Sim's own TRC of them: every frame solved, our markers fitted about as
    well (median RMS marker error 44 against 38 mm, the generic model unscaled for either), OpenSim's right knee angle
    within 2.6° median of the one it finds on Pose2Sim's markers, and our .mot's geometric knee flexion within 2.8° of
    OpenSim's (r 0.994)."""
    import opensim

    data = Path(__file__).parent / "data"
    setup = data / "opensim_pose2sim"
    multiperson = data / "pose2sim_multiperson"
    assert main(["track", "--detections", str(multiperson / "pose"), "--cameras",
                 str(multiperson / "calibration" / "Calib.qca.txt"), "--fps", "60", "--people", "id:1", "--smooth",
                 "--lowpass", "6", "--out", str(tmp_path / "ours.trc"), "--out", str(tmp_path / "ours.mot")]) == 0
    opensim.Logger.setLevelString("error")
    opensim.Logger.removeFileSink()                   # its IK tool would write opensim.log where the suite runs

    def inverse_kinematics(trc: Path, tag: str):
        model = opensim.Model(str(setup / "Model_Pose2Sim_simple.osim"))
        model.set_MarkerSet(opensim.MarkerSet(str(setup / "Markers_Body25b.xml")))
        model.initSystem()
        tool = opensim.InverseKinematicsTool(str(setup / "IK_Setup_Pose2Sim_Body25b.xml"))
        tool.setModel(model)
        tool.setMarkerDataFileName(str(trc))
        times = list(opensim.TimeSeriesTableVec3(str(trc)).getIndependentColumn())
        tool.setStartTime(times[0])
        tool.setEndTime(times[-1])
        tool.setResultsDir(str(tmp_path))
        tool.setOutputMotionFileName(str(tmp_path / f"{tag}.mot"))
        tool.set_report_errors(True)
        assert tool.run()
        errors = opensim.TimeSeriesTable(str(tmp_path / "_ik_marker_errors.sto"))
        rms = [errors.getDependentColumn("marker_error_RMS")[i] for i in range(errors.getNumRows())]
        motion = opensim.TimeSeriesTable(str(tmp_path / f"{tag}.mot"))
        knee = [motion.getDependentColumn("knee_angle_r")[i] for i in range(motion.getNumRows())]
        return np.array(rms), np.array(knee)

    ours, our_knee = inverse_kinematics(tmp_path / "ours_person1.trc", "ik_ours")
    theirs, their_knee = inverse_kinematics(multiperson / "pose2sim_output" / "S00_P01_T02_Participants1-2_P2_0-100.trc",
                                            "ik_theirs")
    assert len(ours) == len(theirs) == 100
    assert np.median(ours) < 1.3 * np.median(theirs) and np.median(ours) < 0.06, (np.median(ours), np.median(theirs))
    assert np.median(np.abs(our_knee - their_knee)) < 5.0
    geometric = opensim.TimeSeriesTable(str(tmp_path / "ours_person1.mot"))
    flexion = np.array([geometric.getDependentColumn("knee_flexion_r")[i] for i in range(geometric.getNumRows())])
    assert np.median(np.abs(flexion - our_knee)) < 5.0 and np.corrcoef(flexion, our_knee)[0, 1] > 0.98
