"""``priortrack track``: a motion's synthetic observations, or real detections from calibrated cameras."""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import replace

from priortrack.cli.common import Progress, add_height_options, camera_map, floor_level, print_json
from priortrack.errors import PriortrackError
from priortrack.output import output_path

log = logging.getLogger(__name__)


def _track(args: argparse.Namespace) -> None:
    if args.detections is not None or args.motion is None:
        _track_detections(args)
        return
    from priortrack.experiments.tracking import track
    from priortrack.viz.replay import replay

    for name in ("cameras", "keypoints", "up", "camera_map", "out", "person", "people", "skeleton", "memory",
                 "workers", "association", "no_fit_check", "rate", "lowpass", "floor"):
        if getattr(args, name):
            raise PriortrackError(f"--{name.replace('_', '-')} is for tracking --detections, not a motion")
    if args.height is not None:
        raise PriortrackError("--height is for tracking --detections, not a motion (its body is the motion's own)")
    if args.rrd:
        output_path(args.rrd, "rerun recording")
    progress = Progress(f"track {args.filter}", "tick {0} of {1}", rate=True)
    try:
        run = track(args.motion, args.filter, args.scenario, args.seed, keep_snapshots=bool(args.rrd),
                    progress=progress, frames=args.frames, device=args.device, **_smoothing(args))
    finally:
        progress.close()
    if args.rrd:
        from priortrack.tracking.presets import load_preset

        replay(run.motion, run.observations, args.rrd, track=run.track,
               smoothed=None if run.smoothed is None else run.smoothed.estimates,
               likelihood=load_preset(args.filter).likelihood(run.observations.camera),
               name=f"{args.filter} · {run.motion.name} · {args.scenario} · seed {args.seed}")
    if args.json:
        print_json(run.result)
        return
    r = run.result
    lag = "" if r.get("lag") is None else f" (lag {r['lag']})"
    smoothed = f" smoothed{lag}, filtered {r['filtered_mpjpe_mm']:.1f} mm" if "filtered_mpjpe_mm" in r else ""
    print(f"{r['filter']} on {r['motion']} ({r['frames']} frames, scenario {r['scenario']}, seed {r['seed']}): "
          f"MPJPE {r['mpjpe_mm']:.1f} mm{smoothed}, root-relative {r['mpjpe_root_rel_mm']:.1f} mm, 2D {r['err2d_px']:.1f} px, "
          f"{1000 * r['seconds_per_frame']:.0f} ms/frame"
          + (f", mean ESS {r['mean_ess']:.0f}" if r["mean_ess"] is not None else "")
          + (f"; wrote {args.rrd}" if args.rrd else ""))


#: :data:`priortrack.filters.smoothing.PARTICLE_SMOOTHERS`, named here so that the help does not import torch.
PARTICLE_SMOOTHERS = ("gaussian", "backward")


def _smoothing(args: argparse.Namespace) -> dict:
    """track's smoothing arguments: --smooth, or a --lag (which implies it), --particle-smoother and --trajectories."""
    if args.lag is not None and args.lag < 0:
        raise PriortrackError(f"--lag must be a whole number of frames ≥ 0, got {args.lag}")
    if args.trajectories is not None and args.trajectories < 1:
        raise PriortrackError(f"--trajectories must be positive, got {args.trajectories}")
    chosen = {"trajectories": args.trajectories} if args.trajectories is not None else {}
    return {"smooth": args.smooth or args.lag is not None, "lag": args.lag,
            "particle_smoother": args.particle_smoother, **chosen}


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
    from priortrack.data.detections import open_detections
    from priortrack.tracking.person import RESULT_SUFFIXES, TrackConfig, track_detections
    from priortrack.filters.step_store import DEFAULT_MEMORY, parse_memory

    if args.motion is not None:
        raise PriortrackError("give a motion or --detections, not both")
    if args.detections is None or args.cameras is None:
        raise PriortrackError("track needs a MOTION (synthetic observations) or --detections with --cameras")
    if args.person is not None:
        raise PriortrackError(f"--person is now --people index:{args.person} (the person at that index of each "
                              f"frame's list)")
    for path in args.out or []:
        if Path(path).suffix.lower() not in RESULT_SUFFIXES:
            raise PriortrackError(f"--out {path}: results are written as {', '.join(RESULT_SUFFIXES)}")
        output_path(path, "result file")
    if args.rrd:
        output_path(args.rrd, "rerun recording")
    if args.rrd_every < 1:
        raise PriortrackError(f"--rrd-every must be a whole number of ticks ≥ 1, got {args.rrd_every}")
    if args.lowpass is not None and not args.lowpass > 0:
        raise PriortrackError(f"--lowpass is a cut-off frequency in Hz above 0, got {args.lowpass:g}")
    config = TrackConfig(fps=args.fps, up=args.up, camera_map=camera_map(args.camera_map),
                         min_confidence=args.min_confidence,
                         seed=args.seed, height=args.height, floor=floor_level(args.floor), device=args.device,
                         memory=DEFAULT_MEMORY if args.memory is None else parse_memory(args.memory),
                         fit_check=not args.no_fit_check, **_smoothing(args))
    skeleton = _skeleton(args.skeleton) if args.skeleton else None
    if args.people is not None:
        _track_scene(args, config, skeleton)
        return
    if args.workers is not None:
        raise PriortrackError("--workers tracks several people side by side: give --people")
    if args.association is not None:
        raise PriortrackError("--association decides who is who among several people: give --people")
    calibration = read_calibration(args.cameras, units=args.units)
    config = replace(config, keep_snapshots=bool(args.rrd), snapshot_every=args.rrd_every, interruptible=True)
    scene = _every_person(args)
    progress = Progress(f"track {args.filter}", "tick {0} of {1}", rate=True)
    try:
        if scene is not None and int(scene.people.max(initial=0)) > 1:      # a scene of one: the person seen most
            from priortrack.tracking.people import track_scene

            log.warning("%s holds up to %d people in a frame: tracking the one seen most (the most keypoints detected; "
                        "--people all tracks each, --people at:CAMERA:X,Y the one there)", args.detections,
                        scene.people.max())
            result = track_scene(scene, calibration, args.filter, config, people=1, skeleton=skeleton,
                                 progress=progress).people[0]
        else:
            if scene is not None:                     # one person per frame: followed in what was read
                detections = scene.followed()
            else:                                     # an npz or npy is read a block of frames at a time
                detections = open_detections(args.detections, keypoints=args.keypoints)
                if args.frames is not None:
                    detections = detections.head(args.frames)
            result = track_detections(detections, calibration, args.filter, config, skeleton=skeleton,
                                      progress=progress)
    finally:
        progress.close()
    if result.interrupted:
        print(f"priortrack: interrupted: writing the {len(result.joints)} ticks tracked until then", file=sys.stderr)
    output = for_output(result, args) if args.out else None
    written = [str(output.save(path)) for path in args.out or []]
    if args.rrd:
        from priortrack.viz.real import record_detections

        written.append(str(record_detections(result, args.rrd)))
    summary = {**result.summary(), "written": written}
    if args.json:
        print_json(summary)
        return
    errors = ", ".join(f"{n} {e:.1f} px" for n, e in summary["reprojection_px"].items())
    print(f"{result.filter}: {summary['frames']} ticks at {result.fps:g} fps in {summary['seconds']:.1f} s; "
          f"median reprojection {errors}; mismatch {100 * summary['mismatch_fraction']:.0f}% of ticks; "
          f"{body_text(summary)}{written_text(written, output)}")


def written_text(written: list[str], output) -> str:
    """"; wrote FILES (N frames at F fps)" for the files written from ``output`` (:func:`for_output`), or ""."""
    return "" if output is None else f"; wrote {', '.join(written)} ({len(output.frames)} frames at {output.fps:g} fps)"


def body_text(summary: dict) -> str:
    """The tracked body of a person's JSON summary in words: height (and where it came from), each limb's left / right,
    metres."""
    if summary.get("height_m") is None:
        return "the body given (--skeleton)"
    limbs = ", ".join(f"{name.replace('_', ' ')} {left:.2f} / {right:.2f}"
                      for name, (left, right) in summary["limbs_left_right_m"].items())
    return f"body {summary['height_m']:.2f} m tall{_from(summary)}, left / right m: {limbs}"


def _from(summary: dict) -> str:
    """Where a summary's body height came from, in words: " (measured from the floor)" and the like, else ""."""
    from priortrack.tracking.person import HEIGHT_FROM

    words = HEIGHT_FROM.get(summary.get("height_from", ""))
    return f" ({words})" if words else ""


#: ``--rate``: the outputs' frames, the detections' own (the default) or the filter's ticks.
RATES = ("detections", "ticks")


def for_output(result, args: argparse.Namespace):
    """A tracked result (one person's or a scene's) as the files are written from it: at the frames ``--rate`` asks
    for, the detections' own (the default: each frame's estimate carried to its time,
    :mod:`priortrack.tracking.resample`) or the filter's ticks, then low-passed where ``--lowpass`` asks
    (:mod:`priortrack.tracking.lowpass`)."""
    result = result if args.rate == "ticks" else result.at_detection_frames()
    return result if args.lowpass is None else result.low_passed(args.lowpass)


def _every_person(args: argparse.Namespace):
    """Every person of detections given to ``track --detections`` without ``--people`` where their format may hold
    several (:func:`~priortrack.data.scene_detections.holds_people`: an OpenPose folder, COCO results, an .npz of
    people; its files parsed once: several people in a frame make it a scene of one, from one camera too; one person
    is followed as :func:`~priortrack.data.detections.read_detections` would); else None (one person's file)."""
    from priortrack.data.scene_detections import holds_people, read_scene_detections

    if not holds_people(args.detections):
        return None
    scene = read_scene_detections(args.detections, keypoints=args.keypoints)
    return scene.head(args.frames) if args.frames is not None else scene


def _track_scene(args: argparse.Namespace, config, skeleton) -> None:
    """``track --detections … --people …``: every person of the scene (:mod:`priortrack.tracking.people`),
    each tracked as ``config`` (:class:`~priortrack.tracking.person.TrackConfig`) says."""
    from priortrack.data.calibration import read_calibration
    from priortrack.data.scene_detections import read_scene_detections
    from priortrack.tracking.people import parse_people, track_scene, worker_count
    from priortrack.tracking.scene import SceneConfig

    workers = worker_count(args.workers)                  # checked before the files are read
    people = parse_people(args.people)
    scene_config = SceneConfig(association=args.association or SceneConfig.association)
    scene = read_scene_detections(args.detections, keypoints=args.keypoints)
    if args.frames is not None:
        scene = scene.head(args.frames)
    calibration = read_calibration(args.cameras, units=args.units)
    progress = Progress(f"track {args.filter}", "{0} of {1}", rate=True)    # people tracked (one person: ticks)
    try:
        result = track_scene(scene, calibration, args.filter,
                             replace(config, interruptible=True, keep_snapshots=bool(args.rrd),
                                     snapshot_every=args.rrd_every), scene_config,
                             people=people, workers=workers, skeleton=skeleton, progress=progress)
    finally:
        progress.close()
    if result.interrupted:
        print(f"priortrack: interrupted: writing the {len(result.person_ids)} "
              f"{'person' if len(result.person_ids) == 1 else 'people'} tracked until then", file=sys.stderr)
    output = for_output(result, args) if args.out else None
    written = [str(p) for path in args.out or [] for p in output.save(path)]
    if args.rrd:
        from priortrack.viz.scene import record_scene

        written.append(str(record_scene(result, args.rrd, args.min_confidence)))
    summary = {**result.summary(), "filter": args.filter, "written": written}
    if args.json:
        print_json(summary)
        return
    people_text = "; ".join(
        f"person {pid} ({v['ticks_present']} ticks, {v['height_m']:.2f} m tall{_from(v)}, seen in {v['frames_seen']} "
        f"frames by {', '.join(v['cameras'])}, at {', '.join(f'{x:.2f}' for x in v['mean_position_m'])} m)"
        for pid, v in summary["per_person"].items())
    skipped = "".join(f"; person {k} not tracked: {v}" for k, v in summary["skipped"].items())
    print(f"{args.filter}: {len(result.person_ids)} {'person' if len(result.person_ids) == 1 else 'people'}, "
          f"{summary['frames']} ticks at {result.fps:g} fps in "
          f"{summary['seconds']:.1f} s: {people_text}{skipped}"
          + written_text(written, output))


def add_parsers(verbs) -> None:
    """Register this family's verbs on the ``priortrack`` sub-parsers."""
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
    track.add_argument("--person", help=argparse.SUPPRESS)                   # now --people index:N
    track.add_argument("--people", nargs="+", metavar="WHO",
                       help="track every person of the scene, each with an identity: all; N (the N seen most: "
                            "keypoints detected); id:A,B; at:CAMERA:X,Y or box:CAMERA:X0,Y0,X1,Y1 (the person there in that camera's "
                            "first frame); index:N (files whose people keep their order: the person at index N of "
                            "each frame's list, no scene tracker). Outputs hold every person: .npz joints (T, P, 15, 3), .csv with a person "
                            "column, a .trc/.bvh per person; the recording colours and labels each")
    track.add_argument("--workers", type=int, metavar="N",
                       help="--people: processes tracking people side by side (default: one per core)")
    track.add_argument("--association", metavar="auto|joints|filter",
                       help="--people: who is who finally decided by the scene tracker's joint model (joints: each "
                            "person then tracked on their own, side by side) or through every person's own filter, "
                            "all stepped together in one process (filter); auto, the default: filter on 2 or 3 "
                            "cameras, joints on more")
    track.add_argument("--skeleton", help="the person's own body (.asf, or a .bvh's hierarchy) instead of the "
                                         "template scaled to the detections")
    track.add_argument("--no-fit-check", action="store_true",
                       help="--detections: do not judge the tracked motion under the prior after the last tick (its "
                            "reference is fitted once if not cached; mismatch flags then from the detections alone)")
    add_height_options(track)
    track.add_argument("--out", action="append",
                       help="write the result by suffix: .npz (joints, spread, ESS, log-likelihood, flags), .csv, "
                            ".trc (Y up, metres, every keypoint: OpenSim), .mot (joint angles, degrees: OpenSim) or "
                            ".bvh (Y up, centimetres: Blender); may repeat (docs/formats.md)")
    track.add_argument("--rate", choices=RATES,
                       help="--detections: the outputs' frames: the detections' own, at their rate (the default: "
                            "each frame's estimate carried to its time by a cubic spline through the filter's "
                            "ticks), or the filter's ticks at its prior's rate (30 fps for the bundled presets)")
    track.add_argument("--lowpass", type=float, metavar="HZ",
                       help="--detections: the outputs' joints also through a zero-lag Butterworth low-pass at HZ "
                            "(4th order, as Pose2Sim filters its markers; 6 is its default), after the filter or "
                            "smoother; the recording keeps the filter's own")
    track.add_argument("--filter", default="ukf-real",
                       help="a preset name (priortrack presets) or a .toml file (default %(default)s)")
    track.add_argument("--scenario", default="clean",
                       help="NAME or NAME:key=value,... (clean, noise, dropout, occlusion, blackout, outliers)")
    track.add_argument("--seed", type=int, default=0, help="seeds the observations and the filter")
    track.add_argument("--device", default="cpu", help="cpu (default), cuda or cuda:N: where a particle filter's "
                                                       "particles live (pf and apf presets; the others run on the CPU)")
    track.add_argument("--frames", type=int, help="track only the first N frames (a motion: ticks at the "
                                                  "prior's rate; --detections: the file's first N frames)")
    track.add_argument("--rrd", help="also write a rerun recording: truth, estimate, particle cloud, 2D observations")
    track.add_argument("--rrd-every", type=int, default=1, metavar="K",
                       help="--detections: the recording's particle cloud at every K-th tick only (a long run's "
                            "memory; skeletons, scalars and events at every tick; default 1)")
    track.add_argument("--smooth", action="store_true",
                       help="also smooth the run: each frame's estimate given every frame (outputs the smoothed joints)")
    track.add_argument("--lag", type=int, help="fixed-lag smoothing: frame t − LAG estimated at frame t (implies --smooth)")
    track.add_argument("--particle-smoother", choices=PARTICLE_SMOOTHERS, default=PARTICLE_SMOOTHERS[0],
                       help="a particle filter's smoother: the RTS recursion on each frame's cloud moments, or "
                            "backward simulation, which keeps a multimodal cloud's modes (default %(default)s)")
    track.add_argument("--trajectories", type=int,
                       help="smoothed trajectories backward simulation draws (default 100)")
    track.add_argument("--memory", help="whole-run --smooth of --detections: the filter's steps held "
                                                       "in memory (e.g. 500MB, 2GB; default 1GB), the rest spilled to a "
                                                       "temporary folder and read back by the smoother; the unscented "
                                                       "smoother's own per-frame matrices get as much again")
    track.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    track.set_defaults(run=_track)
