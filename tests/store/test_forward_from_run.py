"""A run with a central store configured forwards itself: local first, the centre gets everything after."""

import io

import numpy as np

from fakes.cells import demo_config
from app.assemble import RunRequest, run_procedure
from station.config import StationConfig
from station.store import RunStore
from station.store.forward import forward_status
from tests.store.helpers import same_samples
from tests.pace import LOCKSTEP


def _cfg(tmp_path, url):
    d = demo_config(tmp_path, cycles=3, vap_cycles=3, rate_hz=100)
    d["station"]["store_url"] = url
    d["arm_calibration"] = {"train_poses": 15, "test_poses": 5, "poses_per_step": 5}
    return StationConfig.model_validate(d)


def test_a_run_reaches_the_central_store_by_itself(rng, tmp_path, pg_url):
    cfg = _cfg(tmp_path, pg_url)
    out = io.StringIO()
    code = run_procedure(RunRequest(cfg, "arm-calibration", stdout=out, run_id="f1", yes=True, quiet=True, time_scale=LOCKSTEP,
                                    seed=int(rng.integers(2**31)), config_dir=tmp_path,
                                    plan_overrides={"selection_seed": int(rng.integers(2**31))}))
    assert code.status == "done"
    # the centre holds the whole run, its verdict stored after the run included, and the line says so
    assert f"central store: holds run f1 complete" in out.getvalue() and code.forwarding in out.getvalue()
    assert out.getvalue().splitlines()[0].startswith(f"{code.verdict}: run f1")
    with RunStore(cfg.station.store_file(tmp_path)) as local, RunStore(pg_url) as central:
        assert central.run("f1").status == "done" and central.run("f1").station == "demo cell"
        same_samples(local, central, "f1")
        a, b = local.samples("f1", "points"), central.samples("f1", "points")
        assert a["pose"].size == 20 and set(a) == set(b)
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])
        assert forward_status(local)["f1"]["in_centre"] == "complete"
        assert central.result("f1", "verdict") == local.result("f1", "verdict")
        assert central.result("f1", "verdict")["verdict"] == str(code.verdict)


def test_an_unreachable_centre_costs_the_run_nothing(rng, tmp_path):
    cfg = _cfg(tmp_path, "postgresql://station@127.0.0.1:1/plant")
    buf = io.StringIO()
    code = run_procedure(RunRequest(cfg, "arm-calibration", stdout=buf, run_id="f2", yes=True, quiet=True, time_scale=LOCKSTEP,
                                    seed=int(rng.integers(2**31)), config_dir=tmp_path,
                                    plan_overrides={"selection_seed": int(rng.integers(2**31))}))
    assert code.status == "done"
    out = buf.getvalue()
    assert "central store not reached" in out and "station store push" in out
    with RunStore(cfg.station.store_file(tmp_path)) as local:
        assert local.run("f2").status == "done" and local.samples("f2", "points")["pose"].size == 20
