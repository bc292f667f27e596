"""The CMU motion-capture clips shipped with priortrack, and the subject-35 walk/jog set.

The data was obtained from mocap.cs.cmu.edu. The database was created with funding from
NSF EIA-0196217.

Bundled names:
- ``cmu:SS_TT``: an original ASF+AMC trial at 120 Hz (``cmu:07_01``);
- ``walkjog:35_TT``: a trial of the subject-35 walk/jog set at 30 fps (``walkjog:35_29``).
"""

from __future__ import annotations

from dataclasses import dataclass
from fnmatch import fnmatchcase
from functools import lru_cache
from pathlib import Path

import numpy as np

from priortrack.data.skeleton import Skeleton
from priortrack.data.amc import read_amc
from priortrack.data.asf import read_asf
from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError

DATA_DIR = Path(__file__).parent / "cmu"
#: Real OpenPose BODY_25B output of 4 calibrated cameras with their Pose2Sim Calib.toml (its SOURCE.md: the
#: Pose2Sim demo's static trial, BSD 3-Clause).
POSE2SIM_DIR = Path(__file__).parent / "pose2sim"
ASF_AMC_DIR = DATA_DIR / "asf_amc"
WALKJOG_PATH = DATA_DIR / "subject35_walkjog" / "cmu35_walkjog_30fps.npz"
CMU_FPS = 120.0

_DESCRIPTIONS = {
    "07": "walk", "35": "walk", "02": "walk", "05": "walk (slower, 0.9 m/s)", "08": "walk", "39": "walk",
    "01": "playground: forward jumps, turn around", "11": "soccer kick", "13": "jump",
    "49": "balance on one leg, arms out", "131": "stylised dance", "135": "martial arts", "141": "run",
}
#: Trials whose motion differs from their subject's (02_03 is a run; 08_04 is a slow walk).
_TRIAL_DESCRIPTIONS = {"02_03": "run/jog", "08_04": "walk (slow)"}

#: The walking people: person → the bundled walks (patterns over bundled names). CMU subjects 08 and 39
#: are one person (the same skeleton file, bone lengths within 2 cm): one entry, never split.
WALKING_PEOPLE: dict[str, tuple[str, ...]] = {
    "07": ("cmu:07_*",),
    "35": ("walkjog:35_0*", "walkjog:35_1[0-6]", "walkjog:35_28", "walkjog:35_29", "walkjog:35_3*"),
    "02": ("cmu:02_01", "cmu:02_02"),
    "05": ("cmu:05_01",),
    "08+39": ("cmu:08_*", "cmu:39_*"),
}


def person_of(subject: str) -> str:
    """The person a CMU subject number names ("39" → "08+39"; any other subject is its own person)."""
    return "08+39" if subject in ("08", "39") else subject


@dataclass(frozen=True)
class BundledClip:
    """One bundled clip: its name for :func:`load_motion`, subject, motion and frame rate."""

    name: str
    subject: str
    description: str
    fps: float
    frames: int

    @property
    def person(self) -> str:
        """The person the clip shows: its subject, except that CMU subjects 08 and 39 are one ("08+39")."""
        return person_of(self.subject)


@dataclass(frozen=True)
class WalkJogSet:
    """CMU subject 35's walk and jog trials at 30 fps with the literature's train/test split.

    Attributes:
        train: 31 motions (trial names ``35_01`` …), test: 2 motions (35_18 jog, 35_29 walk).
        actions: trial name → "walk" or "jog".
    """

    train: tuple[Motion, ...]
    test: tuple[Motion, ...]
    actions: dict[str, str]

    def walks(self, split: str = "train") -> tuple[Motion, ...]:
        """The walking trials of one split ("train" or "test")."""
        return tuple(m for m in getattr(self, split) if self.actions[m.name] == "walk")


def _amc_frames(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line.strip().isdigit())


@lru_cache(maxsize=None)
def cmu_skeleton(subject: str) -> Skeleton:
    """The bundled ASF skeleton of a CMU subject ("07")."""
    known = sorted(p.stem for p in ASF_AMC_DIR.glob("*.asf"))
    path = ASF_AMC_DIR / f"{subject}.asf"
    if subject not in known:                  # names, never paths: nothing outside the bundled data
        raise PriortrackError(f"no bundled skeleton for CMU subject {subject!r}; subjects: {', '.join(known)}")
    return read_asf(path)


def bundled_clips() -> list[BundledClip]:
    """Every bundled clip, ``cmu:`` trials first, then the ``walkjog:`` set."""
    return list(_bundled_clips())


@lru_cache(maxsize=1)
def _bundled_clips() -> tuple[BundledClip, ...]:
    clips = [
        BundledClip(f"cmu:{p.stem}", p.stem.split("_")[0],
                    _TRIAL_DESCRIPTIONS.get(p.stem, _DESCRIPTIONS.get(p.stem.split("_")[0], "")), CMU_FPS, _amc_frames(p))
        for p in sorted(ASF_AMC_DIR.glob("*.amc"))
    ]
    data = walkjog_arrays()
    for split in ("train", "test"):
        for s, trial in enumerate(data[f"trial_{split}"]):
            clips.append(BundledClip(f"walkjog:{trial}", "35", f"{data[f'action_{split}'][s]} ({split})",
                                     float(data["fps"]), int(np.sum(data[f"seq_index_{split}"] == s))))
    return tuple(clips)


@lru_cache(maxsize=1)
def walkjog_arrays() -> dict[str, np.ndarray]:
    """The raw arrays of the subject-35 walk/jog npz (no pickle)."""
    with np.load(WALKJOG_PATH, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def load_walkjog() -> WalkJogSet:
    """Load the subject-35 walk/jog set as :class:`Motion` objects at 30 fps."""
    data = walkjog_arrays()
    skeleton = cmu_skeleton("35")
    if list(data["channel_names"]) != list(skeleton.channel_names):
        raise PriortrackError(f"{WALKJOG_PATH}: channel_names do not match skeleton 35.asf")
    scale = skeleton.channel_scale()
    splits = {}
    actions = {}
    for split in ("train", "test"):
        Y, index = data[f"Y_{split}"].astype(np.float64), data[f"seq_index_{split}"]
        motions = []
        for s, trial in enumerate(data[f"trial_{split}"]):
            motions.append(Motion(skeleton, Y[index == s] * scale, float(data["fps"]), str(trial), "35"))
            actions[str(trial)] = str(data[f"action_{split}"][s])
        splits[split] = tuple(motions)
    return WalkJogSet(splits["train"], splits["test"], actions)


@lru_cache(maxsize=None)
def _amc_channels(trial: str) -> np.ndarray:
    """A bundled trial's channels (T, C), parsed once per process (a table or a leave-one-out evaluation
    loads the same walks for every run), read-only: :func:`load_bundled` hands out copies."""
    channels = read_amc(ASF_AMC_DIR / f"{trial}.amc", cmu_skeleton(trial.split("_")[0]))
    channels.flags.writeable = False
    return channels


def load_bundled(name: str) -> Motion:
    """Load a bundled clip by name (``cmu:07_01`` or ``walkjog:35_29``)."""
    kind, _, trial = name.partition(":")
    if kind == "cmu":
        if trial in {p.stem for p in ASF_AMC_DIR.glob("*.amc")}:     # a name, never a path
            subject = trial.split("_")[0]
            return Motion(cmu_skeleton(subject), _amc_channels(trial).copy(), CMU_FPS, trial, subject)
    elif kind == "walkjog":
        walkjog = load_walkjog()
        for motion in walkjog.train + walkjog.test:
            if motion.name == trial:
                return motion
    names = [c.name for c in bundled_clips()]
    raise PriortrackError(f"unknown bundled motion {name!r}; bundled: {', '.join(names)}")


def expand_sources(sources: list[str]) -> list[str]:
    """Expand shell-style patterns over bundled names (``walkjog:35_0*``, ``cmu:07_*``);
    anything else (a name, a path) is kept as it is. A pattern matching nothing is an error."""
    names = [c.name for c in bundled_clips()]
    expanded = []
    for source in sources:
        if any(ch in source for ch in "*?[") and ":" in source:
            matches = [n for n in names if fnmatchcase(n, source)]
            if not matches:
                raise PriortrackError(f"{source!r} matches no bundled motion; bundled: {', '.join(names)}")
            expanded += matches
        else:
            expanded.append(source)
    return expanded
