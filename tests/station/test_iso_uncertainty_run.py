"""`station run iso9283` under the guarded decision rule (ISO 14253-1) on the fake cell.

A figure without an uncertainty (fewer than 4 cycles) or inside its guard band
is not decided: the run finishes, its summary says NOT DECIDED and the exit
code is 3; with enough cycles (6: one stop lost on a loaded machine leaves 5) and a limit far above the figure + U the run
passes with every verdict carrying u, U and k.
"""

import json

from procedures.iso9283 import plan_from_config
from station.fleet.questions import limit_decisions_now, over_limits_now
from station.fleet.page import fleet_report
from app.assemble import RunRequest, run_procedure
from station.config import config_from_dict
from station.store import RunStore
from station.verdict import Outcome
from tests.person import person_typing_yes


def _run(fake_cell, tmp_path, capsys, *, cycles, limits, rule="guarded"):
    cfg = config_from_dict(fake_cell.config_dict(
        store_path=str(tmp_path / "s.sqlite"), report_dir=str(tmp_path / "reports"),
        iso9283={"cycles": cycles, "vap_cycles": 2}, limits=limits)
        | {"uncertainty": {"decision_rule": rule, "mc_trials": 2000, "mc_seed": 4}})
    assert plan_from_config(cfg).decision_rule == rule
    outcome = run_procedure(RunRequest(cfg, "iso9283", arm=True, operator=person_typing_yes(), quiet=True, run_id="u1",
                                       config_dir=tmp_path))
    capsys.readouterr()
    return outcome, RunStore(tmp_path / "s.sqlite"), "\n".join(outcome.lines())


def test_guarded_run_without_uncertainty_is_not_decided(fake_cell, tmp_path, capsys):
    code, store, out = _run(fake_cell, tmp_path, capsys, cycles=3, limits={"rp_limit_mm": 5.0})
    assert code.exit_code == 3, out
    assert out.startswith("NOT DECIDED: run u1") and "decision rule: guarded" in out
    assert "NOT DECIDED RP_mm P" in out
    # (a loaded machine may lose a stop: a pose left with fewer than 2 has no RP at all, and no outcome)
    v = [x for x in store.result("u1", "iso9283")["pose"]["verdicts"]
         if x["characteristic"] == "RP_mm" and x["value"] is not None]
    assert v and all(x["outcome"] == "not decided" and x["U_mm"] is None for x in v)
    an = next(s for s in store.steps("u1") if s.name == "analyse")
    # the analysis states the rule, not a verdict of its own: the run has one, decided from the stored rows
    assert an.output["decision_rule"] == "guarded" and "decision" not in an.output and "passed" not in an.output
    assert store.result("u1", "verdict")["verdict"] == "NOT DECIDED"
    rep = next(s for s in store.steps("u1") if s.name == "report").output
    html = open(rep["report"], encoding="utf-8").read()
    assert rep["verdict"] == "NOT DECIDED" and "not decided" in html and "decision rule (ISO 14253-1)" in html
    # the fleet's question: nothing is over its limit, the RP figures are not decided (listed apart)
    d = limit_decisions_now(store, "RP_mm")
    assert d["proven"] == [] and over_limits_now(store, "RP_mm") == []
    assert {r["pose"] for r in d["not_decided"]} == {x["subject"] for x in v}
    assert all(r["rule"] == "guarded" and r["decision"] is Outcome.NOT_DECIDED for r in d["not_decided"])
    from app.cli import main

    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[station]\nname = "x"\nstore_path = "{tmp_path / "s.sqlite"}"\n[devices]\n')
    capsys.readouterr()
    assert main(["store", "exceeding", "--config", str(cfg), "--name", "RP_mm"]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines and all("NOT DECIDED (guard band)" in line for line in lines)
    # the JSON keeps a figure's outcome in the stored word, as before
    assert main(["store", "exceeding", "--config", str(cfg), "--name", "RP_mm", "--json"]) == 0
    assert {r["decision"] for r in json.loads(capsys.readouterr().out)} == {"not decided"}
    page = fleet_report(store, "RP_mm")
    assert page.facts["robots over a limit now"] == "0"
    assert page.facts["robots not decided now (a figure in its guard band, ISO 14253-1)"] == "1"
    assert [r["outcome"] for r in page.rows] == [Outcome.NOT_DECIDED] * len(v) and page.verdict == "NOT DECIDED"


def test_guarded_run_far_inside_the_limit_passes_with_u_and_U(fake_cell, tmp_path, capsys):
    code, store, out = _run(fake_cell, tmp_path, capsys, cycles=6, limits={"rp_limit_mm": 5.0, "ap_limit_mm": 20.0})
    assert code.exit_code == 0, out
    assert out.startswith("PASS: run u1") and "decision rule: guarded" in out
    vs = store.result("u1", "iso9283")["pose"]["verdicts"]
    assert {v["characteristic"] for v in vs} == {"AP_mm", "RP_mm"}
    for v in vs:
        assert v["outcome"] == "pass" and v["k"] == 2.0 and 0 < v["U_mm"] < v["limit"] - abs(v["value"])
        assert v["U_mm"] == 2 * v["u_mm"] or abs(v["U_mm"] - 2 * v["u_mm"]) < 1e-6
    d = limit_decisions_now(store)
    assert d == {"proven": [], "not_decided": []}
    html = open(next(s for s in store.steps("u1") if s.name == "report").output["report"], encoding="utf-8").read()
    assert "U (k=2)" in html and "guard band (limit -/+ U)" in html and "with U (k = 2) and the guard band" in html
    # every figure with an uncertainty is kept with the result, judged or not (POS, PST have no limit here)
    figs = store.result("u1", "iso9283")["pose"]["uncertainty_figures"]
    assert {f["characteristic"] for f in figs} >= {"AP_mm", "RP_mm", "PST_s"}
