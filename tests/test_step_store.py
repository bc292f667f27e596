"""The whole-run smoother's steps within a memory budget: held, spilled to disk past it, read back equal;
smoothing through spilled steps gives the same numbers as through steps in memory; the unscented
smoother's own per-frame matrices likewise (RecordArray)."""

import logging
from pathlib import Path

import numpy as np
import pytest
import torch

from priortrack import PriortrackError
from priortrack.cli.main import main
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.calibration import read_calibration
from priortrack.data.detections import read_detections
from priortrack.tracking.person import TrackConfig, track_detections
from priortrack.filters import particle
from priortrack.filters.snapshot import Snapshot
from priortrack.filters.step_store import Column, RecordArray, StepStore, parse_memory, step_bytes


def _step(frame: int, resampled: bool, rng) -> Snapshot:
    P = 50
    return Snapshot(frame, torch.as_tensor(rng.normal(size=(P, 8)), dtype=torch.float32),
                    torch.softmax(torch.as_tensor(rng.normal(size=P)), 0), 30.0,
                    torch.as_tensor(rng.integers(0, P, P)) if resampled else None, np.zeros((15, 3)),
                    np.zeros((15, 3)), torch.zeros(P, 15, 3), ["no-observation"] if frame == 3 else [],
                    translation_covariance=torch.as_tensor(rng.normal(size=(P, 6, 6))))


def test_parse_memory():
    assert parse_memory("2GB") == 2 * 1024 ** 3 and parse_memory("500mb") == 500 * 1024 ** 2
    assert parse_memory("1.5G") == int(1.5 * 1024 ** 3) and parse_memory("4096") == 4096 and parse_memory("0") == 0
    for bad in ("", "GB", "-1GB", "2TB", "lots", "nan", "1e30"):
        with pytest.raises(PriortrackError, match="--memory"):
            parse_memory(bad)


def test_steps_past_the_budget_are_spilled_and_read_back_equal():
    rng = np.random.default_rng(0)
    steps = [_step(t, t % 2 == 0, rng) for t in range(6)]
    size = step_bytes(steps[1].for_smoothing())                 # a step without ancestors
    assert size == 50 * 8 * 4 + 50 * 8 + 50 * 36 * 8            # particles, weights, covariances; no joints
    store = StepStore(memory=2 * size + 50 * 8)                 # the first two steps (one with ancestors) fit
    for step in steps:
        store.append(step)
    assert len(store) == 6 and store.spilled == 4 and store.held == 2 * size + 50 * 8
    folder = Path(store._directory.name)
    assert len(list(folder.glob("*.npy"))) == 4 * 3 + 2         # 3 arrays a step, ancestors where resampled
    for t, step in enumerate(steps):
        back = store[t]
        assert back.frame == t and back.flags == step.flags and back.joints is None
        for name in ("particles", "weights", "ancestors", "translation_covariance"):
            a, b = getattr(step, name), getattr(back, name)
            assert (a is None and b is None) or (torch.equal(a, b) and a.dtype == b.dtype)
            c = store.array(t, name)
            assert (a is None and c is None) or torch.equal(a, c)
        assert store.array(t, "flags") == step.flags                  # a field kept in memory, spilled step or not
    log_weights = Column(store, "weights", torch.log)
    assert len(log_weights) == 6 and torch.equal(log_weights[-1], torch.log(steps[5].weights))
    assert [s.frame for s in store[1:4]] == [1, 2, 3]
    store.truncate(3)
    assert len(store) == 3 and store.spilled == 1 and len(list(folder.glob("*.npy"))) == 4   # step 2 resampled
    store.close()
    assert not folder.exists() and len(store) == 0
    with pytest.raises(PriortrackError, match="≥ 0 bytes"):
        StepStore(memory=-1)


@pytest.fixture(scope="module")
def trial():
    return read_detections(str(POSE2SIM_DIR / "pose"), keypoints="body25b"), read_calibration(str(POSE2SIM_DIR / "Calib.toml"))


def test_smoothing_through_spilled_steps_gives_the_same_numbers(trial, caplog, monkeypatch):
    """pf-diffusion-local over the bundled real trial, smoothed over the whole run: every step spilled
    (memory 0) gives the smoothed joints of every step in memory to the bit; the joints decoded 7
    trajectory-frames at a time (not all at once) the same to float32 rounding (their mean is summed in
    another order)."""
    detections, calibration = trial
    held = track_detections(detections, calibration, "pf-diffusion-local", TrackConfig(fps=60, smooth=True))
    with caplog.at_level(logging.INFO, logger="priortrack"):
        spilled = track_detections(detections, calibration, "pf-diffusion-local",
                                   TrackConfig(fps=60, smooth=True, memory=0))
    assert "spilling them to" in caplog.text and "read back from disk" in caplog.text
    np.testing.assert_array_equal(spilled.joints, held.joints)
    np.testing.assert_array_equal(spilled.spread, held.spread)
    assert np.abs(held.joints - held.filtered_joints).max() > 1e-3                  # it did smooth
    monkeypatch.setattr(particle, "SMOOTH_JOINT_ROWS", 7)
    chunked = track_detections(detections, calibration, "pf-diffusion-local",
                               TrackConfig(fps=60, smooth=True, memory=0))
    np.testing.assert_allclose(chunked.joints, held.joints, rtol=0, atol=1e-6)
    np.testing.assert_allclose(chunked.spread, held.spread, rtol=0, atol=1e-6)


@pytest.mark.parametrize("memory", [None, 10 ** 6, 0])
def test_record_array_reads_back_what_was_written_in_memory_or_in_its_file(memory, caplog):
    """Records written in any order read back equal, by index, negative index and slice, and as one array;
    past the budget (0 bytes) they live in a file, which close() removes; a record of another shape is refused."""
    rng = np.random.default_rng(0)
    values = rng.normal(size=(7, 3, 4))
    with caplog.at_level(logging.INFO, logger="priortrack"):
        records = RecordArray(7, (3, 4), memory)
    for k in (6, 0, 3, 1, 2, 5, 4):
        records[k] = values[k]
    assert records.spilled == (memory == 0) == ("past the memory budget" in caplog.text)
    assert len(records) == 7
    np.testing.assert_array_equal(records[-1], values[6])
    np.testing.assert_array_equal(records[2:5], values[2:5])
    np.testing.assert_array_equal(np.array(records), values)
    records[-2] = values[0]
    np.testing.assert_array_equal(records[5], values[0])
    if records.spilled:
        folder = Path(records._directory.name)
        assert (folder / "records.bin").stat().st_size == 7 * 12 * 8
        with pytest.raises(PriortrackError, match=r"record of shape \(4, 3\): expected \(3, 4\)"):
            records[0] = values[0].T
        records.close()
        assert not folder.exists()


def test_unscented_smoothing_with_its_matrices_on_disk_gives_the_same_numbers(trial, caplog):
    """ukf-real over the bundled real trial, smoothed over the whole run with every step and every smoother
    matrix spilled (memory 0): the same smoothed joints and spread, to the bit, as all in memory."""
    detections, calibration = trial
    held = track_detections(detections, calibration, "ukf-real", TrackConfig(fps=60, smooth=True))
    with caplog.at_level(logging.INFO, logger="priortrack"):
        spilled = track_detections(detections, calibration, "ukf-real", TrackConfig(fps=60, smooth=True, memory=0))
    assert "past the memory budget" in caplog.text
    np.testing.assert_array_equal(spilled.joints, held.joints)
    np.testing.assert_array_equal(spilled.spread, held.spread)
    assert np.abs(held.joints - held.filtered_joints).max() > 1e-4                  # it did smooth


def test_memory_is_for_detections(capsys):
    assert main(["track", "walkjog:35_29", "--filter", "pf-diffusion-local", "--memory", "1GB"]) == 2
    assert "--memory is for tracking --detections" in capsys.readouterr().err
    assert main(["track", "--detections", str(POSE2SIM_DIR / "pose"), "--cameras", str(POSE2SIM_DIR / "Calib.toml"),
                 "--filter", "pf-diffusion-local", "--smooth", "--memory", "lots"]) == 2
    assert "--memory 'lots'" in capsys.readouterr().err
