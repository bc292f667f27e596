"""A prior knows its support (issue 19, item 2): ``priortrack eval fit-check`` against frames held out
from the prior's own training data, on held-out walks and on motions unlike walking."""

import json

import numpy as np
import pytest
import torch

from priortrack import PriortrackError
from priortrack.cli.main import main
from priortrack.priors.support import IN_SUPPORT, OUTSIDE, verdict


def _check(capsys, *argv) -> dict:
    assert main(["eval", "fit-check", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("preset, motion, expected", [
    ("pf-lie", "walkjog:35_29", "in support"),       # a held-out walk
    ("pf-lie", "cmu:07_10", "in support"),
    ("pf-lie", "cmu:49_18", "outside"),              # balancing on one leg
    ("pf-lie", "cmu:131_04", "outside"),             # a dance
    ("pf-gpdm", "cmu:07_10", "in support"),
    ("pf-gpdm", "cmu:49_18", "outside"),
    ("pf-gpdm", "cmu:135_06", "outside"),            # martial arts
])
def test_walking_priors_know_a_held_out_walk_and_refuse_a_balance_or_a_dance(preset, motion, expected, capsys):
    result = _check(capsys, preset, motion)
    assert result["verdict"] == expected
    assert len(result["frame_percentiles"]) > 10 and set(result["reference_percentiles"]) >= {"1", "50", "99"}


def test_a_diffusion_prior_models_step_sizes_not_poses(capsys):
    """Local diffusion learned on walks accepts a slow balance: it has no model of the pose."""
    assert _check(capsys, "pf-diffusion-local", "cmu:49_18")["verdict"] == "in support"


def test_a_prior_file_is_checked_against_reference_motions_it_was_not_fitted_on(tmp_path, capsys):
    prior = tmp_path / "walk.npz"
    assert main(["fit", "diffusion-local", "--train", "walkjog:35_01", "--out", str(prior)]) == 0
    capsys.readouterr()
    assert main(["eval", "fit-check", str(prior), "cmu:07_10"]) == 2
    assert "give --reference" in capsys.readouterr().err
    result = _check(capsys, str(prior), "cmu:13_39", "--reference", "walkjog:35_02", "walkjog:35_03")
    assert result["verdict"] in ("in support", "partly", "outside") and result["kind"] == "diffusion-local"


def test_the_verdict_counts_frames_below_the_references_first_percentile():
    reference = np.arange(1000.0)                             # p1 = 9.99
    assert verdict(np.full(10, 500.0), reference)["verdict"] == "in support"
    assert verdict(np.r_[np.full(6, 0.0), np.full(4, 500.0)], reference)["verdict"] == "partly"
    assert verdict(np.r_[np.full(9, 0.0), np.full(1, 500.0)], reference)["verdict"] == "outside"
    assert verdict(np.array([-np.inf, 500.0]), reference)["below_p1_fraction"] == 0.5
    assert 0 < IN_SUPPORT < OUTSIDE < 1
    with pytest.raises(PriortrackError, match="at least two frames"):
        verdict(np.array([]), reference)


def test_the_tracker_says_when_the_tracked_motion_is_outside_the_prior():
    """Real-format input (4 cameras): a held-out walk tracked with pf-lie is in its support. A person
    balancing on one leg is lost by it (150 mm, the arms) and flagged (the mismatch test below); the
    fit-check of that *tracked* motion, which the prior itself shaped, read "partly" (seed 0) and "in
    support" (seed 1) once the walking prior learned from five people, so the motion itself is checked
    here: outside pf-lie's support, and the shipped prior that fits it better is named (issue 31). The
    GPDM's tracked motion is not judged (its pose density is in the training skeleton's angles)."""
    from priortrack.data.load import load_motion
    from priortrack.tracking.presets import load_preset
    from priortrack.tracking.person import better_fitting
    from priortrack.experiments.real_format import run_real_format

    walk = run_real_format("pf-lie", "cmu:07_10", seed=0)
    assert walk["fit_check"] == "in support" and walk["better_prior"] is None
    better, skipped = better_fitting(load_motion("cmu:49_18"), load_preset("pf-lie"), below=1.0, fit=True)
    assert better["preset"] == "pf-lie-general" and better["verdict"] == "in support" and skipped == [], better
    assert better_fitting(load_motion("cmu:49_18"), load_preset("pf-lie"), below=0.0) == (None, [])  # none fits better
    assert run_real_format("pf-gpdm", "cmu:07_10", seed=0)["fit_check"] is None


def test_a_tracking_run_does_not_fit_an_alternative_prior_it_can_only_name(tmp_path, monkeypatch):
    """issue 60, item 1: a run's fit-check compares the tracked motion only with alternatives whose prior and reference
    the cache holds; pf-lie-general's took half an hour after the last tick, before anything was written. With an empty
    cache nothing is fitted (fit_prior is never called) and both alternatives are named as not compared."""
    from priortrack.data.load import load_motion
    import priortrack.priors.support as support
    from priortrack.tracking.person import better_fitting
    from priortrack.tracking.presets import load_preset

    import priortrack.tracking.presets as presets

    for module in (support, presets):
        monkeypatch.setattr(module, "fit_prior", lambda *a, **k: pytest.fail("a run fitted an alternative prior"))
    best, skipped = better_fitting(load_motion("cmu:49_18"), load_preset("ukf-real"), below=1.0, cache=tmp_path)
    assert best is None and skipped == ["pf-lie", "pf-lie-general"]


def test_the_mismatch_flag_needs_the_prior_to_find_the_step_implausible(tmp_path):
    """At 30 fps the likelihood alone flagged 72 % of held-out 35_29 under pf-lie; a mismatch tick
    must now also be a step the Lie prior scores below its held-out 1st percentile, or (issue 31) one
    where the estimate has left the per-tick triangulation by LOST_MM on average (the balance, lost by
    the walking prior at 150 mm, was flagged on 12 % of its ticks without that, 79 % with it). Over three seeds
    (detector noise and filter) the held-out walks' median flagged fraction stays low and a balance's
    high. One run is not enough: a run whose estimate goes astray is flagged at length (35_29, seed 0:
    53 % on one machine, 21 % on another, where the filter's float32 kernels round differently), so
    the medians are compared (measured: 35_29 0.53 / 0.02 / 0.00, 07_10 0.03 / 0.06 / 0.00,
    49_18 0.70 / 0.92 / 0.90)."""
    from priortrack.data.calibration import read_calibration
    from priortrack.data.detections import read_detections
    from priortrack.tracking.person import TrackConfig, track_detections
    from priortrack.experiments.real_format import (DEFAULT_CALIBRATION, detector_keypoints, placed_walk,
                                                   write_openpose)
    from priortrack.geometry.camera import PinholeCamera

    calibration = read_calibration(DEFAULT_CALIBRATION)
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    fractions = {}
    for motion, seconds in (("walkjog:35_29", 1.5), ("cmu:07_10", 1.5), ("cmu:49_18", 3.0)):
        X = placed_walk(motion, calibration.up, fps=30.0, seconds=seconds)
        runs = []
        for seed in range(3):
            folder = write_openpose(detector_keypoints(X, cameras, np.random.default_rng(seed)),
                                    tmp_path / f"{motion.replace(':', '_')}-{seed}")
            result = track_detections(read_detections(folder, keypoints="body25b"), calibration, "pf-lie",
                                      TrackConfig(fps=30.0, seed=seed))
            runs.append(result.mismatch_fraction)
        fractions[motion] = float(np.median(runs))
    assert fractions["walkjog:35_29"] < 0.3 and fractions["cmu:07_10"] < 0.3, fractions
    assert fractions["cmu:49_18"] > 0.6, fractions


def test_the_reference_is_cached_and_verified_like_the_priors(tmp_path, caplog):
    """The held-out reference goes through the prior cache's digest check: a planted file is refitted."""
    from priortrack.tracking.presets import load_preset
    from priortrack.priors.support import reference

    preset = load_preset("pf-diffusion-local")
    first = reference(preset, cache=tmp_path)
    (stored,) = tmp_path.glob("support*.npz")
    assert stored.with_suffix(".sha256").is_file()
    np.savez(stored, values=np.zeros(3))
    again = reference(preset, cache=tmp_path)
    assert "does not match its digest" in caplog.text
    np.testing.assert_array_equal(again, first)


def test_the_printed_verdict_gives_its_rule_beside_its_share(capsys):
    """Issue 28: "partly" printed beside "84% of its frames below" read as a contradiction; the line now
    says where the verdicts part, and the share it prints gets the verdict that rule gives."""
    import re

    assert main(["eval", "fit-check", "pf-lie", "cmu:49_18"]) == 0
    line = capsys.readouterr().out
    share = float(re.search(r"(\d+)% of its frames score below", line).group(1)) / 100
    word = "in support" if share < IN_SUPPORT else "outside" if share > OUTSIDE else "partly"
    assert f": {word}." in line and f"'outside' over {100 * OUTSIDE:.0f}%" in line


def test_frame_log_density_scored_in_pieces_is_the_same(monkeypatch):
    """ℓ_t is scored FRAMES_AT_ONCE transitions at a time (a long run's memory): 7 at a time gives every
    frame's value of one piece, for the Lie mixture and the local diffusion."""
    from priortrack.data.bundled import load_walkjog
    from priortrack.priors import support
    from priortrack.priors.diffusion import Diffusion
    from priortrack.priors.lie import LiePrior

    walks = list(load_walkjog().walks("train"))
    held_out = next(iter(load_walkjog().walks("test")))
    for prior in (LiePrior.fit(walks[:3], seed=0), Diffusion.fit(walks[:3], local=True, space="angles")):
        whole = support.frame_log_density(prior, held_out)
        monkeypatch.setattr(support, "FRAMES_AT_ONCE", 7)
        pieces = support.frame_log_density(prior, held_out)
        monkeypatch.setattr(support, "FRAMES_AT_ONCE", 1000)
        assert len(whole) > 50 and np.isfinite(whole).all()
        np.testing.assert_allclose(pieces, whole, rtol=1e-12, atol=1e-9)


def test_bone_directions_encoded_in_blocks_are_each_frames_own(monkeypatch):
    """DirectionSpace.encode works FK_FRAMES frames at a time (a ten-minute run's fit-check): 7 at a time
    gives the directions of the whole clip's joints normalised at once, to the bit."""
    from priortrack.body.fk import joint_positions
    from priortrack.body.normalise import normalise
    from priortrack.data.bundled import load_walkjog
    from priortrack.priors import spaces

    walk = next(iter(load_walkjog().walks("test")))
    whole = normalise(joint_positions(walk, "eval15")).directions.reshape(len(walk), -1)
    monkeypatch.setattr(spaces, "FK_FRAMES", 7)
    x = spaces.DirectionSpace(np.ones(14)).encode(walk)
    assert len(walk) % 7 and x.dtype == torch.float64
    assert torch.equal(x, whole)
