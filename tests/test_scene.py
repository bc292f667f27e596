"""The scene tracker (priortrack.tracking): every person of Pose2Sim's multi-person demo with an identity
that holds, each person's body tracked by a preset against Pose2Sim's own 3D output, the outputs a user
reads, and the errors they get."""

import json
import logging
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from priortrack import PriortrackError
from priortrack.cli.main import main
from priortrack.data.calibration import read_calibration
from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.data.scene_detections import read_scene_detections
from priortrack.data.trc import read_trc
from priortrack.experiments.compare_detections import LIMBS, read_truth
from priortrack.geometry.camera import PinholeCamera
from priortrack.tracking.people import chosen_people, parse_people, track_scene
from priortrack.tracking.person import TrackConfig
from priortrack.tracking.scene import SceneConfig, SceneTracker
from priortrack.viz.scene import person_color

from test_association import _pose2sims_association

MULTIPERSON = Path(__file__).parent / "data" / "pose2sim_multiperson"
POSE, QCA = MULTIPERSON / "pose", MULTIPERSON / "calibration" / "Calib.qca.txt"
#: Pose2Sim's 3D output of the synthetic person (P1) and of the participant (P2).
POSE2SIM_3D = {name: MULTIPERSON / "pose2sim_output" / f"S00_P01_T02_Participants1-2_{name}_0-100.trc"
               for name in ("P1", "P2")}


@pytest.fixture(scope="module")
def demo():
    scene = read_scene_detections(POSE, keypoints="body25b")
    return scene, read_calibration(QCA)


def test_the_demos_two_people_keep_their_identities_and_the_false_positive_none(demo):
    """The scene tracker alone: two people, no track for cam01/cam02's static false positive, and in every
    frame each person's detections are those Pose2Sim's own association gave one and the same person
    (slot 0 the synthetic person, slot 1 the participant): no identity switch."""
    scene, calibration = demo
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    uv, confidence = scene.eval15(0.3)
    association = SceneTracker(cameras, 60.0).run(uv, confidence, scene.frames)
    assert association.person_ids.tolist() == [0, 1]
    reference = _pose2sims_association(scene)
    for p in range(2):
        owners = set()
        for t in range(len(scene.frames)):
            views = {c: int(association.slots[t, c, p]) for c in range(4) if association.slots[t, c, p] >= 0}
            owners |= {k for k, e in enumerate(reference[t]) if set(views.items()) & set(e.items())}
        assert len(owners) == 1
    assert (association.slots >= 0).any(axis=1).all()                     # both tracked in every frame


def test_the_motion_model_of_the_association_is_a_part_that_can_be_swapped(demo):
    """``SceneTracker(…, motion=M)``: every person's motion model in the association is M's (here the default
    joint Kalman filter counting its predictions: the same decisions), and a model that predicts nobody moves,
    with no process noise, loses the people it follows (measured: 584 detections assigned of 798, a third id)."""
    from priortrack.tracking.motion import JointKalman

    class Counted(JointKalman):
        predictions = 0

        def predicted(self, view):
            Counted.predictions += 1
            return super().predicted(view)

    class Frozen(JointKalman):
        def predict(self, dt):
            self.x[:, 3:] = 0.0                  # no velocity, and almost no process noise

    scene, calibration = demo
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    uv, confidence = scene.eval15(0.3)
    default = SceneTracker(cameras, 60.0).run(uv, confidence, scene.frames)
    counted = SceneTracker(cameras, 60.0, motion=Counted).run(uv, confidence, scene.frames)
    np.testing.assert_array_equal(counted.slots, default.slots)
    assert Counted.predictions >= 2 * 4 * 90                 # two people, four cameras, every frame
    frozen = SceneTracker(cameras, 60.0, motion=Frozen).run(uv, confidence, scene.frames)
    assert (frozen.slots >= 0).sum() < 0.9 * (default.slots >= 0).sum()


def test_each_person_is_within_30_mm_of_pose2sims_own_output(demo, tmp_path, caplog):
    """ukf-real on each person: median joint distance (shoulders to ankles) to Pose2Sim's 3D output of that
    person under 30 mm (the issue's figure; measured 14 mm for the synthetic person, 21 mm for the
    participant); the outputs hold both people."""
    scene, calibration = demo
    with caplog.at_level(logging.WARNING, logger="priortrack.tracking.person"):
        result = track_scene(scene, calibration, "ukf-real", TrackConfig(fps=60))
    assert result.person_ids.tolist() == [0, 1] and not result.skipped
    # each person's summary (issue 60, item 2): their height beside the one Pose2Sim's configuration gives them
    # (participant_height = [1.21, 1.72]), the cameras and frames that saw them, where they were; the ghost's
    # body is named as no adult's
    summary = result.summary()["per_person"]
    for pid, height in (("0", 1.21), ("1", 1.72)):
        assert abs(summary[pid]["height_m"] - height) < 0.08 and summary[pid]["height_from"] == "triangulated"
        assert summary[pid]["frames_seen"] == 100 and len(summary[pid]["cameras"]) == 4
        assert len(summary[pid]["mean_position_m"]) == 3
    assert "(person 0): the body measured over the trial is no adult's (1.1" in caplog.text
    assert "(person 1): the body measured" not in caplog.text
    flagged = [line for line in caplog.text.splitlines() if "flagged as mismatch" in line]   # each warning names its person
    assert flagged and all("(person " in line for line in flagged)
    J = [EVAL15_NAMES.index(j) for j in LIMBS]
    ticks = np.flatnonzero(result.frames >= 0)
    for p, name in enumerate(("P1", "P2")):
        truth = read_truth(POSE2SIM_3D[name], scene, calibration, fps=60)[result.frames[ticks]]
        error = 1000 * np.linalg.norm(result.joints[ticks, p][:, J] - truth, axis=-1)
        assert np.isfinite(error).mean() > 0.85
        assert np.nanmedian(error) < 30, (name, np.nanmedian(error))
    written = [p for path in ("s.npz", "s.csv", "s.trc") for p in result.save(tmp_path / path)]
    assert [p.name for p in written] == ["s.npz", "s.csv", "s_person0.trc", "s_person1.trc"]
    with np.load(tmp_path / "s.npz") as f:
        assert f["joints"].shape == (len(result.frames), 2, 15, 3) and f["person_ids"].tolist() == [0, 1]
        np.testing.assert_array_equal(f["joints"], result.joints)
        assert f["slots"].shape == (100, 4, 2) and f["spread"].shape == (len(result.frames), 2, 15)
        # each person's held-out ratio on the scene's ticks: ukf-real follows the detections (under 1 where judged)
        assert f["held_out_ratio"].shape == (len(result.frames), 2)
        for p in range(2):
            judged = np.isfinite(f["held_out_ratio"][:, p])
            assert judged.mean() > 0.8 and (f["held_out_ratio"][judged, p] < 1.0).all(), p
    rows = np.genfromtxt(tmp_path / "s.csv", delimiter=",", names=True)
    assert set(rows["person"].astype(int)) == {0, 1}
    assert np.isfinite(result.joints[..., 0, 0]).sum() == len(rows)
    points, names, _ = read_trc(tmp_path / "s_person1.trc", "z")              # the person's own run
    present = np.isfinite(result.joints[:, 1, 0, 0])
    assert present.all() and len(points) == len(result.people[1].joints)
    np.testing.assert_allclose(points, result.joints[:, 1], atol=1e-5)


def test_people_tracked_in_worker_processes_are_the_runs_of_this_process_and_their_warnings_reach_it(demo, caplog):
    """``workers=2``: each person's run in a loky worker is the run made here (the workers' torch has one
    thread, as this suite's), what a worker logs (here a mismatch warning) is logged here too, and the progress
    report counts the people tracked."""
    scene, calibration = demo
    runs, warnings, reports = {}, {}, {2: [], 1: []}
    for workers in (2, 1):
        caplog.clear()
        with caplog.at_level("WARNING", logger="priortrack"):
            runs[workers] = track_scene(scene, calibration, "ukf-real", TrackConfig(fps=60), workers=workers,
                                        progress=lambda done, total: reports[workers].append((done, total)))
        warnings[workers] = sorted(r.getMessage() for r in caplog.records if r.name == "priortrack.tracking.person")
    np.testing.assert_array_equal(runs[2].joints, runs[1].joints)
    np.testing.assert_array_equal(runs[2].loglik, runs[1].loglik)
    assert warnings[2] == warnings[1] and any("flagged as mismatch" in w for w in warnings[1])
    assert reports[2] == reports[1] == [(1, 2), (2, 2)]                # each person as their run ends


class _EndsItsProcess:
    """Unpickled in a worker, it ends that process (a worker killed, as by the kernel out of memory)."""

    def __reduce__(self):
        import os

        return os._exit, (1,)


def test_a_worker_that_dies_is_a_clear_error():
    from priortrack.tracking.people import _Pool

    with pytest.raises(PriortrackError, match="a worker process tracking a person ended abruptly .*--workers 1"):
        _Pool(2).track([(_EndsItsProcess(),), (_EndsItsProcess(),)])


def test_the_scene_command_writes_every_person_and_a_recording(tmp_path, capsys):
    """``track --people``: the JSON summary per person, the files, and a recording with each person's
    skeleton and label, their detections per camera and the unassigned ones (the false positive), the association
    and each camera's reprojection error per tick."""
    rrd = tmp_path / "scene.rrd"
    assert main(["track", "--detections", str(POSE), "--cameras", str(QCA), "--keypoints", "body25b", "--fps", "60",
                 "--filter", "ukf-diffusion-local", "--people", "id:1", "--frames", "40", "--out",
                 str(tmp_path / "scene.npz"), "--rrd", str(rrd), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert summary["people"] == [1] and set(summary["per_person"]) == {"1"}
    chunks = list(rr.chunk.RrdReader(rrd).stream().to_chunks())
    entities = {str(c.entity_path) for c in chunks}
    # one annotation context with every colour's bones (re-sent contexts drew no bones in the web viewer)
    contexts = [row for c in chunks if str(c.entity_path) == "/world"
                for name in c.to_record_batch().schema.names if name.startswith("AnnotationContext")
                for row in c.to_record_batch().column(name).to_pylist()]
    assert len(contexts) == 1 and len(contexts[0][0]) >= 3
    assert all(len(e["class_description"]["keypoint_connections"]) == 14 for e in contexts[0][0])
    assert {"/world/person1", "/world/person1/label", "/world/cam01_json/image/detections/person1",
            "/world/cam01_json/image/unassigned", "/world/cam01_json/image/estimate/person1",
            "/world/cam01_json/image/association/person1", "/metrics/reprojection_px/person1/cam01_json",
            "/metrics/held_out_ratio/person1"} <= entities
    assert not any("person0" in e for e in entities)
    # the person's series in the person's colour (set once)
    colors = [row for c in chunks if str(c.entity_path) == "/metrics/loglik/person1"
              for name in c.to_record_batch().schema.names if name.startswith("SeriesLines:colors")
              for row in c.to_record_batch().column(name).to_pylist() if row]
    assert len(colors) == 1 and colors[0] == [int.from_bytes(bytes(person_color(1)) + b"\xff", "big")]
    # each camera's per-tick reprojection of the person: its median is the summary's, over every tick and joint
    for camera, whole in summary["per_person"]["1"]["reprojection_px"].items():
        ticks = [row[0] for c in chunks if str(c.entity_path) == f"/metrics/reprojection_px/person1/{camera}"
                 for name in c.to_record_batch().schema.names if name.startswith("Scalars")
                 for row in c.to_record_batch().column(name).to_pylist() if row]
        assert len(ticks) > 15 and abs(np.median(ticks) - whole) < 0.2 * whole + 1.0, (camera, np.median(ticks), whole)


def test_one_person_asked_of_a_scene_is_the_one_seen_most_through_the_scene_tracker(tmp_path, capsys, caplog):
    """``track --detections`` without ``--people`` on files that hold several people: a scene of one, the person
    the detector saw most (issue 60, item 2: the synthetic 0.6 m figure was taken, in as many frames as the
    participant, 100, but with fewer keypoints found: 8400 against 8958), said in a warning; the outputs are one
    person's, within 30 mm of Pose2Sim's own 3D output of the participant; ``--people 1`` takes them too."""
    from priortrack.tracking.people import associated, chosen_people, seen_most

    out = tmp_path / "one.npz"
    with caplog.at_level("WARNING"):
        assert main(["track", "--detections", str(POSE), "--cameras", str(QCA), "--keypoints", "body25b", "--fps",
                     "60", "--filter", "ukf-real", "--out", str(out), "--json"]) == 0
    assert any("people in a frame: tracking the one seen most (the most keypoints detected" in r.getMessage()
               for r in caplog.records)
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert "per_person" not in summary and summary["written"] == [str(out)]
    scene, calibration = read_scene_detections(POSE, keypoints="body25b"), read_calibration(QCA)
    association, _ = associated(scene, calibration, 60.0, TrackConfig(fps=60))
    assert (association.slots >= 0).any(axis=1).sum(axis=0).tolist() == [100, 100]
    assert seen_most(association, scene).tolist() == [8400, 8958] and chosen_people(association, 1, scene) == [1]
    with np.load(out) as f:
        joints, frames = f["joints"], f["frames"]
    assert joints.shape == (len(frames), 15, 3)
    ticks = np.flatnonzero(frames >= 0)
    truth = read_truth(POSE2SIM_3D["P2"], scene, calibration, fps=60)[frames[ticks]]
    J = [EVAL15_NAMES.index(j) for j in LIMBS]
    assert np.nanmedian(1000 * np.linalg.norm(joints[ticks][:, J] - truth, axis=-1)) < 30


def test_compare_detections_per_person_scores_each_persons_held_out_cameras(tmp_path, capsys):
    """``compare --detections … --people all``: each person's grid in OUT/person<id>/, every camera left out
    in turn and scored on that person's own detections there: the median over held-out cameras within 1.25× of
    the other cameras' per-frame DLT of the same person (measured: the synthetic person 27.6 px against 23.5);
    a person asked for who is not there is named, and a truth file is one person's; the scene is read and
    associated once for the whole grid."""
    from priortrack.experiments.compare_detections import _associated

    out = tmp_path / "cmp"
    common = ["compare", "--filters", "ukf-real", "--detections", str(POSE), "--cameras", str(QCA), "--keypoints",
              "body25b", "--fps", "60", "--frames", "60"]
    _associated.cache_clear()
    assert main(common + ["--people", "all", "--out", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert set(result["people"]) == {"0", "1"}
    # the files read and who is who decided once for the plan and every run of the grid (this process)
    assert _associated.cache_info().misses == 1 and _associated.cache_info().hits >= 8
    for pid, person in result["people"].items():
        assert (out / f"person{pid}" / "summary.md").is_file()
        rows = person["rows"]
        assert sorted(r["held_out"] for r in rows) == ["cam01_json", "cam02_json", "cam03_json", "cam04_json"]
        filtered, dlt = (np.median([r[key] for r in rows]) for key in ("median_px", "dlt_median_px"))
        assert filtered < 40 and filtered <= 1.25 * dlt, (pid, [(r["held_out"], r["median_px"], r["dlt_median_px"])
                                                                for r in rows])
    assert main(common + ["--people", "id:5", "--out", str(out)]) == 2
    assert "no person 5 in the scene (people: 0, 1)" in capsys.readouterr().err
    truth = POSE2SIM_3D["P2"]
    assert main(common + ["--people", "all", "--truth", str(truth), "--out", str(out)]) == 2
    assert "--truth holds one person's joints: compare that person alone" in capsys.readouterr().err
    # one person with their truth (Pose2Sim's 3D of the participant): the all-camera run scored in mm
    assert main(common + ["--people", "id:1", "--truth", str(truth), "--out", str(out), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out.splitlines()[-1])["people"]["1"]["rows"]
    every = [r for r in rows if r["held_out"] == ""]
    assert len(every) == 1 and every[0]["mpjpe_mm"] < 40, every          # measured 29.9 (its DLT 20.9)


def test_compare_detections_without_people_compares_the_one_seen_most_and_says_so(tmp_path, capsys, caplog):
    """Issue 60, item 2: ``compare --detections`` on files of several people, without ``--people``, scored whoever the
    single-person reader followed, without a word. It takes the person ``track`` takes (seen most: the participant)
    and warns; its all-camera run against Pose2Sim's 3D of the participant is under 40 mm."""
    from priortrack.experiments.compare_detections import _associated

    _associated.cache_clear()
    with caplog.at_level("WARNING"):
        assert main(["compare", "--filters", "ukf-real", "--detections", str(POSE), "--cameras", str(QCA), "--fps",
                     "60", "--frames", "60", "--truth", str(POSE2SIM_3D["P2"]), "--out", str(tmp_path / "c"),
                     "--json"]) == 0
    assert any("holds up to 4 people in a frame: comparing the one seen most, person 1" in r.getMessage()
               for r in caplog.records), [r.getMessage() for r in caplog.records]
    rows = json.loads(capsys.readouterr().out.splitlines()[-1])["rows"]
    every = [r for r in rows if r["held_out"] == ""]
    assert len(every) == 1 and every[0]["mpjpe_mm"] < 40, every


def test_people_are_chosen_by_count_id_point_and_box(demo):
    scene, calibration = demo
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    association = SceneTracker(cameras, 60.0).run(*scene.eval15(0.3), scene.frames)
    assert chosen_people(association, parse_people(["all"]), scene) == [0, 1]
    assert len(chosen_people(association, parse_people(["1"]), scene)) == 1
    assert chosen_people(association, parse_people(["id:1"]), scene) == [1]
    # each person cam01 shows in its first frame (only the synthetic person: the participant is not there)
    slot = association.slots[0, 0]
    assert (slot >= 0).tolist() == [True, False]
    for p in np.flatnonzero(slot >= 0):
        xy = scene.keypoints[0, 0, slot[p], :, :2]
        xy = xy[np.isfinite(xy).all(axis=1)]
        centre = xy.mean(axis=0)
        assert chosen_people(association, parse_people([f"at:cam01_json:{centre[0]},{centre[1]}"]), scene) == [p]
        box = ",".join(map(str, [*xy.min(axis=0), *xy.max(axis=0)]))
        assert chosen_people(association, parse_people([f"box:cam01_json:{box}"]), scene) == [p]
        # issue 60, item 2: a point or box where nobody is picks nobody (it picked whoever was nearest, however far)
        far = xy.max(axis=0) + 2 * (xy.max(axis=0) - xy.min(axis=0))
        with pytest.raises(PriortrackError, match="nobody is there in cam01_json's first frame with people"):
            chosen_people(association, parse_people([f"at:cam01_json:{far[0]},{far[1]}"]), scene)
        with pytest.raises(PriortrackError, match="no person overlaps it"):
            chosen_people(association, parse_people([f"box:cam01_json:{far[0]},{far[1]},{far[0] + 5},{far[1] + 5}"]),
                          scene)


@pytest.mark.parametrize("words, message", [
    (["id:x"], "--people id:x: give all, a number N"),
    (["at:cam01_json:5"], "--people at:cam01_json:5: give all"),
    (["two"], "--people two: give all"),
    (["index:1", "id:0"], "--people index:1 id:0: index:N alone"),
    (["index:-1"], "--people index:-1: index:N alone, N a whole number ≥ 0"),
])
def test_bad_people_are_named(words, message):
    with pytest.raises(PriortrackError, match=message):
        parse_people(words)


def test_bad_choices_and_settings_are_named(demo, capsys):
    scene, calibration = demo
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    association = SceneTracker(cameras, 60.0).run(*scene.eval15(0.3), scene.frames)
    with pytest.raises(PriortrackError, match=r"no person 7 in the scene \(people: 0, 1\)"):
        chosen_people(association, [7], scene)
    with pytest.raises(PriortrackError, match=r"no camera 'cam9'"):
        chosen_people(association, parse_people(["at:cam9:1,2"]), scene)
    with pytest.raises(PriortrackError, match="scene setting birth_s must be a number ≥ 0"):
        SceneConfig(birth_s=-1)
    with pytest.raises(PriortrackError, match="birth_views must be a whole number ≥ 2"):
        SceneConfig(birth_views=1)
    with pytest.raises(PriortrackError, match="a scene tracker needs a calibrated camera"):
        SceneTracker([], 60.0)
    with pytest.raises(PriortrackError, match="detections of 4 cameras for 3 calibrated cameras"):
        SceneTracker(cameras[:3], 60.0).run(*scene.eval15(0.3), scene.frames)
    with pytest.raises(PriortrackError, match=r"nobody was seen by 3 cameras for 0.1 s: no person to track \(the "
                                              r"detections hold 2 frames, 0.033 s at 60 fps: give more frames\)"):
        track_scene(scene.head(2), calibration, "ukf-real", TrackConfig(fps=60))
    one = replace(scene.head(2), camera_names=("cam03_json",), keypoints=scene.head(2).keypoints[2:3])
    with pytest.raises(PriortrackError, match=r"nobody was seen whole enough \(3 bones\) by its one camera for 0.1 s"):
        track_scene(one, calibration, "ukf-real", TrackConfig(fps=60, camera_map={"cam03_json": "cam_03"}))
    with pytest.raises(PriortrackError, match="workers must be a number of processes ≥ 1, got 0"):
        track_scene(scene, calibration, "ukf-real", TrackConfig(fps=60), workers=0)
    assert main(["track", "--detections", str(POSE), "--cameras", str(QCA), "--keypoints", "body25b", "--fps", "60",
                 "--filter", "ukf-real", "--workers", "2"]) == 2
    assert "--workers tracks several people side by side: give --people" in capsys.readouterr().err
    with pytest.raises(PriortrackError, match="scene setting association must be one of auto, joints, filter, got 'both'"):
        SceneConfig(association="both")
    for extra, message in ((["--association", "filter"], "--association decides who is who among several people: "
                                                         "give --people"),
                           (["--people", "all", "--association", "both"], "association must be one of auto, joints, filter")):
        assert main(["track", "--detections", str(POSE), "--cameras", str(QCA), "--keypoints", "body25b", "--fps",
                     "60", "--filter", "ukf-real", *extra]) == 2
        assert message in capsys.readouterr().err


def test_the_person_at_an_index_of_each_frames_list_is_tracked_through_the_scene_path(demo, tmp_path, capsys):
    """Issue 60, item 7 and "one path": ``--person N`` (the index of each frame's people list, one person, no scene
    tracker: its own reader and pipeline) is folded into ``--people index:N``: the scene path, with that person's
    detections (the files' own order) and everything a scene's person has; ``--person`` now says so; ``compare``,
    whose people are the scene tracker's, refuses the index; a body (``--skeleton``) is one person's."""
    scene, calibration = demo
    out = tmp_path / "i.npz"
    assert main(["track", "--detections", str(POSE), "--cameras", str(QCA), "--keypoints", "body25b", "--fps", "60",
                 "--filter", "ukf-real", "--frames", "30", "--people", "index:0", "--no-fit-check", "--out", str(out),
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert list(summary["per_person"]) == ["0"]
    result = track_scene(scene.head(30), calibration, "ukf-real", TrackConfig(fps=60, fit_check=False),
                         people=parse_people(["index:0"]))
    from priortrack.tracking.scene import SceneAssociation

    np.testing.assert_array_equal(result.association.slots, SceneAssociation.indexed(scene.head(30), 0).slots)
    with np.load(out) as f:
        np.testing.assert_allclose(f["joints"][:, 0], result.at_detection_frames().joints[:, 0], atol=1e-9)
        assert f["person_ids"].tolist() == [0] and "ess" in f.files and "reprojection_px" in f.files
    common = ["--detections", str(POSE), "--cameras", str(QCA), "--keypoints", "body25b", "--fps", "60"]
    for words, message in ((["track", *common, "--filter", "ukf-real", "--person", "1"],
                            "--person is now --people index:1"),
                           (["compare", *common, "--filters", "ukf-real", "--people", "index:0", "--out", str(tmp_path)],
                            "compare --people: index:N is track's"),
                           (["track", *common, "--filter", "ukf-real", "--people", "all", "--skeleton",
                             str(Path(__file__).parent.parent / "priortrack" / "data" / "cmu" / "asf_amc" / "39.asf")],
                            "a skeleton is one person's body: choose one of the scene's 2 people")):
        assert main(words) == 2
        assert message in capsys.readouterr().err


def test_one_person_asked_of_any_file_of_people_takes_the_scene_path(demo, tmp_path, capsys):
    """"One path" (issue 60): ``track`` without ``--people`` on an .npz of every person (cameras, frames, people,
    keypoints, 3), which the one-person reader refused, is a scene of one as the same detections' OpenPose folder
    is: the same person, the same joints; a one-person .npz stays one person's (read a block at a time)."""
    from priortrack.data.keypoints import LAYOUTS
    from priortrack.data.scene_detections import holds_people

    scene, _ = demo
    people = tmp_path / "people.npz"
    np.savez_compressed(people, keypoints=scene.keypoints[:, :20], keypoint_names=np.array(LAYOUTS["body25b"]),
                        camera_names=np.array(scene.camera_names), frames=scene.frames[:20])
    one = tmp_path / "one.npz"
    np.savez(one, keypoints=scene.keypoints[:, :20, 0], keypoint_names=np.array(LAYOUTS["body25b"]))
    assert holds_people(people) and holds_people(POSE) and not holds_people(one)
    runs = []
    for detections in (POSE, people):
        out = tmp_path / f"{detections.stem}.out.npz"
        assert main(["track", "--detections", str(detections), "--cameras", str(QCA), "--keypoints", "body25b",
                     "--fps", "60", "--frames", "20", "--filter", "ukf-real", "--no-fit-check", "--out", str(out)]) == 0
        with np.load(out) as f:
            runs.append(f["joints"])
    capsys.readouterr()
    assert runs[0].shape == (20, 15, 3)
    np.testing.assert_allclose(runs[1], runs[0], atol=1e-9)


def test_the_filters_decide_who_is_who_by_default_on_two_or_three_cameras():
    """SceneConfig's "auto": the filters' association where views are few (2, 3 cameras), the joint model's on more;
    an explicit choice holds on any rig."""
    from priortrack.tracking.scene import FEW_VIEWS

    auto = SceneConfig()
    assert auto.association == "auto" and FEW_VIEWS == 3
    assert [auto.decided_by(c) for c in (2, 3, 4, 5)] == ["filter", "filter", "joints", "joints"]
    assert SceneConfig(association="joints").decided_by(2) == "joints"
    assert SceneConfig(association="filter").decided_by(5) == "filter"


def test_a_person_whose_detector_never_gives_the_head_is_re_identified_by_the_other_bones():
    """BODY_25 without ears never shows the head: the signature is each bone's median over the frames that measured
    it (the head NaN), and a returning person is matched on the bones both signatures have."""
    from types import SimpleNamespace

    from priortrack.tracking.motion import JointKalman
    from priortrack.tracking.scene import REID_MIN_BONES, ProposalInitiator, Track, bone_lengths

    body = np.random.default_rng(0).normal(0, 0.3, (15, 3)) + [0, 0, 1]
    bones = bone_lengths(body)
    headless = np.where(np.arange(14) == 1, np.nan, bones)                            # bone 1: neck to head
    rows = [headless * (1 + d) for d in (-0.02, 0.0, 0.03)]
    old = Track(3, JointKalman(body), 0, 40, bones=rows)
    assert np.isnan(old.signature[1]) and np.allclose(old.signature[[0, 2]], bones[[0, 2]])
    back = Track(-1, JointKalman(body + [0.3, 0, 0]), 60, 60, bones=[headless], born=(58, body[0] + [0.3, 0, 0]))
    scene = SimpleNamespace(frame=60, ended=[old], next_id=5)
    assert ProposalInitiator(2, 2, 0.15, 25.0)._identity(scene, back) == 3 and not scene.ended
    few = np.full(14, np.nan)
    few[:REID_MIN_BONES - 1] = bones[:REID_MIN_BONES - 1]
    scene = SimpleNamespace(frame=60, ended=[Track(3, JointKalman(body), 0, 40, bones=rows)], next_id=5)
    assert ProposalInitiator(2, 2, 0.15, 25.0)._identity(scene, Track(-1, JointKalman(body), 60, 60, bones=[few],
                                                                      born=(58, body[0]))) == 5


def test_a_scenes_npz_holds_what_one_persons_does(demo, tmp_path):
    """issue 60, item 3: --people's .npz lacked ess, reprojection_px, gated, camera_names and, smoothed, filtered_joints.
    Each is one person's own on the scene's tick grid (every tick of the demo's two people: the same ticks)."""
    scene, calibration = demo
    result = track_scene(scene, calibration, "ukf-real", TrackConfig(fps=60, smooth=True, fit_check=False),
                         workers=1)
    result.save(tmp_path / "s.npz")
    with np.load(tmp_path / "s.npz") as f:
        assert f["camera_names"].tolist() == list(scene.camera_names)
        for p, person in enumerate(result.people):
            assert len(person.frames) == len(f["frames"])
            np.testing.assert_array_equal(f["reprojection_px"][:, p], person.reprojection_by_tick)
            np.testing.assert_array_equal(f["gated"][:, p], person.gated)
            np.testing.assert_array_equal(f["filtered_joints"][:, p], person.filtered_joints)
            np.testing.assert_array_equal(f["ess"][:, p], person.ess)                # NaN: no particles
            assert not np.allclose(f["filtered_joints"][:, p], f["joints"][:, p])       # joints: the smoother's


@pytest.mark.parametrize("how", ["filter", "joints"])
def test_ctrl_c_in_a_scene_writes_what_was_tracked(tmp_path, capsys, monkeypatch, how):
    """Issue 60, item 3: Ctrl-C in ``--people`` wrote nothing. Now, with the filters in lockstep (filter), Ctrl-C at
    tick 20 ends every person's run there and both are written; tracked one after the other (joints, one worker),
    Ctrl-C after the first person writes them and skips the second, saying why; exit 0 and ``interrupted``."""
    import priortrack.cli.track as cli_track
    from priortrack.cli.common import Progress
    from priortrack.tracking.people import INTERRUPTED

    stop_at = 20 if how == "filter" else 1

    class Interrupting(Progress):
        def __call__(self, step, total):
            if step == stop_at:
                raise KeyboardInterrupt

    monkeypatch.setattr(cli_track, "Progress", Interrupting)
    assert main(["track", "--detections", str(POSE), "--cameras", str(QCA), "--fps", "60", "--people", "all",
                 "--association", how, "--workers", "1", "--out", str(tmp_path / "s.npz"), "--json"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["interrupted"] is True and "priortrack: interrupted: writing the" in captured.err
    with np.load(tmp_path / "s.npz") as z:
        present = np.isfinite(z["joints"][..., 0, 0])                        # (frames, people) at 60 fps
    if how == "filter":
        assert summary["people"] == [0, 1] and summary["skipped"] == {}
        assert present[:30].all() and not present[45:].any()                 # 20 ticks of 30 fps: 40 frames
    else:
        assert summary["people"] == [0] and summary["skipped"] == {"1": INTERRUPTED}
        assert present.shape[1] == 1 and present.all()


def test_someone_only_one_camera_sees_is_named_not_dropped_silently(demo, caplog):
    """Issue 60, item 2: a person seen by one camera only vanished without a word. The demo's static false positive
    (cam01 and cam02, SOURCE.md) is reported as someone nobody tracked; with the participant taken out of every camera
    but cam01, cam01's detections of them are reported too, in every frame, where the participant stands."""

    from priortrack.tracking.people import associated

    scene, calibration = demo
    with caplog.at_level("WARNING"):
        result = track_scene(scene, calibration, "ukf-real", TrackConfig(fps=60), workers=1)
    assert result.unclaimed == {"cam01_json": 100, "cam02_json": 90}
    assert any("cam02_json detects someone who is none of the people tracked in 90 of 100 frames" in r.getMessage()
               for r in caplog.records)
    association, _ = associated(scene, calibration, 60.0, TrackConfig(fps=60))
    keypoints = scene.keypoints.copy()
    t, c = np.nonzero(association.slots[:, :, 1] >= 0)
    alone = c > 0
    keypoints[c[alone], t[alone], association.slots[t[alone], c[alone], 1]] = np.nan     # the participant: cam01 only
    caplog.clear()
    with caplog.at_level("WARNING"):
        result = track_scene(replace(scene, keypoints=keypoints), calibration, "ukf-real", TrackConfig(fps=60),
                             workers=1)
    assert result.person_ids.tolist() == [0] and result.unclaimed["cam01_json"] == 100
    said = [r.getMessage() for r in caplog.records if "cam01_json detects someone" in r.getMessage()]
    assert len(said) == 1 and "in 100 of 100 frames (first in frame 0, about pixel" in said[0]
    x, y = (float(v) for v in said[0].split("about pixel ")[1].split(")")[0].split(", "))
    nobody = [n for n in range(keypoints.shape[2]) if n not in association.slots[0, 0, [0]]]  # cam01, frame 0
    strong = [keypoints[0, 0, n][keypoints[0, 0, n, :, 2] >= 0.3, :2] for n in nobody]
    centres = [np.median(points, axis=0) for points in strong if len(points) >= 8]
    assert min(np.linalg.norm(centre - [x, y]) for centre in centres) < 1.0, (x, y, centres)


def test_a_scenes_recording_has_each_persons_particle_cloud_ess_and_events(tmp_path):
    """Issue 60, item 3: ``--people`` recorded no particle cloud, ESS or events. With pf-diffusion-local, each
    person's cloud at every ``--rrd-every`` 2nd tick of their run, their ESS fraction at every tick and their events
    (resampling), prefixed by who they are."""
    rrd = tmp_path / "scene.rrd"
    assert main(["track", "--detections", str(POSE), "--cameras", str(QCA), "--fps", "60", "--filter",
                 "pf-diffusion-local", "--people", "all", "--frames", "24", "--rrd", str(rrd), "--rrd-every", "2"]) == 0
    chunks = list(rr.chunk.RrdReader(rrd).stream().to_chunks())
    rows = {}
    for chunk in chunks:
        rows[str(chunk.entity_path)] = rows.get(str(chunk.entity_path), 0) + chunk.num_rows
    for pid in (0, 1):
        assert rows[f"/world/person{pid}/cloud"] == 5                       # ticks 2, 4, 6, 8, 10 of 12
        ess = [v for c in chunks if str(c.entity_path) == f"/metrics/ess_fraction/person{pid}"
               for name in c.to_record_batch().schema.names if name.startswith("Scalars")
               for v in c.to_record_batch().column(name).to_pylist() if v]
        assert len(ess) == 10 and all(0 < v[0] <= 1 for v in ess)            # every filtered tick, a fraction
    texts = [str(t) for c in chunks if str(c.entity_path) == "/events"
             for t in c.to_record_batch().column("TextLog:text").to_pylist()]
    assert any(t.startswith("['person 1: frame") and "resampled" in t for t in texts), texts[:5]


def test_a_returning_person_with_one_limb_mismatched_is_still_re_identified():
    """A returning person whose first frames triangulate one forearm three times too long (two views' arms crossed) is
    the ended person their twelve other bones say (the RMS over the bones is 0.55 off: a new id, as it was); a person 20 %
    larger in every bone is someone else."""
    from types import SimpleNamespace

    from priortrack.tracking.motion import JointKalman
    from priortrack.tracking.scene import ProposalInitiator, Track, bone_lengths, signature_gap

    body = np.random.default_rng(2).normal(0, 0.3, (15, 3)) + [0, 0, 1]
    bones = bone_lengths(body)
    crossed = bones.copy()
    crossed[4] *= 3.0
    assert signature_gap(crossed, bones) == 0.0
    assert np.sqrt(np.mean(((crossed - bones) / bones) ** 2)) > 0.5
    for new, expected in ((crossed, 3), (bones * 1.2, 5)):
        scene = SimpleNamespace(frame=60, ended=[Track(3, JointKalman(body), 0, 40, bones=[bones])], next_id=5)
        assert ProposalInitiator(2, 2, 0.15, 25.0)._identity(scene, Track(-1, JointKalman(body), 60, 60, bones=[new],
                                                                          born=(58, body[0]))) == expected


def test_a_person_back_whose_first_frames_are_mismatched_is_recognised_as_their_bones_are_measured():
    """Issue 58 (Shelf, cameras 1 and 4: a person unseen by both cameras for 0.8 s came back under a new id, their first
    frames' bones wrong in five of eleven: median gap 2.2 at birth, 0.13 after 1 s, 0.08 after 2 s). Born under a new
    id, they are someone who had ended once the median of their bones, measured since, fits (``recognised``); not where
    the ended person was last seen after the new one started, nor too far to have walked there, nor 20 % larger."""
    from types import SimpleNamespace

    from priortrack.tracking.motion import JointKalman
    from priortrack.tracking.scene import ProposalInitiator, Track, bone_lengths

    body = np.random.default_rng(4).normal(0, 0.3, (15, 3)) + [0, 0, 1]
    bones = bone_lengths(body)
    wrong = bones * np.where(np.arange(14) < 8, 3.0, 1.0)                             # 8 of 14 bones mismatched
    initiator = ProposalInitiator(2, 2, 0.15, 25.0)

    def scene_with(last_seen=40, where=0.0, size=1.0, measured=(wrong, wrong)):
        old = Track(3, JointKalman(body), 0, last_seen, bones=[bones] * 5)
        new = Track(-1, JointKalman(body + [where, 0, 0]), 60, 60, bones=[b * size for b in measured],
                    born=(60, body[0] + [where, 0, 0]))
        return SimpleNamespace(frame=60, ended=[old], next_id=5, fps=25.0), new

    scene, new = scene_with()
    assert initiator._identity(scene, new) == 5 and scene.ended                      # at birth: someone new
    scene, new = scene_with(measured=(wrong, wrong, bones, bones, bones))
    assert initiator.recognised(scene, new) == 3 and not scene.ended and new.born is None and new.first == 0
    assert len(new.bones) == 10                                                        # theirs, then the new ones
    for changed in ({"last_seen": 60}, {"where": 4.0}, {"size": 1.2}):
        scene, new = scene_with(**{"measured": (wrong, bones, bones, bones), **changed})
        assert initiator.recognised(scene, new) is None and scene.ended and new.born is not None


def test_a_person_recognised_after_birth_has_their_id_in_every_frame_since_their_return(demo, monkeypatch):
    """The scene tracker with a returning person's first frames refused (as mismatched ones are): the demo's
    participant hidden from every camera for 36 frames (their track ends after 30) comes back under a new id; judged
    again as their bone measurements double, they are recognised, and every frame since their return is theirs (the
    association as if they had been taken back at birth); the other person's frames are untouched."""
    import priortrack.tracking.scene as scene_module

    scene, calibration = demo
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    uv, confidence = scene.eval15(0.3)
    before = SceneTracker(cameras, 60.0).run(uv, confidence, scene.frames)
    uv = uv.copy()
    claimed = np.zeros(uv.shape[:3], dtype=bool)                       # the two people's, not the false positive
    t, c, p = np.nonzero(before.slots >= 0)
    claimed[c, t, before.slots[t, c, p]] = True
    uv[~claimed] = np.nan
    t, c = np.nonzero(before.slots[40:76, :, 1] >= 0)
    uv[c, t + 40, before.slots[t + 40, c, 1]] = np.nan                              # the participant hidden
    taken_back = SceneTracker(cameras, 60.0).run(uv, confidence, scene.frames)
    assert taken_back.person_ids.tolist() == [0, 1]

    def refused(self, scene, track):                                 # at birth: someone new, whoever they are
        scene.next_id += 1
        return scene.next_id - 1

    monkeypatch.setattr(scene_module.ProposalInitiator, "_identity", refused)
    tracker = SceneTracker(cameras, 60.0)
    after = tracker.run(uv, confidence, scene.frames)
    assert [r[:2] for r in tracker.recognised] == [(2, 1)] and tracker.recognised[0][2] > 75
    assert after.person_ids.tolist() == [0, 1]
    np.testing.assert_array_equal(after.slots, taken_back.slots)
    monkeypatch.setattr(scene_module.ProposalInitiator, "recognised", lambda self, scene, track: None)
    assert SceneTracker(cameras, 60.0).run(uv, confidence, scene.frames).person_ids.tolist() == [0, 1, 2]


def test_a_track_whose_bones_are_no_ones_is_dropped_from_every_frame():
    """Two cameras pair one person's detections in one camera with another person's in the other: the "person" they
    triangulate has bones metres long. ``no_body`` tells it by the median of its bones (one crossed limb does not),
    and the scene tracker leaves such a track out of every frame of its association."""
    from priortrack.tracking.scene import MAX_MEDIAN_BONE_M, REID_MIN_BONES, bone_lengths, no_body

    body = np.random.default_rng(3).normal(0, 0.3, (15, 3))
    bones = bone_lengths(body) / np.median(bone_lengths(body)) * 0.28              # an adult's median bone
    assert not no_body(bones) and not no_body(None)
    crossed = bones.copy()
    crossed[[3, 4]] = [3.0, 9.0]                                                   # an arm paired across people
    assert not no_body(crossed)
    assert no_body(bones * 2.5) and 2.5 * 0.28 > MAX_MEDIAN_BONE_M
    few = np.full(14, np.nan)
    few[:REID_MIN_BONES - 1] = 5.0                                                 # too few bones to judge
    assert not no_body(few)


def test_the_scene_tracker_leaves_a_track_of_no_one_out_of_every_frame(demo, monkeypatch):
    """Pose2Sim's demo with its synthetic person (id 0) judged no one at frame 30: id 0 is in no frame of the
    association (its first 30 frames too), the participant's detections are as before, and the synthetic person's
    detections, left over, may start someone new later (judged again as anyone is)."""
    import priortrack.tracking.scene as scene_module

    scene, calibration = demo
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    uv, confidence = scene.eval15(0.3)
    before = SceneTracker(cameras, 60.0).run(uv, confidence, scene.frames)
    tracker = SceneTracker(cameras, 60.0)
    synthetic = lambda signature: tracker.frame >= 30 and signature is not None and any(     # noqa: E731
        t.id == 0 and np.array_equal(t.signature, signature, equal_nan=True) for t in tracker.live)
    monkeypatch.setattr(scene_module, "no_body", synthetic)
    after = tracker.run(uv, confidence, scene.frames)
    assert before.person_ids.tolist() == [0, 1] and tracker.dropped == {0}
    assert after.person_ids.tolist() == [1, 2]          # 0 in no frame; its detections, left over, start person 2
    np.testing.assert_array_equal(after.slots[:, :, 0], before.slots[:, :, 1])
    assert not (after.slots[:30, :, 1] >= 0).any() and (after.slots[30:, :, 1] >= 0).any()


@pytest.mark.parametrize("camera", range(4))
def test_one_camera_follows_each_person_of_the_demo_as_pose2sim_associated_them(demo, camera):
    """One camera alone (no triangulation: each person placed at the depth their size says): in each of the demo's four
    cameras, the participant and the synthetic person are each one track whose detections are, in every frame but at
    most two, the ones Pose2Sim's own four-camera association gave that person; cam01's and cam02's static false
    positive is a third track (one view cannot tell a standing figure from a person), and nothing else is."""
    scene, calibration = demo
    cameras = [PinholeCamera.from_calibration(calibration.cameras[camera])]
    uv, confidence = scene.eval15(0.3)
    association = SceneTracker(cameras, 60.0).run(uv[camera:camera + 1], confidence[camera:camera + 1], scene.frames)
    reference = _pose2sims_association(scene)
    owners = []
    for p in range(len(association.person_ids)):
        counts = np.zeros(3, dtype=int)                                        # Pose2Sim's person 0, 1, or neither
        for t in np.flatnonzero(association.slots[:, 0, p] >= 0):
            same = [k for k in range(2) if reference[t][k].get(camera) == association.slots[t, 0, p]]
            counts[same[0] if same else 2] += 1
        owners.append(counts)
    people = sorted(int(np.argmax(c)) for c in owners)
    assert people == ([0, 1, 2] if camera in (0, 1) else [0, 1])
    for counts in owners:
        if np.argmax(counts) < 2:
            assert counts.sum() - counts.max() <= 2 and counts.max() >= 95


def test_a_detection_alone_is_placed_at_the_depth_its_size_says():
    """The nominal body, upright and facing a camera 4 m away, seen exactly: placed at 4 m to within a few per cent
    (its hips are foreshortened, its trunk and legs are not); its upper body alone too (the shoulders compared as
    bones, not as the shoulders' width); moved along its rays to another depth it keeps its pixels; two bones are too
    few to place."""
    from priortrack.body.ik import scaled_to_height
    from priortrack.body.fk import joint_positions
    from priortrack.data.bundled import cmu_skeleton
    from priortrack.data.keypoints import detector_map
    from priortrack.data.motion import Motion
    from priortrack.tracking.motion import View
    from priortrack.tracking.association import NOMINAL_HEIGHT_M
    from priortrack.tracking.single_view import at_depth, placed_depth, proposal

    skeleton = scaled_to_height(cmu_skeleton("35"), NOMINAL_HEIGHT_M)
    rest = Motion(skeleton, np.zeros((1, skeleton.num_channels)), 30.0, "rest")
    body = detector_map() @ joint_positions(rest, "eval15")[0]
    view = View(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 1.0, 4.0]), 1000.0)   # Y-up world, the body 4 m ahead
    Xc = body @ view.R.T + view.t
    xy, confidence = Xc[:, :2] / Xc[:, 2:], np.ones(15)
    depth = placed_depth(xy, confidence)
    assert abs(depth - np.median(Xc[:, 2])) < 0.04 * 4.0
    placed = proposal(view, xy, confidence, 3)
    assert placed.views == {0: 3}
    moved = at_depth(view, placed.joints, body + [0.0, 0.0, -2.0])
    Xm = moved @ view.R.T + view.t
    np.testing.assert_allclose(Xm[:, :2] / Xm[:, 2:], xy, atol=1e-12)
    np.testing.assert_allclose(np.median(Xm[:, 2]), np.median(Xc[:, 2]) + 2.0, atol=1e-9)
    few = np.where(np.isin(np.arange(15), [0, 9, 10])[:, None], xy, np.nan)
    assert placed_depth(few, confidence) is None and proposal(view, few, confidence, 0) is None
    upper = np.where(np.isin(np.arange(15), [1, 2, 3, 4, 5, 6, 7, 8])[:, None], xy, np.nan)   # behind a desk
    assert abs(placed_depth(upper, confidence) - np.median(Xc[:, 2])) < 0.04 * 4.0          # was 5.0 m: widths


def test_track_people_from_one_camera_writes_each_person(tmp_path):
    """``track --people all`` on one camera's folder (the demo's cam03, matched by --camera-map) writes the two
    people, each with the body their height gives: the participant's measured from the floor (the calibration's
    origin is on it; Pose2Sim's triangulation puts their shoulders where a 1.61 m template's are, this camera alone
    1.54), the static false positive's (a 0.6 m figure) refused as no adult's and taken as 1.7; without --people,
    one of those two as that scene has them (the lockstep association of two filters against one: within 1 cm)."""
    folder = tmp_path / "pose"
    shutil.copytree(POSE / "cam03_json", folder / "cam03_json")
    out = tmp_path / "one.npz"
    assert main(["track", "--detections", str(folder), "--cameras", str(QCA), "--camera-map", "cam03_json=cam_03",
                 "--keypoints", "body25b", "--fps", "60", "--filter", "ukf-real", "--people", "all", "--no-fit-check",
                 "--out", str(out)]) == 0
    with np.load(out) as f:
        assert f["person_ids"].tolist() == [0, 1] and f["camera_names"].tolist() == ["cam03_json"]
        np.testing.assert_allclose(f["height_m"], [1.54, 1.7], atol=0.02)
        assert np.isfinite(f["joints"]).all(axis=(-1, -2)).mean() > 0.9
        both = f["joints"]
    # without --people the one camera's scene is a scene of one, as with several cameras: the person seen most
    alone = tmp_path / "alone.npz"
    assert main(["track", "--detections", str(folder), "--cameras", str(QCA), "--camera-map", "cam03_json=cam_03",
                 "--keypoints", "body25b", "--fps", "60", "--filter", "ukf-real", "--no-fit-check",
                 "--out", str(alone)]) == 0
    with np.load(alone) as f:
        gaps = [np.nanmedian(np.linalg.norm(f["joints"] - both[:, p], axis=-1)) for p in range(2)]
        assert min(gaps) < 0.01 and max(gaps) > 0.3, gaps
