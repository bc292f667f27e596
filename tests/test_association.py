"""Cross-view association (priortrack.tracking.association): ray distances against closed forms, people
placed in the Pose2Sim demo's cameras grouped exactly, and the demo's real detections grouped as
Pose2Sim's own association grouped them."""

import json
from pathlib import Path

import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.data.calibration import read_calibration
from priortrack.data.scene_detections import read_scene_detections
from priortrack.experiments.real_format import placed_walk
from priortrack.geometry.camera import PinholeCamera
from priortrack.tracking.association import associate, pair_distances

MULTIPERSON = Path(__file__).parent / "data" / "pose2sim_multiperson"


@pytest.fixture(scope="module")
def cameras():
    return [PinholeCamera.from_calibration(c)
            for c in read_calibration(MULTIPERSON / "calibration" / "Calib.qca.txt").cameras]


def test_ray_distance_is_the_closed_form():
    """Rays from (0, 0, 0) along x and from (0, 1, h) along y: the lines are h apart; rays meeting in
    front of both cameras are 0 apart; rays whose nearest points lie behind a camera do not count."""
    ex, ey = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    for h in (0.0, 0.07, 0.3):
        d = pair_distances(np.zeros(3), np.tile(ex, (1, 5, 1)), np.ones((1, 5)),
                           np.array([2.0, -1.0, h]), np.tile(ey, (1, 5, 1)), np.ones((1, 5)))
        np.testing.assert_allclose(d, [[h]], atol=1e-12)
    behind = pair_distances(np.zeros(3), np.tile(ex, (1, 5, 1)), np.ones((1, 5)),
                            np.array([-2.0, -1.0, 0.0]), np.tile(ey, (1, 5, 1)), np.ones((1, 5)))
    assert np.isinf(behind).all()
    few = pair_distances(np.zeros(3), np.tile(ex, (1, 5, 1)), np.r_[np.ones(3), 0, 0][None],
                         np.array([2.0, -1.0, 0.0]), np.tile(ey, (1, 5, 1)), np.ones((1, 5)))
    assert np.isinf(few).all()                                       # 3 shared joints: fewer than MIN_SHARED


def _views(X: np.ndarray, cameras, rng, noise_px: float = 3.0):
    """Every camera's people (shuffled), pixels with noise, and the order each camera shuffled them in."""
    uv, conf, orders = [], [], []
    for camera in cameras:
        p = np.stack([camera.project(x)[0] for x in X]) + rng.normal(0, noise_px, (len(X), 15, 2))
        order = rng.permutation(len(X))
        uv.append(p[order])
        conf.append(rng.uniform(0.6, 1.0, (len(X), 15)))
        orders.append(order)
    return uv, conf, orders


@pytest.mark.parametrize("gap", [0.3, 0.5, 1.0])
def test_three_people_are_grouped_exactly_and_triangulated(cameras, gap):
    """Three walks placed ``gap`` metres apart across the demo's capture volume, 3 px noise, every camera's
    list shuffled: three proposals of four views, each person's views together, the joints within 2 cm."""
    rng = np.random.default_rng(1)
    walks = ["walkjog:35_29", "cmu:07_10", "cmu:07_11"]
    X = np.stack([placed_walk(w, "z", seconds=0.5)[10] + [0.0, (i - 1) * gap, 0.0] for i, w in enumerate(walks)])
    uv, conf, orders = _views(X, cameras, rng)
    result = associate(cameras, uv, conf)
    assert not result.candidates and len(result.proposals) == 3
    for proposal in result.proposals:
        assert len(proposal.views) == 4
        people = {int(orders[c][n]) for c, n in proposal.views.items()}
        assert len(people) == 1
        truth = X[people.pop()]
        assert np.median(np.linalg.norm(proposal.joints - truth, axis=-1)) < 0.02
        assert (proposal.reprojection_px < 10).all()


def test_a_person_in_one_camera_is_a_candidate_and_bad_input_is_named(cameras):
    rng = np.random.default_rng(2)
    X = placed_walk("walkjog:35_29", "z", seconds=0.5)[:2]
    uv, conf, _ = _views(X[:1], cameras, rng)
    uv[2] = np.concatenate([uv[2], cameras[2].project(X[1] + [0, 1.5, 0])[0][None]])
    conf[2] = np.concatenate([conf[2], np.ones((1, 15))])
    result = associate(cameras, uv, conf)
    assert [len(p.views) for p in result.proposals] == [4] and result.candidates == [(2, 1)]
    with pytest.raises(PriortrackError, match="3 cameras' people and 4 confidences for 4 cameras"):
        associate(cameras, uv[:3], conf)


def _pose2sims_association(scene) -> list[list[dict[int, int]]]:
    """Per frame, per person of Pose2Sim's pose-associated files (slot 0, slot 1): {camera: the slot of
    ``scene`` holding the same keypoints} (each associated entry is a byte copy of a raw detection)."""
    folders = sorted((MULTIPERSON / "pose2sim_output" / "pose-associated").iterdir())
    frames = []
    for t in range(scene.keypoints.shape[1]):
        people: list[dict[int, int]] = [{}, {}]
        for c, folder in enumerate(folders):
            entries = json.loads(sorted(folder.glob("*.json"))[t].read_text())["people"]
            for slot, entry in enumerate(entries[:2]):
                values = entry.get("pose_keypoints_2d") if isinstance(entry, dict) else None
                if not values:
                    continue
                kp = np.asarray(values, dtype=np.float32).reshape(-1, 3)
                kp[kp[:, 2] == 0, :2] = np.nan
                same = [n for n in range(scene.keypoints.shape[2])
                        if np.array_equal(scene.keypoints[c, t, n, :, :2], kp[:, :2], equal_nan=True)]
                people[slot][c] = same[0]
        frames.append(people)
    return frames


def test_pose2sims_demo_is_grouped_as_pose2sim_grouped_it(cameras):
    """Pose2Sim's multi-person demo (a participant, a synthetic person, a static false positive in
    cam01 and cam02): in every frame the groups equal Pose2Sim's own association (its pose-associated
    files, slot 0 the synthetic person, slot 1 the participant) but where Pose2Sim left a view out (cam03
    at frame 52) or cam01 split the participant in two partial detections (frame 37, either is the
    participant); the false positive never has more than its two cameras."""
    scene = read_scene_detections(MULTIPERSON / "pose", keypoints="body25b")
    uv, conf = scene.eval15(0.3)
    reference = _pose2sims_association(scene)
    agree = 0
    for t in range(uv.shape[1]):
        seen = [np.isfinite(uv[c, t]).any(axis=(-1, -2)) for c in range(4)]
        kept = [np.flatnonzero(s) for s in seen]                          # slots with a joint above 0.3
        result = associate(cameras, [uv[c, t][s] for c, s in enumerate(seen)],
                           [conf[c, t][s] for c, s in enumerate(seen)])
        groups = [{c: int(kept[c][n]) for c, n in p.views.items()} for p in result.proposals]
        expected = [{int(c): n for c, n in person.items()} for person in reference[t]]
        agree += all(e in groups for e in expected)
        false_positive = [g for g in groups if not any(set(g.items()) & set(e.items()) for e in expected)]
        assert all(len(g) <= 2 and set(g) <= {0, 1} for g in false_positive), (t, groups, expected)
    assert agree >= 98


def test_every_person_is_read_from_coco_results_and_npz(tmp_path):
    """Several people per image in a COCO results file (MMPose writes one entry each; an entry with no
    keypoints is nobody) and in an .npz of (cameras, frames, people, K, 3), read slot by slot."""
    rng = np.random.default_rng(0)
    people = rng.uniform(10, 500, (3, 2, 17, 3))                       # (frames, people, K, 3)
    people[..., 2] = 0.9
    entries = [{"image_id": t, "keypoints": people[t, n].ravel().tolist(), "score": 0.9}
               for t in range(3) for n in range(2)] + [{"image_id": 1, "keypoints": [], "score": 0.1}]
    (tmp_path / "results.json").write_text(json.dumps(entries))
    scene = read_scene_detections(tmp_path / "results.json")
    assert scene.layout == "coco17" and scene.keypoints.shape == (1, 3, 2, 17, 3)
    np.testing.assert_allclose(scene.keypoints[0], people, rtol=1e-6)
    np.savez(tmp_path / "s.npz", keypoints=people[None], keypoint_names=np.array(scene.keypoint_names), fps=30.0)
    scene = read_scene_detections(tmp_path / "s.npz")
    assert scene.fps == 30.0 and scene.people.tolist() == [[2, 2, 2]]
    np.savez(tmp_path / "bad.npz", keypoints=people, keypoint_names=np.array(scene.keypoint_names))
    with pytest.raises(PriortrackError, match=r"expected \(cameras, frames, people, keypoints, 3\)"):
        read_scene_detections(tmp_path / "bad.npz")
    (tmp_path / "results.txt").write_text("x")
    with pytest.raises(PriortrackError, match="several people are read from"):
        read_scene_detections(tmp_path / "results.txt")


def test_a_track_gives_back_a_detection_its_other_cameras_rays_do_not_meet():
    """Two cameras a quarter turn apart; a person at the origin and a second 1.5 m behind them in line with camera
    B. A track of the first that took the second's detection in B (their images overlap there) gives it back: the
    rays of B's detection pass the first person at other heights (its knee ray at their ankle), and it costs more
    than A's; with the first person's own detection in B, the track keeps both."""
    from priortrack.tracking.association import PAIR_GATE_M, normalised
    from priortrack.tracking.motion import View
    from priortrack.tracking.scene import PredictionAssociator

    body = placed_walk("cmu:07_10", "z")[0]
    first = body - [*body[0, :2], 0.0]
    second = first + [0.0, 1.5, 0.0]
    a = PinholeCamera.look_at((-3.0, 0.0, 1.5), (0.0, 0.0, 1.0), up=(0, 0, 1), focal_px=1000, width=1000, height=1000)
    b = PinholeCamera.look_at((0.0, -3.0, 1.5), (0.0, 0.0, 1.0), up=(0, 0, 1), focal_px=1000, width=1000, height=1000)
    xy = normalised([a, b], [a.project(first)[0][None], np.stack([b.project(first)[0], b.project(second)[0]])])
    confidence = [np.ones((1, 15)), np.ones((2, 15))]
    views = [View.of(a), View.of(b)]
    associator = PredictionAssociator()
    assert pair_distances(views[0].centre, views[0].rays(xy[0][:1]), confidence[0][:1], views[1].centre,
                          views[1].rays(xy[1][1:]), confidence[1][1:])[0, 0] > PAIR_GATE_M
    kept = associator.consistent({0: (0, False), 1: (1, False)}, views, xy, confidence, {0: 2.0, 1: 5.0})
    assert kept == {0: (0, False)}
    both = {0: (0, False), 1: (0, False)}
    assert associator.consistent(both, views, xy, confidence, {0: 2.0, 1: 5.0}) == both


def test_a_body_no_adult_has_is_two_peoples_detections_paired():
    """Two cameras a quarter turn apart see one "person" twice an adult's size: their rays meet exactly (it is a 3D
    configuration), yet in each camera it is the image of an adult at half the distance, so in two views of several
    people it is what pairing one person's detection in A with another's in B makes (Shelf, cameras 0 and 3: the
    rays of such a pair 0.03–0.09 m apart, a true pair's 0.01–0.05). ``body_scale`` measures it (the nominal adult
    1, this one 2); ``associate`` leaves the two detections apart, and a track given both gives back the costlier;
    an adult 1.2× the nominal is paired and kept. Too few measures: no judgement."""
    from priortrack.tracking.association import MAX_BODY_SCALE, body_scale, nominal_measures, normalised
    from priortrack.tracking.motion import View
    from priortrack.tracking.scene import PredictionAssociator
    from priortrack.body.ik import measured_distances

    body = placed_walk("cmu:07_10", "z")[0]
    body = body - [*body[0, :2], 0.0]
    a = PinholeCamera.look_at((-4.0, 0.0, 1.5), (0.0, 0.0, 1.0), up=(0, 0, 1), focal_px=1000, width=1000, height=1000)
    b = PinholeCamera.look_at((0.0, -4.0, 1.5), (0.0, 0.0, 1.0), up=(0, 0, 1), focal_px=1000, width=1000, height=1000)
    adult = np.median(measured_distances(body[None]) / nominal_measures()[1:])
    assert 0.8 < adult < 1.2
    for size, paired in ((2.0 / adult, False), (1.2 / adult, True)):
        person = body[0] + size * (body - body[0])
        assert body_scale(person) == pytest.approx(size * adult) and (body_scale(person) > MAX_BODY_SCALE) != paired
        uv = [a.project(person)[0][None], b.project(person)[0][None]]
        views, xy = [View.of(a), View.of(b)], normalised([a, b], uv)
        assert pair_distances(views[0].centre, views[0].rays(xy[0]), np.ones((1, 15)),
                              views[1].centre, views[1].rays(xy[1]), np.ones((1, 15)))[0, 0] < 1e-9
        grouped = associate([a, b], uv, [np.ones((1, 15))] * 2)
        assert len(grouped.proposals) == int(paired) and len(grouped.candidates) == 2 * (1 - int(paired))
        kept = PredictionAssociator().consistent({0: (0, False), 1: (0, False)}, views, xy, [np.ones((1, 15))] * 2,
                                                 {0: 2.0, 1: 5.0})
        assert kept == ({0: (0, False), 1: (0, False)} if paired else {0: (0, False)})
    few = np.full((15, 3), np.nan)
    few[[9, 10, 11]] = body[[9, 10, 11]] * 3                      # a thigh and a shin: two of the eight measures
    assert np.isnan(body_scale(few))
