"""Tracking real detections: the Pose2Sim demo's OpenPose output through its 4 calibrated cameras,
from the command line, with every output read back; the lab bench on a held-out walk; bad input."""

import json
import re
from pathlib import Path
from dataclasses import replace

import numpy as np
import pytest
import rerun as rr

from priortrack import PriortrackError
from priortrack.body.fk import joint_positions
from priortrack.cli.main import main
from priortrack.data.asf import read_asf
from priortrack.data.bvh import read_bvh
from priortrack.data.keypoints import detector_map
from priortrack.data.trc import read_trc
from priortrack.geometry.frames import to_y_up
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.calibration import Calibration, read_calibration
from priortrack.data.detections import read_detections
from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.tracking.person import TrackConfig, schedule, track_detections
from priortrack.experiments.real_format import run_real_format
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.triangulation import triangulate

POSE = str(POSE2SIM_DIR / "pose")
CALIB = str(POSE2SIM_DIR / "Calib.toml")


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("real")
    argv = ["track", "--detections", POSE, "--cameras", CALIB, "--keypoints", "body25b", "--fps", "60",
            "--filter", "pf-lie", "--out", str(folder / "r.npz"), "--out", str(folder / "r.csv"),
            "--out", str(folder / "r.trc"), "--out", str(folder / "r.bvh"),
            "--rrd", str(folder / "r.rrd"), "--rate", "ticks", "--json"]
    return folder, argv


def test_the_command_tracks_the_real_trial_and_writes_every_output(outputs, capsys):
    folder, argv = outputs
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 6 and summary["fps"] == 30.0 and set(summary["reprojection_px"]) == {
        "cam01_json", "cam02_json", "cam03_json", "cam04_json"}
    assert all(e < 35 for e in summary["reprojection_px"].values()) and summary["mismatch_fraction"] == 0.0
    with np.load(folder / "r.npz") as z:
        assert set(z.files) == {"joints", "joint_names", "fps", "frames", "spread", "ess", "loglik", "mismatch",
                                "camera_names", "reprojection_px", "gated", "held_out_ratio", "body_measure_names",
                                "body_measures_m", "limb_names", "limbs_left_right_m", "height_m"}
        # the tracked body (issue 59, item 4: in the npz, not only the JSON summary), as the summary gives it
        assert dict(zip(z["body_measure_names"], z["body_measures_m"])) == pytest.approx(summary["bones_m"])
        np.testing.assert_allclose(z["limbs_left_right_m"], [summary["limbs_left_right_m"][n] for n in z["limb_names"]])
        assert float(z["height_m"]) == pytest.approx(summary["height_m"])
        joints = z["joints"]
        by_tick, gated = z["reprojection_px"], z["gated"]
        assert tuple(z["camera_names"]) == ("cam01_json", "cam02_json", "cam03_json", "cam04_json")
        assert by_tick.shape == (6, 4) and gated.shape == (6, 4, 15) and not gated.any()     # a particle filter: no gate
        assert joints.shape == (6, 15, 3) and joints.dtype == np.float64
        assert tuple(z["joint_names"]) == EVAL15_NAMES and float(z["fps"]) == 30.0
        assert z["frames"].tolist() == [0, 2, 4, 6, 8, 10]            # 60 fps data, a 30 fps prior
        assert z["mismatch"].dtype == bool and z["spread"].shape == (6, 15)
        assert np.isfinite(z["loglik"][2:]).all() and np.isfinite(z["ess"][2:]).all()
        held_out = z["held_out_ratio"]
    # The estimate against the triangulation of the same detections, in the calibration's Z-up world.
    cameras = [PinholeCamera.from_calibration(c) for c in read_calibration(CALIB).cameras]
    uv, conf = read_detections(POSE, keypoints="body25b").eval15(0.3)
    X = triangulate(cameras, uv[:, ::2], conf[:, ::2])
    assert np.nanmean(np.linalg.norm(joints[:, 3:] - X[:, 3:], axis=-1)) < 0.05
    # the held-out ratio recomputed in the world, from the written joints (the six ticks are one window): a
    # filter that follows the detections explains each camera better than the other cameras' triangulation
    from priortrack.tracking.held_out import held_out_errors, held_out_ratio
    z = np.concatenate([uv[:, ::2], conf[:, ::2, :, None]], axis=-1).transpose(1, 0, 2, 3)
    z[..., 2] = np.where(np.isfinite(z[..., 0]), z[..., 2], 0.0)
    np.testing.assert_allclose(held_out, held_out_ratio(*held_out_errors(cameras, joints, z)), rtol=1e-6)
    assert (held_out < 1.0).all(), held_out
    # each tick's reprojection error per camera, recomputed here: the median over its detections seen
    for t, c in ((0, 0), (5, 3)):
        projected, _ = cameras[c].project(joints[t])
        seen = conf[c, 2 * t] > 0
        assert by_tick[t, c] == pytest.approx(np.median(np.linalg.norm(projected[seen] - uv[c, 2 * t][seen], axis=-1)))
    assert np.all(joints[:, [11, 14], 2] < 0.2) and np.all(joints[:, 2, 2] > 1.5)          # standing, Z up
    csv = np.loadtxt(folder / "r.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(csv[:, 2:47].reshape(6, 15, 3), joints, atol=1e-6)
    # TRC: Y-up with Pose2Sim's axes for its Z-up world, (X, Y, Z) = (Y, Z, X); read back either way.
    trc_text = (folder / "r.trc").read_text().splitlines()
    assert trc_text[0].startswith("PathFileType\t4\t(X/Y/Z)\tr.trc") and trc_text[2].split("\t")[:5] == [
        "30", "30", "6", "15", "m"]
    trc, names, fps = read_trc(folder / "r.trc", up="z")
    assert [n.lower() for n in names] == ["hip", "neck", "head"] + list(EVAL15_NAMES[3:]) and fps == 30.0
    assert names[:4] == ("Hip", "Neck", "Head", "LShoulder")                    # Pose2Sim's and OpenSim's names
    np.testing.assert_allclose(trc, joints, atol=1e-12)
    np.testing.assert_allclose(read_trc(folder / "r.trc")[0][..., [2, 0, 1]], joints, atol=1e-12)
    # BVH: the body's motion, Y-up, read back by our reader to the joints the filter tracked (IK: mm).
    bvh = read_bvh(folder / "r.bvh")
    Y = np.einsum("ij,tjk->tik", detector_map(), joint_positions(bvh)) @ to_y_up("z")
    error = np.linalg.norm(Y - joints, axis=-1)
    # The mean bounds the conventions (units, axes, absolute root: an error there moves joints by
    # decimetres); the max is the worst IK residual of fixed bone lengths fitted to a per-tick
    # estimate (under 40 mm on one machine, 43 mm on another: the particle filter's float32 rounding).
    assert error.mean() < 0.006 and error.max() < 0.08 and len(bvh) == 6 and bvh.fps == 30.0
    entities = {str(c.entity_path) for c in rr.chunk.RrdReader(folder / "r.rrd").stream().to_chunks()}
    assert {"/world/estimate", "/world/cam02_json/image/detections", "/world/cam02_json/image/estimate",
            "/metrics/ess_fraction", "/metrics/reprojection_px/cam03_json", "/metrics/mismatch",
            "/metrics/held_out_ratio"} <= entities


def test_schedule_steps_at_the_priors_rate():
    assert schedule(np.arange(9), 60.0, 30.0).tolist() == [0, 2, 4, 6, 8]
    assert schedule(np.arange(13), 120.0, 30.0).tolist() == [0, 4, 8, 12]
    twenty_five = schedule(np.arange(26), 25.0, 30.0)                 # some ticks have no frame
    assert len(twenty_five) == 31 and (twenty_five == -1).sum() == 5 and (np.diff(twenty_five[twenty_five >= 0]) > 0).all()


def test_the_lab_bench_tracks_a_held_out_walk_near_the_triangulation():
    """35_29 written as OpenPose JSON through the 4 cameras with detector errors, tracked without truth: pf-lie with its
    guided proposal within 1.5× the per-frame DLT (measured 8.6 mm, DLT 12.6; with the prior's draw 23.8, 1.9×)."""
    run = run_real_format("pf-lie", "walkjog:35_29", seed=0)
    assert run["cameras"] == 4 and run["ticks"] > 30 and run["mismatch_fraction"] == 0.0
    assert run["mpjpe_mm"] < 40 and run["mpjpe_where_dlt_mm"] < 1.5 * run["dlt_mm"]


def test_an_angle_preset_takes_a_body_whose_shoulders_are_not_the_templates():
    """CMU 39's walk through the bench with ukf-real: the template's clavicles (CMU 35's never turn) held at 35's left
    39's shoulders out of reach, 21.9 mm against the DLT's 14.2 and every tick flagged; at 39's own, measured over
    the trial (``own_posture``) and kept by the prior: 10.1 mm, none flagged."""
    run = run_real_format("ukf-real", "cmu:39_01", seed=0)
    assert run["mismatch_fraction"] == 0.0 and run["mpjpe_where_dlt_mm"] < 0.9 * run["dlt_mm"]


def test_bad_input_is_named(tmp_path, capsys):
    detections = read_detections(POSE, keypoints="body25b")
    calibration = read_calibration(CALIB)
    three = Calibration(calibration.cameras[:3], "z", "three.toml")
    with pytest.raises(PriortrackError, match="three.toml has 3 cameras for 4 detection cameras"):
        track_detections(detections, three, "pf-lie", TrackConfig(fps=60))
    blind = replace(detections, keypoints=detections.keypoints.copy())
    blind.keypoints[2] = np.nan
    with pytest.raises(PriortrackError, match="camera cam03_json sees none of the detections"):
        track_detections(blind, calibration, "pf-lie", TrackConfig(fps=60))
    with pytest.raises(PriortrackError, match="do not say their frame rate; give it"):
        track_detections(detections, calibration, "pf-lie")
    one = replace(detections, keypoints=detections.keypoints[:1], camera_names=detections.camera_names[:1])
    with pytest.raises(PriortrackError, match="c.json gives no vertical and one camera cannot triangulate"):
        track_detections(one, Calibration(calibration.cameras[:1], None, "c.json"), "pf-lie", TrackConfig(fps=60))
    flip = np.diag([-1.0, 1.0, -1.0])                      # the camera turned about its y axis, at its place
    turned = replace(calibration.cameras[1], R=flip @ calibration.cameras[1].R, t=flip @ calibration.cameras[1].t)
    with pytest.raises(PriortrackError, match="c.toml: camera 'cam02_json': 100% of the person it detects lies behind"):
        track_detections(detections, Calibration((calibration.cameras[0], turned) + calibration.cameras[2:], "z",
                                                 "c.toml"), "pf-lie", TrackConfig(fps=60))
    with pytest.raises(PriortrackError, match="no camera cam_09"):
        track_detections(detections, calibration, "pf-lie",
                         TrackConfig(fps=60, camera_map={n: "cam_09" for n in detections.camera_names}))
    for argv, message in [
        (["track", "--detections", POSE, "--filter", "pf-lie"], "--detections with --cameras"),
        (["track", "--detections", POSE, "--cameras", CALIB, "--filter", "pf-lie", "--out", str(tmp_path / "x.c3d")],
         "results are written as .npz, .csv, .trc, .mot, .bvh"),
        (["track", "cmu:07_10", "--detections", POSE, "--cameras", CALIB, "--filter", "pf-lie"], "not both"),
        (["track", "cmu:07_10", "--cameras", CALIB, "--filter", "pf-lie"], "--cameras is for tracking --detections"),
        (["track", "--detections", POSE, "--cameras", CALIB, "--keypoints", "body25b", "--fps", "60",
          "--filter", "pf-lie", "--camera-map", "a"], "--camera-map must be FOLDER=CAMERA"),
    ]:
        assert main(argv) == 2
        assert message in capsys.readouterr().err


def test_one_camera_starts_from_the_height_and_tracks_the_pose():
    """From one camera: the body scaled to the height, fitted in 2D, its depth from its size; the
    pose relative to the hips is tracked (35_29 through camera 4 with pf-gpdm)."""
    run = run_real_format("pf-gpdm", "walkjog:35_29", seed=0, cameras=[3])
    assert run["cameras"] == 1 and run["relative_mm"] < 80 and run["mpjpe_mm"] < 400
    detections = read_detections(POSE, keypoints="body25b")
    one = replace(detections, keypoints=detections.keypoints[1:2], camera_names=detections.camera_names[1:2])
    calibration = read_calibration(CALIB)
    result = track_detections(one, Calibration(calibration.cameras[1:2], "z", "one"), "pf-lie",
                              TrackConfig(fps=60, height=1.75))
    assert np.isfinite(result.joints).all() and np.all(result.joints[:, 2, 2] - result.joints[:, [11, 14], 2].min(1) > 1.4)
    with pytest.raises(PriortrackError, match="standing height"):
        track_detections(one, Calibration(calibration.cameras[1:2], "z", "one"), "pf-lie",
                         TrackConfig(fps=60, height=17.0))


@pytest.mark.parametrize("preset", ["ukf-diffusion-local", "map-gpdm"])
def test_the_unscented_and_map_filters_take_several_cameras(preset):
    result = track_detections(read_detections(POSE, keypoints="body25b"), read_calibration(CALIB), preset,
                              TrackConfig(fps=60))
    assert np.isfinite(result.joints).all() and all(e < 35 for e in result.reprojection_px)


def test_a_run_keeps_a_record_a_tick_not_its_point_sets():
    """Without a recording or the whole run's smoother, a detections run keeps no snapshot (its memory a
    few numbers a tick), yet every tick's spread and step record; a recording's clouds every k-th tick;
    a fixed lag smooths as the filter goes (no snapshot kept) and moves the estimate; an unscented
    run has no ESS (NaN, and none in the summary)."""
    detections, calibration = read_detections(POSE, keypoints="body25b"), read_calibration(CALIB)
    plain = track_detections(detections, calibration, "pf-lie", TrackConfig(fps=60))
    T = len(plain.joints)
    assert plain.snapshots is None and [s.frame for s in plain.steps] == list(range(2, T))
    assert np.isfinite(plain.spread[2:]).all() and (plain.spread[2:] > 0).all()
    assert np.isfinite(plain.ess[2:]).all() and plain.summary()["mean_ess"] > 0
    every = track_detections(detections, calibration, "pf-lie",
                             TrackConfig(fps=60, keep_snapshots=True, snapshot_every=3))
    assert [s.frame for s in every.snapshots] == list(range(2, T, 3))
    np.testing.assert_array_equal(every.joints, plain.joints)
    # a snapshot is in the Y-up working frame; in_world maps its estimate onto the world joints of its tick
    for snapshot in every.snapshots:
        np.testing.assert_allclose(every.in_world(snapshot.estimate), every.joints[snapshot.frame], atol=1e-12)
    assert np.abs(every.snapshots[0].estimate - every.joints[2]).max() > 0.1          # the two frames differ here
    lagged = track_detections(detections, calibration, "pf-lie", TrackConfig(fps=60, smooth=True, lag=2))
    assert lagged.snapshots is None and lagged.lag == 2
    np.testing.assert_array_equal(lagged.filtered_joints, plain.joints)
    assert np.isfinite(lagged.joints).all() and np.abs(lagged.joints - plain.joints)[2:].max() > 1e-4
    ukf = track_detections(detections, calibration, "ukf-real", TrackConfig(fps=60))
    assert np.isnan(ukf.ess).all() and ukf.summary()["mean_ess"] is None


def test_a_camera_following_someone_else_is_left_out_at_those_ticks():
    """Camera 3's person replaced by another (shifted 400 px) in ticks 2–4: the other three cameras'
    triangulation disagrees with it there, and only there."""
    from priortrack.tracking.person import cross_view_check

    cameras = [PinholeCamera.from_calibration(c) for c in read_calibration(CALIB).cameras]
    uv, conf = read_detections(POSE, keypoints="body25b").eval15(0.3)
    z = np.concatenate([uv, conf[..., None]], axis=-1).transpose(1, 0, 2, 3).copy()       # (T, C, 15, 3)
    z[2:5, 2, :, 0] += 400.0
    left_out = cross_view_check(cameras, z)
    assert left_out.sum() == 3 and left_out[2:5, 2].all()
    assert np.isnan(z[2:5, 2]).all() and np.isfinite(z[:, [0, 1, 3], :, 0]).any(axis=-1).all()
    assert np.isfinite(z[[0, 1, 5, 6], 2, :, 0]).any()


def test_a_given_skeleton_is_the_body(capsys, tmp_path):
    """--skeleton: the person's own ASF body is used as given (its bone lengths reach the joints)."""
    asf = POSE2SIM_DIR.parent / "cmu" / "asf_amc" / "07.asf"
    assert main(["track", "--detections", POSE, "--cameras", CALIB, "--keypoints", "body25b", "--fps", "60",
                 "--filter", "pf-lie", "--skeleton", str(asf), "--out", str(tmp_path / "r.bvh"), "--json"]) == 0
    assert read_bvh(tmp_path / "r.bvh").skeleton.names[:2] == ("root", "lhipjoint")
    np.testing.assert_allclose(read_bvh(tmp_path / "r.bvh").skeleton.bone_lengths()[1:6],
                               read_asf(asf).bone_lengths()[1:6], rtol=1e-6)
    assert main(["track", "--detections", POSE, "--cameras", CALIB, "--filter", "pf-lie",
                 "--skeleton", str(tmp_path / "r.npz")]) == 2
    assert "give an .asf or .bvh file" in capsys.readouterr().err


def test_the_real_track_benchmark_runs_the_whole_command(capsys):
    """`priortrack bench real-track` (its figures are for the note, not asserted: timing is noisy here)."""
    assert main(["bench", "real-track", "--frames", "12"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["frames"] == 12 and result["cameras"] == 4 and result["command_seconds"] > 0
    assert result["prior_draw_seconds"] > 0 and result["guided_over_prior"] > 0      # pf-lie draws guided
    assert main(["bench", "real-track", "--frames", "12", "--cameras", "5", "--fps", "25", "--filter", "ukf-real"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["cameras"] == 5 and result["fps"] == 25.0 and result["command_seconds"] > 0
    assert result["prior_draw_seconds"] is None and result["single_unscented_seconds"] is None
    assert main(["bench", "real-track", "--frames", "12", "--filter", "ukf-lie"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["single_unscented_seconds"] > 0 and result["sum_over_single"] > 0   # beside one unscented filter
    assert main(["bench", "real-track", "--frames", "5000"]) == 2
    assert "frames must be in [3, 1800]" in capsys.readouterr().err
    assert main(["bench", "real-track", "--cameras", "1"]) == 2
    assert "cameras must be in [2, 12]" in capsys.readouterr().err
    assert main(["bench", "real-track", "--fps", "500"]) == 2
    assert "fps must be in [10, 120]" in capsys.readouterr().err


@pytest.mark.parametrize("preset, ratio", [("ukf-real", 0.9), ("pf-lie-real", 0.98)])
def test_smoothing_real_format_input_lowers_the_error_and_the_jitter(preset, ratio):
    """4 cameras, 35_29 written as OpenPose JSON: the smoother's joints nearer the mocap and less jittery than
    the filter's, from the same run: the unscented filter's posterior linearisation (7.8 against 9.8 mm); the
    particle filter's clouds smoothed as Gaussians (5.7 against 6.1 mm, jitter 5.6 against 7.2 when measured;
    backward simulation was 6.6 mm, jitter 8.0: its trajectories pass through one particle a frame)."""
    run = run_real_format(preset, "walkjog:35_29", seed=0, smooth=True)
    assert run["mpjpe_mm"] < ratio * run["filtered_mm"]
    assert run["jitter_mm"] < run["filtered_jitter_mm"] and run["truth_jitter_mm"] > 0


def test_smoothed_detections_are_exported_beside_the_filtered(tmp_path):
    """A particle smoother's joints are written beside the filter's (joints and spread); backward simulation's
    lie within the reach of the filter's own cloud at every tick: a smoothed trajectory's pose at tick t is one of
    the filter's particles there, with the translation Kalman-smoothed, so each smoothed joint is at
    most the farthest particle's distance from the filtered joint plus the translation's shift (bounded
    by 3 σ of the particles' largest translation variance). No tighter figure holds on every processor:
    on these six frames the filter's ESS falls to 2 at tick 4, the 100 backward trajectories pass
    through one particle, and which one follows the rounding (the right wrist 135 mm from the filtered
    with one torch thread on an AVX2 processor, 19 mm with two, both inside the cloud;
    docs/results/2026-11-27-processors.md)."""
    import torch

    from priortrack.viz.real import record_detections

    result = track_detections(read_detections(POSE, keypoints="body25b"), read_calibration(CALIB), "pf-gpdm",
                              TrackConfig(fps=60, smooth=True, keep_snapshots=True, particle_smoother="backward"))
    assert result.summary()["smoothed"] is True
    with np.load(result.save(tmp_path / "s.npz")) as f:
        joints, filtered, spread = f["joints"], f["filtered_joints"], f["filtered_spread"]
    assert joints.shape == filtered.shape == (6, 15, 3) and spread.shape == (6, 15) and np.isfinite(joints).all()
    np.testing.assert_array_equal(joints, result.joints)
    np.testing.assert_array_equal(filtered, result.filtered_joints)
    assert np.isfinite(spread[2:]).all() and (spread[2:] > 0).all()
    assert np.abs(joints - filtered)[2:].max() > 0                       # the smoother moved something
    for snapshot in result.snapshots:
        t = snapshot.frame
        cloud = result.in_world(snapshot.joints.detach().double().numpy())           # (P, 15, 3)
        reach = np.linalg.norm(cloud - filtered[t], axis=-1).max(axis=0)           # (15,)
        shift = 3 * torch.linalg.eigvalsh(snapshot.translation_covariance[:, :3, :3].double()).max().sqrt().item()
        assert (np.linalg.norm(joints[t] - filtered[t], axis=-1) <= reach + shift).all(), t
    entities = {str(c.entity_path) for c in rr.chunk.RrdReader(record_detections(result, tmp_path / "s.rrd"))
                .stream().to_chunks()}
    assert {"/world/estimate", "/world/filtered"} <= entities


@pytest.mark.parametrize("preset", ["ukf-diffusion-local", "pf-diffusion-local"])
def test_the_exported_spread_is_the_posteriors_spread(preset, tmp_path):
    """The spread written per joint is the RMS distance of the posterior's joints from the estimate: for the
    unscented filter, against 20,000 states drawn from its Gaussian N(mean, P) (within 5 %; the unscented
    transform of a nearly linear map); for the particle filter, the weighted particles' own (to 1e-9)."""
    import torch

    from priortrack.tracking.presets import load_preset
    from priortrack.tracking.person import _spread
    from priortrack.experiments.tracking import track

    run = track("cmu:07_10", preset, "noise:sigma_px=5", seed=0, frames=12, cache=tmp_path)
    filt = load_preset(preset).build(run.observations.camera, seed=0, cache=tmp_path)
    last = filt.run(run.observations.uv, run.motion, keep_snapshots=True).snapshots[-1]
    if preset.startswith("ukf"):
        u = filt.unscented
        draws = torch.randn(20000, u.tangent_dim, dtype=torch.float64) @ torch.linalg.cholesky(last.covariance).T
        joints = u.observe(u.boxplus(last.mean.expand(len(draws), -1), draws))
        centre = u.observe(last.mean[None])[0]
        reference = ((joints - centre) ** 2).sum(-1).mean(0).sqrt().numpy()
        assert np.allclose(_spread(last), reference, rtol=0.05)
    else:
        w = last.weights.double() / last.weights.double().sum()
        X = last.joints.double()
        mean = torch.einsum("p,pjk->jk", w, X)
        reference = torch.einsum("p,pj->j", w, ((X - mean) ** 2).sum(-1))
        if last.translation_spread() is not None:
            reference = reference + float(np.trace(last.translation_spread()[1]))
        assert np.allclose(_spread(last), reference.sqrt().numpy(), atol=1e-9)


def test_a_recording_draws_the_cloud_every_kth_tick(tmp_path, capsys):
    """--rrd-every 2: the particle cloud at ticks 2 and 4 of the six, the skeleton and the scalars at every
    tick; --rrd-every 0 refused by name."""
    argv = ["track", "--detections", POSE, "--cameras", CALIB, "--keypoints", "body25b", "--fps", "60",
            "--filter", "pf-lie", "--rrd", str(tmp_path / "r.rrd")]
    assert main(argv + ["--rrd-every", "2"]) == 0
    rows = {}
    for chunk in rr.chunk.RrdReader(str(tmp_path / "r.rrd")).stream().to_chunks():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    assert rows["/world/estimate/cloud"] == 2 and rows["/world/estimate"] == 6 and rows["/metrics/loglik"] == 6
    assert main(argv + ["--rrd-every", "0"]) == 2
    assert "--rrd-every must be a whole number of ticks ≥ 1, got 0" in capsys.readouterr().err


def test_ctrl_c_writes_what_was_tracked(tmp_path, capsys, monkeypatch):
    """Ctrl-C during track --detections' filter run (here after tick 3 of 6): the outputs hold the four
    ticks tracked until then, valid, and the command says so (exit 0, "interrupted" in the summary). The
    library's run raises it unless asked (an experiment must not count a cut run); Ctrl-C elsewhere is
    one line and exit 130."""
    import priortrack.cli.track as cli_track
    from priortrack.cli.common import Progress

    class Interrupting(Progress):
        def __call__(self, step, total):
            if step == 3:
                raise KeyboardInterrupt

    monkeypatch.setattr(cli_track, "Progress", Interrupting)
    argv = ["track", "--detections", POSE, "--cameras", CALIB, "--keypoints", "body25b", "--fps", "60",
            "--filter", "pf-lie", "--out", str(tmp_path / "r.npz"), "--out", str(tmp_path / "r.csv"), "--json"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "interrupted: writing the 4 ticks tracked until then" in captured.err
    assert json.loads(captured.out)["interrupted"] is True
    with np.load(tmp_path / "r.npz") as z:
        # the 4 ticks at the detections' 60 fps: frames 0–6 and the one half a tick after the last
        assert z["joints"].shape == (8, 15, 3) and np.isfinite(z["joints"]).all() and z["frames"].tolist() == list(range(8))
    assert np.loadtxt(tmp_path / "r.csv", delimiter=",", skiprows=1).shape[0] == 8
    detections, calibration = read_detections(POSE, keypoints="body25b"), read_calibration(CALIB)

    def interrupt(t, T):
        if t == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        track_detections(detections, calibration, "pf-lie", TrackConfig(fps=60), progress=interrupt)
    cut = track_detections(detections, calibration, "pf-lie",
                           TrackConfig(fps=60, interruptible=True, smooth=True, lag=1), progress=interrupt)
    assert cut.interrupted and len(cut.joints) == 4 and len(cut.filtered_joints) == 4 and len(cut.steps) == 2
    monkeypatch.setattr("priortrack.data.calibration.read_calibration",
                        lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt()))
    assert main(argv) == 130 and capsys.readouterr().err.strip() == "priortrack: interrupted"


@pytest.mark.parametrize("phase", ["smooth_run", "tracked_fit_check"])
def test_ctrl_c_while_smoothing_or_fit_checking_writes_the_result(tmp_path, capsys, monkeypatch, phase):
    """Issue 60, item 1: Ctrl-C after the last tick (the smoother, the fit-check) printed "interrupted" and wrote
    nothing. Now the result is written, the filter's own where the smoother was stopped, without the fit-check where
    that was; exit 0, the summary says interrupted."""
    import priortrack.tracking.person as person

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(person, phase, stop)
    assert main(["track", "--detections", POSE, "--cameras", CALIB, "--fps", "60", "--filter", "pf-lie", "--smooth",
                 "--out", str(tmp_path / "r.npz"), "--json"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["interrupted"] is True and summary["smoothed"] is (phase != "smooth_run")
    with np.load(tmp_path / "r.npz") as z:
        assert z["joints"].shape == (12, 15, 3) and np.isfinite(z["joints"]).all()
        assert ("filtered_joints" in z.files) is (phase != "smooth_run")


def test_the_printed_summary_says_ticks_frames_written_and_the_body(tmp_path, capsys):
    """Issue 59, item 4 (a readable summary, not only --json) and issue 60 (frames and ticks told apart): the line
    gives the filter's ticks, the frames written at the detections' rate and the body, height and each limb's sides."""
    assert main(["track", "--detections", POSE, "--cameras", CALIB, "--fps", "60", "--out", str(tmp_path / "r.npz")]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line.startswith("ukf-real: 6 ticks at 30 fps in ") and "mismatch 0% of ticks" in line
    assert re.search(r"body 1\.\d\d m tall \(measured\), left / right m: upper arm 0\.\d\d / 0\.\d\d, forearm .* shin", line), line
    assert line.endswith(f"wrote {tmp_path / 'r.npz'} (12 frames at 60 fps)")


def test_the_mismatch_warning_says_what_it_measured_and_names_no_weaker_preset():
    """Issue 28: a run with 99.6 % of its ticks explained was told "explains 100 % … try pf-diffusion-local"
    (the preset it ran). The warning counts the ticks and gives each cause's count, and names no preset."""
    from priortrack.tracking.person import mismatch_message

    T = 2 + 998
    mismatch, lost = np.zeros(T, bool), np.zeros(T, bool)
    mismatch[500:504] = True
    unlikely = mismatch.copy()
    unlikely[502:504] = False
    lost[502:504] = True
    text = mismatch_message(mismatch, unlikely, lost, "diffusion-local", judged_by_prior=False)
    assert text.startswith("4 of 998 tracked ticks (0.4%) are flagged as mismatch: 2 where the detections")
    assert "2 where the estimate is on average over 100 mm" in text and "3 nats" in text
    assert "pf-" not in text and "100%" not in text and "implausible" not in text
    judged = mismatch_message(mismatch, unlikely, None, "lie", judged_by_prior=True)
    assert "the lie prior finds the tracked pose implausible" in judged and "triangulation" not in judged
    worse = np.zeros(T, bool)
    worse[500:504] = True
    held_out = mismatch_message(mismatch, unlikely, None, "lie", judged_by_prior=True, worse=worse)
    assert "4 where it explains each camera's detections over 1.2× worse than the other cameras' triangulation" in held_out


def test_the_gate_and_each_cameras_reprojection_are_in_the_npz_and_the_recording(tmp_path):
    """A right wrist thrown 300 px off in one camera at one frame: ukf-real's validation gate holds that
    detection out (and no other at that tick; the real trial's own neck and shoulder in cam01 at tick 2
    are held out too), the npz says which (tick, camera, joint), the recording draws each and counts
    them per camera."""
    detections = read_detections(POSE, keypoints="body25b")
    keypoints = detections.keypoints.copy()
    wrist = detections.keypoint_names.index("right_wrist")
    keypoints[1, 6, wrist, :2] += 300.0                                # frame 6 = tick 3, cam02
    result = track_detections(replace(detections, keypoints=keypoints), read_calibration(CALIB), "ukf-real",
                              TrackConfig(fps=60))
    assert result.gated[3, 1, 8] and result.gated[3].sum() == 1, np.argwhere(result.gated)
    result.save_npz(tmp_path / "r.npz")
    with np.load(tmp_path / "r.npz") as z:
        np.testing.assert_array_equal(z["gated"], result.gated)
        np.testing.assert_array_equal(z["reprojection_px"], result.reprojection_by_tick)
    from priortrack.viz.real import record_detections

    record_detections(result, tmp_path / "r.rrd")
    entities = {str(c.entity_path) for c in rr.chunk.RrdReader(tmp_path / "r.rrd").stream().to_chunks()}
    for c, name in enumerate(result.camera_names):
        assert (f"/world/{name}/image/gated" in entities) == (f"/metrics/gated/{name}" in entities) == bool(
            result.gated[:, c].any())
    assert "/world/cam02_json/image/gated" in entities


def test_the_summary_gives_the_persons_own_body_measured_over_the_whole_trial(tmp_path):
    """A held-out walk written as a detector would (noise, drops, swaps, outliers) through the 4
    cameras: the tracked body's measures (medians over every tick's triangulation, left and right averaged, and each
    limb's sides) are the mocap person's own to 2 cm."""
    from priortrack.body.ik import BODY_MEASURES, LIMB_SIDES, measured_distances
    from priortrack.experiments.real_format import DEFAULT_CALIBRATION, detector_keypoints, placed_walk, write_openpose

    calibration = read_calibration(DEFAULT_CALIBRATION)
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    X = placed_walk("walkjog:35_29", "z")
    write_openpose(detector_keypoints(X, cameras, np.random.default_rng(1)), tmp_path)
    result = track_detections(read_detections(tmp_path, keypoints="body25b"), calibration, "ukf-real",
                              TrackConfig(fps=60))
    truth, sides = measured_distances(X), measured_distances(X, own_side=True)
    summary = result.summary()
    measured = summary["bones_m"]
    assert set(measured) == set(BODY_MEASURES)
    for name, j in BODY_MEASURES.items():
        assert abs(measured[name] - truth[j - 1]) < 0.02, (name, measured[name], truth[j - 1])
    for name, (left, right) in LIMB_SIDES.items():                 # each side its own, subject 35's differ
        assert summary["limbs_left_right_m"][name] == pytest.approx([sides[left - 1], sides[right - 1]], abs=0.02)


def test_a_joint_every_camera_agrees_on_is_reacquired_after_the_gate_held_it_out(tmp_path):
    """The right wrist seen 30 cm away from the body's motion by all 4 cameras alike from frame 30 on (a
    limb the filter lost, as the learned priors lost caliscope's wrists): ukf-real's validation gate
    holds it out in every camera, and after GATE_PATIENCE ticks takes it ungated (flagged), so the
    estimate's wrist follows the detections, not the prediction; the other joints are unaffected."""
    from priortrack.experiments.real_format import DEFAULT_CALIBRATION, detector_keypoints, placed_walk, write_openpose
    from priortrack.filters.ukf import GATE_PATIENCE

    calibration = read_calibration(DEFAULT_CALIBRATION)
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    X = placed_walk("walkjog:35_29", "z")
    X[30:, 8] += [0.0, 0.0, 0.3]                                    # eval15 rwrist, 30 cm up in the Z-up world
    write_openpose(detector_keypoints(X, cameras, np.random.default_rng(2)), tmp_path)
    result = track_detections(read_detections(tmp_path, keypoints="body25b"), calibration, "ukf-real",
                              TrackConfig(fps=60))
    flags = {step.frame: step.flags for step in result.steps}
    moved = np.flatnonzero(result.frames >= 30)[0]                 # the first tick that sees the moved wrist
    reacquired = [t for t, f in flags.items() if "joint-reacquired" in f]
    assert reacquired and moved + GATE_PATIENCE <= reacquired[0] <= moved + GATE_PATIENCE + 2, (moved, reacquired)
    z = result.observations[moved:reacquired[0], :, 8]
    seen = np.isfinite(z[..., 0]) & (np.nan_to_num(z[..., 2]) > 0)
    assert (result.gated[moved:reacquired[0], :, 8] | ~seen).all()     # held out in every camera seeing it until then
    late = np.flatnonzero(result.frames >= 60)
    truth = X[result.frames[late]]
    wrist = np.linalg.norm(result.joints[late, 8] - truth[:, 8], axis=-1)
    others = np.linalg.norm(result.joints[late][:, [3, 4, 6, 7, 11, 14]] - truth[:, [3, 4, 6, 7, 11, 14]], axis=-1)
    assert np.median(wrist) < 0.06 and np.median(others) < 0.03, (np.median(wrist), np.median(others))


def _walk_with_a_camera_swapped(folder, seed: int, frames: slice):
    """A held-out walk (35_29) written as a detector would through the 4 cameras (seed), camera 2's left and
    right swapped on ``frames``: (the calibration, the truth X (T, 15, 3))."""
    from priortrack.data.keypoints import LAYOUTS
    from priortrack.experiments.real_format import DEFAULT_CALIBRATION, detector_keypoints, placed_walk, write_openpose

    calibration = read_calibration(DEFAULT_CALIBRATION)
    X = placed_walk("walkjog:35_29", "z")
    keypoints = detector_keypoints(X, [PinholeCamera.from_calibration(c) for c in calibration.cameras],
                                   np.random.default_rng(seed))
    names = LAYOUTS["body25b"]
    left = [names.index(n) for n in names if n.startswith("left_")]
    right = [names.index("right_" + names[k][5:]) for k in left]
    keypoints[1, frames, left + right] = keypoints[1, frames, right + left]
    write_openpose(keypoints, folder)
    return calibration, X


def test_a_cameras_left_right_swap_is_undone_and_tracked_through(tmp_path):
    """One of the 4 cameras sees a held-out walk with left and right swapped (every pair) for 40 frames, as a
    detector misreading the person's facing does: ukf-real undoes the swaps (flagged "swap-corrected" on
    most of those ticks; 16 of 18 here, the others where the camera sees left and right close together and the
    labels fit as well), so the swapped camera's points are used, not held out by the gate, and the limbs' error over
    those ticks is below the same filter's with swaps = false (which keeps the labels)."""
    calibration, X = _walk_with_a_camera_swapped(tmp_path / "pose", 3, slice(30, 70))
    preset = (Path(__file__).parents[1] / "filters" / "ukf-real.toml").read_text().replace(
        'kappa = 0.0', 'kappa = 0.0\nswaps = false')
    (tmp_path / "kept.toml").write_text(preset)
    detections = read_detections(tmp_path / "pose", keypoints="body25b")
    runs = {name: track_detections(detections, calibration, name, TrackConfig(fps=60))
            for name in ("ukf-real", str(tmp_path / "kept.toml"))}
    corrected, kept = runs["ukf-real"], runs[str(tmp_path / "kept.toml")]
    ticks = np.flatnonzero((corrected.frames >= 32) & (corrected.frames < 68))
    flagged = [t for t in ticks if "swap-corrected" in corrected.steps[t].flags]
    assert len(flagged) >= 0.75 * len(ticks), (len(flagged), len(ticks))     # the rest: left and right project close
    assert not any("swap-corrected" in s.flags for s in kept.steps)
    limbs = [3, 4, 5, 6, 7, 8, 10, 11, 13, 14]
    assert corrected.gated[ticks, 1][:, limbs].mean() < 0.1 < kept.gated[ticks, 1][:, limbs].mean()

    def error(run):
        truth = X[run.frames[ticks]]
        return np.linalg.norm(run.joints[ticks][:, limbs] - truth[:, limbs], axis=-1).mean()

    assert error(corrected) < error(kept), (error(corrected), error(kept))


def test_the_start_skips_ticks_whose_triangulation_a_camera_disagrees_with():
    """start_ticks against its definition: consecutive ticks with START_JOINTS joints, and reprojecting within
    START_CONSISTENCY × the median such tick's worst-camera error; without a consistent pair, the counts alone."""
    from priortrack.tracking.person import START_CONSISTENCY, START_JOINTS, start_ticks

    counts = np.array([3, 15, 15, 15, 15, 15, 15, 10, 15, 15])
    residual = np.array([1.0, 40.0, 4.0, 5.0, 4.0, 6.0, 5.0, 4.0, 5.0, 4.0])    # tick 1: a camera swapped
    assert start_ticks(counts).tolist() == [1, 2, 3, 4, 5, 8]
    assert start_ticks(counts, residual).tolist() == [2, 3, 4, 5, 8]
    median = np.median(residual[counts >= START_JOINTS])
    residual[[2, 3, 5, 8]] = START_CONSISTENCY * median + 1                    # every pair has an inconsistent tick
    assert start_ticks(counts, residual).tolist() == [1, 2, 3, 4, 5, 8]


def test_the_start_needs_the_joints_the_trial_shows():
    """start_joints: START_JOINTS where the trial shows as many in VIEW_SHARE of its ticks; else the joints it
    shows (logged, naming those missing); fewer than MIN_START_JOINTS refused, naming the joints seen; and
    start_ticks takes the count."""
    from priortrack.tracking.person import MIN_START_JOINTS, START_JOINTS, VIEW_SHARE, start_joints, start_ticks

    seen = np.ones((10, 15), dtype=bool)
    seen[:3, 10] = False                                              # a knee hidden for 3 ticks
    assert start_joints(seen, False) == START_JOINTS
    seen[:, 9:] = False                                               # the legs never
    seen[: int(10 * VIEW_SHARE), 0] = False                           # the pelvis in half the ticks: shown
    assert start_joints(seen, False) == 9
    seen[:, 0] = False
    seen[: int(10 * VIEW_SHARE) + 1, 8] = False                       # a wrist in fewer than half: not shown
    assert start_joints(seen, False) == 7 >= MIN_START_JOINTS
    seen[:, 5:] = False
    with pytest.raises(PriortrackError, match="only 4 joints .neck, head, lshoulder, lelbow. are triangulated"):
        start_joints(seen, False)
    assert start_ticks(np.array([8, 8, 7, 8, 8]), None, 8).tolist() == [0, 3]


def test_a_swap_in_one_camera_on_the_first_frames_does_not_start_the_track(tmp_path, monkeypatch):
    """A held-out walk whose camera 2 swaps left and right on its first 12 frames: the start waits for the
    frames every camera agrees on, and the track is as good as without the swap (seed 4: 6.3 mm mean, its
    first tick 21 mm; unswapped 5.8 and 19 mm); starting on the swapped frames (the check off) fitted the
    body to them: 57–73 mm over the first ticks, 32 mm mean."""
    from priortrack.tracking import person as real

    calibration, X = _walk_with_a_camera_swapped(tmp_path, 4, slice(0, 12))
    detections = read_detections(tmp_path, keypoints="body25b")

    def errors():
        result = track_detections(detections, calibration, "ukf-real", TrackConfig(fps=60))
        return result.frames[0], np.linalg.norm(result.joints - X[result.frames], axis=-1)[:, 3:].mean(axis=1)

    start, checked = errors()
    monkeypatch.setattr(real, "START_CONSISTENCY", np.inf)
    unchecked_start, unchecked = errors()
    assert start >= 12 and unchecked_start < 12                    # (its first two good ticks: the draw's drops)
    assert checked[0] < 0.03 and checked.mean() < 0.01, (checked[:4], checked.mean())
    assert unchecked[:4].min() > 0.04 and unchecked.mean() > 2 * checked.mean(), (unchecked[:4], unchecked.mean())


def test_the_start_pulls_to_the_presets_training_poses_whatever_the_priors_state():
    """pose_spread: ukf-real's prior (local diffusion on joint angles) and ukf-lie-defensive's (bone directions)
    each get their training motions' per-channel mean and spread (issue 45: the Lie prior's one-camera start,
    pulled to rest, put the legs on the wrong depth branch); a skeleton with other channels gets none (a pull
    to rest)."""
    from priortrack.data.bundled import cmu_skeleton
    from priortrack.tracking.presets import load_preset
    from priortrack.tracking.person import pose_spread

    skeleton = cmu_skeleton("35")
    for name in ("ukf-real", "ukf-lie-defensive"):
        preset = load_preset(name)
        spread = pose_spread(preset, skeleton)
        channels = np.concatenate([m.channels for m in preset.training_motions])
        np.testing.assert_allclose(spread.mean, channels.mean(axis=0))
        np.testing.assert_allclose(spread.std, channels.std(axis=0))
    angles = load_preset("ukf-real")
    other = replace(skeleton, channel_names=tuple(f"x{c}" for c in range(skeleton.num_channels)))
    assert pose_spread(angles, other) is None


@pytest.mark.parametrize("settings, message", [
    ({"fps": 0}, "fps must be a positive frame rate, got 0"),
    ({"min_confidence": 2}, r"min_confidence must be in \[0, 1\], got 2"),
    ({"seed": 1.5}, "seed must be a whole number, got 1.5"),
    ({"height": 0.0}, r"height must be a person's standing height in metres \(0.5–2.6\), got 0.0"),
])
def test_a_bad_track_config_is_named_when_it_is_made(settings, message):
    """TrackConfig checks what it can on its own, before any file is read (its height whatever the cameras:
    with several it is unused, and a wrong one is still a mistake worth naming)."""
    with pytest.raises(PriortrackError, match=message):
        TrackConfig(**settings)


def test_no_fit_check_skips_the_fit_check(tmp_path, capsys, monkeypatch):
    """--no-fit-check (TrackConfig(fit_check=False)): the run never judges its motion under the prior (whose reference
    may have to be fitted first: issue 60, item 1); the summary's fit_check is null. A motion's track refuses it."""
    import priortrack.tracking.person as person

    monkeypatch.setattr(person, "tracked_fit_check", lambda *a, **k: pytest.fail("the fit-check ran"))
    argv = ["track", "--detections", POSE, "--cameras", CALIB, "--keypoints", "body25b", "--fps", "60",
            "--filter", "ukf-real", "--no-fit-check", "--json"]
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["fit_check"] is None
    assert main(["track", "cmu:07_10", "--filter", "ukf-real", "--no-fit-check"]) == 2
    assert "--no-fit-check is for tracking --detections" in capsys.readouterr().err


def test_a_rate_given_against_the_files_is_warned(caplog):
    """issue 60, item 4: an .npz saying 60 fps tracked with --fps 30 was timed at 30 without a word. --fps wins, and
    the conflict is named; the file's rate where none is given; neither is refused."""
    import logging

    from priortrack.tracking.person import data_rate

    with caplog.at_level(logging.WARNING, logger="priortrack.tracking.person"):
        assert data_rate(30.0, 60.0, "walk.npz") == 30.0
    assert "walk.npz says its frames are 60 fps; --fps 30 is taken" in caplog.text and "2×" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="priortrack.tracking.person"):
        assert data_rate(None, 60.0, "walk.npz") == 60.0 and data_rate(60.0, 60.0, "walk.npz") == 60.0
    assert caplog.text == ""
    with pytest.raises(PriortrackError, match="walk.npz: the detections do not say their frame rate; give it"):
        data_rate(None, None, "walk.npz")
    with pytest.raises(PriortrackError, match="positive frame rate"):
        data_rate(-5.0, None, "walk.npz")


def test_small_messages_count_right(capsys):
    """issue 60, item 7: one camera and one person are singular; a trial too short for the filter says so (not that
    it starts too late); --filter defaults to ukf-real, the preset the README recommends."""
    detections = read_detections(POSE, keypoints="body25b")
    calibration = read_calibration(CALIB)
    one = replace(detections, keypoints=detections.keypoints[:1], camera_names=detections.camera_names[:1])
    with pytest.raises(PriortrackError, match="c.toml has 4 cameras for 1 detection camera: say which"):
        track_detections(one, replace(calibration, source="c.toml"), "ukf-real", TrackConfig(fps=60))
    with pytest.raises(PriortrackError, match=r"2 ticks from the start to the end of the detections \(2 ticks in all, "
                                              r"at the prior's 30 fps\): the filter needs 3 to track: give more frames"):
        track_detections(detections.head(3), calibration, "ukf-real", TrackConfig(fps=60))
    assert main(["track", "--detections", POSE, "--cameras", CALIB, "--keypoints", "body25b", "--fps", "60",
                 "--people", "all", "--no-fit-check"]) == 0
    assert capsys.readouterr().out.startswith("ukf-real: 1 person, ")


def test_a_body_of_no_adult_is_named():
    """implausible_body: the template at 1.7 m is an adult's; scaled to 1.0 m it is under 1.2 m; at 2.5 m its thigh is
    over 0.6 m; stature gives back the height scaled to."""
    from priortrack.body.ik import scaled_to_height, stature
    from priortrack.data.bundled import cmu_skeleton
    from priortrack.data.keypoints import detector_map
    from priortrack.tracking.person import implausible_body

    M = detector_map()
    for height in (1.0, 1.7, 2.5):
        assert stature(scaled_to_height(cmu_skeleton("35"), height)) == pytest.approx(height)
    assert implausible_body(scaled_to_height(cmu_skeleton("35"), 1.7), M) == ""
    assert implausible_body(scaled_to_height(cmu_skeleton("35"), 1.0), M) == "1.00 m tall (under 1.2)"
    assert "a thigh of 0.6" in implausible_body(scaled_to_height(cmu_skeleton("35"), 2.5), M)
