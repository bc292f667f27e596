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
    from priortrack.tracking.presets import load_preset
    from priortrack.experiments.tracking import track

    clean = track("cmu:07_10", load_preset(preset), "clean:sigma_px=5", seed=0, frames=12, cache=tmp_path)
    observations = clean.observations.uv.copy()
    observations[6, 0] = [1e6, -1e6]
    filt = load_preset(preset).build(clean.observations.camera, seed=0, cache=tmp_path)
    run = filt.run(observations, clean.motion, keep_snapshots=True)
    assert "outlier-gated" in run.flags[6]
    assert np.isfinite(run.estimates).all()
    assert np.abs(run.estimates - clean.track.estimates).max() < 0.5


def _ukf_run(clean, observations, tmp_path, **options):
    from dataclasses import replace

    from priortrack.tracking.presets import load_preset

    preset = load_preset("ukf-diffusion-local")
    preset = replace(preset, filter_options={**preset.filter_options, **options})
    filt = preset.build(clean.observations.camera, seed=0, cache=tmp_path)
    return filt, filt.run(observations, clean.motion)


def test_the_unscented_filter_gates_a_frame_of_gross_detections_and_stays_on_the_body(tmp_path):
    """One frame whose every detection jumped 400 px (issue 21, item 6): inside the image, so the
    observation model's gate keeps it, and without a validation gate the update drags the body into
    a wrong 3D pose it never leaves. The innovation gate leaves the frame out and the run stays
    with the clean one."""
    from priortrack.tracking.presets import load_preset
    from priortrack.experiments.tracking import track

    clean = track("cmu:07_10", load_preset("ukf-diffusion-local"), "noise", seed=0, frames=40, cache=tmp_path)
    jumped = clean.observations.uv.copy()
    jumped[10] += [400.0, 0.0]
    off_by = {}
    for p in (0.0, 1e-4):
        _, run = _ukf_run(clean, jumped, tmp_path, gate_probability=p)
        off_by[p] = np.linalg.norm(run.estimates - clean.track.estimates, axis=-1).mean(-1)[11:]
        assert ("innovation-gated" in run.flags[10]) == (p > 0)
        assert not any("innovation-gated" in f for t, f in enumerate(run.flags) if t != 10)
    assert off_by[0.0].mean() > 0.2
    assert off_by[1e-4].mean() < 0.15 * off_by[0.0].mean() and off_by[1e-4].max() < 0.1


def test_the_unscented_gate_reopens_when_no_detection_fits_the_prediction_any_more(tmp_path):
    """The detections jump 300 px and stay there (the body really is elsewhere, as after a cut in
    the video): after GATE_PATIENCE gated frames the gate opens and the filter follows the data."""
    from priortrack.tracking.presets import load_preset
    from priortrack.experiments.tracking import track
    from priortrack.filters.ukf import GATE_PATIENCE

    clean = track("cmu:07_10", load_preset("ukf-diffusion-local"), "noise", seed=0, frames=40, cache=tmp_path)
    moved = clean.observations.uv.copy()
    moved[10:] += [300.0, 0.0]
    filt, run = _ukf_run(clean, moved, tmp_path)
    gated = [t for t, f in enumerate(run.flags) if "innovation-gated" in f]
    assert gated[:GATE_PATIENCE] == list(range(10, 10 + GATE_PATIENCE))
    assert "gate-reopened" in run.flags[10 + GATE_PATIENCE]
    uv, _ = filt.model.likelihood.camera.project(torch.as_tensor(run.estimates[-10:]))
    assert np.nanmean(np.linalg.norm(uv.numpy() - moved[-10:], axis=-1)) < 30


def test_the_validation_gate_probability_is_checked():
    from priortrack.filters.ukf import UnscentedFilter
    from linear_gaussian import LinearGaussian

    with pytest.raises(PriortrackError, match=r"gate_probability must be in \[0, 1\)"):
        UnscentedFilter(LinearGaussian(np.eye(2), np.eye(2), np.eye(2), np.eye(2)), gate_probability=1.0)


@pytest.mark.parametrize("preset", ["pf-diffusion-local", "apf-diffusion-local", "ukf-diffusion-local", "map-gpdm"])
@pytest.mark.parametrize("observation", [{"sigma_px": 0.01}, {"sigma_px": 1e4}, {"sigma_px": 0.01, "robust_nu": 0.1},
                                         {"sigma_px": 1e4, "robust_nu": 1e6}])
def test_filters_give_finite_estimates_at_the_ends_of_the_noise_range(preset, observation, tmp_path):
    """Every frame of finite data gets a finite estimate at the smallest and largest σ_px and ν the
    likelihood accepts (issue 21, item 5), on noisy data with outliers (log-weights underflow at
    σ = 0.01 px: the filters work in log space and flag it)."""
    from dataclasses import replace

    from priortrack.tracking.presets import load_preset
    from priortrack.experiments.tracking import track

    chosen = replace(load_preset(preset), observation=observation)
    try:
        run = track("cmu:07_10", chosen, "outliers:sigma_px=5", seed=0, frames=8, cache=tmp_path)
    except PriortrackError as error:   # a filter that needs a Gaussian likelihood says so
        assert "robust_nu" in observation and "robust_nu" in str(error)
        return
    assert np.isfinite(run.track.estimates).all()


def test_absurd_bodies_are_refused_naming_the_unit(tmp_path):
    """A body 10x too large or too small (a file in another unit than read), a bone metres long, or a
    root a thousand kilometres away loads as nothing absurd: each is refused by name."""
    from priortrack.data.amc import read_amc
    from priortrack.data.bundled import ASF_AMC_DIR, cmu_skeleton
    from priortrack.data.bvh import write_bvh
    from priortrack.data.load import load_motion

    with pytest.raises(PriortrackError, match=r"07.asf: bone '.*' is [\d.]+ m long, more than a human body's 1.5 m"):
        _asf(tmp_path, "length 0.45", "length 0.09")()           # CMU: a unit is 1/0.45 inch
    walk = load_motion("cmu:07_01")[:3]
    path = tmp_path / "walk_mm.bvh"
    write_bvh(walk, path, length_unit=0.001)                    # written in millimetres, read as centimetres
    with pytest.raises(PriortrackError, match=f"{path.name}: bone .* is [\\d.]+ m long.*is the file in another unit"):
        read_bvh(path)
    from priortrack.body.fk import joint_positions

    np.testing.assert_allclose(joint_positions(read_bvh(path, length_unit=0.001)), joint_positions(walk), atol=1e-9)
    amc = "\n".join((ASF_AMC_DIR / "07_01.amc").read_text().split("\n")[:3 + 3 * 30])
    lines = amc.split("\n")
    root = next(i for i, line in enumerate(lines) if line.startswith("root"))
    words = lines[root].split()
    lines[root] = " ".join([words[0], "9e7"] + words[2:])
    (tmp_path / "far.amc").write_text("\n".join(lines))
    with pytest.raises(PriortrackError, match="far.amc: frame 0 puts the root [\\d.e+]+ m from the origin"):
        read_amc(tmp_path / "far.amc", cmu_skeleton("07"))
