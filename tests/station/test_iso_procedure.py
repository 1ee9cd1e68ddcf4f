"""The ISO 9283 procedure end to end on the fake cell, through the real drivers.

Truth comes from the simulated world: the tool's true position at the
instants the extraction picked, mapped into the registered base frame. The
measured attained poses differ from it by tracker noise (and the
registration's own noise) only, so the tolerances come from the tracker's
noise model.
"""

import json

import numpy as np
import pytest

from procedures.iso9283 import plan_from_config, registration_of
from procedures.iso9283_truth import predict_static, prediction_scatter
from tests.person import person_typing_yes
from app.assemble import RunRequest, run_procedure
from station.errors import PreflightError
from station.config import config_from_dict
from station.errors import ConfigError
from station.store import RunStore

CYCLES, VAP_CYCLES = 3, 2


def _config(fake_cell, tmp_path, **iso):
    return config_from_dict(fake_cell.config_dict(
        store_path=str(tmp_path / "s.sqlite"), report_dir=str(tmp_path / "reports"),
        iso9283={"cycles": CYCLES, "vap_cycles": VAP_CYCLES, **iso}))


def _run(fake_cell, tmp_path, **iso):
    code = run_procedure(RunRequest(_config(fake_cell, tmp_path, **iso), "iso9283", arm=True, operator=person_typing_yes(), quiet=True, run_id="t1",
                                    config_dir=tmp_path, json_out=str(tmp_path / "out.json")))
    return code, RunStore(tmp_path / "s.sqlite")


@pytest.mark.parametrize("registration", ["axes", "best-fit"])
def test_iso9283_procedure_end_to_end_matches_the_simulated_truth(fake_cell, tmp_path, registration):
    code, store = _run(fake_cell, tmp_path, registration=registration)
    assert code.status == "done", store.steps("t1")[-1].message
    world = fake_cell.world
    steps = store.steps("t1")
    assert [s.name for s in steps if s.status == "done"][-2:] == ["analyse", "report"]
    # no sample lost on the wire in any cycle
    for s in steps:
        if s.name.startswith(("pose cycle", "vAP cycle")):
            assert s.output["lost"] == 0 and s.output["received"] > 100, s.output
    result = store.result("t1", "iso9283")["pose"]
    reg = registration_of({s.name: s.output for s in steps if s.status == "done"})
    assert steps[[s.name for s in steps].index("register base frame")].output["method"] == registration
    sigma = float(np.max(world.tracker.sigma_mm(3000.0)))  # per-coordinate noise, tracker ~2-4 m away
    # registration: rms residual of the fit is robot error + noise; it must be small but not zero (the
    # best fit over the eight inset corners of the drawn robots: 0.8 mm median, 1.7 mm at 99.9 %)
    assert 0 < reg.rms_mm < 3.0
    chars = {(c["pose"], c["name"]): c for c in store.characteristics("t1")}
    for name, pose in result["poses"].items():
        att = pose["attained"]
        meas = np.column_stack([att["x_mm"], att["y_mm"], att["z_mm"]])
        assert meas.shape == (CYCLES, 3)
        true_base = world.arm.tool_position_mm(np.asarray(att["t_s"]))
        true_tracker = true_base @ world.tracker.tracker_T_base[:3, :3].T + world.tracker.tracker_T_base[:3, 3]
        true_in_fit = reg.to_base(true_tracker)
        err = np.linalg.norm(meas - true_in_fit, axis=1)
        # tracker noise of one sample (3-D: sigma*sqrt(3)); 5 sigma bound
        assert np.all(err < 5 * sigma * np.sqrt(3) + 0.005), (name, err, sigma)
        commanded = np.asarray(pose["commanded_mm"])
        ap_true = np.linalg.norm(true_in_fit.mean(axis=0) - commanded)
        assert abs(chars[(name, "AP_mm")]["value"] - ap_true) < 5 * sigma * np.sqrt(3 / CYCLES) + 0.005
        assert chars[(name, "n_cycles")]["value"] == CYCLES
        assert chars[(name, "RP_mm")]["passed"] is (chars[(name, "RP_mm")]["value"] <= 0.5)
    # three-direction approaches gave vAP for P1, P2, P4 and none for P3, P5 (seed Table 3)
    assert chars[("P1", "vAP_mm")]["value"] is not None and chars[("P4", "vAP_mm")]["value"] is not None
    assert ("P3", "vAP_mm") not in chars
    out = json.loads((tmp_path / "out.json").read_text())
    assert out["status"] == "done" and out["results"]["pose"]["poses"]["P1"]["AP_mm"] == pytest.approx(
        chars[("P1", "AP_mm")]["value"], abs=1e-6)
    report = next(s.output["report"] for s in steps if s.name == "report")
    html = open(report).read()
    assert html.count("<svg") >= 5 and "P2-P4" in html
    # the registered frame beside the report, in the form --frame reads
    from station.readers.registration_files import read_frame_json

    frame = next(s.output["frame"] for s in steps if s.name == "report")
    assert frame == str((tmp_path / "reports" / "t1.frame.json").resolve())
    R, t, obj = read_frame_json(frame)
    assert np.array_equal(R, reg.R) and np.array_equal(t, reg.t_mm) and obj["method"] == registration
    if registration == "axes":
        _matches_the_noise_free_prediction(fake_cell, tmp_path, steps, result, chars)


def _matches_the_noise_free_prediction(fake_cell, tmp_path, steps, result, chars):
    """AP and AD against procedures.iso9283_truth from the cell's true effects.

    What the prediction leaves out, the registration's error from the stop
    scatter of its points, the mean of the n stop offsets and the tracker's
    noise, is the Monte Carlo scatter of ``prediction_scatter``: |AP measured -
    predicted| is at most the length of that error vector, allowed 4 rms
    lengths; AD 5 sd. Each plus 0.05 mm for what both simplify (one warm-up
    time for all poses, the direction of a joint that barely moves).
    """
    world = fake_cell.world
    plan = plan_from_config(_config(fake_cell, tmp_path, registration="axes"))
    t_all = np.concatenate([p["attained"]["t_s"] for p in result["poses"].values()])
    warm = float(t_all.mean() - world.arm.warmup_origin_s)
    # the arm as warm as its motion made it at the poses' mean time (fakes.sim.heat)
    pred = predict_static(plan, world.arm.effects, warmup_s=warm,
                          temperature_rise_K=float(world.arm.temperature_rise_K(float(t_all.mean()))[0]))
    tr = world.tracker
    scatter = prediction_scatter(plan, world.arm.effects, world.arm.stop_sigma_rad, cycles=CYCLES,
                                 tracker_sigma_mm=tr.noise.total_um * 1e-3, warmup_s=warm,
                                 tracker_accuracy=(tr.base_T_tracker[:3, 3], tr.mpe_a_um, tr.mpe_b_um_per_m))
    for name in plan.poses_mm:
        tol = 4 * scatter.AP_rms_mm[name] + 0.05
        assert abs(chars[(name, "AP_mm")]["value"] - pred.AP_mm[name]) < tol, (name, pred.AP_mm, tol)
    tol_ad = 5 * scatter.AD_sd_mm["P2-P4"] + 0.05
    assert abs(chars[("P2-P4", "AD_mm")]["value"] - pred.AD_mm["P2-P4"]) < tol_ad


def _arm_q(world):
    return world.arm.actual_q_rad(np.array([world.clock.now()]))[0]


def test_unsafe_plan_is_refused_before_anything_moves(fake_cell, tmp_path):
    """A cube outside the reach: the preflight lists every program that cannot run; no run, the arm never moved."""
    q0 = _arm_q(fake_cell.world)
    big = [(x * 1.6, 1700 + (y - 1700) * 1.6, 1400 + (z - 1400) * 1.6) for x, y, z in
           [(600, 2300, 2000), (600, 1100, 2000), (-600, 1100, 2000), (-600, 2300, 2000),
            (600, 2300, 800), (600, 1100, 800), (-600, 1100, 800), (-600, 2300, 800)]]
    with pytest.raises(PreflightError) as err:
        _run(fake_cell, tmp_path, cube_corners_mm=big, inset_mm=160.0)
    progs = {p.split("'")[1] for p in err.value.problems if p.startswith("program")}
    assert {"pose cycle", "vAP cycle"} <= progs, err.value.problems
    assert all("reach" in p or "workspace" in p for p in err.value.problems)
    assert "nothing moved" in str(err.value)
    assert RunStore(tmp_path / "s.sqlite").runs() == []
    np.testing.assert_allclose(_arm_q(fake_cell.world), q0, atol=1e-9)


def test_a_rate_the_tracker_cannot_stream_is_refused_before_anything_moves(rng, fake_cell, tmp_path):
    """emScon spaces points by whole milliseconds: a rate that is not 1000/k Hz is refused up front."""
    rate = float(rng.choice([3000.0, 2000.0, 300.0, 700.0, 1000.0 / 2.5]))
    q0 = _arm_q(fake_cell.world)
    with pytest.raises(PreflightError, match="tracker_rate_hz: emScon continuous time mode") as err:
        _run(fake_cell, tmp_path, tracker_rate_hz=rate)
    assert len(err.value.problems) == 1 and f"{rate!r}" in err.value.problems[0]
    assert RunStore(tmp_path / "s.sqlite").runs() == []
    np.testing.assert_allclose(_arm_q(fake_cell.world), q0, atol=1e-9)


def test_malformed_station_config_refused_before_start(tmp_path):
    from app.cli import main

    bad = tmp_path / "c.toml"
    bad.write_text('[station]\nname = "x"\n[devices.tracker]\nurl = "laser://1.2.3.4"\n[robots]\n')
    assert main(["run", "iso9283", "--config", str(bad), "--yes"]) == 2
    assert not (tmp_path / "station.sqlite").exists()
    with pytest.raises(ConfigError, match="unknown scheme 'laser'"):
        from station.config import load_config
        load_config(bad)
