"""Pages read from the store: the station's runs with verdicts, a robot's history, a run left by a dead process."""

import re

import numpy as np


def _stored_run(store, run_id, serial, state, rp_by_pose, limit=0.5, status="done"):
    store.create_run(run_id, "iso9283", model="industrial-3100", serial=serial, overhaul_state=state,
                     config={}, params={})
    store.put_characteristics(run_id, [{"pose": p, "name": "RP_mm", "value": v, "unit": "mm", "limit": limit,
                                        "passed": v <= limit} for p, v in rp_by_pose.items()])
    if status != "running":
        store.set_run_status(run_id, status)


def test_robot_history_shows_the_worst_pose_of_each_finished_run(rng, served, client):
    worst = []
    for k in range(4):
        rp = {f"P{i}": float(rng.uniform(0.01, 0.8)) for i in range(1, 6)}
        _stored_run(served.store, f"run-{k}", "SN-7", "after" if k % 2 else "before", rp)
        worst.append(max(rp.values()))
    _stored_run(served.store, "run-other", "SN-8", "after", {"P1": 9.0})  # another robot: not shown
    _stored_run(served.store, "run-live", "SN-7", "after", {"P1": 7.0}, status="running")  # unfinished: not shown
    status, _, html = client.get("/robots/SN-7")
    assert status == 200 and "RP_mm" in html
    assert html.count("<circle") == 4
    shown = [float(x) for x in re.findall(r"<tr><td>run-\d</td><td>\w+</td><td>([0-9.e-]+)</td>", html)]
    assert np.allclose(shown, worst, rtol=1e-3)
    # the station page lists every run with the verdict of its characteristics
    status, _, page = client.get("/")
    for k, w in enumerate(worst):
        verdict = "pass" if w <= 0.5 else "fail"
        assert re.search(rf"run-{k}</a>.*?<td class='{verdict}'>{verdict}</td>", page), (k, w)
    assert "run-other" in page and "9.0" not in page


def test_a_run_left_running_by_a_dead_process_is_not_resumed_from_the_page(served, client):
    _stored_run(served.store, "orphan", "SN-9", "after", {"P1": 0.1}, status="running")
    st = client.state("orphan")
    assert st["status"] == "running" and not st["live"] and st["prompt"] is None
    status, _, text = client.post("/runs/orphan/resume")
    assert status == 409 and "station run --resume" in text
    assert served.hub.active() is None
