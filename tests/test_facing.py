"""The trunk's facing seen by one camera: the detector's feet and face against the Necker reversal of the hips' and
shoulders' line (priortrack.geometry.facing), and the unscented filter turned by them."""

import numpy as np
import pytest
import torch

from priortrack import load_walkjog
from priortrack.body.fk import joint_positions
from priortrack.data.keypoints import LAYOUTS
from priortrack.filters.ukf import UnscentedFilter
from priortrack.geometry import so3
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.facing import MARGIN, UP, facing_turns, image_forward, reflection_turns, turned_placements
from priortrack.models.tracking import TrackingModel
from priortrack.observation.likelihood import JointLikelihood
from priortrack.priors import Diffusion
from priortrack.priors.global_motion import GlobalMotion


def lateral(J):
    v = (J[9] - J[12]) + (J[3] - J[6])
    v = v - (v @ UP) * UP
    return v / np.linalg.norm(v)


def turned(J, angle):
    """Joints J (…, 15, 3) turned by ``angle`` about the vertical through their mid-hips."""
    R = so3.exp(torch.tensor(angle * UP)[None])[0].numpy()
    pivot = J[..., [9, 12], :].mean(-2, keepdims=True)
    return pivot + (J - pivot) @ R.T


def reflection_angle(J, centre):
    """The turn that takes J's hips-and-shoulders line to its reflection across the camera's vertical plane."""
    across = lateral(J)
    ray = J[[9, 12]].mean(0) - centre
    ray = ray - (ray @ UP) * UP
    ray /= np.linalg.norm(ray)
    other = across - 2 * (across @ ray) * ray
    return np.arctan2(np.cross(across, other) @ UP, across @ other)


def forward_pixels(camera, J, facing):
    """The image direction (3,) with weight 1 of a step along ``facing`` from J's mid-hips: a detector's cue."""
    mid = J[[9, 12]].mean(0)
    uv = camera.project(torch.from_numpy(np.stack([mid, mid + 0.3 * facing]))[None])[0][0].numpy()
    d = uv[1] - uv[0]
    return np.array([*(d / np.linalg.norm(d)), 1.0])


@pytest.fixture(scope="module")
def walk():
    w = load_walkjog()
    return list(w.walks("train")), w.test[1]


@pytest.fixture(scope="module")
def standing(walk):
    """A walker's frame (15, 3), Y-up metres, and cameras at its side (its hips-and-shoulders line 20° off the ray,
    as Shelf's side-on actors) and in front of it."""
    J = joint_positions(walk[1][:1], "eval15")[0]
    across, mid = lateral(J), J[[9, 12]].mean(0)
    facing = np.cross(across, UP)
    side = np.cos(np.radians(20)) * across + np.sin(np.radians(20)) * facing
    eye_side = mid + 4.0 * side + np.array([0, 1.0, 0])
    eye_front = mid + 4.0 * facing + np.array([0, 0.5, 0])
    return J, PinholeCamera.look_at(eye_side, mid), PinholeCamera.look_at(eye_front, mid)


def test_image_forward_sums_the_feet_and_the_face():
    names = LAYOUTS["body25"]
    k = np.full((2, len(names), 3), np.nan)
    ix = {n: i for i, n in enumerate(names)}
    k[0, ix["left_heel"]] = (100, 200, 0.9)
    k[0, ix["left_big_toe"]] = (130, 200, 0.8)                    # the left foot points +x, weight 0.8
    k[0, ix["left_small_toe"]] = (130, 220, 0.6)                  # the toes' mean (130, 210): (30, 10) → unit
    k[0, ix["right_heel"]] = (100, 300, 0.2)                      # below the threshold: left out
    k[0, ix["right_big_toe"]] = (60, 300, 0.9)
    k[0, ix["left_ear"]] = (50, 50, 0.7)
    k[0, ix["right_ear"]] = (50, 70, 0.5)
    k[0, ix["nose"]] = (50, 90, 0.9)                              # the face points +y from the ears' mean, weight 0.5
    out = image_forward(k, names, 0.3)
    foot = np.array([30.0, 10.0]) / np.hypot(30, 10)
    np.testing.assert_allclose(out[0, :2], 0.6 * foot + 0.5 * np.array([0.0, 1.0]), atol=1e-12)
    assert out[0, 2] == pytest.approx(1.1)
    np.testing.assert_array_equal(out[1], 0.0)                    # nothing seen: no cue
    coco = LAYOUTS["coco17"]                                      # no feet: the face alone
    kc = np.zeros((len(coco), 3))
    kc[coco.index("nose")] = (10, 0, 1.0)
    kc[coco.index("left_ear")] = (0, 0, 1.0)
    np.testing.assert_allclose(image_forward(kc, coco, 0.3), [1.0, 0.0, 1.0])
    assert not image_forward(np.zeros((4, 3)), ("a", "b", "c", "d"), 0.3).any()      # a layout without cues


def test_the_reflected_trunk_keeps_its_pixels_and_is_turned_back_by_the_feet(standing):
    J, side, _ = standing
    centre = side.center.double().numpy()
    angle = reflection_angle(J, centre)
    assert abs(np.degrees(angle)) > 100                           # side-on: the reflection is a large turn
    assert reflection_turns(J, centre) == pytest.approx(angle, abs=1e-12)
    np.testing.assert_allclose(reflection_turns(np.stack([J, J]), centre), [angle, angle], atol=1e-12)
    M = turned(J, angle)
    trunk = [3, 6, 9, 12]
    pixels = [side.project(torch.from_numpy(X[trunk]))[0].numpy() for X in (J, M)]
    assert np.abs(pixels[0] - pixels[1]).max() < 0.1 * np.abs(np.diff(pixels[0], axis=0)).max() + 6.0
    cue = forward_pixels(side, J, np.cross(lateral(J), UP))      # the detector's feet: the true facing
    px = side.project(torch.from_numpy(J))[0].numpy()                             # the detections (15, 2)
    assert facing_turns(J[None], side, cue, px)[0] == 0             # the truth agrees with its feet
    back = facing_turns(M[None], side, cue, px)[0]
    assert back != 0
    np.testing.assert_allclose(lateral(turned(M, back)), lateral(J), atol=1e-9)
    np.testing.assert_array_equal(facing_turns(np.stack([J, M, J]), side, cue, px), [0, back, 0])   # each its own
    assert facing_turns(M[None], side, np.array([*-cue[:2], 1.0]), px)[0] == 0    # feet that agree with M's facing
    assert facing_turns(M[None], side, np.zeros(3), px)[0] == 0                   # no cue
    assert facing_turns(np.full((1, 15, 3), np.nan), side, cue, px)[0] == 0
    height = np.linalg.norm(px[[3, 6]].mean(0) - px[[9, 12]].mean(0))
    assert facing_turns(M[None], side, cue, px + [0.1 * height, 0])[0] != 0       # a trunk that fits its pixels
    assert facing_turns(M[None], side, cue, px + [0.5 * height, 0])[0] == 0       # a filter off its person: not turned
    only_hips = px.copy()
    only_hips[[3, 6]] = np.nan
    assert facing_turns(M[None], side, cue, only_hips)[0] == 0                    # no trunk's height to judge by


def test_a_frontal_camera_sees_no_reversal(standing):
    J, _, front = standing
    px = front.project(torch.from_numpy(J))[0].numpy()
    for cue in (forward_pixels(front, J, np.cross(lateral(J), UP)), np.array([1.0, 0.0, 1.0]), np.array([0, -1.0, 1])):
        angle = facing_turns(J[None], front, cue, px)[0]
        assert abs(angle) < np.radians(45)                        # facing the camera, the two facings nearly one
    assert MARGIN > 0


def test_a_turned_placement_turns_the_world_joints_about_the_pivot(standing):
    J = standing[0]
    body = torch.from_numpy(J - J[0])[None]
    g = np.array([0.3, 0.9, -1.2, 0.2, -0.5, 0.1])
    world = lambda g_: (body[0] @ so3.exp(torch.tensor(g_[3:])[None])[0].T + torch.tensor(g_[:3])).numpy()  # noqa: E731
    pivot = np.array([0.5, 0.0, -1.0])
    X = world(g)
    R = so3.exp(torch.tensor(1.1 * UP)[None])[0].numpy()
    turned_g = turned_placements(torch.tensor(g)[None], torch.tensor([1.1], dtype=torch.float64), torch.tensor(pivot)[None])[0].numpy()
    np.testing.assert_allclose(world(turned_g), pivot + (X - pivot) @ R.T, atol=1e-12)
    many = turned_placements(torch.tensor(np.stack([g, g])), torch.tensor([1.1, -0.4], dtype=torch.float64), torch.tensor(np.stack([pivot] * 2)))
    np.testing.assert_allclose(many[0].numpy(), turned_g, atol=1e-12)                       # each row its own turn
    np.testing.assert_allclose(many[1, 3:].norm().item(), np.linalg.norm(so3.log(torch.from_numpy(
        so3.exp(torch.tensor(-0.4 * UP)[None])[0].numpy() @ so3.exp(torch.tensor(g[3:])[None])[0].numpy())[None])[0]),
        atol=1e-12)


@pytest.fixture(scope="module")
def seen_side_on(walk, standing):
    """A held-out walk's joints X (4, 15, 3), its frame 2's pixels z in the side camera and the feet's cue there, and
    a model on a prior: (X, side camera, z, cue (3,), model(prior, train))."""
    train, motion = walk
    X = joint_positions(motion[:4], "eval15")
    side = standing[1]
    z = side.project(torch.from_numpy(X[2]))[0].numpy()

    def model(prior, fitted_on):
        return TrackingModel(prior, GlobalMotion.fit([prior.space.global_pose(m) for m in fitted_on]),
                             JointLikelihood(side))

    return X, side, z, forward_pixels(side, X[2], np.cross(lateral(X[2]), UP)), model


def reversed_states(states: torch.Tensor, model, X: np.ndarray, side) -> torch.Tensor:
    """States (N, A) with both placements turned to the Necker reversal of frame 1's trunk in the side camera."""
    angle = reflection_angle(X[1], side.center.double().numpy())
    pivot = torch.tensor(X[1][[9, 12]].mean(0))[None].expand(len(states), 3)
    return model.turned(states, torch.full((len(states),), angle, dtype=torch.float64), pivot)


def facing_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Degrees between two bodies' lines across the body."""
    return float(np.degrees(np.arccos(np.clip(lateral(estimate) @ lateral(truth), -1, 1))))


def test_the_unscented_filter_turns_a_reversed_trunk_to_the_facing_the_feet_show(walk, seen_side_on):
    """A walker seen by one side camera, the filter's state turned to the Necker reversal of its trunk (the same
    pixels of hips and shoulders): with the detector's feet showing the true facing, one step turns it back (flag
    "facing-turned"); without them it stays reversed."""
    train, motion = walk
    X, side, z, cue, model_on = seen_side_on
    model = model_on(Diffusion.fit(train[:2], local=True, space="angles"), train[:2])
    out = {}
    for given in (True, False):
        f = UnscentedFilter(model)
        f.initialise(motion)
        f.kf.x = reversed_states(torch.from_numpy(f.kf.x)[None], model, X, side)[0].numpy()
        if given:
            f.forward = np.tile(cue, (4, 1, 1))                   # (ticks, cameras, 3)
        flags = f.step(z).flags
        out[given] = (flags, facing_error(model.observe(f.mean[None])[0].numpy(), X[2]))
    assert "facing-turned" in out[True][0] and "facing-turned" not in out[False][0]
    assert out[True][1] < 20 and out[False][1] > 90, out


def test_a_runs_ticks_read_the_detectors_forward_per_camera(tmp_path):
    """TickObservations.forward: each tick's cue from its detection frame (the same from a file read a block at a
    time), none where the tick has no frame or the camera-tick is left out."""
    from priortrack.data.detections import Detections, open_detections
    from priortrack.observation.ticks import TickObservations

    names = LAYOUTS["body25"]
    rng = np.random.default_rng(0)
    k = np.concatenate([rng.uniform(0, 500, (2, 6, 25, 2)), rng.uniform(0.2, 1.0, (2, 6, 25, 1))], -1)
    detections = Detections("body25", ("a", "b"), np.arange(6), 30.0, "test", keypoints=k)
    index = np.array([0, 2, -1, 5])
    left_out = np.zeros((4, 2), dtype=bool)
    left_out[3, 1] = True
    ticks = TickObservations(detections, index, 0.3, left_out, block_ticks=2)
    out = ticks.forward()
    expected = image_forward(k.astype(np.float32)[:, [0, 2, 5]], names, 0.3).transpose(1, 0, 2)
    np.testing.assert_allclose(out[[0, 1]], expected[:2], atol=1e-9)
    np.testing.assert_allclose(out[3, 0], expected[2, 0], atol=1e-9)
    assert not out[2].any() and not out[3, 1].any() and out[0, :, 2].min() > 0
    path = tmp_path / "d.npz"
    np.savez(path, keypoints=k, keypoint_names=np.array(names), camera_names=np.array(["a", "b"]), fps=30.0)
    on_disk = open_detections(path)
    assert type(on_disk).__name__ == "DetectionFile"                  # keypoints read a block at a time
    np.testing.assert_allclose(TickObservations(on_disk, index, 0.3, left_out, block_ticks=2).forward(), out, atol=1e-6)


def test_the_particle_filter_turns_its_cloud_to_the_facing_the_feet_show(walk, seen_side_on):
    """The particle filter's turn: every particle of a cloud on the reversed trunk turned to its own reflection (its
    translation's Kalman covariance with it) where the feet show the true facing; without them the cloud stays
    reversed."""
    from priortrack.filters.particle import ParticleFilter

    train, motion = walk
    X, side, z, cue, model_on = seen_side_on
    model = model_on(Diffusion.fit(train[:2], local=True, space="angles"), train[:2])
    out = {}
    for given in (True, False):
        f = ParticleFilter(model, particles=200, translation="marginalised", seed=0)
        f.initialise(motion, translation_std=0.01)
        f.states = reversed_states(f.states, model, X, side)
        f.covariance[:, 0, 0] = 4e-4                             # a covariance the turn must carry along
        if given:
            f.forward = np.tile(cue, (4, 1, 1))
        snap = f.step(z)
        out[given] = (snap.flags, facing_error(snap.estimate, X[2]))
    assert "facing-turned" in out[True][0] and "facing-turned" not in out[False][0]
    assert out[True][1] < 20 and out[False][1] > 90, out


def test_the_particle_filters_turn_carries_the_translations_covariance(walk, seen_side_on):
    """Each particle's Kalman covariance of (t_t, t_{t−1}) is turned with it: B C Bᵀ, B = diag(R, R)."""
    from priortrack.filters.particle import ParticleFilter

    train, motion = walk
    X, side, z, cue, model_on = seen_side_on
    model = model_on(Diffusion.fit(train[:2], local=True, space="angles"), train[:2])
    f = ParticleFilter(model, particles=50, translation="marginalised", seed=0)
    f.initialise(motion, translation_std=0.01)
    f.states = reversed_states(f.states, model, X, side)
    f.covariance[:, 0, 0] = 4e-4
    before = f.covariance.clone()
    f.forward = np.tile(cue, (4, 1, 1))
    f.advance()
    joints = f.predicted_joints().numpy()
    flags = []
    f._faced(torch.from_numpy(z), flags)
    assert flags == ["facing-turned"]
    turns = reflection_turns(joints, side.center.double().numpy())
    R = so3.exp(torch.tensor(turns)[:, None] * torch.tensor(UP))
    B = torch.zeros((50, 6, 6), dtype=torch.float64)
    B[:, :3, :3], B[:, 3:, 3:] = R, R
    np.testing.assert_allclose(f.covariance.numpy(), (B @ before @ B.transpose(-1, -2)).numpy(), atol=1e-15)
    assert np.allclose(f.covariance[:, 2, 2].numpy(), 1e-4 + 3e-4 * np.sin(turns) ** 2)      # the x variance turned


def test_the_gaussian_sums_members_turn_with_the_feet_too(walk, seen_side_on):
    """ukf-lie's bank: each member unscented filter reads the bank's forward directions, so a reversed trunk seen
    by one camera is turned in every member (the bank's flags are its heaviest member's)."""
    from priortrack.filters.gaussian_sum import GaussianSumFilter
    from priortrack.priors.lie import LiePrior

    train, motion = walk
    X, side, z, cue, model_on = seen_side_on
    model = model_on(LiePrior.fit(train[:4], seed=0), train[:4])
    out = {}
    for given in (True, False):
        f = GaussianSumFilter(model)
        f.initialise(motion)
        f.hypotheses_[0].x = reversed_states(torch.from_numpy(f.hypotheses_[0].x)[None], model, X, side)[0].numpy()
        if given:
            f.forward = np.tile(cue, (4, 1, 1))
        flags = f.step(z).flags
        out[given] = (flags, facing_error(model.observe(f.mean[None])[0].numpy(), X[2]))
    assert "facing-turned" in out[True][0] and "facing-turned" not in out[False][0]
    assert out[True][1] < 20 and out[False][1] > 90, out


def test_the_particles_that_face_as_the_feet_show_are_kept(walk, seen_side_on):
    """A cloud half on the reversed trunk, half on the true one: the feet turn the first half and leave the second
    as it was (a decision per particle, not by the cloud's mean)."""
    from priortrack.filters.particle import ParticleFilter

    train, motion = walk
    X, side, z, cue, model_on = seen_side_on
    model = model_on(Diffusion.fit(train[:2], local=True, space="angles"), train[:2])
    f = ParticleFilter(model, particles=40, translation="marginalised", seed=0)
    f.initialise(motion, translation_std=0.01)
    f.states[:20] = reversed_states(f.states[:20], model, X, side)
    f.forward = np.tile(cue, (4, 1, 1))
    f.advance()
    drawn = f.states.clone()
    flags = []
    f._faced(torch.from_numpy(z), flags)
    assert flags == ["facing-turned"]
    assert torch.equal(f.states[20:], drawn[20:]) and not torch.equal(f.states[:20], drawn[:20])
    joints = f.predicted_joints().numpy()
    assert max(facing_error(J, X[2]) for J in joints) < 30
