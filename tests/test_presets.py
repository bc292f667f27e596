"""Filter presets: the shipped TOML files, validation of every section, the fitted-prior cache."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from priortrack import PriortrackError
from priortrack.experiments.tracking import TABLE_PRESETS
from priortrack.tracking import presets as presets_module
from priortrack.tracking.presets import load_preset, parse_preset, preset_names
from priortrack.body.fk import joint_positions

BASE = {
    "filter": {"kind": "pf", "particles": 50},
    "prior": {"kind": "diffusion-local", "train": ["walkjog:35_01", "walkjog:35_02"], "options": {"space": "angles"}},
    "observation": {"sigma_px": 10.0},
}


def table(**changes):
    t = json.loads(json.dumps(BASE))
    for dotted, value in changes.items():
        section, _, key = dotted.partition("__")
        t[section][key] = value
    return t


def test_the_issue_presets_are_shipped_and_valid():
    assert set(TABLE_PRESETS) <= set(preset_names())
    for name in preset_names():
        preset = load_preset(name)
        assert preset.name == name and preset.train and preset.description


def test_patterns_in_train_are_expanded():
    preset = load_preset("pf-diffusion-local")
    assert "walkjog:35_29" not in preset.train and "walkjog:35_01" in preset.train
    assert "walkjog:35_17" not in preset.train                       # a jog


@pytest.mark.parametrize("changes, message", [
    ({"filter__particels": 10}, r"unknown key 'particels'; valid keys: .*particles"),
    ({"filter__kind": "kalman"}, r"kind 'kalman' is not one of pf, apf, ukf, ukf-sum, map"),
    ({"prior__kind": "hmm"}, r"\[prior\] kind 'hmm'"),
    ({"prior__train": []}, r"train must be a non-empty list"),
    ({"prior__options": {"spaces": "angles"}}, r"options \(diffusion-local\): unknown key 'spaces'; valid keys: space"),
    ({"observation__sigma": 3.0}, r"\[observation\]: unknown key 'sigma'; valid keys: one_camera_sigma_px, robust_nu, sigma_px"),
])
def test_mistyped_keys_list_the_valid_ones(changes, message):
    with pytest.raises(PriortrackError, match=message):
        parse_preset(table(**changes), "bad")


@pytest.mark.parametrize("key", ["swaps", "reacquire", "branches"])
def test_the_unscented_filters_switches_must_be_booleans(key):
    """The unscented filter's swap test, joint re-acquisition and depth-branch repair are switched by true/false in
    [filter]; a quoted word is refused, naming the key, and the valid keys list them."""
    unscented = table(prior__kind="lie", prior__options={})
    unscented["filter"] = {"kind": "ukf", key: "no"}
    with pytest.raises(PriortrackError, match=rf"\[filter\]: {key} = 'no' must be true or false"):
        parse_preset(unscented, "bad")
    unscented["filter"] = {"kind": "ukf", "swap": False}
    with pytest.raises(PriortrackError, match=r"unknown key 'swap'; valid keys: .*branches.*reacquire, swaps"):
        parse_preset(unscented, "bad")
    unscented["filter"] = {"kind": "ukf", key: False}
    assert parse_preset(unscented, "ok").filter_options[key] is False


def test_unknown_top_level_key_and_missing_section():
    t = table()
    t["filtre"] = {}
    with pytest.raises(PriortrackError, match="unknown key 'filtre'"):
        parse_preset(t, "bad")
    with pytest.raises(PriortrackError, match=r"a \[prior\] table is required"):
        parse_preset({"filter": {"kind": "pf"}}, "bad")


def test_a_filter_that_cannot_run_the_prior_says_so():
    with pytest.raises(PriortrackError, match="filter 'map' cannot run a 'lie' prior; it runs gpdm, bgpdm"):
        parse_preset(table(filter__kind="map", prior__kind="lie", prior__options={}), "bad")
    unscented = table(prior__kind="lie", prior__options={})
    unscented["filter"] = {"kind": "ukf"}
    assert parse_preset(unscented, "ok").prior_kind == "lie"           # the moment-matched Lie transition


def test_gpdm_dynamics_annealing_is_checked_and_kept_out_of_the_cache_key():
    gpdm = {"prior__kind": "bgpdm", "prior__options": {"d": 3}}
    annealed = parse_preset(table(**gpdm, prior__annealing=0.01), "ok")
    assert annealed.annealing == 0.01 and annealed.cache_key == parse_preset(table(**gpdm), "ok").cache_key
    assert load_preset("pf-gpdm").annealing < 1 and load_preset("map-gpdm").annealing == 1
    with pytest.raises(PriortrackError, match=r"annealing must be a number in \(0, 1\], got 2"):
        parse_preset(table(**gpdm, prior__annealing=2), "bad")
    with pytest.raises(PriortrackError, match="the GPDM's dynamics annealing"):
        parse_preset(table(prior__annealing=0.5), "bad")                       # a diffusion prior
    with pytest.raises(PriortrackError, match=r"MAP tracker takes its own \[filter\] annealing"):
        parse_preset({**table(**gpdm, prior__annealing=0.5), "filter": {"kind": "map"}}, "bad")


def test_not_toml_and_unknown_name(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[filter\nkind = 'pf'")
    with pytest.raises(PriortrackError, match="not valid TOML"):
        load_preset(bad)
    with pytest.raises(PriortrackError, match="no preset 'pf-nothing'.*pf-diffusion-local"):
        load_preset("pf-nothing")


def test_a_second_run_reads_the_cache_and_predicts_identically(tmp_path, monkeypatch):
    preset = parse_preset(table(), "small")
    first = preset.prior(cache=tmp_path)
    assert len(list(tmp_path.glob("diffusion-local-*.npz"))) == 1

    def no_refit(*args, **kwargs):
        raise AssertionError("refitted although the prior is cached")

    monkeypatch.setattr(presets_module, "fit_prior", no_refit)
    second = preset.prior(cache=tmp_path)
    x = first.encode(preset.training_motions[0])[:5]
    g = torch.Generator().manual_seed(0), torch.Generator().manual_seed(0)
    assert torch.equal(first.sample(x, g[0]), second.sample(x, g[1]))
    other = parse_preset(table(prior__train=["walkjog:35_03"]), "small")
    assert other.cache_key != preset.cache_key                        # other training data, other entry


def test_a_cache_that_cannot_be_written_is_a_warning_not_an_error(tmp_path, caplog):
    blocked = tmp_path / "a-file"
    blocked.write_text("not a folder")
    prior = parse_preset(table(), "small").prior(cache=blocked / "priors")     # mkdir fails under a file
    assert prior.kind == "diffusion-local" and blocked.read_text() == "not a folder"
    assert "prior not cached" in caplog.text


def test_build_gives_the_named_filter_with_its_parameters(tmp_path):
    from priortrack.observation import default_camera

    preset = parse_preset(table(), "small")
    motion = preset.training_motions[0]
    filt = preset.build(default_camera(joint_positions(motion, "eval15")), seed=3, cache=tmp_path)
    assert type(filt).__name__ == "ParticleFilter" and filt.P == 50
    assert np.isclose(filt.model.likelihood.sigma_px, 10.0)


def test_one_camera_takes_its_own_sigma_where_the_preset_gives_one(tmp_path):
    """[observation] one_camera_sigma_px: the single-camera likelihood (the lab bench, one camera's detections)
    weighs with it, a recording from two cameras or more with sigma_px; without it both are sigma_px; a value
    that is no positive number is refused by name. The shipped guided particle presets: 5 px with several
    cameras, 10 px with one; the real 4-camera trial's model takes 5 px."""
    from priortrack.data.calibration import Calibration, read_calibration
    from priortrack.data.bundled import POSE2SIM_DIR
    from priortrack.data.detections import read_detections
    from priortrack.observation import default_camera
    from priortrack.tracking.person import TrackConfig, prepared

    preset = parse_preset(table(observation__sigma_px=5.0, observation__one_camera_sigma_px=12.0), "small")
    assert preset.observation == {"sigma_px": 5.0} and preset.one_camera_sigma_px == 12.0
    assert preset.observation_for(1) == {"sigma_px": 12.0} and preset.observation_for(4) == {"sigma_px": 5.0}
    filt = preset.build(default_camera(joint_positions(preset.training_motions[0], "eval15")), cache=tmp_path)
    assert filt.model.likelihood.sigma_px == 12.0
    plain = parse_preset(table(), "small")
    assert plain.observation_for(1) == plain.observation_for(3) == {"sigma_px": 10.0}
    for bad in (0.0, -3.0, "10", float("nan")):
        with pytest.raises(PriortrackError, match="one_camera_sigma_px"):
            parse_preset(table(observation__one_camera_sigma_px=bad), "bad")
    for name in ("pf-lie", "pf-lie-defensive", "pf-diffusion-local"):
        shipped = load_preset(name)
        assert shipped.observation_for(4)["sigma_px"] == 5.0 and shipped.observation_for(1)["sigma_px"] == 10.0
    detections = read_detections(POSE2SIM_DIR / "pose", keypoints="body25b")
    calibration = read_calibration(POSE2SIM_DIR / "Calib.toml")
    four = prepared(detections, calibration, "pf-lie-defensive", TrackConfig(fps=60))
    assert four.model.likelihood.sigma_px == 5.0
    one = prepared(replace(detections, keypoints=detections.keypoints[1:2], camera_names=detections.camera_names[1:2]),
                   Calibration(calibration.cameras[1:2], "z", "one"), "pf-lie-defensive", TrackConfig(fps=60, height=1.75))
    assert one.model.likelihood.sigma_px == 10.0


def test_a_preset_can_name_a_fitted_prior_file(tmp_path):
    """`[prior] file` (relative to the preset's folder): the kind and frame rate come from the file,
    nothing is fitted, and fitting keys or a wrong kind are refused by name."""
    fitted = parse_preset(table(), "small").prior(cache=tmp_path / "cache")
    fitted.save(tmp_path / "walk.npz")
    preset_file = tmp_path / "mine.toml"
    preset_file.write_text('[filter]\nkind = "pf"\nparticles = 20\n\n'
                           '[prior]\nfile = "walk.npz"\ntrain = ["walkjog:35_01"]\n')
    preset = load_preset(preset_file)
    assert preset.prior_kind == "diffusion-local" and preset.prior_file == tmp_path / "walk.npz"
    x = fitted.encode(preset.training_motions[0])[:4]
    loaded = preset.prior(cache=tmp_path / "empty")
    assert torch.equal(loaded.mean(x), fitted.mean(x)) and not (tmp_path / "empty").exists()
    file_table = {"filter": {"kind": "pf"}, "prior": {"file": "walk.npz", "train": ["walkjog:35_01"]}}
    with pytest.raises(PriortrackError, match=r"\[prior\] kind 'lie', but its file .*walk.npz holds a 'diffusion-local'"):
        parse_preset({**file_table, "prior": {**file_table["prior"], "kind": "lie"}}, "bad", folder=tmp_path)
    with pytest.raises(PriortrackError, match="options is for fitting one and cannot go with it"):
        parse_preset({**file_table, "prior": {**file_table["prior"], "options": {}}}, "bad", folder=tmp_path)
    with pytest.raises(PriortrackError, match=r"\[prior\] file .*nothing.npz does not exist"):
        parse_preset({**file_table, "prior": {**file_table["prior"], "file": "nothing.npz"}}, "bad", folder=tmp_path)
    with pytest.raises(PriortrackError, match="filter 'map' cannot run"):
        lie = parse_preset(table(prior__kind="lie", prior__train=["walkjog:35_0[1-4]"],
                                 prior__options={"max_components": 2}), "l").prior(tmp_path / "c")
        lie.save(tmp_path / "lie.npz")
        parse_preset({"filter": {"kind": "map"}, "prior": {"file": "lie.npz", "train": ["walkjog:35_01"]}}, "bad",
                     folder=tmp_path)


def test_the_registry_is_the_one_list_of_kinds():
    from priortrack.priors.registry import PRIOR_KINDS, kinds_with, prior_kind

    assert list(PRIOR_KINDS) == ["diffusion-global", "diffusion-local", "gpdm", "bgpdm", "lie"]
    assert kinds_with("latent") == ("gpdm", "bgpdm") and "lie" in kinds_with("gaussian")
    assert set(prior_kind("bgpdm").options()) == {"d", "seed", "dynamics_noise_floor"}
    with pytest.raises(PriortrackError, match="unknown prior kind 'hmm'; kinds: diffusion-global"):
        prior_kind("hmm")


@pytest.mark.parametrize("changes, message", [
    ({"filter__particles": True}, r"particles = True must be a whole number"),
    ({"filter__particles": "1000"}, r"particles = '1000' must be a whole number"),
    ({"filter__particles": 10 ** 12}, r"must be a whole number up to 10,000,000"),
    ({"filter__ess_threshold": "half"}, r"ess_threshold = 'half' must be a finite number"),
    ({"filter__ess_threshold": float("nan")}, r"ess_threshold = nan must be a finite number"),
    ({"filter__dtype": 32}, r"dtype = 32 must be text"),
    ({"observation__sigma_px": "10"}, r"sigma_px = '10' must be a finite number"),
    ({"observation__robust_nu": False}, r"robust_nu = False must be a finite number"),
])
def test_preset_values_are_checked_for_type_and_range_before_any_fit(changes, message):
    with pytest.raises(PriortrackError, match=message):
        parse_preset(table(**changes), "bad")


def test_the_cache_verifies_what_it_loads(tmp_path, caplog):
    """A cached prior is used only if it matches the digest written beside it and is not a link; a
    corrupted, replaced or linked file is refitted (logged). The key follows the training data's content."""
    preset = parse_preset(table(), "small")
    first = preset.prior(cache=tmp_path)
    (cached,) = tmp_path.glob("diffusion-local-*.npz")
    assert cached.with_suffix(".sha256").read_text().strip() and not list(tmp_path.glob("*.partial*"))
    other = parse_preset(table(prior__options={"space": "directions"}), "small").prior(cache=tmp_path)
    other_file = next(p for p in tmp_path.glob("diffusion-local-*.npz") if p != cached)
    cached.unlink()
    cached.write_bytes(other_file.read_bytes())                      # a planted file
    refit = preset.prior(cache=tmp_path)
    assert "does not match its digest" in caplog.text and refit.state_dim == first.state_dim != other.state_dim
    cached.unlink()
    cached.symlink_to(other_file)
    caplog.clear()
    assert preset.prior(cache=tmp_path).state_dim == first.state_dim and "is a link" in caplog.text
