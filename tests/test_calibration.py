"""Camera calibrations read from files other tools wrote (Pose2Sim, anipose, caliscope, mmhuman3d,
cv2.FileStorage YAML: ``tests/data/formats/``, whose README and SOURCE.md files say where each comes
from), and lens distortion in the projection against cv2.projectPoints."""

import csv
import json
import logging
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from priortrack import PriortrackError
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.calibration import read_calibration, rodrigues
from priortrack.geometry.camera import PinholeCamera

POSE2SIM = POSE2SIM_DIR
FORMATS = Path(__file__).parent / "data" / "formats"
#: file → (format recognised, the translation unit its SOURCE.md gives, up).
TOOL_FILES = {
    "anipose/aniposelib_7cam-allen-mouse_calibration.toml": ("anipose/FreeMoCap calibration.toml", 1e-3, None),
    "anipose/aniposelib_mouse-outdoor_calibration_right_4_10_2026_adjusted.toml":
        ("anipose/FreeMoCap calibration.toml", 1.0, None),
    "anipose/trackstudio_calibration.toml": ("anipose/FreeMoCap calibration.toml", 1e-3, None),
    "caliscope/4_cam_recording_camera_array.toml": ("caliscope camera_array.toml", 1.0, None),
    "caliscope/post_optimization_camera_array.toml": ("caliscope camera_array.toml", 1.0, None),
    "caliscope/post_optimization_config.toml": ("caliscope config.toml", 1.0, None),
    "mmhuman3d/calibration_chessboard_05_28_18_05_19.json": ("mmhuman3d chessboard .json", 1.0, "floor"),
    "pose2sim/Calib_scene.toml": ("Pose2Sim Calib.toml", 1.0, "z"),
}


def _file_cameras(path: Path) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Each camera's (K, dist, rvec, tvec) for cv2.projectPoints, in the file's own units, read here
    from the file by its tool's documented conventions (SOURCE.md), independently of priortrack."""
    if path.suffix == ".json":                              # mmhuman3d: flat K and R, camera → world
        out = []
        for c in json.loads(path.read_text()).values():
            rvec = cv2.Rodrigues(np.reshape(c["R"], (3, 3)).T)[0]      # cv2 takes the nearest rotation
            out.append((np.reshape(c["K"], (3, 3)), np.asarray(c["distCoeff"], float), rvec,
                        -cv2.Rodrigues(rvec)[0] @ np.asarray(c["T"], float)))
        return out
    table = tomllib.loads(path.read_text())
    tables = table["cameras"].values() if "cameras" in table else [v for v in table.values()
                                                                   if isinstance(v, dict) and "matrix" in v]
    out = []
    for c in tables:
        rotation = np.asarray(c["rotation"], float)
        rvec = rotation if rotation.size == 3 else cv2.Rodrigues(rotation)[0]
        out.append((np.asarray(c["matrix"], float), np.asarray(c["distortions"], float), rvec.reshape(3),
                    np.asarray(c["translation"], float)))
    return out


@pytest.mark.parametrize("name", sorted(TOOL_FILES))
def test_every_tool_file_projects_like_cv2_with_its_own_conventions(name, caplog):
    """Each file another tool wrote: recognised (named in the log), its unit right, and every camera
    projecting like cv2.projectPoints with the file's own parameters and conventions (1e-6 px)."""
    fmt, unit, up = TOOL_FILES[name]
    with caplog.at_level(logging.INFO, logger="priortrack"):
        calib = read_calibration(FORMATS / name)
    assert calib.format == fmt and fmt in caplog.text
    assert calib.units == {1.0: "m", 1e-3: "mm"}[unit]
    raw = _file_cameras(FORMATS / name)
    assert len(raw) == len(calib.cameras)
    rng = np.random.default_rng(0)
    for cam, (K, dist, rvec, tvec) in zip(calib.cameras, raw):
        w, h = cam.size
        depth = rng.uniform(0.5, 3.0, size=(300, 1))       # metres in front of the camera, inside the image's middle
        xy = (rng.uniform([0.2 * w, 0.2 * h], [0.8 * w, 0.8 * h], size=(300, 2)) - cam.K[:2, 2]) / np.diag(cam.K)[:2]
        X_c = np.column_stack([xy * depth, depth])
        X = (X_c - cam.t) @ cam.R                           # world metres (ours), then the file's units for cv2
        reference = cv2.projectPoints(X / unit, rvec, tvec, K, dist)[0][:, 0]
        uv, in_front = PinholeCamera.from_calibration(cam).project(X)
        assert in_front.all()
        np.testing.assert_allclose(uv, reference, atol=1e-6, err_msg=f"{name} camera {cam.name}")
    if up == "floor":                                       # measured: see test_mmhuman3d_up_is_the_floor_normal
        assert isinstance(calib.up, np.ndarray)
    else:
        assert calib.up == up


@pytest.mark.parametrize("name", ["caliscope/post_optimization_camera_array.toml",
                                  "caliscope/post_optimization_config.toml"])
def test_caliscope_charuco_points_project_onto_its_own_2d(name):
    """caliscope's triangulated board corners (xyz_CHARUCO.csv), projected with our reading of its
    calibration, land on its detected corners (xy_CHARUCO.csv) as closely as its own (1.15 px median)."""
    calib = read_calibration(FORMATS / name)
    with open(FORMATS / "caliscope/post_optimization_xyz_CHARUCO.csv", newline="") as f:
        xyz = {(r["sync_index"], r["keypoint_id"]): [float(r[k]) for k in ("x_coord", "y_coord", "z_coord")]
               for r in csv.DictReader(f)}
    errors = []
    with open(FORMATS / "caliscope/post_optimization_xy_CHARUCO.csv", newline="") as f:
        for r in csv.DictReader(f):
            X = xyz.get((r["sync_index"], r["keypoint_id"]))
            if X is None:
                continue
            camera = PinholeCamera.from_calibration(calib.cameras[calib.names.index(f"cam_{r['cam_id']}")])
            uv = camera.project(np.array([X]))[0][0]
            errors.append(np.hypot(uv[0] - float(r["img_loc_x"]), uv[1] - float(r["img_loc_y"])))
    assert len(errors) > 2000
    assert np.median(errors) < 1.5 and np.percentile(errors, 90) < 3.0


def test_mmhuman3d_up_is_the_floor_normal():
    """The floor the six depth cameras measured, moved into the world: its points lie on one plane
    across the cameras (within 3 cm along the up found), below every camera."""
    path = FORMATS / "mmhuman3d/calibration_chessboard_05_28_18_05_19.json"
    calib = read_calibration(path)
    data = json.loads(path.read_text())
    floor = np.array([np.reshape(c["R"], (3, 3)) @ c["floor"]["center"] + c["T"] for c in data.values()
                      if c["floor"]["pnum"]])
    heights = floor @ calib.up
    assert len(floor) == 6 and np.ptp(heights) < 0.03
    assert (calib.centres @ calib.up > heights.max() + 0.5).all()


def test_near_rotations_are_projected_and_far_ones_refused(tmp_path, caplog):
    """A rotation stored to 6 digits (off SO(3) by ~1e-6) is the nearest rotation, logged; one off by
    more than 1e-3, or a reflection, is refused naming the file and camera."""
    cam = read_calibration(POSE2SIM / "Calib.toml").cameras[0]
    def write(R, name="lab"):
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps({"up": "z", "cameras": [{"name": "c1", "K": cam.K.tolist(), "R": R.tolist(),
                                                            "t": cam.t.tolist(), "size": list(cam.size)}]}))
        return path
    rounded = np.round(cam.R, 6)
    assert np.abs(rounded @ rounded.T - np.eye(3)).max() > 1e-7
    with caplog.at_level(logging.INFO, logger="priortrack"):
        read = read_calibration(write(rounded)).cameras[0]
    assert "projected onto the nearest rotation" in caplog.text
    np.testing.assert_allclose(read.R @ read.R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(read.R, cv2.Rodrigues(cv2.Rodrigues(rounded)[0])[0], atol=1e-12)
    with pytest.raises(PriortrackError, match=r"far\.json: camera 'c1': the rotation matrix is not a rotation "
                                              r"\(max\|R Rᵀ − I\| = 0\.00"):
        read_calibration(write(cam.R + 2e-3, "far"))
    with pytest.raises(PriortrackError, match=r"camera 'c1': the rotation matrix has determinant -1"):
        read_calibration(write(-cam.R))


def test_units_stated_inferred_and_forced(tmp_path, caplog):
    """A millimetre file is never read as metres: inferred from the layout (logged), stated in the file,
    or forced; a Pose2Sim-layout file in millimetres is read as millimetres with a warning."""
    calib = read_calibration(POSE2SIM / "Calib.toml")
    toml_mm = tmp_path / "Calib_mm.toml"
    text = (POSE2SIM / "Calib.toml").read_text()
    for c in calib.cameras:
        line = next(line for line in text.splitlines() if line.startswith("translation") and
                    np.allclose(np.array(line.split("[")[1].rstrip("]").split(","), float), c.t))
        text = text.replace(line, "translation = [ " + ", ".join(repr(1000 * float(v)) for v in c.t) + "]")
    toml_mm.write_text(text)
    with caplog.at_level(logging.WARNING, logger="priortrack"):
        read = read_calibration(toml_mm)
    assert read.units == "mm" and "read as millimetres" in caplog.text
    np.testing.assert_allclose([c.t for c in read.cameras], [c.t for c in calib.cameras], atol=1e-12)
    assert read_calibration(toml_mm, units="m").units == "m"
    np.testing.assert_allclose(read_calibration(toml_mm, units="m").cameras[0].t, 1000 * calib.cameras[0].t)
    stated = tmp_path / "stated.json"
    stated.write_text(json.dumps({"units": "mm", "cameras": [
        {"name": "a", "K": c.K.tolist(), "R": c.R.tolist(), "t": (1000 * c.t).tolist(), "size": list(c.size)}
        for c in calib.cameras[:1]]}))
    np.testing.assert_allclose(read_calibration(stated).cameras[0].t, calib.cameras[0].t)
    with pytest.raises(PriortrackError, match="units 'feet'"):
        read_calibration(stated, units="feet")


def test_panoptic_and_voxelpose_layouts(tmp_path):
    """Files in the layouts the CMU Panoptic toolbox (centimetres, distCoef, resolution) and VoxelPose
    (fx, fy, cx, cy, k, p; T the camera centre, millimetres) document, made from the Pose2Sim cameras."""
    calib = read_calibration(POSE2SIM / "Calib.toml")
    panoptic = tmp_path / "calibration_171204_pose1.json"
    panoptic.write_text(json.dumps({"calibDataSource": "171204_calib", "cameras": [
        {"name": f"00_0{i}", "type": "hd", "resolution": list(c.size), "panel": 0, "node": i, "K": c.K.tolist(),
         "distCoef": c.dist.tolist(), "R": c.R.tolist(), "t": (100 * c.t).reshape(3, 1).tolist()}
        for i, c in enumerate(calib.cameras)]}))
    voxelpose = tmp_path / "calibration_shelf.json"
    voxelpose.write_text(json.dumps({str(i): {
        "R": c.R.tolist(), "T": (-1000 * c.R.T @ c.t).reshape(3, 1).tolist(), "fx": c.K[0, 0], "fy": c.K[1, 1],
        "cx": c.K[0, 2], "cy": c.K[1, 2], "k": c.dist[[0, 1, 4]].reshape(3, 1).tolist(),
        "p": c.dist[2:4].reshape(2, 1).tolist()} for i, c in enumerate(calib.cameras)}))
    for path, fmt in ((panoptic, "CMU Panoptic calibration.json"), (voxelpose, "VoxelPose calibration.json")):
        read = read_calibration(path)
        assert read.format == fmt and read.units == ("cm" if path is panoptic else "mm")
        for a, b in zip(read.cameras, calib.cameras):
            np.testing.assert_allclose(a.t, b.t, atol=1e-9)
            np.testing.assert_allclose(a.R, b.R, atol=1e-12)
            np.testing.assert_allclose(a.dist, b.dist, atol=1e-15)


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


def test_the_projection_kernel_is_the_torch_path():
    """CPU float64 and float32 points without gradients take the fused kernel
    (priortrack.geometry.projection_kernel): the torch path's pixels (1e-12 relative in float64, float32's
    rounding in float32), the same points in front, NaN for a NaN point and one behind the camera; a point that
    needs a gradient takes the torch path, and the gradient flows."""
    cam = read_calibration(POSE2SIM / "Calib.toml").cameras[0]
    camera = PinholeCamera(cam.K, cam.R, cam.t, *cam.size, dist=np.array([-0.3, 0.1, 0.002, -0.001, -0.02]))
    points = torch.as_tensor(np.random.default_rng(2).uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 1.8], size=(125, 15, 3)))
    points[0, 0] = float("nan")
    R, t = camera.R.numpy(), camera.t.numpy()
    points[0, 1] = torch.as_tensor(R.T @ (np.array([0.0, 0.0, -1.0]) - t))                        # behind
    for dtype, rtol in ((torch.float64, 1e-12), (torch.float32, 1e-5)):
        kernel = camera._project_in_kernel(points.to(dtype))
        reference = camera._project_distorted(points.to(dtype), jacobian=False)[:3]
        assert kernel[0].dtype == dtype and kernel[0].shape == (125, 15, 2)
        assert torch.equal(kernel[1], reference[1]) and not kernel[1][0, :2].any() and kernel[1].sum() == 125 * 15 - 2
        np.testing.assert_allclose(kernel[0].numpy(), reference[0].numpy(), rtol=rtol, atol=1e-9)
        np.testing.assert_allclose(kernel[2].numpy(), reference[2].numpy(), rtol=rtol)
        np.testing.assert_array_equal(camera.project(points.to(dtype))[0].numpy(), kernel[0].numpy())
    wanted = points[1:].clone().requires_grad_(True)
    uv, _ = camera.project(wanted)
    uv.sum().backward()
    assert uv.requires_grad and torch.isfinite(wanted.grad).all()


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
    read = read_calibration(path, units="mm")
    assert read.names == ("side",) and read.up == "z"
    np.testing.assert_allclose(read.cameras[0].t, cam.t)
    only = tmp_path / "intrinsics.json"
    only.write_text(json.dumps({"K": cam.K.tolist(), "size": [1088, 1920]}))
    read = read_calibration(only)
    assert read.up == "-y" and np.array_equal(read.cameras[0].R, np.eye(3)) and not read.cameras[0].t.any()


_K = "matrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nsize = [10, 10]\n"


@pytest.mark.parametrize("text, suffix, message", [
    ('[cam_01]\n' + _K + 'rotation = [0, 0, 0]\n', ".toml", "camera 'cam_01': the translation .* is missing"),
    ('[c]\n' + _K + 'rotation = [0, 0, 0]\ntranslation = [0, 0, 0]\nfisheye = true\n', ".toml", "'c' is a fisheye"),
    ('[c]\nmatrix = [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]\nsize = [10, 10]\nrotation = [0, 0, 0]\ntranslation = [0, 0, 0]\n',
     ".toml", "camera 'c': the intrinsic matrix K is not"),
    ('[c]\n' + _K + 'rotation = [0, 0, nan]\ntranslation = [0, 0, 0]\n', ".toml",
     "camera 'c': the rotation \\(Rodrigues vector\\) contains NaN"),
    ('[c]\n' + _K + 'rotation = [0, 0]\ntranslation = [0, 0, 0]\n', ".toml",
     "camera 'c': the rotation matrix has shape \\(2,\\)"),
    ('[c]\n' + _K + 'rotation = [0, 0, 0]\ntranslation = [0, 0, "x"]\n', ".toml", "camera 'c': the translation is not numeric"),
    ('[c]\n' + _K + 'rotation = [0, 0, 0]\ntranslation = [0, 0, 1, 2]\n', ".toml",
     "camera 'c': the translation has shape \\(4,\\)"),
    ('[c]\nmatrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nsize = [0, 10]\nrotation = [0, 0, 0]\ntranslation = [0, 0, 0]\n',
     ".toml", "camera 'c': the image size must be"),
    ('[c]\n' + _K + 'rotation = [0, 0, 0]\ntranslation = [0, 0, 0]\ndistortions = [0.1, 0.2]\n', ".toml",
     "camera 'c': the distortion must be"),
    ('[cameras.0]\n' + _K + 'rotation = [[1, 0, 0], [0, 1, 0], [0, 0, 2]]\ntranslation = [0, 0, 0]\n', ".toml",
     "camera 'cam_0': the rotation matrix is not a rotation"),
    ('[a]\n' + _K + 'rotation = [0, 0, 0]\ntranslation = [0, 0, 0]\nfisheye = false\n[b]\n' + _K +
     'rotation = [0, 0, 0]\ntranslation = [0, 0, 0]\nname = "a"\nfisheye = false\n', ".toml", "camera names repeat: a, a"),
    ('{"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "size": [4, 4]}', ".json",
     "give both a rotation"),
    ('{"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}', ".json", "image size"),
    ('{"up": "sky", "K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "size": [4, 4]}', ".json", "up 'sky' is neither"),
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


MULTIPERSON = Path(__file__).parent / "data" / "pose2sim_multiperson"


def test_qualisys_qca_is_read_as_pose2sim_converts_it():
    """The Qualisys export Pose2Sim's multi-person demo ships, against Pose2Sim's own conversion of it
    (``Calib_qualisys.toml``, written by Pose2Sim from this file): the same K, distortion, R and t."""
    qca = read_calibration(MULTIPERSON / "calibration" / "Calib.qca.txt")
    pose2sim = read_calibration(MULTIPERSON / "pose2sim_output" / "Calib_qualisys.toml")
    assert qca.format == "Qualisys .qca.txt" and qca.up == "z" and qca.units == "mm"
    assert qca.names == pose2sim.names == ("cam_01", "cam_02", "cam_03", "cam_04")
    for a, b in zip(qca.cameras, pose2sim.cameras):
        assert a.size == b.size == (1088, 1920)
        np.testing.assert_allclose(a.K, b.K, rtol=1e-12)
        np.testing.assert_allclose(a.dist, b.dist, atol=1e-15)
        np.testing.assert_allclose(a.R, b.R, atol=1e-12)
        np.testing.assert_allclose(a.t, b.t, atol=1e-12)


def test_4d_association_calibration_projects_like_cv2(tmp_path):
    """4D Association's calibration layout (per camera ``K`` 9 and ``RT`` 12 numbers, flat row-major,
    world → camera, and ``imgSize``; its ``Camera::Parse``), written from the Pose2Sim cameras with cv2's
    Rodrigues: points project as cv2.projectPoints projects them with the Pose2Sim file's own values."""
    table = tomllib.loads((POSE2SIM / "Calib.toml").read_text())
    cameras = [v for v in table.values() if isinstance(v, dict) and "matrix" in v]
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps({str(i): {
        "K": np.ravel(c["matrix"]).tolist(),
        "RT": np.hstack([cv2.Rodrigues(np.asarray(c["rotation"], float))[0],
                         np.reshape(c["translation"], (3, 1))]).ravel().tolist(),
        "imgSize": [int(s) for s in c["size"]]} for i, c in enumerate(cameras)}, indent=1))
    calib = read_calibration(path)
    assert calib.format == "4D Association calibration.json" and calib.names == ("0", "1", "2", "3")
    X = np.random.default_rng(0).uniform([-1, -1, 0], [1, 1, 2], (50, 3))
    for camera, c in zip(calib.cameras, cameras):
        expected = cv2.projectPoints(X, np.asarray(c["rotation"], float), np.asarray(c["translation"], float),
                                     np.asarray(c["matrix"], float), None)[0][:, 0]
        uv, _ = PinholeCamera.from_calibration(camera).project(X)
        np.testing.assert_allclose(uv, expected, atol=1e-6)
    bad = json.loads(path.read_text())
    bad["0"]["RT"] = bad["0"]["RT"][:11]
    path.write_text(json.dumps(bad))
    with pytest.raises(PriortrackError, match=r"camera '0': RT must be 12 numbers"):
        read_calibration(path)


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace('focalLengthU="107599.671875"', 'focalLengthU="wide"'),
     r"camera 'cam_01': <intrinsic> focalLengthU='wide' is not a number"),
    (lambda t: t.replace("<fov_video ", "<fov_other ", 1), r"camera 'cam_01': no <fov_video> element"),
    (lambda t: t[:len(t) // 2], r"not valid XML"),
    (lambda t: "cam_01 1681 0 533\n", r"unknown calibration format '.txt'"),
])
def test_bad_qualisys_files_name_the_camera_and_field(tmp_path, edit, message):
    path = tmp_path / "Calib.qca.txt"
    path.write_text(edit((MULTIPERSON / "calibration" / "Calib.qca.txt").read_text()))
    with pytest.raises(PriortrackError, match=message):
        read_calibration(path)
