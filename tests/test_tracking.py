"""Tracking with the shipped presets: every one beats holding the first pose still; the track
command's JSON and recording. Fitted priors are cached in .pytest_cache (see conftest.py); the
tests share one xdist group so the GPDM is fitted once."""

import json

import numpy as np
import pytest
import rerun as rr

from priortrack import PriortrackError
from priortrack.cli.main import main
from priortrack.experiments.metrics import mpjpe
from priortrack.experiments.tracking import TABLE_PRESETS, track
from priortrack.body.fk import joint_positions

pytestmark = pytest.mark.xdist_group("presets")
FRAMES = 40


@pytest.mark.parametrize("preset", TABLE_PRESETS)
def test_every_preset_tracks_a_held_out_walk_better_than_holding_still(preset):
    run = track("walkjog:35_29", preset, "clean", seed=0, frames=FRAMES)
    X = joint_positions(run.motion, "eval15")
    still = mpjpe(np.repeat(X[1:2], FRAMES - 2, 0), X[2:]).mean()
    assert np.isfinite(run.track.estimates).all()
    assert run.result["mpjpe_mm"] < 0.5 * still, (run.result, still)
    assert run.result["frames"] == FRAMES and run.result["seconds_per_frame"] > 0


def _entities(path):
    rows = {}
    for chunk in rr.chunk.RrdReader(str(path)).stream().to_chunks():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows


def test_track_command_prints_the_result_and_logs_the_cloud(tmp_path, capsys):
    out = tmp_path / "track.rrd"
    assert main(["track", "walkjog:35_29", "--filter", "pf-diffusion-local", "--scenario", "blackout",
                 "--frames", "30", "--seed", "1", "--rrd", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result) >= {"filter", "motion", "scenario", "frames", "mpjpe_mm", "mpjpe_root_rel_mm", "err2d_px",
                           "seconds_per_frame", "mean_ess"}
    assert result["filter"] == "pf-diffusion-local" and result["frames"] == 30 and result["mpjpe_mm"] > 0
    rows = _entities(out)
    assert rows["/world/truth"] == 30 and rows["/world/estimate"] == 28
    assert rows["/world/estimate/cloud"] == 28                  # one cloud per filtered frame
    assert rows["/world/estimate/translation"] == 28            # the preset integrates the translation out
    assert rows["/world/camera/image/observations"] == 30


def test_all_missing_frames_are_flagged_and_carried():
    run = track("walkjog:35_29", "pf-diffusion-local", "blackout:start_s=0.3,length_s=0.5", seed=0, frames=30)
    flagged = [t for t, f in enumerate(run.track.flags) if "no-observation" in f]
    assert flagged == list(range(9, 24))
    assert np.isfinite(run.track.estimates).all()


def test_bad_track_arguments(capsys):
    assert main(["track", "walkjog:35_29", "--filter", "pf-nothing"]) == 2
    assert "no preset 'pf-nothing'" in capsys.readouterr().err
    with pytest.raises(PriortrackError, match="frames must be at least 3"):
        track("walkjog:35_29", "pf-diffusion-local", frames=2)


def test_eval_tracking_table_and_ratios():
    from priortrack.experiments.tracking import eval_tracking

    result = eval_tracking(["pf-diffusion-local"], ["clean"], ["cmu:07_10"], seeds=2)
    cell = result["table"]["pf-diffusion-local"]["clean"]
    rows = [track("cmu:07_10", "pf-diffusion-local", "clean", seed).result["mpjpe_mm"] for seed in range(2)]
    assert cell["runs"] == 2 and cell["mpjpe_mm"] == pytest.approx(np.mean(rows))
    assert cell["mpjpe_mm_std"] == pytest.approx(np.std(rows, ddof=1))
    assert result["ratios"]["mpjpe_mm"]["pf-diffusion-local"]["clean"] == pytest.approx(1.0)
    with pytest.raises(PriortrackError, match="seeds must be at least 1"):
        eval_tracking(["pf-diffusion-local"], seeds=0)
    with pytest.raises(PriortrackError, match="jobs must be a positive integer"):
        eval_tracking(["pf-diffusion-local"], jobs=0)


def test_eval_tracking_in_worker_processes_gives_the_same_table():
    """jobs = 2: the runs in two spawned workers, each on this process's torch thread count, give
    exactly the numbers of the runs made here (only the timings differ); a bad motion still fails
    before any run, with its own error."""
    from priortrack.experiments.tracking import eval_tracking

    args = (["pf-diffusion-local", "ukf-diffusion-local"], ["occlusion:sigma_px=5"], ["cmu:07_10"])
    here, workers = eval_tracking(*args, seeds=2), eval_tracking(*args, seeds=2, jobs=2)
    for preset, row in here["table"].items():
        for key in ("mpjpe_mm", "mpjpe_mm_std", "mpjpe_root_rel_mm", "mpjpe_root_rel_mm_std", "runs"):
            assert workers["table"][preset]["occlusion:sigma_px=5"][key] == row["occlusion:sigma_px=5"][key]
    assert here["table"]["pf-diffusion-local"]["occlusion:sigma_px=5"]["mpjpe_mm_std"] > 0   # two seeds, two runs
    with pytest.raises(PriortrackError, match="nothing"):
        eval_tracking(["pf-diffusion-local"], ["clean"], ["cmu:nothing"], seeds=1, jobs=2)
