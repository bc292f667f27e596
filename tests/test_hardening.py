"""Bad input found by fuzzing (issue 21): each case a clear PriortrackError, never a hang or a half-used value."""

import numpy as np
import pytest
import torch

from priortrack import PriortrackError
from priortrack.data.bundled import cmu_skeleton, load_bundled
from priortrack.data.bvh import read_bvh
from priortrack.geometry.camera import PinholeCamera
from priortrack.observation.likelihood import JointLikelihood
from priortrack.observation.multiview import MultiViewLikelihood


def test_a_bvh_that_declares_a_billion_frames_of_nothing_is_refused_at_once(tmp_path):
    path = tmp_path / "big.bvh"
    path.write_text("HIERARCHY\nROOT hips\n{\n\tOFFSET 0 0 0\n\tCHANNELS 0\n\tEnd Site\n\t{\n\t\tOFFSET 0 1 0\n\t}\n}\n"
                    "MOTION\nFrames: 1000000000\nFrame Time: 0.01\n")
    with pytest.raises(PriortrackError, match="Frames: 1000000000, but the hierarchy has no channels"):
        read_bvh(path)


@pytest.mark.parametrize("name", ["cmu:../asf_amc/07_01", "cmu:../../cmu/asf_amc/07_01", "cmu:/etc/passwd"])
def test_bundled_names_never_reach_outside_the_bundled_data(name):
    with pytest.raises(PriortrackError, match="unknown bundled motion"):
        load_bundled(name)


def test_bundled_skeletons_are_names_not_paths():
    with pytest.raises(PriortrackError, match="no bundled skeleton"):
        cmu_skeleton("../asf_amc/07")
    assert cmu_skeleton("07").num_joints == 38                   # 31 bones, the root and 6 end sites


def test_a_joint_with_one_coordinate_missing_is_missing_for_the_gaussian_filters():
    camera = PinholeCamera.look_at([0, 1, 5], [0, 1, 0])
    z = np.full((15, 2), 100.0)
    z[3, 0] = np.nan
    z[4, 1] = np.inf
    values, variances = JointLikelihood(camera, 5.0).measurement(z)
    assert np.isnan(values.numpy().reshape(15, 2)[[3, 4]]).all() and np.isfinite(values.numpy().reshape(15, 2)[5:]).all()
    multi = np.concatenate([z, np.ones((15, 1))], axis=1)[None]
    values, variances = MultiViewLikelihood([camera], 5.0, robust_nu=None).measurement(multi)
    assert np.isnan(values.numpy().reshape(15, 2)[[3, 4]]).all() and torch.isfinite(variances).all()


@pytest.mark.parametrize("sigma, nu, message", [(1e-7, None, "sigma_px must be a number of pixels"),
                                                ("10", None, "sigma_px"), (float("nan"), None, "sigma_px"),
                                                (1e9, None, "sigma_px"), (5.0, True, "robust_nu"),
                                                (5.0, 0.0, "robust_nu"), (5.0, float("inf"), "robust_nu")])
def test_noise_scales_out_of_range_are_refused(sigma, nu, message):
    camera = PinholeCamera.look_at([0, 1, 5], [0, 1, 0])
    with pytest.raises(PriortrackError, match=message):
        JointLikelihood(camera, sigma, nu)
    with pytest.raises(PriortrackError, match=message):
        MultiViewLikelihood([camera], sigma, nu)


def _asf(tmp_path, old: str, new: str):
    from priortrack.data.bundled import ASF_AMC_DIR
    from priortrack.data.asf import read_asf

    text = (ASF_AMC_DIR / "07.asf").read_text()
    assert old in text
    path = tmp_path / "07.asf"
    path.write_text(text.replace(old, new, 1))
    return lambda: read_asf(path)


@pytest.mark.parametrize("old, new, message", [
    ("length 6.92462", "length nan", r"length has a non-finite value"),
    ("length 6.92462", "length inf", r"length has a non-finite value"),
    ("direction 0.34202 -0.939693 0", "direction nan -0.939693 0", "direction has a non-finite value"),
    ("axis 0 0 20", "axis 0 0 1e999", "axis has a non-finite value"),
    ("length 6.92462", "length 2000", "is 113 m long"),
    ("length 6.92462", "length -3", "is -0.169 m long"),
    ("direction 0.34202 -0.939693 0", "direction 0 0 0", "has a length but no direction"),
])
def test_asf_files_with_non_finite_or_absurd_numbers_are_refused_by_line(tmp_path, old, new, message):
    with pytest.raises(PriortrackError, match=message):
        _asf(tmp_path, old, new)()


def test_bvh_root_positions_are_absolute_as_blender_reads_them(tmp_path):
    """A root OFFSET of (10, 90, 0) cm with position channels (1, 95, 2): Blender places the root at
    the channels, (0.01, 0.95, 0.02) m; the OFFSET is not added (it was: 1.85 m up)."""
    path = tmp_path / "root.bvh"
    path.write_text("HIERARCHY\nROOT Hips\n{\n\tOFFSET 10 90 0\n\tCHANNELS 6 Xposition Yposition Zposition "
                    "Zrotation Xrotation Yrotation\n\tEnd Site\n\t{\n\t\tOFFSET 0 10 0\n\t}\n}\n"
                    "MOTION\nFrames: 1\nFrame Time: 0.04\n1 95 2 0 0 0\n")
    from priortrack.body.fk import ForwardKinematics

    motion = read_bvh(path)
    p = ForwardKinematics(motion.skeleton)(motion.channels).numpy()[0]
    np.testing.assert_allclose(p, [[0.01, 0.95, 0.02], [0.01, 1.05, 0.02]], atol=1e-12)


def _prior_file(tmp_path):
    from priortrack.data.bundled import load_walkjog
    from priortrack.priors.diffusion import Diffusion

    path = tmp_path / "prior.npz"
    Diffusion.fit(list(load_walkjog().walks("train"))[:2], local=True).save(path)
    return path


def _rewrite(path, out, **changes):
    import json
    import zipfile

    with zipfile.ZipFile(path) as archive:
        members = {i.filename: archive.read(i) for i in archive.infolist()}
    with np.load(path, allow_pickle=False) as z:
        header = json.loads(str(z["header"]))
    header.update(changes.pop("header", {}))
    members["header.npy"] = _npy(np.array(json.dumps(header)))
    members.update(changes)
    with zipfile.ZipFile(out, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return out


def _npy(array):
    import io

    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    return buffer.getvalue()


def test_prior_files_are_checked_before_anything_is_allocated(tmp_path):
    from priortrack.priors.base import load_prior

    good = _prior_file(tmp_path)
    assert load_prior(good).kind == "diffusion-local"
    # An npy header that declares 10^11 float64 values (800 GB) over 3 values of data.
    text = "{'descr': '<f8', 'fortran_order': False, 'shape': (100000000000,), }".ljust(117) + "\n"
    header_only = b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text.encode() + np.zeros(3).tobytes()
    with pytest.raises(PriortrackError, match="declares 800000000000 bytes but holds"):
        load_prior(_rewrite(good, tmp_path / "huge.npz", **{"sigma.npy": header_only}))
    with pytest.raises(PriortrackError, match="header field 'local' is 'false', not of its type"):
        load_prior(_rewrite(good, tmp_path / "flag.npz", header={"local": "false"}))
    with pytest.raises(PriortrackError, match="header fps -30 is not a frame rate"):
        load_prior(_rewrite(good, tmp_path / "fps.npz", header={"fps": -30}))
    with pytest.raises(PriortrackError, match="do not fit together|lacks"):
        load_prior(_rewrite(good, tmp_path / "shape.npz", **{"sigma.npy": _npy(np.zeros((2, 2, 2)))}))


@pytest.mark.parametrize("preset", ["pf-diffusion-local", "ukf-diffusion-local"])
def test_a_detection_a_million_pixels_away_is_gated_and_flagged(preset, tmp_path):
    """An outlier at 10⁶ px (issue 21, item 6): dropped by the validation gate (flag "outlier-gated"),
    the estimate stays where the clean run puts it."""
    from priortrack.experiments.presets import load_preset
    from priortrack.experiments.tracking import track

    clean = track("cmu:07_10", load_preset(preset), "clean:sigma_px=5", seed=0, frames=12, cache=tmp_path)
    observations = clean.observations.uv.copy()
    observations[6, 0] = [1e6, -1e6]
    filt = load_preset(preset).build(clean.observations.camera, seed=0, cache=tmp_path)
    run = filt.run(observations, clean.motion, keep_snapshots=True)
    assert "outlier-gated" in run.flags[6]
    assert np.isfinite(run.estimates).all()
    assert np.abs(run.estimates - clean.track.estimates).max() < 0.5
