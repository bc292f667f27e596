"""The notebooks, executed as Jupyter does (nbclient, a fresh ipykernel each): no cell fails, each
shows its figures inline (image/png outputs) and prints the numbers it is about, what it writes
goes to the scratch folder (PRIORTRACK_SCRATCH), never into notebooks/; and they are stored with the
outputs of such a run (issue 60, item 6: a reader on GitHub sees the figures without running anything)."""

import json
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

FOLDER = Path(__file__).resolve().parents[1] / "notebooks"
#: Per notebook: text its cells must print, the fewest inline images, files it must write to the scratch folder.
EXPECTED = {
    "1_step_through_a_particle_filter": (["occluded frames:", "pf-lie", "distinct particles kept", "frame 2: error"],
                                         3, ["walk_occlusion.rrd"]),
    "2_the_balanced_gpdm": (["balanced latent", "plain    latent", "5 rollouts of 60 steps"], 2, []),
    "3_the_lie_prior": (["conditional  mean next pose", "marginal     mean next pose"], 2, []),
    "4_a_filter_comparison": (["12 runs", "World MPJPE", "best run:"], 1,
                              ["comparison/results.csv", "comparison/plots/summary.png"]),
    "5_real_detections_from_four_cameras": (["ticks at 30 fps; median reprojection", "held out", "mean spread",
                                             "scene: 3 people tracked, ids [0, 1, 2]"], 3, ["crossing/cam01"]),
    "6_a_particle_cloud_on_real_detections": (["person 1 of the scene: 30 ticks at 30 fps", "ESS: min",
                                               "distinct particles kept", "median spread, mm"], 4, []),
}


def _shown(cells) -> tuple[str, list, list]:
    """What code cells printed, their inline images and their errors."""
    outputs = [o for c in cells if c["cell_type"] == "code" for o in c["outputs"]]
    printed = "".join("".join(o.get("text", "")) for o in outputs if o["output_type"] == "stream")
    images = [o for o in outputs if o["output_type"] == "display_data" and "image/png" in o.get("data", {})]
    return printed, images, [o for o in outputs if o["output_type"] == "error"]


def test_every_notebook_is_checked_and_stored_with_its_outputs():
    """Each stored notebook is one run from the top (execution counts 1, 2, …), without errors, showing the numbers
    and figures its run shows."""
    assert sorted(p.stem for p in FOLDER.glob("*.ipynb")) == sorted(EXPECTED)
    for path in FOLDER.glob("*.ipynb"):
        cells = json.loads(path.read_text())["cells"]
        code = [c for c in cells if c["cell_type"] == "code"]
        assert [c["execution_count"] for c in code] == list(range(1, len(code) + 1)), path.name
        printed, images, errors = _shown(cells)
        texts, fewest, _ = EXPECTED[path.stem]
        assert not errors and len(images) >= fewest and all(t in printed for t in texts), path.name
        assert not any("matplotlib.use(" in "".join(c["source"]) for c in cells)      # the kernel's inline backend


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_notebook_runs_in_a_kernel(name, tmp_path, monkeypatch):
    before = sorted(p.name for p in FOLDER.iterdir())
    monkeypatch.setenv("PRIORTRACK_SCRATCH", str(tmp_path / "scratch"))
    notebook = nbformat.read(FOLDER / f"{name}.ipynb", as_version=4)
    NotebookClient(notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    printed, images, errors = _shown(notebook.cells)
    assert not errors
    texts, fewest, files = EXPECTED[name]
    for text in texts:
        assert text in printed, (text, printed)
    assert len(images) >= fewest, len(images)
    for file in files:
        assert (tmp_path / "scratch" / file).stat().st_size > 0, file
    assert sorted(p.name for p in FOLDER.iterdir()) == before                     # nothing written beside them
