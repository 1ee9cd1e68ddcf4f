"""Acceptance scripts meet every verdict and every fake robot a plant can ask for.

Each test reads like a plant's script: a fake station shaped with
``make_fake_station`` (or the ``station`` marker), a run through the real
drivers on loopback, and a check of the one verdict (PASS, FAIL, NOT DECIDED,
ABORTED), its reasons and the test record. The cell's seed is printed: rerun
with ``--station-seed N``.
"""

import xml.etree.ElementTree as ET

import pytest

from app.acceptance import Station
from station.verdict import MARGINAL_FRACTION

from station.measurements import Measurement
from station.store import RunStore
from station.verdict import Outcome
from tests.pace import UR

#: a short run (the pace is the suite's --station-time-scale: the lockstep cell gives the same run at any pace)
SHORT = {"cycles": 3, "vap_cycles": 2}


@pytest.mark.timeout(300)
def test_a_marginal_robot_passes_and_its_plant_measurement_says_marginal(make_fake_station, tmp_path):
    station = make_fake_station(condition="marginal", record={"operator": "J. Kim", "work_order": "WO-2211",
                                                              "overhaul_ticket": "OH-77"}, **SHORT)
    lim = station.config.robots["r1"].limits.ap_limit_mm
    pred = station.prediction
    worst = max(pred["AP_high_mm"], key=lambda p: pred["AP_high_mm"][p] + pred["AP_margin_mm"][p])
    assert pred["AP_high_mm"][worst] + pred["AP_margin_mm"][worst] >= (1 - MARGINAL_FRACTION) * lim
    # the plant's band: everything the worst pose can measure, given its predicted scatter, is marginal
    lowest = min(pred["AP_low_mm"][worst] - pred["AP_margin_mm"][worst], lim)
    near = Measurement("AP_worst_plant", of="AP_mm", unit="mm", high=lim, marginal=lim - lowest + 1e-9,
                       pose=worst, description="worst pose of the marginal robot")
    rp = Measurement("RP_plant", of="RP_mm", unit="mm", high=0.5, pose="each")
    run = station.iso9283(measurements=[near, rp], require_iso=False)  # a short check: its PASS is not conformant
    assert run.verdict is Outcome.PASS, run.reasons
    assert run.passed is True and run.exit_code == 0
    assert f"{worst} AP_worst_plant" in run.marginal
    by = {(m["pose"], m["name"]): m for m in run.measurements}
    assert by[(worst, "AP_worst_plant")]["value"] == pytest.approx(run.value(worst, "AP_mm"))
    assert {p for p, n in by if n == "RP_plant"} == set(run.poses)
    assert all(m["outcome"] == "PASS" for m in run.measurements)

    # the test record: who and what, every measurement, the report; JUnit XML read back
    js, xml = run.write_record(tmp_path / "records")
    root = ET.parse(xml).getroot()
    assert root.tag == "testsuites"
    (suite,) = root.findall("testsuite")
    props = {p.get("name"): p.get("value") for p in suite.find("properties").findall("property")}
    assert props["operator"] == "J. Kim" and props["work_order"] == "WO-2211" and props["overhaul_ticket"] == "OH-77"
    assert props["robot.serial"] == "SIM-0001" and props["verdict"] == "PASS"
    assert props["seed"] == str(station.seed)
    cases = suite.findall("testcase")
    assert int(suite.get("tests")) == len(cases) and int(suite.get("failures")) == 0
    run_case = cases[0]
    measured = {p.get("name"): p.get("value") for p in run_case.find("properties").findall("property")}
    with RunStore(run.store_path) as store:
        rows = store.characteristics(run.run_id)
    assert len(rows) == len(run.characteristics) > 25
    for r in rows:  # every stored number, the plant's included, with unit, limits and outcome
        key = f"{r['pose']}/{r['name']}"
        if r["value"] is None:
            assert measured[key] == ""
        else:
            assert float(measured[key]) == pytest.approx(r["value"], rel=1e-12)
        assert measured[key + ".unit"] == r["unit"]
        assert measured[key + ".outcome"] == ("" if r["limit"] is None and r["passed"] is None
                                              else ("PASS" if r["passed"] else "FAIL"))
    assert measured[f"{worst}/AP_worst_plant.marginal"] == "True"
    assert measured[f"{worst}/AP_worst_plant.high"] == repr(float(lim))
    judged_cases = {c.get("name") for c in cases[1:]}
    assert f"{worst} AP_worst_plant" in judged_cases and f"P1 RP_plant" in judged_cases
    assert (js.parent / f"{run.run_id}.report.html").is_file()
    # a JUnit parser of the kind plant CI systems use reads the same record
    from junitparser import JUnitXml

    parsed = list(JUnitXml.fromfile(str(xml)))
    assert len(parsed) == 1
    jsuite = parsed[0]
    assert {p.name: p.value for p in jsuite.properties()}["verdict"] == "PASS"
    jcases = list(jsuite)
    assert [c.name for c in jcases] == [c.get("name") for c in cases]
    assert all(c.is_passed for c in jcases)  # every judged measurement passed: no failure element
    first = {p.get("name"): p.get("value") for p in jcases[0]._elem.find("properties").findall("property")}
    assert first == measured


def test_a_robot_whose_stops_scatter_fails_on_repeatability(make_fake_station):
    station = make_fake_station(condition="rp-out", **SHORT)
    run = station.iso9283()
    assert run.verdict is Outcome.FAIL and run.exit_code == 1 and run.passed is False
    rp_failures = [r for r in run.reasons if " RP_mm = " in r]
    assert rp_failures and all(r.endswith("> limit 0.5 mm") for r in rp_failures)
    with pytest.raises(AssertionError, match=r"FAIL, outside the limits: .*P\d RP_mm = [\d.]+ mm > limit 0.5 mm"):
        run.assert_within_limits()


def test_a_robot_with_one_pose_out_fails_on_that_pose_alone(make_fake_station):
    station = make_fake_station(condition="one-pose-out", **SHORT)
    out = station.prediction["out_pose"]
    run = station.iso9283(require_iso=False)  # a short check: the pose's failure is the only reason
    assert run.verdict is Outcome.FAIL and run.exit_code == 1
    assert run.reasons == [r for r in run.reasons if r.startswith(f"{out} AP_mm = ")] and len(run.reasons) == 1
    assert run.value(out, "AP_mm") > 5.0
    assert all(run.value(p, "AP_mm") <= 5.0 for p in run.poses if p != out)
    with pytest.raises(AssertionError, match=rf"FAIL, outside the limits: {out} AP_mm = [\d.]+ mm > limit 5 mm$"):
        run.assert_within_limits()


def test_a_cobot_model_runs_on_its_own_fake(make_fake_station):
    """``model=`` picks the arm, its workspace box and its controller's fake (a UR: the UR fake through RTDE)."""
    station = make_fake_station(model="ur5e", cycles=2, vap_cycles=2, time_scale=UR)
    assert station.config.robots["r1"].model == "ur5e"
    run = station.iso9283(require_iso=False)
    assert run.status == "done", run.output
    assert run.verdict is Outcome.PASS and run.subject["model"] == "ur5e"
    assert all(run.value(p, "n_cycles") == 2 for p in run.poses)


@pytest.mark.timeout(400)  # two runs
def test_fewer_cycles_than_asked_is_not_decided(make_fake_station):
    # the same cell twice: the second time the tracker's beam is broken in the middle of pose cycle 2
    first = make_fake_station(condition="in-spec", **SHORT)
    whole = first.iso9283()
    with RunStore(whole.store_path) as store:
        cycle2 = next(s.idx for s in store.steps(whole.run_id) if s.name == "pose cycle 2")
        t = store.samples(whole.run_id, "tracker", steps=[cycle2])["t"]
    span = t.max() - t.min()
    second = Station.fake(first.workdir, seed=first.seed, time_scale=first.time_scale, **SHORT)
    second.fake_options = {"beam_breaks": [[t.min() + 0.2 * span, t.max() - 0.2 * span]]}
    run = second.iso9283()
    assert run.status == "done", run.output
    assert run.verdict is Outcome.NOT_DECIDED and run.exit_code == 3 and run.passed is False
    short = [r for r in run.reasons if r.endswith("of 3 pose cycles found")]
    assert short, run.reasons
    assert any(run.value(p, "n_cycles") < 3 for p in run.poses)
    with pytest.raises(AssertionError, match="NOT DECIDED"):
        run.assert_within_limits()


@pytest.mark.station(serial="NA8608-0042", limits={"rp_limit_mm": 0.45}, payload_kg=20.0, **SHORT)
def test_conformance_required_and_not_met_is_not_decided(fake_station):
    assert fake_station.config.robots["r1"].serial == "NA8608-0042"
    limits = fake_station.config.robots["r1"].limits  # merged: the AP, vAP and AD limits are kept
    assert limits.rp_limit_mm == 0.45 and limits.ap_limit_mm == 5.0 and limits.vap_limit_mm == 2.0
    assert limits.ad_limit_mm == 2.0
    run = fake_station.iso9283()  # an acceptance requires conformance by default; 3 cycles never are (30)
    assert run.conformant is False
    assert run.verdict is Outcome.NOT_DECIDED, run.reasons
    assert any(r.startswith("not conformant (required)") for r in run.reasons), run.reasons
    # 4 when non-conformance is the only reason; a cycle the loaded fakes lost (issue 21) adds one: 3
    others = [r for r in run.reasons if not r.startswith("not conformant (required)")]
    assert run.exit_code == (3 if others else 4), run.reasons
    assert all("pose cycles found" in r or "not computed" in r or r.startswith("vAP") for r in others), others


@pytest.mark.timeout(400)  # a run and its resume
def test_a_run_stopped_by_its_operator_is_aborted_and_resumes_from_the_api(test_seed, tmp_path, request):
    pace = request.config.getoption("--station-time-scale")
    answers = tmp_path / "answers.txt"
    answers.write_text("yes\nclear = no\n")
    seed = test_seed  # the session's seed for this test (printed on failure, --seed replays)
    print(f"fake station seed {seed}")
    stopped = Station.fake(tmp_path, seed=seed, condition="in-spec", operator=answers, time_scale=pace,
                           **SHORT)
    run = stopped.iso9283(run_id="stop-1", require_iso=False)
    assert run.verdict is Outcome.ABORTED and run.exit_code == 5 and run.passed is False
    assert run.reasons and "resume" in run.reasons[0]
    again = Station.fake(tmp_path, seed=seed, condition="in-spec", time_scale=pace, **SHORT)  # a script answering yes
    resumed = again.resume("stop-1")
    assert resumed.run_id == "stop-1" and resumed.status == "done", resumed.output
    assert resumed.verdict is Outcome.PASS, resumed.reasons
    assert resumed.seed == stopped.seed
    with RunStore(resumed.store_path) as store:
        assert store.result("stop-1", "verdict")["verdict"] == "PASS"


def test_a_time_scale_faster_than_the_host_only_slows_the_run_and_loses_no_cycle(tmp_path):
    """On the lockstep fakes a time scale is a pace, not a promise: at 100x (once 18-21 of 30 cycles found)
    every cycle asked is found (tests/sim/test_lockstep.py checks the samples bit for bit at two paces)."""
    fast = Station.fake(tmp_path / "fast", **{**SHORT, "time_scale": 100.0})
    run = fast.iso9283(run_id="fast")
    assert run.status == "done" and run.verdict is not Outcome.ABORTED, run.reasons
    counts = {p: run.value(p, "n_cycles") for p in run.poses}
    assert counts and all(n == SHORT["cycles"] for n in counts.values()), counts


@pytest.mark.timeout(400)  # two runs
def test_history_spans_sessions_in_a_persistent_plant_store(make_fake_station, tmp_path):
    plant = tmp_path / "plant.sqlite"
    ms = {"iso9283": [{"name": "RP_P1_plant", "of": "RP_mm", "high": 0.4, "pose": "P1", "unit": "mm"}]}
    a = make_fake_station(condition="as-drawn", store=plant, measurements=ms, **SHORT)
    b = make_fake_station(condition="as-drawn", store=plant, measurements=ms, **SHORT)
    ra, rb = a.iso9283(), b.iso9283()
    hist = b.history("SIM-0001", "RP_P1_plant", pose="P1")
    assert [h["run_id"] for h in hist] == [ra.run_id, rb.run_id]
    assert [h["value"] for h in hist] == pytest.approx([ra.value("P1", "RP_mm"), rb.value("P1", "RP_mm")])
    assert all(h["limit"] == 0.4 for h in hist)


def test_an_acceptance_of_a_few_cycles_is_not_decided_by_default_and_a_short_check_says_it(make_fake_station):
    """The acceptance API requires ISO 9283 conformance unless told otherwise: 3 cycles of an in-spec robot
    are NOT DECIDED (the reason names the cycles of each characteristic); the same run as a short check
    is a PASS whose line says it is not conformant."""
    station = make_fake_station(condition="in-spec", **SHORT)
    run = station.iso9283()
    assert run.verdict is Outcome.NOT_DECIDED and run.conformant is False and run.passed is False
    (why,) = [r for r in run.reasons if r.startswith("not conformant (required)")]
    assert "fewer than 30 cycles" in why and f"vAP: {SHORT['vap_cycles']} of 30" in why
    check = station.iso9283(require_iso=False)
    assert check.verdict is Outcome.PASS and check.conformant is False
    head = check.output.splitlines()[0]
    assert head.startswith("PASS") and "not ISO 9283 conformant: fewer than 30 cycles" in head, head
