"""The depth branches of a limb seen by one camera: the same pixels, the same bone lengths, another pose."""

import numpy as np
import pytest

from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.depth_branches import (LIMBS, TRUNK_FRACTION, inside_trunk, limb_branches, on_ray, reflected,
                                               trunk_repairs)


@pytest.fixture(scope="module")
def scene():
    """A camera 4 m in front of 15 joints of a person-sized random pose (3 frames)."""
    rng = np.random.default_rng(0)
    camera = PinholeCamera.look_at([0.5, 1.2, 4.0], [0.0, 1.0, 0.0])
    J = np.array([0.0, 1.0, 0.0]) + rng.normal(0, 0.3, (3, 15, 3))
    return camera, J


def _pixels(camera, X):
    return camera.project(X)[0]


def test_a_reflection_keeps_the_pixel_and_the_distance_to_its_anchor(scene):
    camera, J = scene
    centre = camera.center.double().numpy()
    p, a = J[:, 5], J[:, 4]
    q = reflected(p, centre, a)
    np.testing.assert_allclose(_pixels(camera, q), _pixels(camera, p), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(q - a, axis=-1), np.linalg.norm(p - a, axis=-1), atol=1e-12)
    assert (np.linalg.norm(q - p, axis=-1) > 1e-3).all()
    np.testing.assert_allclose(reflected(q, centre, a), p, atol=1e-12)                  # an involution


def test_the_two_points_on_a_ray_are_the_point_and_its_reflection(scene):
    camera, J = scene
    centre = camera.center.double().numpy()
    p, a = J[:, 5], J[:, 4]
    length = np.linalg.norm(p - a, axis=-1)
    both = np.stack([on_ray(p, centre, a, length, sign) for sign in (1.0, -1.0)])       # (2, T, 3)
    for t in range(len(p)):
        found = sorted(both[:, t].tolist())
        np.testing.assert_allclose(found, sorted([p[t].tolist(), reflected(p, centre, a)[t].tolist()]), atol=1e-9)
    farther = np.linalg.norm(both[0] - centre, axis=-1) >= np.linalg.norm(both[1] - centre, axis=-1)
    assert farther.all()
    short = on_ray(p, centre, a, np.full(len(p), 1e-4), 1.0)                           # the ray misses the sphere
    u = (p - centre) / np.linalg.norm(p - centre, axis=-1, keepdims=True)
    np.testing.assert_allclose(((short - a) * u).sum(-1), 0.0, atol=1e-12)              # its closest point


@pytest.mark.parametrize("limb", LIMBS)
def test_every_branch_keeps_the_limbs_pixels_and_bone_lengths(scene, limb):
    camera, J = scene
    root, mid, end = limb
    branches = limb_branches(J, camera.center.double().numpy(), limb)
    assert len(branches) == 3
    for B in branches:
        np.testing.assert_allclose(_pixels(camera, B), _pixels(camera, J), atol=1e-8)
        for a, b in ((root, mid), (mid, end)):
            lengths = np.linalg.norm(J[:, a] - J[:, b], axis=-1)
            reached = np.linalg.norm(B[:, a] - B[:, b], axis=-1)
            hit = np.abs(reached - lengths) < 1e-9
            # the end's ray meets the sphere about the moved mid, or else the end is the ray's closest point
            assert hit.all() or (b == end and (reached[~hit] > lengths[~hit]).all())
        others = [k for k in range(15) if k not in (mid, end)]
        np.testing.assert_array_equal(B[:, others], J[:, others])
        assert (np.linalg.norm(B[:, [mid, end]] - J[:, [mid, end]], axis=-1).max(-1) > 1e-3).all()


def _standing():
    """eval15 joints (15, 3) of an adult standing upright (z up, facing +y), arms hanging: shoulders 0.34 m apart."""
    J = np.zeros((15, 3))
    J[0], J[1], J[2] = [0, 0, 1.0], [0, 0, 1.5], [0, 0, 1.75]
    for side, x in ((0, 0.17), (1, -0.17)):                    # left (+x), right (−x)
        s, e, w = (3, 4, 5) if side == 0 else (6, 7, 8)
        J[s], J[e], J[w] = [x, 0, 1.5], [x * 1.1, 0, 1.22], [x * 1.1, 0.05, 0.97]
        h, k, a = (9, 10, 11) if side == 0 else (12, 13, 14)
        J[h], J[k], J[a] = [x * 0.55, 0, 1.0], [x * 0.55, 0, 0.55], [x * 0.55, 0, 0.1]
    return J


def test_an_elbow_on_the_trunks_axis_is_inside_and_one_at_the_side_or_in_front_is_not():
    J = _standing()
    assert not inside_trunk(J, 4) and not inside_trunk(J, 7)               # arms hanging at the sides
    K = J.copy()
    K[7] = [-0.02, 0.03, 1.3]                                              # on the axis, through the chest
    assert inside_trunk(K, 7) and not inside_trunk(K, 4)
    K[7] = [0.0, 0.15, 1.3]                                                # arms crossed: in front of the chest
    assert not inside_trunk(K, 7)
    K[7] = [0.0, 0.0, 1.8]                                                 # above the shoulders: not the trunk
    assert not inside_trunk(K, 7)
    K[7] = np.nan
    assert not inside_trunk(K, 7)
    width = 0.34
    K[7] = [0.0, TRUNK_FRACTION * width * 0.99, 1.3]                      # the bound, either side
    assert inside_trunk(K, 7)
    K[7] = [0.0, TRUNK_FRACTION * width * 1.01, 1.3]
    assert not inside_trunk(K, 7)


def test_an_elbow_inside_the_trunk_seen_by_one_camera_is_given_its_other_branch():
    """Shelf's case: the right elbow out to the side (akimbo) seen only by a camera at the person's right, looking
    across the body; the branch through the chest has the same pixel and upper-arm length."""
    J = _standing()
    J[7] = [-0.36, 0.0, 1.32]                                              # akimbo: out from the right shoulder
    side = PinholeCamera.look_at([-4.0, 0.3, 1.4], [0.0, 0.0, 1.3])
    centre = side.center.double().numpy()
    inside = J.copy()
    inside[7] = reflected(J[7], centre, J[6])
    assert inside_trunk(inside, 7) and not inside_trunk(J, 7)
    front = PinholeCamera.look_at([0.0, 4.0, 1.4], [0.0, 0.0, 1.3])
    centres = np.stack([centre, front.center.double().numpy()])
    seen = np.zeros((2, 15), dtype=bool)
    seen[0] = True                                                         # the side camera sees every joint
    repairs = dict(trunk_repairs(inside, seen, centres))
    assert sorted(repairs) == [0, 1, 3, 6, 7, 8, 9, 12]                    # the elbow, its wrist, the trunk held
    np.testing.assert_allclose(repairs[7], J[7], atol=1e-9)
    np.testing.assert_allclose(_pixels(side, repairs[7][None]), _pixels(side, inside[7][None]), atol=1e-8)
    for joint in (0, 1, 3, 6, 9, 12):
        np.testing.assert_array_equal(repairs[joint], inside[joint])
    forearm = np.linalg.norm(inside[8] - inside[7])                        # the wrist: on its ray, at the forearm's
    np.testing.assert_allclose(np.linalg.norm(repairs[8] - repairs[7]), forearm, atol=1e-9)       # length
    np.testing.assert_allclose(_pixels(side, repairs[8][None]), _pixels(side, inside[8][None]), atol=1e-6)
    seen[0, 8] = False                                                     # unseen: towards where it was
    unseen = dict(trunk_repairs(inside, seen, centres))[8]
    np.testing.assert_allclose(np.linalg.norm(unseen - repairs[7]), forearm, atol=1e-9)
    towards = (inside[8] - repairs[7]) / np.linalg.norm(inside[8] - repairs[7])
    np.testing.assert_allclose((unseen - repairs[7]) / forearm, towards, atol=1e-9)
    assert trunk_repairs(J, seen, centres) == []                           # outside: nothing to repair
    seen[1, 7] = True                                                      # two views fix the elbow: none either
    assert trunk_repairs(inside, seen, centres) == []
    seen[:, 7] = False                                                     # no view: no ray to reflect along
    assert trunk_repairs(inside, seen, centres) == []
