"""The calibration procedure through the odometry driver and fake; `station calibrate trailer`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fakes.sim.trailer import record_commands
from procedures.trailer import (
    TrailerCalibrationContext, TrailerCalibrationPlan, calibration_steps, check_plan, run_trailer_calibration,
)
from station.cli import main
from station.commands.calibrate import read_trailer_csv, write_trailer_csv
from station.errors import ConfigError, DataError, DeviceTimeout
from station.models.trailer import CurvatureBoundError, JointAngleLimitError

SHORT = dict(commands=(("H", 0.2), ("C", 0.2)), duration_s=40.0, settle_s=10.0, compare=("M17",))


@pytest.mark.parametrize("odometry_fake", [{"checksum_rate": "0.05", "drop_rate": "0.05", "seed": "9"}],
                         indirect=True)
def test_procedure_calibrates_through_driver_and_fake(odometry):
    drv, fake = odometry
    journal = []
    res = run_trailer_calibration(drv, TrailerCalibrationPlan(**SHORT),
                                  record=lambda stream, cols: journal.append((stream, cols)))
    est = res.estimate
    assert est.method == "dynamic" and est.details["input"] == "commanded curvature as instrument"
    assert abs(est.L1_m - 1.25) < 5 * est.L1_sigma_m and abs(est.L2_m - 2.48) < 5 * est.L2_sigma_m
    assert est.L2_sigma_m < 0.03
    assert "M17" in res.comparisons
    assert list(res.steps) == [name for name, _ in calibration_steps(TrailerCalibrationPlan(**SHORT))]
    # every sample the driver decoded is in the record, once, in time order
    s = res.samples
    assert s["t"].size == drv.stats.samples - drv.queued \
        == sum(len(c["t"]) for name, c in journal if name == "odometry")
    setpoints = [c for name, c in journal if name == "setpoints"]
    assert len(setpoints) == 2 and np.isfinite(np.concatenate([c["t_applied"] for c in setpoints])).mean() > 0.8
    # the set points averaged over each sample's interval explain the measured curvature
    drive = s["phase"] == 1
    resid = s["kappa"][drive] - s["kappa_cmd"][drive]
    assert abs(resid.mean()) < 5 * 0.0173 / np.sqrt(resid.size) and resid.std() < 1.1 * 0.0173
    assert np.all(np.diff(s["t"]) > 0)
    assert set(np.unique(s["phase"])) <= {0, 1, 2} and set(np.unique(s["segment"])) == {0, 1}
    prof = s["phase"] == 1
    assert np.ptp(s["t"][prof & (s["segment"] == 0)]) >= 40.0 - 0.5
    # the set points streamed were applied (each either acknowledged or its reply lost on the line)
    cs = res.report["set_points"]
    assert cs["refused"] == 0 and cs["acked"] + cs["lost"] >= cs["sent"] - 2 and cs["acked"] > 0.8 * cs["sent"]
    assert fake.trailer.state().v_m_s == 0.0  # stopped at the end
    json.dumps(res.report)  # JSON-able


def test_plan_check_refuses_before_anything_moves(odometry):
    drv, fake = odometry
    with pytest.raises(CurvatureBoundError, match=r"plan.commands\[1\]"):
        run_trailer_calibration(drv, TrailerCalibrationPlan(commands=(("H", 0.2), ("C", 0.5))))
    with pytest.raises(JointAngleLimitError, match="45"):
        check_plan(TrailerCalibrationContext(drv, TrailerCalibrationPlan(commands=(("L", 0.22),))))
    assert fake.stats["commands"] == 0
    with pytest.raises(ConfigError, match="method"):
        TrailerCalibrationPlan(method="M30")
    with pytest.raises(ConfigError, match="kind"):
        TrailerCalibrationPlan(commands=(("X", 0.1),))
    with pytest.raises(ConfigError, match="v_m_s"):
        TrailerCalibrationPlan(v_m_s=-1.0)


class _FailingDriver:
    """Wraps the real driver; the line dies after ``n`` samples."""

    def __init__(self, drv, n):
        self._drv, self._n = drv, n

    def read_sample(self, timeout_s=None):
        self._n -= 1
        if self._n < 0:
            raise DeviceTimeout("line died (test)")
        return self._drv.read_sample(timeout_s)

    def __getattr__(self, name):
        return getattr(self._drv, name)


def test_a_failed_step_leaves_the_trailer_stopped(odometry):
    drv, fake = odometry
    with pytest.raises(DeviceTimeout, match="line died"):
        run_trailer_calibration(_FailingDriver(drv, 50), TrailerCalibrationPlan(**SHORT))
    assert fake.trailer.state().v_m_s == 0.0


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
