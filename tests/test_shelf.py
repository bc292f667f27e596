"""``priortrack eval shelf`` (issue 58, item 4): Shelf's and Campus's truth as 4D Association ships it, read; a
benchmark folder in that layout, which these tests write themselves (nothing of Shelf is in the project), scored
beside the oracle DLT of the same cameras."""

import json

import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.cli.main import main
from priortrack.data.keypoints import LAYOUTS, detector_map
from priortrack.data.shelf_truth import SHELF15_NAMES, read_shelf_truth
from priortrack.experiments import shelf
from priortrack.experiments.scenes import SCENES, composed
from priortrack.experiments.shelf import LIMB_JOINTS
from priortrack.geometry.camera import PinholeCamera
from priortrack.geometry.triangulation import triangulate

FPS = 25.0


def _truth_text(frames: list[dict[int, np.ndarray]], valid: dict | None = None) -> str:
    """gt.txt's text: per frame {id: (15, 3) joints in SHELF15 order}; ``valid`` {(frame, id): (15,) 0/1}."""
    lines = [f"15\t{len(frames)}"]
    for t, people in enumerate(frames):
        lines.append(str(len(people)))
        for actor, X in people.items():
            lines.append(str(actor))
            lines += ["  ".join(f"{v:.17g}" for v in row) for row in X.T]
            lines.append("  ".join(str(int(v)) for v in (valid or {}).get((t, actor), np.ones(15))))
    return "\n".join(lines) + "\n"


def test_the_truth_file_is_read_as_4d_association_writes_it(tmp_path):
    rng = np.random.default_rng(0)
    a, b, c = (rng.normal(0, 0.5, (15, 3)) for _ in range(3))
    valid = np.ones(15)
    valid[SHELF15_NAMES.index("l_wrist")] = 0
    path = tmp_path / "gt.txt"
    path.write_text(_truth_text([{0: a}, {3: b, 0: c}], {(1, 0): valid}))
    truth = read_shelf_truth(path)
    assert truth.ids.tolist() == [0, 3] and truth.joints.shape == (2, 2, 15, 3)
    assert np.array_equal(truth.joints[0, 0], a) and np.isnan(truth.joints[0, 1]).all()
    assert np.array_equal(truth.joints[1, 1], b)
    wrist = SHELF15_NAMES.index("l_wrist")
    assert np.isnan(truth.joints[1, 0, wrist]).all() and np.array_equal(np.delete(truth.joints[1, 0], wrist, 0),
                                                                       np.delete(c, wrist, 0))
    e = truth.eval15()
    assert np.array_equal(e[0, 0, 10], a[SHELF15_NAMES.index("l_knee")])           # eval15's lknee
    assert np.array_equal(e[0, 0, 6], a[SHELF15_NAMES.index("r_shoulder")])        # eval15's rshoulder
    assert np.array_equal(e[0, 0, 0], a[SHELF15_NAMES.index("pelvis")])
    assert np.isnan(e[:, :, 1:3]).all()                                            # neck and head: no keypoint


@pytest.mark.parametrize("text, message", [
    ("14 1\n0\n", "14 joints"),
    ("15 2\n1\n0\n" + ("1 " * 15 + "\n") * 4, "the file ends where frame 1"),
    ("15 1\n1\n0\n" + ("1 " * 15 + "\n") * 3 + "1 " * 14 + "\n", "line 7: row v of person 0 in frame 0: expected 15"),
    ("15 1\n1\n0\n" + ("x " * 15 + "\n") * 4, "line 4"),
    ("15 1\n1\n0\n" + ("1 " * 15 + "\n") * 3 + "2 " * 15 + "\n", "validity row in frame 0 holds 2"),
    ("15 1\n2\n0\n" + ("1 " * 15 + "\n") * 4 + "0\n" + ("1 " * 15 + "\n") * 4, "person id 0 in frame 0 is given twice"),
    ("15 1\n1\n0\n" + ("1 " * 15 + "\n") * 4 + "1\n", "more lines after"),
    ("15 1\n1.5\n", "whole numbers"),
])
def test_a_malformed_truth_file_is_refused_naming_its_line(tmp_path, text, message):
    path = tmp_path / "gt.txt"
    path.write_text(text)
    with pytest.raises(PriortrackError, match=message):
        read_shelf_truth(path)


def _cameras() -> list[PinholeCamera]:
    """Three cameras round the capture area of a Z-up world (no distortion, as Shelf's)."""
    return [PinholeCamera.look_at((4 * np.cos(a), 4 * np.sin(a), 1.6), (0, 0, 1.0), up=(0, 0, 1), focal_px=900,
                                  width=1032, height=776) for a in np.radians([0.0, 120.0, 240.0])]


@pytest.fixture(scope="module")
def benchmark(tmp_path_factory):
    """A benchmark folder as Shelf ships it: two walkers passing a metre apart, 2 s at 25 fps, seen by three
    cameras; their BODY_25 keypoints with 2 px of noise, every camera's people in a shuffled slot order (the
    permutation kept), ``gt.txt`` of their joints in the detectors' definitions, ``calibration.json``."""
    folder = tmp_path_factory.mktemp("shelf")
    X = composed(SCENES["passing"], seconds=2.0, fps=FPS, gap=1.0)
    X[..., :2] -= X[:, :, 0, :2].mean(axis=(0, 1))                                      # the walks about the origin
    truth = np.einsum("ij,ptjk->ptik", detector_map(), X)                             # (P, T, 15, 3)
    P, T = truth.shape[:2]
    cameras = _cameras()
    rng = np.random.default_rng(1)
    names = LAYOUTS["body25"]
    ours = {"lshoulder": "left_shoulder", "lelbow": "left_elbow", "lwrist": "left_wrist", "rshoulder": "right_shoulder",
            "relbow": "right_elbow", "rwrist": "right_wrist", "lhip": "left_hip", "lknee": "left_knee",
            "lankle": "left_ankle", "rhip": "right_hip", "rknee": "right_knee", "rankle": "right_ankle"}
    from priortrack.data.eval15 import EVAL15_NAMES

    keypoints = np.full((3, T, P, 25, 3), np.nan, dtype=np.float32)
    order = np.stack([np.stack([rng.permutation(P) for _ in range(T)]) for _ in cameras])       # (C, T, P)
    for c, camera in enumerate(cameras):
        uv = camera.project(truth)[0] + rng.normal(0, 2.0, truth.shape[:3] + (2,))            # (P, T, 15, 2)
        for j, name in ours.items():
            k = names.index(name)
            for t in range(T):
                keypoints[c, t, order[c, t], k, :2] = uv[:, t, EVAL15_NAMES.index(j)]
                keypoints[c, t, order[c, t], k, 2] = 0.9
    np.savez(folder / "scene.npz", keypoints=keypoints, keypoint_names=np.array(names),
             camera_names=np.array(["0", "1", "2"]), frames=np.arange(T))
    head_bottom, head_top = truth[:, :, 1], truth[:, :, 2]
    shelf15 = {"r_ankle": 14, "r_knee": 13, "r_hip": 12, "l_hip": 9, "l_knee": 10, "l_ankle": 11, "r_wrist": 8,
               "r_elbow": 7, "r_shoulder": 6, "l_shoulder": 3, "l_elbow": 4, "l_wrist": 5, "pelvis": 0}
    rows = np.zeros((P, T, 15, 3))
    for i, name in enumerate(SHELF15_NAMES):
        rows[:, :, i] = head_bottom if name == "head_bottom" else head_top if name == "head_top" else \
            truth[:, :, shelf15[name]]
    (folder / "gt.txt").write_text(_truth_text([{p: rows[p, t] for p in range(P)} for t in range(T)]))
    np.save(folder / "shelf15.npy", rows)                               # the truth's rows, for a test to change
    (folder / "calibration.json").write_text(json.dumps({str(c): {
        "K": camera.K.double().numpy().ravel().tolist(),
        "RT": np.concatenate([camera.R.double().numpy(), camera.t.double().numpy()[:, None]], 1).ravel().tolist(),
        "imgSize": [camera.width, camera.height]} for c, camera in enumerate(cameras)}))
    return folder, truth, order, cameras


def test_the_oracle_gives_each_actor_their_own_detections_and_their_dlt(benchmark):
    folder, truth, order, cameras = benchmark
    from priortrack.data.scene_detections import read_scene_detections

    scene = read_scene_detections(folder / "scene.npz")
    uv, confidence = scene.eval15()
    by_frame = truth.transpose(1, 0, 2, 3)                                              # (T, P, 15, 3)
    slots = shelf.oracle_slots(cameras, uv, by_frame)
    assert np.array_equal(slots, order)                                                  # the shuffles undone
    dlt = shelf.oracle_dlt(cameras, uv, confidence, slots)
    C, T = order.shape[:2]
    own = np.stack([uv[c, np.arange(T)[:, None], order[c]] for c in range(C)])          # (C, T, P, 15, 2) by hand
    weight = np.stack([confidence[c, np.arange(T)[:, None], order[c]] for c in range(C)])
    assert np.allclose(dlt, triangulate(cameras, own, weight), equal_nan=True)
    error = 1000 * np.linalg.norm(dlt[:, :, LIMB_JOINTS] - by_frame[:, :, LIMB_JOINTS], axis=-1)
    assert error.mean() < 20                                                             # 2 px of noise, 4 m away


def test_the_scores_of_hand_made_tracks():
    """Two tracks that exchange the two actors half-way: one switch each; a third far off: a false track; the
    nearest track scores PCP 100; a frame with no track at all: every part wrong."""
    rng = np.random.default_rng(0)
    body = rng.normal(0, 0.3, (15, 3))
    T = 10
    truth = np.stack([np.tile(body, (T, 1, 1)), np.tile(body + [2.0, 0, 0], (T, 1, 1))], axis=1)    # (T, 2, 15, 3)
    swapped = np.where(np.arange(T)[:, None, None, None] < T // 2, truth, truth[:, ::-1])
    ghost = np.tile(body + [10.0, 0, 0], (T, 1, 1, 1))
    estimate = np.concatenate([swapped, ghost], axis=1)                                  # (T, 3, 15, 3)
    given = shelf.identities(estimate, truth)
    assert shelf.switches(given).tolist() == [1, 1]
    assert not (given == 2).any()
    frames = np.ones(T, dtype=bool)
    rows = shelf.score(shelf.nearest_tracks(estimate, truth), truth, frames)
    assert [r["pcp"] for r in rows] == [100.0, 100.0] and rows[0]["mpjpe_mm"] == 0.0
    # the tracks' detections (T, C, P): track 0 actor 0's, track 1 actor 0's too (never given: a second track of
    # them), track 2 slot 5's, which the truth gives nobody (someone unannotated: not judged)
    oracle = np.full((2, T, 2), -1)
    oracle[:, :, 0], oracle[:, :, 1] = 0, 1
    taken = np.stack([np.zeros((T, 2)), np.zeros((T, 2)), np.full((T, 2), 5)], axis=-1).astype(int)
    never = np.full((T, 2), -1)
    never[:, 0] = 0
    assert shelf.false_tracks(taken, oracle, never).tolist() == [False, True, False]
    off = truth + np.where(np.arange(T)[:, None, None, None] < T // 2, 0.01, 0.03) * np.array([1.0, 0, 0])
    beside = np.where(np.arange(T)[:, None, None, None] < T // 2, truth, np.nan)       # a DLT of the first half
    row = shelf.score(off, truth, frames, beside)[0]
    assert row["mpjpe_mm"] == pytest.approx(20.0) and row["mpjpe_beside_mm"] == pytest.approx(10.0)
    assert row["per_joint_mm"]["lwrist"] == pytest.approx(20.0) and row["per_joint_beside_mm"]["lwrist"] == pytest.approx(10.0)
    estimate[3] = np.nan                                                                  # nobody tracked there
    rows = shelf.score(shelf.nearest_tracks(estimate, truth), truth, frames)
    assert rows[0]["pcp"] == pytest.approx(90.0) and rows[0]["frames"] == T


def test_eval_shelf_scores_every_subset_beside_the_oracle(benchmark, capsys):
    folder = benchmark[0]
    result = shelf.eval_shelf(folder, ["ukf-real"], sizes=[2, 3], actors=(0, 1), workers=1)
    assert [r["cameras"] for r in result["rows"]] == [["0", "1"], ["0", "2"], ["1", "2"], ["0", "1", "2"]]
    for row in result["rows"]:
        assert row["switches"] == 0 and row["false_tracks"] == [] and row["tracks"] == 2
        for actor in row["actors"]:
            assert actor["pcp"] >= 95 and actor["dlt"]["pcp"] >= 95, row
            assert actor["mpjpe_mm"] < 60 and actor["dlt"]["mpjpe_mm"] < 20, row
            assert actor["frames"] == 50
    assert main(["eval", "shelf", str(folder), "--cameras", "0,2", "--actors", "0", "1", "--workers", "1",
                 "--per-joint"]) == 0
    out = capsys.readouterr().out
    assert "| 0,2 | ukf-real |" in out and "MPJPE per limb joint, mm, where the DLT has it" in out
    assert main(["eval", "shelf", str(folder), "--diagnose"]) == 0
    assert "| lhip |" in capsys.readouterr().out
    assert main(["eval", "shelf", str(folder), "--diagnose", "--subsets", "2"]) == 2


def test_eval_shelf_with_one_camera_scores_the_root_relative_error_and_no_dlt(benchmark, capsys):
    """Each camera alone: both actors followed, one track each, no switch; no DLT (None, "—"); each actor's
    root-relative error (what one view measures) within 10 % (+ 5 mm) of the same actor tracked alone from the
    detections the permutation says are theirs (the one-camera person pipeline: the scene loses nothing); printed."""
    from priortrack.data.calibration import read_calibration
    from priortrack.data.detections import Detections
    from priortrack.data.scene_detections import read_scene_detections
    from priortrack.tracking.person import TrackConfig, track_detections

    folder, truth, order, _ = benchmark
    result = shelf.eval_shelf(folder, ["ukf-real"], sizes=[1], actors=(0, 1), workers=1)
    assert [r["cameras"] for r in result["rows"]] == [["0"], ["1"], ["2"]]
    scene, calibration = read_scene_detections(folder / "scene.npz"), read_calibration(folder / "calibration.json")
    T = truth.shape[1]
    for c, row in enumerate(result["rows"]):
        assert row["switches"] == 0 and row["false_tracks"] == [] and row["tracks"] == 2, row
        for p, actor in enumerate(row["actors"]):
            assert actor["dlt"]["pcp"] is None and actor["dlt"]["mpjpe_root_mm"] is None
            own = scene.keypoints[c, np.arange(T), order[c, :, p]][None]                      # (1, T, 25, 3)
            alone = track_detections(Detections(scene.layout, (str(c),), scene.frames, scene.fps, "alone",
                                                keypoints=own), calibration, "ukf-real",
                                     TrackConfig(fps=FPS, up=shelf.truth_up(truth.transpose(1, 0, 2, 3)),
                                                 camera_map={str(c): str(c)}, fit_check=False))
            estimate = np.full(truth.transpose(1, 0, 2, 3).shape, np.nan)                   # (T, P, 15, 3)
            ticked = alone.frames >= 0                                                   # (a 30 fps tick per frame)
            estimate[alone.frames[ticked], p] = alone.joints[ticked]
            mine = shelf.score(estimate, truth.transpose(1, 0, 2, 3), np.ones(T, dtype=bool))[p]["mpjpe_root_mm"]
            assert actor["mpjpe_root_mm"] <= 1.1 * mine + 5.0, (row["cameras"], p, actor["mpjpe_root_mm"], mine)
    assert main(["eval", "shelf", str(folder), "--cameras", "1", "--actors", "0", "1", "--workers", "1"]) == 0
    out = capsys.readouterr().out
    assert "| 1 | ukf-real |" in out and "(—)" in out and "camera 1 alone, ukf-real: root-relative MPJPE" in out


@pytest.mark.parametrize("args, message", [
    (["--cameras", "0,7"], "--cameras 0,7: give one or more"),
    (["--cameras", "1,1"], "--cameras 1,1"),
    (["--subsets", "4"], "--subsets 4"),
    (["--cameras", "0,1", "--subsets", "2"], "not both"),
    (["--actors", "5"], "no actor 5"),
    (["--presets", "pf-nothing"], "pf-nothing"),
    (["--detections", "nowhere.npz"], "nowhere.npz do not exist"),
])
def test_bad_arguments_are_one_line(benchmark, capsys, args, message):
    assert main(["eval", "shelf", str(benchmark[0])] + args) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_a_folder_without_the_benchmarks_files_is_named(tmp_path, capsys):
    assert main(["eval", "shelf", str(tmp_path)]) == 2
    assert "has no calibration.json" in capsys.readouterr().err


def test_the_diagnosis_finds_white_noise_and_a_planted_bias(benchmark, tmp_path):
    """On the benchmark's 2 px white noise: no bias, errors uncorrelated from frame to frame, no swap, the
    annotation never still; truth whose left hip an annotator put 50 mm higher than the keypoint: a 50 mm bias
    there, most of that joint's error, and nowhere else."""
    import shutil

    folder = benchmark[0]
    result = shelf.diagnose(folder, "0,1,2")
    assert result["swapped_share"] == 0.0
    for name, row in result["joints"].items():
        assert row["bias_mm"] < 5 and abs(row["autocorrelation"][0]) < 0.3 and row["truth_still_share"] == 0.0, name
    assert result["summary"]["rms_mm"] < 20
    for name in ("calibration.json", "scene.npz"):
        shutil.copy(folder / name, tmp_path / name)
    rows = np.load(folder / "shelf15.npy")
    rows[:, :, SHELF15_NAMES.index("l_hip"), 2] += 0.05                              # up is z
    (tmp_path / "gt.txt").write_text(_truth_text([{p: rows[p, t] for p in range(rows.shape[0])}
                                                  for t in range(rows.shape[1])]))
    planted = shelf.diagnose(tmp_path, "0,1,2")["joints"]
    assert planted["lhip"]["bias_mm"] == pytest.approx(50, abs=5) and planted["lhip"]["bias_share"] > 0.8
    assert all(row["bias_mm"] < 5 for name, row in planted.items() if name != "lhip")
