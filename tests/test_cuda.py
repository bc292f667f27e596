"""The particle filters on a CUDA GPU (``device="cuda"``), against the same code on the CPU.

The tests marked ``needs_cuda`` are skipped, with that reason in pytest's summary (``-ra``), on a
machine without a CUDA GPU, as CI's is; they were run on an NVIDIA H100 by the session that wrote
them (docs/results/2026-11-25-gpu.md). The refusals run everywhere.
"""

import numpy as np
import pytest
import torch

from priortrack import PriortrackError, load_walkjog
from priortrack.body.fk import joint_positions
from priortrack.cli.main import main
from priortrack.data.bundled import POSE2SIM_DIR
from priortrack.data.calibration import read_calibration
from priortrack.data.detections import read_detections
from priortrack.device import resolve_device
from priortrack.experiments.benchmarks.pf import bench_pf
from priortrack.experiments.benchmarks.ukf import ring_observations
from priortrack.experiments.metrics import mpjpe
from priortrack.tracking.presets import load_preset
from priortrack.tracking.person import TrackConfig, track_detections
from priortrack.experiments.tracking import track
from priortrack.filters.annealed import AnnealedParticleFilter
from priortrack.filters.marginal_translation import kalman_update
from priortrack.filters.particle import ParticleFilter
from priortrack.filters.proposal import GuidedProposal
from priortrack.models.tracking import TrackingModel
from priortrack.observation import default_camera, synthesize
from priortrack.observation.likelihood import JointLikelihood
from priortrack.observation.multiview import MultiViewLikelihood
from priortrack.priors import Diffusion
from priortrack.priors.defensive import DefensiveMixture
from priortrack.priors.gpdm import GPDM
from priortrack.priors.gpdm_pose import PoseStateGPDM
from priortrack.priors.lie import LiePrior
from priortrack.threads import torch_threads

CUDA = torch.cuda.is_available()
needs_cuda = pytest.mark.skipif(not CUDA, reason="needs a CUDA GPU; this machine has none")


@pytest.fixture(scope="module")
def priors():
    walks = list(load_walkjog().walks("train"))
    with torch_threads(1):
        lie = LiePrior.fit(walks[:3], seed=0, max_components=2)
        gpdm = GPDM.fit([m[:15] for m in walks[:2]], seed=0)
        return {"diffusion": Diffusion.fit(walks[:2], local=True),
                "gpdm": gpdm,
                "gpdm-pose": PoseStateGPDM(gpdm.annealed(0.003)),
                "lie": lie,
                "defensive": DefensiveMixture(lie, Diffusion.fit(walks[:2], local=True, space="directions"), 0.1)}


@pytest.fixture(scope="module")
def walk():
    return load_walkjog().walks("test")[0][:40]


def _model(prior, walk, robust_nu=None):
    X = joint_positions(walk, "eval15")
    observations = synthesize(X, walk.fps, default_camera(X), "noise", seed=0)
    model = TrackingModel.fitted(prior, list(load_walkjog().walks("train"))[:2],
                                 JointLikelihood(observations.camera, robust_nu=robust_nu))
    return model, observations


@needs_cuda
@pytest.mark.parametrize("name", ["diffusion", "gpdm", "lie", "defensive"])
def test_a_steps_deterministic_parts_give_the_cpus_numbers(priors, walk, name):
    """On the same float64 particles: decoding to world joints, the likelihood (Gaussian and
    Student-t), the translation's Kalman update and its predictive likelihood, the prior's transition
    density and the weighted mean state agree with the CPU's to 1e-9 (relative)."""
    model, observations = _model(priors[name], walk)
    robust, _ = _model(priors[name], walk, robust_nu=4.0)
    s = model.initial_states(walk, 2000, torch.Generator().manual_seed(0))
    s_next = model.predict(s, torch.Generator().manual_seed(1))
    gpu, gpu_next = s.cuda(), s_next.cuda()
    z = torch.as_tensor(observations.uv[5])
    w = torch.softmax(torch.randn(len(s), generator=torch.Generator().manual_seed(2), dtype=torch.float64), 0)

    def close(cpu, cuda):
        assert cuda.device.type == "cuda"
        np.testing.assert_allclose(cuda.cpu().numpy(), cpu.numpy(), rtol=1e-9, atol=1e-9)

    joints = model.observe(s)
    close(joints, model.observe(gpu))
    close(model.log_likelihood(joints, z), model.log_likelihood(joints.cuda(), z.cuda()))
    close(robust.log_likelihood(joints, z), robust.log_likelihood(joints.cuda(), z.cuda()))
    C = 0.01 * torch.eye(6, dtype=torch.float64).repeat(len(s), 1, 1)
    motion = model.global_motion
    for cpu, cuda in zip(kalman_update(joints, C, motion.sigma[:3], motion.velocity, z, model.likelihood),
                         kalman_update(joints.cuda(), C.cuda(), motion.sigma[:3], motion.velocity, z.cuda(),
                                       model.likelihood)):
        close(cpu, cuda)
    close(model.log_transition(s_next, s), model.log_transition(gpu_next, gpu))
    close(model.mean(s, w), model.mean(gpu, w.cuda()))


@needs_cuda
@pytest.mark.parametrize("name", ["diffusion", "gpdm", "lie", "defensive"])
def test_a_prior_draws_on_the_gpu_with_the_cpus_spread(priors, walk, name):
    """The transition drawn on the GPU (its own generator) has the CPU's one-step spread: the RMS
    tangent step per joint group of 20,000 draws within 4 % (the sampling error is about 1 %)."""
    prior = priors[name]
    x = prior.encode(walk)[10:11].expand(20_000, -1).contiguous()
    space = prior.space

    def rms(device):
        x_d = x.to(device)
        drawn = prior.sample(x_d, torch.Generator(device=device).manual_seed(3))
        assert drawn.device.type == torch.device(device).type and torch.isfinite(drawn).all()
        return space.group_norms_sq(space.boxminus(drawn, x_d)).mean(0).sqrt().cpu()

    cpu, cuda = rms("cpu"), rms("cuda")
    moving = cpu > 1e-6
    np.testing.assert_allclose(cuda[moving].numpy(), cpu[moving].numpy(), rtol=0.04)


@needs_cuda
@pytest.mark.parametrize("translation", ["sampled", "marginalised"])
@pytest.mark.parametrize("name", ["diffusion", "gpdm", "lie"])
def test_a_particle_filter_tracks_on_the_gpu_as_on_the_cpu(priors, walk, name, translation):
    """Whole runs of 38 frames with 2,000 float32 particles, seeds 0–2: on the GPU every estimate is
    finite and the mean MPJPE within 25 % (+ 5 mm) of the CPU runs' (different random draws, the same
    filter; one seed's runs differed by a third, 99 against 134 mm)."""
    model, observations = _model(priors[name], walk)

    def filter_on(device, seed):
        return ParticleFilter(model, 2000, dtype="float32", translation=translation, seed=seed, device=device)

    _tracks_as_on_the_cpu(filter_on, observations.uv, walk, seeds=3)


def _tracks_as_on_the_cpu(filter_on, z, walk, seeds):
    """Runs of ``filter_on(device, seed)`` over z for seeds 0…seeds−1 on the CPU and the GPU: every estimate finite,
    the particles on their device, and the GPU's mean MPJPE within 25 % (+ 5 mm) of the CPU's."""
    truth = joint_positions(walk, "eval15")
    errors = {}
    for device in ("cpu", "cuda"):
        runs = []
        for seed in range(seeds):
            pf = filter_on(device, seed)
            run = pf.run(z, walk)
            assert np.isfinite(run.estimates).all() and pf.states.device.type == device
            runs.append(mpjpe(run.estimates[2:], truth[2:]).mean())
        errors[device] = float(np.mean(runs))
    assert errors["cuda"] <= 1.25 * errors["cpu"] + 5.0, errors


def _ring_model(prior, walk):
    X = joint_positions(walk, "eval15")
    views, z = ring_observations(X, 4, seed=0)
    model = TrackingModel.fitted(prior, list(load_walkjog().walks("train"))[:2],
                                 MultiViewLikelihood(views, sigma_px=5.0, robust_nu=None))
    return model, z


@needs_cuda
@pytest.mark.parametrize("name", ["diffusion", "gpdm", "lie", "defensive"])
def test_the_guided_proposals_linearisation_gives_the_cpus_numbers(priors, walk, name):
    """Four ring cameras, the same float64 parents: the guided proposal's mean steps, each particle's kept
    components (ln π, the means' offsets) and every component's covariance at m̄ agree with the CPU's to 1e-9,
    the pixels' shared Jacobian to 1e-6 (central differences of step 1e-5 divide the pixels' rounding, 1e-13
    of 10³ px, by 2e-5; measured on an H100: 6e-9). The draw itself takes the device's random numbers."""
    model, z = _ring_model(priors[name], walk)
    proposal = GuidedProposal(model, marginal=True)
    parents = model.initial_states(walk, 500, torch.Generator().manual_seed(0))
    weights = torch.softmax(torch.randn(500, generator=torch.Generator().manual_seed(1), dtype=torch.float64), 0)
    seen = torch.isfinite(proposal.form.measurement(z[5])[0])

    def parts(device):
        x, w = parents.to(device), weights.to(device)
        m = proposal.form.mean_step(x)
        m_bar = model.mean(m, w)
        log_pi, offsets, index, Q, moment = proposal._components(x, m, m_bar)
        H = proposal._jacobian(m_bar, proposal.drawn.to(device), seen.to(device))
        assert H.device.type == torch.device(device).type
        return [t.cpu() for t in (m, m_bar, log_pi, offsets, index, Q, moment, H)]

    for cpu, cuda, tolerance in zip(parts("cpu"), parts("cuda"), [1e-9] * 7 + [1e-6]):
        np.testing.assert_allclose(cuda.numpy(), cpu.numpy(), rtol=tolerance, atol=tolerance)


@needs_cuda
@pytest.mark.parametrize("name", ["diffusion", "lie", "defensive", "gpdm-pose"])
def test_a_guided_particle_filter_tracks_on_the_gpu_as_on_the_cpu(priors, walk, name):
    """Four ring cameras (5 px), the guided draw as the presets run it (translation marginalised, fully adapted; the
    GPDM with its pose state), 1,000 float32 particles, seeds 0–1: on the GPU every estimate is finite, some ratio p / q of the draw moved off zero (the
    guided branch ran), and the mean MPJPE is within 25 % (+ 5 mm) of the CPU runs'."""
    model, z = _ring_model(priors[name], walk)
    ratios = {}                                             # (device, seed) → that run's draws' log p / q

    def filter_on(device, seed):
        pf = ParticleFilter(model, 1000, dtype="float32", translation="marginalised", proposal="guided", seed=seed,
                            device=device, auxiliary=True)
        draw, ratios[device, seed] = pf.proposal.draw, []

        def spy(*args, **kwargs):
            states, log_ratio = draw(*args, **kwargs)
            ratios[device, seed].append(log_ratio)
            return states, log_ratio

        pf.proposal.draw = spy
        return pf

    _tracks_as_on_the_cpu(filter_on, z, walk, seeds=2)
    assert len(ratios) == 4
    for (device, _), drawn in ratios.items():
        assert all(r.device.type == device for r in drawn) and any(bool(r.abs().gt(0).any()) for r in drawn)


@needs_cuda
def test_the_annealed_filter_and_the_smoother_run_on_the_gpu(priors, walk):
    model, observations = _model(priors["diffusion"], walk)
    truth = joint_positions(walk, "eval15")
    apf = AnnealedParticleFilter(model, 500, layers=3, seed=0, device="cuda")
    assert mpjpe(apf.run(observations.uv, walk).estimates[2:], truth[2:]).mean() < 150
    result = track("walkjog:35_29", "pf-diffusion-local", "noise", frames=30, smooth=True, device="cuda").result
    assert np.isfinite(result["mpjpe_mm"]) and result["mpjpe_mm"] < 1.5 * result["filtered_mpjpe_mm"] + 10


@needs_cuda
def test_real_detections_track_on_the_gpu():
    """The bundled 4-camera OpenPose trial with pf-diffusion-local (a Student-t multi-view likelihood):
    the GPU run's median reprojection error within 25 % (+ 1 px) of the CPU's."""
    detections = read_detections(str(POSE2SIM_DIR / "pose"), keypoints="body25b")
    calibration = read_calibration(str(POSE2SIM_DIR / "Calib.toml"))
    runs = {device: track_detections(detections, calibration, "pf-diffusion-local", TrackConfig(fps=60, device=device))
            for device in ("cpu", "cuda")}
    medians = {device: np.median(list(run.summary()["reprojection_px"].values())) for device, run in runs.items()}
    assert medians["cuda"] <= 1.25 * medians["cpu"] + 1.0, medians
    # the whole-run smoother on the GPU, its steps in memory and spilled to disk (read back onto the GPU)
    held, spilled = (track_detections(detections, calibration, "pf-diffusion-local",
                                      TrackConfig(fps=60, smooth=True, memory=memory,
                                                  device="cuda")) for memory in (1 << 30, 0))
    assert np.isfinite(held.joints).all()
    np.testing.assert_allclose(spilled.joints, held.joints, rtol=0, atol=1e-5)


@needs_cuda
def test_a_scene_of_two_people_tracks_on_the_gpu_with_either_association():
    """Pose2Sim's multi-person demo (60 frames) with pf-diffusion-local on the GPU: each person's run in a worker
    process (the joint model's association) and every person's filter stepped together here (the filters'
    association): both people tracked, every tracked joint finite, each person's median reprojection within 25 %
    (+ 1 px) of the CPU's."""
    from pathlib import Path

    from priortrack.data.scene_detections import read_scene_detections
    from priortrack.tracking.people import track_scene
    from priortrack.tracking.scene import SceneConfig

    folder = Path(__file__).parent / "data" / "pose2sim_multiperson"
    scene = read_scene_detections(folder / "pose", keypoints="body25b").head(60)
    calibration = read_calibration(folder / "calibration" / "Calib.qca.txt")

    def medians(result):
        return [np.median(list(person.summary()["reprojection_px"].values())) for person in result.people]

    for association in ("joints", "filter"):
        runs = {device: track_scene(scene, calibration, "pf-diffusion-local", TrackConfig(fps=60, device=device),
                                    SceneConfig(association=association), workers=2) for device in ("cpu", "cuda")}
        assert runs["cuda"].person_ids.tolist() == [0, 1]
        assert np.isfinite(runs["cuda"].joints[np.isfinite(runs["cuda"].joints[..., 0, 0])]).all()
        for cpu, cuda in zip(medians(runs["cpu"]), medians(runs["cuda"])):
            assert cuda <= 1.25 * cpu + 1.0, (association, cpu, cuda)


@needs_cuda
def test_bench_pf_times_the_gpu(priors):
    result = bench_pf(particles=100_000, steps=3, warmup=1, priors={k: priors[k] for k in ("diffusion", "gpdm", "lie")},
                      device="cuda")
    assert result["device"] == "cuda" and result["fk_ms"] > 0
    assert all(v > 0 for v in result["particle_steps_per_s"].values())
    guided = bench_pf(particles=100_000, steps=3, warmup=1, priors={"lie": priors["lie"]}, device="cuda", cameras=4,
                      proposal="guided")
    assert guided["proposal"] == "guided" and guided["particle_steps_per_s"]["lie"] > 0


@needs_cuda
def test_filters_without_a_gpu_path_refuse_it():
    with pytest.raises(PriortrackError, match="CPU only"):
        load_preset("ukf-real").filter_for(None, device="cuda")


@pytest.mark.skipif(CUDA, reason="checks the refusal on a machine without a CUDA GPU")
def test_no_gpu_is_one_clear_error(capsys):
    with pytest.raises(PriortrackError, match="no CUDA GPU"):
        resolve_device("cuda")
    assert main(["track", "walkjog:35_29", "--filter", "pf-diffusion-local", "--device", "cuda", "--frames", "5"]) == 2
    assert "no CUDA GPU" in capsys.readouterr().err
    assert main(["bench", "pf", "--device", "cuda"]) == 2                 # said before any prior is fitted
    assert "no CUDA GPU" in capsys.readouterr().err


def test_an_unknown_device_is_named():
    for name in ("tpu", "gpu", "", "cuda:x"):
        with pytest.raises(PriortrackError, match="not one of cpu, cuda"):
            resolve_device(name)
    with pytest.raises(PriortrackError, match="not one of cpu, cuda"):
        ParticleFilter(None, 10, device="tpu")


@needs_cuda
def test_the_particle_filters_prediction_of_its_detections_on_the_gpu_is_the_cpus(priors, walk):
    """advance() then predicted_measurement() (the scene tracker's view of a person's filter) on the GPU: the
    predicted pixels and their covariance are the CPU's weighted moments of the same float64 particles'
    projections to 1e-9 (relative); correct() then weighs them there."""
    model, observations = _model(priors["lie"], walk)
    pf = ParticleFilter(model, 2000, seed=0, device="cuda")
    pf.initialise(walk)
    pf.step(observations.uv[2])
    pf.advance()
    mean, covariance = pf.predicted_measurement()
    states, w = pf.states.cpu(), torch.exp(pf.log_weights).cpu()
    h = model.likelihood.pixels(model.observe(states)).reshape(len(states), -1, 2)
    m = torch.einsum("i,ikc->kc", w, h)
    r = h - m
    np.testing.assert_allclose(mean, m.numpy(), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(covariance, torch.einsum("i,ikc,ikd->kcd", w, r, r).numpy(), rtol=1e-9, atol=1e-9)
    snapshot = pf.correct(observations.uv[3])
    assert pf.states.device.type == "cuda" and np.isfinite(snapshot.estimate).all()


@needs_cuda
@pytest.mark.parametrize("dtype, tolerance", [(torch.float32, 2e-5), (torch.float64, 1e-12)])
def test_forward_kinematics_on_the_gpu_is_one_triton_kernel_equal_to_the_torch_path(dtype, tolerance):
    """Positions on a GPU (no rotations, no gradient) come from priortrack.body.fk_triton's kernel: equal to the
    torch path (asked for rotations too) on 10⁵ perturbed poses to the dtype's rounding (metres), for all joints
    and for a selection; a row count that is no multiple of the kernel's block, and no rows at all."""
    from priortrack.body.fk import ForwardKinematics

    walk = load_walkjog().walks("test")[0]
    skeleton = walk.skeleton
    fk = ForwardKinematics(skeleton, device="cuda", dtype=dtype)
    assert fk._gpu is not None
    rng = np.random.default_rng(0)
    rows = np.resize(walk.channels, (100_003, skeleton.num_channels))
    channels = torch.as_tensor(rows + 0.3 * rng.standard_normal(rows.shape), dtype=dtype, device="cuda")
    reference, _ = fk(channels, rotations=True)
    np.testing.assert_allclose(fk(channels).cpu().numpy(), reference.cpu().numpy(), atol=tolerance, rtol=0)
    chosen = [0, 5, 9, skeleton.num_joints - 1]
    np.testing.assert_allclose(fk(channels, joints=chosen).cpu().numpy(), reference[:, chosen].cpu().numpy(),
                               atol=tolerance, rtol=0)
    assert fk(channels[:0]).shape == (0, skeleton.num_joints, 3)
