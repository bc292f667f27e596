"""A one-camera person's standing height measured from the floor (priortrack.tracking.floor_height): a standing
template's exact height, held-out walks through a real calibration against their mocap, the floor's level, what is
refused, and the tracker and command line taking it."""

import numpy as np
import pytest
import torch

from priortrack.body.fk import ForwardKinematics
from priortrack.body.ik import ANKLE_HEIGHT, scaled_to_height, stature
from priortrack.body.layout import eval15_indices
from priortrack.cli.main import main
from priortrack.cli.track import body_text
from priortrack.data.bundled import cmu_skeleton
from priortrack.data.calibration import Calibration, read_calibration
from priortrack.data.keypoints import LAYOUTS, detector_map
from priortrack.experiments import real_format as rf
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.frames import in_working_frame, to_y_up
from priortrack.tracking.association import NOMINAL_HEIGHT_M
from priortrack.tracking.floor_height import (MIN_TICKS, height_for_shoulders, measured_height, rest_heights,
                                              shoulder_heights)
from priortrack.tracking.person import TrackConfig, prepared


@pytest.fixture(scope="module")
def template():
    return cmu_skeleton("35"), detector_map()


def standing(skeleton, M, floor=0.0):
    """(15, 3) the skeleton's rest joints (the detector's, through M), its lower ankle ANKLE_HEIGHT above the floor and
    both feet there, under the hips (the template's rest pose has its legs 0.76 m apart)."""
    rest = M @ ForwardKinematics(skeleton, dtype=torch.float64)(np.zeros(skeleton.num_channels))[
        eval15_indices(skeleton)].numpy()
    rest = rest - [0.0, rest[[11, 14], 1].min() - ANKLE_HEIGHT - floor, 0.0]
    for hip, knee, ankle in ((9, 10, 11), (12, 13, 14)):
        rest[[knee, ankle]] = rest[hip] * [1, 0, 1] + [[0, rest[knee, 1], 0], [0, ANKLE_HEIGHT + floor, 0]]
    return rest


def seen_by(camera, positions):
    """(T, 15, 3) pixels and confidence 1 of joint sets (T, 15, 3) through the camera."""
    uv, _ = camera.project(np.asarray(positions))
    return np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], axis=-1)


def around(J, T=20, seed=0):
    """(T, 15, 3) the standing joints J (15, 3) turned about the vertical and moved on the floor, 3–6 m ahead of a
    camera at the origin looking along +z."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(T):
        a = rng.uniform(-np.pi, np.pi)
        R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        centre = J[[9, 12]].mean(0) * [1, 0, 1]
        out.append((J - centre) @ R.T + [rng.uniform(-1, 1), 0, rng.uniform(3, 6)])
    return np.stack(out)


def test_a_standing_body_is_measured_at_its_height_from_a_camera_looking_down(template):
    """The template scaled to 1.58 m, standing anywhere on the floor, turned any way, seen from 2.2 m up looking down:
    its height to within 1 %; the same scene 1 m lower with --floor -1; the floor where it is not: a height no adult's,
    refused, saying why; a camera under the ankles measures nothing."""
    skeleton, M = template
    camera = PinholeCamera.look_at([0.0, 2.2, 0.0], [0.0, 0.9, 4.5], focal_px=900, width=1920, height=1080)
    J = around(standing(scaled_to_height(skeleton, 1.58), M))
    measured, why = measured_height(camera, seen_by(camera, J), skeleton, M)
    assert why == "" and measured.ticks == len(J)
    assert abs(measured.height_m - 1.58) < 0.016, measured
    lower = PinholeCamera.look_at([0.0, 1.2, 0.0], [0.0, -0.1, 4.5], focal_px=900, width=1920, height=1080)
    z = seen_by(lower, J - [0, 1.0, 0])
    assert abs(measured_height(lower, z, skeleton, M, floor=-1.0)[0].height_m - 1.58) < 0.016
    refused, why = measured_height(lower, z, skeleton, M, floor=0.0)
    assert refused is None and "no adult's" in why and "--floor" in why
    under = PinholeCamera.look_at([0.0, 0.05, 0.0], [0.0, 0.9, 4.5], focal_px=900, width=1920, height=1080)
    assert np.isnan(shoulder_heights(under, seen_by(under, J))).all()


def test_what_a_tick_needs(template):
    """A tick without a foot, or without both shoulders, measures nothing; fewer than MIN_TICKS such ticks: no height,
    and why."""
    skeleton, M = template
    camera = PinholeCamera.look_at([0.0, 2.2, 0.0], [0.0, 0.9, 4.5], focal_px=900, width=1920, height=1080)
    z = seen_by(camera, around(standing(skeleton, M), T=MIN_TICKS + 2))
    z[0, [11, 14], 2] = 0                                # no foot
    z[1, 3, :2] = np.nan                                 # one shoulder
    Y = shoulder_heights(camera, z)
    assert np.isnan(Y[:2]).all() and np.isfinite(Y[2:]).all()
    measured, why = measured_height(camera, z[:MIN_TICKS], skeleton, M)
    assert measured is None and f"{MIN_TICKS - 2} ticks" in why


def test_height_for_shoulders_is_the_scaled_templates(template):
    """h of height_for_shoulders puts scaled_to_height's shoulders at the given height (and the template's own at its
    own height)."""
    skeleton, M = template
    Y0, h0 = rest_heights(skeleton, M)
    assert abs(h0 - stature(skeleton)) < 1e-12 and abs(float(height_for_shoulders(skeleton, M, Y0)) - h0) < 1e-12
    for h in (1.45, 1.93):
        Y = rest_heights(scaled_to_height(skeleton, h), M)[0]
        assert abs(float(height_for_shoulders(skeleton, M, Y)) - h) < 1e-9


@pytest.mark.parametrize("motion", ["cmu:39_01", "cmu:05_01", "walkjog:35_29"])
def test_held_out_walks_through_a_real_camera(template, motion):
    """Walks written as a detector would (noise, drops, swaps, outliers) through the Pose2Sim demo's cameras (Z up,
    the floor at 0): each camera's measured height within 2.5 % of the one that puts the template's shoulders at the
    walker's (their median height in the mocap)."""
    skeleton, M = template
    calibration = read_calibration(rf.DEFAULT_CALIBRATION)
    X = rf.placed_walk(motion, "z")
    truth = float(height_for_shoulders(skeleton, M, np.median(X[:, [3, 6], 2].mean(axis=1))))
    for c, calibrated in enumerate(calibration.cameras):
        world = PinholeCamera.from_calibration(calibrated)
        keypoints = rf.detector_keypoints(X, [world], np.random.default_rng(c))[0]
        z = np.zeros((len(X), 15, 3))
        for j, name in rf.BODY25B_OF.items():
            z[:, j] = keypoints[:, LAYOUTS["body25b"].index(name)]
        measured, why = measured_height(in_working_frame(world, to_y_up("z")), z, skeleton, M)
        assert why == "" and abs(measured.height_m / truth - 1) < 0.025, (c, measured, truth)


def test_one_camera_tracking_takes_the_measured_height(tmp_path):
    """prepared's body from one camera: the height measured from the floor where none is given (the walker's, not
    1.7), the given one where given, the nominal one where the floor is not known."""
    calibration = read_calibration(rf.DEFAULT_CALIBRATION)
    one = Calibration(calibration.cameras[3:4], calibration.up, calibration.source)
    X = rf.placed_walk("cmu:39_01", "z")
    world = PinholeCamera.from_calibration(one.cameras[0])
    folder = rf.write_openpose(rf.detector_keypoints(X, [world], np.random.default_rng(0)), tmp_path)
    from priortrack.data.detections import read_detections

    detections = read_detections(folder, keypoints="body25b")
    heights = {}
    for label, config in (("floor", TrackConfig(fps=60)), ("given", TrackConfig(fps=60, height=1.81)),
                          ("nominal", TrackConfig(fps=60, floor=None))):
        run = prepared(detections, one, "ukf-real", config)
        heights[label] = stature(run.skeleton)
        assert run.height_from == label
    assert abs(heights["floor"] - 1.58) < 0.03 and abs(heights["given"] - 1.81) < 1e-6
    assert abs(heights["nominal"] - NOMINAL_HEIGHT_M) < 1e-6
    summary = {"height_m": heights["floor"], "height_from": "floor", "limbs_left_right_m": {"thigh": [0.4, 0.41]}}
    assert body_text(summary).startswith(f"body {heights['floor']:.2f} m tall (measured from the floor)")


def test_the_command_line_says_what_a_floor_is(capsys):
    assert main(["track", "--detections", "x", "--cameras", "y", "--floor", "low"]) == 2
    assert "--floor must be metres along up or none, got 'low'" in capsys.readouterr().err
    assert main(["track", "walkjog:35_29", "--filter", "ukf-real", "--height", "1.8"]) == 2
    assert "--height is for tracking --detections" in capsys.readouterr().err


@pytest.fixture(scope="module")
def larger_walker():
    """A walk 6 % larger than the filters' body, its feet on its own floor, seen by one camera: (model, motion, X
    (T, 15, 3), floor, camera)."""
    from priortrack import load_walkjog
    from priortrack.body.fk import joint_positions
    from priortrack.models.tracking import TrackingModel
    from priortrack.observation.likelihood import JointLikelihood
    from priortrack.priors import Diffusion
    from priortrack.priors.global_motion import GlobalMotion

    w = load_walkjog()
    train, motion = list(w.walks("train")), w.test[1][:40]
    walked = joint_positions(motion, "eval15")
    floor = float(walked[:, [11, 14], 1].min(axis=1).mean()) - ANKLE_HEIGHT          # the walk's own floor
    below = walked[0, [9, 12]].mean(0) * [1, 0, 1] + [0, floor, 0]
    X = below + 1.06 * (walked - below)                                                # larger, its feet on the floor
    mid = X[0, [9, 12]].mean(0)
    camera = PinholeCamera.look_at(mid + [3.0, 1.0, 3.0], mid)
    prior = Diffusion.fit(train[:2], local=True, space="angles")
    model = TrackingModel(prior, GlobalMotion.fit([prior.space.global_pose(m) for m in train[:2]]),
                          JointLikelihood(camera))
    return model, motion, X, floor, camera


def pelvis_error(model, estimate, X) -> float:
    return float(np.linalg.norm(estimate[[9, 12]].mean(0) - X[-1, [9, 12]].mean(0)))


def test_the_unscented_filter_keeps_a_foot_on_the_floor(larger_walker):
    """A walker 6 % larger than the filter's body, seen by one camera: the pixels place the smaller body nearer along
    the camera's rays (its pelvis 0.27 m off after 1.2 s); with the floor known each step observes the lower ankle on
    it (flag "floor-contact") and the body stays where the walker is (within 0.1 m)."""
    from priortrack.filters.ukf import UnscentedFilter

    model, motion, X, floor, camera = larger_walker
    errors = {}
    for known in (True, False):
        f = UnscentedFilter(model)
        f.initialise(motion)
        f.floor = floor if known else None
        flags = []
        for t in range(2, len(X)):
            flags += f.step(camera.project(torch.from_numpy(X[t]))[0].numpy()).flags
        errors[known] = pelvis_error(model, model.observe(f.mean[None])[0].numpy(), X)
        assert ("floor-contact" in flags) == known
    assert errors[True] < 0.1 and errors[False] > 0.2, errors
