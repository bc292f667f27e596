"""Detections as the users' tools write them: caliscope's long-format CSV (its real MediaPipe
recording, its three column sets, its cameras aligned by time), FreeMoCap-style .npy arrays, NPZ
files with the detector's own keypoint names and OpenPose's (0, 0, 0) for a missing point; the
caliscope recording tracked straight from its own files, "up" found from the person."""

import csv
import json
import logging
from pathlib import Path

import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.cli.main import main
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.caliscope import align_by_time
from priortrack.data.calibration import read_calibration
from priortrack.data.detections import read_detections
from priortrack.data.keypoints import LAYOUTS

CALISCOPE = Path(__file__).parent / "data" / "caliscope_4cam"
CHARUCO = Path(__file__).parent / "data" / "formats" / "caliscope" / "post_optimization_xy_CHARUCO.csv"
#: OpenPose's own names of BODY_25B, as Pose2Sim's skeletons give them.
BODY25B_OPENPOSE = ("Nose", "LEye", "REye", "LEar", "REar", "LShoulder", "RShoulder", "LElbow", "RElbow", "LWrist",
                    "RWrist", "LHip", "RHip", "LKnee", "RKnee", "LAnkle", "RAnkle", "Neck", "Head", "LBigToe",
                    "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel")


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _write(path: Path, columns: list[str], rows: list[dict]) -> Path:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    return path


def test_caliscope_recording_reads_with_its_cameras_aligned_by_time(caplog):
    """The real file: 4 cameras named as its calibration names them, MediaPipe-33, confidence 1 (said),
    hands and face left out, ~30 fps from its frame times (not config's 24), each detection where the
    file put it at the camera's own frame times."""
    path = CALISCOPE / "xy_HOLISTIC.csv"
    with caplog.at_level(logging.INFO, logger="priortrack"):
        d = read_detections(path)
    assert "no confidence" in caplog.text and "aligned by their frame times" in caplog.text
    assert d.camera_names == read_calibration(CALISCOPE / "config.toml").names == ("cam_0", "cam_1", "cam_2", "cam_3")
    assert d.layout == "mediapipe33" and 29.5 < d.fps < 31
    rows = _rows(path)
    t0 = min(float(r["frame_time"]) for r in rows)
    # a grid frame that falls on a sample's own time holds that sample's pixels
    for r in rows[:: len(rows) // 40]:
        c, point = int(r["port"]), int(r["point_id"])
        i = (float(r["frame_time"]) - t0) * d.fps
        if abs(i - round(i)) < 1e-6:
            np.testing.assert_allclose(d.keypoints[c, round(i), point], [float(r["img_loc_x"]), float(r["img_loc_y"]), 1])
    seen = np.isfinite(d.keypoints[..., 0])
    assert seen[:, :, 11].mean() > 0.9                     # the left shoulder, seen in nearly every frame


def test_caliscope_column_sets_and_frame_time_history(tmp_path):
    """The 2026 columns (cam_id, object_id, keypoint_id, no frame_time) read the same points; with a
    frame_time_history.csv beside them they are aligned by time as the 2023 file is."""
    rows = _rows(CALISCOPE / "xy_HOLISTIC.csv")
    for r in rows:
        r.update(cam_id=r["port"], object_id=0, keypoint_id=r["point_id"], obj_loc_z="")
    new = _write(tmp_path / "xy_HOLISTIC.csv", ["sync_index", "cam_id", "object_id", "keypoint_id", "img_loc_x",
                                                 "img_loc_y", "obj_loc_x", "obj_loc_y", "obj_loc_z"], rows)
    by_sync = read_detections(new)
    assert by_sync.fps is None and by_sync.frames.tolist() == list(range(90))
    first = next(r for r in rows if r["port"] == "2" and r["point_id"] == "12")
    np.testing.assert_allclose(by_sync.keypoints[2, int(first["sync_index"]), 12, :2],
                               [float(first["img_loc_x"]), float(first["img_loc_y"])])
    history = {(r["sync_index"], r["port"]): r["frame_time"] for r in rows}
    _write(tmp_path / "frame_time_history.csv", ["sync_index", "port", "frame_time"],
           [{"sync_index": s, "port": c, "frame_time": t} for (s, c), t in history.items()])
    aligned, original = read_detections(new), read_detections(CALISCOPE / "xy_HOLISTIC.csv")
    assert aligned.fps == pytest.approx(original.fps)
    np.testing.assert_array_equal(aligned.keypoints, original.keypoints)
    with pytest.raises(PriortrackError, match="ChArUco board corners, not a person"):
        read_detections(CHARUCO)
    bad = _write(tmp_path / "xy_POSE.csv", ["sync_index", "port", "point_id", "img_loc_x", "img_loc_y"],
                 [{"sync_index": 0, "port": 0, "point_id": 1, "img_loc_x": "x", "img_loc_y": 2}])
    with pytest.raises(PriortrackError, match="xy_POSE.csv: row 2 is not numbers"):
        read_detections(bad)


def test_align_by_time_is_exact_on_linear_motion():
    """Points moving linearly in time, sampled by two cameras at their own jittered times, land on
    one clock exactly where the motion puts them between two of a camera's samples; before its first
    sample or after its last, the nearest sample within half a frame is taken (off by at most the
    motion over half a frame: which grid points fall there depends on the jitter's draw); a gap
    longer than 1.5 frames stays missing."""
    rng = np.random.default_rng(3)
    T, dt = 40, 1 / 30
    times = np.arange(T)[:, None] * dt + rng.uniform(-0.01, 0.01, size=(T, 2)) + [0.0, 0.004]
    velocity, start = np.array([120.0, -40.0]), np.array([300.0, 200.0])
    keypoints = np.zeros((2, T, 1, 3))
    keypoints[..., 2] = 1.0
    keypoints[:, :, 0, :2] = (start + times.T[..., None] * velocity)
    keypoints[1, 10:13] = np.nan                           # camera 1 misses three frames
    aligned, step = align_by_time(keypoints, times)
    grid = times.min() + step * np.arange(aligned.shape[1])
    expected = start + grid[:, None] * velocity
    ok = np.isfinite(aligned[0, :, 0, 0])
    assert ok.sum() >= T - 2
    between = ok & (grid >= times[:, 0].min()) & (grid <= times[:, 0].max())
    np.testing.assert_allclose(aligned[0, between, 0, :2], expected[between], atol=1e-9)
    edge = ok & ~between
    assert (np.abs(aligned[0, edge, 0, :2] - expected[edge]) <= np.abs(velocity) * 0.5 * dt + 1e-9).all()
    gap = (grid > times[9, 1] + 0.5 * step) & (grid < times[13, 1] - 0.5 * step)
    assert gap.any() and np.isnan(aligned[1, gap, 0, 0]).all()


def test_freemocap_npy_and_npz_with_the_detectors_names(tmp_path):
    """A FreeMoCap-style (cameras, frames, 543, 2) array reads as MediaPipe-33 (NaN missing); an NPZ
    with OpenPose's own names in another order and (0, 0, 0) for missing points reads as the same
    detections as our names and NaN."""
    pose = read_detections(POSE2SIM_DIR / "pose", keypoints="body25b")
    xy = np.full((2, 5, 543, 2), np.nan)
    xy[:, :, :33] = np.random.default_rng(0).uniform(0, 1000, size=(2, 5, 33, 2))
    xy[0, 1, 11] = np.nan
    np.save(tmp_path / "mediapipe_2dData_numCams_numFrames_numTrackedPoints_pixelXY.npy", xy)
    d = read_detections(tmp_path / "mediapipe_2dData_numCams_numFrames_numTrackedPoints_pixelXY.npy")
    assert d.layout == "mediapipe33" and d.camera_names == ("cam_0", "cam_1") and d.keypoints.shape == (2, 5, 33, 3)
    np.testing.assert_array_equal(d.keypoints[..., :2], xy[:, :, :33].astype(np.float32))
    assert d.keypoints[1, 1, 11, 2] == 1.0 and np.isnan(d.keypoints[0, 1, 11]).all()

    order = np.random.default_rng(1).permutation(25)
    zeros = np.nan_to_num(pose.keypoints, nan=0.0)[:, :, order]
    missing = int(np.flatnonzero((zeros[0, 0, :, :2] == 0).all(axis=-1))[0])
    zeros[0, 0, missing, 2] = 0.4                          # (0, 0) with a confidence is missing too
    np.savez(tmp_path / "openpose.npz", keypoints=zeros, keypoint_names=np.array(BODY25B_OPENPOSE)[order], fps=60.0)
    read = read_detections(tmp_path / "openpose.npz")
    assert read.layout == "body25b"
    for a, b in zip(read.eval15(), pose.eval15()):
        np.testing.assert_array_equal(a, b)
    np.savez(tmp_path / "ours.npz", keypoints=pose.keypoints, keypoint_names=np.array(LAYOUTS["body25b"]), fps=60.0)
    np.testing.assert_array_equal(read_detections(tmp_path / "ours.npz").eval15()[0], read.eval15()[0])
    np.save(tmp_path / "odd.npy", np.zeros((1, 3, 40, 2)))
    with pytest.raises(PriortrackError, match="40 points per frame fit no layout"):
        read_detections(tmp_path / "odd.npy")


def test_caliscope_recording_tracks_from_its_own_files(tmp_path, caplog, capsys):
    """`track --detections xy_HOLISTIC.csv --cameras config.toml`: the format and the time alignment
    are recognised, "up" is found from the (seated) person within 12° of the two level webcams'
    image-up (which themselves differ by 10°), --frames limits the run, and the estimate reprojects
    within the detector's own error (the shared data's per-frame DLT: 8–17 px median all-view)."""
    with caplog.at_level(logging.INFO, logger="priortrack"):
        code = main(["track", "--detections", str(CALISCOPE / "xy_HOLISTIC.csv"), "--cameras",
                     str(CALISCOPE / "config.toml"), "--filter", "ukf-real", "--frames", "60", "--out",
                     str(tmp_path / "caliscope.npz"), "--json"])
    assert code == 0
    assert "caliscope config.toml" in caplog.text and "found from the person (pelvis to neck" in caplog.text
    summary = json.loads(capsys.readouterr().out)
    assert len(summary["up"]) == 3 and abs(np.linalg.norm(summary["up"]) - 1) < 1e-9
    assert max(summary["reprojection_px"].values()) < 30 and np.median(list(summary["reprojection_px"].values())) < 15
    result = np.load(tmp_path / "caliscope.npz")
    assert 50 <= len(result["frames"]) <= 60 and result["frames"].max() < 60
    calib = read_calibration(CALISCOPE / "config.toml")
    level = -(calib.cameras[0].R[1] + calib.cameras[3].R[1])
    level /= np.linalg.norm(level)
    index = {str(n): i for i, n in enumerate(result["joint_names"])}
    torso = np.nanmedian(result["joints"][:, index["neck"]] - result["joints"][:, index["pelvis"]], axis=0)
    assert np.degrees(np.arccos(torso @ level / np.linalg.norm(torso))) < 12


def _caliscope_cameras(kept: list[str]):
    """caliscope's detections and calibration of the cameras ``kept`` only, with the whole recording's up (found
    from the person in all 4, as compare --detections gives it to each run)."""
    from dataclasses import replace

    from priortrack.data.calibration import Calibration
    from priortrack.tracking.person import match_cameras, up_from_detections
    from priortrack.geometry.camera import PinholeCamera

    detections, calibration = read_detections(CALISCOPE / "xy_HOLISTIC.csv"), read_calibration(CALISCOPE / "config.toml")
    matched = match_cameras(detections, calibration, None)
    up = up_from_detections([PinholeCamera.from_calibration(c) for c in matched], detections, 0.3, calibration.source)
    index = [detections.camera_names.index(name) for name in kept]
    seen = replace(detections, keypoints=detections.keypoints[index], camera_names=tuple(kept),
                   switches=(0,) * len(index))
    return seen, Calibration(tuple(matched[c] for c in index), up, calibration.source, calibration.format,
                             calibration.units)


@pytest.mark.parametrize("left_out", ["cam_1", "cam_2"])
def test_caliscope_seated_person_starts_from_the_joints_its_other_cameras_see(left_out, caplog):
    """Without cam_1 or cam_2 the other webcams triangulate the seated person's upper body only (8 joints;
    the legs under the desk are seen by one camera): the start fits those 8 joints, the bones no tick
    measures take the template's proportions and the summary names them, and the estimate reprojects into
    every camera still used within the detector's error (the whole recording's up, as compare gives it)."""
    from priortrack.tracking.person import TrackConfig, track_detections

    seen, calibration = _caliscope_cameras([name for name in ("cam_0", "cam_1", "cam_2", "cam_3") if name != left_out])
    with caplog.at_level(logging.WARNING, logger="priortrack"):
        result = track_detections(seen, calibration, "ukf-real", TrackConfig(fps=30))
    assert "the trial shows 8 joints in most ticks" in caplog.text
    summary = result.summary()
    assert summary["bones_unmeasured"] == ["trunk", "hip_width", "thigh", "shin"]
    assert max(summary["reprojection_px"].values()) < 20, summary["reprojection_px"]
    assert np.isfinite(result.joints).all()


def test_caliscope_one_webcam_that_never_sees_the_legs_tracks_the_upper_body(caplog):
    """cam_0 alone sees the seated person's neck, head, shoulders and right arm in most ticks: the start fits
    those, its depth from the upper body's least foreshortened length, with a warning that says what that costs;
    the upper body lands within 0.3 m (median) of the 4-camera track (one camera's depth: 164 mm when measured)
    and reprojects within the detector's error."""
    from priortrack.tracking.person import TrackConfig, track_detections

    every = track_detections(*_caliscope_cameras(["cam_0", "cam_1", "cam_2", "cam_3"]), "ukf-real", TrackConfig(fps=30))
    with caplog.at_level(logging.WARNING, logger="priortrack"):
        result = track_detections(*_caliscope_cameras(["cam_0"]), "ukf-real", TrackConfig(fps=30))
    assert "the trial shows 6 joints in most ticks" in caplog.text and "from one camera without the legs" in caplog.text
    assert result.summary()["reprojection_px"]["cam_0"] < 15
    T = min(len(result.joints), len(every.joints))
    upper = np.linalg.norm(result.joints[:T, 1:9] - every.joints[:T, 1:9], axis=-1)
    assert np.nanmedian(upper) < 0.3, np.nanmedian(upper)


def test_caliscope_smoothed_arms_stay_with_the_detections_the_filter_used():
    """Without cam_0, ukf-real with its whole-run smoother: the smoother conditions on the detections the
    filter updated with (its gate's and swap decisions), so no smoothed arm joint lies more than 40 mm
    further from the other webcams' per-frame triangulation than the filtered one (measured 17 mm). Gating
    again against its own posterior, the smoother had held the right arm out of two webcams and carried
    the right wrist 150–160 mm off for 8 ticks (123 mm further than the filtered). With every step spilled
    to disk, the filter's decisions are read back with them: the same smoothed joints."""
    from priortrack.data.eval15 import EVAL15_NAMES
    from priortrack.tracking.person import TrackConfig, track_detections
    from priortrack.geometry.camera import PinholeCamera
    from priortrack.geometry.triangulation import triangulate

    seen, calibration = _caliscope_cameras(["cam_1", "cam_2", "cam_3"])
    result = track_detections(seen, calibration, "ukf-real", TrackConfig(smooth=True))
    ticks = result.frames >= 0
    at = np.searchsorted(seen.frames, result.frames[ticks])
    uv, confidence = seen.eval15(0.3)
    arms = [EVAL15_NAMES.index(j) for j in ("lshoulder", "lelbow", "lwrist", "rshoulder", "relbow", "rwrist")]
    dlt = triangulate([PinholeCamera.from_calibration(c) for c in calibration.cameras], uv[:, at],
                      confidence[:, at])[:, arms]
    off = {name: np.linalg.norm(joints[ticks][:, arms] - dlt, axis=-1)
           for name, joints in (("smoothed", result.joints), ("filtered", result.filtered_joints))}
    assert np.isfinite(off["smoothed"]).sum() > 0.9 * off["smoothed"].size
    assert np.nanmax(off["smoothed"] - off["filtered"]) < 0.04
    # the filter's decisions travel with its steps spilled to disk too (memory 0): the same joints
    assert result.gated.sum() > 50
    spilled = track_detections(seen, calibration, "ukf-real", TrackConfig(smooth=True, memory=0))
    np.testing.assert_array_equal(spilled.joints, result.joints)
