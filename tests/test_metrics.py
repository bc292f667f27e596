"""Tests for priortrack.experiments.metrics."""

import numpy as np
import pytest
import torch

from priortrack.errors import PriortrackError
from priortrack.experiments.metrics import error_2d, mpjpe, mpjpe_root_relative, summarise


@pytest.fixture
def gt():
    return np.random.default_rng(0).normal(size=(10, 15, 3))


def test_mpjpe_known_offset(gt):
    pred = gt + np.array([0.003, 0.004, 0.0])  # 3, 4, 0 mm -> 5 mm
    e = mpjpe(pred, gt)
    assert e.shape == (10,)
    np.testing.assert_allclose(e, 5.0, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(mpjpe(gt, gt), 0.0)
    # one joint off by 15 cm in one frame -> 150 / 15 = 10 mm in that frame only
    pred2 = gt.copy()
    pred2[4, 7, 1] += 0.15
    e2 = mpjpe(pred2, gt)
    assert e2[4] == pytest.approx(10.0, abs=1e-9)
    assert np.count_nonzero(e2) == 1
    # torch inputs work
    np.testing.assert_allclose(mpjpe(torch.from_numpy(pred), torch.from_numpy(gt)), 5.0, atol=1e-9)


def test_root_relative_removes_translation(gt):
    shift = np.random.default_rng(1).normal(size=(10, 1, 3))  # a different translation per frame
    pred = gt + shift
    np.testing.assert_allclose(mpjpe_root_relative(pred, gt), 0.0, atol=1e-9)
    assert mpjpe(pred, gt).min() > 100.0
    # a pelvis-only error appears on the 14 other joints after re-rooting: 14 * 20 mm / 15
    pred = gt.copy()
    pred[:, 0, 0] += 0.02
    np.testing.assert_allclose(mpjpe_root_relative(pred, gt), 14 * 20.0 / 15, atol=1e-9)
    np.testing.assert_allclose(mpjpe(pred, gt), 20.0 / 15, atol=1e-9)


def test_mpjpe_errors(gt):
    with pytest.raises(PriortrackError, match=r"pred, gt.*\(10, 15, 3\).*\(9, 15, 3\)"):
        mpjpe(gt, gt[:9])
    with pytest.raises(PriortrackError, match=r"pred.*\(T, 15, 3\)"):
        mpjpe(gt[:, :14], gt[:, :14])
    bad = gt.copy()
    bad[2, 3, 0] = np.nan
    with pytest.raises(PriortrackError, match="pred.*NaN"):
        mpjpe(bad, gt)
    with pytest.raises(PriortrackError, match="gt.*NaN"):
        mpjpe_root_relative(gt, bad)


def test_error_2d_ignores_missing():
    obs = np.zeros((3, 15, 2))
    pred = np.zeros((3, 15, 2))
    pred[:, :, 0] = 3.0
    pred[:, :, 1] = 4.0  # 5 px everywhere
    pred[0, 1] = [6.0, 8.0]  # 10 px at joint 1 of frame 0
    obs[0, 2:] = np.nan  # frame 0: joints 0 and 1 observed -> (5 + 10) / 2
    obs[1] = np.nan  # frame 1: nothing observed -> NaN
    obs[2, 0, 1] = np.nan  # a half-NaN entry counts as missing
    pred[1, 3] = np.nan  # predictions at unobserved entries may be NaN
    e = error_2d(pred, obs)
    assert e.shape == (3,)
    assert e[0] == pytest.approx(7.5)
    assert np.isnan(e[1])
    assert e[2] == pytest.approx(5.0)


def test_error_2d_errors():
    with pytest.raises(PriortrackError, match=r"pred_uv, obs_uv.*\(2, 15, 2\).*\(3, 15, 2\)"):
        error_2d(np.zeros((2, 15, 2)), np.zeros((3, 15, 2)))
    with pytest.raises(PriortrackError, match=r"pred_uv.*\(T, J, 2\).*\(2, 15, 3\)"):
        error_2d(np.zeros((2, 15, 3)), np.zeros((2, 15, 2)))
    with pytest.raises(PriortrackError, match=r"obs_uv.*\(T, J, 2\).*\(15, 2\)"):
        error_2d(np.zeros((2, 15, 2)), np.zeros((15, 2)))
    pred = np.zeros((2, 15, 2))
    pred[1, 4, 0] = np.nan
    with pytest.raises(PriortrackError, match="pred_uv.*frame 1"):
        error_2d(pred, np.zeros((2, 15, 2)))


def test_summarise():
    s = summarise(np.array([1.0, 2.0, np.nan, 3.0, 10.0, np.nan]))
    assert s["frames"] == 4 and s["frames_without_data"] == 2
    assert s["mean"] == pytest.approx(4.0)
    assert s["median"] == pytest.approx(2.5)
    assert s["max"] == pytest.approx(10.0)
    assert s["std"] == pytest.approx(np.sqrt((9 + 4 + 1 + 36) / 4))
    assert all(isinstance(s[k], float) for k in ("mean", "median", "max", "std"))
    empty = summarise(np.full(3, np.nan))
    assert empty["frames"] == 0 and empty["frames_without_data"] == 3 and np.isnan(empty["mean"])
    with pytest.raises(PriortrackError, match=r"per_frame.*\(T,\)"):
        summarise(np.zeros((2, 2)))


def test_a_table_cells_mean_and_sample_std():
    from priortrack.experiments.metrics import mean_std

    assert mean_std([1.0, 2.0, 3.0]) == (2.0, 1.0)
    assert mean_std([4.0, None, float("nan")]) == (4.0, 0.0)
    mean, std = mean_std([None])
    assert np.isnan(mean) and np.isnan(std)
