"""The 2D joint likelihood: Gaussian and Student-t against scipy, missing entries ignored."""

import numpy as np
import pytest
import torch
from scipy import stats

from priortrack import PriortrackError
from priortrack.geometry.camera import PinholeCamera
from priortrack.observation.likelihood import JointLikelihood


@pytest.fixture
def camera():
    return PinholeCamera.look_at((0.0, 1.0, 6.0), (0.0, 1.0, 0.0), focal_px=1000.0, width=1000, height=1000)


def _scene(seed=0, P=7):
    rng = np.random.default_rng(seed)
    joints = torch.as_tensor(rng.normal(0, 0.4, (P, 15, 3)) + [0, 1, 0])
    z = rng.uniform(300, 700, (15, 2))
    z[[1, 4, 9]] = np.nan
    return joints, z


def test_gaussian_equals_independent_normals(camera):
    joints, z = _scene()
    lik = JointLikelihood(camera, sigma_px=10.0)
    uv, _ = camera.project(joints.numpy())
    seen = ~np.isnan(z[:, 0])
    expected = stats.norm(0, 10.0).logpdf(uv[:, seen] - z[seen]).sum(axis=(1, 2))
    np.testing.assert_allclose(lik.log_likelihood(joints, z).numpy(), expected, rtol=1e-12)


def test_student_t_equals_scipy_multivariate_t(camera):
    joints, z = _scene(1)
    lik = JointLikelihood(camera, sigma_px=8.0, robust_nu=4.0)
    uv, _ = camera.project(joints.numpy())
    seen = ~np.isnan(z[:, 0])
    t = stats.multivariate_t(loc=[0, 0], shape=64.0 * np.eye(2), df=4.0)
    expected = np.array([t.logpdf(uv[p, seen] - z[seen]).sum() for p in range(len(uv))])
    np.testing.assert_allclose(lik.log_likelihood(joints, z).numpy(), expected, rtol=1e-12)


def test_missing_frame_and_behind_camera(camera):
    joints, z = _scene(2)
    lik = JointLikelihood(camera)
    assert torch.equal(lik.log_likelihood(joints, np.full((15, 2), np.nan)), torch.zeros(7, dtype=torch.float64))
    behind = joints.clone()
    behind[0, :, 2] = 20.0                  # every joint of particle 0 behind the camera
    out = lik.log_likelihood(behind, z)
    assert torch.isfinite(out).all() and out[0] < out[1:].min()


def test_bad_input(camera):
    with pytest.raises(PriortrackError, match="sigma_px"):
        JointLikelihood(camera, sigma_px=0)
    with pytest.raises(PriortrackError, match="robust_nu"):
        JointLikelihood(camera, robust_nu=-1)
    with pytest.raises(PriortrackError, match=r"expected \(P, J, 3\) and \(J, 2\)"):
        JointLikelihood(camera).log_likelihood(torch.zeros(3, 15, 3), np.zeros((14, 2)))


def test_one_cameras_likelihood_lists_its_camera_as_a_multi_view_one_does():
    camera = PinholeCamera.look_at([0.0, 1.5, 5.0], [0.0, 1.0, 0.0])
    assert JointLikelihood(camera).cameras == [camera]
