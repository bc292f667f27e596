"""``priortrack compare``: a grid of filters × motions × scenarios × seeds, run serially or on Dask,
cached by configuration, written as a CSV, a Markdown summary, plots and (optionally) recordings.

Every argument is checked before any work starts (:func:`plan`): presets are parsed, motions
loaded, scenarios parsed, counts checked. Each run is one :func:`~priortrack.experiments.tracking.track`
on one torch thread (so that a serial run and a Dask run of the same grid give the same numbers:
the GPDM fits, and some reductions, part in their last digits with the thread count), its priors
fitted once beforehand in this process.

**Cache.** A run's configuration hash (:attr:`RunConfig.key`) covers the preset file's text, the
motion (its name and, for a file, its bytes), the scenario, seed, frame count, smoothing, the
thread count and priortrack's version. ``DIR/runs/<hash>.json`` (the CSV row) and ``<hash>.npz``
(its per-frame series) are written when a run finishes; a run whose files are there is not run
again, so a rerun of the same grid does no work and an interrupted one resumes.

**Dask.** ``workers`` starts a ``LocalCluster`` of that many one-thread worker processes;
``scheduler`` (``tcp://host:port``) uses a running one (a lab's ``dask-scheduler``, or
dask-jobqueue's SLURM cluster). A worker gets the configuration (text) and returns the row and the
series (numbers); this process writes every file, so workers need no shared folder, only
priortrack installed and the priors' cache (fitted here first, or fitted there on first use).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from priortrack.errors import PriortrackError

log = logging.getLogger(__name__)

#: A frame whose MPJPE exceeds this (mm) counts as a tracking failure.
FAILURE_MM = 200.0
#: Torch threads per run (serial and on Dask alike: the same numbers either way).
RUN_THREADS = 1
#: The CSV's columns, in order.
COLUMNS = ("filter", "motion", "scenario", "seed", "mpjpe_mm", "rootrel_mm", "px_err", "failure_rate",
           "s_per_frame", "mean_ess", "mismatch_fraction", "config_hash")
SMOOTHED_COLUMNS = ("filtered_mpjpe_mm", "filtered_rootrel_mm")
#: The series kept per run (DIR/runs/<hash>.npz), each (T,).
SERIES = ("error_mm", "ess", "observed_fraction")
#: The most a run's series file may hold (a detections run of 10⁶ ticks: five (T, 12) float64 series).
SERIES_BYTES = 5 * 12 * 8 * 10**6


def config_key(config, contents: bytes) -> str:
    """The hash of a run's configuration (a dataclass with a ``filter``), 16 hex digits: its fields, the
    torch threads of a run, priortrack's version, the preset file's text, then ``contents`` (the bytes of
    the run's input files, or their digests)."""
    from priortrack import __version__
    from priortrack.tracking.presets import preset_path

    digest = hashlib.sha256(json.dumps([asdict(config), RUN_THREADS, __version__], sort_keys=True).encode())
    digest.update(preset_path(config.filter).read_bytes())
    digest.update(contents)
    return digest.hexdigest()[:16]


@dataclass(frozen=True)
class RunConfig:
    """One run of the grid (plain values: what a Dask worker is sent)."""

    filter: str
    motion: str
    scenario: str
    seed: int
    frames: int | None = None
    smooth: bool = False

    @cached_property
    def key(self) -> str:
        """The configuration hash (module docstring), 16 hex digits; computed once (it reads the
        preset file, and a motion file's bytes)."""
        motion = Path(self.motion)
        return config_key(self, motion.read_bytes() if motion.is_file() else b"")

    @property
    def label(self) -> str:
        """filter · motion · scenario · seed: the run's name in recordings and logs."""
        return f"{self.filter} · {self.motion} · {self.scenario} · seed {self.seed}"

    @property
    def recording_stem(self) -> str:
        return "_".join((self.filter, Path(self.motion).name, self.scenario, f"seed{self.seed}"))

    def run(self, cache: str | None = None, rrd: bool = False) -> tuple[dict, dict[str, list[float]], bytes | None]:
        return run(self, cache, rrd)

    @staticmethod
    def write_results(rows: Sequence[dict], series: dict[str, dict[str, np.ndarray]], out: Path) -> None:
        """``out``/results.csv, summary.md and plots/."""
        from priortrack.viz.compare_plots import write_plots

        write_csv(rows, out / "results.csv",
                  list(COLUMNS) + [c for c in SMOOTHED_COLUMNS if any(c in r for r in rows)])
        (out / "summary.md").write_text(summary_markdown(rows))
        write_plots(rows, series, out / "plots")


def check_grid(filters: Sequence[str], seeds: int, frames: int | None, smooth: bool, **lists: Sequence[str]) -> None:
    """The checks every grid's arguments share (one PriortrackError naming the first bad one): ``filters``
    and each of ``lists`` non-empty and without repeats, the presets readable (and smoothable with
    ``smooth``), ``seeds`` positive, ``frames`` None or at least 3 (two known, one tracked)."""
    from priortrack.tracking.presets import UNSCENTED_KINDS, load_preset

    for name, values in (("filters", filters), *lists.items()):
        if not values:
            raise PriortrackError(f"compare: give at least one of --{name}")
        repeated = sorted({v for v in values if list(values).count(v) > 1})
        if repeated:
            raise PriortrackError(f"compare: --{name} repeats {', '.join(repeated)}")
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise PriortrackError(f"compare: --seeds must be a positive whole number, got {seeds!r}")
    if frames is not None and (isinstance(frames, bool) or not isinstance(frames, int) or frames < 3):
        raise PriortrackError(f"compare: --frames must be at least 3 (two known, one tracked), got {frames!r}")
    for name in filters:
        preset = load_preset(name)
        if smooth and preset.filter_kind not in ("pf", *UNSCENTED_KINDS):
            raise PriortrackError(f"compare: --smooth needs particle or unscented filters; {name} is a "
                                  f"{preset.filter_kind!r} filter")


def plan(filters: Sequence[str], motions: Sequence[str], scenarios: Sequence[str], seeds: int,
         frames: int | None = None, smooth: bool = False) -> list[RunConfig]:
    """Every run of the grid, after checking every argument (one PriortrackError naming the first
    bad one, before any work)."""
    from priortrack.data.load import load_motion
    from priortrack.observation.synthetic import parse_scenario

    check_grid(filters, seeds, frames, smooth, motions=motions, scenarios=scenarios)
    for name in motions:
        load_motion(name)
    for spec in scenarios:
        parse_scenario(spec)
    return [RunConfig(f, m, s, seed, frames, smooth) for f in filters for m in motions for s in scenarios
            for seed in range(seeds)]


def run(config: RunConfig, cache: str | None = None, rrd: bool = False) -> tuple[dict, dict[str, list[float]], bytes | None]:
    """One run on RUN_THREADS torch threads: its CSV row, per-frame series and, with ``rrd``, its
    recording (:func:`priortrack.viz.replay.replay`) as the bytes of an .rrd file: plain values, what
    a Dask worker returns."""
    from priortrack.body.fk import joint_positions
    from priortrack.experiments.metrics import mpjpe
    from priortrack.tracking.presets import load_preset
    from priortrack.tracking.person import detection_weight, frame_log_likelihoods, mismatch_flags
    from priortrack.experiments.tracking import track
    from priortrack.filters.snapshot import KNOWN_FRAMES
    from priortrack.threads import torch_threads

    with torch_threads(RUN_THREADS):
        result = track(config.motion, config.filter, config.scenario, config.seed, cache=cache,
                       frames=config.frames, smooth=config.smooth, keep_snapshots=rrd)
    r, uv = result.result, result.observations.uv
    estimates = result.track.estimates if result.smoothed is None else result.smoothed.estimates
    error = np.full(len(uv), np.nan)
    error[KNOWN_FRAMES:] = mpjpe(estimates[KNOWN_FRAMES:], joint_positions(result.motion, "eval15")[KNOWN_FRAMES:])
    preset = load_preset(config.filter)
    likelihood = preset.likelihood(result.observations.camera)
    particles = preset.filter_kind in ("pf", "apf")          # the UKF's "ESS" counts sigma points: none
    loglik = frame_log_likelihoods(likelihood, result.track.estimates, uv)     # (mismatch_flags skips the known frames)
    confident = np.concatenate([uv, np.ones(uv.shape[:2] + (1,))], -1)[:, None]          # (T, 1, J, 3)
    mismatch = mismatch_flags(loglik, detection_weight(confident), likelihood)
    row = {"filter": config.filter, "motion": config.motion, "scenario": config.scenario, "seed": config.seed,
           "mpjpe_mm": r["mpjpe_mm"], "rootrel_mm": r["mpjpe_root_rel_mm"], "px_err": r["err2d_px"],
           "failure_rate": float(np.mean(error[KNOWN_FRAMES:] > FAILURE_MM)),
           "s_per_frame": r["seconds_per_frame"], "mean_ess": r["mean_ess"] if particles else None,
           "mismatch_fraction": float(mismatch[KNOWN_FRAMES:].mean()), "config_hash": config.key}
    if config.smooth:
        row.update(filtered_mpjpe_mm=r["filtered_mpjpe_mm"], filtered_rootrel_mm=r["filtered_mpjpe_root_rel_mm"])
    observed = np.isfinite(uv).all(axis=-1).sum(axis=-1)
    ess = np.asarray(result.track.ess, dtype=float) if particles else np.full(len(uv), np.nan)
    series = {"error_mm": error.tolist(), "ess": ess.tolist(),
              "observed_fraction": (observed / max(int(observed.max()), 1)).tolist()}
    return row, series, _recording(config, result, likelihood, mismatch) if rrd else None


def _recording(config: RunConfig, result, likelihood, mismatch: np.ndarray) -> bytes:
    """The bytes of the run's .rrd file (named by :attr:`RunConfig.label`; its log-likelihood and
    mismatch scalars from ``likelihood`` and the flags)."""
    import tempfile

    from priortrack.viz.replay import replay

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.rrd"
        replay(result.motion, result.observations, path, track=result.track, name=config.label,
               smoothed=None if result.smoothed is None else result.smoothed.estimates, likelihood=likelihood,
               mismatch=mismatch)
        return path.read_bytes()


@dataclass
class Progress:
    """What a progress display gets after each finished (or cached) run."""

    done: int
    total: int
    cached: int
    eta_s: float | None
    label: str


def compare(configs: Sequence, out: str | Path, workers: int | None = None, scheduler: str | None = None,
            rrd: bool = False, cache: str | Path | None = None,
            progress: Callable[[Progress], None] | None = None) -> list[dict]:
    """Run (or read from ``out``'s cache) every configuration (:class:`RunConfig`s of motion capture, or
    :class:`~priortrack.experiments.compare_detections.DetectionRunConfig`s of a user's detections: each
    knows its run and its results' files), write ``out``/results.csv, summary.md, plots/ and (``rrd``)
    recordings/; returns the rows in the grid's order."""
    from priortrack.priors.cache import cache_dir
    from priortrack.tracking.presets import load_preset
    from priortrack.threads import torch_threads

    if workers is not None and scheduler is not None:
        raise PriortrackError("compare: give --workers or --scheduler, not both")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise PriortrackError(f"compare: --workers must be a positive whole number, got {workers!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise PriortrackError(f"compare: --out {out} exists and is not a folder")
    runs_dir = out / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    cache = str(cache_dir() if cache is None else cache)
    rows: dict[RunConfig, dict] = {}
    for config in configs:
        stored = _stored(runs_dir, config.key)
        if stored is not None and (not rrd or _recording_path(out, config).exists()):
            rows[config] = stored
    pending = [c for c in configs if c not in rows]
    log.info("compare: %d runs, %d cached, %d to run", len(configs), len(rows), len(pending))
    start, cached = time.perf_counter(), len(rows)

    def finished(config: RunConfig, row: dict, series: dict, recording: bytes | None) -> None:
        _store(runs_dir, config.key, row, series)
        if recording is not None:
            path = _recording_path(out, config)
            path.parent.mkdir(exist_ok=True)
            path.write_bytes(recording)
        rows[config] = row
        if progress:
            fresh = len(rows) - cached
            rate = (time.perf_counter() - start) / fresh
            progress(Progress(len(rows), len(configs), cached, rate * (len(configs) - len(rows)), config.label))

    if pending:
        with torch_threads(RUN_THREADS):
            for name in dict.fromkeys(c.filter for c in pending):
                load_preset(name).prior(cache)                  # fitted once, here, before any run
        if workers is None and scheduler is None:
            for config in pending:
                finished(config, *config.run(cache, rrd))
        else:
            _on_dask(pending, cache, rrd, workers, scheduler, finished)
    ordered = [rows[c] for c in configs]
    if configs:
        type(configs[0]).write_results(ordered, series_of(out, configs), out)
    return ordered


def _run(config, cache: str, rrd: bool):
    """A configuration's run (what a Dask worker calls)."""
    return config.run(cache, rrd)


def _on_dask(pending: list[RunConfig], cache: str, rrd: bool, workers: int | None, scheduler: str | None,
             finished: Callable) -> None:
    """Run ``pending`` on a Dask cluster (module docstring), calling ``finished`` as each completes."""
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise PriortrackError("compare --workers/--scheduler runs on Dask: pip install 'priortrack[cluster]' "
                              "(dask[distributed])") from None
    from priortrack.experiments.tracking import THREAD_VARIABLES, environment

    with environment({name: str(RUN_THREADS) for name in THREAD_VARIABLES}):
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout="20s")
            except (OSError, TimeoutError) as exc:
                raise PriortrackError(f"compare: no Dask scheduler at {scheduler} ({exc})") from None
            cluster = None
        else:
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None)
            client = Client(cluster)
    try:
        futures = {client.submit(_run, config, cache, rrd, pure=False): config for config in pending}
        for future in as_completed(futures):
            finished(futures[future], *future.result())
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _recording_path(out: Path, config) -> Path:
    from priortrack.viz.recording import entry_name

    return out / "recordings" / f"{entry_name(config.recording_stem)}.rrd"


def _stored(runs_dir: Path, key: str) -> dict | None:
    row_path, series_path = runs_dir / f"{key}.json", runs_dir / f"{key}.npz"
    if not (row_path.is_file() and series_path.is_file()):
        return None
    try:
        return json.loads(row_path.read_text())
    except (OSError, json.JSONDecodeError):
        log.warning("compare: %s is unreadable; running it again", row_path)
        return None


def _store(runs_dir: Path, key: str, row: dict, series: dict) -> None:
    """The run's series, then its row (written last, atomically: a row on disk means a finished run)."""
    with open(runs_dir / f"{key}.npz", "wb") as f:
        np.savez(f, **{name: np.asarray(values, dtype=float) for name, values in series.items()})
    partial = runs_dir / f"{key}.json.partial"
    partial.write_text(json.dumps(row))
    os.replace(partial, runs_dir / f"{key}.json")


def series_of(out: str | Path, configs: Sequence) -> dict[str, dict[str, np.ndarray]]:
    """The stored series of every configuration of a finished grid in ``out``, by configuration hash."""
    return {c.key: _series(Path(out) / "runs", c.key) for c in configs}


def _series(runs_dir: Path, key: str) -> dict[str, np.ndarray]:
    from priortrack.data.npz import read_npz

    return read_npz(runs_dir / f"{key}.npz", SERIES_BYTES, "compare run series")


def write_csv(rows: Sequence[dict], path: Path, columns: Sequence[str]) -> None:
    """One line per run, its ``columns``; empty = none."""
    import csv

    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for row in rows:
            writer.writerow(["" if row.get(c) is None else row[c] for c in columns])


def table(rows: Sequence[dict], key: str) -> dict[str, dict[str, tuple[float, float]]]:
    """{filter: {scenario: (mean, std) of ``key`` over motions and seeds}} (:func:`~priortrack.experiments.metrics.mean_std`)."""
    from priortrack.experiments.metrics import mean_std

    filters = list(dict.fromkeys(r["filter"] for r in rows))
    scenarios = list(dict.fromkeys(r["scenario"] for r in rows))
    return {f: {s: mean_std([r.get(key) for r in rows if r["filter"] == f and r["scenario"] == s])
                for s in scenarios} for f in filters}


def summary_markdown(rows: Sequence[dict]) -> str:
    """Mean ± std per filter × scenario of each figure; the best (lowest error, failure rate, time;
    highest ESS) of each scenario in bold."""
    scenarios = list(dict.fromkeys(r["scenario"] for r in rows))
    motions = sorted({r["motion"] for r in rows})
    seeds = len({r["seed"] for r in rows})
    lines = [f"# Filter comparison\n\n{len(rows)} runs: {len(motions)} motion(s) ({', '.join(motions)}) × "
             f"{seeds} seed(s) per filter and scenario; mean ± std. Best of each scenario in bold.\n"]
    figures = [("mpjpe_mm", "World MPJPE (mm)", min), ("rootrel_mm", "Root-relative MPJPE (mm)", min),
               ("px_err", "2D error (px)", min), ("failure_rate", f"Failure rate (frames > {FAILURE_MM:.0f} mm)", min),
               ("mean_ess", "Mean ESS", max), ("mismatch_fraction", "Mismatch fraction", min),
               ("s_per_frame", "Seconds per frame", min)]
    if any("filtered_mpjpe_mm" in r for r in rows):
        figures.insert(1, ("filtered_mpjpe_mm", "World MPJPE of the filter, before smoothing (mm)", min))
    for key, title, best_of in figures:
        t = table(rows, key)
        lines += [f"## {title}\n", "| filter | " + " | ".join(scenarios) + " |", "|---|" + "---|" * len(scenarios)]
        best = {s: best_of((v[s][0] for v in t.values() if math.isfinite(v[s][0])), default=None) for s in scenarios}
        for name, cells in t.items():
            shown = []
            for s in scenarios:
                mean, std = cells[s]
                text = "—" if not math.isfinite(mean) else f"{mean:.3g} ± {std:.2g}"
                shown.append(f"**{text}**" if best[s] is not None and mean == best[s] else text)
            lines.append(f"| {name} | " + " | ".join(shown) + " |")
        lines.append("")
    return "\n".join(lines)
