"""Tests for priortrack.observation.synthetic."""

import json

import numpy as np
import pytest

from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera
from priortrack.observation import (
    PAPER_OBSERVED,
    SCENARIOS,
    Observations,
    default_camera,
    parse_scenario,
    synthesize,
)
from priortrack.observation.synthetic import EVAL15_NAMES

FPS = 30.0

# A standing stick figure, eval15 order, metres, world Y-up, facing +x.
REST = np.array(
    [
        [0.00, 0.95, 0.00],  # pelvis
        [0.00, 1.45, 0.00],  # neck
        [0.00, 1.65, 0.00],  # head
        [0.00, 1.42, 0.18],  # lshoulder
        [0.00, 1.15, 0.20],  # lelbow
        [0.00, 0.90, 0.20],  # lwrist
        [0.00, 1.42, -0.18],  # rshoulder
        [0.00, 1.15, -0.20],  # relbow
        [0.00, 0.90, -0.20],  # rwrist
        [0.00, 0.92, 0.10],  # lhip
        [0.00, 0.50, 0.10],  # lknee
        [0.00, 0.08, 0.10],  # lankle
        [0.00, 0.92, -0.10],  # rhip
        [0.00, 0.50, -0.10],  # rknee
        [0.00, 0.08, -0.10],  # rankle
    ]
)


def walker(T=120, fps=FPS, speed=1.3):
    """A walking-like trajectory (T, 15, 3): translation along x plus limb swing."""
    t = np.arange(T) / fps
    phase = 2 * np.pi * t / 1.1  # ~1.1 s gait cycle
    pos = np.repeat(REST[None], T, axis=0)
    pos[:, :, 0] += speed * t[:, None]
    swing = 0.25 * np.sin(phase)
    for j, sign, scale in ((10, 1, 0.5), (11, 1, 1.0), (13, -1, 0.5), (14, -1, 1.0), (5, -1, 0.6), (8, 1, 0.6)):
        pos[:, j, 0] += sign * scale * swing
    pos[:, :, 1] += 0.02 * np.cos(2 * phase)[:, None]
    return pos


@pytest.fixture(scope="module")
def pos():
    return walker()


@pytest.fixture(scope="module")
def cam(pos):
    return default_camera(pos)


OBS_IDX = [EVAL15_NAMES.index(n) for n in PAPER_OBSERVED]
UNOBS_IDX = [j for j in range(15) if j not in OBS_IDX]


def test_eval15_and_paper_joints():
    assert len(EVAL15_NAMES) == 15 and EVAL15_NAMES[0] == "pelvis" and EVAL15_NAMES[14] == "rankle"
    assert len(PAPER_OBSERVED) == 8 and set(PAPER_OBSERVED) <= set(EVAL15_NAMES)


def test_default_camera_keeps_walk_in_view():
    long_walk = walker(T=300)  # 13 m along x
    cam = default_camera(long_walk)
    uv, front = cam.project(long_walk)
    assert front.all()
    assert uv.min() >= 100 - 1e-6 and uv.max() <= 900 + 1e-6
    assert (cam.width, cam.height, cam.fx) == (1000, 1000, 1000.0)
    c = cam.center.numpy()
    box_c = (long_walk.reshape(-1, 3).min(0) + long_walk.reshape(-1, 3).max(0)) / 2
    assert c[1] == pytest.approx(1.5) and c[2] > box_c[2] + 5.0 - 1e-9  # at +z, >= 5 m away
    # a short clip: exactly 5 m from the box centre
    short = walker(T=10)
    c_short = default_camera(short).center.numpy()
    box_s = (short.reshape(-1, 3).min(0) + short.reshape(-1, 3).max(0)) / 2
    assert c_short[2] - box_s[2] == pytest.approx(5.0)


def test_clean_is_projection_of_observed_joints(pos, cam):
    obs = synthesize(pos, FPS, cam)
    uv_ref, _ = cam.project(pos)
    np.testing.assert_array_equal(obs.uv[:, OBS_IDX], uv_ref[:, OBS_IDX])
    assert np.isnan(obs.uv[:, UNOBS_IDX]).all()
    assert obs.uv.shape == (120, 15, 2) and obs.uv.dtype == np.float64
    assert obs.missing.shape == (120, 15)
    assert obs.missing[:, UNOBS_IDX].all() and not obs.missing[:, OBS_IDX].any()
    assert obs.joints == PAPER_OBSERVED and obs.scenario == "clean" and obs.seed == 0 and obs.fps == FPS


def test_camera_none_uses_default(pos, cam):
    np.testing.assert_array_equal(synthesize(pos, FPS, None).uv, synthesize(pos, FPS, cam).uv)


def test_deterministic_for_seed(pos, cam):
    for scenario in ("noise", "dropout", "outliers"):
        a = synthesize(pos, FPS, cam, scenario, seed=7)
        b = synthesize(pos, FPS, cam, scenario, seed=7)
        c = synthesize(pos, FPS, cam, scenario, seed=8)
        np.testing.assert_array_equal(a.uv, b.uv)
        assert not np.array_equal(a.uv, c.uv, equal_nan=True)
    g1 = synthesize(pos, FPS, cam, "noise", seed=np.random.default_rng(3))
    g2 = synthesize(pos, FPS, cam, "noise", seed=np.random.default_rng(3))
    np.testing.assert_array_equal(g1.uv, g2.uv)
    assert g1.seed is None


@pytest.mark.parametrize("sigma", [2.0, 5.0, 10.0])
def test_noise_sigma(sigma):
    pos = walker(T=300)  # 300 frames x 8 joints x 2 coords = 4800 entries
    cam = default_camera(pos)
    clean = synthesize(pos, FPS, cam, "clean")
    noisy = synthesize(pos, FPS, cam, "noise", seed=1, sigma_px=sigma)
    diff = (noisy.uv - clean.uv)[:, OBS_IDX].ravel()
    assert diff.size == 4800 and np.isfinite(diff).all()
    assert abs(diff.std() / sigma - 1.0) < 0.05
    assert abs(diff.mean()) < 4 * sigma / np.sqrt(diff.size)
    assert np.isnan(noisy.uv[:, UNOBS_IDX]).all()


def test_noise_default_and_clean_sigma(pos, cam):
    assert SCENARIOS["noise"].defaults["sigma_px"] == 5.0
    assert synthesize(pos, FPS, cam, "noise").params["sigma_px"] == 5.0
    assert synthesize(pos, FPS, cam, "clean").params == {"sigma_px": 0.0}
    noisy_clean = synthesize(pos, FPS, cam, "clean", sigma_px=1.0)
    assert not np.array_equal(noisy_clean.uv[:, OBS_IDX], synthesize(pos, FPS, cam).uv[:, OBS_IDX])


def test_dropout_missing_fraction():
    pos = walker(T=3000)
    cam = default_camera(pos)
    rate, lo, hi = 0.5, 3, 15
    # stationary Poisson process of span starts: P(missing) = 1 - exp(-rate * E[len] / fps)
    expected = 1.0 - np.exp(-rate * (lo + hi) / 2 / FPS)
    fractions = []
    for seed in range(8):  # the mean of 8 has a standard error of about 0.0024
        obs = synthesize(pos, FPS, cam, "dropout", seed=seed)
        fractions.append(obs.missing[:, OBS_IDX].mean())
        assert np.isnan(obs.uv[:, UNOBS_IDX]).all()
        # missing spans of each joint are at least min_frames long (unless cut by the clip)
        m = obs.missing[:, OBS_IDX[0]].astype(int)
        edges = np.flatnonzero(np.diff(np.r_[0, m, 0]))
        lengths = edges[1::2] - edges[::2]
        inner = (edges[::2] > 0) & (edges[1::2] < len(m))
        assert (lengths[inner] >= lo).all()
    assert expected == pytest.approx(0.1393, abs=1e-4)
    assert np.mean(fractions) == pytest.approx(expected, abs=0.01)
    # a higher rate drops more
    more = synthesize(pos, FPS, cam, "dropout", seed=0, rate_per_s=2.0).missing[:, OBS_IDX].mean()
    assert more == pytest.approx(1 - np.exp(-2.0 * 9 / FPS), abs=0.04)
    none = synthesize(pos, FPS, cam, "dropout", seed=0, rate_per_s=0.0)
    assert not none.missing[:, OBS_IDX].any()


def test_occlusion_interval(pos, cam):
    clean = synthesize(pos, FPS, cam)
    obs = synthesize(pos, FPS, cam, "occlusion")
    # default start: a third of the 4 s clip = frame 40; 1.0 s = 30 frames -> frames 40..69
    assert obs.params["start_s"] == pytest.approx(4.0 / 3.0) and obs.params["length_s"] == 1.0
    head = EVAL15_NAMES.index("head")
    others = [j for j in OBS_IDX if j != head]
    expected_missing = np.zeros((120, 15), bool)
    expected_missing[:, UNOBS_IDX] = True
    expected_missing[40:70, others] = True
    np.testing.assert_array_equal(obs.missing, expected_missing)
    np.testing.assert_array_equal(obs.uv[~expected_missing], clean.uv[~expected_missing])
    # explicit interval, clipped at the end of the clip
    late = synthesize(pos, FPS, cam, "occlusion", start_s=3.5, length_s=2.0)
    assert late.missing[105:, others].all() and not late.missing[:105, others].any()
    assert not late.missing[:, head].any()


def test_blackout_interval(pos, cam):
    obs = synthesize(pos, FPS, cam, "blackout")
    # frames 40 .. 40 + round(1.1 * 30) - 1 = 72
    expected = np.zeros(120, bool)
    expected[40:73] = True
    np.testing.assert_array_equal(obs.missing.all(axis=1), expected)
    assert not obs.missing[~expected][:, OBS_IDX].any()
    obs2 = synthesize(pos, FPS, cam, "blackout", start_s=0.5, length_s=0.5)
    assert obs2.missing[15:30].all() and not obs2.missing[:15, OBS_IDX].any()
    assert not obs2.missing[30:, OBS_IDX].any()


def test_outliers_fraction_and_distance():
    pos = walker(T=600)
    cam = default_camera(pos)
    clean = synthesize(pos, FPS, cam)
    frac, lo, hi = 0.1, 100.0, 300.0
    obs = synthesize(pos, FPS, cam, "outliers", seed=5, fraction=frac, min_px=lo, max_px=hi)
    dist = np.linalg.norm(obs.uv - clean.uv, axis=-1)[:, OBS_IDX]  # (T, 8)
    displaced = dist > 0
    n = dist.size
    se = np.sqrt(frac * (1 - frac) / n)
    assert abs(displaced.mean() - frac) < 3 * se
    assert (dist[displaced] >= lo - 1e-9).all() and (dist[displaced] <= hi + 1e-9).all()
    assert dist[displaced].min() < lo + 20 and dist[displaced].max() > hi - 20  # spans the range
    assert np.isnan(obs.uv[:, UNOBS_IDX]).all()
    everything = synthesize(pos, FPS, cam, "outliers", seed=5, fraction=1.0)
    assert (np.linalg.norm(everything.uv - clean.uv, axis=-1)[:, OBS_IDX] >= 100 - 1e-9).all()


def test_custom_joints_and_behind_camera(pos):
    cam = PinholeCamera.look_at((0.5, 1.0, 5.0), (0.5, 1.0, 0.0))
    shifted = pos.copy()
    shifted[:, :, 2] += np.where(np.arange(120) < 60, 0.0, 10.0)[:, None]  # second half behind camera
    obs = synthesize(shifted, FPS, cam, joints=["pelvis", "head"])
    assert obs.joints == ("pelvis", "head")
    assert not obs.missing[:60, [0, 2]].any() and obs.missing[60:].all()
    assert obs.missing[:, 1].all() and obs.missing[:, 3:].all()


def test_save_load_round_trip(tmp_path, pos, cam):
    obs = synthesize(pos, FPS, cam, "dropout", seed=3, rate_per_s=1.0)
    assert np.isnan(obs.uv[:, OBS_IDX]).any()
    path = tmp_path / "obs.npz"
    obs.save(path)
    back = Observations.load(path)
    np.testing.assert_array_equal(back.uv, obs.uv)  # NaN in the same places
    assert back.joints == obs.joints and back.scenario == "dropout" and back.seed == 3
    assert back.params == obs.params and back.fps == FPS
    assert back.camera == cam
    # written exactly where asked (no .npz appended)
    odd = tmp_path / "obs.data"
    obs.save(odd)
    assert odd.exists() and Observations.load(odd).uv.shape == (120, 15, 2)


def _rewrite(path, out, drop=None, meta_update=None, drop_meta=None):
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["metadata"][()]))
    if meta_update:
        meta.update(meta_update)
    if drop_meta:
        del meta[drop_meta]
    arrays["metadata"] = np.array(json.dumps(meta))
    if drop:
        del arrays[drop]
    with open(out, "wb") as fh:
        np.savez(fh, **arrays)


def test_load_errors(tmp_path, pos, cam):
    path = tmp_path / "obs.npz"
    synthesize(pos, FPS, cam).save(path)
    bad = tmp_path / "bad_version.npz"
    _rewrite(path, bad, meta_update={"format_version": 2})
    with pytest.raises(PriortrackError, match=r"bad_version\.npz.*format_version"):
        Observations.load(bad)
    no_uv = tmp_path / "no_uv.npz"
    _rewrite(path, no_uv, drop="uv")
    with pytest.raises(PriortrackError, match=r"no_uv\.npz.*'uv'"):
        Observations.load(no_uv)
    no_cam = tmp_path / "no_cam.npz"
    _rewrite(path, no_cam, drop_meta="camera")
    with pytest.raises(PriortrackError, match=r"no_cam\.npz.*'camera'"):
        Observations.load(no_cam)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(PriortrackError, match="junk"):
        Observations.load(junk)


def test_synthesize_errors(pos, cam):
    with pytest.raises(PriortrackError, match=r"unknown scenario 'fog'.*clean.*outliers"):
        synthesize(pos, FPS, cam, "fog")
    with pytest.raises(PriortrackError, match=r"'sigma'.*sigma_px"):
        synthesize(pos, FPS, cam, "noise", sigma=3.0)
    with pytest.raises(PriortrackError, match="'fraction'.*valid parameters: sigma_px"):
        synthesize(pos, FPS, cam, "noise", fraction=0.5)
    with pytest.raises(PriortrackError, match="sigma_px"):
        synthesize(pos, FPS, cam, "noise", sigma_px=-1.0)
    with pytest.raises(PriortrackError, match="fraction"):
        synthesize(pos, FPS, cam, "outliers", fraction=1.5)
    with pytest.raises(PriortrackError, match="length_s"):
        synthesize(pos, FPS, cam, "blackout", length_s=0.0)
    with pytest.raises(PriortrackError, match=r"positions.*\(T, 15, 3\)"):
        synthesize(pos[:, :14], FPS, cam)
    bad = pos.copy()
    bad[5, 3, 1] = np.nan
    with pytest.raises(PriortrackError, match=r"positions.*\(T, 15, 3\)"):
        synthesize(bad, FPS, cam)
    with pytest.raises(PriortrackError, match="joints.*'lhand'"):
        synthesize(pos, FPS, cam, joints=["lhand"])
    with pytest.raises(PriortrackError, match="fps"):
        synthesize(pos, 0.0, cam)
    with pytest.raises(PriortrackError, match="max_frames"):
        synthesize(pos, FPS, cam, "dropout", min_frames=5, max_frames=4)


def test_parse_scenario():
    assert parse_scenario("clean") == ("clean", {})
    assert parse_scenario("noise:sigma_px=2") == ("noise", {"sigma_px": 2.0})
    assert parse_scenario(" dropout: rate_per_s=1.5 , max_frames=20") == (
        "dropout",
        {"rate_per_s": 1.5, "max_frames": 20.0},
    )
    assert parse_scenario("occlusion:start_s=none,length_s=0.5") == ("occlusion", {"start_s": None, "length_s": 0.5})
    with pytest.raises(PriortrackError, match="fog.*valid scenarios"):
        parse_scenario("fog")
    with pytest.raises(PriortrackError, match="'amount'.*fraction"):
        parse_scenario("outliers:amount=0.2")
    with pytest.raises(PriortrackError, match="fraction"):
        parse_scenario("outliers:fraction=2")
    with pytest.raises(PriortrackError, match="sigma_px"):
        parse_scenario("noise:sigma_px=abc")
    with pytest.raises(PriortrackError, match="key=value"):
        parse_scenario("noise:sigma_px")
    with pytest.raises(PriortrackError, match="duplicate"):
        parse_scenario("noise:sigma_px=1,sigma_px=2")


def test_parsed_scenario_feeds_synthesize(pos, cam):
    name, params = parse_scenario("dropout:rate_per_s=1,min_frames=2,max_frames=4")
    obs = synthesize(pos, FPS, cam, name, seed=0, **params)
    assert obs.params["min_frames"] == 2 and obs.params["max_frames"] == 4


def test_observations_validation(cam):
    uv = np.full((4, 15, 2), np.nan)
    uv[:, 0] = 1.0
    Observations(uv, ("pelvis",), "custom", {}, None, 25.0, cam)
    with pytest.raises(PriortrackError, match="joints not in joints"):
        Observations(uv, ("head",), "custom", {}, None, 25.0, cam)
    with pytest.raises(PriortrackError, match=r"uv.*\(T, 15, 2\)"):
        Observations(uv[:, :3], ("pelvis",), "custom", {}, None, 25.0, cam)
