"""Files priortrack writes: an output path is checked before any work is done for it.

A fit or a tracking run can take minutes; its output path is checked first (the command line
checks every ``--out`` and ``--rrd`` before it starts), and every writer checks again, so that a
missing folder or a wrong suffix is one ``PriortrackError`` naming the path, never a traceback
from numpy, matplotlib or rerun after the work is done.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from priortrack.errors import PriortrackError


def output_path(path: str | os.PathLike[str], what: str, suffixes: Iterable[str] | None = None) -> Path:
    """``path`` as a ``Path`` once a file can be written there: its folder exists and is writable,
    the path is not itself a folder (nor an existing read-only file), and, when ``suffixes`` is
    given (e.g. ``(".png", ".pdf")``, lower case), its suffix is one of them, case-insensitive.

    ``what`` names the file in the error (e.g. ``"prior file"``); raises ``PriortrackError``."""
    path = Path(path)
    folder = path.parent
    if not folder.is_dir():
        raise PriortrackError(f"cannot write {what} {path}: folder {folder} does not exist")
    if path.is_dir():
        raise PriortrackError(f"cannot write {what} {path}: it is a folder; give a file name")
    if not os.access(folder, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise PriortrackError(f"cannot write {what} {path}: permission denied")
    if suffixes is not None:
        allowed = sorted(suffixes)
        if path.suffix.lower() not in allowed:
            raise PriortrackError(f"cannot write {what} {path}: the suffix must be one of {', '.join(allowed)}")
    return path
