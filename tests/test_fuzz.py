"""Property-based fuzzing of every reader (issue 21): from a valid file, random mutations (numbers
turned into nan, inf, huge, negative or garbage values, lines deleted or repeated, the file cut short)
must either load with every number finite (NaN only where a format says "missing") or raise a PriortrackError, never another exception, and
each input is read in well under a second.

The short profile runs in CI; ``make fuzz`` runs the long one (PRIORTRACK_FUZZ=long).
"""

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from priortrack import PriortrackError
from priortrack.data.bundled import ASF_AMC_DIR, POSE2SIM_DIR

settings.register_profile("ci", max_examples=60, deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
settings.register_profile("long", max_examples=3000, deadline=None,
                          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
settings.load_profile("long" if os.environ.get("PRIORTRACK_FUZZ") == "long" else "ci")

WEIRD = ["nan", "NaN", "inf", "-inf", "1e308", "1e999", "-1", "0", "-0", "", "x", "9" * 30, "²", "1,5", "[", "}",
         "{", "\"", "true", "null", "-9999999999", "0x10", "1e-320"]
NUMBER = re.compile(r"-?\d+(\.\d+)?(e-?\d+)?")


@st.composite
def mutated(draw, text: str):
    """``text`` with 1–4 mutations: a number replaced, a line deleted or repeated, the text cut short."""
    lines = text.split("\n")
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["number", "number", "delete", "repeat", "cut"]))
        i = draw(st.integers(0, len(lines) - 1))
        if kind == "number":
            matches = list(NUMBER.finditer(lines[i]))
            if matches:
                m = matches[draw(st.integers(0, len(matches) - 1))]
                lines[i] = lines[i][:m.start()] + draw(st.sampled_from(WEIRD)) + lines[i][m.end():]
        elif kind == "delete" and len(lines) > 1:
            del lines[i]
        elif kind == "repeat":
            lines.insert(i, lines[i])
        elif kind == "cut":
            lines = lines[:i + 1]
            lines[-1] = lines[-1][:draw(st.integers(0, len(lines[-1])))]
    return "\n".join(lines)


def _only_priortrack_errors(load, path: Path, text: str):
    path.write_text(text)
    try:
        result = load(path)
    except PriortrackError:
        return None
    return result


ASF = (ASF_AMC_DIR / "07.asf").read_text()
AMC = "\n".join((ASF_AMC_DIR / "07_01.amc").read_text().split("\n")[:3 + 3 * 30])   # header and 3 frames
CALIB = (POSE2SIM_DIR / "Calib.toml").read_text()
OPENPOSE = (POSE2SIM_DIR / "pose" / "cam01_json" / "Static_cam_01.00000.json").read_text()
PRESET = (Path(__file__).resolve().parents[1] / "filters" / "pf-lie.toml").read_text()


@given(text=mutated(ASF))
def test_asf(tmp_path, text):
    from priortrack.data.asf import read_asf

    skeleton = _only_priortrack_errors(read_asf, tmp_path / "07.asf", text)
    if skeleton is not None:
        assert np.isfinite(skeleton.offsets).all() and np.isfinite(skeleton.rot_axes).all()
        _assert_a_human_body(skeleton)


def _assert_a_human_body(skeleton, channels=None):
    """No absurd body loads: bones, rest pose and root within a human's bounds (skeleton.py)."""
    from priortrack.data.skeleton import MAX_BONE_M, MAX_EXTENT_M, MAX_ROOT_M

    assert np.linalg.norm(skeleton.offsets[1:], axis=1).max() <= MAX_BONE_M
    rest = np.zeros((skeleton.num_joints, 3))
    for j in range(1, skeleton.num_joints):
        rest[j] = rest[skeleton.parents[j]] + skeleton.offsets[j]
    assert np.linalg.norm(rest.max(axis=0) - rest.min(axis=0)) <= MAX_EXTENT_M
    if channels is not None:
        root = skeleton.trans_channels[0][skeleton.trans_channels[0] >= 0]
        assert np.abs(channels[:, root]).max(initial=0.0) <= MAX_ROOT_M


@given(text=mutated(AMC))
def test_amc(tmp_path, text):
    from priortrack.data.amc import read_amc
    from priortrack.data.bundled import cmu_skeleton

    channels = _only_priortrack_errors(lambda p: read_amc(p, cmu_skeleton("07")), tmp_path / "07_01.amc", text)
    if channels is not None:
        assert np.isfinite(channels).all()
        _assert_a_human_body(cmu_skeleton("07"), channels)


@pytest.fixture(scope="module")
def bvh_text(tmp_path_factory):
    from priortrack.data.bvh import write_bvh
    from priortrack.data.load import load_motion

    path = tmp_path_factory.mktemp("bvh") / "walk.bvh"
    write_bvh(load_motion("cmu:07_01")[:4], path)
    return path.read_text()


@given(data=st.data())
def test_bvh(tmp_path, bvh_text, data):
    from priortrack.data.bvh import read_bvh

    motion = _only_priortrack_errors(read_bvh, tmp_path / "walk.bvh", data.draw(mutated(bvh_text)))
    if motion is not None:
        assert np.isfinite(motion.channels).all() and np.isfinite(motion.skeleton.offsets).all()
        _assert_a_human_body(motion.skeleton, motion.channels)


@given(text=mutated(OPENPOSE))
def test_openpose(tmp_path, text):
    from priortrack.data.detections import read_detections

    folder = tmp_path / "cam"
    folder.mkdir(exist_ok=True)
    detections = _only_priortrack_errors(lambda p: read_detections(folder, keypoints="body25b"),
                                         folder / "clip.000000.json", text)
    if detections is not None:
        confidence = detections.keypoints[..., 2]                     # NaN is missing, and data; inf never
        assert not np.isinf(detections.keypoints).any()
        assert np.all(np.isnan(confidence) | (confidence >= 0))


@given(text=mutated(PRESET))
def test_preset(tmp_path, text):
    from priortrack.tracking.presets import load_preset

    _only_priortrack_errors(load_preset, tmp_path / "mine.toml", text)


@pytest.fixture(scope="module")
def prior_bytes(tmp_path_factory):
    from priortrack.data.bundled import load_walkjog
    from priortrack.priors.diffusion import Diffusion

    path = tmp_path_factory.mktemp("prior") / "prior.npz"
    Diffusion.fit(list(load_walkjog().walks("train"))[:2], local=True).save(path)
    return path.read_bytes()


@given(data=st.data())
def test_prior_file(tmp_path, prior_bytes, data):
    """Bytes flipped, cut or the JSON header's numbers mutated: a PriortrackError or a finite prior."""
    from priortrack.priors.base import load_prior

    raw = bytearray(prior_bytes)
    for _ in range(data.draw(st.integers(1, 3))):
        kind = data.draw(st.sampled_from(["flip", "cut", "header"]))
        if kind == "flip" and raw:
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
        elif kind == "cut":
            raw = raw[:data.draw(st.integers(0, len(raw)))]
        else:
            text = raw.decode("latin-1")
            match = list(re.finditer(r"\d+\.\d+", text))
            if match:
                m = match[data.draw(st.integers(0, len(match) - 1))]
                value = data.draw(st.sampled_from(["NaN", "Infinity", "1e999", "-1"]))
                raw = bytearray((text[:m.start()] + value.ljust(m.end() - m.start())[:m.end() - m.start()]
                                 + text[m.end():]).encode("latin-1"))
    path = tmp_path / "prior.npz"
    path.write_bytes(bytes(raw))
    try:
        prior = load_prior(path)
    except PriortrackError:
        return
    assert bool(prior.sigma.isfinite().all()) and np.isfinite(prior.fps)


COCO = json.dumps([{"image_id": t, "category_id": 1, "score": 0.9,
                    "keypoints": [round(v, 2) for k in range(17) for v in (100.0 + 7 * k + t, 200.0 + 5 * k, 0.8)]}
                   for t in range(3)], indent=0)
CALIB_JSON = json.dumps({"up": "z", "cameras": [
    {"name": "a", "K": [[1000.0, 0.0, 500.0], [0.0, 1000.0, 400.0], [0.0, 0.0, 1.0]], "dist": [0.01, -0.02, 0.0, 0.0],
     "rvec": [0.1, 0.2, 0.3], "t": [0.1, 0.2, 3.0], "size": [1000, 800]}]}, indent=0)


@given(text=mutated(COCO))
def test_coco_results(tmp_path, text):
    from priortrack.data.detections import read_detections

    detections = _only_priortrack_errors(read_detections, tmp_path / "results.json", text)
    if detections is not None:
        assert not np.isinf(detections.keypoints).any()


TEST_DATA = Path(__file__).parent / "data"
#: Calibrations other tools wrote (tests/data/formats), by the name a mutated copy is written under.
TOOL_CALIBRATIONS = {
    "anipose.toml": TEST_DATA / "formats/anipose/trackstudio_calibration.toml",
    "camera_array.toml": TEST_DATA / "formats/caliscope/4_cam_recording_camera_array.toml",
    "config.toml": TEST_DATA / "formats/caliscope/post_optimization_config.toml",
    "mmhuman3d.json": TEST_DATA / "formats/mmhuman3d/calibration_chessboard_05_28_18_05_19.json",
}


@pytest.mark.parametrize("name", ["Calib.toml", "calib.json", *TOOL_CALIBRATIONS])
@given(data=st.data())
def test_calibration(tmp_path, name, data):
    from priortrack.data.calibration import read_calibration

    original = (TOOL_CALIBRATIONS[name].read_text() if name in TOOL_CALIBRATIONS else
                CALIB if name.endswith(".toml") else CALIB_JSON)
    calibration = _only_priortrack_errors(read_calibration, tmp_path / name, data.draw(mutated(original)))
    if calibration is not None:
        for camera in calibration.cameras:
            assert all(np.isfinite(a).all() for a in (camera.K, camera.dist, camera.R, camera.t))
            np.testing.assert_allclose(camera.R @ camera.R.T, np.eye(3), atol=1e-9)
        assert calibration.up is None or isinstance(calibration.up, str) or np.isfinite(calibration.up).all()


CALISCOPE = "\n".join((TEST_DATA / "caliscope_4cam/xy_HOLISTIC.csv").read_text().split("\n")[:400])


@given(text=mutated(CALISCOPE))
def test_caliscope_csv(tmp_path, text):
    from priortrack.data.detections import read_detections

    detections = _only_priortrack_errors(read_detections, tmp_path / "xy_HOLISTIC.csv", text)
    if detections is not None:
        assert not np.isinf(detections.keypoints).any() and (detections.fps is None or np.isfinite(detections.fps))
        confidence = detections.keypoints[..., 2]
        assert np.all(np.isnan(confidence) | (confidence == 1))


@given(values=st.lists(st.sampled_from([0.0, 1.0, -1.0, 500.0, float("nan"), float("inf"), 1e300, 0.5]),
                       min_size=2 * 3 * 33 * 3, max_size=2 * 3 * 33 * 3))
def test_freemocap_npy(tmp_path, values):
    from priortrack.data.detections import read_detections

    path = tmp_path / "d.npy"
    np.save(path, np.array(values).reshape(2, 3, 33, 3))
    try:
        detections = read_detections(path)
    except PriortrackError:
        return
    assert not np.isinf(detections.keypoints).any()
    confidence = detections.keypoints[..., 2]
    assert np.all(np.isnan(confidence) | (confidence > 0))


@given(keypoints=st.lists(st.sampled_from([0.0, 1.0, -1.0, 500.0, float("nan"), float("inf"), 1e300, 0.5]),
                          min_size=2 * 3 * 17 * 3, max_size=2 * 3 * 17 * 3),
       fps=st.sampled_from([30.0, 0.0, -5.0, float("nan"), 1e9]),
       frames=st.sampled_from([[0, 1, 2], [2, 1, 0], [0, 0, 1]]))
def test_detections_npz(tmp_path, keypoints, fps, frames):
    from priortrack.data.detections import read_detections
    from priortrack.data.keypoints import LAYOUTS

    path = tmp_path / "d.npz"
    np.savez(path, keypoints=np.array(keypoints).reshape(2, 3, 17, 3), keypoint_names=np.array(LAYOUTS["coco17"]),
             fps=np.array(fps), frames=np.array(frames))
    try:
        detections = read_detections(path)
    except PriortrackError:
        return
    assert not np.isinf(detections.keypoints).any() and np.isfinite(detections.fps)
    confidence = detections.keypoints[..., 2]
    assert np.all(np.isnan(confidence) | (confidence >= 0))
