"""Tests for priortrack.geometry.camera.PinholeCamera."""

import json
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@pytest.fixture
def cam():
    K = np.array([[800.0, 0.0, 320.0], [0.0, 900.0, 240.0], [0.0, 0.0, 1.0]])
    R = rot_y(0.3)
    t = np.array([0.1, -0.2, 4.0])
    return PinholeCamera(K, R, t, width=640, height=480)


def test_project_matches_hand_computation(cam):
    X = np.array([0.5, 1.0, -0.7])
    c, s = math.cos(0.3), math.sin(0.3)
    # X_c = R X + t, R = rot_y(0.3)
    xc = c * 0.5 + s * (-0.7) + 0.1
    yc = 1.0 - 0.2
    zc = -s * 0.5 + c * (-0.7) + 4.0
    u = 800.0 * xc / zc + 320.0
    v = 900.0 * yc / zc + 240.0
    uv, front = cam.project(X[None])
    assert front.tolist() == [True]
    np.testing.assert_allclose(uv[0], [u, v], rtol=0, atol=1e-9)


def test_project_hand_numbers():
    # R: a 90 degree rotation about world y (camera x = world z, camera z = -world x), t in metres
    K = [[800.0, 0.0, 320.0], [0.0, 900.0, 240.0], [0.0, 0.0, 1.0]]
    R = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]
    t = [0.1, -0.2, 4.0]
    cam = PinholeCamera(K, R, t, 640, 480)
    # X = (0.5, 1.0, -0.7):  X_c = R X + t = (-0.7 + 0.1, 1.0 - 0.2, -0.5 + 4.0) = (-0.6, 0.8, 3.5)
    # u = 800 * -0.6 / 3.5 + 320 = 182.857142...,  v = 900 * 0.8 / 3.5 + 240 = 445.714285...
    uv, front = cam.project(np.array([[0.5, 1.0, -0.7]]))
    assert bool(front[0])
    np.testing.assert_allclose(uv[0], [182.857142857142857, 445.714285714285714], rtol=0, atol=1e-9)
    uv_t, front_t = cam.project(torch.tensor([[0.5, 1.0, -0.7]], dtype=torch.float64))
    np.testing.assert_allclose(uv_t.numpy()[0], [182.857142857142857, 445.714285714285714], rtol=0, atol=1e-9)


def test_project_skew_and_center(cam):
    K = np.array([[800.0, 5.0, 320.0], [0.0, 900.0, 240.0], [0.0, 0.0, 1.0]])
    c2 = PinholeCamera(K, cam.R, cam.t, 640, 480)
    X = np.array([[0.2, 0.3, 0.4]])
    xc = cam.R.numpy() @ X[0] + cam.t.numpy()
    uv, _ = c2.project(X)
    np.testing.assert_allclose(uv[0], [800 * xc[0] / xc[2] + 5 * xc[1] / xc[2] + 320, 900 * xc[1] / xc[2] + 240])
    # the centre has X_c = 0
    C = cam.center.numpy()
    np.testing.assert_allclose(cam.R.numpy() @ C + cam.t.numpy(), 0.0, atol=1e-12)


def test_look_at_target_up_and_behind():
    eye, target = np.array([1.0, 1.5, 6.0]), np.array([0.5, 1.0, 0.0])
    cam = PinholeCamera.look_at(eye, target, focal_px=1000.0, width=1000, height=1000)
    uv, front = cam.project(np.stack([target, target + [0, 0.5, 0], 2 * eye - target]))
    np.testing.assert_allclose(uv[0], [500.0, 500.0], atol=1e-9)  # principal point
    assert uv[1, 1] < uv[0, 1] - 50  # world up -> image up (smaller v)
    assert front.tolist() == [True, True, False]
    assert np.isnan(uv[2]).all()
    np.testing.assert_allclose(cam.center.numpy(), eye, atol=1e-12)
    assert cam.K[0, 2].item() == 500.0 and cam.K[1, 2].item() == 500.0


def test_look_at_side_view_axes():
    # camera at +z looking toward -z: world +x is image right, world +y image up
    cam = PinholeCamera.look_at((0.0, 1.0, 5.0), (0.0, 1.0, 0.0))
    uv, _ = cam.project(np.array([[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 2.0, 0.0]]))
    assert uv[1, 0] == pytest.approx(700.0)  # 1000 * 1 / 5 + 500
    assert uv[2, 1] == pytest.approx(300.0)
    np.testing.assert_allclose(cam.R.numpy(), np.diag([1.0, -1.0, -1.0]), atol=1e-15)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(-10, 10), min_size=3, max_size=3),
    st.lists(st.floats(-10, 10), min_size=3, max_size=3),
)
def test_look_at_target_projects_to_principal_point(eye, target):
    eye, target = np.array(eye), np.array(target)
    d = target - eye
    if np.linalg.norm(d) < 1e-2 or np.linalg.norm(np.cross(d / np.linalg.norm(d), [0, 1, 0])) < 1e-3:
        return
    cam = PinholeCamera.look_at(eye, target)
    uv, front = cam.project(target[None])
    assert front[0]
    np.testing.assert_allclose(uv[0], [500.0, 500.0], atol=1e-6)
    up_uv, _ = cam.project((target + [0, 1e-3, 0])[None])
    assert up_uv[0, 1] < uv[0, 1]


def test_nan_and_plane_points():
    cam = PinholeCamera.look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0))
    pts = np.array([[np.nan, 0.0, 0.0], [1.0, 0.0, 5.0], [0.0, 0.0, 5.0 - 2e-6]])
    uv, front = cam.project(pts)
    assert front.tolist() == [False, False, True]
    assert np.isnan(uv[:2]).all() and np.isfinite(uv[2]).all()


def test_numpy_and_torch_types_and_shapes():
    cam = PinholeCamera.look_at((0.0, 1.5, 5.0), (0.0, 1.0, 0.0))
    pts64 = np.random.default_rng(0).normal(size=(4, 7, 15, 3))
    uv, front = cam.project(pts64)
    assert isinstance(uv, np.ndarray) and uv.dtype == np.float64 and uv.shape == (4, 7, 15, 2)
    assert isinstance(front, np.ndarray) and front.dtype == bool and front.shape == (4, 7, 15)

    pts = torch.from_numpy(np.random.default_rng(1).normal(size=(10000, 15, 3))).float()
    uv_t, front_t = cam.project(pts)
    assert isinstance(uv_t, torch.Tensor) and uv_t.dtype == torch.float32 and uv_t.shape == (10000, 15, 2)
    assert front_t.dtype == torch.bool and front_t.shape == (10000, 15)
    assert uv_t.device == pts.device
    uv_ref, front_ref = cam.project(pts.double().numpy())
    np.testing.assert_array_equal(front_t.numpy(), front_ref)
    np.testing.assert_allclose(uv_t.numpy(), uv_ref, rtol=1e-4, atol=1e-2)

    # float32 numpy stays float32; lists work
    uv32, _ = cam.project(pts64.astype(np.float32))
    assert uv32.dtype == np.float32
    uv_list, _ = cam.project([[0.0, 1.0, 0.0]])
    np.testing.assert_allclose(uv_list, [[500.0, 500.0]])


def test_torch_projection_differentiable():
    cam = PinholeCamera.look_at((0.0, 1.5, 5.0), (0.0, 1.0, 0.0))
    pts = torch.tensor([[0.0, 1.0, 0.0], [0.0, 1.0, 7.0]], dtype=torch.float64, requires_grad=True)
    uv, front = cam.project(pts)
    uv[front].sum().backward()
    assert torch.isfinite(pts.grad).all()
    assert torch.equal(pts.grad[1], torch.zeros(3, dtype=torch.float64))


def test_to_device_dtype():
    cam = PinholeCamera.look_at((0.0, 1.5, 5.0), (0.0, 1.0, 0.0))
    c32 = cam.to(dtype=torch.float32)
    assert c32.K.dtype == torch.float32 and cam.K.dtype == torch.float64
    assert c32.R.dtype == torch.float32 and c32.t.dtype == torch.float32


def test_dict_round_trip():
    cam = PinholeCamera.look_at((0.3, 1.7, 4.2), (0.1, 0.9, -0.2), focal_px=1234.5, width=640, height=480)
    d = json.loads(json.dumps(cam.to_dict()))
    back = PinholeCamera.from_dict(d)
    assert back == cam
    assert torch.equal(back.R, cam.R) and torch.equal(back.t, cam.t) and torch.equal(back.K, cam.K)
    assert (back.width, back.height) == (640, 480)
    with pytest.raises(PriortrackError, match="'t'"):
        PinholeCamera.from_dict({k: v for k, v in d.items() if k != "t"})


def test_invalid_inputs():
    K = np.array([[1000.0, 0, 500], [0, 1000, 500], [0, 0, 1]])
    with pytest.raises(PriortrackError, match="R"):
        PinholeCamera(K, np.diag([1.0, 1.0, 1.001]), np.zeros(3))
    with pytest.raises(PriortrackError, match="R"):
        PinholeCamera(K, np.diag([1.0, 1.0, -1.0]), np.zeros(3))  # reflection, det -1
    with pytest.raises(PriortrackError, match=r"K.*\(3, 3\)"):
        PinholeCamera(np.eye(4), np.eye(3), np.zeros(3))
    with pytest.raises(PriortrackError, match="t"):
        PinholeCamera(K, np.eye(3), np.zeros(4))
    with pytest.raises(PriortrackError, match="width"):
        PinholeCamera(K, np.eye(3), np.zeros(3), width=0)
    with pytest.raises(PriortrackError, match="K"):
        PinholeCamera(K * 2, np.eye(3), np.zeros(3))  # K[2] != (0, 0, 1)
    cam = PinholeCamera(K, np.eye(3), np.zeros(3))
    with pytest.raises(PriortrackError, match=r"points.*\(\.\.\., J, 3\)"):
        cam.project(np.zeros((5, 2)))
    with pytest.raises(PriortrackError, match="up"):
        PinholeCamera.look_at((0, 5, 0), (0, 0, 0))
    with pytest.raises(PriortrackError, match="eye"):
        PinholeCamera.look_at((1, 1, 1), (1, 1, 1))
