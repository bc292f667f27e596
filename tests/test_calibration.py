"""Camera calibrations read from files other tools wrote (Pose2Sim's Calib.toml, cv2.FileStorage
YAML), and lens distortion in the projection against cv2.projectPoints."""

import json

import cv2
import numpy as np
import pytest
import torch

from priortrack import PriortrackError
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.calibration import read_calibration, rodrigues
from priortrack.geometry.camera import PinholeCamera

POSE2SIM = POSE2SIM_DIR


def test_pose2sims_calib_toml():
    calib = read_calibration(POSE2SIM / "Calib.toml")
    assert calib.names == ("cam_01", "cam_02", "cam_03", "cam_04") and calib.up == "z"
    cam = calib.cameras[0]
    assert cam.size == (1088, 1920)
    np.testing.assert_allclose(cam.K[0], [1681.244873046875, 0.0, 532.97369384375])
    np.testing.assert_allclose(cam.dist, [-0.000721609375, 0.002187234375, 9.5e-06, 1.078125e-05, 0.0])
    np.testing.assert_allclose(cam.R, cv2.Rodrigues(np.array([1.68827548, 1.04832205, -0.41955852]))[0], atol=1e-8)
    np.testing.assert_allclose(cam.t, [0.32110489, 0.95633206, 2.89071305], atol=1e-8)


def test_rodrigues_is_cv2s():
    for rvec in np.random.default_rng(0).normal(size=(20, 3)) * 2:
        np.testing.assert_allclose(rodrigues(rvec), cv2.Rodrigues(rvec)[0], atol=1e-12)


@pytest.mark.parametrize("name", ["cam_01", "cam_02", "cam_03", "cam_04"])
def test_distorted_projection_is_cv2_project_points(name):
    """The real cameras, and the same with strong distortion, against cv2.projectPoints (1e-9 px);
    the Jacobian against central differences."""
    cam = next(c for c in read_calibration(POSE2SIM / "Calib.toml").cameras if c.name == name)
    points = np.random.default_rng(1).uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 1.8], size=(200, 3))  # a person's volume
    for dist in (cam.dist, np.array([-0.3, 0.1, 0.002, -0.001, -0.02])):
        camera = PinholeCamera(cam.K, cam.R, cam.t, *cam.size, dist=dist)
        assert camera.distorted
        uv, in_front = camera.project(points)
        reference, _ = cv2.projectPoints(points, cv2.Rodrigues(cam.R)[0], cam.t, cam.K, dist)
        assert in_front.all()
        np.testing.assert_allclose(uv, reference[:, 0], atol=1e-9)
        torch_uv, J, _ = camera.project_jacobian(torch.as_tensor(points))
        np.testing.assert_allclose(torch_uv.numpy(), uv, atol=1e-9)
        eps, numeric = 1e-6, np.zeros((len(points), 2, 3))
        for k in range(3):
            step = np.zeros(3)
            step[k] = eps
            numeric[:, :, k] = (camera.project(points + step)[0] - camera.project(points - step)[0]) / (2 * eps)
        np.testing.assert_allclose(J.numpy(), numeric, atol=1e-4)


def test_opencv_filestorage_yaml_single_and_multi_camera(tmp_path):
    """Files written by cv2.FileStorage: one camera (K, dist, rvec, tvec, image size) and the
    multi-camera layout (names, K_<name>, dist_<name>, Rot_<name>, T_<name>)."""
    cams = read_calibration(POSE2SIM / "Calib.toml").cameras
    one = tmp_path / "one.yml"
    fs = cv2.FileStorage(str(one), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", cams[0].K)
    fs.write("distortion_coefficients", cams[0].dist[:4].reshape(1, 4))
    fs.write("rvec", cv2.Rodrigues(cams[0].R)[0])
    fs.write("tvec", cams[0].t.reshape(3, 1))
    fs.write("image_width", 1088)
    fs.write("image_height", 1920)
    fs.release()
    read = read_calibration(one).cameras[0]
    np.testing.assert_allclose(read.K, cams[0].K)
    np.testing.assert_allclose(read.R, cams[0].R, atol=1e-12)
    np.testing.assert_allclose(read.t, cams[0].t)
    assert read.size == (1088, 1920) and read_calibration(one).up is None

    multi = tmp_path / "multi.yml"
    fs = cv2.FileStorage(str(multi), cv2.FILE_STORAGE_WRITE)
    fs.startWriteStruct("names", cv2.FileNode_SEQ)
    for c in cams:
        fs.write("", c.name)
    fs.endWriteStruct()
    for c in cams:
        fs.write(f"K_{c.name}", c.K)
        fs.write(f"dist_{c.name}", c.dist.reshape(1, 5))
        fs.write(f"Rot_{c.name}", c.R)
        fs.write(f"T_{c.name}", c.t.reshape(3, 1))
        fs.write(f"size_{c.name}", np.array([[1088.0, 1920.0]]))
    fs.release()
    calib = read_calibration(multi)
    assert calib.names == tuple(c.name for c in cams)
    for a, b in zip(calib.cameras, cams):
        np.testing.assert_allclose(a.R, b.R)
        np.testing.assert_allclose(a.dist, b.dist)


def test_json_cameras_and_intrinsics_only(tmp_path):
    cam = read_calibration(POSE2SIM / "Calib.toml").cameras[1]
    path = tmp_path / "calib.json"
    path.write_text(json.dumps({"up": "z", "cameras": [
        {"name": "side", "K": cam.K.tolist(), "dist": cam.dist[:4].tolist(), "R": cam.R.tolist(),
         "t": (1000 * cam.t).tolist(), "size": [1088, 1920]}]}))
    read = read_calibration(path, translation_unit=0.001)
    assert read.names == ("side",) and read.up == "z"
    np.testing.assert_allclose(read.cameras[0].t, cam.t)
    only = tmp_path / "intrinsics.json"
    only.write_text(json.dumps({"K": cam.K.tolist(), "size": [1088, 1920]}))
    read = read_calibration(only)
    assert read.up == "-y" and np.array_equal(read.cameras[0].R, np.eye(3)) and not read.cameras[0].t.any()


@pytest.mark.parametrize("text, suffix, message", [
    ('[cam_01]\nmatrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nsize = [10, 10]\nrotation = [0, 0, 0]\n', ".toml",
     "camera 'cam_01': field 'translation' is missing"),
    ('[c]\nmatrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nfisheye = true\n', ".toml", "fisheye"),
    ('[c]\nmatrix = [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]\nsize = [10, 10]\nrotation = [0, 0, 0]\ntranslation = [0, 0, 0]\n',
     ".toml", "K is not"),
    ('[c]\nmatrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nsize = [10, 10]\nrotation = [0, 0, nan]\n'
     'translation = [0, 0, 0]\n', ".toml", "rvec contains NaN"),
    ('{"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "size": [4, 4]}', ".json",
     "give both a rotation"),
    ('{"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}', ".json", "image size"),
    ('[1, 2]', ".json", "expected a mapping"),
    ('{"K": [1, 2, 3]', ".json", "not valid JSON"),
    ('x: [', ".yml", "not valid YAML"),
    ('cameras', ".txt", "unknown calibration format"),
    ('[metadata]\nadjusted = false\n', ".toml", "no camera found"),
])
def test_bad_calibrations_name_the_file_camera_and_field(tmp_path, text, suffix, message):
    path = tmp_path / f"calib{suffix}"
    path.write_text(text)
    with pytest.raises(PriortrackError, match=message):
        read_calibration(path)
    with pytest.raises(PriortrackError, match="does not exist"):
        read_calibration(tmp_path / "none.toml")
