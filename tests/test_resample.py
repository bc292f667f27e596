"""Estimates at the detections' own frames (issue 60, item 5: Pose2Sim's 60 fps, 100 frames came out as 30 fps, 50
ticks): the spline through the ticks against closed forms, and a real run written at the detections' rate."""

import json
from pathlib import Path

import numpy as np
import pytest

from priortrack.cli.main import main
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.tracking.resample import REACH_TICKS, frame_times, interpolated, nearest_tick

MULTIPERSON = Path(__file__).parent / "data" / "pose2sim_multiperson"


def test_a_cubic_is_carried_exactly_and_runs_are_not_bridged():
    ticks = np.arange(10) / 30.0
    times = np.arange(-2, 22) / 60.0                             # 60 fps frames, one tick beyond each end
    cubic = lambda t: 2.0 - t + 3 * t ** 2 - 5 * t ** 3        # noqa: E731
    values = np.stack([cubic(ticks), -cubic(ticks)], axis=1)     # (T, 2)
    out = interpolated(values, ticks, times)
    reach = (times >= -REACH_TICKS / 30 - 1e-9) & (times <= ticks[-1] + REACH_TICKS / 30 + 1e-9)
    assert reach.tolist() == [False] + [True] * 21 + [False, False]
    np.testing.assert_allclose(out[reach, 0], cubic(times[reach]), atol=1e-12)       # not-a-knot: a cubic is itself
    np.testing.assert_allclose(out[reach, 1], -out[reach, 0])
    assert np.isnan(out[~reach]).all()
    np.testing.assert_allclose(out[2:20:2], values[:9], atol=1e-14)                 # every other frame: a tick's own
    gap = values.copy()
    gap[4:6] = np.nan                                                                 # absent two ticks: two runs
    split = interpolated(gap, ticks, times)
    frames_of_gap = (times > ticks[3] + 0.5 / 30 + 1e-9) & (times < ticks[6] - 0.5 / 30 - 1e-9)
    assert np.isnan(split[frames_of_gap]).all() and frames_of_gap.sum() == 3
    lone = np.full((10, 1), np.nan)
    lone[[2, 7, 8]] = [[1.0], [3.0], [5.0]]                       # one tick: constant; two: a straight line
    out = interpolated(lone, ticks, np.array([2, 14, 15, 16, 17]) / 60.0)
    np.testing.assert_allclose(out[:, 0], [np.nan, 3.0, 4.0, 5.0, 6.0])
    np.testing.assert_array_equal(nearest_tick(ticks, np.array([0.0, 0.016, 0.017, 1.0])), [0, 0, 1, 9])
    np.testing.assert_allclose(frame_times(np.array([100, 101, 103]), 25.0), [0, 0.04, 0.12])


def test_a_real_run_is_written_at_the_detections_rate(tmp_path, capsys):
    """The bundled Pose2Sim trial (60 fps, 12 frames), ukf-real: the default output has the detections' 12 frames at
    60 fps, every other one the tick's own estimate (--rate ticks' file), the ones between on the spline; each frame's
    verdicts are its nearest tick's."""
    base = ["track", "--detections", str(POSE2SIM_DIR / "pose"), "--cameras", str(POSE2SIM_DIR / "Calib.toml"),
            "--fps", "60", "--filter", "ukf-real", "--json"]
    assert main(base + ["--out", str(tmp_path / "f.npz"), "--out", str(tmp_path / "f.csv")]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 6                        # the summary: the filter's ticks
    assert main(base + ["--out", str(tmp_path / "t.npz"), "--rate", "ticks"]) == 0
    with np.load(tmp_path / "f.npz") as f, np.load(tmp_path / "t.npz") as t:
        assert float(f["fps"]) == 60.0 and float(t["fps"]) == 30.0
        assert f["frames"].tolist() == list(range(12)) and t["frames"].tolist() == [0, 2, 4, 6, 8, 10]
        np.testing.assert_allclose(f["joints"][::2], t["joints"], atol=1e-12)
        np.testing.assert_allclose(f["spread"][::2], t["spread"], atol=1e-12)
        between = 0.5 * (t["joints"][:-1] + t["joints"][1:])                 # a spline, not the chord, but near it
        assert np.abs(f["joints"][1:-1:2] - between).max() < 0.02
        for name in ("mismatch", "loglik", "held_out_ratio", "reprojection_px", "gated"):
            np.testing.assert_array_equal(f[name], np.repeat(t[name], 2, axis=0), err_msg=name)
    csv = np.loadtxt(tmp_path / "f.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(csv[:, :2], np.column_stack([np.arange(12), np.arange(12) / 60]), atol=1e-9)
    assert main(["track", "cmu:07_10", "--filter", "ukf-real", "--rate", "ticks"]) == 2
    assert "--rate is for tracking --detections" in capsys.readouterr().err


def test_a_scene_is_written_at_the_detections_rate_each_person_where_present(tmp_path):
    """Pose2Sim's multi-person demo (60 fps, 100 frames, two people), joint association: the scene's npz and each
    person's TRC at the 100 frames; a person's frames outside their ticks stay absent."""
    from priortrack.data.calibration import read_calibration
    from priortrack.data.scene_detections import read_scene_detections
    from priortrack.tracking.people import track_scene
    from priortrack.data.trc import read_trc
    from priortrack.tracking.person import TrackConfig

    scene = read_scene_detections(MULTIPERSON / "pose").head(20)
    calibration = read_calibration(MULTIPERSON / "calibration" / "Calib.qca.txt")
    result = track_scene(scene, calibration, "ukf-real", TrackConfig(fps=60), workers=1)
    frames = result.at_detection_frames()
    assert frames.fps == 60.0 and frames.frames.tolist() == list(range(20)) and frames.joints.shape[:2] == (20, 2)
    np.testing.assert_allclose(frames.joints[::2], result.joints, atol=1e-12)
    result.joints[3:, 0] = np.nan                              # person 0 gone after tick 2: frames 0–5 only
    cut = result.at_detection_frames()
    present = np.isfinite(cut.joints[..., 0, 0])
    assert present[:, 0].tolist() == [True] * 6 + [False] * 14 and present[:, 1].all()
    assert not cut.mismatch[6:, 0].any() and np.isnan(cut.spread[6:, 0]).all()
    written = frames.save(tmp_path / "s.trc")
    for path, person in zip(written, frames.people):
        trc, names, fps = read_trc(path, up="z")
        assert fps == 60.0 and len(trc) == len(person.joints) and names[0] == "Hip" and names[15] == "Nose"
        np.testing.assert_allclose(trc[:, :15], person.joints, atol=1e-12)


def test_the_lowpass_is_a_zero_lag_fourth_order_butterworth():
    """A sinusoid through the filter, far from the ends, keeps its phase and is scaled by the dual pass's gain
    1 / (1 + (tan(π f / fs) / tan(π f_c / fs))⁴) (the bilinear transform's prewarped Butterworth, squared); a joint's
    gaps are kept and a run too short to pad is left as it is; a cut-off at or over Nyquist is refused."""
    from priortrack.errors import PriortrackError
    from priortrack.tracking.lowpass import PADLEN, lowpassed

    fps, cutoff = 60.0, 6.0
    t = np.arange(1200) / fps
    for f in (1.0, 6.0, 12.0):
        wave = np.stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.zeros_like(t)], axis=-1)[:, None]
        out = lowpassed(wave, fps, cutoff)
        gain = 1 / (1 + (np.tan(np.pi * f / fps) / np.tan(np.pi * cutoff / fps)) ** 4)
        np.testing.assert_allclose(out[400:800], gain * wave[400:800], atol=1e-6)
    assert gain < 0.06                                                           # 12 Hz: an octave over, −25 dB
    noisy = np.random.default_rng(0).normal(size=(100, 2, 3))
    noisy[40:42, 0] = np.nan                                                     # joint 0 absent two frames
    noisy[:50, 1] = noisy[50 + PADLEN:, 1] = np.nan                             # joint 1 seen for PADLEN frames
    out = lowpassed(noisy, fps, cutoff)
    np.testing.assert_array_equal(np.isnan(out), np.isnan(noisy))
    assert np.abs(out[:40, 0] - noisy[:40, 0]).max() > 0.1                       # filtered either side of the gap
    np.testing.assert_array_equal(out[50:50 + PADLEN, 1], noisy[50:50 + PADLEN, 1])     # too short: as it was
    for bad in (30.0, 45.0, 0.0, float("nan")):
        with pytest.raises(PriortrackError, match="the cut-off must lie between 0 and half the output's 60 fps"):
            lowpassed(noisy, fps, bad)


def test_lowpass_on_the_command_line(tmp_path, capsys):
    """--lowpass 6 low-passes what is written (npz lowpass_hz; the acceleration of the wrists falls), not the
    summary; a cut-off of 0 is refused before tracking, one over the output's Nyquist frequency by name."""
    base = ["track", "--detections", str(POSE2SIM_DIR / "pose"), "--cameras", str(POSE2SIM_DIR / "Calib.toml"),
            "--fps", "60", "--filter", "ukf-real"]
    assert main(base + ["--out", str(tmp_path / "raw.npz")]) == 0
    assert main(base + ["--out", str(tmp_path / "low.npz"), "--lowpass", "6"]) == 0
    with np.load(tmp_path / "raw.npz") as raw, np.load(tmp_path / "low.npz") as low:
        assert "lowpass_hz" not in raw.files and float(low["lowpass_hz"]) == 6.0
        accel = [np.abs(np.diff(z["joints"][:, [5, 8]], 2, axis=0)).mean() for z in (raw, low)]
        assert accel[1] < 0.5 * accel[0], accel
        assert np.abs(low["joints"] - raw["joints"]).max() < 0.05
    capsys.readouterr()
    assert main(base + ["--lowpass", "0"]) == 2
    assert "--lowpass is a cut-off frequency in Hz above 0, got 0" in capsys.readouterr().err
    assert main(base + ["--lowpass", "20", "--rate", "ticks", "--out", str(tmp_path / "x.npz")]) == 2
    assert "between 0 and half the output's 30 fps (15 Hz)" in capsys.readouterr().err
