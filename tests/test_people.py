"""``priortrack eval people`` (issue 31, item 2): leave one walking person out, refit, track their walks."""

import json

import numpy as np
import pytest

from priortrack import PriortrackError
from priortrack.cli.main import main
from priortrack.data.bundled import WALKING_PEOPLE, bundled_clips, expand_sources
from priortrack.experiments import people
from priortrack.tracking.presets import load_preset


def test_the_walking_people_are_every_bundled_walk_once_and_08_39_stay_together():
    walks = [n for patterns in WALKING_PEOPLE.values() for n in expand_sources(list(patterns))]
    assert len(walks) == len(set(walks))
    persons = {c.name: c.person for c in bundled_clips()}
    for person, patterns in WALKING_PEOPLE.items():
        assert {persons[n] for n in expand_sources(list(patterns))} == {person}
    bundled_walks = {c.name for c in bundled_clips() if c.description.startswith("walk")
                     and not c.description.endswith("(test)") and c.name != "cmu:35_01"}   # = walkjog:35_01
    assert bundled_walks - {"walkjog:35_29"} <= set(walks)
    assert persons["cmu:08_01"] == persons["cmu:39_06"] == "08+39"


@pytest.mark.parametrize("held_out", list(WALKING_PEOPLE))
def test_a_fold_never_trains_on_the_held_out_person(held_out):
    own = set(expand_sources(list(WALKING_PEOPLE[held_out])))
    lie = people.fold_training(load_preset("pf-lie"), held_out)
    gpdm = people.fold_training(load_preset("pf-gpdm"), held_out)
    assert not own & set(lie) and not own & set(gpdm)
    assert set(people.TEST_WALKS[held_out]) <= own
    others = [p for p in WALKING_PEOPLE if p != held_out]
    assert len(gpdm) == people.GPDM_PEOPLE                # the GPDM: a few walks, one per other person
    assert len({n.split(":")[1][:2] for n in gpdm}) == people.GPDM_PEOPLE
    assert len(lie) == sum(len(expand_sources(list(WALKING_PEOPLE[p]))) for p in others)


def test_bad_arguments_are_named_before_any_work(tmp_path):
    with pytest.raises(PriortrackError, match="--people 99"):
        people.eval_people(["pf-lie"], ["99"], out=tmp_path)
    with pytest.raises(PriortrackError, match="--benches moon"):
        people.eval_people(["pf-lie"], ["05"], benches=["moon"], out=tmp_path)
    with pytest.raises(PriortrackError, match="--seeds"):
        people.eval_people(["pf-lie"], ["05"], seeds=0, out=tmp_path)
    with pytest.raises(PriortrackError, match="no preset"):
        people.eval_people(["pf-nothing"], ["05"], out=tmp_path)
    assert main(["eval", "people", "--people", "99", "--out", str(tmp_path)]) == 2
    assert not list((tmp_path / "runs").glob("*.json")) if (tmp_path / "runs").exists() else True


def test_a_small_evaluation_runs_is_cached_and_its_table_holds_the_runs(tmp_path, monkeypatch, capsys):
    """One held-out person (05, the slow walker), the baseline and pf-lie, one seed, the lab and one camera."""
    args = (["pf-diffusion-local", "pf-lie"], ["05"], 1, ["lab", "real1"], tmp_path)
    result = people.eval_people(*args)
    runs = result["runs"]
    assert len(runs) == 2 * (2 + 1)                    # two presets × (clean, blackout; one camera)
    assert len(list((tmp_path / "runs").glob("*.json"))) == len(runs)
    cells = result["table"]["05"]
    base, lie = cells["pf-diffusion-local"], cells["pf-lie"]
    assert base["clean_ratio"] == 1.0 and base["blackout_ratio"] == 1.0
    for name in ("clean", "blackout"):
        row = [r for r in runs if r["preset"] == "pf-lie" and r["scenario"].startswith(name)][0]
        assert lie[f"{name}_mm"] == pytest.approx(row["error_mm"])
        assert lie[f"{name}_ratio"] == pytest.approx(row["error_mm"] / [
            r for r in runs if r["preset"] == "pf-diffusion-local" and r["scenario"].startswith(name)][0]["error_mm"])
    for cell in cells.values():
        assert 0 < cell["clean_mm"] < 1000 and 0 < cell["real1_relative_mm"] < 1000
        assert "real4_mm" not in cell
    # a rerun does no work: every run comes from its cached row
    monkeypatch.setattr(people, "run_one", lambda *a, **k: pytest.fail("a cached run was run again"))
    again = people.eval_people(*args)
    assert again["runs"] == runs
    assert main(["eval", "people", "--presets", "pf-diffusion-local", "pf-lie", "--people", "05", "--seeds", "1",
                 "--benches", "lab", "real1", "--out", str(tmp_path), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert np.isclose(printed["table"]["05"]["pf-lie"]["clean_mm"], lie["clean_mm"])


def test_a_run_that_fails_is_a_counted_row_not_a_stopped_evaluation(tmp_path, monkeypatch, capsys):
    """A filter that diverges on one held-out walk (a PriortrackError) is recorded and counted; the
    other runs go on and the table's means leave it out."""
    def errors(run, preset, cache):
        if run.preset == "pf-lie" and run.scenario.startswith("blackout"):
            raise PriortrackError("state is not on the spheres")
        return {"error_mm": 100.0 if run.preset == "pf-lie" else 200.0, "relative_mm": 50.0, "seconds_per_frame": 0.01}

    monkeypatch.setattr(people, "_errors", errors)
    result = people.eval_people(["pf-diffusion-local", "pf-lie"], ["05"], 2, ["lab"], tmp_path)
    failed = [r for r in result["runs"] if r.get("failed")]
    assert len(failed) == 2 and all(r["error_mm"] is None and "spheres" in r["failed"] for r in failed)
    cells = result["table"]["05"]["pf-lie"]
    assert cells["failed_runs"] == 2 and cells["clean_mm"] == 100.0 and cells["clean_ratio"] == 0.5
    assert "blackout_mm" not in cells and result["table"]["05"]["pf-diffusion-local"]["failed_runs"] == 0
    assert main(["eval", "people", "--presets", "pf-diffusion-local", "pf-lie", "--people", "05", "--benches", "lab",
                 "--out", str(tmp_path)]) == 0
    assert "| 05 | pf-lie | 100 (0.50) | — | — | — | — | 2 |" in capsys.readouterr().out


def test_a_preset_reading_a_prior_file_cannot_be_refitted_and_says_so(tmp_path):
    prior = tmp_path / "walk.npz"
    assert main(["fit", "diffusion-local", "--train", "walkjog:35_01", "--out", str(prior)]) == 0
    preset = tmp_path / "mine.toml"
    preset.write_text('[filter]\nkind = "pf"\n[prior]\nfile = "walk.npz"\ntrain = ["walkjog:35_01"]\n')
    with pytest.raises(PriortrackError, match="reads its prior from .*walk.npz: eval people refits each prior"):
        people.eval_people([str(preset)], ["05"], out=tmp_path / "runs")


def test_the_four_camera_cells_give_the_share_of_ticks_flagged_beside_the_ratio_to_dlt(monkeypatch, capsys):
    """real4 cells: the error, its ratio to DLT (where DLT has the joints) and the mean fraction of ticks flagged
    as mismatch (issue 45: a preset worse than DLT should say so); printed as its own column."""
    rows = [{"preset": "pf-gpdm", "person": "05", "bench": "real4", "scenario": "detector", "error_mm": e,
             "where_dlt_mm": w, "dlt_mm": d, "seconds_per_frame": 0.1, "mismatch_fraction": f}
            for e, w, d, f in ((30.0, 29.0, 10.0, 1.0), (40.0, 41.0, 12.0, 0.5))]
    cell = people._table(rows, ["pf-gpdm"], ["05"])["05"]["pf-gpdm"]
    assert cell["real4_mm"] == pytest.approx(35.0) and cell["real4_dlt_ratio"] == pytest.approx(35.0 / 11.0)
    assert cell["real4_flagged"] == pytest.approx(0.75) and cell["failed_runs"] == 0
    monkeypatch.setattr(people, "eval_people", lambda *a, **k: {"table": {"05": {"pf-gpdm": cell}}})
    assert main(["eval", "people", "--presets", "pf-gpdm", "--people", "05", "--benches", "real4"]) == 0
    assert "| 05 | pf-gpdm | — | — | 35 (3.18) | 75% | — | 0 |" in capsys.readouterr().out
