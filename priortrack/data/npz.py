"""Reading npz and npy files without trusting them: every array's header is checked before its data is read."""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np

from priortrack.errors import PriortrackError

#: The dtypes an array may have: numbers, booleans and text (never objects).
ARRAY_KINDS = "biufU"


def _checked_size(stream, where: str, available: int) -> int:
    """The bytes an npy stream's header declares, after its dtype (numbers and text only) and its size
    (at most ``available``) are checked; the stream is left at the data."""
    version = np.lib.format.read_magic(stream)
    shape, _, dtype = (np.lib.format.read_array_header_1_0(stream) if version == (1, 0)
                       else np.lib.format.read_array_header_2_0(stream))
    if dtype.kind not in ARRAY_KINDS or dtype.hasobject:
        raise PriortrackError(f"{where} has dtype {dtype} (numbers and text only)")
    size = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    if size > available:
        raise PriortrackError(f"{where} declares {size} bytes but holds {available}")
    return size


def read_npy(path: str | Path, max_bytes: int, what: str = "npy file") -> np.ndarray:
    """The array of an npy file, its header checked first (:func:`read_npz`'s rules)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            size = _checked_size(f, str(path), path.stat().st_size)
        if size > max_bytes:
            raise PriortrackError(f"{path}: it holds {size} bytes, more than a {what} may ({max_bytes})")
        return np.load(path, allow_pickle=False)
    except (EOFError, ValueError, OSError, TypeError) as exc:
        raise PriortrackError(f"{path} is not a readable {what} (truncated or not npy: {exc})") from None


def read_npz(path: str | Path, max_bytes: int, what: str = "npz file") -> dict[str, np.ndarray]:
    """The arrays of an npz file, after each npy member's header (not its data) is read and the file
    refused if an array declares objects or an unknown dtype, more bytes than its member holds, or more
    than ``max_bytes`` in all; a broken zip (truncated, an unknown version or compression) is refused too."""
    path = Path(path)
    try:
        total = 0
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                with archive.open(info) as member:
                    total += _checked_size(member, f"{path}: array {info.filename}", info.file_size)
        if total > max_bytes:
            raise PriortrackError(f"{path}: its arrays hold {total} bytes, more than a {what} may ({max_bytes})")
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, EOFError, ValueError, OSError, KeyError, TypeError, NotImplementedError,
            RuntimeError, zlib.error) as exc:       # zipfile: an unknown version or compression, encryption
        raise PriortrackError(f"{path} is not a readable {what} (truncated or not npz: {exc})") from None
