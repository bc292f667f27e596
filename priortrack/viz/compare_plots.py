"""The plots of ``priortrack compare`` (matplotlib, Agg, PNG):

- ``error_<scenario>.png``: world MPJPE per frame, one panel per motion, one line per filter (the
  mean over seeds), the frames where joints were missing shaded (darker where more were missing,
  over the runs);
- ``ess_<scenario>.png``: the effective sample size per frame of the filters that have one;
- ``summary.png``: mean ± std MPJPE per filter, bars grouped by scenario.

and of ``priortrack compare --detections`` (:mod:`priortrack.experiments.compare_detections`):

- ``held_out_cdf.png``: the cumulative distribution of the pixel errors in the cameras left out, one
  line per filter and one for the DLT of the other cameras;
- ``held_out_joints.png``: the median pixel error per joint, bars grouped by joint.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=-]+", "-", name)


def _figure(**size):
    """A figure drawn without pyplot (its own Agg canvas): the caller's backend (a notebook's inline
    one) is left alone."""
    from matplotlib.figure import Figure

    return Figure(**size)


def _saved(figure, ax, path: Path) -> Path:
    """Draw ``ax``'s legend, lay the figure out and write it to ``path``; returns ``path``."""
    ax.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    return path


def _grouped_bars(ax, groups: Sequence[str], bars: dict[str, Sequence[float]], colours: dict, yerr=None) -> None:
    """One bar per name of ``bars`` (its values, one per group) in each group, side by side."""
    width = 0.8 / len(bars)
    for i, (name, values) in enumerate(bars.items()):
        ax.bar(np.arange(len(groups)) + i * width, values, width, color=colours[name], label=name,
               **({} if yerr is None else {"yerr": yerr[name], "capsize": 3}))
    ax.set_xticks(np.arange(len(groups)) + 0.4 - width / 2, groups, fontsize=8)


def _mean_over_runs(values: np.ndarray) -> np.ndarray:
    """(R, T) → (T,) the mean over the runs with a value at each frame (NaN where none has one)."""
    seen = np.isfinite(values)
    count = seen.sum(axis=0)
    return np.where(count > 0, np.where(seen, values, 0.0).sum(axis=0) / np.maximum(count, 1), np.nan)


def write_plots(rows: Sequence[dict], series: dict[str, dict[str, np.ndarray]], folder: Path) -> list[Path]:
    """Write the plots of ``rows`` (the CSV rows) with their per-frame ``series`` (by config hash)
    into ``folder``; returns the files written."""
    from matplotlib import colormaps

    folder.mkdir(parents=True, exist_ok=True)
    filters = list(dict.fromkeys(r["filter"] for r in rows))
    scenarios = list(dict.fromkeys(r["scenario"] for r in rows))
    motions = list(dict.fromkeys(r["motion"] for r in rows))
    colours = {f: colormaps["tab10"](i % 10) for i, f in enumerate(filters)}
    written = []
    for scenario in scenarios:
        for key, ylabel, stem in (("error_mm", "world MPJPE (mm)", "error"), ("ess", "ESS", "ess")):
            figure = _figure(figsize=(5 * len(motions), 3.5))
            axes = figure.subplots(1, len(motions), squeeze=False)
            drawn = False
            for ax, motion in zip(axes[0], motions):
                runs = [r for r in rows if r["scenario"] == scenario and r["motion"] == motion]
                missing = np.mean([1 - series[r["config_hash"]]["observed_fraction"] for r in runs], axis=0)
                for t in np.flatnonzero(missing > 0):
                    ax.axvspan(t - 0.5, t + 0.5, color="grey", alpha=0.35 * float(missing[t]), lw=0)
                for name in filters:
                    values = [series[r["config_hash"]][key] for r in runs if r["filter"] == name]
                    if values and np.isfinite(values).any():
                        ax.plot(_mean_over_runs(np.array(values)), color=colours[name], label=name, lw=1.2)
                        drawn = True
                ax.set_title(motion, fontsize=9)
                ax.set_xlabel("frame")
                ax.set_ylabel(ylabel)
            if not drawn:                     # no filter of the grid keeps particles: no ESS plot
                continue
            figure.suptitle(f"{scenario} (shaded: joints missing)", fontsize=10)
            written.append(_saved(figure, axes[0][0], folder / f"{stem}_{_safe(scenario)}.png"))
    figure = _figure(figsize=(max(5, 1.6 * len(scenarios) * max(1, len(filters)) / 2), 3.8))
    ax = figure.subplots()
    stats = {name: [[r["mpjpe_mm"] for r in rows if r["filter"] == name and r["scenario"] == s] for s in scenarios]
             for name in filters}
    _grouped_bars(ax, scenarios, {n: [np.mean(v) if v else np.nan for v in runs] for n, runs in stats.items()},
                  colours, yerr={n: [np.std(v, ddof=1) if len(v) > 1 else 0.0 for v in runs]    # no run: no bar
                                 for n, runs in stats.items()})
    ax.set_ylabel("world MPJPE (mm), mean ± std")
    written.append(_saved(figure, ax, folder / "summary.png"))
    return written


def write_detection_plots(rows: Sequence[dict], series: dict[str, dict[str, np.ndarray]], folder: Path) -> list[Path]:
    """Write the plots of a detections grid (module docstring) into ``folder``; returns the files written."""
    from matplotlib import colormaps

    from priortrack.experiments.compare_detections import held_out_errors

    folder.mkdir(parents=True, exist_ok=True)
    filters = list(dict.fromkeys(r["filter"] for r in rows))
    joints = list(rows[0]["joints"])
    pooled = held_out_errors(rows, series)
    colours = {f: colormaps["tab10"](i % 10) for i, f in enumerate(filters)} | {"DLT": "black", "DLT + low-pass": "grey"}
    written = []
    figure = _figure(figsize=(6, 4))
    ax = figure.subplots()
    for name, e in pooled.items():
        values = np.sort(e[np.isfinite(e)])
        if len(values):
            ax.plot(values, np.arange(1, len(values) + 1) / len(values), color=colours[name], label=name,
                    lw=1.2, ls="--" if name.startswith("DLT") else "-")
    ax.set_xscale("log")
    ax.set_xlabel("pixel error in the camera left out")
    ax.set_ylabel("fraction of joints")
    ax.grid(alpha=0.3)
    written.append(_saved(figure, ax, folder / "held_out_cdf.png"))
    figure = _figure(figsize=(max(6, 0.9 * len(joints)), 3.8))
    ax = figure.subplots()
    _grouped_bars(ax, joints, {name: [np.nanmedian(e[:, j]) if np.isfinite(e[:, j]).any() else np.nan
                                      for j in range(len(joints))] for name, e in pooled.items()}, colours)
    ax.set_ylabel("median pixel error, camera left out")
    written.append(_saved(figure, ax, folder / "held_out_joints.png"))
    return written
