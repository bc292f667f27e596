"""priortrack bench long, small: each run in its own process reports its ticks, its time per tick along the
run and its peak memory beside the reference run's; bad sizes refused. (No timing is asserted: the figures
are the benchmark's, docs/results/2026-11-25-long-recordings.md.)"""

import json

import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.cli.main import main
from priortrack.data.detections import read_detections
from priortrack.experiments.benchmarks.long import bench_long, write_long_input


def test_the_long_input_is_four_cameras_at_60_fps(tmp_path):
    detections = read_detections(str(write_long_input(1300, tmp_path / "long.npz")))
    assert detections.keypoints.shape[:3] == (4, 1300, 25) and detections.fps == 60.0
    seen = detections.keypoints[..., 2] > 0
    assert seen.mean() > 0.4 and seen.any(axis=(0, 2)).all()          # every frame has detections


def test_bench_long_runs_each_preset_in_its_own_process(capsys):
    assert main(["bench", "long", "--frames", "300", "--reference-frames", "300", "--presets", "ukf-real"]) == 0
    run, = json.loads(capsys.readouterr().out)["runs"]
    assert run["preset"] == "ukf-real" and run["frames"] == 300 and run["ticks"] == 150
    assert run["peak_rss_mb"] > 100 and run["peak_over_reference"] > 0 and np.isfinite(run["last_over_first"])
    with pytest.raises(PriortrackError, match="frames must be ≥ 300"):
        bench_long(frames=200)


def test_a_run_s_peak_is_its_own_not_its_parent_s():
    """Linux carries ru_maxrss across fork and exec: a run started by a parent holding 400 MB read 400 MB.
    The bench reads the run's own high-water mark (VmHWM)."""
    import subprocess
    import sys

    held = np.ones(50_000_000)                              # 400 MB in this process
    code = "from priortrack.experiments.benchmarks.long import peak_rss_mb; print(peak_rss_mb())"
    child = float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout)
    assert 10 < child < 500 and held.sum() == 50_000_000          # inherited, it would read this process's 650+
