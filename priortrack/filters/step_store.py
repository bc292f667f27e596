"""The steps a whole run's smoother reads, and the smoother's own per-frame arrays, held in memory up to a
budget and spilled to disk past it.

A particle filter's step, as the smoother reads it (:meth:`Snapshot.for_smoothing`), is its states,
weights, ancestors and translation covariances: pf-lie's 1,000 particles take 376 kB a tick, 6.8 GB
for ten minutes at 30 ticks a second (the unscented filter's mean and covariance 31 kB).
:class:`StepStore` keeps the steps in memory while their arrays total at most ``memory`` bytes; each
later step's arrays go to a ``.npy`` file of their own in a temporary folder (numpy's format, no
pickle) and are read back when the smoother asks for that step, so a run's length alone never
exhausts the memory. The folder goes with :meth:`StepStore.close`
(or when the store is collected).

The unscented smoother's own per-frame matrices (the smoothed covariances, and the posterior-linearisation
pass's gains: three n × n matrices a frame, 93 kB for ukf-real) are :class:`RecordArray` s of the same
budget: in memory where they fit, else records of a temporary file read and written one at a time.
"""

from __future__ import annotations

import logging
import math
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from priortrack.errors import PriortrackError
from priortrack.filters.snapshot import Snapshot

log = logging.getLogger(__name__)

#: The arrays of a step that a smoother reads (the rest of a Snapshot is a few numbers).
ARRAYS = ("particles", "weights", "ancestors", "translation_covariance", "mean", "covariance")

#: The default budget in bytes (``track --memory``): the steps of a whole run held in memory before spilling
#: (1 GB: with the rest of a run and the smoother's own arrays, a 10-minute pf-lie run stays under 4 GB).
DEFAULT_MEMORY = 1024 ** 3


def parse_memory(text: str) -> int:
    """"500MB", "2GB", "1.5G", "800M" or a number of bytes → bytes (powers of 1024); a PriortrackError
    naming the text otherwise."""
    units = {"": 1, "B": 1, "K": 1024, "KB": 1024, "M": 1024 ** 2, "MB": 1024 ** 2, "G": 1024 ** 3, "GB": 1024 ** 3}
    stripped = str(text).strip().upper()
    number = stripped.rstrip("KMGB")
    try:
        value = float(number) * units[stripped[len(number):]]
    except (ValueError, KeyError):
        value = -1.0
    if not 0 <= value < 1024 ** 5 or not np.isfinite(value):
        raise PriortrackError(f"--memory {text!r}: give a size such as 500MB or 2GB (0: spill every step)")
    return int(value)


def step_bytes(snapshot: Snapshot) -> int:
    """The bytes of a step's arrays (:data:`ARRAYS`)."""
    return sum(a.nelement() * a.element_size() for a in (getattr(snapshot, n) for n in ARRAYS) if a is not None)


class StepStore(Sequence):
    """An append-only sequence of steps (:meth:`Snapshot.for_smoothing` forms) within a memory budget.

    Args:
        memory: bytes of step arrays held in memory; the steps past it are spilled (0: every one).
        folder: where the temporary folder goes (default: the system's temporary directory).

    Indexing returns the step with its arrays (read back from disk, onto the device they were on,
    for a spilled step); ``spilled`` counts the steps on disk and ``held`` the bytes in memory.
    """

    def __init__(self, memory: int = DEFAULT_MEMORY, folder: str | Path | None = None):
        if memory < 0:
            raise PriortrackError(f"the smoother's memory budget must be ≥ 0 bytes, got {memory}")
        self.memory, self.held, self.spilled = int(memory), 0, 0
        self._folder = folder
        self._directory: tempfile.TemporaryDirectory | None = None
        self._steps: list[Snapshot] = []
        self._devices: list[torch.device | None] = []

    def append(self, snapshot: Snapshot) -> None:
        step = snapshot.for_smoothing()
        size = step_bytes(step)
        if self.held + size <= self.memory:
            self._steps.append(step)
            self._devices.append(None)
            self.held += size
            return
        if self._directory is None:
            self._directory = tempfile.TemporaryDirectory(prefix="priortrack-steps-", dir=self._folder)
            log.info("the smoother's steps exceed %.0f MB: spilling them to %s", self.memory / 1024 ** 2,
                     self._directory.name)
        index = len(self._steps)
        device = None
        for name in ARRAYS:
            array = getattr(step, name)
            if array is not None:
                device = array.device
                np.save(self._path(index, name), array.detach().cpu().numpy(), allow_pickle=False)
        self._steps.append(replace(step, **{name: None for name in ARRAYS}))
        self._devices.append(device)
        self.spilled += 1

    def array(self, index: int, name: str) -> torch.Tensor | None:
        """One array (``ARRAYS``) of step ``index``: a spilled step's read from its own file alone; any
        other field of the step (kept in memory) as it is."""
        step, device = self._steps[index], self._devices[index]
        if device is None or name not in ARRAYS:
            return getattr(step, name)
        path = self._path(range(len(self))[index], name)
        return torch.from_numpy(np.load(path, allow_pickle=False)).to(device) if path.exists() else None

    def truncate(self, length: int) -> None:
        """Keep the first ``length`` steps (an interrupted run's), forgetting the rest."""
        for index in range(length, len(self)):
            if self._devices[index] is None:
                self.held -= step_bytes(self._steps[index])
            else:
                self.spilled -= 1
                for name in ARRAYS:
                    self._path(index, name).unlink(missing_ok=True)
        del self._steps[length:], self._devices[length:]

    def _path(self, index: int, name: str) -> Path:
        return Path(self._directory.name) / f"{index:07d}-{name}.npy"

    def __len__(self) -> int:
        return len(self._steps)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        if self._devices[index] is None:
            return self._steps[index]
        return replace(self._steps[index], **{name: self.array(index, name) for name in ARRAYS})

    def close(self) -> None:
        """Remove the spilled steps' folder (the store is empty after)."""
        self._steps.clear()
        self._devices.clear()
        self.held = self.spilled = 0
        if self._directory is not None:
            self._directory.cleanup()
            self._directory = None


class Column(Sequence):
    """One array of every step, read when indexed (from a :class:`StepStore`, a spilled step's one file),
    through ``transform`` if given: what backward simulation walks through, one frame at a time."""

    def __init__(self, steps: Sequence[Snapshot], name: str, transform: Callable | None = None):
        self.steps, self.name, self.transform = steps, name, transform

    def __len__(self) -> int:
        return len(self.steps)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        steps = self.steps
        array = steps.array(index, self.name) if isinstance(steps, StepStore) else getattr(steps[index], self.name)
        return array if self.transform is None or array is None else self.transform(array)


class RecordArray(Sequence):
    """``length`` float64 records of one ``shape``, indexed by record: a numpy array where they total at most
    ``memory`` bytes (None: no limit), else the fixed-size records of a temporary file, each read or written
    alone (numpy's raw float64 bytes), so that the array does not hold the process's memory.

    ``a[k]`` reads record k ((*shape) array; a slice: the records stacked), ``a[k] = value`` writes it;
    :meth:`close` removes the file."""

    def __init__(self, length: int, shape: tuple[int, ...], memory: int | None = None, folder: str | Path | None = None):
        self.shape, self._count = tuple(shape), math.prod(shape)
        self._length = int(length)
        size = self._length * self._count * 8
        self._directory: tempfile.TemporaryDirectory | None = None
        if memory is None or size <= memory:
            self._data, self._file = np.empty((self._length, *self.shape)), None
            return
        self._data = None
        self._directory = tempfile.TemporaryDirectory(prefix="priortrack-records-", dir=folder)
        self._file = open(Path(self._directory.name) / "records.bin", "w+b")
        self._file.truncate(size)
        log.info("%d records of %s (%.0f MB) past the memory budget: kept in %s", self._length, self.shape,
                 size / 1024 ** 2, self._directory.name)

    @property
    def spilled(self) -> bool:
        """Whether the records are in a file."""
        return self._file is not None

    def __len__(self) -> int:
        return self._length

    def __getitem__(self, index):
        if isinstance(index, slice):
            if self._file is None:
                return self._data[index]
            return np.stack([self[k] for k in range(*index.indices(self._length))])
        k = range(self._length)[index]
        if self._file is None:
            return self._data[k]
        self._file.seek(k * self._count * 8)
        return np.fromfile(self._file, dtype=np.float64, count=self._count).reshape(self.shape)

    def __setitem__(self, index: int, value: np.ndarray) -> None:
        k = range(self._length)[index]
        if self._file is None:
            self._data[k] = value
            return
        value = np.ascontiguousarray(value, dtype=np.float64)
        if value.shape != self.shape:
            raise PriortrackError(f"record of shape {value.shape}: expected {self.shape}")
        self._file.seek(k * self._count * 8)
        value.tofile(self._file)

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self[:], dtype=dtype)

    def close(self) -> None:
        """Remove the records' file (the array is unusable after)."""
        if self._file is not None:
            self._file.close()
            self._directory.cleanup()
            self._file = self._directory = None
