"""ASF/AMC readers, bundled data, Motion, load_motion: against CMU's own numbers and an
independent implementation of the Acclaim forward kinematics."""

import shutil

import numpy as np
import pytest

import priortrack
from priortrack import PriortrackError, load_motion
from priortrack.data.amc import read_amc
from priortrack.data.asf import INCH, read_asf
from priortrack.data.bundled import ASF_AMC_DIR, bundled_clips, load_walkjog
from priortrack.body.fk import joint_positions
from priortrack.body.layout import layout_names

# CMU's frame counts, from shared/data/README.md.
FRAMES = {
    "07_01": 316, "07_02": 329, "07_09": 306, "07_10": 301, "07_11": 315, "35_01": 358,
    "01_01": 2751, "11_01": 597, "13_39": 351, "49_18": 1102, "49_19": 957, "49_20": 898,
    "131_04": 1086, "135_06": 3261,
}


def _rot(axis, a):
    c, s = np.cos(a), np.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def acclaim_fk(asf_path, amc_frame_lines):
    """Bone end points straight from the Acclaim rules in shared/data/README.md, written
    without priortrack: C = Rz(az)Ry(ay)Rx(ax), M = Rz(rz)Ry(ry)Rx(rx), L = C M Cᵀ,
    G = G_parent L, end = parent end + length·G·direction (ASF units, degrees)."""
    bones, hierarchy, section, bone = {}, {}, None, None
    for line in open(asf_path):
        w = line.split()
        if not w or w[0].startswith("#"):
            continue
        if w[0].startswith(":"):
            section = w[0]
        elif section == ":bonedata":
            if w[0] == "begin":
                bone = {"dof": []}
            elif w[0] == "end":
                bones[bone["name"]] = bone
            elif w[0] in ("name",):
                bone["name"] = w[1]
            elif w[0] == "direction":
                bone["direction"] = np.array(w[1:4], float)
            elif w[0] == "length":
                bone["length"] = float(w[1])
            elif w[0] == "axis":
                bone["axis"] = np.radians(np.array(w[1:4], float))
            elif w[0] == "dof":
                bone["dof"] = w[1:]
        elif section == ":hierarchy" and w[0] not in ("begin", "end"):
            hierarchy[w[0]] = w[1:]
    values = {w[0]: np.array(w[1:], float) for w in (line.split() for line in amc_frame_lines)}
    root = values["root"]
    G = {"root": _rot("z", np.radians(root[5])) @ _rot("y", np.radians(root[4])) @ _rot("x", np.radians(root[3]))}
    end = {"root": root[:3]}
    stack = [("root", c) for c in hierarchy["root"]]
    while stack:
        parent, name = stack.pop()
        b = bones[name]
        C = _rot("z", b["axis"][2]) @ _rot("y", b["axis"][1]) @ _rot("x", b["axis"][0])
        angles = dict(zip(b["dof"], np.radians(values.get(name, np.zeros(0)))))
        M = _rot("z", angles.get("rz", 0)) @ _rot("y", angles.get("ry", 0)) @ _rot("x", angles.get("rx", 0))
        G[name] = G[parent] @ C @ M @ C.T
        end[name] = end[parent] + b["length"] * G[name] @ b["direction"]
        stack += [(name, c) for c in hierarchy.get(name, [])]
    return end


def _frame_lines(amc_path, frame):
    lines = open(amc_path).read().splitlines()
    start = lines.index(str(frame)) + 1
    out = []
    for line in lines[start:]:
        if line.strip().isdigit():
            break
        out.append(line)
    return out


@pytest.mark.parametrize("trial", sorted(FRAMES))
def test_every_bundled_clip_parses_with_constant_bone_lengths(trial):
    motion = load_motion(f"cmu:{trial}")
    assert len(motion) == FRAMES[trial]
    assert motion.fps == 120.0 and motion.subject == trial.split("_")[0]
    p = joint_positions(motion, "full")
    parents = motion.skeleton.parents
    lengths = np.linalg.norm(p[:, 1:] - p[:, parents[1:]], axis=-1)
    assert np.abs(lengths - motion.skeleton.bone_lengths()[1:]).max() < 1e-7
    height = p[0, :, 1].max() - p[0, :, 1].min()
    assert 1.3 < height < 2.0
    assert np.isfinite(p).all()


@pytest.mark.parametrize("trial,frames", [("07_01", (1, 200)), ("131_04", (5, 900)), ("135_06", (3000,))])
def test_fk_matches_independent_acclaim_implementation(trial, frames):
    subject = trial.split("_")[0]
    motion = load_motion(f"cmu:{trial}")
    p = joint_positions(motion, "full")
    unit = INCH / 0.45
    for frame in frames:
        ends = acclaim_fk(ASF_AMC_DIR / f"{subject}.asf", _frame_lines(ASF_AMC_DIR / f"{trial}.amc", frame))
        for bone, end in ends.items():
            # A bone's end is where its children start, or its "_end" joint.
            name = bone if bone == "root" else next(
                (c for c in motion.skeleton.names if c == f"{bone}_end"), None) or \
                motion.skeleton.names[motion.skeleton.children(motion.skeleton.index(bone))[0]]
            np.testing.assert_allclose(p[frame - 1, motion.skeleton.index(name)], end * unit, atol=1e-12)


def test_asf_units_and_channels():
    sk = read_asf(ASF_AMC_DIR / "07.asf")
    assert sk.num_channels == 62 and sk.channel_names[:6] == ("root.tx", "root.ty", "root.tz", "root.rx", "root.ry", "root.rz")
    assert sk.length_unit == pytest.approx(0.0254 / 0.45)
    femur = sk.index("ltibia")   # the joint at the femur's end
    assert np.linalg.norm(sk.offsets[femur]) == pytest.approx(6.92462 * 0.0254 / 0.45)


def test_walkjog_split_and_same_positions_as_120hz_clip():
    walkjog = load_walkjog()
    assert len(walkjog.train) == 31 and [m.name for m in walkjog.test] == ["35_18", "35_29"]
    assert sum(len(m) for m in walkjog.train) == 2644 and sum(len(m) for m in walkjog.test) == 169
    assert walkjog.actions["35_18"] == "jog" and all(m.fps == 30.0 for m in walkjog.train)
    assert len(walkjog.walks("test")) == 1
    at_30 = next(m for m in walkjog.train if m.name == "35_01")
    at_120 = load_motion("cmu:35_01")
    resampled = at_120.resample(30)
    assert len(resampled) == len(at_30)
    # The npz stores float32 (angles in degrees, translations in ASF units): 1e-5 m.
    np.testing.assert_allclose(joint_positions(resampled, "full"), joint_positions(at_30, "full"), atol=1e-5)
    np.testing.assert_allclose(joint_positions(at_120[::4], "full"), joint_positions(at_30, "full"), atol=1e-5)


def test_resample_is_exact_on_source_instants_and_interpolates_between():
    m = load_motion("cmu:07_01")
    np.testing.assert_array_equal(m.resample(30).channels, m.channels[::4])
    up = m.resample(240)
    assert len(up) == 2 * len(m) - 1 and up.fps == 240
    np.testing.assert_array_equal(up.channels[::2], m.channels)
    a, b = m.channels[10], m.channels[11]
    wrapped = np.mod(b - a + np.pi, 2 * np.pi) - np.pi
    wrapped[:3] = (b - a)[:3]
    np.testing.assert_allclose(up.channels[21], a + 0.5 * wrapped, atol=1e-15)


@pytest.mark.parametrize("fps", [0.0, -30.0, float("nan"), float("inf")])
def test_resample_refuses_a_rate_that_is_not_positive_and_finite(fps):
    with pytest.raises(PriortrackError, match="fps must be positive and finite"):
        load_motion("cmu:07_01").resample(fps)


def test_resample_interpolates_the_short_way_round():
    m = load_motion("cmu:07_01")[:2]
    channels = m.channels.copy()
    channels[0, 6], channels[1, 6] = np.radians(179.0), np.radians(-179.0)
    from dataclasses import replace
    up = replace(m, channels=channels).resample(240)
    assert np.degrees(up.channels[1, 6]) == pytest.approx(180.0)


def test_motion_slicing_and_names():
    m = load_motion("cmu:07_01")
    part = m[10:50:2]
    assert len(part) == 20 and part.fps == 60.0
    np.testing.assert_array_equal(part.channels, m.channels[10:50:2])
    assert layout_names(m.skeleton, "eval15")[0] == "pelvis"
    assert len(layout_names(m.skeleton, "full")) == m.skeleton.num_joints
    assert joint_positions(m).shape == (len(m), 15, 3)
    with pytest.raises(PriortrackError, match="slice"):
        m[3]
    with pytest.raises(PriortrackError, match="layout"):
        joint_positions(m, "eval17")


def test_load_motion_paths_and_cmu_naming(tmp_path):
    shutil.copy(ASF_AMC_DIR / "07.asf", tmp_path / "07.asf")
    shutil.copy(ASF_AMC_DIR / "07_02.amc", tmp_path / "07_02.amc")
    m = load_motion(tmp_path / "07_02.amc")
    np.testing.assert_array_equal(m.channels, load_motion("cmu:07_02").channels)
    shutil.copy(ASF_AMC_DIR / "07_02.amc", tmp_path / "16_15.amc")
    with pytest.raises(PriortrackError, match="16.asf"):
        load_motion(tmp_path / "16_15.amc")
    m = load_motion(tmp_path / "16_15.amc", skeleton=tmp_path / "07.asf")
    assert m.name == "16_15" and len(m) == 329
    with pytest.raises(PriortrackError, match="does not exist"):
        load_motion(tmp_path / "nothing.amc")
    with pytest.raises(PriortrackError, match="expected a bundled name"):
        load_motion(tmp_path / "07.asf")


def test_unknown_bundled_name_lists_the_bundled_ones():
    with pytest.raises(PriortrackError, match="cmu:07_01"):
        load_motion("cmu:99_99")
    with pytest.raises(PriortrackError, match="unknown bundled"):
        load_motion("walkjog:35_99")
    assert any(c.name == "walkjog:35_29" for c in bundled_clips())


def test_package_exports():
    assert priortrack.PriortrackError is PriortrackError
    assert issubclass(PriortrackError, ValueError)


# ---- bad input --------------------------------------------------------------------------

@pytest.fixture
def skeleton07():
    return read_asf(ASF_AMC_DIR / "07.asf")


def _amc_text():
    return (ASF_AMC_DIR / "07_01.amc").read_text().splitlines(keepends=True)


@pytest.mark.parametrize("cut", [10, 45, 100, 1000])
def test_truncated_amc_names_file_and_line(tmp_path, skeleton07, cut):
    lines = _amc_text()
    path = tmp_path / "cut.amc"
    path.write_text("".join(lines[:cut]) + lines[cut][: len(lines[cut]) // 2])
    with pytest.raises(PriortrackError, match=r"cut\.amc:\d+"):
        read_amc(path, skeleton07)


@pytest.mark.parametrize("line,replacement,message", [
    (6, "lowerback -6.36782 oops -6.683\n", "not a number"),
    (6, "lowerback -6.36782 -4.70696\n", "has 2 values"),
    (6, "tail 1 2 3\n", "bone 'tail' is not in skeleton"),
    (6, "lowerback nan 0 0\n", "non-finite"),
    (4, "7\n", "frame number 7"),
])
def test_malformed_amc(tmp_path, skeleton07, line, replacement, message):
    lines = _amc_text()
    lines[line - 1] = replacement
    path = tmp_path / "bad.amc"
    path.write_text("".join(lines))
    with pytest.raises(PriortrackError, match=rf"bad\.amc:{line}: .*{message}"):
        read_amc(path, skeleton07)


def test_amc_of_another_skeleton(tmp_path):
    asf = (ASF_AMC_DIR / "07.asf").read_text().replace("name lfemur", "name lthigh").replace(
        "lhipjoint lfemur", "lhipjoint lthigh").replace("lfemur ltibia", "lthigh ltibia")
    (tmp_path / "07.asf").write_text(asf)
    with pytest.raises(PriortrackError, match="bone 'lfemur' is not in skeleton"):
        read_amc(ASF_AMC_DIR / "07_01.amc", read_asf(tmp_path / "07.asf"))


def test_amc_with_all_zero_limb_frames_loads(tmp_path, skeleton07):
    text = "".join(_amc_text())
    text = text.replace("lhumerus -1.92727 -17.3217 82.8203", "lhumerus 0 0 0").replace(
        "lradius 47.7499", "lradius 0")
    path = tmp_path / "zeros.amc"
    path.write_text(text)
    channels = read_amc(path, skeleton07)
    assert np.all(channels[0, [skeleton07.channel_names.index(f"lhumerus.r{a}") for a in "xyz"]] == 0)
    assert np.isfinite(channels).all()


@pytest.mark.parametrize("old,new,message", [
    ("length 6.92462", "length", "length needs 1 numbers"),
    ("direction 0.34202 -0.939693 0  ", "direction 0.34202 x 0", "not a number"),
    ("lfemur ltibia", "lfemur shin", "unknown bone 'shin'"),
    ("dof rx ry rz", "dof rx ry l", "unsupported dof"),
    ("  length 0.45", "  length", "length unit needs 1 numbers"),
])
def test_malformed_asf(tmp_path, old, new, message):
    text = (ASF_AMC_DIR / "07.asf").read_text()
    assert old in text
    path = tmp_path / "bad.asf"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(PriortrackError, match=rf"bad\.asf:\d+: .*{message}"):
        read_asf(path)


def test_truncated_asf(tmp_path):
    text = (ASF_AMC_DIR / "07.asf").read_text()
    for cut in (0.3, 0.6, 0.95):
        path = tmp_path / "cut.asf"
        path.write_text(text[: int(len(text) * cut)])
        with pytest.raises(PriortrackError, match=r"cut\.asf"):
            read_asf(path)


def test_a_motion_played_at_another_pace():
    walk = load_motion("cmu:07_01").resample(30)
    slow = walk.played_at(0.5)
    assert slow.fps == 30 and slow.name == "07_01@0.5" and abs(len(slow) - 2 * len(walk)) <= 1
    np.testing.assert_allclose(slow.channels[::2][:len(walk)], walk.channels[:len(slow.channels[::2])], atol=1e-12)
    with pytest.raises(PriortrackError, match="pace must be a speed"):
        walk.played_at(0.0)


def test_amc_read_a_bone_at_a_time_equals_line_by_line(tmp_path):
    """Every bundled AMC is read by the fast path (each bone's lines of every frame at once), to the bit what
    the line-by-line reader gives; a file whose frames list their bones in different orders (legal AMC) is
    read line by line, to the same channels."""
    from priortrack.data import amc
    from priortrack.data.asf import _Lines
    from priortrack.data.bundled import cmu_skeleton

    for path in sorted(ASF_AMC_DIR.glob("*.amc")):
        skeleton = cmu_skeleton(path.stem.split("_")[0])
        by_bone = {}
        for c, name in enumerate(skeleton.channel_names):
            by_bone.setdefault(name.split(".", 1)[0], []).append(c)
        lines = _Lines(path, "AMC")
        fast = amc._regular_frames(lines, by_bone, skeleton.num_channels)
        assert fast is not None, path.name
        np.testing.assert_array_equal(fast, amc._line_by_line(lines, by_bone, skeleton), err_msg=path.name)
    lines = _amc_text()
    second = next(k for k, line in enumerate(lines) if line.strip() == "2")
    lines[second + 1], lines[second + 2] = lines[second + 2], lines[second + 1]      # frame 2: two bones swapped
    (tmp_path / "shuffled.amc").write_text("".join(lines))
    skeleton = read_asf(ASF_AMC_DIR / "07.asf")
    np.testing.assert_array_equal(read_amc(tmp_path / "shuffled.amc", skeleton), read_amc(ASF_AMC_DIR / "07_01.amc", skeleton))
