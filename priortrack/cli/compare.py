"""``priortrack compare``: a grid of filters × motions × scenarios × seeds, cached and resumable."""

from __future__ import annotations

import argparse
import logging

from priortrack.cli.common import Progress, print_json
from priortrack.errors import PriortrackError

log = logging.getLogger(__name__)


def _compare(args: argparse.Namespace) -> None:
    from pathlib import Path

    from priortrack.experiments.compare import compare, plan, series_of, table
    from priortrack.experiments.compare_detections import LIMBS, plan_detections, summary

    if args.people is not None:
        _compare_people(args)
        return
    if args.detections is not None:
        if args.motions or args.scenarios:
            raise PriortrackError("compare --detections scores the filters on your recording: give no --motions or "
                                  "--scenarios")
        if args.cameras is None:
            raise PriortrackError("compare --detections needs the cameras' calibration (--cameras)")
        configs = plan_detections(args.filters, args.detections, args.cameras, args.seeds, args.truth,
                                  args.keypoints, args.fps, args.frames, args.smooth,
                                  args.joints or LIMBS, person=_seen_most(args), lowpass=args.lowpass)
    else:
        for name in ("cameras", "truth", "keypoints", "fps", "joints", "lowpass"):
            if getattr(args, name) is not None:
                raise PriortrackError(f"--{name} is for compare --detections")
        if not args.motions:
            raise PriortrackError("compare needs --motions (bundled motion capture) or --detections with --cameras")
        configs = plan(args.filters, args.motions, args.scenarios or ["clean"], args.seeds, args.frames, args.smooth)
    progress = Progress("compare", "{0}")

    def show(p) -> None:
        eta = "" if p.eta_s is None else f", about {p.eta_s:.0f} s left"
        progress(f"run {p.done} of {p.total} ({p.cached} cached){eta}: {p.label}", 0)

    try:
        rows = compare(configs, args.out, workers=args.workers, scheduler=args.scheduler, rrd=args.rrd, progress=show)
    finally:
        progress.close()
    files = sorted(str(f) for f in Path(args.out).rglob("*") if f.is_file() and f.parent.name != "runs")
    if args.detections is not None:
        if args.json:
            print_json({"rows": rows, "summary": summary(rows, series_of(args.out, configs)), "out": args.out,
                        "files": files})
            return
        print((Path(args.out) / "summary.md").read_text())
        print(f"wrote {args.out}/results.csv, {args.out}/summary.md and the plots {args.out}/plots/*.png")
        return
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


def _seen_most(args: argparse.Namespace) -> int | None:
    """The scene tracker's id of the person seen most (as ``track`` takes without ``--people``) where an OpenPose
    folder holds several people in a frame, said in a warning; else None (one person followed per camera)."""
    from pathlib import Path

    from priortrack.data.scene_detections import read_scene_detections
    from priortrack.experiments.compare_detections import scene_people

    if not Path(args.detections).is_dir():
        return None
    scene = read_scene_detections(args.detections, keypoints=args.keypoints)
    if int(scene.people.max(initial=0)) < 2:
        return None
    person = scene_people(args.detections, args.cameras, 1, args.keypoints, args.fps, args.frames)[0]
    log.warning("%s holds up to %d people in a frame: comparing the one seen most, person %d (the most keypoints "
                "detected; --people all compares each)", args.detections, scene.people.max(), person)
    return person


def _compare_people(args: argparse.Namespace) -> None:
    """``compare --detections … --people …``: each chosen person of a scene compared on their own, in
    OUT/person<id>/ (as ``compare --detections`` writes one person's)."""
    from pathlib import Path

    from priortrack.experiments.compare import compare, series_of
    from priortrack.experiments.compare_detections import LIMBS, plan_detections, scene_people, summary
    from priortrack.tracking.people import parse_people

    if args.detections is None or args.cameras is None:
        raise PriortrackError("--people compares the people of your recording: give --detections and --cameras")
    if args.motions or args.scenarios:
        raise PriortrackError("compare --detections scores the filters on your recording: give no --motions or "
                              "--scenarios")
    ids = scene_people(args.detections, args.cameras, parse_people(args.people), args.keypoints, args.fps, args.frames)
    if args.truth is not None and len(ids) > 1:
        raise PriortrackError(f"--truth holds one person's joints: compare that person alone (--people id:N; the "
                              f"scene's people: {', '.join(map(str, ids))})")
    grids = {pid: plan_detections(args.filters, args.detections, args.cameras, args.seeds, args.truth, args.keypoints,
                                  args.fps, args.frames, args.smooth, args.joints or LIMBS, person=pid,
                                  lowpass=args.lowpass) for pid in ids}
    progress = Progress("compare", "{0}")

    def show(p) -> None:
        progress(f"run {p.done} of {p.total} ({p.cached} cached): {p.label}", 0)

    results = {}
    try:
        for pid, configs in grids.items():
            out = Path(args.out) / f"person{pid}"
            rows = compare(configs, out, workers=args.workers, scheduler=args.scheduler, rrd=args.rrd, progress=show)
            results[pid] = {"rows": rows, "summary": summary(rows, series_of(out, configs)), "out": str(out)}
    finally:
        progress.close()
    if args.json:
        print_json({"people": {str(pid): r for pid, r in results.items()}, "out": args.out})
        return
    for pid, result in results.items():
        print(f"## person {pid}\n")
        print((Path(result["out"]) / "summary.md").read_text())
    print(f"wrote {', '.join(r['out'] for r in results.values())}: results.csv, summary.md and plots/ each")


def add_parsers(verbs) -> None:
    """Register this family's verbs on the ``priortrack`` sub-parsers."""
    grid = verbs.add_parser("compare", help="a grid of filters x motions x scenarios x seeds, or filters on your own "
                                            "--detections with each camera left out in turn: CSV, summary, plots, "
                                            "recordings; cached, resumable, serial or on Dask")
    grid.add_argument("--filters", nargs="+", required=True, help="preset names or .toml files")
    grid.add_argument("--motions", nargs="+", help="bundled names, .amc or .bvh files")
    grid.add_argument("--scenarios", nargs="+", help="NAME or NAME:key=value,... (clean)")
    grid.add_argument("--detections", help="your recording's 2D keypoints (as track --detections reads them): each "
                                           "filter tracks from all cameras but one, scored in the one left out")
    grid.add_argument("--cameras", help="--detections: the calibration file (as track --cameras reads it)")
    grid.add_argument("--truth", help="--detections: 3D joints of the same frames (.trc or .npz) to score MPJPE")
    grid.add_argument("--keypoints", help="--detections: their layout, if the files do not say it")
    grid.add_argument("--fps", type=float, help="--detections: their frame rate, if the files do not say it")
    grid.add_argument("--joints", nargs="+", help="--detections: the eval15 joints scored (default shoulders to "
                                                  "ankles; e.g. the arms' six for a person seated at a desk)")
    grid.add_argument("--people", nargs="+", metavar="WHO",
                      help="--detections of several people: compare each (all; N seen most; id:A,B; at:CAMERA:X,Y; "
                           "box:CAMERA:X0,Y0,X1,Y1, as track --people), each in OUT/person<id>/")
    grid.add_argument("--seeds", type=int, default=1, help="seeds per motion and scenario (1)")
    grid.add_argument("--frames", type=int, help="track only the first N frames of each motion")
    grid.add_argument("--out", required=True, help="the results folder (reused: finished runs are not run again)")
    grid.add_argument("--workers", type=int, help="run on a local Dask cluster of N one-thread workers")
    grid.add_argument("--scheduler", help="run on the Dask scheduler at tcp://host:port")
    grid.add_argument("--rrd", action="store_true", help="one rerun recording per run, under OUT/recordings/")
    grid.add_argument("--smooth", action="store_true", help="smooth each run (MPJPE smoothed, filtered beside it)")
    grid.add_argument("--lowpass", type=float, metavar="HZ",
                      help="--detections: each estimate through Pose2Sim's zero-lag Butterworth at HZ (as track "
                           "--lowpass), and a row 'DLT + low-pass': the other cameras' DLT through the same filter")
    grid.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    grid.set_defaults(run=_compare)
