"""A tracked result drawn for those who would rather look than read: ``priortrack plot RESULT.npz``.

One row per person (a scene's ``.npz`` holds several, one person's one), three panels over time (seconds from the
first frame written): the pelvis's three world coordinates (metres: where they went), each camera's median
reprojection error (pixels: which camera disagreed, and when), and the filter's effective sample size (a particle
filter's; otherwise each joint's spread, millimetres: how sure it was). Ticks flagged as mismatch are shaded red in
every panel: where to look in the recording.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backend_bases import FigureCanvasBase
from matplotlib.figure import Figure

from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.data.npz import read_npz
from priortrack.errors import PriortrackError
from priortrack.output import output_path
from priortrack.tracking.resample import finite_runs

#: The most a result file may hold, bytes.
MAX_RESULT_BYTES = 8 << 30
_NEEDED = ("joints", "fps", "frames", "mismatch", "reprojection_px", "camera_names")


def is_result(path: str | Path) -> bool:
    """Whether ``path`` is an ``.npz`` holding a tracking result's arrays (by its members' names; nothing is read)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            names = {Path(n).stem for n in archive.namelist()}
    except (OSError, zipfile.BadZipFile):
        return False
    return set(_NEEDED) <= names


def read_result(path: str | Path) -> dict:
    """A result ``.npz`` of ``track --detections`` (one person's or a scene's) as one person's arrays per person:
    {"ids": (P,), "time": (F,), "joints": (F, P, 15, 3), "reprojection": (F, P, C), "mismatch": (F, P),
    "ess": (F, P), "spread": (F, P, 15), "cameras": (C,)}; a file that is not one is refused by name."""
    arrays = read_npz(path, MAX_RESULT_BYTES, "result file")
    missing = [k for k in _NEEDED if k not in arrays]
    if missing:
        raise PriortrackError(f"{path}: not a tracking result of priortrack track --detections (no "
                              f"{', '.join(missing)})")
    scene = "person_ids" in arrays
    add = (lambda a: a) if scene else (lambda a: np.asarray(a)[:, None])           # one person: P = 1
    frames, fps = np.asarray(arrays["frames"]), float(arrays["fps"])
    # at the detections' frames, each one's time; on the filter's ticks (some without a frame), the ticks'
    time = (frames - frames[0] if len(frames) and (frames >= 0).all() else np.arange(len(frames))) / fps
    joints = add(arrays["joints"])
    return {"ids": np.asarray(arrays["person_ids"]) if scene else np.array([0]), "time": time, "joints": joints,
            "reprojection": add(arrays["reprojection_px"]), "mismatch": add(arrays["mismatch"]).astype(bool),
            "ess": add(arrays["ess"]) if "ess" in arrays else np.full(joints.shape[:2], np.nan),
            "spread": add(arrays["spread"]) if "spread" in arrays else np.full(joints.shape[:3], np.nan),
            "cameras": [str(c) for c in arrays["camera_names"]], "scene": scene}


def _shade(ax, time: np.ndarray, flagged: np.ndarray) -> None:
    """Shade the runs of flagged ticks in red."""
    step = np.median(np.diff(time)) if len(time) > 1 else 1.0
    for start, stop in finite_runs(flagged):
        ax.axvspan(time[start] - step / 2, time[stop - 1] + step / 2, color="red", alpha=0.2, lw=0)


def plot_result(path: str | Path, out: str | Path) -> Path:
    """Draw the result at ``path`` (module docstring) into ``out`` (PNG, or any format matplotlib infers from the
    suffix), without pyplot. Returns ``out``."""
    out = output_path(out, "plot", suffixes=(f".{f}" for f in FigureCanvasBase.get_supported_filetypes()))
    r = read_result(path)
    P = len(r["ids"])
    fig = Figure(figsize=(15, 3.2 * P), dpi=100)
    axes = np.atleast_2d(fig.subplots(P, 3, squeeze=False))
    pelvis = EVAL15_NAMES.index("pelvis")
    for p, row in enumerate(axes):
        who = f"person {int(r['ids'][p])}" if r["scene"] else "the person"
        for k, axis in enumerate("xyz"):
            row[0].plot(r["time"], r["joints"][:, p, pelvis, k], label=axis)
        row[0].set_ylabel("pelvis (m)")
        row[0].set_title(f"{who}: where", fontsize=9)
        row[0].legend(fontsize=7)
        for c, camera in enumerate(r["cameras"]):
            row[1].plot(r["time"], r["reprojection"][:, p, c], label=camera)
        row[1].set_ylabel("median reprojection (px)")
        row[1].set_title(f"{who}: each camera's detections against the estimate", fontsize=9)
        row[1].legend(fontsize=7)
        if np.isfinite(r["ess"][:, p]).any():
            row[2].plot(r["time"], r["ess"][:, p])
            row[2].set_ylabel("effective sample size")
        else:
            for name in ("pelvis", "rwrist", "lwrist", "rankle", "lankle"):
                row[2].plot(r["time"], 1000 * r["spread"][:, p, EVAL15_NAMES.index(name)], label=name)
            row[2].set_ylabel("spread (mm)")
            row[2].legend(fontsize=7)
        row[2].set_title(f"{who}: how sure (mismatch ticks in red: {int(r['mismatch'][:, p].sum())})", fontsize=9)
        for ax in row:
            _shade(ax, r["time"], r["mismatch"][:, p])
            ax.set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(out)
    return out
