"""The calibration procedure through the odometry driver and fake; `station calibrate trailer`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers.odometry import OdometryDriver
from fakes.sim.trailer import record_commands
from procedures.devices import DeviceSet
from procedures.trailer import (TrailerCalibrationPlan, TrailerSession, build_procedure, plan_check, plan_params,
                                preflight_problems)
from app.cli import main
from station.readers.trailer_csv import read_trailer_csv, write_trailer_csv
from station.errors import ConfigError, DataError
from station.models.trailer import JointAngleLimitError
from station.runner import Runner
from station.store import RunStore

SHORT = dict(commands=(("H", 0.2), ("C", 0.2)), duration_s=40.0, settle_s=10.0, compare=("M17",))


def _run(drv, plan, tmp_path):
    """The trailer procedure through the application layer's session, on an injected (already open) driver."""
    store = RunStore(tmp_path / "s.sqlite")
    session = TrailerSession(DeviceSet(drivers={"odometry": drv}))
    params = {"plan": plan_params(plan), "report_dir": str(tmp_path / "r")}
    out = Runner(store, build_procedure(plan), session=session).start("t", params=params, model="trailer",
                                                                       serial="TR-T")
    session.close()
    return out, store, session


# in lockstep (as a dry run): at 200x a host stalled 0.1 s would otherwise be 20 s of late set points
@pytest.mark.parametrize("odometry_fake", [{"checksum_rate": "0.05", "drop_rate": "0.05", "seed": "9",
                                            "lockstep": True}], indirect=True)
def test_procedure_calibrates_through_driver_and_fake(odometry, tmp_path):
    drv, fake = odometry
    plan = TrailerCalibrationPlan(**SHORT)
    out, store, session = _run(drv, plan, tmp_path)
    assert out.status == "done", out.error
    tc = session  # the session holds the record and the estimates
    est = tc.estimates["dynamic"]
    assert est.method == "dynamic" and est.details["input"] == "commanded curvature as instrument"
    assert abs(est.L1_m - 1.25) < 5 * est.L1_sigma_m and abs(est.L2_m - 2.48) < 5 * est.L2_sigma_m
    assert est.L2_sigma_m < 0.03
    assert "M17" in tc.estimates
    assert [s.name for s in store.steps("t")] == [st.name for st in build_procedure(plan).steps]
    # every sample the driver decoded (but those the unit sent again after a lost one) is in the record and
    # the store, once, in time order
    s = tc.arrays()
    assert fake.stats["resent_samples"] > 0  # the lossy line lost samples: the driver asked for them again
    assert s["t"].size == drv.stats.samples - drv.command_stats.repeats - drv.queued == store.sample_count(
        "t", "odometry")
    setpoints = store.samples("t", "setpoints")
    assert np.isfinite(setpoints["t_applied"]).mean() > 0.8
    assert all(st.output["samples"] > 100 for st in store.steps("t") if st.name.startswith("command"))
    # the set points averaged over each sample's interval explain the measured curvature
    drive = s["phase"] == 1
    resid = s["kappa"][drive] - s["kappa_cmd"][drive]
    assert abs(resid.mean()) < 5 * 0.0173 / np.sqrt(resid.size) and resid.std() < 1.1 * 0.0173
    assert np.all(np.diff(s["t"]) > 0)
    assert set(np.unique(s["phase"])) <= {0, 1, 2} and set(np.unique(s["segment"])) == {0, 1}
    prof = s["phase"] == 1
    assert np.ptp(s["t"][prof & (s["segment"] == 0)]) >= 40.0 - 0.5
    # the set points streamed were applied (each either acknowledged or its reply lost on the line)
    cs = store.result("t", "trailer")["set_points"]
    assert cs["refused"] == 0 and cs["acked"] + cs["lost"] >= cs["sent"] - 2 and cs["acked"] > 0.8 * cs["sent"]
    assert fake.trailer.state().v_m_s == 0.0  # stopped at the end


def test_plan_check_refuses_before_anything_moves(odometry, tmp_path):
    drv, fake = odometry
    bad = TrailerCalibrationPlan(commands=(("H", 0.2), ("C", 0.5)))
    # the preflight names it before a run exists ...
    problems = preflight_problems({"plan": plan_params(bad), "report_dir": str(tmp_path)}, None,
                                DeviceSet(drivers={"odometry": drv}))
    assert len(problems) == 1 and "plan.commands[1]" in problems[0]
    # ... and the procedure's first step refuses it too, before the first command
    out, store, _ = _run(drv, bad, tmp_path)
    assert out.status == "failed" and "CurvatureBoundError" in out.error and "plan.commands[1]" in out.error
    assert [s.name for s in store.steps("t")] == ["check plan"]
    with pytest.raises(JointAngleLimitError, match="45"):
        plan_check(TrailerCalibrationPlan(commands=(("L", 0.22),)))
    assert fake.stats["commands"] == 0
    with pytest.raises(ConfigError, match="method"):
        TrailerCalibrationPlan(method="M30")
    with pytest.raises(ConfigError, match="kind"):
        TrailerCalibrationPlan(commands=(("X", 0.1),))
    with pytest.raises(ConfigError, match="v_m_s"):
        TrailerCalibrationPlan(v_m_s=-1.0)


@pytest.mark.parametrize("odometry_fake", [{"stall": "drive+200:240", "lockstep": True}], indirect=True)
def test_a_failed_step_leaves_the_trailer_stopped(odometry_fake, tmp_path):
    """The line goes silent in the middle of a long command (the fake's stall fault: 200 simulated s after
    the trailer was set moving, for 240 s; counted from the unit's own event). The unit is stepped by its
    driver, as a dry run's is, so the deadline is the device's: the sample read times out after 0.5 s of
    listening, or, on a host too loaded to have listened that long before the line came back, at the first
    sample 240 s of device time after the one before; either way the run fails, and its safe state stops
    the trailer once the line answers again (set points are re-sent until acknowledged: up to 51 attempts of
    0.2 s, generous for a simulated unit on a loaded host; a real one acknowledges within its 0.1 s cycle)."""
    drv = OdometryDriver.open(odometry_fake.endpoint["device"], timeout_s=1.0, ack_timeout_s=0.2, command_retries=50,
                              lockstep=True)
    plan = TrailerCalibrationPlan(**{**SHORT, "commands": (("H", 0.2),), "duration_s": 2000.0}, sample_timeout_s=0.5)
    try:
        out, _, _ = _run(drv, plan, tmp_path)
    finally:
        drv.close()
    assert out.status == "failed" and "no odometry sample" in out.error and "within 0.5 s" in out.error
    assert odometry_fake.stats["stalled_samples"] > 0
    assert odometry_fake.trailer.state().v_m_s == 0.0


# ----------------------------------------------------------------------------- command line
@pytest.fixture(scope="module")
def trailer_csv(tmp_path_factory):
    rec = record_commands([("H", 0.2), ("L", 0.2)], rng=np.random.default_rng(31), settle_s=15.0,
                          duration_s=63.0)
    path = tmp_path_factory.mktemp("trailer") / "T.csv"
    write_trailer_csv(path, rec["t"], rec["kappa"], rec["psi"], rec["v"])
    return path


def test_calibrate_trailer_writes_json(trailer_csv, tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["calibrate", "trailer", "--data", str(trailer_csv), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "L1" in text and "dynamic" in text
    res = json.loads(out.read_text())
    for key in ("L1_m", "L2_m", "L1_sigma_m", "L2_sigma_m", "condition_number", "method"):
        assert key in res
    assert res["method"] == "dynamic"
    assert abs(res["L1_m"] - 1.25) < 5 * res["L1_sigma_m"] and abs(res["L2_m"] - 2.48) < 5 * res["L2_sigma_m"]
    assert main(["calibrate", "trailer", "--data", str(trailer_csv), "--method", "M21",
                 "--json", str(out)]) == 0
    assert json.loads(out.read_text())["method"] == "M21"


def test_calibrate_trailer_uses_the_command_column(tmp_path, capsys):
    rec = record_commands([("H", 0.2), ("C", 0.2)], rng=np.random.default_rng(32), settle_s=15.0, duration_s=63.0)
    path = tmp_path / "T.csv"
    write_trailer_csv(path, rec["t"], rec["kappa"], rec["psi"], rec["v"], rec["kappa_cmd"])
    data = read_trailer_csv(path)
    assert set(data) == {"t", "kappa", "psi", "v", "kappa_cmd"}
    out = tmp_path / "r.json"
    assert main(["calibrate", "trailer", "--data", str(path), "--json", str(out)]) == 0
    assert "commanded curvature as instrument" in capsys.readouterr().out
    with_cmd = json.loads(out.read_text())
    assert main(["calibrate", "trailer", "--data", str(path), "--no-command", "--json", str(out)]) == 0
    without = json.loads(out.read_text())
    assert without["details"]["input"] == "measured curvature"
    assert with_cmd["L2_sigma_m"] < 0.6 * without["L2_sigma_m"]
    assert abs(with_cmd["L2_m"] - 2.48) < 5 * with_cmd["L2_sigma_m"]


def test_calibrate_trailer_bad_files(tmp_path, capsys):
    cases = {
        "missing.csv": ("t,kappa,v\n0,0.1,1\n", "missing column"),
        "text.csv": ("t,kappa,psi\n0,0.1,0.2\n0.1,abc,0.2\n", "line 3, column 'kappa'"),
        "order.csv": ("t,kappa,psi\n0,0.1,0.2\n0.2,0.1,0.2\n0.1,0.1,0.2\n", "increase strictly"),
        "short.csv": ("t,kappa,psi,v\n" + "".join(f"{i / 10},{0.01 * i},{0.03 * i},1\n" for i in range(10)),
                      "at least"),
    }
    for name, (content, message) in cases.items():
        path = tmp_path / name
        path.write_text(content)
        assert main(["calibrate", "trailer", "--data", str(path)]) == 2
        assert message in capsys.readouterr().err, name
    nov = tmp_path / "nov.csv"
    write_trailer_csv(nov, np.arange(100) * 0.1, 0.1 * np.sin(np.arange(100) * 0.1),
                      0.37 * np.sin(np.arange(100) * 0.1))
    assert main(["calibrate", "trailer", "--data", str(nov), "--method", "dynamic"]) == 2
    assert "needs the speed" in capsys.readouterr().err
    assert main(["calibrate", "trailer", "--data", str(tmp_path / "absent.csv")]) == 2
    with pytest.raises(DataError, match="missing column"):
        read_trailer_csv(tmp_path / "missing.csv")


@pytest.mark.parametrize("method", ["dynamic", "odr", "M17"])
def test_one_absurd_sample_is_refused_with_its_row(trailer_csv, tmp_path, capsys, method, rng):
    """Issue reproducer: kappa = -1e9 in one row ended in LinAlgError tracebacks or L1 = L2 = -0.0000, exit 0."""
    rec = read_trailer_csv(trailer_csv)
    row = int(rng.integers(0, len(rec["t"])))
    kappa = np.array(rec["kappa"], dtype=float)
    kappa[row] = -1e9
    path = tmp_path / "T.csv"
    write_trailer_csv(path, rec["t"], kappa, rec["psi"], rec["v"])
    out = tmp_path / "o.json"
    assert main(["calibrate", "trailer", "--data", str(path), "--method", method, "--json", str(out)]) == 2
    err = capsys.readouterr().err
    # the reader refuses it, naming file, line (header = line 1) and column
    assert f"{path}: line {row + 2}, column 'kappa': -1e+09 is beyond" in err and "Traceback" not in err
    assert not out.exists()
