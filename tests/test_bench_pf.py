"""The particle-filter throughput benchmark on tiny priors: what it reports and its bad input."""

import pytest
import torch

from priortrack import PriortrackError, load_walkjog
from priortrack.cli.main import main
from priortrack.experiments.benchmarks.pf import PHASES, bench_pf
from priortrack.priors import Diffusion
from priortrack.priors.gpdm import GPDM
from priortrack.priors.lie import LiePrior
from priortrack.threads import torch_threads


@pytest.fixture(scope="module")
def priors():
    walks = list(load_walkjog().walks("train"))
    with torch_threads(1):                          # small fits: one thread is the fastest
        return {"diffusion": Diffusion.fit(walks[:2], local=True),
                "gpdm": GPDM.fit([m[:15] for m in walks[:2]], seed=0),
                "lie": LiePrior.fit(walks[:3], seed=0, max_components=2)}


def test_reports_every_prior_from_real_steps(priors):
    threads = torch.get_num_threads()
    result = bench_pf(particles=64, steps=3, warmup=1, threads=1, dtype="float32", priors=priors)
    assert torch.get_num_threads() == threads                                   # restored
    assert result["particles"] == 64 and result["steps"] == 3 and result["threads"] == 1
    assert result["dtype"] == "float32" and result["translation"] == "marginalised"
    for name in priors:
        ms = result["ms_per_step"][name]
        low, high = result["ms_per_step_range"][name]
        assert 0 < low <= ms <= high
        assert result["particle_steps_per_s"][name] == pytest.approx(64 / (ms / 1000))
        assert set(result["phases_ms"][name]) == set(PHASES)
        # Every phase is a part of a step: each is positive, and none is slower than the slowest step.
        assert all(0 < v <= high for v in result["phases_ms"][name].values())
        assert 0 <= result["resamples"][name] <= 3
        assert result["cpu_ms_per_step"][name] > 0
        # The FK alone, timed beside the steps: the step over it and its share are each other's inverse.
        assert result["step_over_fk"][name] == pytest.approx(ms / result["fk_ms"])
        assert result["fk_share"][name] == pytest.approx(result["fk_ms"] / ms)
    assert result["fk_ms"] > 0 and result["device"] == "cpu"


def test_guided_steps_through_a_ring_of_cameras(priors):
    """--cameras 4 --proposal guided: the presets' real-data step (the multi-view likelihood, the guided draw)."""
    result = bench_pf(particles=64, steps=2, warmup=1, threads=1, priors={"lie": priors["lie"]}, cameras=4,
                      proposal="guided")
    assert result["cameras"] == 4 and result["proposal"] == "guided"
    assert result["ms_per_step"]["lie"] > 0 and set(result["phases_ms"]["lie"]) == set(PHASES)


def test_bad_arguments(priors):
    with pytest.raises(PriortrackError, match="positive"):
        bench_pf(particles=0, priors=priors)
    with pytest.raises(PriortrackError, match="dtype"):
        bench_pf(particles=8, dtype="float16", priors=priors)
    with pytest.raises(PriortrackError, match="translation must be one of"):
        bench_pf(particles=8, translation="integrated", priors=priors)
    with pytest.raises(PriortrackError, match="guided proposal with 2 or more"):
        bench_pf(particles=8, proposal="guided", priors=priors)
    with pytest.raises(PriortrackError, match="cameras in"):
        bench_pf(particles=8, cameras=9, priors=priors)
    with pytest.raises(PriortrackError, match="exceeds"):
        bench_pf(particles=8, steps=200, priors=priors)
    with pytest.raises(PriortrackError, match="expected some of"):
        bench_pf(particles=8, steps=1, priors={"kalman": priors["diffusion"]})
    slow = Diffusion.fit(list(load_walkjog().walks("train"))[:2], fps=15.0)
    with pytest.raises(PriortrackError, match="fps"):
        bench_pf(particles=8, steps=1, priors={"diffusion": slow})


def test_the_command_refuses_bad_view_settings_before_fitting(capsys, monkeypatch):
    """`bench pf --proposal guided` with one camera, or `--cameras 9`: one line, exit 2, before any prior is fitted."""
    import priortrack.experiments.benchmarks.pf as pf

    def no_fit(*args, **kwargs):
        raise AssertionError("the priors were fitted before the settings were checked")

    monkeypatch.setattr(pf, "bench_priors", no_fit)
    for arguments in (["--proposal", "guided"], ["--cameras", "9"]):
        assert main(["bench", "pf", *arguments]) == 2
        assert "guided proposal with 2 or more" in capsys.readouterr().err
