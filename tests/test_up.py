"""The world's up: as an axis or a vector (`--up`), and found from the person where a calibration
gives none (anipose, caliscope, FreeMoCap: the world is camera 1's frame)."""

import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.body.fk import joint_positions
from priortrack.data.calibration import rodrigues
from priortrack.data.load import load_motion
from priortrack.geometry.frames import nearest_axis, to_y_up, up_from_person, up_vector


def test_to_y_up_takes_axes_and_vectors():
    """A proper rotation taking the up direction to e_y; the axes as before (z: x stays, z → y,
    y → −z); a vector given as text, a sequence or an array; nonsense refused by name."""
    rng = np.random.default_rng(0)
    for up in ["x", "y", "z", "-x", "-y", "-z", "0.2,-0.9,0.3", *rng.normal(size=(20, 3))]:
        A = to_y_up(up)
        np.testing.assert_allclose(A @ A.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(A) == pytest.approx(1.0)
        np.testing.assert_allclose(A @ up_vector(up), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(to_y_up("z"), [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-15)
    np.testing.assert_allclose(up_vector("0,0,2"), [0, 0, 1])
    assert nearest_axis([0.1, -0.98, 0.2]) == "-y" and nearest_axis("z") == "z"
    for bad in ["sky", "1,2", "0,0,0", "nan,1,0"]:
        with pytest.raises(PriortrackError, match="up"):
            to_y_up(bad)


@pytest.mark.parametrize("motion", ["cmu:07_10", "walkjog:35_29"])
def test_up_from_a_walking_person_in_a_turned_world(motion):
    """A walk's joints in a world turned at random (as camera 1 sees it): up is found from the ankles
    to the neck within 3° of the truth, also with a fifth of the joints missing."""
    X = joint_positions(load_motion(motion))                                 # (T, 15, 3) eval15, Y-up
    rng = np.random.default_rng(1)
    for _ in range(3):
        R = rodrigues(rng.normal(size=3))
        world = X @ R.T
        world[rng.uniform(size=world.shape[:2]) < 0.2] = np.nan
        up, what, frames = up_from_person(world)
        assert what == "ankles to neck" and frames > 50
        assert np.degrees(np.arccos(up @ R[:, 1])) < 3


def test_too_little_of_the_person_asks_for_up():
    with pytest.raises(PriortrackError, match="give it \\(--up"):
        up_from_person(np.full((30, 15, 3), np.nan))
