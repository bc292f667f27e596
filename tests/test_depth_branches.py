"""The depth branches of a limb seen by one camera: the same pixels, the same bone lengths, another pose."""

import numpy as np
import pytest

from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.depth_branches import LIMBS, limb_branches, on_ray, reflected


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
