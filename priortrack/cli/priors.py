"""``priortrack fit``, ``sample`` and ``plot``: a prior fitted to motions, rolled out, its latent space (or a tracked
result) drawn."""

from __future__ import annotations

import argparse

from priortrack.cli.common import Progress, load_motions
from priortrack.errors import PriortrackError
from priortrack.output import output_path


def _fit(args: argparse.Namespace) -> None:
    from priortrack.priors.registry import PRIOR_KINDS, fit_prior

    output_path(args.out, "prior file")
    motions = load_motions(args.train)
    flags = {"space": args.space, "d": args.d, "dynamics_noise_floor": args.dynamics_noise_floor,
             "max_components": args.components, "seed": args.seed}
    schema = PRIOR_KINDS[args.kind].options()          # each kind takes the flags its fit has
    options = {"fps": args.fps, **{k: v for k, v in flags.items() if k in schema and v is not None}}
    progress = Progress(f"fit {args.kind}")
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
    from priortrack.priors import load_prior
    from priortrack.priors.registry import PRIOR_KINDS
    from priortrack.viz.latent_plot import plot_latent
    from priortrack.viz.result_plot import is_result, plot_result

    if is_result(args.prior):
        plot_result(args.prior, args.out)
        print(f"wrote {args.out}")
        return
    try:
        prior = load_prior(args.prior)
    except PriortrackError as exc:
        raise PriortrackError(f"{args.prior}: neither a result of track --detections nor a prior file ({exc})") from None
    if "latent" not in PRIOR_KINDS[prior.kind].capabilities:
        raise PriortrackError(f"{args.prior} is a {prior.kind} prior; 'plot' draws the latent space of a gpdm or bgpdm")
    plot_latent(prior, args.out)
    print(f"wrote {args.out}")


def add_parsers(verbs) -> None:
    """Register this family's verbs on the ``priortrack`` sub-parsers."""
    from priortrack.priors.registry import PRIOR_KINDS

    fit = verbs.add_parser("fit", help="fit a prior to motions")
    fit.add_argument("kind", choices=list(PRIOR_KINDS), help=f"the prior: {', '.join(PRIOR_KINDS)}")
    fit.add_argument("--train", nargs="+", required=True,
                     help="bundled names (patterns allowed: 'walkjog:35_0*'), .amc or .bvh files")
    fit.add_argument("--out", required=True, help="the prior file to write (.npz)")
    fit.add_argument("--fps", type=float, default=30.0, help="the prior's frame rate (default 30)")
    fit.add_argument("--space", choices=["angles", "directions"], default="angles", help="diffusion state space")
    fit.add_argument("--d", type=int, default=3, help="GPDM latent dimension")
    fit.add_argument("--dynamics-noise-floor", type=float,
                     help="GPDM: lower bound on the dynamics noise variance 1/alpha4 (default 1e-4)")
    fit.add_argument("--components", type=int, default=30, help="Lie prior: initial mixture components")
    fit.add_argument("--seed", type=int, default=0, help="random seed (default %(default)s): the same seed, the same numbers")
    fit.set_defaults(run=_fit)

    sample = verbs.add_parser("sample", help="roll a prior out from a real pose into a rerun recording")
    sample.add_argument("prior", help="a prior file written by 'priortrack fit'")
    sample.add_argument("--from", dest="source", required=True, help="the motion to start from")
    sample.add_argument("--frame", type=int, default=0, help="start frame, at the prior's frame rate")
    sample.add_argument("--steps", type=int, default=30, help="steps per rollout (default %(default)s)")
    sample.add_argument("--n", type=int, default=10, help="number of rollouts")
    sample.add_argument("--seed", type=int, default=0, help="random seed (default %(default)s): the same seed, the same numbers")
    sample.add_argument("--out", required=True, help="the .rrd file to write")
    sample.set_defaults(run=_sample)

    plot = verbs.add_parser("plot", help="a tracked result over time (where each person went, each camera's "
                                         "reprojection error, how sure, flagged ticks), or a GPDM's latent space")
    plot.add_argument("prior", metavar="FILE", help="a result .npz of track --detections (one person or a scene), or "
                                                    "a gpdm or bgpdm prior file (its latent trajectories over its log "
                                                    "reconstruction variance)")
    plot.add_argument("--out", required=True, help="the image to write (.png)")
    plot.set_defaults(run=_plot)
