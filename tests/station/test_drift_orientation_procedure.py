"""The ISO 9283 drift programme with a 6-DoF target (a T-Mac over emScon) on the fake cell: the orientation's
drift dAPa, dAPb, dAPc (and dRPa..c) per pose, with U, against the simulated arm's truth.

The simulated warm-up (``thermal_drift``) scales the arm's link lengths, which turns no link
(tests/iso9283/test_drift_orientation.py): it gives the orientation nothing to drift. The world of this test
adds a drawn warm-up of the wrist: joints 4-6 sit off their encoders by ``theta_j (1 - exp(-t / tau))``, the
growing offset of a gearbox or encoder as it warms. The truth of each visit's orientation AP is what the
T-Mac reads, its noise aside, of the noise-free arm at the visit's time, through the run's own registered
frame (the frame is common to the visits: its rotation drops out of the drift).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from app.assemble import RunRequest, run_procedure
from fakes.station import FakeStation
from procedures.devices import DeviceSet
from procedures.iso9283 import IsoPlan, registration_of
from procedures.iso9283_drift import RESULT, summary
from procedures.iso9283_truth import RunGeometry, _noise_free
from station import characteristics as table
from station.analysis.iso9283.orientation import abc_of_matrices
from station.config import config_from_dict
from station.models import kinematics as kin
from station.models.effects import EffectContext
from station.models.rotation import rotvec_of, rotvec_to_matrix
from station.programs.builders import TOOL_DOWN
from station.store import RunStore
from tests.pace import LOCKSTEP

#: one procedure run of an hour of simulated time on the fakes (a minute or two on a shared machine)
pytestmark = pytest.mark.timeout(900)

CYCLES = 5  # per visit: four stops at least for a drift's U
#: one-sided tail of each check on drawn data
TAIL = 1e-5
KEYS = tuple(f"d{kind}{ax}_deg" for kind in ("AP", "RP") for ax in "abc")


class _WristWarmup:
    """The arm's error effects and a warm-up of its wrist: joints 4-6 turned by ``theta_rad (1 - exp(-t / tau_s))``
    at the warm-up time t of each sample (the context's), after every effect of the arm's own."""

    def __init__(self, base, theta_rad, tau_s: float):
        self.base, self.theta, self.tau = base, np.asarray(theta_rad, dtype=float), float(tau_s)

    def offsets_rad(self, warmup_s) -> np.ndarray:
        w = np.maximum(np.asarray(warmup_s, dtype=float), 0.0)
        return self.theta[None, :] * -np.expm1(-w / self.tau)[:, None]

    def apply(self, dh, q_rad, ctx=None):
        dh_out, q_out = self.base.apply(dh, q_rad, ctx)
        q_out = np.array(q_out, dtype=float, copy=True)
        w = np.zeros(len(q_out)) if ctx is None or ctx.warmup_s is None else np.broadcast_to(
            np.asarray(ctx.warmup_s, dtype=float), (len(q_out),))
        q_out[:, 3:] += self.offsets_rad(w)
        return dh_out, q_out

    def __getattr__(self, name):  # every other question about the arm's effects: its own
        return getattr(self.base, name)


def _true_abc_deg(world, plan: IsoPlan, reg, t_device_s: float) -> np.ndarray:
    """The angles a, b, c (P, 3), deg, less the commanded tool down, of the noise-free arm at every pose at
    ``t_device_s``, as the T-Mac reads it (its noise aside) through the run's registered frame."""
    geo = RunGeometry.of(plan)
    arm, tr = world.arm, world.tracker
    ctx = EffectContext(robot=plan.robot, last_dir=geo.arrival_dir,
                        warmup_s=np.full(len(geo.q_pose_rad), t_device_s - tr.latency_s - arm.warmup_origin_s),
                        payload_kg=plan.payload_kg)
    R_base = kin.fk(*arm.effects.apply(plan.robot.dh_nominal, geo.q_pose_rad, ctx))[:, :3, :3]
    R_read = rotvec_to_matrix(tr.systematic_rotvec_rad) @ tr.tracker_T_base[:3, :3]
    dev = np.degrees(abc_of_matrices(reg.R.T @ R_read @ R_base) - abc_of_matrices(TOOL_DOWN))
    return (dev + 180.0) % 360.0 - 180.0


def _stops_truth_deg(store, run_id: str, world, plan: IsoPlan, frame) -> dict[str, np.ndarray]:
    """Per pose: the mean (3,), deg, of the arm's true angles a, b, c less the commanded tool down at visit 1's
    attained stops (the programme's own extraction of its stream), as the T-Mac reads them, its noise aside,
    through ``frame``."""
    from procedures.iso9283 import STREAM, QUAT_COLUMNS
    from procedures.iso9283_drift import drift_params, visit_stops
    from station.analysis.iso9283.orientation import abc_in_base

    index = {s.name: i for i, s in store.done_steps(run_id).items()}
    smp = store.samples(run_id, STREAM, steps=[index["visit 1"]])
    order = np.argsort(smp["t"], kind="stable")
    reg = registration_of({s.name: s.output for s in store.done_steps(run_id).values()})
    xyz = reg.to_base(np.column_stack([smp[c] for c in "xyz"]))[order]
    abc = abc_in_base(np.column_stack([smp[c] for c in QUAT_COLUMNS])[order], reg.R)
    stops = visit_stops(plan, drift_params(store.run(run_id).params), smp["t"][order], xyz, abc)
    tr = world.tracker
    R_read = rotvec_to_matrix(tr.systematic_rotvec_rad) @ tr.tracker_T_base[:3, :3]
    out = {}
    for pose, (_, t, _) in stops.items():
        R_base = world.arm.tool_pose(np.asarray(t) - tr.latency_s)[:, :3, :3]
        dev = np.degrees(abc_of_matrices(frame.R.T @ R_read @ R_base) - abc_of_matrices(TOOL_DOWN))
        out[pose] = np.mean((dev + 180.0) % 360.0 - 180.0, axis=0)
    return out


def test_the_drift_programme_with_a_6dof_target_finds_the_wrists_warm_up_within_its_uncertainty(
        tmp_path, rng, test_seed):
    warmup = (float(rng.uniform(3.0, 6.0)), float(rng.uniform(900.0, 2400.0)))
    # the wrist's warm-up: 0.1-0.2 deg on each of joints 4-6, either sign, its own time constant (its drift
    # of the angles some times the U of a drift of 5 stops a visit read with the T-Mac's 0.01 deg)
    theta = np.radians(rng.uniform(0.1, 0.2, 3) * rng.choice([-1.0, 1.0], 3))
    tau = float(rng.uniform(900.0, 2400.0))
    span, interval = 3600.0, 1200.0
    # the robot's limits of the orientation drift, drawn about what the wrist's warm-up gives: some pass, some fail
    limits = {f"d{kind.lower()}{ax}_limit_deg": float(rng.uniform(*((0.01, 0.15) if kind == "AP" else (5e-4, 0.01))))
              for kind in ("AP", "RP") for ax in "abc"}
    with FakeStation.start(seed=test_seed, time_scale=LOCKSTEP, warmup=warmup,
                           stop_sigma_mm=float(rng.uniform(0.005, 0.02))) as cell:
        cell.world.arm.effects = _WristWarmup(cell.world.arm.effects, theta, tau)
        d = cell.config_dict(store_path=str(tmp_path / "s.sqlite"), report_dir=str(tmp_path / "reports"),
                             iso9283={"cycles": 3, "vap_cycles": 2}, limits={"rp_limit_mm": 0.5, **limits})
        d["devices"]["tracker"]["six_dof"] = True
        d["uncertainty"] = {"mc_trials": 4000}
        d["iso9283_drift"] = {"span_s": span, "interval_s": interval, "cycles_per_visit": CYCLES}
        devices = DeviceSet(urls={"tracker": cell.tracker_url, "controller": cell.controller_url},
                            time_scale=LOCKSTEP)
        out = run_procedure(RunRequest(config_from_dict(d), "iso9283-drift", devices=devices, quiet=True,
                                       run_id="d6", config_dir=tmp_path, yes=True))
        assert out.status == "done", out.error
        with RunStore(tmp_path / "s.sqlite") as store:
            res = store.result("d6", RESULT)
            rec = store.run("d6")
            outputs = {s.name: s.output for s in store.done_steps("d6").values()}
            rows = {(r["pose"], r["name"]): r for r in store.characteristics("d6")}
            history = {k: store.history(rec.serial, k) for k in KEYS}
            lines = summary(store, "d6")
        plan = IsoPlan.from_params(rec.params)
        reg = registration_of(outputs)
        names = list(plan.poses_mm)
        t0 = res["t_start_device_s"]
        by = {(v["visit"], v["pose"]): v for v in res["visits"]}
        assert res["visits_analysed"] == 4 and all(v["n"] == CYCLES for v in res["visits"])
        truth = {k: _true_abc_deg(cell.world, plan, reg, t0 + by[(k, "P1")]["t_since_start_s"]) for k in (1, 4)}
        # the frame a noise-free registration gives (the same circles of the true arm, read by the same tracker):
        # the run's frame is off it by the noise of its sweep points, which its jackknife states
        geo = RunGeometry.of(plan)
        tr = cell.world.tracker
        _, reg_nf = _noise_free(plan, cell.world.arm.effects, geo, 0.0)
        R_frame = rotvec_to_matrix(tr.systematic_rotvec_rad) @ tr.tracker_T_base[:3, :3] @ reg_nf.R
        frame = replace(reg, R=R_frame)
        with RunStore(tmp_path / "s.sqlite") as store:
            truth_nf = _stops_truth_deg(store, "d6", cell.world, plan, frame)
    # the run's frame's rotation error against the noise-free frame, in units of its stated (jackknife) sd
    cov = np.asarray(outputs["register base frame"]["rotation_cov_deg2"])
    delta = np.degrees(rotvec_of(R_frame.T @ reg.R).ravel())
    print(f"frame rotation error {delta} deg, stated sd {np.sqrt(np.diag(cov))} deg")
    assert np.all(np.abs(delta) <= stats.norm.isf(TAIL / 6) * np.sqrt(np.diag(cov))), (delta, cov)
    # each pose's orientation AP at visit 1 against the truth of its stops in the noise-free frame: within its
    # U, which carries the frame's rotation (an error common to the poses: each within k = 4, the count printed)
    far = []
    for j, pose in enumerate(names):
        for i, ax in enumerate("abc"):
            v = by[(1, pose)]
            e = abs(v[f"AP{ax}_deg"] - truth_nf[pose][i])
            print(f"{pose} AP{ax} visit 1: {v[f'AP{ax}_deg']:.5f} U {v[f'U_AP{ax}_deg']:.5f}; truth "
                  f"{truth_nf[pose][i]:.5f}")
            assert e <= 2.0 * v[f"U_AP{ax}_deg"], (pose, ax, v[f"AP{ax}_deg"], truth_nf[pose][i], v[f"U_AP{ax}_deg"])
            far += [(pose, ax)] if e > v[f"U_AP{ax}_deg"] else []
    print(f"visit 1 orientation AP outside U of the noise-free frame's truth: {far}")
    outside, found, checked = [], 0, 0
    for j, pose in enumerate(names):
        dr = res["drift"][pose]
        first, last = by[(1, pose)], by[(4, pose)]
        for i, ax in enumerate("abc"):
            true_step = truth[4][j, i] - truth[1][j, i]
            U = dr[f"U_dAP{ax}_deg"]
            print(f"{pose} dAP{ax}: {dr[f'dAP{ax}_deg']:.5f} deg, U {U:.5f}, truth {abs(true_step):.5f}; "
                  f"dRP{ax} {dr[f'dRP{ax}_deg']:.5f} U {dr[f'U_dRP{ax}_deg']:.5f}")
            # ISO 9283 drift: |APa(t_1) - APa(t_n)| of the visits' own APa, and its sign follows the truth
            assert dr[f"dAP{ax}_deg"] == pytest.approx(abs(last[f"AP{ax}_deg"] - first[f"AP{ax}_deg"]), abs=2e-7)
            err = abs((last[f"AP{ax}_deg"] - first[f"AP{ax}_deg"]) - true_step)
            checked += 1
            if err > U:
                outside.append((pose, ax, dr[f"dAP{ax}_deg"], true_step, U))
            assert err <= 2.0 * U, (pose, ax, dr, true_step)  # fifteen figures, each within k = 4
            if abs(true_step) > 3.0 * U:  # a drift well above U is found: stated above its U
                found += 1
                assert dr[f"dAP{ax}_deg"] > U
            # the stops' scatter is the same at both visits: dRP's truth is 0, within 2 U
            assert dr[f"dRP{ax}_deg"] <= 2.0 * dr[f"U_dRP{ax}_deg"], (pose, ax, dr)
            # each visit states its orientation AP with U (the frame's rotation in it)
            assert first[f"U_AP{ax}_deg"] > 0 and last[f"U_RP{ax}_deg"] > 0
    # U covers the truth at least 95 % of the time: of 15 figures, more outside than that leaves with 1e-4 fails
    assert len(outside) <= stats.binom.isf(1e-4, checked, 0.05), outside
    # the drawn warm-up of 0.1-0.2 deg a joint is found at most poses
    assert found >= 5, found
    # the rows of the table, one per pose and figure, judged against the robot's limit of it, in the robot's
    # history and the console; a figure over its limit fails the run
    by_key = {c.key: c.limit_key for c in table.characteristics("drift")}
    over = []
    for pose in names:
        for key in KEYS:
            r = rows[(pose, key)]
            assert r["unit"] == "deg" and r["value"] == pytest.approx(res["drift"][pose][key], abs=1e-6)
            assert r["limit"] == limits[by_key[key]] and r["passed"] is (r["value"] <= r["limit"])
            over += [(pose, key)] if not r["passed"] else []
    print(f"over their drawn limits: {over}")
    assert (str(out.verdict) == "FAIL") == bool(over), (out.verdict, out.reasons, over)
    assert set(KEYS) <= set(table.history_names())
    for key in KEYS:
        assert {h["pose"]: h["value"] for h in history[key]} == {p: rows[(p, key)]["value"] for p in names}
    assert any("dAPa deg" in line for line in lines)
    html = open(res["report"], encoding="utf-8").read()
    assert "APa against the time since the cold start" in html and "dAPc = " in html
