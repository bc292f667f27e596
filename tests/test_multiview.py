"""The multi-camera observation model: its log-likelihood against per-camera sums, its linearisation
against autograd and against the one-camera model, and the translation's Kalman update through it."""

import numpy as np
import pytest
import torch

from priortrack import PriortrackError
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.calibration import read_calibration
from priortrack.filters.marginal_translation import kalman_update
from priortrack.geometry.camera import PinholeCamera
from priortrack.observation.likelihood import JointLikelihood
from priortrack.observation.multiview import MultiViewLikelihood

POSE2SIM = POSE2SIM_DIR


@pytest.fixture(scope="module")
def scene():
    cameras = [PinholeCamera.from_calibration(c) for c in read_calibration(POSE2SIM / "Calib.toml").cameras]
    rng = np.random.default_rng(0)
    truth = rng.uniform([-0.3, -0.3, 0.1], [0.3, 0.3, 1.7], size=(15, 3))
    z = np.zeros((4, 15, 3))
    for c, camera in enumerate(cameras):
        z[c, :, :2] = camera.project(truth)[0] + rng.normal(0, 4, size=(15, 2))
        z[c, :, 2] = rng.uniform(0.3, 1.0, size=15)
    z[1, 3, :2] = np.nan                                   # missing, by pixels
    z[2, 5, 2] = 0.0                                       # missing, by confidence
    z[3, 7, :2] += 300                                     # an outlier
    joints = torch.as_tensor(truth)[None] + torch.as_tensor(rng.normal(0, 0.03, size=(6, 15, 3)))
    return cameras, torch.as_tensor(z), joints


@pytest.mark.parametrize("nu", [4.0, None])
def test_log_likelihood_is_the_confidence_weighted_sum_over_cameras(scene, nu):
    cameras, z, joints = scene
    model = MultiViewLikelihood(cameras, sigma_px=5.0, robust_nu=nu)
    expected = torch.zeros(len(joints), dtype=torch.float64)
    for c, camera in enumerate(cameras):
        single = JointLikelihood(camera, 5.0, nu)
        for j in range(15):
            u, w = z[c, j, :2], z[c, j, 2]
            if torch.isfinite(u).all() and w > 0:
                d = camera.project(joints[:, j:j + 1])[0][:, 0] - u
                expected += w * single.per_joint((d * d).sum(-1))
    torch.testing.assert_close(model.log_likelihood(joints, z), expected, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("nu", [4.0, None])
def test_b_is_the_gradient_in_the_translation(scene, nu):
    """b = ∇_t log p at the linearisation point (IRLS weights are the Student-t's exact gradient
    weights), A is symmetric positive definite."""
    cameras, z, joints = scene
    model = MultiViewLikelihood(cameras, sigma_px=5.0, robust_nu=nu)
    A, b, log_p = model.linearised(joints, z)
    shift = torch.zeros(len(joints), 1, 3, dtype=torch.float64, requires_grad=True)
    value = model.log_likelihood(joints + shift, z)
    (gradient,) = torch.autograd.grad(value.sum(), shift)
    torch.testing.assert_close(b, gradient[:, 0], rtol=1e-9, atol=1e-6)
    torch.testing.assert_close(log_p, value.detach())
    torch.testing.assert_close(A, A.transpose(1, 2))
    assert (torch.linalg.eigvalsh(A) > 0).all()


def test_one_camera_gaussian_with_unit_confidences_is_the_joint_likelihood(scene):
    cameras, z, joints = scene
    camera = PinholeCamera(cameras[0].K, cameras[0].R, cameras[0].t, 1088, 1920)      # no distortion: the kernel path
    pixels = z[0, :, :2].clone()
    pixels[4] = float("nan")
    ones = torch.cat([pixels, torch.where(torch.isfinite(pixels[:, :1]), 1.0, 0.0)], -1)[None]
    single, multi = JointLikelihood(camera, 5.0), MultiViewLikelihood([camera], 5.0, robust_nu=None)
    torch.testing.assert_close(multi.log_likelihood(joints, ones), single.log_likelihood(joints, pixels))
    C = torch.eye(6, dtype=torch.float64).expand(len(joints), 6, 6) * 0.01
    args = (C, torch.full((3,), 0.003, dtype=torch.float64), torch.ones(3, dtype=torch.float64))
    for got, want in zip(kalman_update(joints, *args[:1], *args[1:], ones, multi),
                         kalman_update(joints, *args[:1], *args[1:], pixels, single)):
        torch.testing.assert_close(got, want, rtol=1e-9, atol=1e-9)


def test_bad_shapes_and_arguments(scene):
    cameras, z, joints = scene
    model = MultiViewLikelihood(cameras)
    with pytest.raises(PriortrackError, match=r"expected \(P, 15, 3\) and \(4, 15, 3\)"):
        model.log_likelihood(joints, z[:2])
    with pytest.raises(PriortrackError, match="at least one camera"):
        MultiViewLikelihood([])
