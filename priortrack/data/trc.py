"""TRC marker files, as OpenSim reads them and Pose2Sim writes them.

Layout (tab-separated; Pose2Sim's ``make_trc``)::

    PathFileType  4  (X/Y/Z)  <file name>
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    <fps>  <fps>  <T>  <J>  m  <fps>  <first frame>  <T>
    Frame#  Time  <name 1>  (two empty cells)  <name 2> …
    (two empty cells)  X1  Y1  Z1  X2  Y2  Z2 …
    1  <t>  x  y  z …

Coordinates are Y-up, as OpenSim wants them: a Z-up world (Pose2Sim's calibrations) is written as
(X, Y, Z)_trc = (Y, Z, X)_world, Pose2Sim's ``zup2yup``; a Y-up world as it is. Missing markers are
empty cells.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from priortrack.errors import PriortrackError
from priortrack.output import output_path

#: World up axis → the permutation of world axes that gives the TRC's X, Y, Z.
_TO_TRC = {"y": [0, 1, 2], "z": [1, 2, 0]}


def write_trc(path: str | Path, joints: np.ndarray, names, fps: float, up: str = "y", first_frame: int = 0) -> Path:
    """Write joints (T, J, 3) metres of a world whose up axis is ``up`` ("y" or "z") as a TRC file."""
    if up not in _TO_TRC:
        raise PriortrackError(f"TRC files are Y-up: write from a Y-up or Z-up world, not {up!r}")
    joints = np.asarray(joints, dtype=np.float64)
    T, J = joints.shape[:2]
    if joints.shape != (T, len(names), 3):
        raise PriortrackError(f"joints have shape {joints.shape}; expected (T, {len(names)}, 3)")
    path = output_path(path, "TRC file")
    rows = joints[..., _TO_TRC[up]].reshape(T, -1)
    lines = [f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
             "\t".join(map(str, [f"{fps:g}", f"{fps:g}", T, J, "m", f"{fps:g}", first_frame, T])),
             "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
             "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(J))]
    for t in range(T):
        cells = ["" if not np.isfinite(v) else repr(float(v)) for v in rows[t]]
        lines.append("\t".join([str(t + 1), repr(t / fps)] + cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def read_trc(path: str | Path, up: str = "y") -> tuple[np.ndarray, tuple[str, ...], float]:
    """Read a TRC file: joints (T, J, 3) in a world whose up axis is ``up`` (the inverse of
    :func:`write_trc`'s axes), marker names, data rate. Empty cells are NaN; units mm are converted."""
    path = Path(path)
    if up not in _TO_TRC:
        raise PriortrackError(f"TRC files are Y-up: read into a Y-up or Z-up world, not {up!r}")
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError as exc:
        raise PriortrackError(f"{path}: cannot be read ({exc})") from None
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise PriortrackError(f"{path}: not a TRC file (no PathFileType header)")
    keys, values = lines[1].split("\t"), lines[2].split("\t")
    header = dict(zip(keys, values))
    try:
        fps, J = float(header["DataRate"]), int(header["NumMarkers"])
    except (KeyError, ValueError):
        raise PriortrackError(f"{path}: line 3 lacks a DataRate or NumMarkers") from None
    scale = {"m": 1.0, "mm": 0.001, "cm": 0.01}.get(header.get("Units", "m"))
    if scale is None:
        raise PriortrackError(f"{path}: unknown units {header.get('Units')!r}")
    names = tuple(n for n in lines[3].split("\t")[2:] if n)
    if len(names) != J:
        raise PriortrackError(f"{path}: line 4 names {len(names)} markers, the header says {J}")
    rows = []
    for number, line in enumerate(lines[5:], start=6):
        if not line.strip():
            continue
        cells = line.split("\t")[2:2 + 3 * J]
        cells += [""] * (3 * J - len(cells))
        try:
            rows.append([float(c) if c.strip() else np.nan for c in cells])
        except ValueError:
            raise PriortrackError(f"{path}, line {number}: a coordinate is not a number") from None
    trc = np.array(rows, dtype=np.float64).reshape(-1, J, 3) * scale
    world = np.empty_like(trc)
    world[..., _TO_TRC[up]] = trc
    return world, names, fps
