"""OpenSim motion (``.mot``) files of joint angles, as OpenSim's Storage reads them and its tools write them.

Layout (tab-separated)::

    <name>
    version=1
    nRows=<T>
    nColumns=<1 + columns>
    inDegrees=yes
    endheader
    time  <column 1>  <column 2> …
    <t>   <value>     <value>    …

A value that is not known is written ``NaN``, which OpenSim reads as not-a-number.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from priortrack.errors import PriortrackError
from priortrack.output import output_path


def write_mot(path: str | Path, times: np.ndarray, columns: dict[str, np.ndarray], in_degrees: bool = True) -> Path:
    """Write ``columns`` {name: (T,)} at ``times`` (T,) seconds as an OpenSim ``.mot`` file (module docstring)."""
    times = np.asarray(times, dtype=np.float64)
    values = np.column_stack([times] + [np.asarray(v, dtype=np.float64) for v in columns.values()])
    if values.shape != (len(times), 1 + len(columns)):
        raise PriortrackError(f"every .mot column needs {len(times)} values")
    path = output_path(path, ".mot file", (".mot",))
    lines = [path.stem, "version=1", f"nRows={len(times)}", f"nColumns={1 + len(columns)}",
             f"inDegrees={'yes' if in_degrees else 'no'}", "endheader", "\t".join(["time", *columns])]
    lines += ["\t".join("NaN" if not np.isfinite(v) else repr(float(v)) for v in row) for row in values]
    path.write_text("\n".join(lines) + "\n")
    return path
