"""``priortrack compare --detections`` (issue 28): filters scored on a recording by leaving each camera
out in turn, beside the other cameras' DLT, and against a 3D truth where one is given.

The recording is the real-format lab bench (a held-out walk written as OpenPose BODY_25B JSON through
the Pose2Sim demo's 4 real cameras, with a detector's noise, drops, swaps and outliers), so the truth
is known; the real trials (Pose2Sim's, caliscope's) are run in the README's table, not here."""

import csv
import json

import matplotlib.image
import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.cli.main import main
from priortrack.data.calibration import read_calibration
from priortrack.data.detections import read_detections
from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.data.trc import write_trc
from priortrack.experiments import compare_detections as module
from priortrack.experiments.compare import compare
from priortrack.experiments.compare_detections import ALL_CAMERAS, LIMBS, plan_detections, read_truth
from priortrack.experiments.real_format import DEFAULT_CALIBRATION, detector_keypoints, placed_walk, write_openpose
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.triangulation import triangulate

pytestmark = pytest.mark.xdist_group("compare_detections")     # one worker builds the grid

#: Pose2Sim's marker names for the limb joints (its TRC files' spelling).
POSE2SIM_NAMES = {"lshoulder": "LShoulder", "lelbow": "LElbow", "lwrist": "LWrist", "rshoulder": "RShoulder",
                  "relbow": "RElbow", "rwrist": "RWrist", "lhip": "LHip", "lknee": "LKnee", "lankle": "LAnkle",
                  "rhip": "RHip", "rknee": "RKnee", "rankle": "RAnkle"}


@pytest.fixture(scope="module")
def trial(tmp_path_factory):
    """A recording with its truth: OpenPose folders, the calibration, truth.npz (by frame number) and
    truth.trc (Pose2Sim's names, Y-up as TRC files are)."""
    folder = tmp_path_factory.mktemp("trial")
    calibration = read_calibration(DEFAULT_CALIBRATION)
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    X = placed_walk("walkjog:35_29", "z", seconds=1.0)
    write_openpose(detector_keypoints(X, cameras, np.random.default_rng(3)), folder / "pose")
    np.savez(folder / "truth.npz", joints=X, joint_names=np.array(EVAL15_NAMES), frames=np.arange(len(X)))
    write_trc(folder / "truth.trc", X[:, 3:], [POSE2SIM_NAMES[n] for n in LIMBS], 60.0, up="z")
    return folder, X, cameras


@pytest.fixture(scope="module")
def grid(trial, tmp_path_factory):
    folder, X, cameras = trial
    out = tmp_path_factory.mktemp("grid")
    configs = plan_detections(["ukf-real"], str(folder / "pose"), str(DEFAULT_CALIBRATION), 1,
                              truth=str(folder / "truth.npz"), keypoints="body25b", fps=60.0)
    return out, configs, compare(configs, out)


def test_each_camera_is_left_out_and_scored_beside_the_other_cameras_dlt(trial, grid):
    folder, X, cameras = trial
    out, configs, rows = grid
    assert [r["held_out"] for r in rows] == ["cam01", "cam02", "cam03", "cam04", ALL_CAMERAS]
    with open(out / "results.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert list(table[0])[:len(module.COLUMNS)] == list(module.COLUMNS) and "mpjpe_mm" in table[0]
    # the DLT of the three other cameras, recomputed here on the frames the run consumed, projected
    # into the fourth: the row's figures (the scoring's frame and joint bookkeeping)
    detections = read_detections(folder / "pose", keypoints="body25b")
    uv, confidence = detections.eval15(0.3)
    series = np.load(out / "runs" / f"{rows[0]['config_hash']}.npz")
    ticks = rows[0]["ticks"]
    assert series["error_px"].shape == series["dlt_px"].shape == (ticks, 12)
    for r in rows[:4]:
        c = ["cam01", "cam02", "cam03", "cam04"].index(r["held_out"])
        others = [k for k in range(4) if k != c]
        frames = np.load(out / "runs" / f"{r['config_hash']}.npz")["frames"].astype(int)
        assert (np.diff(frames) == 2).all()                 # 60 fps data, a 30 fps prior: every other frame
        dlt = triangulate([cameras[k] for k in others], uv[others][:, frames], confidence[others][:, frames])[:, 3:]
        projected, _ = cameras[c].project(np.nan_to_num(dlt))
        e = np.linalg.norm(projected - uv[c, frames, 3:], axis=-1)
        e = e[(confidence[c, frames, 3:] > 0) & np.isfinite(dlt).all(-1) & np.isfinite(e)]
        assert r["dlt_median_px"] == pytest.approx(np.median(e), rel=1e-9)
        # 3 px detector noise (1 % outliers) in both views: both are a few pixels off, not tens
        assert r["dlt_median_px"] < 8 and r["median_px"] < 8, r
    everything = rows[4]
    frames = np.load(out / "runs" / f"{everything['config_hash']}.npz")["frames"].astype(int)
    truth_dlt = triangulate(cameras, uv[:, frames], confidence[:, frames])[:, 3:]
    err = 1000 * np.linalg.norm(truth_dlt - X[frames, 3:], axis=-1)
    assert everything["dlt_mpjpe_mm"] == pytest.approx(np.nanmean(err), rel=1e-9)
    assert everything["mpjpe_mm"] < 25 and everything["dlt_mpjpe_mm"] < 40, everything


def test_the_summary_pools_the_cameras_and_names_the_dlt_row(grid):
    out, configs, rows = grid
    summary = (out / "summary.md").read_text()
    assert "| DLT |" in summary and "## Median by camera left out (px)" in summary and "## Median by joint" in summary
    result = module.summary(rows, {c.key: dict(np.load(out / "runs" / f"{c.key}.npz")) for c in configs})
    tracker, dlt = result["held_out"]["ukf-real"], result["held_out"]["DLT"]
    pooled = np.concatenate([np.load(out / "runs" / f"{r['config_hash']}.npz")["error_px"].ravel() for r in rows[:4]])
    assert tracker["median_px"] == pytest.approx(np.nanmedian(pooled), rel=1e-12)
    assert tracker["ratio_median"] == pytest.approx(tracker["median_px"] / dlt["median_px"], rel=1e-12)
    assert set(tracker["by_camera"]) == {"cam01", "cam02", "cam03", "cam04"} and list(tracker["by_joint"]) == list(LIMBS)
    assert tracker["mpjpe_mm"] == pytest.approx(rows[4]["mpjpe_mm"]) and dlt["mpjpe_mm"] == pytest.approx(rows[4]["dlt_mpjpe_mm"])
    for name in ("held_out_cdf.png", "held_out_joints.png"):
        assert matplotlib.image.imread(out / "plots" / name).shape[2] in (3, 4)


def test_a_low_passed_grid_scores_beside_the_low_passed_dlt(trial, tmp_path, capsys):
    """``--lowpass 6``: each estimate through the Butterworth at the ticks' rate (its runs' keys differ from the plain
    grid's), and the row "DLT + low-pass": every frame's DLT of the other cameras through the filter at the data's
    60 fps, scored on the run's frames (recomputed here); a cut-off at or above 15 Hz (the 30 fps ticks' Nyquist) is
    refused before any work."""
    from priortrack.tracking.lowpass import lowpassed

    folder, X, cameras = trial
    configs = plan_detections(["ukf-real"], str(folder / "pose"), str(DEFAULT_CALIBRATION), 1, keypoints="body25b",
                              fps=60.0, lowpass=6.0)
    rows = compare(configs, tmp_path)
    detections = read_detections(folder / "pose", keypoints="body25b")
    uv, confidence = detections.eval15(0.3)
    for r in rows:
        c = ["cam01", "cam02", "cam03", "cam04"].index(r["held_out"])
        others = [k for k in range(4) if k != c]
        frames = np.load(tmp_path / "runs" / f"{r['config_hash']}.npz")["frames"].astype(int)
        dlt = lowpassed(triangulate([cameras[k] for k in others], uv[others], confidence[others])[:, 3:], 60.0, 6.0)
        projected, _ = cameras[c].project(np.nan_to_num(dlt[frames]))
        e = np.linalg.norm(projected - uv[c, frames, 3:], axis=-1)
        e = e[(confidence[c, frames, 3:] > 0) & np.isfinite(dlt[frames]).all(-1) & np.isfinite(e)]
        assert r["dlt_lowpass_median_px"] == pytest.approx(np.median(e), rel=1e-9)
        assert r["dlt_lowpass_median_px"] != pytest.approx(r["dlt_median_px"], rel=1e-6)
    table = module.summary(rows, {c.key: dict(np.load(tmp_path / "runs" / f"{c.key}.npz")) for c in configs})
    assert list(table["held_out"]) == ["ukf-real", "DLT", "DLT + low-pass"]
    assert "| DLT + low-pass |" in (tmp_path / "summary.md").read_text()
    plain = plan_detections(["ukf-real"], str(folder / "pose"), str(DEFAULT_CALIBRATION), 1, keypoints="body25b",
                            fps=60.0)
    assert {c.key for c in plain}.isdisjoint(c.key for c in configs)
    with pytest.raises(PriortrackError, match="--lowpass 15 Hz: the cut-off must lie between 0 and half"):
        plan_detections(["ukf-real"], str(folder / "pose"), str(DEFAULT_CALIBRATION), 1, keypoints="body25b",
                        fps=60.0, lowpass=15.0)


def test_a_rerun_does_no_work(grid, monkeypatch):
    out, configs, rows = grid
    monkeypatch.setattr(module, "run_detections", lambda *a, **k: pytest.fail("a cached run was run again"))
    assert compare(configs, out) == rows


def test_a_run_that_cannot_track_is_reported_and_the_others_scored(trial, tmp_path, monkeypatch):
    """Leaving a camera out can leave too few views to start (a seated person's legs in caliscope's
    webcams): that run's row says why, the summary lists it, the others are scored."""
    folder, X, cameras = trial
    from priortrack.tracking import person as real_module            # (the run imports it when it runs)

    tracked = real_module.track_detections

    def failing(detections, *args, **kwargs):
        if "cam02" not in detections.camera_names:
            raise PriortrackError("no two consecutive frames have 14 joints seen by two cameras: cannot start")
        return tracked(detections, *args, **kwargs)

    monkeypatch.setattr(real_module, "track_detections", failing)
    configs = plan_detections(["ukf-real"], str(folder / "pose"), str(DEFAULT_CALIBRATION), 1, keypoints="body25b",
                              fps=60.0, frames=40, joints=("lshoulder", "lelbow", "lwrist"))
    rows = compare(configs, tmp_path)
    assert [("error" in r) for r in rows] == [False, True, False, False]
    assert "cannot start" in rows[1]["error"] and rows[0]["median_px"] > 0
    summary = (tmp_path / "summary.md").read_text()
    assert "## Runs that could not track" in summary and "without cam02" in summary
    assert "| lshoulder | lelbow | lwrist |" in summary


def test_truth_files_of_either_kind_give_the_same_joints(trial):
    """A TRC with Pose2Sim's marker names (Y-up, turned back into the Z-up world) and an NPZ by frame
    number: the same positions; a truth that starts later is NaN before it."""
    folder, X, _ = trial
    detections = read_detections(folder / "pose", keypoints="body25b")
    calibration = read_calibration(DEFAULT_CALIBRATION)
    from_npz = read_truth(folder / "truth.npz", detections, calibration)
    from_trc = read_truth(folder / "truth.trc", detections, calibration)
    np.testing.assert_allclose(from_trc, from_npz, atol=1e-12)
    np.testing.assert_allclose(from_npz, X[:, 3:], atol=0)
    np.savez(folder / "late.npz", joints=X[10:], frames=np.arange(10, len(X)))
    late = read_truth(folder / "late.npz", detections, calibration)
    assert np.isnan(late[:10]).all() and np.allclose(late[10:], X[10:, 3:])


@pytest.mark.parametrize("change, message", [
    (dict(filters=[]), "at least one of --filters"),
    (dict(seeds=0), "--seeds must be a positive"),
    (dict(joints=("lshoulder", "nose")), "nose is not one"),
    (dict(joints=("lshoulder", "lshoulder")), "--joints must name distinct"),
    (dict(fps=None), "give it (--fps)"),
    (dict(truth="missing.npz"), "does not exist"),
    (dict(truth="truth.csv"), "give a .trc or .npz"),
    (dict(truth="few.npz"), "lacks the joints"),
    (dict(truth="slow.trc"), "is at 30 fps, the detections at 60"),
    (dict(truth="nameless.npz"), "has no 'joints' array"),
    (dict(truth="elsewhen.npz"), "covers none of the detections' frames"),
])
def test_bad_arguments_are_refused_before_any_work(trial, change, message):
    folder, X, _ = trial
    np.savez(folder / "few.npz", joints=X[:, :4], joint_names=np.array(EVAL15_NAMES[:4]))
    write_trc(folder / "slow.trc", X[:, 3:], list(LIMBS), 30.0, up="z")
    (folder / "truth.csv").write_text("x\n")
    np.savez(folder / "nameless.npz", points=X)
    np.savez(folder / "elsewhen.npz", joints=X, frames=np.arange(len(X)) + 10_000)
    arguments = dict(filters=["ukf-real"], detections=str(folder / "pose"), cameras=str(DEFAULT_CALIBRATION),
                     seeds=1, keypoints="body25b", fps=60.0) | change
    if isinstance(arguments.get("truth"), str):
        arguments["truth"] = str(folder / arguments["truth"])
    with pytest.raises(PriortrackError, match=message.replace("(", r"\(").replace(")", r"\)")):
        plan_detections(**arguments)


def test_one_camera_cannot_be_left_out(trial, tmp_path):
    folder, X, cameras = trial
    write_openpose(detector_keypoints(X, cameras[:1], np.random.default_rng(0)), tmp_path / "one")
    with pytest.raises(PriortrackError, match="needs two or more"):
        plan_detections(["ukf-real"], str(tmp_path / "one"), str(DEFAULT_CALIBRATION), 1, keypoints="body25b", fps=60.0)


def test_the_command_line(trial, grid, capsys):
    """`compare --detections` prints the summary (or JSON with the pooled table), reusing the grid's runs;
    mocap-only and detections-only options are refused in one line."""
    folder, X, _ = trial
    out, configs, rows = grid
    arguments = ["compare", "--detections", str(folder / "pose"), "--cameras", str(DEFAULT_CALIBRATION),
                 "--keypoints", "body25b", "--fps", "60", "--truth", str(folder / "truth.npz"),
                 "--filters", "ukf-real", "--out", str(out)]
    assert main(arguments + ["--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["rows"] == rows and printed["summary"]["held_out"]["DLT"]["median_px"] > 0
    assert main(arguments) == 0
    assert "| ukf-real |" in capsys.readouterr().out
    assert main(arguments + ["--motions", "cmu:07_10"]) == 2
    assert "give no --motions" in capsys.readouterr().err
    assert main(["compare", "--filters", "ukf-real", "--motions", "cmu:07_10", "--truth", "t.npz", "--out",
                 str(out)]) == 2
    assert "--truth is for compare --detections" in capsys.readouterr().err


def test_dask_gives_the_serial_numbers_and_recordings_come_back(grid, tmp_path):
    """Two runs of the grid on a LocalCluster of two one-thread workers: the serial rows (but the
    timing), and with --rrd each run's recording, written by this process."""
    pytest.importorskip("dask.distributed", reason="the Dask extra (priortrack[cluster]) is a dev dependency")
    import rerun as rr

    out, configs, rows = grid
    on_dask = compare(configs[:2], tmp_path, workers=2, rrd=True)
    for serial, parallel in zip(rows[:2], on_dask):
        assert {k: v for k, v in serial.items() if k != "s_per_frame"} == \
            {k: v for k, v in parallel.items() if k != "s_per_frame"}
    recordings = sorted((tmp_path / "recordings").glob("*.rrd"))
    assert [p.name for p in recordings] == ["ukf-real_cam01_seed0.rrd", "ukf-real_cam02_seed0.rrd"]
    entities = {str(c.entity_path) for c in rr.chunk.RrdReader(recordings[0]).stream().to_chunks()}
    assert "/world/estimate" in entities and "/world/cam02/image/detections" in entities
    assert "/world/cam01/image/detections" not in entities              # the camera left out is not tracked
