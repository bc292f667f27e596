"""Inverse kinematics: 3D joints → a Motion on a scaled template; the detector's joint definitions."""

import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.body.fk import joint_positions
from priortrack.body.ik import fitted_skeleton, inverse_kinematics, measured_distances
from priortrack.data.bundled import cmu_skeleton
from priortrack.data.keypoints import detector_map
from priortrack.data.load import load_motion
from priortrack.experiments.real import steady_start


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
