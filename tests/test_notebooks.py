"""The notebooks run (issue 20, item 4): their code cells, in order, in a fresh namespace, as a
kernel would run them (no Jupyter needed), each checked for what it must print and write; and they
are stored without outputs."""

import json
from pathlib import Path

import pytest

FOLDER = Path(__file__).resolve().parents[1] / "notebooks"
#: Per notebook: text its cells must print, and files they must write.
EXPECTED = {
    "1_step_through_a_particle_filter": (["occluded frames:", "pf-lie", "distinct particles kept"],
                                         ["error_and_ess.png", "cloud.png", "walk_occlusion.rrd"]),
    "2_the_balanced_gpdm": (["balanced latent", "plain    latent", "5 rollouts of 60 steps"],
                            ["latent_balanced.png", "latent_plain.png", "dynamics_samples.png"]),
    "3_the_lie_prior": (["conditional  mean next pose", "marginal     mean next pose"], ["responsibilities.png"]),
    "4_a_filter_comparison": (["12 runs", "World MPJPE", "best run:"],
                              ["comparison/results.csv", "comparison/plots/summary.png"]),
}


def test_every_notebook_is_checked_and_stored_without_outputs():
    assert sorted(p.stem for p in FOLDER.glob("*.ipynb")) == sorted(EXPECTED)
    for path in FOLDER.glob("*.ipynb"):
        cells = json.loads(path.read_text())["cells"]
        assert all(not c.get("outputs") and c.get("execution_count") is None for c in cells if c["cell_type"] == "code")


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_notebook_runs(name, tmp_path, monkeypatch, capsys):
    cells = json.loads((FOLDER / f"{name}.ipynb").read_text())["cells"]
    monkeypatch.chdir(tmp_path)                                   # files the notebook writes land here
    namespace: dict = {}
    for cell in cells:
        if cell["cell_type"] == "code":
            exec(compile("".join(cell["source"]), f"{name}.ipynb", "exec"), namespace)
    printed = capsys.readouterr().out
    texts, files = EXPECTED[name]
    for text in texts:
        assert text in printed, (text, printed)
    for file in files:
        assert (tmp_path / file).stat().st_size > 0, file
