"""Reading npz and npy files without trusting them: every array's header is checked before its data is read."""

from __future__ import annotations

import struct
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from priortrack.errors import PriortrackError

#: The dtypes an array may have: numbers, booleans and text (never objects).
ARRAY_KINDS = "biufU"


def _checked_header(stream, where: str, available: int) -> tuple[tuple[int, ...], bool, np.dtype, int]:
    """An npy stream's header: shape, Fortran order, dtype and bytes, after its dtype (numbers and text
    only) and its size (at most ``available``) are checked; the stream is left at the data."""
    version = np.lib.format.read_magic(stream)
    shape, fortran, dtype = (np.lib.format.read_array_header_1_0(stream) if version == (1, 0)
                             else np.lib.format.read_array_header_2_0(stream))
    if dtype.kind not in ARRAY_KINDS or dtype.hasobject:
        raise PriortrackError(f"{where} has dtype {dtype} (numbers and text only)")
    size = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    if size > available:
        raise PriortrackError(f"{where} declares {size} bytes but holds {available}")
    return shape, fortran, dtype, size


def _checked_size(stream, where: str, available: int) -> int:
    """The bytes an npy stream's header declares (:func:`_checked_header`)."""
    return _checked_header(stream, where, available)[3]


@dataclass(frozen=True)
class ArrayOnDisk:
    """An array (A, B, …) stored uncompressed in C order in a file (an .npy, or an .npz's stored member),
    read a slice of its second axis at a time: ``[:, start:stop]`` costs A reads of contiguous bytes and
    only that slice's memory (a long recording's keypoints (cameras, frames, …), a block of frames).

    Attributes:
        path: the file; offset: where the array's data begins in it, bytes; shape, dtype: the header's."""

    path: Path
    offset: int
    shape: tuple[int, ...]
    dtype: np.dtype

    def columns(self, start: int, stop: int) -> np.ndarray:
        """array[:, start:stop] (A, stop − start, …), read from the file; a file cut short is refused."""
        A, B = self.shape[:2]
        start, stop = max(0, start), min(B, stop)
        inner = int(np.prod(self.shape[2:], dtype=np.int64))
        count = max(stop - start, 0) * inner
        out = np.empty((A, max(stop - start, 0)) + tuple(self.shape[2:]), dtype=self.dtype)
        with open(self.path, "rb") as f:
            for a in range(A):
                f.seek(self.offset + (a * B + start) * inner * self.dtype.itemsize)
                data = f.read(count * self.dtype.itemsize)
                if len(data) != count * self.dtype.itemsize:
                    raise PriortrackError(f"{self.path} is cut short: its array ends before row {a}, columns "
                                          f"{start}–{stop}")
                out[a] = np.frombuffer(data, dtype=self.dtype).reshape(out.shape[1:])
        return out


def npy_on_disk(path: str | Path, max_bytes: int, what: str = "npy file") -> ArrayOnDisk | None:
    """An npy file's array as an :class:`ArrayOnDisk` (header checked as :func:`read_npy` checks it), or
    None where it is stored in Fortran order or has fewer than two axes (read it whole)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            shape, fortran, dtype, size = _checked_header(f, str(path), path.stat().st_size)
            offset = f.tell()
    except (EOFError, ValueError, OSError, TypeError) as exc:
        raise PriortrackError(f"{path} is not a readable {what} (truncated or not npy: {exc})") from None
    if size > max_bytes:
        raise PriortrackError(f"{path}: it holds {size} bytes, more than a {what} may ({max_bytes})")
    return None if fortran or len(shape) < 2 else ArrayOnDisk(path, offset, tuple(shape), dtype)


def npz_member_on_disk(path: str | Path, name: str) -> ArrayOnDisk | None:
    """The array ``name`` of an npz file as an :class:`ArrayOnDisk` (its header checked as :func:`read_npz`
    checks it), or None where its member is compressed (``np.savez_compressed``), in Fortran order, or has
    fewer than two axes (read it whole)."""
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            if f"{name}.npy" not in archive.namelist():
                raise PriortrackError(f"{path}: the array {name!r} is missing")
            info = archive.getinfo(f"{name}.npy")
        if info.compress_type != zipfile.ZIP_STORED:
            return None
        with open(path, "rb") as f:
            f.seek(info.header_offset)
            local = f.read(30)                     # the local file header: its name and extra field follow
            if len(local) != 30 or local[:4] != b"PK\x03\x04":
                raise PriortrackError(f"{path}: the member {name}.npy has no local header where the zip says")
            f.seek(info.header_offset + 30 + sum(struct.unpack("<HH", local[26:30])))
            start = f.tell()
            shape, fortran, dtype, _ = _checked_header(f, f"{path}: array {name}", info.file_size)
            offset = f.tell()
    except (zipfile.BadZipFile, EOFError, ValueError, OSError) as exc:
        raise PriortrackError(f"{path} is not a readable npz file ({exc})") from None
    if offset - start + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize > info.file_size:
        raise PriortrackError(f"{path}: array {name} declares more bytes than its member holds")
    return None if fortran or len(shape) < 2 else ArrayOnDisk(path, offset, tuple(shape), dtype)


def npz_member_shape(path: str | Path, name: str) -> tuple[int, ...] | None:
    """The shape an npz file's array ``name`` declares, from its header alone (compressed or not; checked as
    :func:`read_npz` checks it); None where the file has no such array."""
    try:
        with zipfile.ZipFile(path) as archive:
            if f"{name}.npy" not in archive.namelist():
                return None
            info = archive.getinfo(f"{name}.npy")
            with archive.open(info) as stream:
                return tuple(_checked_header(stream, f"{path}: array {name}", info.file_size)[0])
    except (zipfile.BadZipFile, EOFError, ValueError, OSError, zlib.error) as exc:
        raise PriortrackError(f"{path} is not a readable npz file ({exc})") from None


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


def read_npz(path: str | Path, max_bytes: int, what: str = "npz file", skip: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The arrays of an npz file, after each npy member's header (not its data) is read and the file
    refused if an array declares objects or an unknown dtype, more bytes than its member holds, or more
    than ``max_bytes`` in all; a broken zip (truncated, an unknown version or compression) is refused too.
    The arrays named in ``skip`` are checked but not read (:func:`npz_member_on_disk` reads them in pieces)."""
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
            return {k: z[k] for k in z.files if k not in skip}
    except (zipfile.BadZipFile, EOFError, ValueError, OSError, KeyError, TypeError, NotImplementedError,
            RuntimeError, zlib.error) as exc:       # zipfile: an unknown version or compression, encryption
        raise PriortrackError(f"{path} is not a readable {what} (truncated or not npz: {exc})") from None
