"""``priortrack presets``, ``data list`` and ``replay``: what is bundled, and the synthetic observations of a motion."""

from __future__ import annotations

import argparse
import json

from priortrack.output import output_path


def _presets(args: argparse.Namespace) -> None:
    from priortrack.tracking.presets import load_preset, preset_names

    presets = [load_preset(name) for name in preset_names()]
    if args.json:
        print(json.dumps([{"name": p.name, "filter": p.filter_kind, "prior": p.prior_kind, "description": p.description}
                          for p in presets], indent=2))
        return
    print(f"{'preset':<22} {'filter':<7} {'prior':<17} description")
    for p in presets:
        print(f"{p.name:<22} {p.filter_kind:<7} {p.prior_kind:<17} {p.description}")


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
    from shlex import quote

    from priortrack.data.bundled import POSE2SIM_DIR

    print(f"\nReal detections (no 3D truth): Pose2Sim's static demo trial, OpenPose BODY_25B from 4 phone cameras, 12 "
          f"frames at 60 fps, one person standing (BSD-3, {POSE2SIM_DIR / 'SOURCE.md'}):\n"
          f"  priortrack track --detections {quote(str(POSE2SIM_DIR / 'pose'))} --cameras "
          f"{quote(str(POSE2SIM_DIR / 'Calib.toml'))} --keypoints body25b --fps 60 --out person.npz")


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


def add_parsers(verbs) -> None:
    """Register this family's verbs on the ``priortrack`` sub-parsers."""
    presets = verbs.add_parser("presets", help="list the filter presets")
    presets.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    presets.set_defaults(run=_presets)

    data = verbs.add_parser("data", help="bundled motion data").add_subparsers(dest="action", required=True)
    listing = data.add_parser("list", help="list the bundled clips")
    listing.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    listing.set_defaults(run=_data_list)

    replay = verbs.add_parser("replay", help="log a motion and its synthetic 2D observations to rerun")
    replay.add_argument("motion", help="bundled name (cmu:07_01, walkjog:35_29), .amc or .bvh file")
    replay.add_argument("--scenario", default="clean",
                        help="NAME or NAME:key=value,... (clean, noise, dropout, occlusion, blackout, outliers)")
    replay.add_argument("--seed", type=int, default=0, help="random seed (default %(default)s): the same seed, the same numbers")
    replay.add_argument("--fps", type=float, default=30.0, help="resample to this rate first (default 30)")
    replay.add_argument("--observations", help="also save the observations to this .npz")
    replay.add_argument("--out", required=True, help="the .rrd file to write")
    replay.set_defaults(run=_replay)
