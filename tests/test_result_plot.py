"""``priortrack plot RESULT.npz`` (issue 60, item 6: for those who would rather look than read): one person's result
and a scene's drawn, their arrays read back per person; a file that is neither a result nor a prior is one line."""

from pathlib import Path

import numpy as np
from matplotlib.image import imread

from priortrack.cli.main import main
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.viz.result_plot import is_result, read_result

MULTIPERSON = Path(__file__).parent / "data" / "pose2sim_multiperson"


def test_one_person_and_a_scene_are_drawn(tmp_path, capsys):
    assert main(["track", "--detections", str(POSE2SIM_DIR / "pose"), "--cameras", str(POSE2SIM_DIR / "Calib.toml"),
                 "--fps", "60", "--filter", "ukf-real", "--out", str(tmp_path / "one.npz")]) == 0
    assert main(["track", "--detections", str(MULTIPERSON / "pose"), "--cameras",
                 str(MULTIPERSON / "calibration" / "Calib.qca.txt"), "--fps", "60", "--frames", "30", "--people", "all",
                 "--out", str(tmp_path / "scene.npz")]) == 0
    one, scene = read_result(tmp_path / "one.npz"), read_result(tmp_path / "scene.npz")
    assert one["joints"].shape == (12, 1, 15, 3) and one["reprojection"].shape == (12, 1, 4) and not one["scene"]
    np.testing.assert_allclose(one["time"], np.arange(12) / 60)
    assert scene["ids"].tolist() == [0, 1] and scene["joints"].shape[1:] == (2, 15, 3) and scene["scene"]
    with np.load(tmp_path / "scene.npz") as z:
        np.testing.assert_array_equal(scene["mismatch"], z["mismatch"])
    capsys.readouterr()
    for name, rows in (("one", 1), ("scene", 2)):
        assert main(["plot", str(tmp_path / f"{name}.npz"), "--out", str(tmp_path / f"{name}.png")]) == 0
        assert f"wrote {tmp_path / name}.png" in capsys.readouterr().out
        height, width = imread(tmp_path / f"{name}.png").shape[:2]
        assert width == 1500 and height == 320 * rows                           # a row of three panels a person


def test_a_file_that_is_no_result_is_refused(tmp_path, capsys):
    np.savez(tmp_path / "x.npz", joints=np.zeros((3, 15, 3)))
    assert not is_result(tmp_path / "x.npz") and not is_result(tmp_path / "missing.npz")
    assert main(["plot", str(tmp_path / "x.npz"), "--out", str(tmp_path / "x.png")]) == 2
    assert "x.npz: neither a result of track --detections nor a prior file" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()
