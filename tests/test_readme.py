"""The README: its Python blocks run as printed, the demo's table is what the demo prints, and it
stays a user's page (≤ 250 lines, the two commands within the first 30)."""

import re
from pathlib import Path

import numpy as np

README = (Path(__file__).resolve().parents[1] / "README.md").read_text()


def test_the_readme_is_short_and_starts_with_the_two_commands():
    lines = README.splitlines()
    assert len(lines) <= 250
    first = "\n".join(lines[:30])
    assert "make demo" in first and "make test" in first


def test_the_python_blocks_run(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", README, re.S)
    assert len(blocks) == 2
    monkeypatch.setenv("PRIORTRACK_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)
    printed = capsys.readouterr().out.splitlines()
    T = len(namespace["walk"])
    assert printed[0] == f"({T}, 15, 2)"
    assert 10 < float(printed[1].removesuffix(" mm")) < 1000           # a world MPJPE in millimetres
    run = namespace["run"]
    assert run.result["frames"] == 40 and len(run.track.snapshots) == 38
    assert printed[2].startswith("torch.Size([1000, ")
    capsys.readouterr()
    exec(compile(blocks[1], "README.md", "exec"), namespace)                 # real detections
    shape, mismatch = capsys.readouterr().out.split(") ")
    assert shape == "(6, 15, 3" and float(mismatch) == 0.0
    with np.load(tmp_path / "person.npz") as z:
        assert z["joints"].shape == (6, 15, 3)


def test_the_demo_prints_the_table_the_readme_shows(tmp_path, capsys):
    """The Makefile's demo command, run here: its table rows are the README's (but the timing column)."""
    from priortrack.cli.main import main

    makefile = (Path(__file__).resolve().parents[1] / "Makefile").read_text()
    command = re.search(r"priortrack (compare .*?--rrd)", makefile.replace("\\\n", " "), re.S).group(1).split()
    out = command.index("--out") + 1
    command[out] = str(tmp_path / "demo")
    assert main(command) == 0
    printed = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ") and "---" not in line]
    shown = re.search(r"It prints\n\n```text\n(.*?)```", README, re.S).group(1).splitlines()
    def untimed(rows: list[str]) -> list[str]:
        return [row.rsplit("|", 2)[0] for row in rows]

    assert len(printed) == 5 and untimed(printed) == untimed(shown)
