"""The detector's keypoints beyond the 15 joints, carried by the tracked body (issue 60, item 5; issue 59, item 2):
the smoother against filterpy's, the layouts' extras, a synthetic person's feet recovered, and Pose2Sim's demo
participant's TRC with a toe and a heel each side against Pose2Sim's own output."""

from pathlib import Path

import numpy as np
import pytest

from priortrack.cli.main import main
from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.data.keypoints import LAYOUTS
from priortrack.data.trc import read_trc, write_trc
from priortrack.geometry.camera import PinholeCamera
from priortrack.tracking.extra_keypoints import (DIFFUSE, MAX_GAP_S, carried, extra_keypoints, marker_name, parent_joint,
                                                 rts_constant_velocity)

MULTIPERSON = Path(__file__).parent / "data" / "pose2sim_multiperson"
POSE2SIM_P2 = MULTIPERSON / "pose2sim_output" / "S00_P01_T02_Participants1-2_P2_0-100{}.trc"


def test_the_smoother_is_filterpys_rts_and_keeps_a_straight_line():
    from filterpy.kalman import KalmanFilter

    rng = np.random.default_rng(0)
    dt, T = 1 / 60, 90
    z = np.cumsum(rng.normal(size=(T, 2)), axis=0) * 0.01
    z[10:16, 0] = np.nan                                                        # a gap in one coordinate
    ours = rts_constant_velocity(z, dt)
    q = dt * (2 * np.pi * 6.0) ** 4
    for n in range(2):
        kf = KalmanFilter(dim_x=2, dim_z=1)
        kf.F, kf.H = np.array([[1, dt], [0, 1.0]]), np.array([[1.0, 0]])
        kf.Q = q * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
        kf.x, kf.P = np.array([[z[0, n]], [0.0]]), np.diag([DIFFUSE, DIFFUSE])
        mu, cov, _, _ = kf.batch_filter([None if np.isnan(v) else v for v in z[:, n]])
        np.testing.assert_allclose(ours[:, n], kf.rts_smoother(mu, cov)[0][:, 0, 0], atol=1e-12)
    line = 0.3 - 0.8 * np.arange(T) * dt
    np.testing.assert_allclose(rts_constant_velocity(line[:, None], dt)[:, 0], line, atol=1e-4)  # 0.1 mm


def test_each_layouts_extra_keypoints_ride_on_their_joint():
    assert extra_keypoints("body25b") == ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_big_toe",
                                          "left_small_toe", "left_heel", "right_big_toe", "right_small_toe",
                                          "right_heel")
    assert extra_keypoints("body25") == extra_keypoints("body25b")[:1] + ("right_eye", "left_eye", "right_ear",
                                                                          "left_ear") + extra_keypoints("body25b")[5:]
    assert extra_keypoints("coco17") == ("nose", "left_eye", "right_eye", "left_ear", "right_ear")
    assert len(extra_keypoints("mediapipe33")) == 33 - 12
    names = {k: EVAL15_NAMES[parent_joint(k)] for k in ("left_big_toe", "right_heel", "left_foot_index", "nose",
                                                        "right_ear", "mouth_left", "left_pinky", "right_thumb")}
    assert names == {"left_big_toe": "lankle", "right_heel": "rankle", "left_foot_index": "lankle", "nose": "head",
                     "right_ear": "head", "mouth_left": "head", "left_pinky": "lwrist", "right_thumb": "rwrist"}
    assert [marker_name(k) for k in ("left_big_toe", "right_small_toe", "right_heel", "nose", "left_ear")] == [
        "LBigToe", "RSmallToe", "RHeel", "Nose", "LEar"]


def _cameras():
    """Three cameras 4 m around a Z-up room, 1 m high, looking at its middle."""
    return [PinholeCamera.look_at([4 * np.cos(a), 4 * np.sin(a), 1.0], [0.0, 0.0, 0.5], up=(0, 0, 1))
            for a in (0.0, 2.0, 4.0)]


def test_a_persons_feet_are_recovered_from_three_cameras_and_a_detectors_error_is_not_taken():
    """A walker's ankles move (the tracked joints, given); the big toes and heels sit at offsets that turn with the
    foot; their detections (1.5 px noise, one far outlier a foot, one foot unseen for 0.2 s, the face never seen)
    are carried within a centimetre; a single camera carries nothing."""
    cameras, fps, F = _cameras(), 60.0, 120
    t = np.arange(F) / fps
    joints = np.full((F, 15, 3), np.nan)
    joints[:, :, :] = [0.0, 0.0, 1.0]
    for side, j in ((0.1, EVAL15_NAMES.index("lankle")), (-0.1, EVAL15_NAMES.index("rankle"))):
        joints[:, j] = np.stack([0.8 * t, np.full(F, side), 0.08 + 0.05 * np.sin(2 * np.pi * t)], axis=1)
    extras = extra_keypoints("body25b")
    truth = np.full((F, len(extras), 3), np.nan)
    heading = 0.4 * np.sin(2 * np.pi * 0.5 * t)                                     # the foot turns
    for e, k in enumerate(extras):
        if k.endswith(("toe", "heel")):
            length = {"big_toe": 0.18, "small_toe": 0.15, "heel": -0.06}[k.split("_", 1)[1]]
            offset = length * np.stack([np.cos(heading), np.sin(heading), -0.05 * np.ones(F)], axis=1)
            truth[:, e] = joints[:, parent_joint(k)] + offset
    rng = np.random.default_rng(1)
    keypoints = np.full((3, F, 25, 3), np.nan)
    layout = LAYOUTS["body25b"]
    for c, camera in enumerate(cameras):
        for e, k in enumerate(extras):
            if np.isfinite(truth[:, e]).all():
                uv, _ = camera.project(truth[:, e][:, None])
                keypoints[c, :, layout.index(k), :2] = uv[:, 0] + rng.normal(0, 1.5, (F, 2))
                keypoints[c, :, layout.index(k), 2] = 0.9
    big_toe = layout.index("left_big_toe")
    keypoints[:, 30, big_toe, :2] += [300.0, -200.0]                                 # a detector's error, every view
    keypoints[:, 60:72, layout.index("right_heel")] = np.nan                           # unseen 0.2 s
    out, names = carried(keypoints, "body25b", cameras, joints, fps, 0.3, (5.0, 4.0))
    assert names[5:] == ("LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel")
    feet = np.isfinite(truth).all(axis=(0, 2))
    error = np.linalg.norm(out[:, feet] - truth[:, feet], axis=-1)
    assert np.isfinite(error).all() and np.median(error) < 0.004 and error.max() < 0.012, (np.median(error), error.max())
    assert np.isnan(out[:, ~feet]).all()                                            # the face: never seen
    alone, _ = carried(keypoints[:1], "body25b", cameras[:1], joints, fps, 0.3, (5.0, 4.0))
    assert np.isnan(alone).all()
    gone = keypoints.copy()
    gone[:, 40:, big_toe] = np.nan                                                   # not seen again: carried 0.5 s
    out, _ = carried(gone, "body25b", cameras, joints, fps, 0.3, (5.0, 4.0))
    shown = np.isfinite(out[:, 5, 0])
    assert shown[:40 + int(MAX_GAP_S * fps) - 1].all() and not shown[40 + int(MAX_GAP_S * fps):].any()


@pytest.fixture(scope="module")
def participant(tmp_path_factory):
    folder = tmp_path_factory.mktemp("feet")
    assert main(["track", "--detections", str(MULTIPERSON / "pose"), "--cameras",
                 str(MULTIPERSON / "calibration" / "Calib.qca.txt"), "--fps", "60", "--people", "all", "--smooth",
                 "--lowpass", "6", "--out", str(folder / "s.trc"), "--out", str(folder / "s.npz"),
                 "--out", str(folder / "s.csv")]) == 0
    return folder


def test_the_demo_participants_trc_has_every_keypoint_at_60_fps_near_pose2sims_and_as_smooth(participant):
    """Issue 60's figures: Pose2Sim's demo participant (person 1) as a TRC at 60 fps, 100 frames, with a toe and a
    heel each side; the 12 limb joints and the feet within 25 / 20 mm median of Pose2Sim's own triangulation
    (measured 19.6 / 15.0; 16.1 / 11.5 from its Butterworth-filtered output); the right wrist's acceleration RMS
    (central differences) at most that of Pose2Sim's Butterworth output (measured 8.7 against 11.1 m/s²)."""
    ours, names, fps = read_trc(participant / "s_person1.trc", up="z")
    assert fps == 60.0 and ours.shape == (100, 26, 3) and np.isfinite(ours).all()
    assert {"LBigToe", "LHeel", "RBigToe", "RHeel", "LSmallToe", "RSmallToe", "Nose"} <= set(names)
    theirs, their_names, _ = read_trc(str(POSE2SIM_P2).format(""), up="z")
    filtered, _, their_fps = read_trc(str(POSE2SIM_P2).format("_filt_butterworth"), up="z")
    assert their_fps == 60.0 and len(theirs) == 100
    limbs = [s + p for s in "LR" for p in ("Shoulder", "Elbow", "Wrist", "Hip", "Knee", "Ankle")]
    feet = [s + p for s in "LR" for p in ("BigToe", "SmallToe", "Heel")]
    for markers, bound in ((limbs, 0.025), (feet, 0.020)):
        a, b = [names.index(m) for m in markers], [their_names.index(m) for m in markers]
        assert np.median(np.linalg.norm(ours[:, a] - theirs[:, b], axis=-1)) < bound, markers

    def acceleration(X):
        return np.sqrt(np.mean(np.sum(((X[2:] - 2 * X[1:-1] + X[:-2]) * 60.0 ** 2) ** 2, axis=-1)))

    assert acceleration(ours[:, names.index("RWrist")]) <= acceleration(filtered[:, their_names.index("RWrist")])
    with np.load(participant / "s.npz") as z:
        assert z["keypoints"].shape == (100, 2, 11, 3) and "RHeel" in z["keypoint_names"].tolist()
        assert float(z["fps"]) == 60.0 and float(z["lowpass_hz"]) == 6.0
        assert z["limbs_left_right_m"].shape == (2, 4, 2) and 1.6 < z["height_m"][1] < 1.8    # each person's body
        heels = z["keypoints"][:, 1, list(z["keypoint_names"]).index("RHeel")]
    rows = np.genfromtxt(participant / "s.csv", delimiter=",", names=True)
    mine = rows[rows["person"] == 1]
    from_csv = np.column_stack([mine["RHeel_x"], mine["RHeel_y"], mine["RHeel_z"]])        # the world's axes
    np.testing.assert_allclose(from_csv, heels, atol=1e-8)
    np.testing.assert_allclose(from_csv, ours[:, names.index("RHeel")], atol=1e-8)      # the TRC read back to them


def test_eval_against_trc_gives_issue_60s_figures(tmp_path, capsys):
    """``priortrack eval against-trc``: the demo, against Pose2Sim's Butterworth output of the participant (the person
    it picks, by the limbs): the 12 limb joints within 21 mm median in every run (measured 16.8–18.6), the feet within
    15 (11.5–12.5), the right wrist's acceleration at most the reference's with the low-pass (8.7 and 9.0 against
    11.1) and above it without (22–26: the issue's 17.4 at 30 fps); a TRC without limb markers is refused by name."""
    import json

    common = ["eval", "against-trc", "--detections", str(MULTIPERSON / "pose"), "--cameras",
              str(MULTIPERSON / "calibration" / "Calib.qca.txt"), "--fps", "60"]
    assert main(common + ["--reference", str(POSE2SIM_P2).format("_filt_butterworth"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["person"] == 1 and result["frames"] == 100 and result["fps"] == 60.0
    rows = {r["run"]: r for r in result["rows"]}
    assert list(rows) == ["filtered", "--lowpass 6", "--smooth", "--smooth --lowpass 6"]
    assert all(r["limbs_mm"] < 21 and r["feet_mm"] < 15 for r in rows.values()), rows
    reference = result["reference_wrist_m_s2"]
    assert 11.0 < reference < 11.2
    assert rows["--smooth --lowpass 6"]["wrist_m_s2"] <= reference and rows["--lowpass 6"]["wrist_m_s2"] <= reference
    assert rows["--smooth"]["wrist_m_s2"] > reference and rows["filtered"]["wrist_m_s2"] > reference
    write_trc(tmp_path / "nolimbs.trc", np.zeros((100, 1, 3)), ["Nose"], 60.0, up="z")
    assert main(common + ["--reference", str(tmp_path / "nolimbs.trc")]) == 2
    assert "nolimbs.trc: none of its markers is a limb joint's" in capsys.readouterr().err


def test_eval_against_trc_from_one_camera(tmp_path, capsys):
    """One camera's folder of the demo (cam03, matched by --camera-map; --height the participant's 1.72 m as four
    cameras measure them): the person picked is the participant (id 0 of that camera's scene), within 0.3 m median of
    Pose2Sim's four-camera triangulation over the limbs in every run (measured 132–226 mm with 1.7 m: one view's
    depth), where the synthetic person stands a metre off; no feet (one camera triangulates no further keypoint)."""
    import json
    import shutil

    folder = tmp_path / "pose"
    shutil.copytree(MULTIPERSON / "pose" / "cam03_json", folder / "cam03_json")
    assert main(["eval", "against-trc", "--detections", str(folder), "--cameras",
                 str(MULTIPERSON / "calibration" / "Calib.qca.txt"), "--camera-map", "cam03_json=cam_03", "--fps", "60",
                 "--height", "1.72", "--reference", str(POSE2SIM_P2).format(""), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["person"] == 0 and result["frames"] == 100
    assert all(r["limbs_mm"] < 300 and r["feet_mm"] is None for r in result["rows"]), result["rows"]


def test_one_camera_writes_no_further_keypoints(tmp_path):
    """One camera triangulates nothing: its TRC and npz carry the 15 joints only (no empty marker columns)."""
    from priortrack.data.bundled import POSE2SIM_DIR

    assert main(["track", "--detections", str(POSE2SIM_DIR / "pose" / "cam01_json"), "--cameras",
                 str(POSE2SIM_DIR / "Calib.toml"), "--camera-map", "cam01_json=cam_01", "--fps", "60", "--out",
                 str(tmp_path / "one.trc"), "--out", str(tmp_path / "one.npz")]) == 0
    _, names, fps = read_trc(tmp_path / "one.trc", up="z")
    assert len(names) == 15 and fps == 60.0
    with np.load(tmp_path / "one.npz") as z:
        assert "keypoints" not in z.files
