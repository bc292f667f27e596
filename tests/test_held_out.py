"""The held-out ratio (priortrack/tracking/held_out.py): each camera's detections against the estimate and
against the other cameras' triangulation, on the Pose2Sim demo's 4 real cameras, and the flag it raises on a
learned preset that is worse than triangulating (issue 45, item 6)."""

import numpy as np
import pytest

from priortrack.data.calibration import read_calibration
from priortrack.experiments.real_format import DEFAULT_CALIBRATION, placed_walk
from priortrack.geometry.camera import PinholeCamera
from priortrack.tracking.held_out import WINDOW, WORSE_RATIO, held_out_errors, held_out_ratio

CALIBRATION = read_calibration(DEFAULT_CALIBRATION)
CAMERAS = [PinholeCamera.from_calibration(c) for c in CALIBRATION.cameras]


def detections(X: np.ndarray, noise_px: float, rng: np.random.Generator) -> np.ndarray:
    """(T, C, 15, 3) every camera's projection of the joints X (T, 15, 3), with N(0, noise_px²) pixel noise and
    confidence 1."""
    z = np.ones((len(X), len(CAMERAS), 15, 3))
    for c, camera in enumerate(CAMERAS):
        uv, _ = camera.project(X)
        z[:, c, :, :2] = uv + rng.normal(0, noise_px, size=uv.shape)
    return z


def test_noise_free_detections_are_explained_exactly_by_the_truth_and_by_triangulation():
    """Without noise the other cameras' DLT reprojects onto each camera's detection and so does the truth: both
    errors vanish (to rounding); an estimate moved 5 cm has the pixel error of that move, camera by camera."""
    X = placed_walk("cmu:07_10", CALIBRATION.up)[:20]
    z = detections(X, 0.0, np.random.default_rng(0))
    e_E, e_X = held_out_errors(CAMERAS, X, z)
    assert e_E.shape == e_X.shape == (len(CAMERAS), 20, 15)
    assert np.nanmax(e_E) < 1e-6 and np.nanmax(e_X) < 1e-4, (np.nanmax(e_E), np.nanmax(e_X))
    moved = X + np.array([0.05, 0.0, 0.0])
    e_moved, _ = held_out_errors(CAMERAS, moved, z)
    for c, camera in enumerate(CAMERAS):
        expected = np.linalg.norm(camera.project(moved)[0] - camera.project(X)[0], axis=-1)
        np.testing.assert_allclose(e_moved[c], expected, rtol=1e-9, atol=1e-9)


def test_the_truth_is_below_one_and_an_estimate_off_by_a_few_centimetres_is_worse_than_triangulation():
    """With 3 px of detector noise the truth explains each camera better than the others' triangulation (q < 1:
    the triangulation carries the other cameras' noise too); an estimate whose joints are each 40 mm off, in
    random directions, explains it worse by more than WORSE_RATIO; a camera that sees nothing at some ticks
    (NaN, confidence 0) leaves those ticks to the others."""
    rng = np.random.default_rng(1)
    X = placed_walk("cmu:07_10", CALIBRATION.up)
    z = detections(X, 3.0, rng)
    z[10:30, 0] = np.nan
    z[40:60, 1, :, 2] = 0.0
    truth = held_out_ratio(*held_out_errors(CAMERAS, X, z))
    direction = rng.normal(size=X.shape)
    off = X + 0.04 * direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    worse = held_out_ratio(*held_out_errors(CAMERAS, off, z))
    assert np.isfinite(truth).all() and np.isfinite(worse).all()
    assert truth.max() < 1.0 and worse.min() > WORSE_RATIO, (truth.max(), worse.min())


def test_only_the_ticks_where_the_estimate_leaves_the_detections_are_worse():
    """An estimate at the truth but 10 cm off over ticks 40–59: the ratio is over WORSE_RATIO about those ticks
    and under it a window's half-width away from them."""
    rng = np.random.default_rng(2)
    X = placed_walk("cmu:07_10", CALIBRATION.up)
    z = detections(X, 3.0, rng)
    E = X.copy()
    E[40:60] += np.array([0.0, 0.1, 0.0])
    q = held_out_ratio(*held_out_errors(CAMERAS, E, z))
    assert (q[45:55] > WORSE_RATIO).all(), q[45:55]
    far = np.r_[:40 - WINDOW // 2, 60 + WINDOW // 2:len(q)]
    assert (q[far] < 1.0).all(), q[far]


def test_too_few_errors_in_a_window_leave_the_tick_unjudged():
    X = placed_walk("cmu:07_10", CALIBRATION.up)[:40]
    z = detections(X, 3.0, np.random.default_rng(3))
    z[:, :, 1:, 2] = 0.0                                            # one joint seen: 4 cameras × 16–31 ticks
    q = held_out_ratio(*held_out_errors(CAMERAS, X, z))
    assert np.isfinite(q).all()
    z[:, :, :, 2] = 0.0
    z[::8, :, 0, 2] = 1.0                                            # one joint every 8th tick: ≤ 16 errors a window
    assert np.isnan(held_out_ratio(*held_out_errors(CAMERAS, X, z))).all()


@pytest.mark.parametrize("preset, flagged, below", [("pf-gpdm latent", True, None), ("pf-gpdm", False, 1.0),
                                                    ("ukf-real", False, 0.8)])
def test_a_preset_worse_than_triangulation_is_flagged_and_one_better_is_not(preset, flagged, below, monkeypatch):
    """The real-format bench (4 cameras, detector-like errors) on 05_01, a person neither prior was trained on:
    pf-gpdm with its latent state alone (its pose on the manifold of two training walks) at 2.9–4.0× per-frame DLT
    (measured) had 0 % of its ticks flagged before the held-out flag (as with the flag off here) and is flagged on
    nearly every tick; ukf-real at 0.6× on none; pf-gpdm as shipped (the pose in its state with 2+ cameras) at
    0.64–0.70× (one or two torch threads) on none."""
    from dataclasses import replace

    from priortrack.experiments.real_format import run_real_format
    from priortrack.tracking.presets import load_preset
    import priortrack.tracking.person as person

    if preset == "pf-gpdm latent":
        preset = replace(load_preset("pf-gpdm"), pose_state=False)
    run = run_real_format(preset, "cmu:05_01", seed=0)
    ratio = run["mpjpe_where_dlt_mm"] / run["dlt_mm"]
    if flagged:
        assert ratio > 2.0 and run["mismatch_fraction"] > 0.9, (ratio, run["mismatch_fraction"])
        monkeypatch.setattr(person, "WORSE_RATIO", np.inf)
        assert run_real_format(preset, "cmu:05_01", seed=0)["mismatch_fraction"] < 0.1
    else:
        assert ratio < below and run["mismatch_fraction"] < 0.1, (ratio, run["mismatch_fraction"])
