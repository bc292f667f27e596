"""RerunLogger (issue 20, item 3): a user's own filter loop written to a recording, read back."""

import numpy as np
import rerun as rr

from priortrack.body.fk import joint_positions
from priortrack.data.bundled import load_bundled
from priortrack.experiments.presets import load_preset
from priortrack.observation.synthetic import default_camera, synthesize
from priortrack.viz.logger import OCCLUDED_COLOR, TRUTH_COLOR, RerunLogger


def _chunks(path):
    return list(rr.chunk.RrdReader(str(path)).stream().to_chunks())


def test_a_users_loop_is_recorded_with_its_scalars_flags_and_occlusions(tmp_path):
    walk = load_bundled("cmu:07_10").resample(30)[:20]
    truth = joint_positions(walk, "eval15")
    camera = default_camera(truth)
    z = synthesize(truth, walk.fps, camera, "occlusion", seed=0, sigma_px=5, start_s=0.3, length_s=0.2).uv
    z[12] = np.nan                                                    # one frame with nothing seen: flagged
    filt = load_preset("pf-diffusion-local").build(camera, seed=0)
    filt.initialise(walk)
    path = tmp_path / "mine.rrd"
    with RerunLogger(path, camera, name="pf · 07_10 · mine", likelihood=filt.model.likelihood) as logger:
        for t in range(2, len(z)):
            logger.log(t, filt.step(z[t]), observation=z[t], truth=truth[t])
    chunks = _chunks(path)
    rows = {}
    for chunk in chunks:
        rows[str(chunk.entity_path)] = rows.get(str(chunk.entity_path), 0) + chunk.num_rows
    assert rows["/world/truth"] == rows["/world/estimate"] == rows["/metrics/error_mm"] == rows["/metrics/ess"] == 18
    assert rows["/metrics/loglik"] == 17                                  # not on the frame with nothing seen
    assert rows["/events"] >= 1 and rows["/world/estimate/cloud"] == 18
    texts = [t for c in chunks if str(c.entity_path) == "/events"
             for t in c.to_record_batch().column("TextLog:text").to_pylist()]
    assert any("frame 12: no-observation" in str(t) for t in texts)
    colours = [c.to_record_batch().column("Points3D:colors").to_pylist() for c in chunks
               if str(c.entity_path) == "/world/truth"]
    colours = [row for batch in colours for row in batch]                # one row of 15 colours per frame
    occluded = ~np.isfinite(z[2:]).all(axis=-1)                           # (18, 15)
    grey = _rgba(OCCLUDED_COLOR)
    for row, missing in zip(colours, occluded):
        assert [c == grey for c in row] == missing.tolist()
    assert _rgba(TRUTH_COLOR) in colours[0]


def _rgba(rgb) -> int:
    r, g, b = rgb
    return (r << 24) | (g << 16) | (b << 8) | 0xFF


def test_the_recording_carries_its_default_layout(tmp_path):
    """The blueprint (3D view, camera image, time series, events) is stored in the .rrd beside the data."""
    import subprocess
    import sys
    from pathlib import Path

    camera = default_camera(np.zeros((1, 15, 3)) + [0, 1, 0])
    with RerunLogger(tmp_path / "b.rrd", camera, name="layout") as logger:
        logger.log(0, observation=np.full((15, 2), 500.0), truth=np.zeros((15, 3)) + [0, 1, 0])
    rerun = Path(sys.executable).with_name("rerun")
    printed = subprocess.run([str(rerun), "rrd", "print", str(tmp_path / "b.rrd")], capture_output=True, text=True,
                             check=True).stdout
    assert "Blueprint" in printed and "Recording" in printed
