"""The command line: data list, replay to a rerun recording (read back), bench fk, errors."""

import json
import shlex
import subprocess
import sys

import numpy as np
import pytest
import rerun as rr
import torch

from priortrack import load_motion
from priortrack.cli.main import main
from priortrack.observation import Observations
from priortrack.body.fk import joint_positions


def _points(path, entity, row):
    """The ``row``-th Points3D positions (N, 3) logged at ``entity`` in the recording at ``path``."""
    rows = [np.array(p) for chunk in rr.chunk.RrdReader(str(path)).stream().to_chunks() if chunk.entity_path == entity
            for p in chunk.to_record_batch().column("Points3D:positions").to_pylist()]
    return rows[row]


def _entities(path):
    rows = {}
    for chunk in rr.chunk.RrdReader(str(path)).stream().to_chunks():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows


def test_data_list(capsys):
    assert main(["data", "list", "--json"]) == 0
    clips = json.loads(capsys.readouterr().out)
    by_name = {c["name"]: c for c in clips}
    assert by_name["cmu:07_01"]["frames"] == 316 and by_name["walkjog:35_29"]["fps"] == 30.0
    assert main(["data", "list"]) == 0
    out = capsys.readouterr().out
    assert "mocap.cs.cmu.edu" in out
    command = shlex.split(out.splitlines()[-1])                       # the bundled real trial's command runs as shown
    assert command[:2] == ["priortrack", "track"] and "--detections" in command
    assert main(command[1:-2] + ["--no-fit-check", "--json"]) == 0 and json.loads(capsys.readouterr().out)["frames"] > 0


def test_replay_writes_a_recording_with_every_frame(tmp_path, capsys):
    out, obs = tmp_path / "walk.rrd", tmp_path / "obs.npz"
    assert main(["replay", "cmu:07_01", "--scenario", "occlusion", "--out", str(out),
                 "--observations", str(obs)]) == 0
    assert "79 frames" in capsys.readouterr().out
    rows = _entities(out)
    assert rows["/world/truth"] == 79
    assert rows["/world/camera/image/observations"] == 79
    assert rows["/world/camera/image"] == 1 and rows["/world/camera"] == 1
    observations = Observations.load(obs)
    assert observations.scenario == "occlusion" and observations.uv.shape == (79, 15, 2)
    # During the occlusion only the head is seen; the recording holds what was seen.
    occluded = np.isnan(observations.uv[:, 0, 0])
    assert occluded.any() and not np.isnan(observations.uv[occluded][:, 2]).any()


def test_replay_points_are_the_projected_truth(tmp_path):
    out, obs = tmp_path / "clean.rrd", tmp_path / "clean.npz"
    assert main(["replay", "walkjog:35_29", "--fps", "30", "--out", str(out), "--observations", str(obs)]) == 0
    observations = Observations.load(obs)
    for chunk in rr.chunk.RrdReader(str(out)).stream().to_chunks():
        if chunk.entity_path == "/world/camera/image/observations":
            batch = chunk.to_record_batch()
            first = np.array(batch.column("Points2D:positions")[0].as_py())
            ids = np.array(batch.column("Points2D:keypoint_ids")[0].as_py())
            break
    np.testing.assert_allclose(first, observations.uv[0, ids], atol=1e-3)
    assert len(ids) == 8


def test_bench_fk_json(capsys):
    import torch

    threads = torch.get_num_threads()
    assert main(["bench", "fk", "--batch", "300", "--repeats", "2", "--threads", str(threads + 1), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result) >= {"batch", "priortrack_ms", "pytorch_kinematics_ms", "max_abs_err_m"}
    assert result["batch"] == 300 and result["max_abs_err_m"] < 1e-9 and result["threads"] == threads + 1
    assert torch.get_num_threads() == threads                   # the bench's thread count was scoped


@pytest.mark.parametrize("argv,message", [
    (["replay", "cmu:99_01", "--out", "x.rrd"], "unknown bundled motion"),
    (["replay", "cmu:07_01", "--scenario", "fog", "--out", "x.rrd"], "fog"),
    (["replay", "cmu:07_01", "--scenario", "noise:sigma=3", "--out", "x.rrd"], "sigma"),
    (["bench", "fk", "--batch", "0"], "positive"),
])
def test_errors_are_one_line_and_exit_2(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("priortrack: error:") and message in err and "Traceback" not in err


def test_console_script_runs():
    result = subprocess.run([sys.executable, "-m", "priortrack.cli.main", "data", "list"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "cmu:135_06" in result.stdout


def test_fit_and_sample_a_prior(tmp_path, capsys):
    prior = tmp_path / "local.npz"
    assert main(["fit", "diffusion-local", "--train", "walkjog:35_0[1-4]", "--out", str(prior)]) == 0
    out = capsys.readouterr().out
    assert "diffusion-local prior" in out and "4 motions" in out and "final objective" in out
    rrd = tmp_path / "rollouts.rrd"
    assert main(["sample", str(prior), "--from", "cmu:07_01", "--frame", "5", "--steps", "12", "--n", "3",
                 "--out", str(rrd)]) == 0
    rows = _entities(rrd)
    assert rows["/world/truth"] == 13 and all(rows[f"/world/rollouts/{k}"] == 13 for k in range(3))
    capsys.readouterr()
    for argv, message in ((["--frame", "79"], r"--frame must be in [0, 78] (cmu:07_01 at 30 fps), got 79"),
                          (["--steps", "0"], "--steps must be positive, got 0"), (["--n", "-3"], "--n must be positive, got -3")):
        assert main(["sample", str(prior), "--from", "cmu:07_01", *argv, "--out", str(rrd)]) == 2
        assert message in capsys.readouterr().err


def test_fit_lie_and_plot_refuses_non_gpdm(tmp_path, capsys):
    prior = tmp_path / "lie.npz"
    assert main(["fit", "lie", "--train", "cmu:07_0[12]", "walkjog:35_0[1-6]", "--components", "8",
                 "--out", str(prior)]) == 0
    assert "lie prior" in capsys.readouterr().out
    assert main(["plot", str(prior), "--out", str(tmp_path / "x.png")]) == 2
    assert "draws the latent space of a gpdm" in capsys.readouterr().err


def test_fit_a_gpdm_with_its_dynamics_noise_floor(tmp_path, capsys):
    from priortrack.priors import load_prior

    prior = tmp_path / "bgpdm.npz"
    assert main(["fit", "bgpdm", "--train", "walkjog:35_01", "--fps", "10", "--dynamics-noise-floor", "1e-2",
                 "--out", str(prior)]) == 0
    model = load_prior(prior)
    assert model.fit_summary["dynamics_noise_floor"] == 1e-2 and 1 / model.alpha[3] >= 1e-2 * (1 - 1e-12)
    # Rollouts from the held-out 35_02: the truth logged beside them is its real pose (its pairwise
    # joint distances are the mocap's), not μ_Y of its latent, which is off by centimetres.
    rrd = tmp_path / "rollouts.rrd"
    assert main(["sample", str(prior), "--from", "walkjog:35_02", "--frame", "4", "--steps", "2", "--n", "2",
                 "--out", str(rrd)]) == 0
    truth = np.stack([_points(rrd, "/world/truth", row) for row in range(3)])
    real = torch.as_tensor(joint_positions(load_motion("walkjog:35_02").resample(10), "eval15")[4:7])
    truth = torch.as_tensor(truth, dtype=torch.float64)
    np.testing.assert_allclose(torch.cdist(truth, truth), torch.cdist(real, real), atol=1e-5)
    reconstructed = model.joints(model.encode(load_motion("walkjog:35_02"))[4:7])
    assert (torch.cdist(reconstructed, reconstructed) - torch.cdist(real, real)).abs().max() > 0.01
    capsys.readouterr()
    assert main(["fit", "bgpdm", "--train", "walkjog:35_01", "--dynamics-noise-floor", "2", "--out", str(prior)]) == 2
    assert "dynamics_noise_floor must lie in" in capsys.readouterr().err


def test_fit_errors(tmp_path, capsys):
    assert main(["fit", "lie", "--train", "walkjog:99_*", "--out", str(tmp_path / "x.npz")]) == 2
    assert "matches no bundled motion" in capsys.readouterr().err
    assert main(["sample", str(tmp_path / "missing.npz"), "--from", "cmu:07_01", "--out", "x.rrd"]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_track_smooth_prints_both_errors_and_records_both_skeletons(tmp_path, capsys):
    """--smooth: mpjpe_mm is the smoothed estimate's, filtered_mpjpe_mm the filter's own, from the same
    run (ukf-gpdm through a blackout on held-out 07_10: 84 vs 121 mm measured); the recording holds
    the smoothed skeleton beside the filter's."""
    out = tmp_path / "s.rrd"
    assert main(["track", "cmu:07_10", "--filter", "ukf-gpdm", "--scenario", "blackout:sigma_px=5", "--smooth",
                 "--rrd", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["mpjpe_mm"] < 0.8 * result["filtered_mpjpe_mm"] and result["lag"] is None
    rows = _entities(out)
    assert rows["/world/smoothed"] == rows["/world/estimate"] == 74
    assert main(["track", "cmu:07_10", "--filter", "ukf-gpdm", "--frames", "20", "--lag", "3", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["lag"] == 3
    assert main(["track", "cmu:07_10", "--filter", "ukf-gpdm", "--lag", "-1"]) == 2
    assert "--lag must be" in capsys.readouterr().err


def test_off_a_terminal_progress_is_a_line_every_ten_seconds_and_the_last(monkeypatch, capsys):
    """issue 60, item 6: with stderr not a terminal (a log, nohup, a notebook's !) nothing showed, even with -v. Now a
    line every INTERVAL_S seconds, and the last one at the end; ticks, not frames."""
    from priortrack.cli import common

    clock = iter([0.0, 4.0, 11.0, 12.0, 13.0])
    monkeypatch.setattr(common.time, "perf_counter", lambda: next(clock))
    progress = common.Progress("track ukf-real", "tick {0} of {1}", rate=True)
    assert not progress.shown                                          # pytest's captured stderr is no terminal
    for step in (1, 5, 12, 13, 14):
        progress(step, 100)
    progress.close()
    lines = capsys.readouterr().err.splitlines()
    assert [line.split("  ")[0] for line in lines] == ["track ukf-real: tick 1 of 100", "track ukf-real: tick 12 of 100",
                                                        "track ukf-real: tick 14 of 100"]
    assert "ETA" in lines[-1]


def test_the_progress_line_gives_the_rate_and_the_time_left(monkeypatch, capsys):
    """track's progress line: frames per second since the first update, and the time left at that rate."""
    from priortrack.cli import common

    clock = iter([100.0, 101.0])
    monkeypatch.setattr(common.time, "perf_counter", lambda: next(clock))
    progress = common.Progress("track pf-lie", "frame {0} of {1}", rate=True)
    progress.shown = True
    progress(2, 1002)
    progress(12, 1002)
    progress.close()
    lines = capsys.readouterr().err.split("\r")
    assert lines[-1].strip() == "track pf-lie: frame 12 of 1002  10.0/s  ETA 1:39"
