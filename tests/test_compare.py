"""``priortrack compare`` (issue 20): a 4 × 1 × 2 × 2 grid writes 16 rows, the summary and valid PNG
plots, resumes without running anything again, and gives the same numbers on a Dask LocalCluster."""

import csv
import json

import matplotlib.image
import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.cli.main import main
from priortrack.experiments import compare as compare_module
from priortrack.experiments.compare import compare, plan

FILTERS = ["pf-diffusion-local", "pf-gpdm", "pf-lie", "ukf-gpdm"]
SCENARIOS = ["occlusion:sigma_px=5", "clean"]
NUMBERS = ("mpjpe_mm", "rootrel_mm", "px_err", "failure_rate", "mean_ess", "mismatch_fraction")


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    out = tmp_path_factory.mktemp("grid")
    configs = plan(FILTERS, ["cmu:07_10"], SCENARIOS, 2, frames=20)
    rows = compare(configs, out)
    return out, configs, rows


@pytest.mark.xdist_group("compare")
def test_a_grid_writes_its_csv_summary_and_plots(grid):
    out, configs, rows = grid
    table = _rows(out / "results.csv")
    assert len(table) == 16 and list(table[0]) == list(compare_module.COLUMNS)
    assert {(r["filter"], r["scenario"], r["seed"]) for r in table} == {
        (f, s, str(seed)) for f in FILTERS for s in SCENARIOS for seed in (0, 1)}
    assert all(float(r["mpjpe_mm"]) > 0 for r in table)
    assert all(r["mean_ess"] == "" for r in table if r["filter"] == "ukf-gpdm")    # sigma points have no ESS
    assert len({r["config_hash"] for r in table}) == 16
    summary = (out / "summary.md").read_text()
    assert "## World MPJPE (mm)" in summary and summary.count("**") >= 2 * len(SCENARIOS)
    pngs = sorted((out / "plots").glob("*.png"))
    assert {p.name for p in pngs} >= {"summary.png", "error_clean.png", "error_occlusion-sigma_px=5.png",
                                      "ess_clean.png"}
    for png in pngs:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and matplotlib.image.imread(png).shape[2] in (3, 4)


@pytest.mark.xdist_group("compare")
def test_a_rerun_does_no_work_and_an_interrupted_grid_resumes(grid, monkeypatch):
    out, configs, rows = grid
    monkeypatch.setattr(compare_module, "run", lambda *a, **k: pytest.fail("a cached run was run again"))
    assert compare(configs, out) == rows
    # one run's files gone (as if interrupted before it finished): only that run runs again
    key = configs[5].key
    (out / "runs" / f"{key}.json").unlink()
    ran = []
    monkeypatch.setattr(compare_module, "run", lambda config, *a: ran.append(config) or
                        (rows[5], {n: [0.0] * 20 for n in compare_module.SERIES}, None))
    compare(configs, out)
    assert ran == [configs[5]]


@pytest.mark.xdist_group("compare")
def test_dask_gives_the_serial_numbers(grid, tmp_path):
    """The same grid on a LocalCluster of two one-thread workers: every number but the timing equal."""
    pytest.importorskip("dask.distributed", reason="the Dask extra (priortrack[cluster]) is a dev dependency")
    out, configs, rows = grid
    on_dask = compare(configs[:6], tmp_path / "dask", workers=2)
    for serial, parallel in zip(rows[:6], on_dask):
        assert {k: serial[k] for k in NUMBERS} == {k: parallel[k] for k in NUMBERS}


def test_every_argument_is_checked_before_any_work(tmp_path, capsys):
    for argv, message in [
        (["--filters", "pf-lie", "nope"], "no preset 'nope'"),
        (["--motions", "cmu:99"], "unknown bundled motion 'cmu:99'"),
        (["--scenarios", "fog"], "unknown scenario 'fog'"),
        (["--seeds", "0"], "--seeds must be a positive whole number"),
        (["--frames", "2"], "--frames must be at least 3"),
        (["--workers", "0"], "--workers must be a positive whole number"),
        (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not both"),
        (["--filters", "map-gpdm", "--smooth"], "--smooth needs particle or unscented filters"),
    ]:
        base = {"--filters": ["pf-lie"], "--motions": ["cmu:07_10"], "--out": [str(tmp_path / "out")]}
        flags = [a for a in argv if a.startswith("--")]
        args = [x for k, v in base.items() if k not in flags for x in (k, *v)] + argv
        assert main(["compare", *args]) == 2, argv
        assert message in capsys.readouterr().err, argv
        assert not (tmp_path / "out").exists()


def test_the_command_prints_the_table_and_names_its_files(tmp_path, capsys):
    assert main(["compare", "--filters", "ukf-gpdm", "--motions", "cmu:07_10", "--frames", "10",
                 "--out", str(tmp_path / "o"), "--rrd", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert len(result["rows"]) == 1 and np.isfinite(result["rows"][0]["mpjpe_mm"])
    assert any(f.endswith(".rrd") for f in result["files"]) and any(f.endswith("summary.png") for f in result["files"])
    with pytest.raises(PriortrackError, match="not both"):
        compare(plan(["ukf-gpdm"], ["cmu:07_10"], ["clean"], 1, frames=5), tmp_path / "p", workers=1,
                scheduler="tcp://127.0.0.1:1")


def test_a_smoothed_grid_has_the_filtered_error_beside_the_smoothed(tmp_path):
    rows = compare(plan(["ukf-gpdm"], ["cmu:07_10"], ["blackout:sigma_px=5"], 1, smooth=True), tmp_path / "s")
    table = _rows(tmp_path / "s" / "results.csv")
    assert list(table[0])[-2:] == ["filtered_mpjpe_mm", "filtered_rootrel_mm"]
    assert rows[0]["mpjpe_mm"] < 0.8 * rows[0]["filtered_mpjpe_mm"]          # 84 vs 121 mm measured on 07_10
    assert "before smoothing" in (tmp_path / "s" / "summary.md").read_text()
