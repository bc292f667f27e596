"""``priortrack bench …``: timings against a reference run side by side."""

from __future__ import annotations

import argparse
import json

from priortrack.cli.common import print_json


def _bench_fk(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.fk import bench_fk

    result = bench_fk(batch=args.batch, repeats=args.repeats, threads=args.threads)
    if args.json:
        print(json.dumps(result))
    else:
        print(f"FK at batch {result['batch']} (float32, {result['threads']} threads): priortrack "
              f"{result['priortrack_ms']:.1f} ms, pytorch-kinematics {result['pytorch_kinematics_ms']:.1f} ms "
              f"({result['ratio']:.1f}x); max |difference| in float64 {result['max_abs_err_m']:.1e} m")


def _bench_gpdm_fit(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.gpdm_fit import bench_gpdm_fit

    print_json(bench_gpdm_fit(frames=args.frames, threads=args.threads))


def _bench_lie_sample(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.lie_sample import bench_lie_sample

    print_json(bench_lie_sample(n=args.n, threads=args.threads))


def _bench_scene(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.scene import bench_scene

    print_json(bench_scene(people=args.people, cameras=args.cameras, frames=args.frames, fps=args.fps,
                           preset=args.filter, seed=args.seed, association=args.association))


def _bench_ukf(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.ukf import bench_ukf

    print_json(bench_ukf(repeats=args.repeats, seed=args.seed, threads=args.threads, cameras=args.cameras))


def _bench_pf(args: argparse.Namespace) -> None:
    from priortrack.device import resolve_device
    from priortrack.experiments.benchmarks.pf import bench_pf, bench_priors, check_views

    resolve_device(args.device)                      # a missing GPU is said before the priors are fitted
    check_views(args.cameras, args.proposal)         # and settings that cannot run
    priors = bench_priors(args.seed)                 # fitted once for every particle count
    runs = [bench_pf(particles=p, steps=args.steps, seed=args.seed, threads=args.threads, dtype=args.dtype,
                     translation=args.translation, device=args.device, priors=priors, cameras=args.cameras,
                     proposal=args.proposal) for p in args.particles]
    print_json(runs[0] if len(runs) == 1 else runs)


def _bench_real_track(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.real_track import bench_real_track

    print_json(bench_real_track(frames=args.frames, preset=args.filter, seed=args.seed, cameras=args.cameras,
                                fps=args.fps))


def _bench_smooth(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.smooth import bench_smooth

    print_json(bench_smooth(args.presets, frames=args.frames, trajectories=args.trajectories, seed=args.seed))


def _bench_long(args: argparse.Namespace) -> None:
    from priortrack.experiments.benchmarks.long import bench_long

    print_json(bench_long(frames=args.frames, presets=args.presets, smooth=args.smooth,
                          reference_frames=args.reference_frames, seed=args.seed))


def _json_options(parser: argparse.ArgumentParser, seed: bool = True) -> None:
    """The options every JSON-printing benchmark takes: --seed (where it draws) and --json (accepted;
    the output is JSON anyway)."""
    if seed:
        parser.add_argument("--seed", type=int, default=0,
                            help="random seed (default %(default)s): the same seed, the same numbers")
    parser.add_argument("--json", action="store_true", help="(the output is always JSON)")


def add_parsers(verbs) -> None:
    """Register this family's verbs on the ``priortrack`` sub-parsers."""
    bench = verbs.add_parser("bench", help="benchmarks against a reference").add_subparsers(dest="what", required=True)
    fk = bench.add_parser("fk", help="our FK against pytorch-kinematics")
    fk.add_argument("--batch", type=int, default=10_000, help="poses per call (default %(default)s)")
    fk.add_argument("--repeats", type=int, default=9, help="repetitions of each timing, the median reported (default %(default)s)")
    fk.add_argument("--threads", type=int, default=2, help="torch threads (default %(default)s)")
    fk.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    fk.set_defaults(run=_bench_fk)
    gpdm_fit = bench.add_parser("gpdm-fit", help="time a balanced GPDM fit to convergence")
    gpdm_fit.add_argument("--frames", type=int, default=300, help="training frames the GPDM is fitted on (default %(default)s)")
    gpdm_fit.add_argument("--threads", type=int, default=2, help="torch threads (default %(default)s)")
    _json_options(gpdm_fit, seed=False)
    gpdm_fit.set_defaults(run=_bench_gpdm_fit)
    lie_sample = bench.add_parser("lie-sample", help="Lie prior conditional samples per second vs scikit-learn")
    lie_sample.add_argument("--n", type=int, default=200_000, help="samples per timing")
    lie_sample.add_argument("--threads", type=int, default=2, help="torch threads (default %(default)s)")
    _json_options(lie_sample, seed=False)
    lie_sample.set_defaults(run=_bench_lie_sample)

    ukf = bench.add_parser("ukf", help="one UKF step, batched sigma points vs filterpy's per-point loop")
    ukf.add_argument("--repeats", type=int, default=9, help="repetitions of each timing, the median reported (default %(default)s)")
    ukf.add_argument("--threads", type=int, default=1, help="torch threads around the steps (default %(default)s; "
                                                            "each step itself runs on one, ukf.STEP_THREADS)")
    ukf.add_argument("--cameras", type=int, default=1, help="1: one side camera; 2 to 8: distorted cameras on a "
                                                            "ring, ukf-real's multi-view step with its gate (default %(default)s)")
    _json_options(ukf)
    ukf.set_defaults(run=_bench_ukf)
    pf = bench.add_parser("pf", help="particle-steps per second of the particle filter with each prior")
    pf.add_argument("--particles", type=int, nargs="+", default=[10_000],
                    help="particles (default %(default)s); several: one run each, the priors fitted once")
    pf.add_argument("--device", default="cpu", help="cpu (default), cuda or cuda:N: where the particles live")
    pf.add_argument("--steps", type=int, default=20, help="timed steps per prior")
    pf.add_argument("--cameras", type=int, default=1, help="1: one side camera (default); 2 to 8: distorted cameras "
                    "on a ring, the multi-view likelihood (σ = 5 px)")
    pf.add_argument("--proposal", choices=("prior", "guided"), default="prior",
                    help="the particles' draw: the prior's (default) or guided by the detections (2 cameras or more; "
                         "fully adapted, the GPDM with its pose state, as the presets run)")
    pf.add_argument("--threads", type=int, default=2, help="torch threads (default %(default)s)")
    pf.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                    help="the particles' dtype (the particle-filter presets run float32)")
    pf.add_argument("--translation", choices=("marginalised", "sampled"), default="marginalised",
                    help="the body's translation integrated out per particle (as the presets run) or sampled")
    _json_options(pf)
    pf.set_defaults(run=_bench_pf)

    scene = bench.add_parser("scene", help="the whole track --detections --people all command on several people, "
                                           "beside the single-person command on one")
    scene.add_argument("--people", type=int, default=4, help="people in the scene, 1 to 9 (default %(default)s)")
    scene.add_argument("--cameras", type=int, default=5, help="ring cameras, 3 to 12 (default %(default)s)")
    scene.add_argument("--frames", type=int, default=300, help="frames, 10 to 1800 (default %(default)s)")
    scene.add_argument("--fps", type=float, default=30.0, help="the input's frame rate (default %(default)s)")
    scene.add_argument("--filter", default="ukf-real", help="the preset (default %(default)s)")
    scene.add_argument("--association", default="joints", metavar="joints|filter",
                       help="who is who finally decided (track --association; default %(default)s)")
    _json_options(scene)
    scene.set_defaults(run=_bench_scene)
    real_track = bench.add_parser("real-track", help="the whole track --detections command on real-format input "
                                                     "(4 cameras), beside DLT of the same input")
    real_track.add_argument("--frames", type=int, default=100, help="frames of the synthetic input, 3 to 1800 (default %(default)s)")
    real_track.add_argument("--cameras", type=int, default=4, help="4: the Pose2Sim demo's; else 2 to 12 distorted "
                                                                   "cameras on a ring (default %(default)s)")
    real_track.add_argument("--fps", type=float, default=30.0, help="the input's frame rate (default %(default)s)")
    real_track.add_argument("--filter", default="pf-lie", help="the preset (its particles: 1000 for pf-lie)")
    _json_options(real_track)
    real_track.set_defaults(run=_bench_real_track)
    smooth = bench.add_parser("smooth", help="the smoother's time against the forward pass it smooths")
    smooth.add_argument("--presets", nargs="+", default=["pf-diffusion-local", "pf-gpdm", "pf-lie", "ukf-gpdm"], help="preset names or .toml files (default: %(default)s)")
    smooth.add_argument("--frames", type=int, default=100, help="frames tracked, then smoothed (default %(default)s)")
    smooth.add_argument("--trajectories", type=int, default=100, help="smoothed trajectories drawn (default %(default)s)")
    _json_options(smooth)
    smooth.set_defaults(run=_bench_smooth)
    long = bench.add_parser("long", help="a long 4-camera recording tracked: peak memory beside a run a tenth as "
                                         "long, and time per tick over the first and last tenth")
    long.add_argument("--frames", type=int, default=36_000, help="frames at 60 fps (default %(default)s: 10 minutes)")
    long.add_argument("--reference-frames", type=int, help="the reference run's frames (default a tenth, at least 300)")
    long.add_argument("--presets", nargs="+", default=["ukf-real", "pf-lie"], help="preset names (default: %(default)s)")
    long.add_argument("--smooth", action="store_true", help="smooth each run over the whole run too")
    _json_options(long)
    long.set_defaults(run=_bench_long)
