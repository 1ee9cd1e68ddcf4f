"""The ISO 9283 drift programme end to end on the fake cell through the real drivers (emScon tracker, controller).

The simulated arm warms while its joints move and cools at rest (:mod:`fakes.sim.heat`: a first-order balance
of a thermal drift drawn at random here, ``warmup``: ``dT_max_K`` under continuous ISO cycling, ``tau_s``;
steel links grow by 1.2e-5 per K): the programme's visits warm it, its waits cool it. The truth of each
visit's AP is what the tracker reads, its noise aside, of the arm's noise-free position at the temperature
its motion gave it at the visit's time, through the run's own registered frame
(:mod:`procedures.iso9283_truth` gives the true position of each pose at a temperature rise). The programme
runs over half an hour of simulated time in lockstep, much faster than real time.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.assemble import RunRequest, run_procedure
from fakes.station import FakeStation
from procedures.devices import DeviceSet
from procedures.iso9283 import IsoPlan, registration_of
from procedures.iso9283_drift import RESULT
from procedures.iso9283_truth import RunGeometry, _true_positions
from station import characteristics as table
from station.config import config_from_dict
from station.errors import ConfigError
from station.models.arm_extended import STEEL_ALPHA_PER_K
from station.runner import FAKE_CARRY_KEY, RunControl
from station.store import RunStore
from tests.pace import LOCKSTEP
from tests.station.abort_at import AbortAtStep

CYCLES = 5  # per visit: four stops at least for dAP's U


def _warmup(rng) -> tuple[float, float]:
    """A warm-running arm: 10-15 K under continuous cycling, with a time constant of 15-30 minutes (the programme
    spans half an hour; its visits keep the arm moving about a quarter of the time: 1-2 K by the last visit)."""
    return float(rng.uniform(10.0, 15.0)), float(rng.uniform(900.0, 1800.0))


def _cfg(cell_or_none, tmp_path, limits=None, drift=None):
    if cell_or_none is not None:
        d = cell_or_none.config_dict(store_path=str(tmp_path / "s.sqlite"), report_dir=str(tmp_path / "reports"),
                                     iso9283={"cycles": 3, "vap_cycles": 2}, limits=limits)
    else:
        from fakes.cells import demo_config

        d = demo_config(tmp_path, cycles=3, vap_cycles=2, rate_hz=100.0)
    if drift is not None:
        d["iso9283_drift"] = dict(drift)
    return config_from_dict(d)


def _true_at(world, plan: IsoPlan, geo, t: float) -> np.ndarray:
    """The noise-free arm's positions of every pose (plan order) at the temperature its motion gave it at ``t``."""
    rise = float(world.arm.temperature_rise_K(float(t))[0])
    return _true_positions(plan, world.arm.effects, geo.q_pose_rad, geo.arrival_dir, float(t), rise)


def _truth_ap(world, plan: IsoPlan, reg, t_device_s: np.ndarray) -> np.ndarray:
    """AP of every pose (plan order) at each time (V,) as the tracker reads the noise-free arm: (V, P) mm."""
    geo = RunGeometry.of(plan)
    cmd = np.array(list(plan.poses_mm.values()))
    out = []
    for t in t_device_s:
        x = _true_at(world, plan, geo, t)
        read = reg.to_base(world.tracker.reading(world.tracker.to_tracker_frame(x)))
        out.append(np.linalg.norm(read - cmd, axis=1))
    return np.array(out)


def test_drift_programme_finds_the_simulated_warm_up_within_its_uncertainty(tmp_path, rng, test_seed):
    warmup = _warmup(rng)
    span, interval = 1800.0, 300.0
    # a precise arm (stops scattering 5-20 um per coordinate at home), so that the warm-up stands out of U
    scatter_mm = float(rng.uniform(0.005, 0.02))
    with FakeStation.start(seed=test_seed, time_scale=LOCKSTEP, warmup=warmup, stop_sigma_mm=scatter_mm) as cell:
        # the programme from the config's section (a plan override would reach it the same way)
        cfg = _cfg(cell, tmp_path, limits={"rp_limit_mm": 0.5, "dap_limit_mm": 1.0},
                   drift={"span_s": span, "interval_s": interval, "cycles_per_visit": CYCLES})
        devices = DeviceSet(urls={"tracker": cell.tracker_url, "controller": cell.controller_url},
                            time_scale=LOCKSTEP)
        out = run_procedure(RunRequest(cfg, "iso9283-drift", devices=devices, quiet=True, run_id="d1", config_dir=tmp_path,
                            yes=True))
        with RunStore(tmp_path / "s.sqlite") as store:
            assert out.status == "done", out.error
            res = store.result("d1", RESULT)
            rec = store.run("d1")
            outputs = {s.name: s.output for s in store.done_steps("d1").values()}
            rows = store.characteristics("d1")
            history = store.history(rec_serial(store), "dAP_mm")
        plan = IsoPlan.from_params(rec.params)
        reg = registration_of(outputs)
        visits = res["visits"]
        V = int(span // interval) + 1
        assert res["visits_planned"] == res["visits_analysed"] == V
        assert sorted({v["visit"] for v in visits}) == list(range(1, V + 1))
        assert all(v["n"] == CYCLES for v in visits)
        names = list(plan.poses_mm)
        t0 = res["t_start_device_s"]
        # each visit at its time on the device clock: the first stop of the visit within its cycles of the plan
        for v in visits:
            assert 0.0 <= v["t_since_start_s"] - (v["visit"] - 1) * interval < 120.0, v
        # the truth at each pose's first and last visit, through the run's frame
        by = {(v["visit"], v["pose"]): v for v in visits}
        dT_max, tau = warmup
        for j, pose in enumerate(names):
            first, last = by[(1, pose)], by[(V, pose)]
            ts = np.array([t0 + first["t_since_start_s"], t0 + last["t_since_start_s"]])
            ap_true = _truth_ap(cell.world, plan, reg, ts)[:, j]
            d = res["drift"][pose]
            dap_true = abs(ap_true[1] - ap_true[0])
            print(f"{pose}: dAP {d['dAP_mm'] * 1e3:.1f} um, U {d['U_dAP_mm'] * 1e3:.1f}, truth {dap_true * 1e3:.1f}; "
                  f"shift {d['shift_mm'] * 1e3:.1f} um")
            # five poses at once: each within 2 U (k = 4), so an honest U fails this about 1 time in 3000
            assert abs(d["dAP_mm"] - dap_true) <= 2.0 * d["U_dAP_mm"], (pose, d, dap_true)
            if dap_true > 3.0 * d["U_dAP_mm"]:  # a drift well above U is found: stated above its U
                assert d["dAP_mm"] > d["U_dAP_mm"], (pose, d, dap_true)
            # the visit's own AP follows the truth between them: AP(t_n) - AP(t_1) with its sign
            assert abs((last["AP_mm"] - first["AP_mm"]) - (ap_true[1] - ap_true[0])) <= 2.0 * d["U_dAP_mm"]
            # the warm-up between the two visits moved the arm: the barycentres moved as the noise-free arm
            # did, within what the stops' scatter leaves in two means of CYCLES stops
            geo = RunGeometry.of(plan)
            x = [_true_at(cell.world, plan, geo, t)[j] for t in ts]
            true_shift = float(np.linalg.norm(x[1] - x[0]))
            scatter = math.sqrt(first["RP_mm"] ** 2 + last["RP_mm"] ** 2) / 3.0 / math.sqrt(CYCLES)
            assert abs(d["shift_mm"] - true_shift) <= 4.0 * scatter + 0.005, (pose, d["shift_mm"], true_shift)
        # something to find: the visits warmed the arm (its waits cooled it less), the links grew by alpha dT
        # between the first and the last visit, tens of micrometres at the poses
        t1, tV = (t0 + by[(k, "P1")]["t_since_start_s"] for k in (1, V))
        rise = cell.world.arm.temperature_rise_K(np.array([t1, tV]))
        print(f"dT_max {dT_max:.2f} K, tau {tau:.0f} s: the arm {rise[0]:.3f} K warm at the first visit, "
              f"{rise[1]:.3f} K at the last")
        grown = STEEL_ALPHA_PER_K * float(rise[1] - rise[0])
        assert grown * 1500.0 > 0.015  # the poses are 1.5 m and more from the base
    # rows of the drift programme's characteristics, judged against the config's limit
    got = {(r["pose"], r["name"]): r for r in rows}
    for pose in names:
        for c in table.characteristics("drift"):
            if c.with_orientation:  # a position-only tracker states no orientation drift
                assert (pose, c.key) not in got
                continue
            assert got[(pose, c.key)]["unit"] == c.unit
        assert got[(pose, "dAP_mm")]["limit"] == 1.0
        assert got[(pose, "dAP_mm")]["passed"] is (got[(pose, "dAP_mm")]["value"] <= 1.0)
    # the robot's history (its page, `station store fleet`) follows dAP across its runs
    assert "dAP_mm" in table.history_names() and "dRP_mm" in table.history_names()
    assert sorted(h["pose"] for h in history) == sorted(names)
    assert {h["pose"]: h["value"] for h in history} == {p: got[(p, "dAP_mm")]["value"] for p in names}
    html = open(store_result_report(tmp_path)).read()
    assert "AP against the time since the cold start" in html and "RP against the time" in html and "<svg" in html
    assert any("dAP mm" in line for line in out.summary)


def rec_serial(store) -> str:
    return store.run("d1").serial


def store_result_report(tmp_path) -> str:
    with RunStore(tmp_path / "s.sqlite") as store:
        return store.result("d1", RESULT)["report"]


def test_a_drift_run_killed_mid_span_resumes_to_the_same_visits_and_figures(tmp_path, rng, test_seed):
    warmup = _warmup(rng)
    plan = {"span_s": 2400.0, "interval_s": 1200.0, "cycles_per_visit": CYCLES}
    fake = {"warmup": list(warmup)}
    # the kill: as a visit or a wait starts, drawn (within a visit: its program is under way when it stops)
    where = str(rng.choice(["visit 2", "wait 2", "visit 3", "wait 1"]))
    results = {}
    for name, kill in (("whole", None), ("killed", where)):
        d = tmp_path / name
        d.mkdir()
        cfg = _cfg(None, d, drift={})
        control = RunControl()
        out = run_procedure(RunRequest(cfg, "iso9283-drift", run_id="r", yes=True, quiet=True, time_scale=LOCKSTEP,
                            seed=test_seed, config_dir=d, plan_overrides=plan, fake_options=fake, control=control,
                            progress=AbortAtStep(control, kill) if kill else None))
        db = cfg.station.store_file(d)
        if kill:
            assert out.status == "aborted", out.error
            with RunStore(db) as store:
                before = store.samples("r", "tracker", finished_only=False)
                # the killed cell left its arm warm from visit 1 at least: the resumed cell starts with it
                t_left, rise = store.result("r", FAKE_CARRY_KEY)["arm_rise"]
            assert rise > 0.0
            out = run_procedure(RunRequest(cfg, None, resume="r", yes=True, quiet=True, time_scale=LOCKSTEP, config_dir=d))
            assert out.fake["arm_rise"] == [t_left, rise]
        assert out.status == "done", out.error
        with RunStore(db) as store:
            results[name] = store.result("r", RESULT)
            steps = store.steps("r")
            if kill:
                after = store.samples("r", "tracker", finished_only=False)
                # every sample committed before the kill is still there, unchanged
                assert np.isin(before["t"], after["t"]).all()
                k = np.searchsorted(after["t"], before["t"])
                assert np.array_equal(after["x"][k], before["x"])
        done = [s.name for s in steps if s.status == "done"]
        for v in (1, 2, 3):  # every visit measured once, whatever was redone
            assert done.count(f"visit {v}") == 1
    whole, killed = results["whole"], results["killed"]
    assert killed["visits_analysed"] == whole["visits_analysed"] == 3
    tw = {(v["visit"], v["pose"]): v for v in whole["visits"]}
    tk = {(v["visit"], v["pose"]): v for v in killed["visits"]}
    assert sorted(tw) == sorted(tk)
    # the resume costs the time of its session's start (home, the entry cycle): a visit after it may start late
    lag = max(abs(tk[k]["t_since_start_s"] - tw[k]["t_since_start_s"]) for k in tw)
    for res in (whole, killed):  # no visit before its time (the clock of the resumed cell went on)
        assert not res["early"]
        assert all(s >= (v - 1) * plan["interval_s"] - 1.0 for v, s in
                   enumerate(res["visit_starts_since_start_s"], start=1)), res["visit_starts_since_start_s"]
    assert lag < 120.0, (where, lag, sorted((k, tw[k]["t_since_start_s"], tk[k]["t_since_start_s"]) for k in tw))
    # the same stops (each move draws its own scatter and noise) at nearly the same warmth (the resumed cell's arm
    # as warm as the killed one left it): the figures agree within what the warm-up moves in the lag and the
    # resume's own moves (an arm cycling warms by about dT_max / tau per second; alpha of that at 3 m at most)
    rate_mm_per_s = STEEL_ALPHA_PER_K * warmup[0] / warmup[1] * 3000.0
    for pose, dw in whole["drift"].items():
        dk = killed["drift"][pose]
        print(where, pose, dw["dAP_mm"], dk["dAP_mm"], lag)
        assert abs(dw["dAP_mm"] - dk["dAP_mm"]) <= 2.0 * rate_mm_per_s * lag + 1e-4, (pose, dw, dk)
        assert abs(dw["dRP_mm"] - dk["dRP_mm"]) <= 1e-4 + 2.0 * rate_mm_per_s * lag, (pose, dw, dk)


@pytest.mark.parametrize("override, key", [
    ({"interval_s": 10.0}, "iso9283_drift.interval_s"),
    ({"interval_s": 7200.0, "span_s": 3600.0}, "iso9283_drift.interval_s"),
    ({"span_s": float("nan")}, "iso9283_drift.span_s"),
    ({"span_s": "8h"}, "iso9283_drift.span_s"),
    ({"cycles_per_visit": 1}, "iso9283_drift.cycles_per_visit"),
    ({"cycles_per_visit": 2.5}, "iso9283_drift.cycles_per_visit"),
    ({"poses": ["P1", "P9"]}, "iso9283_drift.poses"),
    ({"poses": []}, "iso9283_drift.poses"),
    ({"span_s": 86400.0, "interval_s": 60.0}, "iso9283_drift.interval_s"),
    ({"intervall_s": 600.0}, "intervall_s"),
])
def test_bad_drift_plan_refused_naming_the_key_and_nothing_recorded(tmp_path, override, key):
    cfg = _cfg(None, tmp_path, drift={})
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        run_procedure(RunRequest(cfg, "iso9283-drift", run_id="bad", yes=True, quiet=True, time_scale=LOCKSTEP,
                      config_dir=tmp_path, plan_overrides=override))
    with RunStore(cfg.station.store_file(tmp_path)) as store:
        assert "bad" not in [r.run_id for r in store.runs()]


def test_the_config_section_offers_the_programme_and_its_bad_values_are_refused_naming_them(tmp_path):
    from procedures.registry import runnable_procedures

    assert "iso9283-drift" not in runnable_procedures(_cfg(None, tmp_path))
    assert "iso9283-drift" in runnable_procedures(_cfg(None, tmp_path, drift={"interval_s": 900.0}))
    with pytest.raises(ConfigError, match="no drift programme section"):
        run_procedure(RunRequest(_cfg(None, tmp_path), "iso9283-drift", run_id="x", yes=True, quiet=True, config_dir=tmp_path))
    with pytest.raises(Exception, match="interval_s"):
        _cfg(None, tmp_path, drift={"interval_s": 5.0})
