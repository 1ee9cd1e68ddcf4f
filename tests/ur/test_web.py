"""The operator's page shows the cobot like the other devices: its kind, state and the target it moves to."""

from __future__ import annotations

import time

from fakes.cells import demo_config
from station.config import config_from_dict
from station.store import RunStore
from app.web import pages
from app.web.live import RunHub
from app.web.state import station_state


CUBE = {"P1", "P2", "P3", "P4", "P5"}


def test_the_station_page_shows_the_urs_target_while_a_run_moves_it(tmp_path):
    d = demo_config(tmp_path, cycles=2, vap_cycles=2, rate_hz=100.0, robot="ur5e")
    d["devices"]["controller"]["url"] = "ur://10.0.0.9"  # the configured cobot (a dry run uses the fake cell)
    cfg = config_from_dict(d)
    hub = RunHub(cfg, tmp_path, time_scale=10.0)
    seen, passed = set(), set()
    try:
        run_id = hub.start("iso9283", "r1", seed=3)
        deadline = time.monotonic() + 90  # inside the test's timeout: a run that never gets there says why
        with RunStore(cfg.station.store_file(tmp_path)) as store:
            # the run's own progress is read every 2 ms (cheap: a short stop is not missed under load); the page's
            # state is built whenever the run moves to a target, and must show it. Two of the cube's poses (of
            # the 2 pose and 2 vAP cycles) are asked for; a run that ends stops the wait
            while time.monotonic() < deadline and (len(passed & CUBE) < 2 or not seen):
                live = hub.live(run_id)
                if live.finished:
                    break
                if live.operator.prompt is not None:
                    hub.answer(run_id, live.operator.prompt["id"], True)
                detail = live.detail
                if detail.startswith("->"):
                    passed.add(detail[2:].strip())
                    st = station_state(cfg, store, hub)
                    dev = {x["name"]: x for x in st["devices"]}
                    assert dev["controller"]["kind"] == "UR-style cobot (ur_rtde)"
                    assert dev["tracker"]["target"] == ""  # only the robot's controller moves to targets
                    if dev["controller"]["target"]:
                        seen.add(dev["controller"]["target"])
                        html = pages.station_page(st, "csrf", ["iso9283"])
                        assert f"<td class='target'>{dev['controller']['target']}</td>" in html
                time.sleep(0.002)
            steps = store.steps(run_id)
        hub.abort(run_id)
    finally:
        hub.close()
    # the cycles' targets went by, in the cube's names, and the page showed them
    assert len(passed & CUBE) >= 2 and seen, (
        seen, passed, live.exit_code, live.error, [(x.name, x.status, x.message) for x in steps])
