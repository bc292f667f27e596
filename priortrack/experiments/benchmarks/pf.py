"""Benchmark: particle-filter throughput, particle-steps per second, for each pose prior.

A particle-step is one particle carried through everything a real filter step does
(:meth:`priortrack.filters.particle.ParticleFilter.step`): the transition (pose prior and
global motion), forward kinematics / decoding to joints, projection, the 2D likelihood (with
the translation integrated out by each particle's Kalman update, as the presets run; or sampled),
the weight normalisation and estimate, and resampling when the ESS falls below P/2. For P
particles and a median step time t, the throughput is P / t.

Setup, per prior: the prior is fitted on the subject-35 training walks of the bundled walk/jog
set (the GPDM on their first ``gpdm_frames`` frames, :func:`priortrack.experiments.benchmarks.gpdm_fit.bench_walks`,
so that its fit stays short), global motion by :meth:`GlobalMotion.fit` on the same walks, the
likelihood a :class:`JointLikelihood` through :func:`priortrack.observation.default_camera`;
observations are the ``noise`` scenario of the first test walk (the paper's eight joints). With ``cameras``
C > 1 instead: C distorted cameras on a ring (:func:`~priortrack.experiments.benchmarks.ukf.ring_observations`,
every joint with 5 px noise) under the multi-view Gaussian likelihood (σ = 5 px), the real-data setting, where
``proposal="guided"`` (the presets' draw, :mod:`priortrack.filters.proposal`) looks at the detections, fully adapted
(``auxiliary``) and with the GPDM's pose in its state (:mod:`priortrack.priors.gpdm_pose`), as the presets run. The
filters of all priors start on that walk's first two frames and step through its frames in
lockstep (diffusion, gpdm, lie, diffusion, …), so that machine noise hits every prior alike;
fitting and the warm-up steps are not timed.

Beside every step, in the same loop, the forward kinematics alone of P poses of the walk's own
skeleton (:class:`~priortrack.body.fk.ForwardKinematics`, the particles' dtype and device: the
kinematics a joint-angle particle's decoding needs): ``step_over_fk`` is a step's median time over
the FK's, and ``fk_share`` its inverse, the fraction of a step the kinematics of its particles
would take. On a GPU (``device="cuda"``) every timing waits for the device's queued work.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch

from priortrack.data.bundled import load_walkjog
from priortrack.errors import PriortrackError
from priortrack.device import resolve_device, synchronize
from priortrack.experiments.benchmarks.timing import load_average
from priortrack.experiments.benchmarks.gpdm_fit import bench_walks
from priortrack.experiments.benchmarks.ukf import ring_observations
from priortrack.filters.particle import DTYPES, PROPOSALS, ParticleFilter
from priortrack.models.tracking import TrackingModel
from priortrack.observation import default_camera, synthesize
from priortrack.observation.likelihood import JointLikelihood
from priortrack.observation.multiview import MultiViewLikelihood
from priortrack.priors.base import TransitionModel
from priortrack.priors.diffusion import Diffusion
from priortrack.priors.gpdm import GPDM
from priortrack.priors.gpdm_pose import PoseStateGPDM
from priortrack.priors.lie import LiePrior
from priortrack.threads import torch_threads
from priortrack.body.fk import ForwardKinematics, joint_positions

logger = logging.getLogger(__name__)

#: The priors timed, in the order their filters are stepped.
PRIORS = ("diffusion", "gpdm", "lie")
#: The phases of :attr:`priortrack.filters.snapshot.Snapshot.timings`.
PHASES = ("predict", "weight", "estimate", "resample")


def bench_priors(seed: int = 0, gpdm_frames: int = 100) -> dict[str, TransitionModel]:
    """The three priors of the benchmark, fitted on the bundled subject-35 training walks:
    local Gaussian diffusion in angle space, a balanced GPDM (d = 3) on the first
    ``gpdm_frames`` frames of those walks, and the Lie-algebra mixture."""
    train = list(load_walkjog().walks("train"))
    return {"diffusion": Diffusion.fit(train, local=True, space="angles"),
            "gpdm": GPDM.fit(bench_walks(gpdm_frames), balanced=True, d=3, seed=seed),
            "lie": LiePrior.fit(train, seed=seed)}


def check_views(cameras: int, proposal: str) -> None:
    """A PriortrackError unless ``cameras`` is in [1, 8] and ``proposal`` one of PROPOSALS, "guided" with 2 or more."""
    if proposal not in PROPOSALS or not 1 <= cameras <= 8 or (proposal == "guided" and cameras < 2):
        raise PriortrackError(f"bench pf: proposal must be one of {', '.join(PROPOSALS)} and cameras in [1, 8], the "
                              f"guided proposal with 2 or more (got {proposal!r} with {cameras})")


def bench_pf(particles: int = 10_000, steps: int = 20, seed: int = 0, threads: int = 2, warmup: int = 2,
             gpdm_frames: int = 100, dtype: str = "float32", translation: str = "marginalised",
             priors: dict[str, TransitionModel] | None = None, device: str = "cpu", cameras: int = 1,
             proposal: str = "prior") -> dict:
    """Time ``steps`` particle-filter steps with ``particles`` particles for every prior.

    Args:
        particles: P.
        steps: timed steps per prior (after ``warmup`` untimed ones); the test walk has 125
            frames, so warmup + steps ≤ 123.
        seed: seeds the fits, the observation noise and the filters.
        threads: torch intra-op threads during the timed steps.
        gpdm_frames: training frames of the GPDM (its step cost grows with them).
        dtype: the particles' dtype (``ParticleFilter(dtype=...)``): "float32", as the
            particle-filter presets run, or "float64".
        translation: ``ParticleFilter(translation=...)``: "marginalised", as the particle-filter
            presets run (a Kalman filter per particle), or "sampled".
        priors: name → fitted prior, instead of :func:`bench_priors` (tests pass small ones).
        device: where the particles live ("cpu", "cuda"; ``ParticleFilter(device=...)``).
        cameras: 1, the default side camera; 2 to 8, a ring of distorted cameras (module docstring).
        proposal: ``ParticleFilter(proposal=...)``: "prior" (the bootstrap draw) or "guided" (two cameras or more).

    Returns:
        ``{"particles", "particle_steps_per_s": {prior: P / median step}, "ms_per_step":
        {prior: median ms}, "ms_per_step_range": {prior: [min, max] ms}, "cpu_ms_per_step":
        {prior: median process CPU ms, all threads}, "phases_ms": {prior: {phase: median ms}},
        "resamples": {prior: count over the timed steps}, "steps", "threads", "load_average":
        [1-minute load before, after] (None where the system has none), "dtype", "translation", "device", "cameras",
        "proposal",
        "fk_ms": median ms of the FK alone, "step_over_fk": {prior: ms_per_step / fk_ms}, "fk_share":
        {prior: fk_ms / ms_per_step}}``; the phases are those of
        ``Snapshot.timings`` (predict, weight = joints + projection + likelihood +
        normalisation, estimate, resample).
        On a machine busy with other work the wall time exceeds the CPU time (waiting for a
        core, and intra-op threads waiting on each other): compare the two and the load.
    """
    if particles < 1 or steps < 1 or threads < 1 or warmup < 0:
        raise PriortrackError(f"bench pf: particles, steps and threads must be positive and warmup ≥ 0 "
                              f"(got {particles}, {steps}, {threads}, {warmup})")
    if dtype not in DTYPES:
        raise PriortrackError(f"bench pf: dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
    check_views(cameras, proposal)
    device = resolve_device(device)
    walk = load_walkjog().walks("test")[0]
    if warmup + steps > len(walk) - 2:
        raise PriortrackError(f"bench pf: warmup + steps = {warmup + steps} exceeds the {len(walk) - 2} "
                              f"frames of the test walk {walk.name!r} after its two known frames")
    priors = bench_priors(seed, gpdm_frames) if priors is None else priors
    unknown = set(priors) - set(PRIORS)
    if unknown or not priors:
        raise PriortrackError(f"bench pf: prior names {sorted(priors)}; expected some of {', '.join(PRIORS)}")
    if any(prior.fps != walk.fps for prior in priors.values()):
        raise PriortrackError(f"bench pf: every prior must run at the test walk's {walk.fps:g} fps, got "
                              f"{ {name: prior.fps for name, prior in priors.items()} }")
    train = list(load_walkjog().walks("train"))
    X = joint_positions(walk, "eval15")
    if cameras == 1:
        observations = synthesize(X, walk.fps, default_camera(X), "noise", seed=seed)
        likelihood, z = JointLikelihood(observations.camera), observations.uv
    else:
        views, z = ring_observations(X, cameras, seed)
        likelihood = MultiViewLikelihood(views, sigma_px=5.0, robust_nu=None)
    filters = {}
    guided = proposal == "guided"
    for name, prior in priors.items():
        prior = PoseStateGPDM(prior) if guided and isinstance(prior, GPDM) else prior
        model = TrackingModel.fitted(prior, train, likelihood)
        filters[name] = ParticleFilter(model, particles, dtype=dtype, translation=translation, seed=seed,
                                       device=device, threads=threads, proposal=proposal, auxiliary=guided)
        filters[name].initialise(walk)
    fk = ForwardKinematics(walk.skeleton, device=device, dtype=DTYPES[dtype])
    poses = torch.as_tensor(walk.channels[np.random.default_rng(seed).integers(0, len(walk), particles)],
                            dtype=DTYPES[dtype], device=device)

    times = {name: [] for name in filters}
    fk_times = []
    cpu = {name: [] for name in filters}
    phases = {name: {phase: [] for phase in PHASES} for name in filters}
    resamples = dict.fromkeys(filters, 0)
    before = load_average()
    with torch_threads(threads):
        for t in range(2, 2 + warmup + steps):
            start = time.perf_counter()
            fk(poses)
            synchronize(device)
            if t >= 2 + warmup:
                fk_times.append(time.perf_counter() - start)
            for name, pf in filters.items():
                start, start_cpu = time.perf_counter(), time.process_time()
                snap = pf.step(z[t])
                synchronize(device)
                seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - start_cpu
                if t < 2 + warmup:
                    continue
                times[name].append(seconds)
                cpu[name].append(cpu_seconds)
                for phase in PHASES:
                    phases[name][phase].append(snap.timings[phase])
                resamples[name] += snap.ancestors is not None
    ms = {name: 1000.0 * float(np.median(t)) for name, t in times.items()}
    fk_ms = 1000.0 * float(np.median(fk_times))
    result = {
        "particles": particles,
        "particle_steps_per_s": {name: particles / (ms[name] / 1000.0) for name in filters},
        "ms_per_step": ms,
        "ms_per_step_range": {name: [1000.0 * min(t), 1000.0 * max(t)] for name, t in times.items()},
        "cpu_ms_per_step": {name: 1000.0 * float(np.median(t)) for name, t in cpu.items()},
        "phases_ms": {name: {phase: 1000.0 * float(np.median(v)) for phase, v in p.items()}
                      for name, p in phases.items()},
        "resamples": resamples,
        "steps": steps,
        "threads": threads,
        "load_average": None if before is None else [before[0], load_average()[0]],
        "dtype": str(next(iter(filters.values())).states.dtype).removeprefix("torch."),
        "translation": translation,
        "device": str(device),
        "cameras": cameras,
        "proposal": proposal,
        "fk_ms": fk_ms,
        "step_over_fk": {name: ms[name] / fk_ms for name in filters},
        "fk_share": {name: fk_ms / ms[name] for name in filters},
    }
    for name in filters:
        logger.info("bench pf %s: %.0f particle-steps/s (%.1f ms per step of %d particles on %s, %.1f× the FK alone; "
                    "%s)", name, result["particle_steps_per_s"][name], ms[name], particles, device,
                    result["step_over_fk"][name],
                    ", ".join(f"{k} {v:.1f} ms" for k, v in result["phases_ms"][name].items()))
    return result
