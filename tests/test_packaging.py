"""What a user gets from `pip install .`: every package, the presets as package data, a light command line."""

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_of_the_tree_is_listed_in_pyproject():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "priortrack").rglob("__init__.py")}
    assert found | {"priortrack.tracking.preset_files"} == listed


@pytest.mark.xdist_group("install")
def test_a_non_editable_install_lists_every_preset(tmp_path):
    """Build the wheel, install it (without dependencies: this environment has them) into a folder
    of its own, and run `priortrack presets --json` from there, away from the source tree."""
    wheels, target, source = tmp_path / "wheels", tmp_path / "site", tmp_path / "source"
    # A copy without build outputs (a stale build/ folder would be packed instead of the source).
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".venv", ".git", "build", "*.egg-info", ".*cache",
                                                                "__pycache__", "*.rrd", ".mplconfig", ".hypothesis"))
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
                            "-w", str(wheels), str(source)], capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    install = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target", str(target),
                              *map(str, wheels.glob("*.whl"))], capture_output=True, text=True)
    assert install.returncode == 0, install.stderr
    env = {**os.environ, "PYTHONPATH": str(target)}
    listed = subprocess.run([sys.executable, "-c", "from priortrack.cli.main import main; main(['presets', '--json'])"],
                            capture_output=True, text=True, cwd=tmp_path, env=env)
    assert listed.returncode == 0, listed.stderr
    names = {p["name"] for p in json.loads(listed.stdout)}
    assert names == {p.stem for p in (ROOT / "filters").glob("*.toml")} and len(names) == 15
    where = subprocess.run([sys.executable, "-c", "import priortrack; print(priortrack.__file__)"],
                           capture_output=True, text=True, cwd=tmp_path, env=env).stdout
    assert where.startswith(str(target))                          # the installed copy ran, not the source


def _modules_after(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", f"{code}\nimport sys; print(' '.join(sys.modules))"],
                         capture_output=True, text=True, check=True, cwd=ROOT)
    return set(out.stdout.split())


def test_the_help_and_argument_errors_do_not_import_torch():
    assert "torch" not in _modules_after("from priortrack.cli.main import build_parser; build_parser()")
    from priortrack.cli import track
    from priortrack.filters import smoothing

    assert track.PARTICLE_SMOOTHERS == smoothing.PARTICLE_SMOOTHERS           # the CLI's copy, kept free of torch
    for argv in (["--help"], ["fit", "no-such-kind", "--train", "x", "--out", "y.npz"]):
        modules = _modules_after(f"from priortrack.cli.main import main\ntry:\n    main({argv!r})\n"
                                 f"except SystemExit:\n    pass")
        assert "torch" not in modules, argv


def test_the_data_layer_imports_neither_torch_nor_the_body_layer():
    modules = _modules_after("import priortrack, priortrack.data.load, priortrack.data.bvh, priortrack.data.bundled")
    assert "torch" not in modules and not any(m.startswith("priortrack.body") for m in modules)


def test_there_is_a_licence_and_the_cmu_terms_ship():
    assert "MIT License" in (ROOT / "LICENSE").read_text()
    assert (ROOT / "priortrack" / "data" / "cmu" / "CMU_TERMS.txt").exists()
