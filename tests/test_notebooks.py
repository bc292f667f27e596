"""The notebooks run: their code cells, in order, in a fresh namespace (no Jupyter needed)."""

import json
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks():
    assert NOTEBOOKS


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_runs(path, tmp_path, monkeypatch, capsys):
    cells = json.loads(path.read_text())["cells"]
    code = ["".join(cell["source"]) for cell in cells if cell["cell_type"] == "code"]
    monkeypatch.chdir(tmp_path)                                   # files the notebook writes land here
    namespace: dict = {}
    for source in code:
        exec(compile(source, str(path), "exec"), namespace)
    printed = capsys.readouterr().out
    assert "frames with nothing observed" in printed
    assert any(f.suffix == ".rrd" and f.stat().st_size > 0 for f in tmp_path.iterdir())
