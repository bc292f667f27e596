"""Resamplers: unbiased, seeded, systematic counts within floor/ceil of N w."""

import numpy as np
import pytest
import torch

from priortrack import PriortrackError
from priortrack.filters.resampling import RESAMPLERS, resampler, systematic

N = 50


def _weights(seed=0):
    rng = np.random.default_rng(seed)
    w = rng.gamma(0.5, size=N)
    return torch.as_tensor(w / w.sum())


@pytest.mark.parametrize("name", sorted(RESAMPLERS))
def test_unbiased_expected_counts(name):
    w = _weights()
    g = torch.Generator().manual_seed(0)
    runs = 1500
    counts = torch.zeros(N, dtype=torch.float64)
    for _ in range(runs):
        a = resampler(name)(w, g)
        assert a.shape == (N,) and a.dtype == torch.int64 and bool((a[1:] >= a[:-1]).all())
        counts += torch.bincount(a, minlength=N)
    mean = counts / runs
    # Each count has variance at most N w (1 − w) (multinomial); 5 standard errors.
    se = torch.sqrt(N * w * (1 - w) / runs)
    assert torch.all((mean - N * w).abs() <= 5 * se + 1e-12), name


def test_systematic_counts_are_floor_or_ceil():
    w = _weights(1)
    g = torch.Generator().manual_seed(1)
    for _ in range(200):
        counts = torch.bincount(systematic(w, g), minlength=N).double()
        assert torch.all((counts >= torch.floor(N * w)) & (counts <= torch.ceil(N * w)))


@pytest.mark.parametrize("name", sorted(RESAMPLERS))
def test_seeded_and_degenerate(name):
    w = _weights(2)
    a = resampler(name)(w, torch.Generator().manual_seed(5))
    b = resampler(name)(w, torch.Generator().manual_seed(5))
    assert torch.equal(a, b)
    one = torch.zeros(N, dtype=torch.float64)
    one[17] = 1.0
    assert torch.all(resampler(name)(one, torch.Generator().manual_seed(0)) == 17)


def test_residual_keeps_the_deterministic_part():
    w = torch.tensor([0.5, 0.3, 0.2], dtype=torch.float64)     # N w = 1.5, 0.9, 0.6
    counts = torch.bincount(resampler("residual")(w, torch.Generator().manual_seed(0)), minlength=3)
    assert counts[0] >= 1 and counts.sum() == 3


def test_bad_weights():
    g = torch.Generator()
    with pytest.raises(PriortrackError, match="sum to zero"):
        systematic(torch.zeros(4, dtype=torch.float64), g)
    with pytest.raises(PriortrackError, match="non-negative"):
        systematic(torch.tensor([0.5, float("nan")]), g)
    with pytest.raises(PriortrackError, match=r"expected \(N,\)"):
        systematic(torch.ones(2, 2), g)
    with pytest.raises(PriortrackError, match="systematic, stratified"):
        resampler("fancy")
