"""The annealed particle filter: the annealing schedule, its survival rate, tracking a walk."""

import math

import numpy as np
import pytest
import torch

from priortrack import PriortrackError, load_walkjog
from priortrack.experiments.metrics import mpjpe
from priortrack.filters.annealed import AnnealedParticleFilter
from priortrack.filters.tempering import annealing_exponent, survival
from priortrack.models.tracking import TrackingModel
from priortrack.observation import default_camera, synthesize
from priortrack.observation.likelihood import JointLikelihood
from priortrack.priors import Diffusion
from priortrack.body.fk import joint_positions


def test_survival_is_the_normalised_ess():
    log_lik = torch.tensor([0.0, -1.0, -2.0, -math.inf], dtype=torch.float64)
    w = torch.exp(0.7 * log_lik)
    w = w / w.sum()
    assert survival(log_lik, 0.7) == pytest.approx(float(1 / (w ** 2).sum() / 4), rel=1e-12)


def test_annealing_exponent_hits_the_target_survival():
    log_lik = -0.5 * torch.randn(2000, generator=torch.Generator().manual_seed(0), dtype=torch.float64).pow(2) * 400
    beta = annealing_exponent(log_lik, 0.5)
    assert 0 < beta < 1
    assert survival(log_lik, beta) == pytest.approx(0.5, abs=1e-6)
    flat = torch.zeros(100, dtype=torch.float64)
    assert annealing_exponent(flat, 0.5) == 1.0                      # nothing to choose: the full likelihood
    assert annealing_exponent(log_lik, 0.5, lower=0.9) == 0.9        # β never decreases across layers


@pytest.fixture(scope="module")
def walk():
    walkjog = load_walkjog()
    train = list(walkjog.walks("train"))[:8]
    prior = Diffusion.fit(train, local=True)
    motion = walkjog.test[1][:30]
    X = joint_positions(motion, "eval15")
    obs = synthesize(X, motion.fps, default_camera(X), "noise", seed=0, sigma_px=5.0)
    model = TrackingModel.fitted(prior, train,
                          JointLikelihood(obs.camera))
    return model, motion, X, obs


@pytest.mark.parametrize("translation", ["sampled", "marginalised"])
def test_layers_keep_half_the_particles_and_beta_grows(walk, translation):
    model, motion, X, obs = walk
    apf = AnnealedParticleFilter(model, 400, layers=4, survival=0.5, translation=translation, seed=0)
    apf.initialise(motion)
    snap = apf.step(obs.uv[2])
    assert len(apf.betas) == 4 and all(b2 >= b1 for b1, b2 in zip(apf.betas, apf.betas[1:]))
    assert all(0 < b <= 1 for b in apf.betas)
    if apf.betas[-1] < 1:                                             # the exponent was chosen by survival
        assert snap.ess / 400 == pytest.approx(0.5, abs=0.01)
    assert snap.ancestors is not None                                 # tempered weights: always resampled


@pytest.mark.parametrize("translation", ["sampled", "marginalised"])
def test_tracks_a_walk_better_than_holding_still(walk, translation):
    model, motion, X, obs = walk
    track = AnnealedParticleFilter(model, 300, layers=4, translation=translation, seed=1).run(obs.uv, motion)
    still = mpjpe(np.repeat(X[1:2], len(X) - 2, 0), X[2:]).mean()
    assert mpjpe(track.estimates[2:], X[2:]).mean() < 0.5 * still
    assert np.isfinite(track.estimates).all() and np.all(track.ess[2:] >= 1)


def test_all_missing_frame_runs_no_layer(walk):
    model, motion, X, obs = walk
    apf = AnnealedParticleFilter(model, 100, seed=0)
    apf.initialise(motion)
    snap = apf.step(np.full((15, 2), np.nan))
    assert "no-observation" in snap.flags and apf.betas == [] and snap.ancestors is None


def test_bad_parameters(walk):
    model = walk[0]
    with pytest.raises(PriortrackError, match="layers"):
        AnnealedParticleFilter(model, 10, layers=0)
    with pytest.raises(PriortrackError, match="survival"):
        AnnealedParticleFilter(model, 10, survival=1.0)


def test_marginalised_layers_score_the_predictive_likelihood_and_keep_the_last_update(walk, monkeypatch):
    """Every layer calls the Kalman update on the previous frame's covariances (resampled with their
    particles); the translation is not diffused; the frame ends on the last layer's update."""
    import priortrack.filters.particle as particle                   # where the filters call the update

    model, motion, X, obs = walk
    apf = AnnealedParticleFilter(model, 200, layers=3, translation="marginalised", seed=0)
    apf.initialise(motion)
    apf.step(obs.uv[2])
    calls, diffused = [], []
    real = particle.kalman_update

    def spy(joints, C, *rest):
        out = real(joints, C, *rest)
        calls.append((C.clone(), out[1]))
        return out

    real_diffuse = apf.diffuse

    def diffuse_spy(s, std_x, std_g, shrink):
        diffused.append(std_g.clone())
        return real_diffuse(s, std_x, std_g, shrink)

    monkeypatch.setattr(particle, "kalman_update", spy)
    monkeypatch.setattr(apf, "diffuse", diffuse_spy)
    before = apf.covariance.clone()
    snap = apf.step(obs.uv[3])
    assert len(calls) == 3 and len(diffused) == 2
    torch.testing.assert_close(calls[0][0], before)                   # layer 1: the previous covariances
    for C_prev, _ in calls[1:]:                                       # later layers: resampled rows of them
        assert all(any(torch.equal(row, b) for b in before) for row in C_prev[:20])
    assert all(not std[:3].any() and std[3:].all() for std in diffused)   # the rotation diffused, not t
    torch.testing.assert_close(apf.covariance, calls[-1][1][torch.as_tensor(snap.ancestors)])
