"""Output paths: a missing folder, a folder given as the file or a wrong suffix is one PriortrackError
naming the path, from every writer and from the command line before any work is done."""

import pytest

from priortrack import PriortrackError, load_motion
from priortrack.cli.main import main
from priortrack.observation.synthetic import default_camera, synthesize
from priortrack.output import output_path
from priortrack.priors import Diffusion
from priortrack.viz.recording import Recording
from priortrack.body.fk import joint_positions


def test_output_path_accepts_a_writable_file_and_names_what_is_wrong(tmp_path):
    assert output_path(tmp_path / "a.PNG", "plot", suffixes=(".png", ".pdf")) == tmp_path / "a.PNG"
    (tmp_path / "old.npz").write_bytes(b"x")
    assert output_path(tmp_path / "old.npz", "prior file") == tmp_path / "old.npz"     # overwriting is fine
    with pytest.raises(PriortrackError, match=r"cannot write prior file .*missing/a\.npz: folder .*missing does not"):
        output_path(tmp_path / "missing" / "a.npz", "prior file")
    with pytest.raises(PriortrackError, match="it is a folder"):
        output_path(tmp_path, "rerun recording")
    with pytest.raises(PriortrackError, match=r"suffix must be one of \.pdf, \.png"):
        output_path(tmp_path / "a.txt", "plot", suffixes=(".png", ".pdf"))


def test_every_writer_checks_its_path(tmp_path):
    motion = load_motion("cmu:07_01").resample(30.0)
    missing = tmp_path / "missing"
    with pytest.raises(PriortrackError, match="prior file .* does not exist"):
        Diffusion.fit([motion], local=True).save(missing / "prior.npz")
    with pytest.raises(PriortrackError, match="rerun recording .* does not exist"):
        Recording(missing / "walk.rrd")
    positions = joint_positions(motion, "eval15")
    observations = synthesize(positions, motion.fps, default_camera(positions), "clean", seed=0)
    with pytest.raises(PriortrackError, match="observations file .* does not exist"):
        observations.save(missing / "obs.npz")
    assert not missing.exists()


def _must_not_run(*args, **kwargs):
    raise AssertionError("the work started before the output path was checked")


@pytest.mark.parametrize("argv,message", [
    (["fit", "diffusion-local", "--train", "cmu:07_01", "--out", "missing/prior.npz"], "folder missing does not exist"),
    (["track", "cmu:07_10", "--filter", "pf-diffusion-local", "--rrd", "missing/t.rrd"], "folder missing does not"),
    (["replay", "cmu:07_01", "--out", "."], "it is a folder"),
    (["replay", "cmu:07_01", "--out", "walk.rrd", "--observations", "missing/o.npz"], "observations file"),
])
def test_the_command_line_checks_outputs_before_the_work(argv, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("priortrack.priors.registry.PriorKind.fit", _must_not_run)
    monkeypatch.setattr("priortrack.experiments.tracking.track", _must_not_run)
    monkeypatch.setattr("priortrack.data.load.load_motion", _must_not_run)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("priortrack: error: cannot write") and message in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []
