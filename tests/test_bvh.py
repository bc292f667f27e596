"""BVH reader and writer: hand-computed poses, round trips, gimbal lock, bad input."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from priortrack.body.fk import ForwardKinematics
from priortrack.data.amc import read_amc
from priortrack.data.asf import axis_rotation, read_asf
from priortrack.data.bvh import read_bvh, write_bvh, zxy_angles
from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError

CMU = Path(__file__).resolve().parents[1] / "priortrack" / "data" / "cmu" / "asf_amc"

# Line numbers matter: the bad-input tests name them.
TINY = """\
HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT Neck
    {
      OFFSET 0 0 5
      CHANNELS 3 Xrotation Yrotation Zrotation
      End Site
      {
        OFFSET 3 0 0
      }
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.04
0 0 0 0 0 0 0 0 0 0 0 0
100 50 -20 90 0 0 0 90 90 90 90 0
"""

# Odd layouts: a root OFFSET, mixed channel order, translations on a non-root joint, two
# rotation channels, CHANNELS 0, braces on the keyword's line, a childless JOINT.
ODD = """\
HIERARCHY
ROOT Hips
{
 OFFSET 1 2 3
 CHANNELS 6 Yrotation Xposition Zrotation Yposition Xrotation Zposition
 JOINT Chest
 {
  OFFSET 0 10 0
  CHANNELS 6 Xposition Yposition Zposition Xrotation Yrotation Zrotation
  JOINT Neck
  {
   OFFSET 0 5 1
   CHANNELS 2 Yrotation Xrotation
   End Site
   { OFFSET 0 4 0 }
  }
  JOINT LeftArm
  {
   OFFSET 5 0 0
   CHANNELS 0
   JOINT LeftHand
   {
    OFFSET 7 0 0
    CHANNELS 1 Zrotation
   }
  }
 }
 JOINT Leg {
  OFFSET -3 -10 0
  CHANNELS 3 Zrotation Xrotation Yrotation
  End Site
  {
   OFFSET 0 -40 0
  }
 }
}
MOTION
"""
ODD_CHANNELS = 6 + 6 + 2 + 1 + 3


def _write(tmp_path: Path, text: str, name: str = "clip.bvh") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _positions(motion: Motion) -> np.ndarray:
    """(T, J, 3) positions of every joint, metres."""
    return ForwardKinematics(motion.skeleton)(motion.channels).numpy()


def _by_name(motion: Motion, names) -> np.ndarray:
    """(T, len(names), 3) positions of the named joints."""
    return _positions(motion)[:, [motion.skeleton.names.index(n) for n in names]]


def _odd_motion(tmp_path: Path, frames: int = 40) -> Path:
    rng = np.random.default_rng(3)
    values = rng.uniform(-180.0, 180.0, size=(frames, ODD_CHANNELS))
    values[:, [1, 3, 5, 6, 7, 8]] = rng.uniform(-50.0, 50.0, size=(frames, 6))   # positions, cm
    values[0, -2] = 90.0       # Leg Xrotation at gimbal lock
    values[1, -2] = -90.0
    rows = "\n".join(" ".join(repr(v) for v in row) for row in values.tolist())
    return _write(tmp_path, ODD + f"Frames: {frames}\nFrame Time: 0.0333333333\n{rows}\n", "odd.bvh")


# --------------------------------------------------------------------------- reading


def test_tiny_positions_by_hand(tmp_path):
    motion = read_bvh(_write(tmp_path, TINY))
    assert motion.skeleton.names == ("Hips", "Spine", "Neck", "Neck_end")
    assert motion.skeleton.source == "bvh"
    assert motion.skeleton.channel_names[:6] == ("Hips.tx", "Hips.ty", "Hips.tz", "Hips.rz", "Hips.rx", "Hips.ry")
    assert motion.skeleton.channel_names[9:] == ("Neck.rx", "Neck.ry", "Neck.rz")
    assert motion.fps == 25.0 and motion.name == "clip" and motion.subject == ""
    p = _positions(motion)
    rest = np.array([[0, 0, 0], [0, 0.1, 0], [0, 0.1, 0.05], [0.03, 0.1, 0.05]])
    np.testing.assert_allclose(p[0], rest, rtol=0, atol=1e-12)
    # Frame 1: root at (1, 0.5, -0.2) m turned 90° about z (x → y, y → −x); the spine,
    # "Zrotation Xrotation Yrotation" = (0, 90, 90), is Rx(90)·Ry(90); the neck,
    # "Xrotation Yrotation Zrotation" = (90, 90, 0), is Rx(90)·Ry(90).
    root = np.array([1.0, 0.5, -0.2])
    spine = root + np.array([-0.1, 0.0, 0.0])                 # Rz90 · (0, 0.1, 0)
    # G_spine = Rz90·Rx90·Ry90: (0, 0, 0.05) → Ry → (0.05, 0, 0) → Rx → same → Rz → (0, 0.05, 0)
    neck = spine + np.array([0.0, 0.05, 0.0])
    # L_neck·(0.03, 0, 0): Ry90 → (0, 0, −0.03), Rx90 → (0, 0.03, 0);
    # G_spine·(0, 0.03, 0): Ry → same, Rx90 → (0, 0, 0.03), Rz90 → same.
    end = neck + np.array([0.0, 0.0, 0.03])
    np.testing.assert_allclose(p[1], np.stack([root, spine, neck, end]), rtol=0, atol=1e-12)


def test_tiny_rotation_order_matters(tmp_path):
    """Listing the neck's rotations in the other order moves its end site elsewhere."""
    swapped = TINY.replace("Xrotation Yrotation Zrotation", "Yrotation Xrotation Zrotation")
    p = _positions(read_bvh(_write(tmp_path, swapped)))
    # L = Ry90·Rx90 now: (0.03, 0, 0) → Rx → same → Ry → (0, 0, −0.03);
    # G_spine = Rz90·Rx90·Ry90: Ry → (−0.03, 0, 0), Rx → same, Rz90 → (0, −0.03, 0).
    np.testing.assert_allclose(p[1, 3] - p[1, 2], [0.0, -0.03, 0.0], rtol=0, atol=1e-12)


def test_length_unit_and_fps_snap(tmp_path):
    text = TINY.replace("Frame Time: 0.04", "Frame Time: 0.00833333")
    motion = read_bvh(_write(tmp_path, text), length_unit=0.1)
    assert motion.fps == 120.0
    np.testing.assert_allclose(motion.skeleton.offsets[1], [0, 1, 0])
    ntsc = read_bvh(_write(tmp_path, TINY.replace("0.04", "0.0333667")))
    assert ntsc.fps == pytest.approx(1 / 0.0333667, rel=1e-15)          # not near an integer: kept


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("subject, clip", [("07", "07_01"), ("35", "35_01"), ("131", "131_04")])
def test_asf_amc_round_trip(tmp_path, subject, clip):
    skeleton = read_asf(CMU / f"{subject}.asf")
    motion = Motion(skeleton, read_amc(CMU / f"{clip}.amc", skeleton), 120.0, clip, subject)
    path = tmp_path / f"{clip}.bvh"
    write_bvh(motion, path)
    back = read_bvh(path)
    assert back.skeleton.names == skeleton.names
    assert back.fps == 120.0 and back.name == clip and len(back) == len(motion)
    error = np.abs(_by_name(back, skeleton.names) - _positions(motion)).max()
    assert error < 1e-6, error
    # The layout is normalised now: a second write → read reproduces the channels.
    write_bvh(back, tmp_path / "again.bvh")
    again = read_bvh(tmp_path / "again.bvh")
    assert again.skeleton.channel_names == back.skeleton.channel_names
    np.testing.assert_allclose(again.channels, back.channels, rtol=0, atol=1e-9)


def test_written_layout(tmp_path):
    skeleton = read_asf(CMU / "07.asf")
    motion = Motion(skeleton, read_amc(CMU / "07_01.amc", skeleton)[:3], 120.0, "07_01", "07")
    write_bvh(motion, tmp_path / "w.bvh")
    text = (tmp_path / "w.bvh").read_text()
    lines = text.splitlines()
    assert lines[:5] == ["HIERARCHY", "ROOT root", "{", "\tOFFSET 0.0 0.0 0.0",
                         "\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
    assert "\t\tCHANNELS 0" in lines                                   # lhipjoint has no dof
    assert "_end" not in text and text.count("End Site") == sum(n.endswith("_end") for n in skeleton.names)
    assert "e-" not in text and "e+" not in text
    assert "Frames: 3" in lines and "Frame Time: 0.008333333333333333" in lines


def test_bvh_round_trip_is_idempotent(tmp_path):
    first = read_bvh(_odd_motion(tmp_path))
    assert first.skeleton.names == ("Hips", "Chest", "Neck", "Neck_end", "LeftArm", "LeftHand", "Leg", "Leg_end")
    write_bvh(first, tmp_path / "b.bvh")
    second = read_bvh(tmp_path / "b.bvh")
    # The childless JOINT LeftHand gained a zero End Site: an extra joint at its position.
    assert second.skeleton.names == first.skeleton.names[:6] + ("LeftHand_end",) + first.skeleton.names[6:]
    assert first.fps == second.fps == 30.0                              # 1 / 0.0333333333 snapped
    np.testing.assert_allclose(_by_name(second, first.skeleton.names), _positions(first), rtol=0, atol=1e-9)
    np.testing.assert_allclose(_by_name(second, ["LeftHand_end"]), _by_name(second, ["LeftHand"]), atol=1e-12)
    write_bvh(second, tmp_path / "c.bvh")
    third = read_bvh(tmp_path / "c.bvh")
    assert third.skeleton.names == second.skeleton.names
    assert third.skeleton.channel_names == second.skeleton.channel_names
    assert third.fps == second.fps
    np.testing.assert_allclose(third.channels, second.channels, rtol=0, atol=1e-9)
    np.testing.assert_allclose(_positions(third), _positions(second), rtol=0, atol=1e-9)
    np.testing.assert_allclose(third.skeleton.offsets, second.skeleton.offsets, rtol=0, atol=1e-12)


def test_round_trip_in_metres_and_other_fps(tmp_path):
    motion = read_bvh(_write(tmp_path, TINY))
    motion = Motion(motion.skeleton, motion.channels, 29.97, "tiny")
    write_bvh(motion, tmp_path / "m.bvh", length_unit=1.0)
    back = read_bvh(tmp_path / "m.bvh", length_unit=1.0)
    assert back.fps == pytest.approx(29.97, rel=1e-14)
    np.testing.assert_allclose(_positions(back), _positions(motion), rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- gimbal lock


def _zxy(z: float, x: float, y: float) -> np.ndarray:
    return axis_rotation(2, z) @ axis_rotation(0, x) @ axis_rotation(1, y)


@pytest.mark.parametrize("x_deg", [90.0, -90.0, 90.0 - 1e-7, -90.0 + 1e-9])
def test_gimbal_lock_recomposes(x_deg):
    rng = np.random.default_rng(0)
    for z, y in rng.uniform(-np.pi, np.pi, size=(50, 2)):
        R = _zxy(z, np.radians(x_deg), y)
        angles = zxy_angles(R)
        np.testing.assert_allclose(_zxy(*angles), R, rtol=0, atol=1e-9)
        assert abs(angles[1] - np.radians(x_deg)) < 1e-7


def test_zxy_angles_batch_recovers_angles():
    rng = np.random.default_rng(1)
    angles = np.stack([rng.uniform(-3, 3, 200), rng.uniform(-1.5, 1.5, 200), rng.uniform(-3, 3, 200)], axis=1)
    R = np.stack([_zxy(*a) for a in angles]).reshape(10, 20, 3, 3)
    np.testing.assert_allclose(zxy_angles(R).reshape(-1, 3), angles, rtol=0, atol=1e-12)


def test_gimbal_lock_through_a_file(tmp_path):
    """A joint at x = ±90° in ZXY is written and read back to the same positions."""
    first = read_bvh(_odd_motion(tmp_path, frames=2))
    leg_x = first.skeleton.channel_names.index("Leg.rx")
    np.testing.assert_allclose(np.degrees(first.channels[:, leg_x]), [90.0, -90.0])
    write_bvh(first, tmp_path / "lock.bvh")
    back = read_bvh(tmp_path / "lock.bvh")
    np.testing.assert_allclose(_by_name(back, first.skeleton.names), _positions(first), rtol=0, atol=1e-9)
    G = ForwardKinematics(first.skeleton)(first.channels, rotations=True)[1].numpy()
    G_back = ForwardKinematics(back.skeleton)(back.channels, rotations=True)[1].numpy()
    leg = first.skeleton.index("Leg")
    np.testing.assert_allclose(G_back[:, back.skeleton.index("Leg")], G[:, leg], rtol=0, atol=1e-9)


# --------------------------------------------------------------------------- bad input


def _assert_fails(path: Path, line: int | None = None, match: str = "") -> PriortrackError:
    with pytest.raises(PriortrackError) as info:
        read_bvh(path)
    message = str(info.value)
    where = rf"{re.escape(str(path))}:{line if line is not None else r'[0-9]+'}: "
    assert re.match(where, message), message
    assert re.search(match, message), message
    return info.value


@pytest.mark.parametrize("old, new, line, match", [
    ("OFFSET 0 10 0", "OFFSET 0 10", 8, "OFFSET needs 3 numbers"),
    ("OFFSET 0 10 0", "OFFSET 0 10 0 4", 8, "OFFSET needs 3 numbers"),
    ("OFFSET 0 10 0", "OFFSET 0 ten 0", 8, "not a number"),
    ("OFFSET 0 0 5", "OFSET 0 0 5", 12, "unknown keyword 'OFSET'"),
    ("CHANNELS 3 Zrotation", "CHANNELS 2 Zrotation", 9, "says 2 channels but lists 3"),
    ("CHANNELS 3 Zrotation", "CHANNELS three Zrotation", 9, "CHANNELS needs a count"),
    ("Xrotation Yrotation Zrotation", "Xrotation Wrotation Zrotation", 13, "unknown channel 'Wrotation'"),
    ("Xrotation Yrotation Zrotation", "Xrotation Xrotation Zrotation", 13, "twice"),
    ("JOINT Neck", "JOINT Spine", 10, "duplicate joint name 'Spine'"),
    ("JOINT Neck", "JOINT", 10, "needs a name"),
    ("        OFFSET 3 0 0\n      }\n", "        OFFSET 3 0 0\n", 20, "unbalanced braces"),
    ("}\nMOTION", "}\n}\nMOTION", 21, "unbalanced braces"),
    ("End Site\n      {", "End Site\n      {\n CHANNELS 1 Xrotation", 16, "CHANNELS outside"),
    ("    JOINT Neck\n    {", "    JOINT Neck\n    JOINT Head", 11, "expected '{'"),
    ("HIERARCHY", "HIERARCHIE", 1, "starts with HIERARCHY"),
    ("Frames: 2", "Frames: 3", 25, "Frames: 3 .line 22. but 2 rows"),
    ("Frames: 2", "Frames: 1", 25, "Frames: 1 .line 22. but 2 rows"),
    ("Frames: 2", "Frames: two", 22, "not a whole number"),
    ("Frames: 2", "Frames: -2", 22, "negative"),
    ("Frames: 2\n", "", 22, "expected 'Frames:'"),
    ("Frame Time: 0.04", "Frame Time: 0", 23, "positive"),
    ("Frame Time: 0.04", "Frame Time: -0.04", 23, "positive"),
    ("Frame Time: 0.04", "Frame Time: fast", 23, "not a number"),
    ("90 90 90 0\n", "90 90 90\n", 25, "frame 1 has 11 values, the hierarchy has 12"),
    ("90 90 90 0\n", "90 90 90 0 0\n", 25, "frame 1 has 13 values"),
    ("100 50 -20", "1OO 50 -20", 25, "not a number"),
    ("100 50 -20", "nan 50 -20", 25, "non-finite"),
])
def test_bad_input_names_file_and_line(tmp_path, old, new, line, match):
    assert TINY.count(old) == 1
    _assert_fails(_write(tmp_path, TINY.replace(old, new)), line, match)


def test_missing_motion_section(tmp_path):
    _assert_fails(_write(tmp_path, TINY[:TINY.index("MOTION")]), 20, "no MOTION section")
    _assert_fails(_write(tmp_path, ""), 1, "starts with HIERARCHY")


def test_every_truncation_fails_cleanly(tmp_path):
    """Every prefix of a valid file (bar the final newline) is an error naming file and line."""
    path = tmp_path / "cut.bvh"
    assert TINY.endswith("0\n")
    for end in range(len(TINY) - 1):
        path.write_text(TINY[:end])
        _assert_fails(path)
    path.write_text(TINY[:-1])
    assert len(read_bvh(path)) == 2


def test_write_rejects_unwritable_names(tmp_path):
    motion = read_bvh(_write(tmp_path, TINY))
    skeleton = motion.skeleton
    bad = replace(skeleton, names=("Hips", "Upper Spine") + skeleton.names[2:])
    with pytest.raises(PriortrackError, match="one word"):
        write_bvh(Motion(bad, motion.channels, 25.0, "bad"), tmp_path / "bad.bvh")
    nan = motion.channels.copy()
    nan[0, 0] = np.nan
    with pytest.raises(PriortrackError, match="non-finite"):
        write_bvh(Motion(skeleton, nan, 25.0, "nan"), tmp_path / "nan.bvh")
