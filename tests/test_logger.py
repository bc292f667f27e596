"""RerunLogger (issue 20, item 3): a user's own filter loop written to a recording, read back with its
layout (issue 30: labels off, one time-series view per quantity, events, the 3D view framed)."""

import numpy as np
import rerun as rr

from priortrack.body.fk import joint_positions
from priortrack.data.bundled import load_bundled
from priortrack.tracking.presets import load_preset
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
    assert rows["/world/truth"] == rows["/world/estimate"] == rows["/metrics/error_mm"] == rows["/metrics/ess_fraction"] == 18
    assert rows["/metrics/loglik"] == 17                                  # not on the frame with nothing seen
    assert rows["/events"] >= 1 and rows["/world/estimate/cloud"] == 18
    texts = [t for c in chunks if str(c.entity_path) == "/events"
             for t in c.to_record_batch().column("TextLog:text").to_pylist()]
    assert any("frame 12: nothing observed" in str(t) for t in texts)
    assert any("resampled" in str(t) for t in texts)
    fractions = [v for c in chunks if str(c.entity_path) == "/metrics/ess_fraction"
                 for v in c.to_record_batch().column("Scalars:scalars").to_pylist()]
    assert all(0 < f[0] <= 1 for f in fractions)
    labels = [c.to_record_batch().column("Points3D:show_labels").to_pylist() for c in chunks
              if str(c.entity_path) == "/world/estimate"]
    assert labels and all(row == [False] for batch in labels for row in batch)
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


def _views(path) -> list[tuple[str, str, str]]:
    """The (kind, name, origin) of every view of a recording's blueprint, read back from the .rrd."""
    reader = rr.chunk.RrdReader(str(path))
    views = []
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        if "ViewBlueprint:class_identifier" in batch.schema.names:
            views.append(tuple(batch.column(f"ViewBlueprint:{k}").to_pylist()[0][0]
                               for k in ("class_identifier", "display_name", "space_origin")))
    return views


def test_the_recording_carries_its_layout(tmp_path):
    """The blueprint stored in the .rrd: the 3D world (its eye on the person, beyond the camera), the
    camera's image, one time series per quantity named with its unit, the events; a valid entry name."""
    from priortrack.viz.recording import QUANTITIES, Recording, entry_name

    camera = default_camera(np.zeros((1, 15, 3)) + [0, 1, 0])
    with RerunLogger(tmp_path / "b.rrd", camera, name="pf-lie · 07_10 · occlusion:sigma_px=5") as logger:
        logger.log(0, observation=np.full((15, 2), 500.0), truth=np.zeros((15, 3)) + [0, 1, 0],
                   estimate=np.zeros((15, 3)) + [0, 1.01, 0], mismatch=True)
    views = sorted(_views(tmp_path / "b.rrd"))
    assert views == sorted([("3D", "3D", "world"), ("2D", "camera", "world/camera/image"),
                            ("TimeSeries", QUANTITIES["error_mm"], "metrics/error_mm"),
                            ("TimeSeries", QUANTITIES["mismatch"], "metrics/mismatch"),
                            ("TextLog", "events", "events")])
    reader = rr.chunk.RrdReader(str(tmp_path / "b.rrd"))
    assert {s.application_id for s in reader.recordings()} == {"priortrack"}
    assert entry_name("pf-lie_cmu-07_10_occlusion-sigma_px=5_seed0") == "pf-lie_cmu-07_10_occlusion-sigma_px-5_seed0"
    with Recording(tmp_path / "c.rrd", up="z") as rec:                     # the eye looks at the person
        rec.camera(camera, "side")
        rec.skeleton("truth", np.zeros((15, 3)) + [2.0, 3.0, 1.0])
    reader = rr.chunk.RrdReader(str(tmp_path / "c.rrd"))
    eye = next(c.to_record_batch() for c in reader.stream(store=reader.blueprints()[0]).to_chunks()
               if str(c.entity_path).endswith("/EyeControls3D"))
    target, position, up = (np.array(eye.column(f"EyeControls3D:{k}").to_pylist()[0][0])
                            for k in ("look_target", "position", "eye_up"))
    np.testing.assert_allclose(target, [2.0, 3.0, 1.0]) and np.testing.assert_allclose(up, [0, 0, 1])
    centre = camera.center.numpy()
    assert np.linalg.norm(position - target) > np.linalg.norm(centre - target)   # the camera in view, behind the eye's target
    assert (position - target) @ (centre - target) > 0                           # looking from the camera's side


def test_step_events_name_what_happened():
    """Resampling, gating (with the count held out), the gate reopening, nothing observed and mismatch
    become events, each once, with its level."""
    from priortrack.filters.snapshot import StepRecord
    from priortrack.viz.logger import step_events

    step = StepRecord(7, 1.5, 4, True, ("innovation-gated", "gate-reopened"), np.array([True, False, True]))
    events = step_events(7, step, mismatch=True, observed=True)
    assert events == [("frame 7: resampled (ESS 2 of 4)", "DEBUG"),
                      ("frame 7: the gate held out detections the prediction cannot explain (2 points)", "INFO"),
                      ("frame 7: the gate reopened: every detection had failed it too long", "WARN"),
                      ("frame 7: mismatch: the prior does not explain this frame", "WARN")]
    quiet = StepRecord(8, 4.0, 4, False, ("no-observation",))
    assert step_events(8, quiet, observed=False) == [("frame 8: nothing observed: the prediction stands", "WARN")]
    assert step_events(9, None, observed=False) == [("frame 9: missing: nothing observed", "WARN")]
    repaired = StepRecord(10, 4.0, 4, False, ("branch-repaired",))
    assert step_events(10, repaired) == [("frame 10: an elbow one camera sees moved off its branch through the chest",
                                          "INFO")]
    assert step_events(-1, quiet, observed=False) == [("a tick without a detection frame: nothing observed: the "
                                                      "prediction stands", "WARN")]
    turned = StepRecord(11, 4.0, 4, False, ("facing-turned",))
    assert step_events(11, turned) == [("frame 11: a trunk one camera sees turned to the facing its feet and face show",
                                        "INFO")]
    floored = StepRecord(12, 4.0, 4, False, ("floor-contact",))           # every tick of a one-camera unscented run
    assert step_events(12, floored) == [("frame 12: the lower ankle held on the floor (one camera)", "DEBUG")]


def test_a_clouds_colours_span_four_decades_of_weight(tmp_path):
    """Issue 60, item 6: weights from 1e-120 to 1 coloured by their share of the heaviest showed one colour. Levels
    are 1 + clip(log10(w / max), −4, 0) / 4; a recorded cloud's colours go from dark blue to yellow by them."""
    from priortrack.viz.recording import Recording
    from priortrack.viz.weights import DECADES, weight_levels

    w = np.array([1.0, 1e-1, 1e-2, 1e-4, 1e-120, 0.0]) * 0.3
    np.testing.assert_allclose(weight_levels(w), [1.0, 0.75, 0.5, 0.0, 0.0, 0.0])
    assert DECADES == 4 and weight_levels(np.zeros(3)).tolist() == [1.0, 1.0, 1.0]
    assert weight_levels([-0.2, np.nan, 0.6]).tolist() == [0.0, 0.0, 1.0]    # a sigma point's negative weight: lowest
    path = tmp_path / "cloud.rrd"
    with Recording(path, "cloud") as recording:
        recording.frame(0)
        recording.cloud("estimate", np.zeros((6, 15, 3)), w)
    colors = [row for c in _chunks(path) if str(c.entity_path) == "/world/estimate/cloud"
              for row in c.to_record_batch().column("Points3D:colors").to_pylist() if row][0]
    rgba = np.array([[(v >> s) & 255 for s in (24, 16, 8)] for v in colors[::15]])     # one joint a particle
    np.testing.assert_array_equal(rgba[[0, 3]], [[255, 230, 40], [30, 40, 120]])
    np.testing.assert_array_equal(rgba[1], (np.array([30, 40, 120]) + 0.75 * np.array([225, 190, -80])).astype(int))
