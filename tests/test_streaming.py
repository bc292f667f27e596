"""Long recordings read a block at a time (issue 29): an .npz's or .npy's keypoints read from the file in
slices (files numpy wrote), detections opened without reading them, a run's observations built a block of
ticks at a time, and a whole tracked run the same, to the bit, as from detections in memory in one block."""

import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.calibration import read_calibration
from priortrack.data.detections import DetectionFile, open_detections, read_detections
from priortrack.data.keypoints import LAYOUTS
from priortrack.data.npz import npy_on_disk, npz_member_on_disk
from priortrack.observation import ticks
from priortrack.observation.ticks import TickObservations

POSE, CALIB = POSE2SIM_DIR / "pose", POSE2SIM_DIR / "Calib.toml"


def test_an_array_on_disk_reads_the_slices_numpy_wrote(tmp_path):
    """np.save and np.savez (stored) members read in column slices equal numpy's own read of them; a
    compressed member or a Fortran-order array is not sliced (None: read whole); a file cut short is refused."""
    a = np.random.default_rng(0).normal(size=(3, 50, 4, 2)).astype(np.float32)
    np.save(tmp_path / "a.npy", a)
    np.savez(tmp_path / "a.npz", other=np.arange(7), keypoints=a)
    for on_disk in (npy_on_disk(tmp_path / "a.npy", 1 << 20), npz_member_on_disk(tmp_path / "a.npz", "keypoints")):
        assert on_disk.shape == a.shape and on_disk.dtype == np.float32
        for start, stop in [(0, 50), (0, 1), (17, 33), (49, 60), (40, 40)]:
            np.testing.assert_array_equal(on_disk.columns(start, stop), a[:, start:stop])
    np.savez_compressed(tmp_path / "c.npz", keypoints=a)
    assert npz_member_on_disk(tmp_path / "c.npz", "keypoints") is None
    np.save(tmp_path / "f.npy", np.asfortranarray(a))
    assert npy_on_disk(tmp_path / "f.npy", 1 << 20) is None
    with pytest.raises(PriortrackError, match="the array 'x' is missing"):
        npz_member_on_disk(tmp_path / "a.npz", "x")
    cut = tmp_path / "cut.npy"
    cut.write_bytes((tmp_path / "a.npy").read_bytes()[:-100])
    with pytest.raises(PriortrackError, match="cut short"):
        npy_on_disk(cut, 1 << 20).columns(0, 50)


def _pose2sim_npz(path, compressed=False):
    """The Pose2Sim demo's OpenPose detections written as an .npz of BODY_25B keypoints, in the file's own
    keypoint order reversed (the reader puts them back by name)."""
    d = read_detections(POSE, keypoints="body25b")
    kp = np.nan_to_num(d.keypoints, nan=0.0)[:, :, ::-1]
    (np.savez_compressed if compressed else np.savez)(
        path, keypoints=kp, keypoint_names=np.array(LAYOUTS["body25b"][::-1]), fps=np.array(60.0),
        camera_names=np.array(d.camera_names), frames=d.frames)
    return d


def test_detections_opened_from_a_file_read_what_reading_it_whole_reads(tmp_path):
    original = _pose2sim_npz(tmp_path / "d.npz")
    d = read_detections(tmp_path / "d.npz")
    assert d.layout == "body25b" and np.array_equal(np.isnan(d.keypoints[..., 0]), np.isnan(original.keypoints[..., 0]))
    opened = open_detections(tmp_path / "d.npz")
    assert isinstance(opened, DetectionFile) and opened.camera_names == d.camera_names and opened.fps == 60.0
    np.testing.assert_array_equal(opened.load().keypoints, d.keypoints)
    for start, stop in [(0, None), (3, 11), (20, 21)]:
        for a, b in zip(opened.eval15(0.3, start, stop), d.eval15(0.3, start, stop)):
            np.testing.assert_array_equal(a, b)
    assert len(opened.head(5).frames) == 5 and opened.head(5).load().keypoints.shape[1] == 5
    _pose2sim_npz(tmp_path / "c.npz", compressed=True)
    np.testing.assert_array_equal(open_detections(tmp_path / "c.npz").keypoints, d.keypoints)   # compressed: whole
    np.save(tmp_path / "d.npy", np.nan_to_num(read_detections(tmp_path / "d.npz").keypoints[:, :, :17]))
    npy = open_detections(tmp_path / "d.npy", keypoints="coco17")
    assert isinstance(npy, DetectionFile)
    np.testing.assert_array_equal(npy.load().keypoints, read_detections(tmp_path / "d.npy", keypoints="coco17").keypoints)


def test_a_bad_value_late_in_a_file_is_refused_when_its_block_is_read(tmp_path):
    kp = np.ones((2, 40, 17, 3), dtype=np.float32)
    kp[1, 33, 5, 2] = -0.5
    np.savez(tmp_path / "neg.npz", keypoints=kp, keypoint_names=np.array(LAYOUTS["coco17"]))
    opened = open_detections(tmp_path / "neg.npz")
    opened.eval15(0.3, 0, 30)                                     # the frames before it are fine
    with pytest.raises(PriortrackError, match=r"negative confidences \(first at \[1, 33, 5\]\)"):
        opened.eval15(0.3, 30, 40)
    kp[1, 33, 5] = [np.inf, 1.0, 1.0]
    np.save(tmp_path / "inf.npy", kp)
    with pytest.raises(PriortrackError, match=r"inf or a value beyond float32.s range \(first at \[1, 33, 5\]\)"):
        open_detections(tmp_path / "inf.npy").load()


def test_tick_observations_are_the_schedule_s_frames_block_by_block():
    """z_t = each camera's eval15 pixels and confidence of the frame tick t consumes (NaN where none, or
    left out), the same whatever the block size, by index, slice or iteration."""
    d = read_detections(POSE, keypoints="body25b")
    uv, confidence = d.eval15(0.3)
    index = np.array([0, -1, 2, 4, 5, -1, 7, 9, 10, 11])
    left_out = np.zeros((len(index), 4), dtype=bool)
    left_out[3, 1] = True
    expected = np.full((len(index), 4, 15, 3), np.nan)
    used = index >= 0
    expected[used, :, :, :2] = uv[:, index[used]].transpose(1, 0, 2, 3)
    expected[used, :, :, 2] = confidence[:, index[used]].transpose(1, 0, 2)
    expected[3, 1] = np.nan
    for block in (1, 3, 100):
        z = TickObservations(d, index, 0.3, left_out, block_ticks=block)
        assert z.shape == expected.shape and len(z) == 10
        np.testing.assert_array_equal(z[2:8], expected[2:8])
        np.testing.assert_array_equal(np.stack(list(z)), expected)
        np.testing.assert_array_equal(z[7], expected[7])
        np.testing.assert_array_equal(z[-1, 2], expected[-1, 2])
        np.testing.assert_array_equal(z.between(3)[0], expected[3])
        assert np.isfinite(z.raw(3, 4)[0, 1, :, 0]).any()                # as detected, before left out
    with pytest.raises(IndexError):
        z[10]


def test_a_run_from_a_file_in_small_blocks_is_the_run_in_memory(tmp_path, monkeypatch):
    """track_detections on detections opened from an .npz (bench long's input, 400 frames: 200 ticks), its
    ticks read 7 at a time, gives the joints, likelihoods, flags and reprojection errors of the run on the
    detections in memory in one block."""
    from priortrack.experiments.benchmarks.long import write_long_input
    from priortrack.tracking.person import track_detections
    from priortrack.experiments.real_format import DEFAULT_CALIBRATION

    path = write_long_input(400, tmp_path / "long.npz")
    calibration = read_calibration(DEFAULT_CALIBRATION)
    whole = track_detections(read_detections(path), calibration, "ukf-real")
    monkeypatch.setattr(ticks, "BLOCK_TICKS", 7)
    opened = track_detections(open_detections(path), calibration, "ukf-real")
    for name in ("joints", "spread", "loglik", "mismatch", "reprojection_px", "reprojection_by_tick", "gated", "frames"):
        np.testing.assert_array_equal(getattr(opened, name), getattr(whole, name), err_msg=name)
    assert opened.observations.block_ticks == 7 and len(opened.observations) == len(whole.joints) > 190
    np.testing.assert_array_equal(opened.observations[5:19], whole.observations[5:19])


def test_an_openpose_folder_is_parsed_a_file_at_a_time(tmp_path, monkeypatch):
    """Each camera's JSON files are parsed in frame order as the person is followed, and a file's people are
    let go once the followed one is kept: while reading 2 cameras × 40 frames of 3 people, no more than two
    frames' people (and the last one followed) are alive at once, where reading every file first held all 240.
    The person followed and the switches are those of the files' own people (a third, far person ignored)."""
    import json
    import weakref

    from priortrack.data import detections

    rng = np.random.default_rng(0)

    def body25(xy):                                      # BODY_25's keypoint 8, MidHip, the hips' (9, 12) midpoint
        xy[8] = 0.5 * (xy[9] + xy[12])
        return xy

    base = body25(rng.uniform(300, 400, size=(25, 2)))
    for c in range(2):
        (tmp_path / f"cam{c}").mkdir()
        for t in range(40):
            people = [base + t + c, base + 300, body25(rng.uniform(600, 700, size=(25, 2)))]
            if t == 20:
                people = people[1:]                                  # the person followed is not seen
            entries = [{"pose_keypoints_2d": np.c_[xy, np.full(25, 0.9)].ravel().tolist()} for xy in people]
            (tmp_path / f"cam{c}" / f"cam{c}_{t:012d}_keypoints.json").write_text(json.dumps({"people": entries}))
    alive, most = [0], [0]
    parse = detections._people

    def counted(path):
        people = parse(path)
        for p in people:
            alive[0] += 1
            weakref.finalize(p, lambda: alive.__setitem__(0, alive[0] - 1))
        most[0] = max(most[0], alive[0])
        return people

    monkeypatch.setattr(detections, "_people", counted)
    read = detections.read_detections(tmp_path, "body25")
    assert most[0] <= 2 * 3 + 1, most
    assert read.switches == (1, 1) and read.keypoints.shape == (2, 40, 25, 3)
    np.testing.assert_allclose(read.keypoints[1, 5, :, :2], base + 6, rtol=1e-6)
    assert np.isnan(read.keypoints[:, 20]).all()


def test_an_openpose_folder_with_a_late_odd_person_or_nobody_is_refused(tmp_path):
    """Keypoint counts are checked as the files are parsed: a 17-point person late in a BODY_25 folder is refused
    with both counts; a folder where nobody is detected is refused as such."""
    import json

    xy = np.c_[np.random.default_rng(0).uniform(300, 400, size=(25, 2)), np.full(25, 0.9)]
    for t in range(5):
        person = xy[:17] if t == 4 else xy
        (tmp_path / f"f_{t:04d}.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": person.ravel().tolist()}]}))
    with pytest.raises(PriortrackError, match=r"different keypoint counts \(\[17, 25\]\)"):
        read_detections(tmp_path, "body25")
    for t in range(5):
        (tmp_path / f"f_{t:04d}.json").write_text(json.dumps({"people": []}))
    with pytest.raises(PriortrackError, match="nobody is detected in any frame"):
        read_detections(tmp_path, "body25")
