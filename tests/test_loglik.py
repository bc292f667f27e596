"""The held-out log-likelihood of the priors (priortrack eval loglik, Simo-Serra et al. Table 2)."""

import math

import pytest

from priortrack import PriortrackError
from priortrack.tracking.presets import load_preset
from priortrack.experiments.reproductions.loglik import eval_loglik


def test_one_split_scores_every_model_and_the_defensive_mixture_lies_between_its_parts():
    """On one split (subject 35's walks 35_01-35_09 learned, subject 07's 07_10 scored): the learned prior beats both
    diffusions on its own training frames, and the defensive mixture's mean log-density obeys the
    mixture's bounds, ln(1 − ε) + ln p_lie ≤ ln p_mix and ln ε + ln p_local ≤ ln p_mix frame by frame."""
    result = eval_loglik(train=[f"walkjog:35_0{i}" for i in range(1, 10)], test=["cmu:07_10"])
    eps = load_preset("pf-lie-defensive").defensive
    assert result["lie"]["train"] > result["diffusion_local"]["train"] > result["diffusion_global"]["train"]
    for part in ("train", "test"):
        mix, lie, local = (result[m][part] for m in ("lie_defensive", "lie", "diffusion_local"))
        assert all(math.isfinite(v) for v in (mix, lie, local))
        assert mix >= math.log1p(-eps) + lie - 1e-9 and mix >= math.log(eps) + local - 1e-9
    assert result["folds"][0]["test_frames"] == result["test_frames"] > 0
    # calibration: one person's walks learned, another's scored: every model over-confident there (measured: Lie
    # moment-matched 17.0, local diffusion 4.0, global 2.7 against 1), the shares beyond χ² 99 % a fraction
    assert result["lie"]["test_d2"] > result["diffusion_local"]["test_d2"] > 1
    assert all(0 <= result[m]["test_beyond"] <= 1 for m in ("lie", "lie_defensive", "diffusion_local", "diffusion_global"))
    assert result["lie"]["test_beyond"] > 0.5


def test_calibration_is_one_on_the_frames_a_diffusion_learned_by_maximum_likelihood():
    """A diffusion's σ² per joint is the mean squared step of its training frames (its maximum-likelihood fit), so
    on those frames the mean d²/n of its Gaussian step is 1 exactly (both kinds)."""
    from priortrack.data.load import load_motion
    from priortrack.experiments.reproductions.loglik import _normalised_distances
    from priortrack.priors.diffusion import Diffusion

    train = [load_motion(f"walkjog:35_0{i}") for i in range(1, 4)]
    local = Diffusion.fit(train, local=True, space="directions", fps=30.0)
    models = {"lie": local, "diffusion_global": Diffusion.fit(train, local=False, space="directions", fps=30.0)}
    for name, d2 in _normalised_distances(models, train).items():
        assert float(d2.mean()) == pytest.approx(1.0, abs=1e-9), name


def test_a_split_needs_both_sides():
    with pytest.raises(PriortrackError, match="give both train and test"):
        eval_loglik(train=["cmu:07_01"])
    with pytest.raises(PriortrackError, match="at least one motion"):
        eval_loglik(train=["cmu:07_01"], test=[])
