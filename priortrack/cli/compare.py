"""``priortrack compare``: a grid of filters × motions × scenarios × seeds, cached and resumable."""

from __future__ import annotations

import argparse

from priortrack.cli.common import Progress, print_json


def _compare(args: argparse.Namespace) -> None:
    from pathlib import Path

    from priortrack.experiments.compare import compare, plan, table

    configs = plan(args.filters, args.motions, args.scenarios, args.seeds, args.frames, args.smooth)
    progress = Progress("compare", "{0}")

    def show(p) -> None:
        eta = "" if p.eta_s is None else f", about {p.eta_s:.0f} s left"
        progress(f"run {p.done} of {p.total} ({p.cached} cached){eta}: {p.label}", 0)

    try:
        rows = compare(configs, args.out, workers=args.workers, scheduler=args.scheduler, rrd=args.rrd, progress=show)
    finally:
        progress.close()
    files = sorted(str(f) for f in Path(args.out).rglob("*") if f.is_file() and f.parent.name != "runs")
    if args.json:
        print_json({"rows": rows, "out": args.out, "files": files})
        return
    scenarios = list(dict.fromkeys(r["scenario"] for r in rows))
    spread = args.seeds > 1 or len(args.motions) > 1

    def cell(value: tuple[float, float], digits: int) -> str:
        mean, std = value
        return "—" if mean != mean else f"{mean:.{digits}f}" + (f" ± {std:.{digits}f}" if spread else "")

    figures = (("mpjpe_mm", "MPJPE mm", 1), ("rootrel_mm", "root-rel. mm", 1), ("px_err", "2D px", 1),
               ("failure_rate", "failures", 2), ("mean_ess", "ESS", 0), ("s_per_frame", "s/frame", 3))
    tables = {key: table(rows, key) for key, _, _ in figures}
    for scenario in scenarios:
        print(f"\n{scenario}: {len(args.motions)} motion(s) × {args.seeds} seed(s)"
              + (", mean ± std" if spread else ""))
        print("| filter | " + " | ".join(label for _, label, _ in figures) + " |")
        print("|---|" + "---|" * len(figures))
        for name in tables["mpjpe_mm"]:
            print(f"| {name} | " + " | ".join(cell(tables[key][name][scenario], digits) for key, _, digits in figures)
                  + " |")
    print(f"\nwrote {args.out}/results.csv, {args.out}/summary.md and the plots {args.out}/plots/*.png")
    recordings = [f for f in files if f.endswith(".rrd")]
    if recordings:
        print(f"recordings (truth, estimate, particle cloud, camera view), one per run: rerun {recordings[0]}  (or any of "
              f"{args.out}/recordings/*.rrd)")


def add_parsers(verbs) -> None:
    """Register this family's verbs on the ``priortrack`` sub-parsers."""
    grid = verbs.add_parser("compare", help="a grid of filters x motions x scenarios x seeds: CSV, summary, plots, "
                                            "recordings; cached, resumable, serial or on Dask")
    grid.add_argument("--filters", nargs="+", required=True, help="preset names or .toml files")
    grid.add_argument("--motions", nargs="+", required=True, help="bundled names, .amc or .bvh files")
    grid.add_argument("--scenarios", nargs="+", default=["clean"], help="NAME or NAME:key=value,... (clean)")
    grid.add_argument("--seeds", type=int, default=1, help="seeds per motion and scenario (1)")
    grid.add_argument("--frames", type=int, help="track only the first N frames of each motion")
    grid.add_argument("--out", required=True, help="the results folder (reused: finished runs are not run again)")
    grid.add_argument("--workers", type=int, help="run on a local Dask cluster of N one-thread workers")
    grid.add_argument("--scheduler", help="run on the Dask scheduler at tcp://host:port")
    grid.add_argument("--rrd", action="store_true", help="one rerun recording per run, under OUT/recordings/")
    grid.add_argument("--smooth", action="store_true", help="smooth each run (MPJPE smoothed, filtered beside it)")
    grid.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    grid.set_defaults(run=_compare)
