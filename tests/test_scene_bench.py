"""The scene bench (priortrack.experiments.scenes, `eval scenes`, `bench scene`): the scenes' geometry,
the occlusion model, the scores against hand-made tracks, and one scene tracked end to end."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from priortrack.cli.main import main
from priortrack.data.calibration import read_calibration
from priortrack.experiments.metrics import pcp
from priortrack.experiments.real_format import DEFAULT_CALIBRATION
from priortrack.experiments.scenes import (SCENES, capture_centre, composed, false_positive_place, hidden,
                                           scene_keypoints, score_scene)
from priortrack.geometry.camera import PinholeCamera


@pytest.fixture(scope="module")
def cameras():
    return [PinholeCamera.from_calibration(c) for c in read_calibration(DEFAULT_CALIBRATION).cameras]


def test_passing_walkers_pass_the_gap_apart_where_every_camera_sees_them(cameras):
    centre = capture_centre(cameras)
    for gap in (0.3, 1.0):
        X = composed(SCENES["passing"], gap=gap, centre=centre)
        apart = np.linalg.norm(X[0, :, 0, :2] - X[1, :, 0, :2], axis=-1)
        assert abs(apart.min() - gap) < 0.1, (gap, apart.min())
        travel = X[:, -1, 0, :2] - X[:, 0, 0, :2]
        assert travel[0] @ travel[1] < 0                                  # towards each other
    for camera in cameras:                                                # the centre's body in every image
        uv, front = camera.project(centre + np.array([[0, 0, 0.05], [0, 0, 1.8]]))
        assert front.all() and ((uv >= 0) & (uv < [camera.width, camera.height])).all()


def test_walkers_together_stay_shoulder_to_shoulder_and_hide_each_other(cameras):
    """``together``: the same heading, 0.5 m apart (0.48–0.57 m pelvis to pelvis as their paces differ), and from
    some camera the nearer hides joints of the other in most frames."""
    X = composed(SCENES["together"], centre=capture_centre(cameras))
    apart = np.linalg.norm(X[0, :, 0, :2] - X[1, :, 0, :2], axis=-1)
    assert 0.45 < apart.min() and apart.max() < 0.6, (apart.min(), apart.max())
    travel = X[:, -1, 0, :2] - X[:, 0, 0, :2]
    assert travel[0] @ travel[1] > 0.9 * np.linalg.norm(travel[0]) * np.linalg.norm(travel[1])    # side by side
    assert max(hidden(X, camera).any(axis=(0, 2)).mean() for camera in cameras) > 0.5


def test_a_joint_behind_a_nearer_body_is_hidden_and_the_false_positive_is_seen_by_two(cameras):
    camera = cameras[0]
    X = composed(SCENES["passing"], centre=capture_centre(cameras))[:, :1]
    eye = camera.center.numpy()
    behind = X[1].copy()
    behind[0] = eye + 1.6 * (X[0, 0] - eye)                             # person 1: person 0's joints, further away
    gone = hidden(np.stack([X[0], behind]), camera)
    assert gone[1, 0].all() and not gone[0, 0].any()
    place = false_positive_place(X, cameras)
    assert np.linalg.norm(X[:, :, 0, :2] - place[:2], axis=-1).min() >= 1.0
    keypoints = scene_keypoints(X, cameras, np.random.default_rng(0))
    shown = (keypoints[:, :, -1, :, 2] > 0).sum(axis=-1)[:, 0]
    assert (shown[:2] >= 8).all() and (shown[2:] == 0).all()


def test_pcp_and_the_identity_scores_against_hand_made_tracks():
    """PCP of the truth is 100 %, of a body with one end of one limb moved 1.2 limb lengths (mean end
    error 0.6 > 0.5 of the length) 1 limb in 10 lower; two tracks that exchange their walkers half-way:
    py-motmetrics counts 2 switches and IDF1 0.5."""
    rng = np.random.default_rng(0)
    truth = rng.normal(0, 0.3, (1, 15, 3)) + [0, 0, 1]
    assert pcp(truth, truth) == 100.0
    moved = truth.copy()
    length = np.linalg.norm(truth[0, 5] - truth[0, 4])
    moved[0, 5] += [1.2 * length, 0, 0]                                  # the left wrist: forearm wrong
    assert pcp(moved, truth) == pytest.approx(90.0)
    T = 20
    walkers = np.stack([np.tile(truth, (T, 1, 1)), np.tile(truth + [3.0, 0, 0], (T, 1, 1))])   # (2, T, 15, 3)
    swapped = np.where(np.arange(T)[:, None, None, None] < T // 2, walkers.transpose(1, 0, 2, 3),
                       walkers[::-1].transpose(1, 0, 2, 3))
    result = SimpleNamespace(frames=np.arange(T), joints=swapped, person_ids=np.array([0, 1]))
    row = score_scene(result, walkers, np.ones((2, T), dtype=bool))
    assert row["num_switches"] == 2 and row["idf1"] == pytest.approx(0.5) and row["false_tracks"] == 0
    clean = score_scene(SimpleNamespace(frames=np.arange(T), joints=walkers.transpose(1, 0, 2, 3),
                                        person_ids=np.array([0, 1])), walkers, np.ones((2, T), dtype=bool))
    assert clean["num_switches"] == 0 and clean["idf1"] == 1.0 and clean["mota"] == 1.0


def test_eval_scenes_passing_half_a_metre_apart(capsys):
    """Two people the prior never saw (CMU 02 and 05; ukf-real's prior refitted without them) walk towards
    each other and pass 0.5 m apart, every person in every file, shuffled, with occlusions and a false
    positive: no switch, no false track, IDF1 1, each within 1.1× of their error tracked alone."""
    assert main(["eval", "scenes", "--scenes", "passing", "--presets", "ukf-real", "--seeds", "1", "--gaps", "0.5",
                 "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    (row,) = result["rows"]
    assert row["trained_without"] == ["02", "05"] and row["tracks"] == 2
    assert row["num_switches"] == 0 and row["false_tracks"] == 0 and row["idf1"] == 1.0
    for person in row["people"]:
        assert person["pcp"] >= 99 and person["ratio_to_alone"] <= 1.1
    assert result["table"]["passing 0.5 m · ukf-real"]["switches"] == 0


def test_bench_scene_runs_and_refuses_bad_sizes(capsys):
    for association in ("joints", "filter"):
        assert main(["bench", "scene", "--people", "2", "--cameras", "4", "--frames", "20",
                     "--association", association]) == 0
        result = json.loads(capsys.readouterr().out)
        assert result["people_tracked"] == 2 and result["command_seconds"] > 0 and result["single_person_seconds"] > 0
        assert result["association"] == association
    assert main(["bench", "scene", "--association", "best"]) == 2
    assert "association must be one of auto, joints, filter, got 'best'" in capsys.readouterr().err
    assert main(["bench", "scene", "--people", "12"]) == 2
    assert "people must be in [1, 9]" in capsys.readouterr().err
    assert main(["eval", "scenes", "--scenes", "dance"]) == 2
    assert "unknown scene 'dance'" in capsys.readouterr().err
