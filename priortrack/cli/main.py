"""The ``priortrack`` command line.

Verbs: ``data list``, ``replay``, ``fit``, ``sample``, ``track``, ``plot``, ``eval``, ``bench``. Bad input
ends with one line ``priortrack: error: …`` and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys

from priortrack.errors import PriortrackError
from priortrack.output import output_path


def _data_list(args: argparse.Namespace) -> None:
    from priortrack.data.bundled import bundled_clips

    clips = bundled_clips()
    if args.json:
        print(json.dumps([clip.__dict__ for clip in clips], indent=2))
        return
    print(f"{'name':<16} {'subject':>7} {'fps':>5} {'frames':>6}  motion")
    for c in clips:
        print(f"{c.name:<16} {c.subject:>7} {c.fps:>5g} {c.frames:>6}  {c.description}")
    print("\nThe data was obtained from mocap.cs.cmu.edu. "
          "The database was created with funding from NSF EIA-0196217.")


def _replay(args: argparse.Namespace) -> None:
    from priortrack.body.fk import joint_positions
    from priortrack.data.load import load_motion
    from priortrack.observation.synthetic import default_camera, parse_scenario, synthesize
    from priortrack.viz.replay import replay

    output_path(args.out, "rerun recording")
    if args.observations:
        output_path(args.observations, "observations file")
    motion = load_motion(args.motion)
    if args.fps:
        motion = motion.resample(args.fps)
    name, params = parse_scenario(args.scenario)
    positions = joint_positions(motion, "eval15")
    observations = synthesize(positions, motion.fps, default_camera(positions), name, seed=args.seed, **params)
    if args.observations:
        observations.save(args.observations)
    replay(motion, observations, args.out)
    missing = float(observations.missing[:, list(observations.joint_indices)].mean())
    print(f"wrote {args.out}: {motion.name}, {len(motion)} frames at {motion.fps:g} fps, "
          f"scenario {name}, {100 * missing:.1f}% of observed-joint detections missing")


def _motions(sources: list[str]):
    from priortrack.data.bundled import expand_sources
    from priortrack.data.load import load_motion

    return [load_motion(source) for source in expand_sources(sources)]


class _Progress:
    """A one-line progress display on stderr: a step count and a value (objective, or total).
    Shown only on a terminal: a log file would get every update on one line."""

    def __init__(self, label: str, template: str = "step {0:5d}  objective {1:.6g}"):
        self.label, self.template = label, template
        self.shown = sys.stderr.isatty()
        self.last = None

    def __call__(self, step: int, value: float) -> None:
        if not self.shown:
            return
        self.last = (step, value)
        print(f"\r{self.label}: " + self.template.format(step, value), end="", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.last is not None:
            print(file=sys.stderr)


def _fit(args: argparse.Namespace) -> None:
    from priortrack.priors.registry import PRIOR_KINDS, fit_prior

    output_path(args.out, "prior file")
    motions = _motions(args.train)
    flags = {"space": args.space, "d": args.d, "dynamics_noise_floor": args.dynamics_noise_floor,
             "max_components": args.components, "seed": args.seed}
    schema = PRIOR_KINDS[args.kind].options()          # each kind takes the flags its fit has
    options = {"fps": args.fps, **{k: v for k, v in flags.items() if k in schema and v is not None}}
    progress = _Progress(f"fit {args.kind}")
    try:
        model = fit_prior(args.kind, motions, progress=progress, **options)
    finally:
        progress.close()
    model.save(args.out)
    frames = sum(len(m.resample(args.fps)) if m.fps != args.fps else len(m) for m in motions)
    print(f"wrote {args.out}: {args.kind} prior, state dimension {model.state_dim}, {len(motions)} motions, "
          f"{frames} frames at {args.fps:g} fps, final objective {model.objective:.6g}")


def _sample(args: argparse.Namespace) -> None:
    import torch

    from priortrack.data.load import load_motion
    from priortrack.errors import PriortrackError
    from priortrack.priors import load_prior
    from priortrack.viz.recording import Recording

    prior = load_prior(args.prior)
    motion = load_motion(args.source)
    motion = motion if motion.fps == prior.fps else motion.resample(prior.fps)
    states = prior.encode(motion)
    if not 0 <= args.frame < len(states):
        raise PriortrackError(f"--frame must be in [0, {len(states) - 1}] ({args.source} at {prior.fps:g} fps), "
                              f"got {args.frame}")
    for name in ("steps", "n"):
        if getattr(args, name) < 1:
            raise PriortrackError(f"--{name} must be positive, got {getattr(args, name)}")
    generator = torch.Generator().manual_seed(args.seed)
    x = states[args.frame].expand(args.n, -1).contiguous()
    body = prior.space.for_body(motion)           # the subject's bones, for the rollouts and the truth alike
    truth = body.pose_joints(motion[args.frame:args.frame + args.steps + 1])
    with Recording(args.out) as rec:
        for step in range(args.steps + 1):
            rec.frame(args.frame + step)
            if step < len(truth):
                rec.skeleton("truth", truth[step], color=(60, 160, 255))
            for k, pose in enumerate(body.joints(prior.check_state(x))):
                rec.skeleton(f"rollouts/{k}", pose, color=(255, 90, 60))
            x = prior.sample(x, generator)
    print(f"wrote {args.out}: {args.n} rollouts of {args.steps} steps from frame {args.frame} of {args.source} "
          f"({prior.kind} prior at {prior.fps:g} fps)")


def _plot(args: argparse.Namespace) -> None:
    from priortrack.errors import PriortrackError
    from priortrack.priors import load_prior
    from priortrack.priors.registry import PRIOR_KINDS
    from priortrack.viz.latent_plot import plot_latent

    prior = load_prior(args.prior)
    if "latent" not in PRIOR_KINDS[prior.kind].capabilities:
        raise PriortrackError(f"{args.prior} is a {prior.kind} prior; 'plot' draws the latent space of a gpdm or bgpdm")
    plot_latent(prior, args.out)
    print(f"wrote {args.out}")


def _track(args: argparse.Namespace) -> None:
    if args.detections is not None or args.motion is None:
        _track_detections(args)
        return
    from priortrack.experiments.tracking import track
    from priortrack.viz.replay import replay

    for name in ("cameras", "keypoints", "up", "camera_map", "out", "person", "skeleton"):   # (--height has a default)
        if getattr(args, name):
            raise PriortrackError(f"--{name.replace('_', '-')} is for tracking --detections, not a motion")
    if args.rrd:
        output_path(args.rrd, "rerun recording")
    progress = _Progress(f"track {args.filter}", "frame {0} of {1}")
    try:
        run = track(args.motion, args.filter, args.scenario, args.seed, keep_snapshots=bool(args.rrd),
                    progress=progress, frames=args.frames, **_smoothing(args))
    finally:
        progress.close()
    if args.rrd:
        from priortrack.experiments.presets import load_preset

        replay(run.motion, run.observations, args.rrd, track=run.track,
               smoothed=None if run.smoothed is None else run.smoothed.estimates,
               likelihood=load_preset(args.filter).likelihood(run.observations.camera),
               name=f"{args.filter} · {run.motion.name} · {args.scenario} · seed {args.seed}")
    if args.json:
        _print_json(run.result)
        return
    r = run.result
    lag = "" if r.get("lag") is None else f" (lag {r['lag']})"
    smoothed = f" smoothed{lag}, filtered {r['filtered_mpjpe_mm']:.1f} mm" if "filtered_mpjpe_mm" in r else ""
    print(f"{r['filter']} on {r['motion']} ({r['frames']} frames, scenario {r['scenario']}, seed {r['seed']}): "
          f"MPJPE {r['mpjpe_mm']:.1f} mm{smoothed}, root-relative {r['mpjpe_root_rel_mm']:.1f} mm, 2D {r['err2d_px']:.1f} px, "
          f"{1000 * r['seconds_per_frame']:.0f} ms/frame"
          + (f", mean ESS {r['mean_ess']:.0f}" if r["mean_ess"] is not None else "")
          + (f"; wrote {args.rrd}" if args.rrd else ""))


def _smoothing(args: argparse.Namespace) -> dict:
    """track's smoothing arguments: --smooth, or a --lag (which implies it), and --trajectories."""
    if args.lag is not None and args.lag < 0:
        raise PriortrackError(f"--lag must be a whole number of frames ≥ 0, got {args.lag}")
    if args.trajectories is not None and args.trajectories < 1:
        raise PriortrackError(f"--trajectories must be positive, got {args.trajectories}")
    chosen = {"trajectories": args.trajectories} if args.trajectories is not None else {}
    return {"smooth": args.smooth or args.lag is not None, "lag": args.lag, **chosen}


def _skeleton(path: str):
    """The skeleton of an ASF file or of a BVH file's hierarchy."""
    from pathlib import Path

    from priortrack.data.asf import read_asf
    from priortrack.data.bvh import read_bvh

    suffix = Path(path).suffix.lower()
    if suffix == ".asf":
        return read_asf(path)
    if suffix == ".bvh":
        return read_bvh(path).skeleton
    raise PriortrackError(f"--skeleton {path}: give an .asf or .bvh file")


def _track_detections(args: argparse.Namespace) -> None:
    from pathlib import Path

    from priortrack.data.calibration import read_calibration
    from priortrack.data.detections import read_detections
    from priortrack.experiments.real import RESULT_SUFFIXES, track_detections

    if args.motion is not None:
        raise PriortrackError("give a motion or --detections, not both")
    if args.detections is None or args.cameras is None:
        raise PriortrackError("track needs a MOTION (synthetic observations) or --detections with --cameras")
    for path in args.out or []:
        if Path(path).suffix.lower() not in RESULT_SUFFIXES:
            raise PriortrackError(f"--out {path}: results are written as {', '.join(RESULT_SUFFIXES)}")
        output_path(path, "result file")
    if args.rrd:
        output_path(args.rrd, "rerun recording")
    camera_map = None
    if args.camera_map:
        pairs = [item.split("=", 1) for item in args.camera_map.split(",")]
        if any(len(p) != 2 or not p[0] or not p[1] for p in pairs):
            raise PriortrackError(f"--camera-map must be FOLDER=CAMERA,…, got {args.camera_map!r}")
        camera_map = dict(pairs)
    skeleton = _skeleton(args.skeleton) if args.skeleton else None
    detections = read_detections(args.detections, keypoints=args.keypoints, person=args.person)
    if args.frames is not None:
        detections = detections.head(args.frames)
    calibration = read_calibration(args.cameras, units=args.units)
    progress = _Progress(f"track {args.filter}", "frame {0} of {1}")
    try:
        result = track_detections(detections, calibration, args.filter, fps=args.fps, up=args.up,
                                  camera_map=camera_map, min_confidence=args.min_confidence, seed=args.seed,
                                  keep_snapshots=bool(args.rrd), progress=progress, height=args.height,
                                  skeleton=skeleton, **_smoothing(args))
    finally:
        progress.close()
    written = [str(result.save(path)) for path in args.out or []]
    if args.rrd:
        from priortrack.viz.real import record_detections

        written.append(str(record_detections(result, args.rrd)))
    summary = {**result.summary(), "written": written}
    if args.json:
        _print_json(summary)
        return
    errors = ", ".join(f"{n} {e:.1f} px" for n, e in summary["reprojection_px"].items())
    print(f"{result.filter}: {summary['frames']} frames at {result.fps:g} fps in {summary['seconds']:.1f} s; "
          f"median reprojection {errors}; mismatch {100 * summary['mismatch_fraction']:.0f}% of frames"
          + (f"; wrote {', '.join(written)}" if written else ""))


def _eval_tracking(args: argparse.Namespace) -> None:
    from priortrack.experiments.tracking import TABLE_MOTIONS, TABLE_PRESETS, TABLE_SCENARIOS, TABLE_SEEDS, eval_tracking

    def show(row: dict) -> None:
        logging.getLogger("priortrack.track").info("%s %s %s seed %d: %.1f mm", row["filter"], row["motion"],
                                                    row["scenario"], row["seed"], row["mpjpe_mm"])

    presets, scenarios = args.presets or list(TABLE_PRESETS), args.scenarios or list(TABLE_SCENARIOS)
    motions, seeds = args.motions or list(TABLE_MOTIONS), TABLE_SEEDS if args.seeds is None else args.seeds
    result = eval_tracking(presets, scenarios, motions, seeds, progress=show, jobs=args.jobs)
    if args.json:
        _print_json(result)
        return
    for key, label in (("mpjpe_mm", "MPJPE"), ("mpjpe_root_rel_mm", "root-relative MPJPE")):
        print(f"{label} (mm), mean ± std over {len(motions)} motions × {seeds} seeds; "
              f"ratio to pf-diffusion-local in brackets")
        print("| preset | " + " | ".join(scenarios) + " |")
        print("|---|" + "---|" * len(scenarios))
        for name, row in result["table"].items():
            cells = []
            for s in scenarios:
                ratio = result["ratios"].get(key, {}).get(name, {}).get(s)
                cells.append(f"{row[s][key]:.0f} ± {row[s][key + '_std']:.0f}" + (f" ({ratio:.2f})" if ratio else ""))
            print(f"| {name} | " + " | ".join(cells) + " |")
        print()


def _print_json(result: dict) -> None:
    print(json.dumps(result, indent=None if not sys.stdout.isatty() else 2))


def _eval_fill_in(args: argparse.Namespace) -> None:
    from priortrack.experiments.reproductions.fill_in import eval_fill_in

    result = eval_fill_in(seed=args.seed)
    if args.json:
        _print_json(result)
        return
    print("missing-frame fill-in (Wang et al. PAMI 2008, Table 2 protocol): mean RMS per frame, degrees "
          "(the paper's own figures, in its units, beside)")
    rows = (("bgpdm", "B-GPDM", "49.31"), ("gpdm", "GPDM (MAP)", "73.87"),
            ("knn_paper", f"paper's KNN, least squares, K = {result['knn_paper_k']} picked on the test data", "55.62"),
            ("knn15", "window-KNN-15 (ours, a stronger baseline)", "—"), ("spline", "cubic spline", "93.34"))
    for key, label, paper in rows:
        print(f"  {label:<62} {result[key]:8.2f}   paper {paper}")


def _eval_loglik(args: argparse.Namespace) -> None:
    from priortrack.experiments.reproductions.loglik import eval_loglik

    result = eval_loglik(train=args.train, test=args.test, seed=args.seed)
    if args.json:
        _print_json(result)
        return
    print("mean log p(v_t | x_t) per frame (higher is better)")
    for model in ("lie", "lie_defensive", "diffusion_local", "diffusion_global"):
        print(f"  {model:<17} train {result[model]['train']:9.2f}   test {result[model]['test']:9.2f}")


def _eval_real_format(args: argparse.Namespace) -> None:
    from priortrack.experiments.real_format import eval_real_format

    result = eval_real_format(args.presets, args.motions, args.seeds, cameras=args.cameras, smooth=args.smooth)
    if args.json:
        _print_json(result)
        return
    if args.smooth:
        print(f"real-format input ({result['cameras']} cameras), smoothed vs filtered, world MPJPE shoulders to ankles "
              f"(mm) and jitter (mean joint acceleration, mm per tick²), mean over {len(args.motions)} walks × "
              f"{args.seeds} seeds")
        print("| preset | smoothed | filtered | ratio | jitter smoothed | filtered | mocap truth |")
        print("|---|---|---|---|---|---|---|")
        for name, row in result["table"].items():
            print(f"| {name} | {row['mpjpe_mm']:.1f} | {row['filtered_mm']:.1f} | {row['mpjpe_mm'] / row['filtered_mm']:.2f} "
                  f"| {row['jitter_mm']:.2f} | {row['filtered_jitter_mm']:.2f} | {row['truth_jitter_mm']:.2f} |")
        return
    print(f"real-format input ({result['cameras']} of the Pose2Sim demo's cameras, detector errors), world MPJPE "
          f"shoulders to ankles, mm, mean over {len(args.motions)} walks × {args.seeds} seeds")
    print("| preset | tracker | relative to the hips | per-frame DLT | ratio | s per run |")
    print("|---|---|---|---|---|---|")
    for name, row in result["table"].items():
        print(f"| {name} | {row['mpjpe_mm']:.1f} | {row['relative_mm']:.1f} | {row['dlt_mm']:.1f} | {row['ratio']:.2f} "
              f"| {row['seconds']:.1f} |")


def _eval_leave_one_out(args: argparse.Namespace) -> None:
    import numpy as np

    from priortrack.experiments.real_format import leave_one_camera_out

    rows = [leave_one_camera_out(p, c) for p in args.presets for c in range(4)]
    if args.json:
        _print_json(rows)
        return
    print("real detections (Pose2Sim demo): tracked from 3 cameras, median pixel error in the 4th (shoulders to "
          "ankles, confidence > 0.3)")
    print("| preset | " + " | ".join(r["held_out"] for r in rows[:4]) + " | mean |")
    print("|---|" + "---|" * 5)
    for p in args.presets:
        mine = [r for r in rows if r["preset"] == p]
        print(f"| {p} | " + " | ".join(f"{r['tracker_px']:.1f}" for r in mine)
              + f" | {np.mean([r['tracker_px'] for r in mine]):.1f} |")
    print("| 3-camera DLT | " + " | ".join(f"{r['dlt_px']:.1f}" for r in rows[:4])
          + f" | {np.mean([r['dlt_px'] for r in rows[:4]]):.1f} |")


def _bench_gpdm_fit(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.gpdm_fit import bench_gpdm_fit

    _print_json(bench_gpdm_fit(frames=args.frames, threads=args.threads))


def _bench_lie_sample(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.lie_sample import bench_lie_sample

    _print_json(bench_lie_sample(n=args.n, threads=args.threads))


def _bench_ukf(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.ukf import bench_ukf

    _print_json(bench_ukf(repeats=args.repeats, seed=args.seed, threads=args.threads))


def _bench_pf(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.pf import bench_pf

    _print_json(bench_pf(particles=args.particles, steps=args.steps, seed=args.seed, threads=args.threads,
                         dtype=args.dtype, translation=args.translation))


def _bench_real_track(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.real_track import bench_real_track

    _print_json(bench_real_track(frames=args.frames, preset=args.filter, seed=args.seed))


def _compare(args: argparse.Namespace) -> None:
    from pathlib import Path

    from priortrack.experiments.compare import compare, plan, table

    configs = plan(args.filters, args.motions, args.scenarios, args.seeds, args.frames, args.smooth)
    progress = _Progress("compare", "{0}")

    def show(p) -> None:
        eta = "" if p.eta_s is None else f", about {p.eta_s:.0f} s left"
        progress(f"run {p.done} of {p.total} ({p.cached} cached){eta}: {p.label}", 0)

    try:
        rows = compare(configs, args.out, workers=args.workers, scheduler=args.scheduler, rrd=args.rrd, progress=show)
    finally:
        progress.close()
    files = sorted(str(f) for f in Path(args.out).rglob("*") if f.is_file() and f.parent.name != "runs")
    if args.json:
        _print_json({"rows": rows, "out": args.out, "files": files})
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


def _eval_fit_check(args: argparse.Namespace) -> None:
    from pathlib import Path

    from priortrack.data.load import load_motion
    from priortrack.experiments.presets import load_preset
    from priortrack.priors.base import load_prior
    from priortrack.priors.support import frame_log_density, reference, verdict

    motion = load_motion(args.motion)
    given = [load_motion(m) for m in args.reference or []]
    if Path(args.prior).suffix.lower() == ".npz":
        prior = load_prior(args.prior)
        if not given:
            raise PriortrackError(f"{args.prior} is a prior file: its training motions are not known; give "
                                  f"--reference MOTION… (motions of its kind that it was not fitted on)")
        reference_values = None
    else:
        preset = load_preset(args.prior)
        prior = preset.prior()
        reference_values = None if given else reference(preset)
    if reference_values is None:
        import numpy as np

        reference_values = np.concatenate([frame_log_density(prior, m) for m in given])
    result = {"prior": args.prior, "kind": prior.kind, "motion": args.motion,
              **verdict(frame_log_density(prior, motion), reference_values)}
    if args.json:
        _print_json(result)
        return
    p = result["reference_percentiles"]
    print(f"{args.motion} under {args.prior} ({prior.kind}): {result['verdict']}. "
          f"{100 * result['below_p1_fraction']:.0f}% of its frames score below the 1st percentile of frames the prior "
          f"was not fitted on ({p['1']:.1f}); median log-density {result['median_log_density']:.1f} per frame, at the "
          f"{result['median_percentile']:.0f}th percentile (reference median {p['50']:.1f})")


def _eval_pace(args: argparse.Namespace) -> None:
    from priortrack.experiments.pace import eval_pace

    result = eval_pace(args.presets, args.motions, args.paces, args.scenarios, args.seeds)
    if args.json:
        _print_json(result)
        return
    walks = list(next(iter(result["table"].values())))
    print(f"world MPJPE (mm), mean over {args.seeds} seeds; a walk@p is played at p x its speed")
    for scenario in args.scenarios:
        print(f"\n{scenario}")
        print("| preset | " + " | ".join(walks) + " |")
        print("|---|" + "---|" * len(walks))
        for preset, cells in result["table"].items():
            print(f"| {preset} | " + " | ".join(f"{cells[w][scenario]:.0f}" for w in walks) + " |")


def _eval_people(args: argparse.Namespace) -> None:
    from priortrack.experiments.people import LAB_SCENARIOS, eval_people

    result = eval_people(args.presets, args.people, args.seeds, args.benches, args.out, jobs=args.jobs)
    if args.json:
        _print_json(result)
        return
    columns = [(f"{s.split(':')[0]}_mm", f"{s.split(':')[0]}_ratio") for s in LAB_SCENARIOS] + \
        [("real4_mm", "real4_dlt_ratio"), ("real1_relative_mm", None)]
    print(f"leave one walking person out, mean over the person's walks and {args.seeds} seeds: lab world MPJPE mm "
          f"(x pf-diffusion-local), 4 cameras shoulders-ankles mm (x DLT), 1 camera relative to hips mm")
    print("| held out | preset | clean | blackout | 4 cameras | 1 camera | failed runs |")
    print("|---|---|---|---|---|---|---|")
    for person, presets in result["table"].items():
        for preset, cells in presets.items():
            text = [(f"{cells[value]:.0f}" + (f" ({cells[ratio]:.2f})" if ratio in cells else "")) if value in cells
                    else "—" for value, ratio in columns]
            print(f"| {person} | {preset} | " + " | ".join(text) + f" | {cells['failed_runs']} |")


def _bench_smooth(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.smooth import bench_smooth

    _print_json(bench_smooth(args.presets, frames=args.frames, trajectories=args.trajectories, seed=args.seed))


def _eval_smoothing(args: argparse.Namespace) -> None:
    from priortrack.experiments.smoothing import eval_smoothing

    result = eval_smoothing(args.presets, args.motions, args.seeds)
    if args.json:
        _print_json(result)
        return
    print(f"smoothed vs filtered, {result['scenario']}, world MPJPE (mm), mean over {len(args.motions)} held-out "
          f"walks × {args.seeds} seeds (ratio = smoothed / filtered; worst = the worst walk's blackout ratio)")
    print("| preset | blackout filtered | smoothed | ratio | worst | clean filtered | smoothed | ratio | "
          "s forward | s smoothing |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, r in result["table"].items():
        print(f"| {name} | {r['filtered_blackout_mm']:.1f} | {r['smoothed_blackout_mm']:.1f} | {r['blackout_ratio']:.2f} "
              f"| {r['worst_blackout_ratio']:.2f} | {r['filtered_clean_mm']:.1f} | {r['smoothed_clean_mm']:.1f} "
              f"| {r['clean_ratio']:.2f} | {r['forward_seconds']:.1f} | {r['smoothing_seconds']:.1f} |")


def _bench_fk(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.fk import bench_fk

    result = bench_fk(batch=args.batch, repeats=args.repeats, threads=args.threads)
    if args.json:
        print(json.dumps(result))
    else:
        print(f"FK at batch {result['batch']} (float32, {result['threads']} threads): priortrack "
              f"{result['priortrack_ms']:.1f} ms, pytorch-kinematics {result['pytorch_kinematics_ms']:.1f} ms "
              f"({result['ratio']:.1f}x); max |difference| in float64 {result['max_abs_err_m']:.1e} m")


def _presets(args: argparse.Namespace) -> None:
    from priortrack.experiments.presets import load_preset, preset_names

    presets = [load_preset(name) for name in preset_names()]
    if args.json:
        print(json.dumps([{"name": p.name, "filter": p.filter_kind, "prior": p.prior_kind, "description": p.description}
                          for p in presets], indent=2))
        return
    print(f"{'preset':<22} {'filter':<6} {'prior':<17} description")
    for p in presets:
        print(f"{p.name:<22} {p.filter_kind:<6} {p.prior_kind:<17} {p.description}")


def build_parser() -> argparse.ArgumentParser:
    """The command line's parser; it imports nothing heavy (no torch), so ``--help`` and argument
    errors are immediate."""
    from priortrack.priors.registry import PRIOR_KINDS

    parser = argparse.ArgumentParser(prog="priortrack", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    verbs = parser.add_subparsers(dest="verb", required=True)

    presets = verbs.add_parser("presets", help="list the filter presets")
    presets.add_argument("--json", action="store_true")
    presets.set_defaults(run=_presets)

    data = verbs.add_parser("data", help="bundled motion data").add_subparsers(dest="action", required=True)
    listing = data.add_parser("list", help="list the bundled clips")
    listing.add_argument("--json", action="store_true")
    listing.set_defaults(run=_data_list)

    replay = verbs.add_parser("replay", help="log a motion and its synthetic 2D observations to rerun")
    replay.add_argument("motion", help="bundled name (cmu:07_01, walkjog:35_29), .amc or .bvh file")
    replay.add_argument("--scenario", default="clean",
                        help="NAME or NAME:key=value,... (clean, noise, dropout, occlusion, blackout, outliers)")
    replay.add_argument("--seed", type=int, default=0)
    replay.add_argument("--fps", type=float, default=30.0, help="resample to this rate first (default 30)")
    replay.add_argument("--observations", help="also save the observations to this .npz")
    replay.add_argument("--out", required=True, help="the .rrd file to write")
    replay.set_defaults(run=_replay)

    fit = verbs.add_parser("fit", help="fit a prior to motions")
    fit.add_argument("kind", choices=list(PRIOR_KINDS))
    fit.add_argument("--train", nargs="+", required=True,
                     help="bundled names (patterns allowed: 'walkjog:35_0*'), .amc or .bvh files")
    fit.add_argument("--out", required=True, help="the prior file to write (.npz)")
    fit.add_argument("--fps", type=float, default=30.0, help="the prior's frame rate (default 30)")
    fit.add_argument("--space", choices=["angles", "directions"], default="angles", help="diffusion state space")
    fit.add_argument("--d", type=int, default=3, help="GPDM latent dimension")
    fit.add_argument("--dynamics-noise-floor", type=float,
                     help="GPDM: lower bound on the dynamics noise variance 1/alpha4 (default 1e-4)")
    fit.add_argument("--components", type=int, default=30, help="Lie prior: initial mixture components")
    fit.add_argument("--seed", type=int, default=0)
    fit.set_defaults(run=_fit)

    sample = verbs.add_parser("sample", help="roll a prior out from a real pose into a rerun recording")
    sample.add_argument("prior", help="a prior file written by 'priortrack fit'")
    sample.add_argument("--from", dest="source", required=True, help="the motion to start from")
    sample.add_argument("--frame", type=int, default=0, help="start frame, at the prior's frame rate")
    sample.add_argument("--steps", type=int, default=30)
    sample.add_argument("--n", type=int, default=10, help="number of rollouts")
    sample.add_argument("--seed", type=int, default=0)
    sample.add_argument("--out", required=True, help="the .rrd file to write")
    sample.set_defaults(run=_sample)

    bench = verbs.add_parser("bench", help="benchmarks against a reference").add_subparsers(dest="what", required=True)
    fk = bench.add_parser("fk", help="our FK against pytorch-kinematics")
    fk.add_argument("--batch", type=int, default=10_000)
    fk.add_argument("--repeats", type=int, default=9)
    fk.add_argument("--threads", type=int, default=2)
    fk.add_argument("--json", action="store_true")
    fk.set_defaults(run=_bench_fk)
    gpdm_fit = bench.add_parser("gpdm-fit", help="time a balanced GPDM fit to convergence")
    gpdm_fit.add_argument("--frames", type=int, default=300)
    gpdm_fit.add_argument("--threads", type=int, default=2)
    gpdm_fit.add_argument("--json", action="store_true", help="(the output is always JSON)")
    gpdm_fit.set_defaults(run=_bench_gpdm_fit)
    lie_sample = bench.add_parser("lie-sample", help="Lie prior conditional samples per second vs scikit-learn")
    lie_sample.add_argument("--n", type=int, default=200_000, help="samples per timing")
    lie_sample.add_argument("--threads", type=int, default=2)
    lie_sample.add_argument("--json", action="store_true", help="(the output is always JSON)")
    lie_sample.set_defaults(run=_bench_lie_sample)

    track = verbs.add_parser("track", help="track detections from calibrated cameras, or a motion's synthetic "
                                           "2D observations, with a filter preset")
    track.add_argument("motion", nargs="?", help="bundled name (cmu:07_10, walkjog:35_29), .amc or .bvh file: "
                                                 "track its synthetic observations")
    track.add_argument("--detections", help="OpenPose JSON folder (one sub-folder per camera), COCO results "
                                            ".json or .npz of 2D keypoints")
    track.add_argument("--cameras", help="calibration, its format recognised from the content: Pose2Sim, anipose, "
                                         "FreeMoCap or caliscope .toml; OpenCV-style, mmhuman3d, Panoptic or "
                                         "VoxelPose .json; OpenCV .yml/.yaml")
    track.add_argument("--units", choices=("m", "cm", "mm"),
                       help="the calibration's translation unit, if the file does not state it and its camera "
                            "layout misleads (else inferred and logged)")
    track.add_argument("--keypoints", help="the detections' layout: body25, body25b, coco18, coco17, mediapipe33")
    track.add_argument("--fps", type=float, help="the detections' frame rate (if their files do not say it)")
    track.add_argument("--up", help="the calibration world's up: an axis (x, y, z, -x, -y, -z) or a vector "
                                    "X,Y,Z; else the file's, else found from the person (ankles to neck)")
    track.add_argument("--camera-map", help="FOLDER=CAMERA,… matching detection folders to calibration cameras")
    track.add_argument("--min-confidence", type=float, default=0.3, help="keypoints below it are missing (0.3)")
    track.add_argument("--person", type=int, help="follow this index of each frame's people list")
    track.add_argument("--skeleton", help="the person's own body (.asf, or a .bvh's hierarchy) instead of the "
                                         "template scaled to the detections")
    track.add_argument("--height", type=float, default=1.7,
                       help="the person's standing height, metres (one camera: the body's size and depth; 1.7)")
    track.add_argument("--out", action="append", help="write the result (.npz, .csv); may repeat")
    track.add_argument("--filter", required=True, help="a preset name (priortrack presets) or a .toml file")
    track.add_argument("--scenario", default="clean",
                       help="NAME or NAME:key=value,... (clean, noise, dropout, occlusion, blackout, outliers)")
    track.add_argument("--seed", type=int, default=0, help="seeds the observations and the filter")
    track.add_argument("--frames", type=int, help="track only the first N frames (a motion: ticks at the "
                                                  "prior's rate; --detections: the file's first N frames)")
    track.add_argument("--rrd", help="also write a rerun recording: truth, estimate, particle cloud, 2D observations")
    track.add_argument("--smooth", action="store_true",
                       help="also smooth the run: each frame's estimate given every frame (outputs the smoothed joints)")
    track.add_argument("--lag", type=int, help="fixed-lag smoothing: frame t − LAG estimated at frame t (implies --smooth)")
    track.add_argument("--trajectories", type=int,
                       help="smoothed trajectories a particle smoother draws (default 100)")
    track.add_argument("--json", action="store_true")
    track.set_defaults(run=_track)

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
    grid.add_argument("--json", action="store_true")
    grid.set_defaults(run=_compare)

    ukf = bench.add_parser("ukf", help="one UKF step, batched sigma points vs filterpy's per-point loop")
    ukf.add_argument("--repeats", type=int, default=9)
    ukf.add_argument("--threads", type=int, default=1)
    ukf.add_argument("--seed", type=int, default=0)
    ukf.add_argument("--json", action="store_true", help="(the output is always JSON)")
    ukf.set_defaults(run=_bench_ukf)
    pf = bench.add_parser("pf", help="particle-steps per second of the particle filter with each prior")
    pf.add_argument("--particles", type=int, default=10_000)
    pf.add_argument("--steps", type=int, default=20, help="timed steps per prior")
    pf.add_argument("--threads", type=int, default=2)
    pf.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                    help="the particles' dtype (the particle-filter presets run float32)")
    pf.add_argument("--translation", choices=("marginalised", "sampled"), default="marginalised",
                    help="the body's translation integrated out per particle (as the presets run) or sampled")
    pf.add_argument("--seed", type=int, default=0)
    pf.add_argument("--json", action="store_true", help="(the output is always JSON)")
    pf.set_defaults(run=_bench_pf)

    real_track = bench.add_parser("real-track", help="the whole track --detections command on real-format input "
                                                     "(4 cameras), beside DLT of the same input")
    real_track.add_argument("--frames", type=int, default=100)
    real_track.add_argument("--filter", default="pf-lie", help="the preset (its particles: 1000 for pf-lie)")
    real_track.add_argument("--seed", type=int, default=0)
    real_track.add_argument("--json", action="store_true", help="(the output is always JSON)")
    real_track.set_defaults(run=_bench_real_track)
    smooth = bench.add_parser("smooth", help="the smoother's time against the forward pass it smooths")
    smooth.add_argument("--presets", nargs="+", default=["pf-diffusion-local", "pf-gpdm", "pf-lie", "ukf-gpdm"])
    smooth.add_argument("--frames", type=int, default=100)
    smooth.add_argument("--trajectories", type=int, default=100)
    smooth.add_argument("--seed", type=int, default=0)
    smooth.add_argument("--json", action="store_true", help="(the output is always JSON)")
    smooth.set_defaults(run=_bench_smooth)

    plot = verbs.add_parser("plot", help="a GPDM's latent trajectories over its log reconstruction variance")
    plot.add_argument("prior", help="a gpdm or bgpdm prior file")
    plot.add_argument("--out", required=True, help="the image to write (.png)")
    plot.set_defaults(run=_plot)

    evaluate = verbs.add_parser("eval", help="the papers' experiments on bundled data").add_subparsers(
        dest="experiment", required=True)
    fill_in = evaluate.add_parser("fill-in", help="GPDM missing-frame fill-in (Wang et al. 2008, Table 2)")
    fill_in.add_argument("--seed", type=int, default=0)
    fill_in.add_argument("--json", action="store_true")
    fill_in.set_defaults(run=_eval_fill_in)
    loglik = evaluate.add_parser("loglik", help="held-out log-likelihood of the Lie prior and the diffusions")
    loglik.add_argument("--train", nargs="+", help="training motions (default: leave one subject out)")
    loglik.add_argument("--test", nargs="+", help="test motions")
    loglik.add_argument("--seed", type=int, default=0)
    loglik.add_argument("--json", action="store_true")
    loglik.set_defaults(run=_eval_loglik)
    real = evaluate.add_parser("real-format", help="held-out walks written as OpenPose JSON through the Pose2Sim "
                                                   "cameras, tracked without truth, against the mocap and DLT")
    real.add_argument("--presets", nargs="+", default=["pf-diffusion-local", "apf-diffusion-local", "pf-gpdm", "pf-lie",
                                                       "ukf-diffusion-local", "ukf-gpdm", "map-gpdm", "ukf-real"])
    real.add_argument("--motions", nargs="+", default=["walkjog:35_29", "cmu:07_10", "cmu:07_11"])
    real.add_argument("--seeds", type=int, default=1)
    real.add_argument("--cameras", type=int, nargs="+", help="indices of the calibration's cameras to use (all 4)")
    real.add_argument("--smooth", action="store_true", help="smooth each run: smoothed vs filtered error and jitter "
                                                            "(the particle and unscented presets)")
    real.add_argument("--json", action="store_true")
    real.set_defaults(run=_eval_real_format)
    fit_check = evaluate.add_parser("fit-check", help="is a motion in a prior's support? its per-frame log-density "
                                                      "against frames held out from the prior's training data")
    fit_check.add_argument("prior", help="a preset name or .toml, or a prior file (.npz, with --reference)")
    fit_check.add_argument("motion", help="bundled name, .amc or .bvh file")
    fit_check.add_argument("--reference", nargs="+", help="motions of the prior's kind it was not fitted on (default "
                                                          "for a preset: two-fold cross-fits of its training motions)")
    fit_check.add_argument("--json", action="store_true")
    fit_check.set_defaults(run=_eval_fit_check)
    pace = evaluate.add_parser("pace", help="filters on held-out walks played slower and faster than the training walks")
    pace.add_argument("--presets", nargs="+", default=["pf-diffusion-local", "pf-lie", "pf-lie-defensive", "pf-gpdm"])
    pace.add_argument("--motions", nargs="+", default=["walkjog:35_29", "cmu:07_10", "cmu:07_11"])
    pace.add_argument("--paces", type=float, nargs="+", default=[0.6, 1.0, 1.4])
    pace.add_argument("--scenarios", nargs="+", default=["noise", "blackout:sigma_px=5"])
    pace.add_argument("--seeds", type=int, default=2)
    pace.add_argument("--json", action="store_true")
    pace.set_defaults(run=_eval_pace)
    people = evaluate.add_parser("people", help="leave one walking person out: priors refitted without them, their "
                                                "walks tracked on the lab and the real-format benches")
    people.add_argument("--presets", nargs="+", default=["pf-diffusion-local", "pf-gpdm", "pf-lie", "pf-lie-defensive"],
                        help="presets (names or .toml paths); the lab ratios need pf-diffusion-local among them")
    people.add_argument("--people", nargs="+", default=["07", "35", "02", "05", "08+39"],
                        help="the held-out people (08+39: CMU subjects 08 and 39, one person)")
    people.add_argument("--benches", nargs="+", default=["lab", "real4", "real1"],
                        help="lab (synthetic side camera), real4 (OpenPose-style JSON, 4 cameras), real1 (1 camera)")
    people.add_argument("--seeds", type=int, default=2)
    people.add_argument("--out", help="the run cache: a rerun does no work, an interrupted one resumes "
                                      "(default: people/ beside the prior cache)")
    people.add_argument("--jobs", type=int, default=1, help="runs in this many worker processes (the same numbers)")
    people.add_argument("--json", action="store_true")
    people.set_defaults(run=_eval_people)
    smoothing = evaluate.add_parser("smoothing", help="smoothed vs filtered through a blackout on held-out walks")
    smoothing.add_argument("--presets", nargs="+",
                           default=["pf-diffusion-local", "pf-gpdm", "pf-lie", "ukf-diffusion-local", "ukf-gpdm"])
    smoothing.add_argument("--motions", nargs="+", default=["walkjog:35_29", "cmu:07_10", "cmu:07_11"])
    smoothing.add_argument("--seeds", type=int, default=1)
    smoothing.add_argument("--json", action="store_true")
    smoothing.set_defaults(run=_eval_smoothing)
    loo = evaluate.add_parser("leave-one-out", help="real detections: track from 3 cameras, reproject into the 4th")
    loo.add_argument("--presets", nargs="+", default=["pf-diffusion-local", "apf-diffusion-local", "pf-gpdm", "pf-lie",
                                                      "ukf-diffusion-local", "ukf-gpdm", "map-gpdm", "ukf-real"])
    loo.add_argument("--json", action="store_true")
    loo.set_defaults(run=_eval_leave_one_out)
    tracking = evaluate.add_parser("tracking", help="the accuracy table: every preset x scenario over seeds")
    tracking.add_argument("--presets", nargs="+", help="default: the table's nine presets")
    tracking.add_argument("--scenarios", nargs="+", help="default: clean, occlusion and blackout at 5 px")
    tracking.add_argument("--motions", nargs="+", help="held-out motions to track (default: 35_29, 07_10, 07_11)")
    tracking.add_argument("--seeds", type=int, help="seeds per motion (default 5)")
    tracking.add_argument("--jobs", type=int, default=1,
                          help="runs in this many worker processes (the same numbers; the MAP and unscented "
                               "filters run on one thread each, so 2 jobs about halve their rows' time)")
    tracking.add_argument("--json", action="store_true")
    tracking.set_defaults(run=_eval_tracking)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        args.run(args)
    except (PriortrackError, OSError) as exc:         # OSError: a file that could not be read or written
        print(f"priortrack: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
