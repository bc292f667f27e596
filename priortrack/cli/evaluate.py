"""``priortrack eval …``: the papers' experiments and our own benches on bundled data."""

from __future__ import annotations

import argparse
import logging

from priortrack.cli.common import add_height_options, camera_map, floor_level, print_json
from priortrack.errors import PriortrackError


def _eval_fill_in(args: argparse.Namespace) -> None:
    from priortrack.experiments.reproductions.fill_in import eval_fill_in

    result = eval_fill_in(seed=args.seed)
    if args.json:
        print_json(result)
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
        print_json(result)
        return
    print("mean log p(v_t | x_t) per frame (higher is better); held-out steps' d²/n under each model's Gaussian step "
          "(1: calibrated; more: over-confident) and their share beyond its χ² 99th percentile (1 %: calibrated)")
    for model in ("lie", "lie_defensive", "diffusion_local", "diffusion_global"):
        r = result[model]
        print(f"  {model:<17} train {r['train']:9.2f}   test {r['test']:9.2f}   d²/n {r['test_d2']:6.2f}   "
              f"beyond {100 * r['test_beyond']:5.1f} %")


def _eval_real_format(args: argparse.Namespace) -> None:
    from priortrack.experiments.real_format import eval_real_format

    result = eval_real_format(args.presets, args.motions, args.seeds, cameras=args.cameras, smooth=args.smooth)
    if args.json:
        print_json(result)
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


def _eval_fit_check(args: argparse.Namespace) -> None:
    from pathlib import Path

    from priortrack.data.load import load_motion
    from priortrack.tracking.presets import load_preset
    from priortrack.priors.base import load_prior
    from priortrack.priors.support import frame_log_density, reference, verdict, verdict_rule

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
        print_json(result)
        return
    p = result["reference_percentiles"]
    print(f"{args.motion} under {args.prior} ({prior.kind}): {result['verdict']}. "
          f"{100 * result['below_p1_fraction']:.0f}% of its frames score below the 1st percentile of frames the prior "
          f"was not fitted on ({p['1']:.1f}); median log-density {result['median_log_density']:.1f} per frame, at the "
          f"{result['median_percentile']:.0f}th percentile (reference median {p['50']:.1f}); {verdict_rule()}")


def _eval_pace(args: argparse.Namespace) -> None:
    from priortrack.experiments.pace import eval_pace

    result = eval_pace(args.presets, args.motions, args.paces, args.scenarios, args.seeds)
    if args.json:
        print_json(result)
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
        print_json(result)
        return
    columns = [(f"{s.split(':')[0]}_mm", f"{s.split(':')[0]}_ratio") for s in LAB_SCENARIOS] + \
        [("real4_mm", "real4_dlt_ratio"), ("real1_relative_mm", None)]
    print(f"leave one walking person out, mean over the person's walks and {args.seeds} seeds: lab world MPJPE mm "
          f"(x pf-diffusion-local), 4 cameras shoulders-ankles mm (x DLT) and % of ticks flagged as mismatch, 1 camera "
          f"relative to hips mm")
    print("| held out | preset | clean | blackout | 4 cameras | flagged | 1 camera | failed runs |")
    print("|---|---|---|---|---|---|---|---|")
    for person, presets in result["table"].items():
        for preset, cells in presets.items():
            text = [(f"{cells[value]:.0f}" + (f" ({cells[ratio]:.2f})" if ratio in cells else "")) if value in cells
                    else "—" for value, ratio in columns]
            flagged = f"{100 * cells['real4_flagged']:.0f}%" if "real4_flagged" in cells else "—"
            print(f"| {person} | {preset} | " + " | ".join(text[:-1] + [flagged, text[-1]]) + f" | {cells['failed_runs']} |")


def _eval_scenes(args: argparse.Namespace) -> None:
    from priortrack.experiments.scenes import eval_scenes

    result = eval_scenes(args.scenes, args.presets, args.seeds, args.gaps, args.association)
    if args.json:
        print_json(result)
        return
    print(f"scenes of people held out of the priors (4 cameras, detector errors, occlusions, a false positive), "
          f"{args.seeds} seeds: MOTA, IDF1, identity switches, false tracks, lowest PCP, mean MPJPE shoulders to "
          f"ankles, and the highest ratio of a person's MPJPE to the same person tracked alone")
    print("| scene · preset | MOTA | IDF1 | switches | false tracks | min PCP % | MPJPE mm | max × alone |")
    print("|---|---|---|---|---|---|---|---|")
    for key, c in result["table"].items():
        print(f"| {key} | {c['mota']:.3f} | {c['idf1']:.3f} | {c['switches']} | {c['false_tracks']} | "
              f"{c['min_pcp']:.1f} | {c['mpjpe_mm']:.1f} | {c['max_ratio_to_alone']:.2f} |")


def _eval_against_trc(args: argparse.Namespace) -> None:
    from priortrack.experiments.against_trc import against_trc

    result = against_trc(args.detections, args.cameras, args.reference, args.fps, args.filter, args.keypoints,
                         camera_map(args.camera_map), args.height, floor_level(args.floor))
    if args.json:
        print_json(result)
        return
    print(f"{args.filter}, person {result['person']} ({result['frames']} frames at {result['fps']:g} fps) against "
          f"{args.reference}: median distance of the 12 limb joints and of the feet markers, mm; the right wrist's "
          f"acceleration RMS, m/s² (the reference's: "
          + ("—" if result["reference_wrist_m_s2"] is None else f"{result['reference_wrist_m_s2']:.1f}") + ")")
    print("| run | limbs mm | feet mm | right wrist m/s² |")
    print("|---|---|---|---|")
    for row in result["rows"]:
        feet = "—" if row["feet_mm"] is None else f"{row['feet_mm']:.1f}"
        print(f"| {row['run']} | {row['limbs_mm']:.1f} | {feet} | {row['wrist_m_s2']:.1f} |")


def _shelf_diagnosis(args: argparse.Namespace) -> None:
    from priortrack.experiments.shelf import LAGS, SMOOTHING_WIDTH, diagnose

    if args.subsets:
        raise PriortrackError("--diagnose looks at one subset of cameras: give --cameras, not --subsets")
    result = diagnose(args.directory, args.cameras, args.detections, args.fps, args.actors)
    if args.json:
        print_json(result)
        return
    print(f"per-frame DLT given the true association, cameras {','.join(result['cameras'])}, actors "
          f"{', '.join(map(str, result['actors']))}: what its error is made of (mm; autocorrelation of the error "
          f"less its bias at {', '.join(map(str, LAGS))} frames; smoothed: a centred {SMOOTHING_WIDTH}-frame mean; "
          f"body: the tracker's body fitted to the DLT, and to the truth; still: annotation unchanged from the last frame)")
    print("| joint | RMS | bias | bias share | autocorrelation | smoothed | body on DLT | body on truth | still |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, r in list(result["joints"].items()) + [("mean", result["summary"])]:
        ac = " ".join(f"{v:.2f}" for v in r["autocorrelation"]) if "autocorrelation" in r else ""
        still = f"{100 * r['truth_still_share']:.0f}%" if "truth_still_share" in r else ""
        print(f"| {name} | {r['rms_mm']:.1f} | {r['bias_mm']:.1f} | {100 * r['bias_share']:.0f}% | {ac} | "
              f"{r['smoothed_rms_mm']:.1f} | {r['body_rms_mm']:.1f} | {r['truth_body_rms_mm']:.1f} | {still} |")
    print(f"left-right swapped camera-detections: {100 * result['swapped_share']:.2f}%; joints move "
          f"{result['tick_offset_mm']['mean']:.1f} mm (p95 {result['tick_offset_mm']['p95']:.1f}) between a frame "
          f"and the 30 fps tick that takes it")


def _eval_shelf(args: argparse.Namespace) -> None:
    from priortrack.experiments.shelf import eval_shelf

    if args.diagnose:
        _shelf_diagnosis(args)
        return
    result = eval_shelf(args.directory, args.presets, args.cameras, args.subsets, args.detections, args.fps,
                        args.actors, args.seed, args.workers, association=args.association)
    if args.json:
        print_json(result)
        return
    actors = result["actors"]
    print(f"{result['detections']}, {result['frames']} frames at {result['fps']:g} fps: per actor PCP % of the 8 limb "
          f"parts, and MPJPE mm of the 12 limb joints where the DLT has them (every frame's after the slash), the "
          f"oracle DLT of the same cameras (the true association) in brackets; identity switches and false tracks "
          f"over every annotated actor; seconds")
    print("| cameras | preset | " + " | ".join(f"actor {a} PCP" for a in actors) + " | mean PCP | " +
          " | ".join(f"actor {a} mm" for a in actors) + " | switches | false tracks | s |")
    print("|---|---|" + "---|" * (2 * len(actors) + 4))

    def cell(mine, dlt, digits=1):
        shown = lambda v: "—" if v is None else f"{v:.{digits}f}"          # noqa: E731
        return f"{shown(mine)} ({shown(dlt)})"

    for row in result["rows"]:
        people = row["actors"]
        mean = [None if any(v is None for v in values) else sum(values) / len(values)
                for values in ([p["pcp"] for p in people], [p["dlt"]["pcp"] for p in people])]
        print(f"| {','.join(row['cameras'])} | {row['preset']} | " + " | ".join(cell(p["pcp"], p["dlt"]["pcp"]) for p in people) +
              f" | {cell(*mean)} | " + " | ".join(f"{cell(p['mpjpe_beside_mm'], p['dlt']['mpjpe_mm'], 0)} / "
                                                   f"{'—' if p['mpjpe_mm'] is None else round(p['mpjpe_mm'])}"
                                                   for p in people) +
              f" | {row['switches']} | {len(row['false_tracks'])} | {row['seconds']:.1f} |")
    for row in result["rows"]:
        if len(row["cameras"]) == 1:
            print(f"camera {row['cameras'][0]} alone, {row['preset']}: root-relative MPJPE (mid-hips aligned) per actor, "
                  "mm: " + ", ".join(f"actor {p['actor']} " + ("—" if p["mpjpe_root_mm"] is None else
                                                              f"{p['mpjpe_root_mm']:.0f}") for p in row["actors"]))
    if args.per_joint:
        for row in result["rows"]:
            print(f"\ncameras {','.join(row['cameras'])}, {row['preset']}: MPJPE per limb joint, mm, where the DLT has "
                  f"it (the oracle DLT's in brackets) / every frame's")
            joints = list(row["actors"][0]["per_joint_mm"])
            print("| actor | " + " | ".join(joints) + " |")
            print("|---|" + "---|" * len(joints))
            for p in row["actors"]:
                beside = p.get("per_joint_beside_mm") or dict.fromkeys(joints)
                every = {j: "—" if p["per_joint_mm"][j] is None else round(p["per_joint_mm"][j]) for j in joints}
                print(f"| {p['actor']} | " + " | ".join(f"{cell(beside[j], p['dlt']['per_joint_mm'][j], 0)} / {every[j]}"
                                                       for j in joints) + " |")


def _eval_smoothing(args: argparse.Namespace) -> None:
    from priortrack.experiments.smoothing import eval_smoothing

    result = eval_smoothing(args.presets, args.motions, args.seeds)
    if args.json:
        print_json(result)
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


def _eval_tracking(args: argparse.Namespace) -> None:
    from priortrack.experiments.tracking import TABLE_MOTIONS, TABLE_PRESETS, TABLE_SCENARIOS, TABLE_SEEDS, eval_tracking

    def show(row: dict) -> None:
        logging.getLogger("priortrack.track").info("%s %s %s seed %d: %.1f mm", row["filter"], row["motion"],
                                                    row["scenario"], row["seed"], row["mpjpe_mm"])

    presets, scenarios = args.presets or list(TABLE_PRESETS), args.scenarios or list(TABLE_SCENARIOS)
    motions, seeds = args.motions or list(TABLE_MOTIONS), TABLE_SEEDS if args.seeds is None else args.seeds
    result = eval_tracking(presets, scenarios, motions, seeds, progress=show, jobs=args.jobs)
    if args.json:
        print_json(result)
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


def add_parsers(verbs) -> None:
    """Register this family's verbs on the ``priortrack`` sub-parsers."""
    evaluate = verbs.add_parser("eval", help="the papers' experiments on bundled data").add_subparsers(
        dest="experiment", required=True)
    fill_in = evaluate.add_parser("fill-in", help="GPDM missing-frame fill-in (Wang et al. 2008, Table 2)")
    fill_in.add_argument("--seed", type=int, default=0, help="random seed (default %(default)s): the same seed, the same numbers")
    fill_in.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    fill_in.set_defaults(run=_eval_fill_in)
    loglik = evaluate.add_parser("loglik", help="held-out log-likelihood of the Lie prior and the diffusions")
    loglik.add_argument("--train", nargs="+", help="training motions (default: leave one subject out)")
    loglik.add_argument("--test", nargs="+", help="test motions")
    loglik.add_argument("--seed", type=int, default=0, help="random seed (default %(default)s): the same seed, the same numbers")
    loglik.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    loglik.set_defaults(run=_eval_loglik)
    real = evaluate.add_parser("real-format", help="held-out walks written as OpenPose JSON through the Pose2Sim "
                                                   "cameras, tracked without truth, against the mocap and DLT")
    real.add_argument("--presets", nargs="+", default=["pf-diffusion-local", "apf-diffusion-local", "pf-gpdm", "pf-lie",
                                                       "ukf-diffusion-local", "ukf-gpdm", "map-gpdm", "ukf-real"], help="preset names or .toml files (default: %(default)s)")
    real.add_argument("--motions", nargs="+", default=["walkjog:35_29", "cmu:07_10", "cmu:07_11"], help="bundled names (cmu:07_10, walkjog:35_29), .amc or .bvh files (default: %(default)s)")
    real.add_argument("--seeds", type=int, default=1, help="seeds per motion (default %(default)s)")
    real.add_argument("--cameras", type=int, nargs="+", help="indices of the calibration's cameras to use (all 4)")
    real.add_argument("--smooth", action="store_true", help="smooth each run: smoothed vs filtered error and jitter "
                                                            "(the particle and unscented presets)")
    real.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    real.set_defaults(run=_eval_real_format)
    fit_check = evaluate.add_parser("fit-check", help="is a motion in a prior's support? its per-frame log-density "
                                                      "against frames held out from the prior's training data")
    fit_check.add_argument("prior", help="a preset name or .toml, or a prior file (.npz, with --reference)")
    fit_check.add_argument("motion", help="bundled name, .amc or .bvh file")
    fit_check.add_argument("--reference", nargs="+", help="motions of the prior's kind it was not fitted on (default "
                                                          "for a preset: two-fold cross-fits of its training motions)")
    fit_check.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    fit_check.set_defaults(run=_eval_fit_check)
    pace = evaluate.add_parser("pace", help="filters on held-out walks played slower and faster than the training walks")
    pace.add_argument("--presets", nargs="+", default=["pf-diffusion-local", "pf-lie", "pf-lie-defensive", "pf-gpdm"], help="preset names or .toml files (default: %(default)s)")
    pace.add_argument("--motions", nargs="+", default=["walkjog:35_29", "cmu:07_10", "cmu:07_11"], help="bundled names (cmu:07_10, walkjog:35_29), .amc or .bvh files (default: %(default)s)")
    pace.add_argument("--paces", type=float, nargs="+", default=[0.6, 1.0, 1.4], help="playback speeds, 1 = as recorded (default: %(default)s)")
    pace.add_argument("--scenarios", nargs="+", default=["noise", "blackout:sigma_px=5"], help="NAME or NAME:key=value,... (clean, noise, dropout, occlusion, blackout, outliers; default: %(default)s)")
    pace.add_argument("--seeds", type=int, default=2, help="seeds per motion (default %(default)s)")
    pace.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    pace.set_defaults(run=_eval_pace)
    people = evaluate.add_parser("people", help="leave one walking person out: priors refitted without them, their "
                                                "walks tracked on the lab and the real-format benches")
    people.add_argument("--presets", nargs="+", default=["pf-diffusion-local", "pf-gpdm", "pf-lie", "pf-lie-defensive"],
                        help="presets (names or .toml paths); the lab ratios need pf-diffusion-local among them")
    people.add_argument("--people", nargs="+", default=["07", "35", "02", "05", "08+39"],
                        help="the held-out people (08+39: CMU subjects 08 and 39, one person)")
    people.add_argument("--benches", nargs="+", default=["lab", "real4", "real1"],
                        help="lab (synthetic side camera), real4 (OpenPose-style JSON, 4 cameras), real1 (1 camera)")
    people.add_argument("--seeds", type=int, default=2, help="seeds per motion (default %(default)s)")
    people.add_argument("--out", help="the run cache: a rerun does no work, an interrupted one resumes "
                                      "(default: people/ beside the prior cache)")
    people.add_argument("--jobs", type=int, default=1, help="runs in this many worker processes (the same numbers)")
    people.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    people.set_defaults(run=_eval_people)
    scenes = evaluate.add_parser("scenes", help="several people: walks of people the priors never saw composed "
                                                "into scenes, tracked with identities, scored by CLEAR-MOT, IDF1, "
                                                "PCP and MPJPE beside each person tracked alone")
    scenes.add_argument("--scenes", nargs="+", default=["passing", "return", "crossing"],
                        help="passing (two walking towards each other), return (one leaves the view and comes "
                             "back), crossing (three), together (two side by side, shoulder to shoulder)")
    scenes.add_argument("--presets", nargs="+", default=["ukf-real", "pf-lie"],
                        help="presets, each with its prior refitted without the scene's people (default: ukf-real pf-lie)")
    scenes.add_argument("--seeds", type=int, default=3, help="runs of each scene, each with its own detector errors (3)")
    scenes.add_argument("--gaps", nargs="+", type=float, default=[0.3, 1.0],
                        help="passing: the distances the two pass apart, metres (default 0.3 1.0)")
    scenes.add_argument("--association", default="joints", metavar="joints|filter",
                        help="who is who finally decided by the scene tracker's joint model or through every "
                             "person's own filter (track --association; default %(default)s)")
    scenes.add_argument("--json", action="store_true", help="print every run's scores and the table as JSON")
    scenes.set_defaults(run=_eval_scenes)
    against = evaluate.add_parser("against-trc", help="your recording tracked as track --people all would, filtered "
                                                       "and smoothed, with and without --lowpass 6, beside another "
                                                       "tool's TRC of one person (Pose2Sim's): distance, smoothness")
    against.add_argument("--detections", required=True, help="the detections, any layout track reads")
    against.add_argument("--cameras", required=True, help="their calibration")
    against.add_argument("--reference", required=True, help="the other tool's .trc of one person (its rows the "
                                                            "detections' frames from the first, as Pose2Sim writes)")
    against.add_argument("--fps", type=float, help="the detections' frame rate (if their files do not say it)")
    against.add_argument("--keypoints", help="the detections' layout, where it cannot be told")
    against.add_argument("--camera-map", help="FOLDER=CAMERA,… matching detection folders to calibration cameras")
    add_height_options(against)
    against.add_argument("--filter", default="ukf-real", help="the preset (default %(default)s)")
    against.add_argument("--json", action="store_true", help="print the table as JSON")
    against.set_defaults(run=_eval_against_trc)
    shelf = evaluate.add_parser("shelf", help="several real people seen by few cameras, scored against manual 3D truth "
                                              "(Shelf or Campus as 4D Association ships them: you download them) "
                                              "beside per-frame DLT given the true association")
    shelf.add_argument("directory", help="the benchmark's folder: calibration.json, gt.txt and (unless --detections) "
                                         "scene.npz")
    shelf.add_argument("--cameras", help="one subset of the cameras, indices in the calibration's order: 0,2,4 "
                                         "(default: all of them)")
    shelf.add_argument("--subsets", type=int, nargs="+", help="every subset of these sizes: --subsets 2 3")
    shelf.add_argument("--presets", nargs="+", default=["ukf-real"], help="preset names or .toml files (default: "
                                                                          "%(default)s)")
    shelf.add_argument("--detections", help="every person's detections, any layout priortrack reads (default: "
                                            "DIRECTORY/scene.npz)")
    shelf.add_argument("--fps", type=float, default=25.0, help="the recording's frame rate (default %(default)s, as "
                                                               "the field takes Shelf)")
    shelf.add_argument("--actors", type=int, nargs="+",
                       help="the annotated actors scored (default: 0 1 2, the field's, where annotated)")
    shelf.add_argument("--seed", type=int, default=0, help="random seed (default %(default)s)")
    shelf.add_argument("--workers", type=int, help="processes tracking people side by side (default: one per core)")
    shelf.add_argument("--association", default="auto", metavar="auto|joints|filter",
                       help="who is who finally decided (track --association; default %(default)s)")
    shelf.add_argument("--per-joint", action="store_true", help="also a table of each limb joint's error per subset")
    shelf.add_argument("--diagnose", action="store_true",
                       help="no tracking: what per-frame DLT's error is made of on --cameras (bias, autocorrelation, "
                            "what smoothing or the body model could gain, swaps, the tick schedule)")
    shelf.add_argument("--json", action="store_true", help="print every score as JSON instead of tables")
    shelf.set_defaults(run=_eval_shelf)
    smoothing = evaluate.add_parser("smoothing", help="smoothed vs filtered through a blackout on held-out walks")
    smoothing.add_argument("--presets", nargs="+",
                           default=["pf-diffusion-local", "pf-gpdm", "pf-lie", "ukf-diffusion-local", "ukf-gpdm"], help="preset names or .toml files (default: %(default)s)")
    smoothing.add_argument("--motions", nargs="+", default=["walkjog:35_29", "cmu:07_10", "cmu:07_11"], help="bundled names (cmu:07_10, walkjog:35_29), .amc or .bvh files (default: %(default)s)")
    smoothing.add_argument("--seeds", type=int, default=1, help="seeds per motion (default %(default)s)")
    smoothing.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    smoothing.set_defaults(run=_eval_smoothing)
    tracking = evaluate.add_parser("tracking", help="the accuracy table: every preset x scenario over seeds")
    tracking.add_argument("--presets", nargs="+", help="default: the table's nine presets")
    tracking.add_argument("--scenarios", nargs="+", help="default: clean, occlusion and blackout at 5 px")
    tracking.add_argument("--motions", nargs="+", help="held-out motions to track (default: 35_29, 07_10, 07_11)")
    tracking.add_argument("--seeds", type=int, help="seeds per motion (default 5)")
    tracking.add_argument("--jobs", type=int, default=1,
                          help="runs in this many worker processes (the same numbers; the MAP and unscented "
                               "filters run on one thread each, so 2 jobs about halve their rows' time)")
    tracking.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    tracking.set_defaults(run=_eval_tracking)
