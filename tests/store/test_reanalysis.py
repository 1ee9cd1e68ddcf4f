"""Re-analysis of archived runs: from raw samples, beside the originals, under the analysis version."""

import json
import shutil

import pytest

from fakes.station import FakeStation
from tests.person import person_typing_yes
from app.assemble import RunRequest, run_procedure
from app.cli import main
from station.config import config_from_dict
from app.reanalysis import analysis_version, reanalyze
from station.store import RunStore
from tests.seeding import seed_for
from tests.pace import LOCKSTEP


@pytest.fixture(scope="module")
def iso_store(tmp_path_factory, request):
    """A store with one real ISO 9283 run (3 + 2 cycles) made through the drivers on the fake cell."""
    tmp = tmp_path_factory.mktemp("iso")
    with FakeStation.start(seed=seed_for(request), time_scale=LOCKSTEP) as cell:
        cfg = config_from_dict(cell.config_dict(store_path=str(tmp / "s.sqlite"), report_dir=str(tmp / "reports"),
                                                iso9283={"cycles": 3, "vap_cycles": 2}))
        code = run_procedure(RunRequest(cfg, "iso9283", arm=True, operator=person_typing_yes(), quiet=True, run_id="iso-1", config_dir=tmp))
    assert code.status == "done"
    (tmp / "c.json").write_text(json.dumps({"station": {"name": "cell", "store_path": "s.sqlite"}, "devices": {}}))
    return tmp


def test_reanalysis_with_the_same_code_reproduces_the_numbers_and_keeps_them_apart(iso_store, tmp_path, capsys):
    shutil.copytree(iso_store, tmp_path / "w")
    db = tmp_path / "w" / "s.sqlite"
    with RunStore(db) as store:
        original = store.characteristics("iso-1")
        original_result = store.result("iso-1", "iso9283")
    assert main(["store", "reanalyze", "--config", str(tmp_path / "w" / "c.json")]) == 0
    out = capsys.readouterr().out
    assert "largest change 0," in out and "0 verdict changes" in out
    with RunStore(db) as store:
        again = store.reanalyses("iso-1")
        assert list(again) == [analysis_version()]
        rows = again[analysis_version()]["iso9283"]["characteristics"]
        assert {(r["pose"], r["name"]): r["value"] for r in rows} == \
               {(c["pose"], c["name"]): c["value"] for c in original}
        assert store.characteristics("iso-1") == original and store.result("iso-1", "iso9283") == original_result
    # the same version again is skipped; --force redoes it
    assert main(["store", "reanalyze", "--config", str(tmp_path / "w" / "c.json")]) == 0
    assert "already done at this version" in capsys.readouterr().out
    assert main(["store", "reanalyze", "--config", str(tmp_path / "w" / "c.json"), "--force"]) == 0
    assert "0 verdict changes" in capsys.readouterr().out


def test_a_changed_analysis_is_kept_under_its_own_version_and_its_verdict_changes_are_named(iso_store, tmp_path,
                                                                                            monkeypatch):
    shutil.copytree(iso_store, tmp_path / "w")
    db = tmp_path / "w" / "s.sqlite"
    import procedures.iso9283 as iso
    import app.reanalysis as rea

    real = iso.characteristic_rows

    def stricter(main, vap):  # a "new analysis" that reports every RP 1 mm worse
        rows = real(main, vap)
        for r in rows:
            if r["name"] == "RP_mm" and r["value"] is not None:
                r["value"] += 1.0
                r["passed"] = False if r["limit"] is not None else None
        return rows

    first = reanalyze(db, ["iso-1"])[0]
    monkeypatch.setattr(iso, "characteristic_rows", stricter)
    monkeypatch.setattr(rea, "analysis_version", lambda: "0.1.0+changed")
    second = reanalyze(db, ["iso-1"])[0]
    assert first.max_change == 0.0 and second.max_change == pytest.approx(1.0)
    assert second.verdict_changes and all("RP_mm: pass -> FAIL" in v for v in second.verdict_changes)
    with RunStore(db) as store:
        kept = store.reanalyses("iso-1")
        assert set(kept) == {first.version, "0.1.0+changed"}
        assert all(c["value"] < 1.0 for c in store.characteristics("iso-1") if c["name"] == "RP_mm")


def test_reanalysis_in_parallel_processes_and_bad_input(iso_store, tmp_path, capsys):
    shutil.copytree(iso_store, tmp_path / "w")
    db = tmp_path / "w" / "s.sqlite"
    with RunStore(db) as store:  # a second archived run: the same samples under another id
        for table in ("runs", "steps", "sample_batches", "results", "characteristics"):
            cols = [r[1] for r in store.backend.query(f"PRAGMA table_info({table})")]
            sel = ", ".join("'iso-2'" if c == "run_id" else c for c in cols)
            store.backend.execute(f"INSERT INTO {table} ({', '.join(cols)}) SELECT {sel} FROM {table} WHERE run_id='iso-1'")
    done = reanalyze(db, ["iso-1", "iso-2"], jobs=2)
    assert [d.run_id for d in done] == ["iso-1", "iso-2"] and not any(d.error for d in done)
    assert done[0].n_values == done[1].n_values > 10 and done[0].max_change == done[1].max_change == 0.0
    cfg = str(tmp_path / "w" / "c.json")
    assert main(["store", "reanalyze", "--config", cfg, "--procedure", "trailer"]) == 2
    assert "no re-analysis for procedure 'trailer'" in capsys.readouterr().err
    assert main(["store", "reanalyze", "--config", cfg, "--run", "nope"]) == 2
    assert main(["store", "reanalyze", "--config", cfg, "--jobs", "0"]) == 2


def test_reanalysis_on_the_central_store_after_a_push(iso_store, pg_url, capsys):
    from station.store.forward import push

    with RunStore(iso_store / "s.sqlite") as local, RunStore(pg_url) as central:
        push(local, central, station="cell")
        original = {(c["pose"], c["name"]): c["value"] for c in central.characteristics("iso-1")}
    cfg = iso_store / "central.json"
    cfg.write_text(json.dumps({"station": {"name": "cell", "store_path": "s.sqlite", "store_url": pg_url},
                               "devices": {}}))
    assert main(["store", "reanalyze", "--config", str(cfg), "--central", "--force"]) == 0
    assert "largest change 0," in capsys.readouterr().out
    with RunStore(pg_url) as central:
        (value,) = central.reanalyses("iso-1").values()
        again = {(r["pose"], r["name"]): r["value"] for r in value["iso9283"]["characteristics"]}
    assert again == original and len(again) > 10
