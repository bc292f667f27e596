"""The README: its Python block runs as printed, and it stays a user's page (≤ 250 lines, the two
commands within the first 30)."""

import re
from pathlib import Path

README = (Path(__file__).resolve().parents[1] / "README.md").read_text()


def test_the_readme_is_short_and_starts_with_the_two_commands():
    lines = README.splitlines()
    assert len(lines) <= 250
    first = "\n".join(lines[:30])
    assert "make demo" in first and "make test" in first


def test_the_python_block_runs(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", README, re.S)
    assert len(blocks) == 1
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
