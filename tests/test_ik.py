"""Inverse kinematics: 3D joints → a Motion on a scaled template; the detector's joint definitions."""

import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.body.fk import joint_positions
from priortrack.body.ik import fitted_skeleton, inverse_kinematics, measured_distances
from priortrack.data.bundled import cmu_skeleton
from priortrack.data.keypoints import detector_map
from priortrack.data.load import load_motion
from priortrack.tracking.person import steady_start


@pytest.fixture(scope="module")
def walk():
    return joint_positions(load_motion("cmu:07_10").resample(30))[10:16]           # (6, 15, 3) subject 07


def test_a_walk_through_another_subjects_template(walk):
    """Subject 07's joints fitted on subject 35's skeleton scaled to them: a few millimetres."""
    motion = inverse_kinematics(walk, 30.0)
    error = np.linalg.norm(joint_positions(motion) - walk, axis=-1)
    assert error.mean() < 0.008 and error.max() < 0.02
    # Every distance to 1 cm but the head's (mid-shoulders to head top), 1.2 cm: the neck chain that
    # carries it starts at the thorax, not between the shoulders.
    np.testing.assert_allclose(measured_distances(joint_positions(motion)), measured_distances(walk), atol=0.015)


def test_detector_definitions(walk):
    """M X: pelvis = mid-hips, neck = mid-shoulders; a fit to detector-defined targets reproduces them
    through M, and the scaled template's distances in those definitions match the targets'."""
    M = detector_map()
    np.testing.assert_allclose(M.sum(axis=1), 1.0)
    targets = np.einsum("ij,tjk->tik", M, walk)
    np.testing.assert_allclose(targets[:, 0], (walk[:, 9] + walk[:, 12]) / 2)
    np.testing.assert_allclose(targets[:, 1], (walk[:, 3] + walk[:, 6]) / 2)
    skeleton = fitted_skeleton(cmu_skeleton("35"), targets, M)
    motion = inverse_kinematics(targets, 30.0, joint_map=M, skeleton=skeleton)
    fitted = np.einsum("ij,tjk->tik", M, joint_positions(motion))
    assert np.linalg.norm(fitted - targets, axis=-1).mean() < 0.008


def test_bones_no_frame_measures_take_the_measured_bones_scale(walk):
    """A seated person's legs, never seen: the template's leg bones are scaled by the median of the measured
    bones' factors (its proportions) and named; the arms are scaled as with the whole body seen; nothing
    measured is refused."""
    from priortrack.body.ik import unmeasured_measures
    from priortrack.body.layout import eval15_indices
    from priortrack.data.motion import Motion

    template = cmu_skeleton("35")
    upper = walk.copy()
    upper[:, [0, 9, 10, 11, 12, 13, 14]] = np.nan                    # pelvis, hips, knees, ankles: never seen
    assert unmeasured_measures(upper) == ["trunk", "hip_width", "thigh", "shin"] and unmeasured_measures(walk) == []
    whole, seated = fitted_skeleton(template, walk), fitted_skeleton(template, upper)
    index = eval15_indices(template)
    arms, legs = index[[4, 5, 7, 8]], index[[10, 11, 13, 14]]        # elbows, wrists; knees, ankles
    np.testing.assert_allclose(seated.offsets[arms], whole.offsets[arms], rtol=1e-12)
    rest = joint_positions(Motion(template, np.zeros((1, template.num_channels)), 30.0, "rest"))
    factors = measured_distances(upper, own_side=True) / measured_distances(rest, own_side=True)
    assert np.isfinite(factors).sum() == 7                           # head, shoulders ×2, upper arms ×2, forearms ×2
    np.testing.assert_allclose(seated.offsets[legs], np.nanmedian(factors) * template.offsets[legs], rtol=1e-12)
    with pytest.raises(PriortrackError, match="no bone is measured"):
        fitted_skeleton(template, np.full_like(walk, np.nan))


def test_each_side_takes_its_own_measured_length_not_the_templates_asymmetry(walk):
    """Issue 59, item 4: CMU 35's template has an upper arm 3 % longer on one side, and a body scaled by one factor
    per measure (left and right averaged) kept that for everyone (Pose2Sim's demo participant: 277 / 293 mm). Each
    side is now scaled to its own measured length (medians over frames): a right upper arm 10 % longer comes out so,
    the left as measured, and equal sides come out equal."""
    from priortrack.body.ik import limb_sides
    from priortrack.data.motion import Motion

    template = cmu_skeleton("35")
    rest = joint_positions(Motion(template, np.zeros((1, template.num_channels)), 30.0, "rest"))
    sides = measured_distances(rest, own_side=True)
    assert abs(sides[3] / sides[6] - 1) > 0.02                                   # upper arms: the template's differ
    targets = walk.copy()
    targets[:, 7] = targets[:, 6] + 1.1 * (targets[:, 7] - targets[:, 6])        # a right upper arm 10 % longer
    for X in (walk, targets):
        skeleton = fitted_skeleton(template, X)
        fitted = joint_positions(Motion(skeleton, np.zeros((1, template.num_channels)), 30.0, "r"))
        np.testing.assert_allclose(measured_distances(fitted, own_side=True)[[3, 6, 9, 12]],
                                   measured_distances(X, own_side=True)[[3, 6, 9, 12]], atol=1e-4)
        assert limb_sides(skeleton)["upper_arm"] == pytest.approx(measured_distances(X, own_side=True)[[3, 6]], abs=1e-4)
    mirror = walk.copy()
    mirror[:, [6, 7, 8]] = mirror[:, [3, 4, 5]] * [-1, 1, 1]                     # the right arm the left's mirror
    mirror[:, [12, 13, 14]] = mirror[:, [9, 10, 11]] * [-1, 1, 1]
    fitted = joint_positions(Motion(fitted_skeleton(template, mirror), np.zeros((1, template.num_channels)), 30.0, "m"))
    lengths = measured_distances(fitted, own_side=True)
    np.testing.assert_allclose(lengths[[3, 4, 9, 10]], lengths[[6, 7, 12, 13]], atol=1e-4)   # equal sides: equal


def test_sides_differ_only_beyond_their_medians_noise():
    """person_lengths: a walk's joints with 2 cm of noise a joint and frame (its 76 frames' errors independent): a
    right upper arm 3 mm longer than the left is within the noise of the sides' medians (both take their average);
    60 or 20 mm longer, each side takes its own; noise that persists from frame to frame (an AR(1) of ρ = 0.95) widens
    the medians' error, and 20 mm is then within it."""
    from priortrack.body.ik import person_lengths

    X = joint_positions(load_motion("cmu:07_10").resample(30))
    rng = np.random.default_rng(0)
    white = rng.normal(0, 0.02, X.shape)
    persistent = np.empty_like(X)
    persistent[0] = rng.normal(0, 0.02, X.shape[1:])
    for t in range(1, len(X)):                                          # AR(1), ρ = 0.95, σ 2 cm
        persistent[t] = 0.95 * persistent[t - 1] + rng.normal(0, 0.02 * np.sqrt(1 - 0.95 ** 2), X.shape[1:])

    def longer(by: float, noise: np.ndarray) -> np.ndarray:
        """The walk with its right upper arm the left's length plus ``by`` (07's own differ by 14 mm), and noise."""
        Y = X.copy()
        along = (Y[:, 7] - Y[:, 6]) / np.linalg.norm(Y[:, 7] - Y[:, 6], axis=-1, keepdims=True)
        left = np.linalg.norm(Y[:, 4] - Y[:, 3], axis=-1, keepdims=True)
        elbow = Y[:, 6] + (left + by) * along
        Y[:, 8] += elbow - Y[:, 7]                                      # the forearm moves with the elbow
        Y[:, 7] = elbow
        return Y + noise

    for by, noise, split in ((0.003, white, False), (0.06, white, True), (0.02, white, True),
                             (0.02, persistent, False)):
        lengths = person_lengths(longer(by, noise))
        assert (abs(lengths[3] - lengths[6]) > 1e-9) == split, (by, lengths[3], lengths[6])
        if not split:
            assert lengths[3] == measured_distances(longer(by, noise))[3]


def test_missing_joints_follow_their_neighbours(walk):
    holes = walk.copy()
    holes[2, [10, 11]] = np.nan                                   # a leg unseen in one frame
    motion = inverse_kinematics(holes, 30.0)
    assert np.linalg.norm(joint_positions(motion)[2, [10, 11]] - walk[2, [10, 11]], axis=-1).max() < 0.06


def test_the_start_is_steadied(walk):
    window = inverse_kinematics(walk, 30.0)
    start = steady_start(window)
    assert len(start) == 2
    root_t, root_r = window.skeleton.trans_channels[0], window.skeleton.rot_channels[0]
    np.testing.assert_array_equal(start.channels[0, root_r], start.channels[1, root_r])
    slope, intercept = np.polyfit(np.arange(6), window.channels[:, root_t], 1)
    np.testing.assert_allclose(start.channels[:, root_t], intercept + np.outer([0, 1], slope))


def test_bad_targets(walk):
    with pytest.raises(PriortrackError, match=r"expected \(T, 15, 3\)"):
        inverse_kinematics(walk[:, :14], 30.0)
    sparse = walk.copy()
    sparse[1, 3:] = np.nan
    with pytest.raises(PriortrackError, match=r"frames \[1\] have fewer than 6 known joints"):
        inverse_kinematics(sparse, 30.0)
    with pytest.raises(PriortrackError, match="inf"):
        inverse_kinematics(np.full_like(walk, np.inf), 30.0)


def test_a_long_motion_is_fitted_in_chunks(monkeypatch):
    """Past CHUNK frames the fit goes chunk by chunk (its memory flat in the motion's length): each chunk
    is the fit of its frames alone, and every frame lands on its joints as a whole fit does."""
    from priortrack.body import ik

    X = joint_positions(load_motion("cmu:49_18").resample(30)[:50], "eval15")
    monkeypatch.setattr(ik, "CHUNK", 20)
    chunked = ik.inverse_kinematics(X, 30.0)
    assert len(chunked) == 50
    np.testing.assert_array_equal(chunked.channels[20:40], ik.inverse_kinematics(X[20:40], 30.0,
                                                                                   skeleton=chunked.skeleton).channels)
    assert np.linalg.norm(joint_positions(chunked, "eval15") - X, axis=-1).mean() < 0.01


def test_the_jacobian_taken_a_few_frames_at_a_time_is_the_whole_ones(monkeypatch):
    """The normal equations built JACOBIAN_FRAMES frames at a time (bounded memory) are those of the whole
    chunk's Jacobian at once, and so is the fit."""
    from priortrack.body import ik

    X = joint_positions(load_motion("cmu:49_18").resample(30)[:30], "eval15")
    X = X + np.random.default_rng(0).normal(0, 0.01, X.shape)
    whole = ik.inverse_kinematics(X, 30.0).channels
    monkeypatch.setattr(ik._LevenbergMarquardt, "JACOBIAN_FRAMES", 7)
    np.testing.assert_allclose(ik.inverse_kinematics(X, 30.0).channels, whole, rtol=0, atol=1e-10)


def test_the_fit_is_a_minimum_of_its_objective(walk, monkeypatch):
    """Run to its last step, the Levenberg–Marquardt fit of noisy joints ends where torch's autograd finds the
    objective's gradient (module docstring: data, λ pull to rest, μ smoothness) vanishing, to 10⁻⁵ of its size
    at the start; its usual stop (TOLERANCE) is within 0.1 mm of there."""
    import torch

    from priortrack.body import ik
    from priortrack.body.fk import ForwardKinematics
    from priortrack.body.layout import eval15_indices

    X = walk + np.random.default_rng(0).normal(0.0, 0.01, walk.shape)
    stopped = inverse_kinematics(X, 30.0)
    monkeypatch.setattr(ik._LevenbergMarquardt, "TOLERANCE", 0.0)
    motion = inverse_kinematics(X, 30.0)
    assert np.sqrt(((joint_positions(stopped) - joint_positions(motion)) ** 2).mean()) < 1e-4
    skeleton = motion.skeleton
    fk = ForwardKinematics(skeleton, dtype=torch.float64)
    rotation = np.ones(skeleton.num_channels, dtype=bool)
    rotation[skeleton.trans_channels[skeleton.trans_channels >= 0]] = False

    def gradient(channels: np.ndarray) -> np.ndarray:
        theta = torch.tensor(channels, requires_grad=True)
        joints = fk(theta, joints=eval15_indices(skeleton))
        value = (((joints - torch.as_tensor(X)) ** 2).sum() + ik.REGULARISATION * (theta[:, rotation] ** 2).sum()
                 + ik.SMOOTHNESS * ((theta[1:] - theta[:-1]) ** 2).sum())
        value.backward()
        return theta.grad.numpy()

    start = np.zeros_like(motion.channels)
    start[:, skeleton.trans_channels[0]] = motion.channels[:, skeleton.trans_channels[0]]
    assert np.abs(gradient(motion.channels)).max() < 1e-5 * np.abs(gradient(start)).max()


def test_moving_channels_are_those_that_move_a_joint():
    """Every channel outside the set leaves the eval15 joints where they are, from any pose; every one in it
    moves one of them from a generic pose (finite differences)."""
    from priortrack.body.fk import ForwardKinematics
    from priortrack.body.ik import moving_channels
    from priortrack.body.layout import eval15_indices

    skeleton = cmu_skeleton("35")
    index = eval15_indices(skeleton)
    moving = moving_channels(skeleton, index)
    pose = np.random.default_rng(1).uniform(-0.5, 0.5, skeleton.num_channels)
    shifted = pose + 1e-3 * np.eye(skeleton.num_channels)
    fk = ForwardKinematics(skeleton)
    moved = np.abs(fk(shifted, joints=index).numpy() - fk(pose, joints=index).numpy()).max(axis=(1, 2)) > 1e-9
    np.testing.assert_array_equal(np.flatnonzero(moved), moving)


def test_the_pull_to_a_priors_poses():
    """Without a pose spread, λ on every rotation channel toward 0 (none on translations); with one, the root's
    rotations keep that, and every channel below it is pulled to its training mean with weight λ / max(σ, floor)²
    (CMU 35's clavicles, which its walks never move, at the floor); a spread of another layout, or of motions of
    two layouts, is refused."""
    from dataclasses import replace

    from priortrack.body.ik import REGULARISATION, SPREAD_FLOOR, PoseSpread, pull
    from priortrack.data.motion import Motion

    skeleton = cmu_skeleton("35")
    translation = skeleton.trans_channels[skeleton.trans_channels >= 0]
    root = skeleton.rot_channels[0][skeleton.rot_channels[0] >= 0]
    weights, centre = pull(skeleton, None)
    assert (weights[translation] == 0).all() and np.count_nonzero(weights) == skeleton.num_channels - len(translation)
    np.testing.assert_array_equal(weights[weights > 0], REGULARISATION)
    np.testing.assert_array_equal(centre, 0.0)

    walks = [load_motion(f"cmu:35_0{k}") for k in (1,)] + [load_motion("walkjog:35_02")]
    walks = [Motion(skeleton, m.channels, m.fps, m.name) for m in walks]
    pose = PoseSpread.of(walks)
    channels = np.concatenate([m.channels for m in walks])
    weights, centre = pull(skeleton, pose)
    body = np.setdiff1d(np.flatnonzero(pull(skeleton, None)[0]), root)
    np.testing.assert_allclose(weights[body], REGULARISATION / np.maximum(channels.std(axis=0), SPREAD_FLOOR)[body] ** 2)
    np.testing.assert_allclose(centre[body], channels.mean(axis=0)[body])
    np.testing.assert_array_equal(weights[root], REGULARISATION)
    np.testing.assert_array_equal(centre[root], 0.0)
    clavicles = [skeleton.channel_names.index(n) for n in ("lclavicle.ry", "rclavicle.rz")]
    np.testing.assert_allclose(weights[clavicles], REGULARISATION / SPREAD_FLOOR ** 2)
    with pytest.raises(PriortrackError, match="pose spread of 3 channels"):
        pull(skeleton, PoseSpread(np.zeros(3), np.ones(3)))
    renamed = replace(skeleton, channel_names=tuple(f"x{c}" for c in range(skeleton.num_channels)))
    with pytest.raises(PriortrackError, match="the motions have 2 channel layouts; expected one"):
        PoseSpread.of([walks[0], Motion(renamed, walks[1].channels, walks[1].fps, walks[1].name)])


def test_a_persons_own_posture_where_the_priors_motions_have_none(caplog):
    """CMU 35's walks never turn its clavicles. A walker of 35's body with the clavicles turned 12°, −8°, −10°,
    6° (every joint seen) gets those from :func:`own_posture` to 2° (the pull at 0.2 rad shrinks 12° to 10.3°),
    the other channels' spread and means untouched; where no 8 consecutive ticks see every joint, the motions'
    posture stays (the clavicles at 0)."""
    from priortrack.body.ik import PoseSpread, own_posture
    from priortrack.data.motion import Motion

    skeleton = cmu_skeleton("35")
    walks = [Motion(skeleton, m.channels, m.fps, m.name)
             for m in (load_motion("cmu:35_01"), load_motion("walkjog:35_02"))]
    pose = PoseSpread.of(walks)
    names = ("lclavicle.ry", "lclavicle.rz", "rclavicle.ry", "rclavicle.rz")
    clavicles = [skeleton.channel_names.index(n) for n in names]
    channels = load_motion("walkjog:35_29").resample(30).channels[:40].copy()
    channels[:, clavicles] = np.radians([12.0, -8.0, -10.0, 6.0])
    X = joint_positions(Motion(skeleton, channels, 30.0, "other shoulders"))
    with caplog.at_level("INFO", logger="priortrack.body.ik"):
        own = own_posture(X, 30.0, skeleton, pose, source="walk.npz (person 3)")
    assert "walk.npz (person 3): its own posture over 40 ticks: lclavicle.ry +10°" in caplog.text   # whose, in words
    np.testing.assert_allclose(np.degrees(own.mean[clavicles]), [12.0, -8.0, -10.0, 6.0], atol=2.0)
    others = np.setdiff1d(np.arange(skeleton.num_channels), clavicles)
    np.testing.assert_array_equal(own.mean[others], pose.mean[others])
    np.testing.assert_array_equal(own.std, pose.std)
    gappy = X.copy()
    gappy[::7, 5] = np.nan                                          # a wrist unseen every 7th tick
    assert own_posture(gappy, 30.0, skeleton, pose) is pose


def test_one_cameras_depth_from_the_least_foreshortened_length():
    """depth / f from a body's image: neck to mid-ankles where shown; without the legs, each frame's least ratio
    L / ℓ over the upper body's lengths, which foreshortening can only raise (a length turned away from the image
    plane looks shorter); nothing to measure is refused."""
    from priortrack.body.ik import _metres_per_pixel

    rest = np.zeros((15, 3))
    rest[1], rest[2] = [0, 1.5, 0], [0, 1.75, 0]                               # neck, head
    rest[[3, 4, 5]] = [[0.2, 1.45, 0], [0.5, 1.45, 0], [0.75, 1.45, 0]]       # left shoulder, elbow, wrist
    rest[[6, 7, 8]] = [[-0.2, 1.45, 0], [-0.5, 1.45, 0], [-0.75, 1.45, 0]]
    rest[[0, 9, 12]] = [[0, 1.0, 0], [0.1, 1.0, 0], [-0.1, 1.0, 0]]
    rest[[10, 11, 13, 14]] = [[0.1, 0.5, 0], [0.1, 0.05, 0], [-0.1, 0.5, 0], [-0.1, 0.05, 0]]
    scale = 0.004                                                               # depth / f, metres per pixel
    uv = np.repeat((rest[:, :2] / scale)[None], 5, axis=0)                     # (5, 15, 2): facing the camera
    seen = np.ones((5, 15), dtype=bool)
    assert _metres_per_pixel(rest, uv, seen) == pytest.approx(scale, rel=1e-12)
    seen[:, [0, 9, 10, 11, 12, 13, 14]] = False                                 # legs under the desk
    turned = uv.copy()
    turned[:, 3:9, 0] *= 0.7                                                    # the body turned 46° about the vertical
    turned[:, [4, 5]] = turned[:, [3]] + (turned[:, [4, 5]] - turned[:, [3]]) * 0.5     # the left arm pointing away
    assert _metres_per_pixel(rest, turned, seen) == pytest.approx(scale, rel=1e-12)     # the neck to the head
    noisy = uv + np.random.default_rng(0).normal(0, 1.0, uv.shape)
    assert _metres_per_pixel(rest, noisy, seen) == pytest.approx(scale, rel=0.05)
    seen[:] = False
    seen[:, [0, 9]] = True
    with pytest.raises(PriortrackError, match="no depth for the body"):
        _metres_per_pixel(rest, uv, seen)



@pytest.fixture(scope="module")
def one_camera():
    """A held-out walk (07_10) at 30 fps in the Pose2Sim demo's Y-up working frame (8, 15, 3), its 4 cameras there,
    CMU 35's body scaled to 1.75 m and the pose spread of other people's walks: the one-camera start's setting."""
    from priortrack.body.ik import PoseSpread, scaled_to_height
    from priortrack.data.calibration import read_calibration
    from priortrack.experiments.real_format import DEFAULT_CALIBRATION, placed_walk
    from priortrack.geometry.camera import PinholeCamera
    from priortrack.geometry.frames import in_working_frame, to_y_up

    calibration = read_calibration(DEFAULT_CALIBRATION)
    A = to_y_up(calibration.up)
    X = placed_walk("cmu:07_10", calibration.up)[::2][:8] @ A.T
    cameras = [in_working_frame(PinholeCamera.from_calibration(c), A) for c in calibration.cameras]
    spread = PoseSpread.of([load_motion(m).resample(30) for m in ("walkjog:35_29", "cmu:02_01", "cmu:05_01")])
    return X, cameras, scaled_to_height(cmu_skeleton("35"), 1.75), spread


def _relative_mm(J, X):
    """Mean joint error (mm) relative to the mid-hips."""
    def relative(Y):
        return Y - Y[:, [9, 12]].mean(axis=1, keepdims=True)
    return 1000 * np.linalg.norm(relative(J) - relative(X), axis=-1).mean()


def test_one_camera_fit_over_the_depth_branches(one_camera):
    """The walk's exact pixels through each camera: a fit from rest lands on a wrong branch of some limbs (through
    cameras 1 and 4, 263 and 109 mm root-relative when measured); trying every limb's other branches lowers the
    objective there and the error with it (82 and 75 mm), and changes nothing where the first fit was best."""
    from priortrack.body.ik import OneCameraFit

    X, cameras, skeleton, spread = one_camera
    errors = []
    for camera in cameras:
        fit = OneCameraFit(camera.project(X)[0], np.ones(X.shape[:2]), camera, skeleton, pose=spread)
        from_rest = fit.fit()
        branched = fit.over_branches(from_rest)
        assert fit.cost(branched) <= fit.cost(from_rest)
        errors.append([_relative_mm(fit.joints(theta), X) for theta in (from_rest, branched)])
    errors = np.array(errors)                                                    # (4, 2) mm: from rest, branched
    assert (errors[:, 1] <= errors[:, 0] + 1.0).all()
    assert errors[0, 0] > 150 and errors[0, 1] < 100 and errors[3, 0] > 100 and errors[3, 1] < 90


def test_a_robust_one_camera_fit_is_bent_less_by_outliers(one_camera):
    """The walk through camera 4 with four detections thrown 100–140 px off, as a detector's outliers: least
    squares bends the pose towards them (129 against 109 mm from the clean pixels, when measured); reweighted
    by the tracker's Student-t (σ = 10 px, ν = 4) the thrown points lose their pull (116 mm)."""
    from priortrack.body.ik import REWEIGHTS, OneCameraFit

    X, cameras, skeleton, spread = one_camera
    camera = cameras[3]
    uv = camera.project(X)[0]
    clean = OneCameraFit(uv, np.ones(X.shape[:2]), camera, skeleton, pose=spread)
    clean_mm = _relative_mm(clean.joints(clean.fit()), X)
    thrown = uv.copy()
    for t, j, shift in ((1, 5, (100, 40)), (3, 11, (-90, 100)), (4, 7, (120, -60)), (6, 14, (-140, 0))):
        thrown[t, j] += shift
    fit = OneCameraFit(thrown, np.ones(X.shape[:2]), camera, skeleton, pose=spread)
    theta = fit.fit()
    bent_mm = _relative_mm(fit.joints(theta), X)
    for _ in range(REWEIGHTS):
        fit.reweight(theta, 10.0, 4.0)
        theta = fit.fit(theta)
    robust_mm = _relative_mm(fit.joints(theta), X)
    assert float(fit.rho[1, 5]) < 0.2 and float(fit.rho[4, 7]) < 0.2 and float(fit.rho[0].min()) > 0.5
    assert bent_mm > clean_mm + 10 and robust_mm < bent_mm - 8, (clean_mm, bent_mm, robust_mm)


def test_the_start_reweighs_an_outlier_two_cameras_cannot_tell(one_camera):
    """The walk through two of the cameras (2 px noise), four pixels thrown 100–140 px off, each in one camera: two
    cameras' triangulation puts each thrown joint wherever their rays pass, and inverse kinematics bends towards it;
    the tracker's start (person.robust_start) reweighs each point by the Student-t (σ = 5 px, ν = 4) at its
    reprojection and is bent less (measured 11.0 mm clean, 18.9 bent, 13.9 reweighed). On the clean pixels it
    changes nothing that matters."""
    from priortrack.geometry.triangulation import triangulate
    from priortrack.tracking.person import robust_start

    X, cameras, _, spread = one_camera
    views = cameras[:2]
    rng = np.random.default_rng(0)
    uv = np.stack([c.project(X)[0] for c in views]) + rng.normal(0, 2.0, (2,) + X.shape[:2] + (2,))
    thrown = uv.copy()
    for v, t, j, shift in ((0, 1, 5, (100, 40)), (1, 3, 11, (-90, 100)), (0, 4, 7, (120, -60)), (1, 6, 14, (-140, 0))):
        thrown[v, t, j] += shift
    skeleton = fitted_skeleton(cmu_skeleton("35"), X)
    M = np.eye(15)

    def world_mm(motion):
        return 1000 * np.linalg.norm(joint_positions(motion) - X, axis=-1).mean()

    def z(pixels):                                                                  # (T, C, 15, 3), confidence 1
        return np.concatenate([pixels, np.ones(pixels.shape[:-1] + (1,))], -1).transpose(1, 0, 2, 3)

    clean, bent = (triangulate(views, pixels) for pixels in (uv, thrown))
    plain = inverse_kinematics(clean, 30.0, skeleton=skeleton, pose=spread)
    bent_mm = world_mm(inverse_kinematics(bent, 30.0, skeleton=skeleton, pose=spread))
    robust_mm = world_mm(robust_start(bent, z(thrown), views, 30.0, M, skeleton, spread, (5.0, 4.0)))
    assert bent_mm > world_mm(plain) + 5 and robust_mm < bent_mm - 0.5 * (bent_mm - world_mm(plain)), (
        world_mm(plain), bent_mm, robust_mm)
    again = robust_start(clean, z(uv), views, 30.0, M, skeleton, spread, (5.0, 4.0))
    assert world_mm(again) < world_mm(plain) + 1


def test_bad_start_weights_are_named(walk):
    """Per-joint weights of the wrong shape, negative or NaN are refused with the shape they must have."""
    for weights in (np.ones((6, 14)), -np.ones((6, 15)), np.full((6, 15), np.nan)):
        with pytest.raises(PriortrackError, match=r"weights must be finite, non-negative and of shape \(6, 15\)"):
            inverse_kinematics(walk, 30.0, weights=weights)


def test_bad_pixels_for_one_camera_are_named(one_camera):
    """The one-camera fit refuses pixels of the wrong shape and frames with fewer than 6 detected joints."""
    from priortrack.body.ik import OneCameraFit

    X, cameras, skeleton, spread = one_camera
    uv = cameras[0].project(X)[0]
    with pytest.raises(PriortrackError, match=r"pixels \(8, 15, 3\) and weights \(8, 15\); expected"):
        OneCameraFit(np.concatenate([uv, uv[..., :1]], -1), np.ones(X.shape[:2]), cameras[0], skeleton)
    weights = np.ones(X.shape[:2])
    weights[2, 5:] = 0.0
    with pytest.raises(PriortrackError, match=r"frames \[2\] have fewer than 6 detected joints"):
        OneCameraFit(uv, weights, cameras[0], skeleton, pose=spread)
