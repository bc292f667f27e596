"""`load_motion`: one entry point for bundled clips, ASF+AMC files and BVH files."""

from __future__ import annotations

from pathlib import Path

from priortrack.data.skeleton import Skeleton
from priortrack.data.amc import read_amc
from priortrack.data.asf import read_asf
from priortrack.data.bundled import load_bundled
from priortrack.data.bvh import read_bvh
from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError

#: Frame rate of CMU AMC files (they do not say it themselves).
AMC_FPS = 120.0


def load_motion(source: str | Path, skeleton: Skeleton | str | Path | None = None,
                fps: float | None = None) -> Motion:
    """Load a motion.

    Args:
        source: a bundled name (``"cmu:07_01"``, ``"walkjog:35_29"``; see
            ``priortrack data list``), a path to an ``.amc`` file or to a ``.bvh`` file.
        skeleton: for an ``.amc``: its skeleton, as a :class:`Skeleton` or a path to an
            ``.asf``. By default CMU naming finds it beside the AMC (``16_15.amc`` → ``16.asf``).
        fps: for an ``.amc``: its frame rate (default 120, CMU's capture rate).
    """
    text = str(source)
    if ":" in text and not Path(text).exists():
        return load_bundled(text)
    path = Path(source)
    suffix = path.suffix.lower()
    if suffix not in (".amc", ".bvh"):
        raise PriortrackError(f"cannot load {text!r}: expected a bundled name such as 'cmu:07_01', "
                              f"an .amc file or a .bvh file")
    if not path.exists():
        raise PriortrackError(f"motion file {path} does not exist")
    if suffix == ".bvh":
        return read_bvh(path)
    subject = path.stem.split("_")[0]
    if skeleton is None:
        asf = path.with_name(f"{subject}.asf")
        if not asf.exists():
            raise PriortrackError(f"no skeleton for {path}: {asf.name} is not beside it (CMU naming); "
                                  f"pass skeleton=PATH_TO.asf")
        skeleton = asf
    if not isinstance(skeleton, Skeleton):
        skeleton = read_asf(skeleton)
    return Motion(skeleton, read_amc(path, skeleton), fps or AMC_FPS, path.stem, subject)
