"""A run's verdict from what it stored: every rule of procedures.decision on hand-built runs.

Values are drawn at random around their limits (seed printed), so a rule
that compared the wrong way or ignored a row would be caught.
"""

import json

import numpy as np
import pytest

from procedures.decision import decide, record_measurements
from procedures.registry import get_procedure
from station.measurements import Measurement, evaluate
from station.store import RunStore
from station.run_record import junit_xml
from station.verdict import Outcome

ISO = get_procedure("iso9283")
POSES = ["P1", "P2", "P3", "P4", "P5"]


@pytest.fixture
def rng(test_seed):
    seed = test_seed  # the session's seed for this test (printed on failure, --seed replays)
    print(f"test_decision seed {seed}")
    return np.random.default_rng(seed)


def _run(store, run_id, *, rows, cycles=5, limits=None, conformant=True, acceptance=None, status="done",
         vap_missing=0):
    params = {"cycles": cycles, "vap_cycles": 2, "limits": limits or {"AP_mm": 5.0, "RP_mm": 0.5}}
    if acceptance:
        params["acceptance"] = acceptance
    store.create_run(run_id, "iso9283", model="industrial-3100", serial="SN-1", overhaul_state="after",
                     config={}, params=params)
    store.put_characteristics(run_id, rows)
    store.put_result(run_id, "iso9283", {
        "pose": {"iso_conformant": conformant, "iso_reasons": [] if conformant else ["fewer than 30 cycles"]},
        "vap": {"extraction": {"missing": [{"cycle": 1, "pose": "P1"}] * vap_missing}}})
    if status != "running":
        store.set_run_status(run_id, status)


def _rows(rng, *, ap_lim=5.0, rp_lim=0.5, n_cycles=5, bad=None):
    """AP and RP inside their limits at every pose, except ``bad`` = (pose, name) over it."""
    rows = []
    for p in POSES:
        for name, lim in (("AP_mm", ap_lim), ("RP_mm", rp_lim)):
            v = float(rng.uniform(0.1, 0.9) * lim)
            if bad == (p, name):
                v = float(rng.uniform(1.05, 2.0) * lim)
            rows.append({"pose": p, "name": name, "value": v, "unit": "mm", "limit": lim, "passed": v <= lim})
        rows.append({"pose": p, "name": "n_cycles", "value": n_cycles, "unit": "1", "limit": None, "passed": None})
    return rows


def test_every_rule_gives_its_verdict_reasons_and_exit_code(tmp_path, rng):
    with RunStore(tmp_path / "s.sqlite") as store:
        _run(store, "pass", rows=_rows(rng))
        d = decide(ISO, store, "pass")
        assert d.outcome is Outcome.PASS and d.reasons == () and d.exit_code == 0

        bad = (str(rng.choice(POSES)), str(rng.choice(["AP_mm", "RP_mm"])))
        rows = _rows(rng, bad=bad)
        _run(store, "fail", rows=rows)
        d = decide(ISO, store, "fail")
        value = next(r["value"] for r in rows if (r["pose"], r["name"]) == bad)
        lim = 5.0 if bad[1] == "AP_mm" else 0.5
        assert d.outcome is Outcome.FAIL and d.exit_code == 1
        assert d.reasons == (f"{bad[0]} {bad[1]} = {value:.4g} mm > limit {lim:.4g} mm",)

        # a limit whose characteristic was not computed at one pose
        rows = _rows(rng)
        rows[0] = {**rows[0], "value": None, "passed": None}
        _run(store, "none", rows=rows)
        d = decide(ISO, store, "none")
        assert d.outcome is Outcome.NOT_DECIDED and d.exit_code == 3
        assert d.reasons == ("P1 AP_mm: limit 5 mm, not computed",)

        # a configured limit the analysis never computed
        _run(store, "absent", rows=_rows(rng), limits={"AP_mm": 5.0, "RP_mm": 0.5, "PST_s": 0.3})
        d = decide(ISO, store, "absent")
        assert d.outcome is Outcome.NOT_DECIDED and "PST_s" in d.reasons[0]

        # fewer cycles found than asked at one pose, the others complete
        k = int(rng.integers(1, 5))
        rows = _rows(rng)
        rows[2] = {**rows[2], "value": k}
        _run(store, "short", rows=rows, cycles=5)
        d = decide(ISO, store, "short")
        assert d.outcome is Outcome.NOT_DECIDED and d.reasons == (f"P1: {k} of 5 pose cycles found",)

        _run(store, "vap", rows=_rows(rng), vap_missing=2)
        assert decide(ISO, store, "vap").outcome is Outcome.NOT_DECIDED

        # conformance: only when required; alone it is exit 4, beside a failure the failure wins
        _run(store, "noniso", rows=_rows(rng), conformant=False)
        assert decide(ISO, store, "noniso").outcome is Outcome.PASS
        _run(store, "req", rows=_rows(rng), conformant=False, acceptance={"require_conformance": True})
        d = decide(ISO, store, "req")
        assert d.outcome is Outcome.NOT_DECIDED and d.exit_code == 4 and d.conformant is False
        _run(store, "req-fail", rows=_rows(rng, bad=("P3", "RP_mm")), conformant=False,
             acceptance={"require_conformance": True})
        d = decide(ISO, store, "req-fail")
        assert d.outcome is Outcome.FAIL and d.exit_code == 1 and len(d.reasons) == 2

        for status in ("aborted", "failed"):
            _run(store, status, rows=_rows(rng), status=status)
            d = decide(ISO, store, status)
            assert d.outcome is Outcome.ABORTED and d.exit_code == 5 and "resume" in d.reasons[0]


def test_plant_measurements_are_judged_stored_and_counted(tmp_path, rng):
    high = float(rng.uniform(0.2, 0.4))
    ms = [Measurement("RP_plant", of="RP_mm", high=high, marginal=0.05, pose="each").to_dict(),
          Measurement("AP_worst", of="AP_mm", low=0.0, high=6.0).to_dict()]
    rows = _rows(rng)
    with RunStore(tmp_path / "s.sqlite") as store:
        _run(store, "m", rows=rows, acceptance={"measurements": ms})
        judged = record_measurements(store, "m")
        assert record_measurements(store, "m") == judged  # idempotent
        rp = {r["pose"]: r["value"] for r in rows if r["name"] == "RP_mm"}
        mine = {m["pose"]: m for m in judged if m["name"] == "RP_plant"}
        assert set(mine) == set(POSES)
        for p, m in mine.items():
            assert m["value"] == rp[p]
            assert m["outcome"] == ("PASS" if rp[p] <= high else "FAIL")
            assert m["marginal"] == (high - 0.05 < rp[p] <= high)
        (worst,) = [m for m in judged if m["name"] == "AP_worst"]
        # the whole run's value is the pose nearest a limit (here low 0 or high 6 mm)
        aps = [r["value"] for r in rows if r["name"] == "AP_mm"]
        assert worst["pose"] == "run" and worst["value"] == min(aps, key=lambda v: min(v - 0.0, 6.0 - v))
        d = decide(ISO, store, "m")
        assert d.outcome is (Outcome.PASS if max(rp.values()) <= high else Outcome.FAIL)
        assert store.result("m", "measurements") == judged
        # stored as characteristics: history sees them
        hist = store.history("SN-1", "RP_plant", pose="P1")
        assert [h["value"] for h in hist] == [rp["P1"]] and hist[0]["limit"] == high


def test_a_measurement_of_nothing_computed_is_not_decided():
    (m,) = evaluate([Measurement("x", of="RP_mm", high=1.0, pose="P1")], [{"pose": "P1", "name": "RP_mm", "value": None}])
    assert m["outcome"] == "NOT DECIDED" and m["passed"] is None
    (m,) = evaluate([Measurement("x", of="RP_mm", high=1.0)], [])
    assert m["outcome"] == "NOT DECIDED"


def test_the_junit_xml_of_a_failed_run_carries_every_number(rng):
    from xml.etree import ElementTree as ET

    rows = [{"pose": "P1", "name": "AP_mm", "value": 6.2, "unit": "mm", "low": None, "high": 5.0, "outcome": "FAIL",
             "marginal": False, "of": None, "source": "procedure"},
            {"pose": "P1", "name": "POS_mm", "value": 0.1, "unit": "mm", "low": None, "high": None, "outcome": "",
             "marginal": False, "of": None, "source": "procedure"}]
    record = {"run_id": "r", "procedure": "iso9283", "verdict": "FAIL", "reasons": ["P1 AP_mm = 6.2 mm > limit 5 mm"],
              "seed": 3, "conformant": False, "report": None, "started_at": 0.0, "finished_at": 10.0,
              "who": {"robot": {"model": "m", "serial": "s", "overhaul_state": "after"}, "station": "c",
                      "operator": None, "work_order": None, "overhaul_ticket": None}, "measurements": rows}
    root = ET.fromstring(ET.tostring(junit_xml(record).getroot()))
    suite = root.find("testsuite")
    assert suite.get("failures") == "2" and suite.get("errors") == "0"
    cases = suite.findall("testcase")
    assert cases[0].find("failure").get("type") == "FAIL"
    assert cases[1].get("name") == "P1 AP_mm" and "limits high 5 mm" in cases[1].find("failure").get("message")
    props = {p.get("name"): p.get("value") for p in cases[0].find("properties")}
    assert props["P1/AP_mm"] == "6.2" and props["P1/POS_mm.outcome"] == "" and props["P1/AP_mm.high"] == "5.0"
    json.dumps(record)


def test_a_characteristic_the_run_could_not_state_is_not_a_pass(tmp_path, rng):
    """A figure the plan's analysis states but this run's stream could not give (no limit on it; e.g. a posing
    time lost across a gap) makes the run NOT DECIDED, naming it; a figure with a limit says so once, in its own
    reason."""
    pair = f"{rng.choice(POSES)}->{rng.choice(POSES)}"
    with RunStore(tmp_path / "s.sqlite") as store:
        stated = _rows(rng) + [{"pose": pair, "name": "MPT_s", "value": float(rng.uniform(0.5, 2.0)), "unit": "s",
                                "limit": None, "passed": None}]
        _run(store, "stated", rows=stated)
        assert decide(ISO, store, "stated").outcome is Outcome.PASS
        _run(store, "lost", rows=_rows(rng) + [{**stated[-1], "value": None}])
        d = decide(ISO, store, "lost")
        assert d.outcome is Outcome.NOT_DECIDED and d.exit_code == 3
        assert d.reasons == (f"not stated (the stream could not give them): MPT_s {pair}",)


def test_a_passing_figure_in_the_guard_band_of_its_limit_is_marginal(tmp_path, rng):
    """A PASS within the plant's fraction of its limit, or whose U carries it over the limit, is listed marginal
    (the verdict stays PASS); one clear of both is not; a FAIL is never marginal; the fraction is the run's."""
    fraction = float(rng.uniform(0.05, 0.2))
    rows, U, expect = _rows(rng), {}, set()
    ap = {r["pose"]: r for r in rows if r["name"] == "AP_mm"}
    band, straddle, clear = (str(p) for p in rng.permutation(POSES)[:3])
    lim = ap[band]["limit"]
    ap[band]["value"] = float(rng.uniform(1 - fraction, 1) * lim)  # inside the band
    ap[straddle]["value"] = v = float(rng.uniform(0.5, 1 - fraction) * lim)  # below it, but U reaches over
    U[straddle] = float(rng.uniform(1.01, 1.5) * (lim - v))
    ap[clear]["value"] = v = float(rng.uniform(0.3, 0.8) * lim)  # below it, U short of the limit
    U[clear] = float(rng.uniform(0.2, 0.9) * ((1 - fraction) * lim - v))
    # the three placed, and any other drawn row that happens to lie in a band wider than 10 %
    expect = {(r["pose"], r["name"]) for r in rows if r["limit"] is not None and r["value"] >= (1 - fraction) * r["limit"]}
    expect |= {(straddle, "AP_mm")}
    assert {(band, "AP_mm"), (straddle, "AP_mm")} <= expect and (clear, "AP_mm") not in expect
    verdicts = [{"characteristic": "AP_mm", "subject": p, "value": ap[p]["value"], "limit": lim, "U_mm": u}
                for p, u in U.items()]
    with RunStore(tmp_path / "s.sqlite") as store:
        _run(store, "m", rows=rows, acceptance={"marginal_fraction": fraction})
        store.put_result("m", "iso9283", {"pose": {"iso_conformant": True, "iso_reasons": [], "verdicts": verdicts},
                                          "vap": {}})
        d = decide(ISO, store, "m")
        assert d.outcome is Outcome.PASS and d.exit_code == 0
        assert {(p, n) for p, n, _ in d.marginal} == expect
        said = {(p, n): s for p, n, s in d.marginal}
        assert f"within {100 * fraction:.3g} % of its limit 5 mm" in said[(band, "AP_mm")]
        assert "straddles the limit" in said[(straddle, "AP_mm")]
        assert d.to_dict()["marginal"] == [s for _, _, s in d.marginal]
        # the default band is 10 %; over the limit is a FAIL, never marginal
        ap[band]["value"] = float(rng.uniform(1.01, 1.5) * lim)
        ap[band]["passed"] = False
        _run(store, "f", rows=rows)
        d = decide(ISO, store, "f")
        assert d.outcome is Outcome.FAIL
        assert (band, "AP_mm") not in {(p, n) for p, n, _ in d.marginal}
        _run(store, "dflt", rows=[{**r, "value": 0.95 * r["limit"]} if r["name"] == "RP_mm" else r
                                  for r in _rows(rng)])
        assert {n for _, n, _ in decide(ISO, store, "dflt").marginal} == {"RP_mm"}
