"""The prior cache: fitted priors and their support references, each file beside the SHA-256 of its bytes
(a file that does not match is refitted, never trusted), written atomically; in ``$PRIORTRACK_CACHE``, else
``$XDG_CACHE_HOME/priortrack/priors``, else ``~/.cache/priortrack/priors``."""

from __future__ import annotations

import hashlib
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from priortrack.errors import PriortrackError

log = logging.getLogger(__name__)


def _digest_path(path: Path) -> Path:
    return path.with_suffix(".sha256")


def read_cached(path: Path, load: Callable[[Path], Any], what: str = "prior"):
    """``load(path)`` of the cache entry ``path`` if it is a regular file (not a link) whose SHA-256
    matches the digest written beside it; None (logged) otherwise, for a refit."""
    if not path.exists() and not path.is_symlink():
        return None
    digest = _digest_path(path)
    if path.is_symlink() or digest.is_symlink() or not path.is_file() or not digest.is_file():
        log.warning("cached %s %s is a link or lacks its digest: not used, refitting", what, path)
        return None
    try:
        if hashlib.sha256(path.read_bytes()).hexdigest() != digest.read_text().strip():
            log.warning("cached %s %s does not match its digest (corrupted or replaced): refitting", what, path)
            return None
        log.info("%s from cache %s", what, path)
        return load(path)
    except (OSError, PriortrackError) as exc:
        log.warning("cached %s %s cannot be read (%s): refitting", what, path, exc)
        return None


def write_cached(path: Path, save: Callable[[Path], Any], what: str = "prior") -> None:
    """Write a cache entry by ``save(file)`` and its digest atomically (each to a partial file, then
    renamed); a cache that cannot be written costs the next run a refit, no more."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_suffix(f".partial{os.getpid()}" + path.suffix)     # one per process writing it
        save(partial)
        text = hashlib.sha256(partial.read_bytes()).hexdigest()
        digest_partial = _digest_path(path).with_suffix(f".partial{os.getpid()}.sha256")
        digest_partial.write_text(text + "\n")
        partial.replace(path)
        digest_partial.replace(_digest_path(path))
        log.info("fitted %s cached at %s", what, path)
    except (PriortrackError, OSError) as exc:
        log.warning("fitted %s not cached (%s)", what, exc)


def cache_dir() -> Path:
    """``$PRIORTRACK_CACHE``, else ``$XDG_CACHE_HOME/priortrack/priors``, else ``~/.cache/priortrack/priors``."""
    if os.environ.get("PRIORTRACK_CACHE"):
        return Path(os.environ["PRIORTRACK_CACHE"])
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "priortrack" / "priors"
