"""``priortrack eval people``: learned priors on people they never saw (leave one walking person out).

The bundled walking people are :data:`~priortrack.data.bundled.WALKING_PEOPLE` (CMU 07, 35, 02, 05 and
08 = 39, one person). For each held-out person P and each preset, the preset's prior (and its global
motion) is learned again from the walks of every *other* person (:func:`fold_preset`) and P's walks
(:data:`TEST_WALKS`) are tracked on three benches:

- ``lab``: the synthetic side camera, 5 px noise, every observed joint seen (``clean:sigma_px=5``) and
  through a one-gait-cycle blackout (``blackout:sigma_px=5``); world MPJPE (mm), compared with the
  baseline preset (pf-diffusion-local, learned on the same fold) on the same walks and seeds;
- ``real4``: the real-format bench (:mod:`priortrack.experiments.real_format`: the walk written as
  OpenPose JSON through the Pose2Sim demo's 4 cameras with a detector's errors, tracked without the
  truth), world MPJPE shoulders to ankles, compared with per-frame DLT of the same detections;
- ``real1``: the same through one camera (:data:`ONE_CAMERA`), the error relative to the mid-hips.

Runs are cached by configuration in ``out/runs/<hash>.json`` (the preset file's text, the fold, the
motion, bench, scenario, seed and priortrack's version): a rerun does no work and an interrupted
evaluation resumes. The fitted priors go to the prior cache as usual (keyed by their training motions).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import multiprocessing
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from priortrack.data.bundled import WALKING_PEOPLE, expand_sources
from priortrack.errors import PriortrackError
from priortrack.priors.cache import cache_dir
from priortrack.tracking.presets import Preset, load_preset, preset_path
from priortrack.priors.registry import PRIOR_KINDS

log = logging.getLogger(__name__)

PRESETS = ("pf-diffusion-local", "pf-gpdm", "pf-lie", "pf-lie-defensive")
BASELINE = "pf-diffusion-local"
#: The walks tracked when a person is held out: at most two each, the slow ones among them
#: (05_01 at 0.9 m/s, 08_04 "slow walk"); 35_29, 07_10 and 07_11 are the tracking table's.
TEST_WALKS: dict[str, tuple[str, ...]] = {
    "07": ("cmu:07_10", "cmu:07_11"), "35": ("walkjog:35_29",), "02": ("cmu:02_01", "cmu:02_02"),
    "05": ("cmu:05_01",), "08+39": ("cmu:08_04", "cmu:39_01"),
}
BENCHES = ("lab", "real4", "real1")
LAB_SCENARIOS = ("clean:sigma_px=5", "blackout:sigma_px=5")
#: The one camera of ``real1``: the Pose2Sim demo's 4th (the one-camera bench of the real-data notes).
ONE_CAMERA = 3
#: The GPDM kinds learn from the first walk of this many other people (:func:`fold_training`).
GPDM_PEOPLE = 2
#: Torch threads per run (serial and in worker processes alike).
RUN_THREADS = 1


def fold_training(preset: Preset, held_out: str | tuple[str, ...]) -> tuple[str, ...]:
    """The training motions of ``preset``'s prior with ``held_out`` (a person, or several: a scene's
    walkers) left out: every walk of every other
    walking person; for the GPDM kinds, as the GPDM papers and the shipped presets do, a few sequences:
    the first walk of each of the first :data:`GPDM_PEOPLE` other people (07 and 35 unless one of them
    is held out). One walk of each of four people (N = 325–396 frames at 30 fps) was measured: the fit
    did not converge in 3000 L-BFGS iterations, its dynamics variance came out dominated by the RBF
    term (α₀ = 14–21, against 10⁻⁵ for two walks), and at the presets' annealing λ the particles diverged."""
    held_out = (held_out,) if isinstance(held_out, str) else tuple(held_out)
    unknown = [p for p in held_out if p not in WALKING_PEOPLE]
    if unknown:
        raise PriortrackError(f"unknown walking person {unknown[0]!r}; people: {', '.join(WALKING_PEOPLE)}")
    others = [person for person in WALKING_PEOPLE if person not in held_out]
    if "latent" in PRIOR_KINDS[preset.prior_kind].capabilities:
        return tuple(expand_sources(list(WALKING_PEOPLE[person]))[0] for person in others[:GPDM_PEOPLE])
    return tuple(name for person in others for name in expand_sources(list(WALKING_PEOPLE[person])))


def fold_preset(preset: Preset, held_out: str | tuple[str, ...]) -> Preset:
    """``preset`` with its prior learned without ``held_out`` (:func:`fold_training`); a preset that
    reads a fitted prior file cannot be refitted and is refused."""
    if preset.prior_file is not None:
        raise PriortrackError(f"preset {preset.name!r} reads its prior from {preset.prior_file}: eval people "
                              f"refits each prior without the held-out person, so it needs [prior] train")
    return replace(preset, train=fold_training(preset, held_out))


@dataclass(frozen=True)
class PeopleRun:
    """One run: ``preset`` (name or path) learned without ``person``, tracking ``motion`` on ``bench``."""

    preset: str
    person: str
    motion: str
    bench: str
    scenario: str
    seed: int

    def key(self) -> str:
        """The configuration hash (module docstring), 16 hex digits."""
        from priortrack import __version__

        digest = hashlib.sha256(json.dumps([asdict(self), RUN_THREADS, __version__, WALKING_PEOPLE],
                                           sort_keys=True).encode())
        digest.update(preset_path(self.preset).read_bytes())
        return digest.hexdigest()[:16]


def plan(presets: Sequence[str], people: Sequence[str], seeds: int, benches: Sequence[str]) -> list[PeopleRun]:
    """Every run, after checking every argument (one PriortrackError naming the first bad one)."""
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise PriortrackError(f"eval people: --seeds must be a positive whole number, got {seeds!r}")
    for name, values, valid in (("people", people, WALKING_PEOPLE), ("benches", benches, BENCHES)):
        unknown = [v for v in values if v not in valid]
        if not values or unknown:
            raise PriortrackError(f"eval people: --{name} {' '.join(unknown) or '(none)'}: give some of "
                                  f"{', '.join(valid)}")
    if not presets:
        raise PriortrackError("eval people: give at least one preset")
    for name in presets:
        fold_preset(load_preset(name), people[0])
    runs = []
    for person in people:
        for motion in TEST_WALKS[person]:
            for preset in presets:
                for bench in benches:
                    for scenario in (LAB_SCENARIOS if bench == "lab" else ("detector",)):
                        runs += [PeopleRun(preset, person, motion, bench, scenario, s) for s in range(seeds)]
    return runs


def run_one(run: PeopleRun, cache=None) -> dict:
    """One run's result row: the run's fields and its errors (mm; the bench's comparison beside them;
    None where there is none: no DLT from one camera). A run that stops on a PriortrackError (a filter
    that diverged) is a row too, its ``failed`` the message and its errors None: counted, not hidden."""
    torch.set_num_threads(RUN_THREADS)
    preset = fold_preset(load_preset(run.preset), run.person)
    start = time.perf_counter()
    row = {**asdict(run), "preset": preset.name}
    try:
        row.update(_errors(run, preset, cache))
    except PriortrackError as exc:
        log.warning("eval people: %s without %s on %s (%s, %s, seed %d) failed: %s", run.preset, run.person,
                    run.motion, run.bench, run.scenario, run.seed, exc)
        row.update(failed=str(exc), error_mm=None, relative_mm=None)
    row["seconds"] = time.perf_counter() - start
    return {key: None if isinstance(value, float) and math.isnan(value) else value for key, value in row.items()}


def _errors(run: PeopleRun, preset: Preset, cache) -> dict:
    """The bench's figures of one run (:func:`run_one`)."""
    from priortrack.experiments.real_format import run_real_format
    from priortrack.experiments.tracking import track

    row: dict = {}
    if run.bench == "lab":
        result = track(run.motion, preset, run.scenario, run.seed, cache=cache).result
        row.update(error_mm=result["mpjpe_mm"], relative_mm=result["mpjpe_root_rel_mm"],
                   seconds_per_frame=result["seconds_per_frame"])
    else:
        result = run_real_format(preset, run.motion, run.seed, cameras=[ONE_CAMERA] if run.bench == "real1" else None,
                                 cache=cache)
        row.update(error_mm=result["mpjpe_mm"], relative_mm=result["relative_mm"],
                   where_dlt_mm=result["mpjpe_where_dlt_mm"], dlt_mm=result["dlt_mm"],
                   seconds_per_frame=result["seconds"] / max(result["ticks"], 1),
                   mismatch_fraction=result["mismatch_fraction"])
    return row


def _read_row(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _write_row(path: Path, row: dict) -> None:
    partial = path.with_suffix(".partial")
    partial.write_text(json.dumps(row, allow_nan=False))
    partial.replace(path)


def _fit_priors(presets: Sequence[str], people: Sequence[str], cache, real: bool) -> None:
    """Fit (or load) every fold's prior here, once, before any run (workers then read the cache); with
    ``real`` runs to come, also the support references their fit-check reads (for the kinds it judges)."""
    from priortrack.priors.support import reference

    for person in people:
        for name in presets:
            preset = fold_preset(load_preset(name), person)
            preset.prior(cache)
            if real and "latent" not in PRIOR_KINDS[preset.prior_kind].capabilities:
                reference(preset)


def eval_people(presets: Sequence[str] = PRESETS, people: Sequence[str] = tuple(WALKING_PEOPLE), seeds: int = 2,
                benches: Sequence[str] = BENCHES, out: str | Path | None = None, cache=None, jobs: int = 1,
                progress: Callable[[dict], None] | None = None) -> dict:
    """Leave one walking person out (module docstring) for every preset, person, walk, bench and seed.

    ``out``: the run cache (default: ``people`` beside the prior cache); ``jobs`` > 1 runs in that many
    spawned worker processes of one torch thread each (the same numbers as serially).

    Returns {"table": {person: {preset: {cell: value}}}, "runs": [row, …], "presets", "people", "seeds"}.
    A cell is a mean over the person's test walks and seeds: ``clean_mm``, ``blackout_mm`` (lab, world
    MPJPE) with ``clean_ratio`` and ``blackout_ratio`` to the baseline on the same runs; ``real4_mm``
    with ``real4_dlt_ratio`` (the error where DLT has the joints / DLT's), ``real4_dlt_mm`` and ``real4_flagged``
    (the fraction of tracked ticks flagged as mismatch: a preset worse than DLT should be);
    ``real1_relative_mm``; ``seconds_per_frame`` (real4, the median: a process's first run also fits what
    the fit-check reads); ``failed_runs``, the runs that stopped on an
    error (left out of the means). Cells of benches not run are absent.
    """
    from priortrack.experiments.tracking import THREAD_VARIABLES, environment

    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise PriortrackError(f"eval people: --jobs must be a positive whole number, got {jobs!r}")
    runs = plan(presets, people, seeds, benches)
    folder = Path(out) if out is not None else cache_dir().parent / "people"
    (folder / "runs").mkdir(parents=True, exist_ok=True)
    rows: dict[PeopleRun, dict] = {}
    todo = []
    for run in runs:
        row = _read_row(folder / "runs" / f"{run.key()}.json")
        if row is None:
            todo.append(run)
        else:
            rows[run] = row
    log.info("eval people: %d runs, %d cached", len(runs), len(runs) - len(todo))

    def done(run: PeopleRun, row: dict) -> None:
        _write_row(folder / "runs" / f"{run.key()}.json", row)
        rows[run] = row
        if progress:
            progress(row)

    if todo:
        _fit_priors(presets, sorted({r.person for r in todo}), cache, any(r.bench != "lab" for r in todo))
    if jobs == 1 or len(todo) < 2:
        for run in todo:
            done(run, run_one(run, cache))
    else:
        context = multiprocessing.get_context("spawn")
        with environment({name: str(RUN_THREADS) for name in THREAD_VARIABLES}), \
                ProcessPoolExecutor(jobs, mp_context=context) as pool:
            futures = {pool.submit(run_one, run, cache): run for run in todo}
            for future in as_completed(futures):
                done(futures[future], future.result())
    ordered = [rows[run] for run in runs]
    return {"table": _table(ordered, presets, people), "runs": ordered, "presets": list(presets),
            "people": list(people), "seeds": seeds}


def _table(rows: list[dict], presets: Sequence[str], people: Sequence[str]) -> dict:
    """Per person and preset, the cells of :func:`eval_people`."""
    def mean(selected: list[dict], key: str) -> float:
        return float(np.mean([r[key] for r in selected]))

    failed = [r for r in rows if r.get("failed")]
    rows = [r for r in rows if not r.get("failed")]

    table: dict[str, dict[str, dict[str, float]]] = {}
    for person in people:
        table[person] = {}
        for preset in presets:
            mine = [r for r in rows if r["person"] == person and r["preset"] == Path(preset).stem]
            base = [r for r in rows if r["person"] == person and r["preset"] == BASELINE]
            cells: dict[str, float] = {}
            for scenario in LAB_SCENARIOS:
                lab = [r for r in mine if r["bench"] == "lab" and r["scenario"] == scenario]
                if lab:
                    name = scenario.split(":")[0]
                    cells[f"{name}_mm"] = mean(lab, "error_mm")
                    ref = [r for r in base if r["bench"] == "lab" and r["scenario"] == scenario]
                    if ref:
                        cells[f"{name}_ratio"] = cells[f"{name}_mm"] / mean(ref, "error_mm")
            real4 = [r for r in mine if r["bench"] == "real4"]
            if real4:
                cells.update(real4_mm=mean(real4, "error_mm"), real4_dlt_mm=mean(real4, "dlt_mm"),
                             real4_dlt_ratio=mean(real4, "where_dlt_mm") / mean(real4, "dlt_mm"),
                             real4_flagged=mean(real4, "mismatch_fraction"),
                             seconds_per_frame=float(np.median([r["seconds_per_frame"] for r in real4])))
            real1 = [r for r in mine if r["bench"] == "real1"]
            if real1:
                cells["real1_relative_mm"] = mean(real1, "relative_mm")
            cells["failed_runs"] = sum(1 for r in failed if r["person"] == person and r["preset"] == Path(preset).stem)
            table[person][Path(preset).stem] = cells
    return table
