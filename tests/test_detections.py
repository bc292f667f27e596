"""Detections from real OpenPose output (Pose2Sim's demo, BODY_25B, 4 cameras) and from files in the
documented COCO, MediaPipe and NPZ layouts; the eval15 map; following one person; triangulation."""

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.calibration import read_calibration
from priortrack.data.detections import read_detections
from priortrack.data.keypoints import LAYOUTS
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.triangulation import triangulate, undistort_normalised

POSE2SIM = POSE2SIM_DIR


def _cameras():
    return [PinholeCamera.from_calibration(c) for c in read_calibration(POSE2SIM / "Calib.toml").cameras]


def test_real_openpose_body25b_is_told_from_body25_and_reads(caplog):
    """25 keypoints are BODY_25 or BODY_25B: without --keypoints the bundled BODY_25B trial is read as BODY_25B, said
    in the log (its keypoint 8 is no midpoint of 9 and 12), as it is read with the layout named."""
    with caplog.at_level(logging.INFO, logger="priortrack.data.keypoints"):
        found = read_detections(POSE2SIM / "pose")
    assert found.layout == "body25b" and "read as BODY_25B: keypoint 8 is not the midpoint" in caplog.text
    d = read_detections(POSE2SIM / "pose", keypoints="BODY_25B")
    np.testing.assert_array_equal(found.keypoints, d.keypoints)
    assert d.keypoints.shape == (4, 12, 25, 3) and d.layout == "body25b"
    assert d.camera_names == ("cam01_json", "cam02_json", "cam03_json", "cam04_json")
    assert d.frames.tolist() == list(range(12)) and d.switches == (0, 0, 0, 0)
    raw = json.loads((POSE2SIM / "pose" / "cam02_json" / "Static_cam_02.00005.json").read_text())
    expected = np.array(raw["people"][0]["pose_keypoints_2d"]).reshape(25, 3)
    expected[expected[:, 2] == 0, :2] = np.nan                            # OpenPose's (0, 0, 0): not found
    assert d.keypoints.dtype == np.float32
    np.testing.assert_array_equal(d.keypoints[1, 5], expected.astype(np.float32))
    uv, conf = d.eval15(min_confidence=0.3)
    k = d.keypoint_names.index
    body = d.keypoints[2, 7]
    np.testing.assert_allclose(uv[2, 7, 0], (body[k("left_hip"), :2] + body[k("right_hip"), :2]) / 2)    # pelvis
    np.testing.assert_allclose(uv[2, 7, 1], (body[k("left_shoulder"), :2] + body[k("right_shoulder"), :2]) / 2)
    np.testing.assert_allclose(uv[2, 7, 2], body[k("head_top"), :2])                                    # head
    np.testing.assert_allclose(uv[2, 7, 4], body[k("left_elbow"), :2])                                  # lelbow
    assert conf[2, 7, 0] == min(body[k("left_hip"), 2], body[k("right_hip"), 2])


def test_the_real_trial_triangulates_to_a_standing_person():
    """DLT through the distortion model: a Z-up world, ankles near the floor, head ~1.7 m, and a
    median reprojection error near the 13 px the data's SOURCE.md reports."""
    cameras = _cameras()
    uv, conf = read_detections(POSE2SIM / "pose", keypoints="body25b").eval15(0.3)
    X = triangulate(cameras, uv, conf)                                   # (12, 15, 3)
    assert np.isfinite(X).all()
    assert np.all(np.abs(X[:, [11, 14], 2]) < 0.2) and np.all(np.abs(X[:, 2, 2] - 1.7) < 0.1)
    reprojected = np.stack([c.project(X)[0] for c in cameras])
    median = float(np.nanmedian(np.linalg.norm(reprojected - uv, axis=-1)))
    assert 8 < median < 16


def test_triangulation_and_undistortion_are_exact_on_projected_points():
    cameras = _cameras()
    X = np.random.default_rng(0).uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 1.8], size=(40, 15, 3))
    uv = np.stack([c.project(X)[0] for c in cameras])
    np.testing.assert_allclose(triangulate(cameras, uv), X, atol=1e-9)
    Xc = X @ cameras[0].R.numpy().T + cameras[0].t.numpy()
    np.testing.assert_allclose(undistort_normalised(cameras[0], uv[0]), Xc[..., :2] / Xc[..., 2:], atol=1e-12)
    uv[1:, 0, 0] = np.nan                                                 # one camera left: not triangulated
    weights = np.ones(uv.shape[:-1])
    weights[0, 0, 1] = 0.0
    uv[2:, 0, 1] = np.nan                                                 # two cameras, one of weight 0
    X_hat = triangulate(cameras, uv, weights)
    assert np.isnan(X_hat[0, :2]).all() and np.isfinite(X_hat[0, 2:]).all()


def _openpose_frame(folder: Path, number: int, people: list[list[float]]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"clip_{number:012d}_keypoints.json").write_text(
        json.dumps({"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": p} for p in people]}))


def _person(offset: float, K: int = 17, conf: float = 0.9) -> list[float]:
    rng = np.random.default_rng(int(offset))
    xy = offset + rng.uniform(0, 100, size=(K, 2))
    return np.concatenate([xy, np.full((K, 1), conf)], axis=1).ravel().tolist()


def test_several_people_the_same_one_is_followed_and_a_jump_is_not_taken(tmp_path):
    folder = tmp_path / "cam"
    _openpose_frame(folder, 0, [_person(500, conf=0.5), _person(100)])       # the more confident: at 100
    _openpose_frame(folder, 1, [_person(101), _person(502)])
    _openpose_frame(folder, 2, [_person(499)])                               # only the other person
    _openpose_frame(folder, 3, [_person(500), _person(102)])
    d = read_detections(folder)
    assert d.layout == "coco17" and d.switches == (1,)
    np.testing.assert_array_equal(d.keypoints[0, 1].ravel(), np.float32(_person(101)))
    assert np.isnan(d.keypoints[0, 2]).all()
    np.testing.assert_array_equal(d.keypoints[0, 3].ravel(), np.float32(_person(102)))
    pinned = read_detections(folder, person=1)
    np.testing.assert_array_equal(pinned.keypoints[0, 0].ravel(), np.float32(_person(100)))
    assert np.isnan(pinned.keypoints[0, 2]).all()
    # every person read once, then followed (track --detections of an OpenPose folder): the same person
    from priortrack.data.scene_detections import read_scene_detections

    coco = tmp_path / "results.json"
    coco.write_text(json.dumps([{"image_id": n, "category_id": 1, "keypoints": person, "score": 0.9}
                                for n, people in enumerate([[_person(500, conf=0.5), _person(100)], [_person(101)],
                                                            [_person(499)], [_person(500), _person(102)]])
                                for person in people]))
    multiperson = Path(__file__).parent / "data" / "pose2sim_multiperson" / "pose"
    for path, layout in ((folder, None), (POSE2SIM_DIR / "pose", "body25b"), (multiperson, "body25b"), (coco, None)):
        once, twice = read_scene_detections(path, layout).followed(), read_detections(path, layout)
        np.testing.assert_array_equal(once.keypoints, twice.keypoints)
        assert (once.switches, once.camera_names, once.layout) == (twice.switches, twice.camera_names, twice.layout)
        np.testing.assert_array_equal(once.frames, twice.frames)
    # the person at an index of each frame's list (track --people index:N): what person=N reads
    from priortrack.tracking.scene import SceneAssociation

    for path, layout, index in ((folder, None, 1), (multiperson, "body25b", 0), (multiperson, "body25b", 2)):
        scene = read_scene_detections(path, layout)
        np.testing.assert_array_equal(SceneAssociation.indexed(scene, index).detections_of(scene, 0).keypoints,
                                      read_detections(path, layout, person=index).keypoints)
    with pytest.raises(PriortrackError, match=r"no frame lists 7 people \(at most 2; indices from 0\)"):
        SceneAssociation.indexed(read_scene_detections(folder), 6)


def test_coco_results_mediapipe_and_npz(tmp_path):
    coco = tmp_path / "results.json"
    coco.write_text(json.dumps([{"image_id": 7, "category_id": 1, "keypoints": _person(100), "score": 0.9},
                                {"image_id": 3, "category_id": 1, "keypoints": _person(200), "score": 0.8}]))
    d = read_detections(coco)
    assert d.layout == "coco17" and d.frames.tolist() == [3, 7] and d.keypoints.shape == (1, 2, 17, 3)
    folder = tmp_path / "mp"
    _openpose_frame(folder, 0, [_person(100, K=33)])
    assert read_detections(folder).layout == "mediapipe33"
    kp = np.random.default_rng(0).uniform(0, 500, size=(2, 5, 17, 3))
    kp[..., 2] = 0.8
    kp[0, 1, 3] = [np.nan, np.nan, 0.0]
    np.savez(tmp_path / "d.npz", keypoints=kp, keypoint_names=np.array(LAYOUTS["coco17"]), fps=np.array(60.0),
             camera_names=np.array(["left", "right"]))
    d = read_detections(tmp_path / "d.npz")
    assert d.fps == 60.0 and d.camera_names == ("left", "right") and np.isnan(d.keypoints[0, 1, 3]).all()
    uv, conf = d.eval15(0.5)
    assert uv.shape == (2, 5, 15, 2) and conf[0, 0, 3] == 0.8


@pytest.mark.parametrize("files, message", [
    ({"a_0.json": {"people": [{"pose_keypoints_2d": [1.0] * 60}]}}, "20 keypoints per person fit no layout"),
    ({"a_0.json": {"persons": []}}, "not OpenPose JSON"),
    ({"a_0.json": {"people": [{"pose_keypoints_2d": [1.0, 2.0, -0.5] * 17}]}}, "confidence -0.5"),
    ({"a_0.json": {"people": [{"pose_keypoints_2d": [1.0, 2.0, float("nan")] * 17}]}}, "confidence nan"),
    ({"a_0.json": {"people": []}}, "nobody is detected"),
    ({"a_0.json": {"people": [{"pose_keypoints_2d": []}]}}, "nobody is detected"),
    ({"a_0.json": {"people": [{"pose_keypoints_2d": [1, 2]}]}}, "not a list of x, y, confidence triples"),
    ({"a_1.json": {"people": []}, "b_01.json": {"people": []}}, "frame 1 appears twice"),
    ({"nodigits.json": {"people": []}}, "no frame number"),
])
def test_bad_detections_name_the_file_and_field(tmp_path, files, message):
    for name, content in files.items():
        (tmp_path / name).write_text(json.dumps(content))
    with pytest.raises(PriortrackError, match=message):
        read_detections(tmp_path)


def test_bad_npz_and_arguments(tmp_path):
    np.savez(tmp_path / "names.npz", keypoints=np.zeros((1, 2, 17, 3)), keypoint_names=np.array(["a"] * 17))
    with pytest.raises(PriortrackError, match="are not one layout.s"):
        read_detections(tmp_path / "names.npz")
    kp = np.ones((1, 2, 17, 3))
    kp[0, 0, 0, 2] = -1
    np.savez(tmp_path / "neg.npz", keypoints=kp, keypoint_names=np.array(LAYOUTS["coco17"]))
    with pytest.raises(PriortrackError, match="negative confidences"):
        read_detections(tmp_path / "neg.npz")
    np.savez(tmp_path / "order.npz", keypoints=np.ones((1, 2, 17, 3)), keypoint_names=np.array(LAYOUTS["coco17"]),
             frames=np.array([5, 3]))
    with pytest.raises(PriortrackError, match="frames must be 2 increasing integers"):
        read_detections(tmp_path / "order.npz")
    with pytest.raises(PriortrackError, match="unknown keypoint layout 'body26'"):
        read_detections(POSE2SIM / "pose", keypoints="body26")
    with pytest.raises(PriortrackError, match="layout coco17 has 17"):
        read_detections(POSE2SIM / "pose", keypoints="coco17")
    with pytest.raises(PriortrackError, match="do not exist"):
        read_detections(tmp_path / "nothing.json")
    with pytest.raises(PriortrackError, match="min_confidence"):
        read_detections(POSE2SIM / "pose", keypoints="body25b").eval15(1.5)


def test_triangulation_in_chunks_is_the_same(monkeypatch):
    """A long recording is triangulated CHUNK points at a time (its memory flat): the same points."""
    from priortrack.geometry import triangulation

    cameras = _cameras()
    uv, conf = read_detections(POSE2SIM / "pose", keypoints="body25b").eval15(0.3)
    whole = triangulate(cameras, uv, conf)
    monkeypatch.setattr(triangulation, "CHUNK", 7)
    np.testing.assert_array_equal(triangulate(cameras, uv, conf), whole)


def test_an_empty_keypoint_list_is_a_person_not_there():
    """Pose2Sim's multi-person demo: cam01's frame 1 holds an entry whose ``pose_keypoints_2d`` is []
    (the participant left out) beside two people; it is nobody, not an error, and the other entries
    of that file are read."""
    folder = Path(__file__).parent / "data" / "pose2sim_multiperson" / "pose"
    d = read_detections(folder, keypoints="body25b")
    assert d.camera_names == ("cam01_json", "cam02_json", "cam03_json", "cam04_json")
    assert d.keypoints.shape == (4, 100, 25, 3) and np.isfinite(d.keypoints[0, 1, :, :2]).any()


def test_a_25_keypoint_layout_read_as_the_other_is_refused_naming_it(tmp_path, capsys):
    """issue 60, item 4: BODY_25B read as BODY_25 made bodies of no one (a 0.63 m thigh, hips 0.66 m apart) and the run
    exited 0. BODY_25's keypoint 8 (MidHip) is the midpoint of 9 and 12; BODY_25B's 8, 9, 12 are an elbow, a wrist and
    a hip. The bundled BODY_25B trial read as BODY_25 is refused, naming --keypoints body25b; BODY_25 detections (8 the
    hips' midpoint, written here) read as BODY_25B are refused naming body25; each read as itself is taken, and a
    file with too few people-frames to tell is taken as named."""
    from priortrack.cli.main import main
    from priortrack.data.keypoints import settled_layout
    from priortrack.data.scene_detections import read_scene_detections

    with pytest.raises(PriortrackError, match=r"read as BODY_25 \(--keypoints body25\), but its keypoint 8 is not "
                                              r"the midpoint of 9 and 12 .*--keypoints body25b"):
        read_detections(POSE2SIM / "pose", keypoints="body25")
    with pytest.raises(PriortrackError, match="--keypoints body25b"):
        read_scene_detections(POSE2SIM / "pose", keypoints="body25")
    read_detections(POSE2SIM / "pose", keypoints="body25b")
    rng = np.random.default_rng(0)
    camera = tmp_path / "cam01"
    camera.mkdir()
    for t in range(12):
        kp = np.column_stack([rng.uniform(100, 500, (25, 2)), np.full(25, 0.9)])
        kp[8, :2] = 0.5 * (kp[9, :2] + kp[12, :2]) + rng.normal(0, 1, 2)          # MidHip
        (camera / f"walk_{t:012d}_keypoints.json").write_text(
            json.dumps({"people": [{"pose_keypoints_2d": kp.ravel().tolist()}]}))
    read_detections(tmp_path, keypoints="body25")
    assert read_detections(tmp_path).layout == read_scene_detections(tmp_path).layout == "body25"     # told, unnamed
    with pytest.raises(PriortrackError, match=r"read as BODY_25B .*is the midpoint of 9 and 12.*--keypoints body25\b"):
        read_detections(tmp_path, keypoints="body25b")
    assert settled_layout(np.full((1, 5, 25, 3), 1.0), ("body25b",), "few") == "body25b"   # nothing to tell it by
    with pytest.raises(PriortrackError, match=r"few: 25 keypoints fit body25 and body25b, and too few people-frames "
                                              r"\(5\) show keypoints 8, 9 and 12 to tell which; say which"):
        settled_layout(np.full((1, 5, 25, 3), 1.0), ("body25", "body25b"), "few")
    assert main(["track", "--detections", str(POSE2SIM / "pose"), "--cameras", str(POSE2SIM / "Calib.toml"),
                 "--keypoints", "body25", "--fps", "60", "--filter", "ukf-real"]) == 2
    assert "--keypoints body25b" in capsys.readouterr().err
