"""The run page's instrument panel per procedure, from what the store holds (the tracker's own view has
tests/web/test_tracker_view.py)."""

import numpy as np

from app.web.instrument_view import ODOMETRY_WINDOW_S, instrument_view
from app.web.state import run_state
from station.store import RunStore


def _run(store, run_id, procedure, params):
    store.create_run(run_id, procedure, model="industrial-3100", serial="SN-1", overhaul_state="after",
                     config={}, params=params)
    return store.step_started(run_id, 0, "measure")


def test_an_arm_calibration_by_scanner_says_poses_measured_and_corners_not_found(rng, tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    planned = int(rng.integers(8, 20))
    params = {"instrument": "scanner", "q_deg": [[0.0] * 6] * planned}
    att = _run(store, "a1", "arm-calibration", params)
    n = int(rng.integers(3, planned))
    missed = sorted(rng.choice(n, size=2, replace=False).tolist())
    for i in range(n):
        found = 0.0 if i in missed else 1.0
        xyz = rng.normal(0, 300, 3) if found else np.full(3, np.nan)
        store.append_samples("a1", "features", 0, att, {
            "pose": np.array([i], float), "x": xyz[:1], "y": xyz[1:2], "z": xyz[2:3],
            "sigma_x": np.array([0.001]), "sigma_y": np.array([0.001]), "sigma_z": np.array([0.001]),
            "points": np.array([1e4]), "found": np.array([found])})
    v = instrument_view(store, "a1", "arm-calibration", params)
    assert v["kind"] == "scanner" and v["measured"] == n and v["planned"] == planned
    assert v["not_found"] == [m + 1 for m in missed]
    assert v["last"]["pose"] == n and (v["last"]["x"] is None) == ((n - 1) in missed)
    # the page's state carries it while the run goes, and after
    st = run_state(store, "a1", None)
    assert st["instrument"] == v
    store.close()


def test_an_arm_calibration_by_tracker_counts_its_points(rng, tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    params = {"instrument": "tracker", "q_deg": [[0.0] * 6] * 12}
    att = _run(store, "a2", "arm-calibration", params)
    n = int(rng.integers(1, 12))
    pts = rng.normal(0, 1000, (n, 3))
    for i in range(n):
        store.append_samples("a2", "points", 0, att, {"pose": np.array([i], float), "x": pts[i, :1],
                                                      "y": pts[i, 1:2], "z": pts[i, 2:]})
    v = instrument_view(store, "a2", "arm-calibration", params)
    assert v["kind"] == "tracker" and v["measured"] == n and v["planned"] == 12 and v["not_found"] == []
    assert np.allclose([v["last"][c] for c in "xyz"], pts[-1])
    store.close()


def test_a_trailer_run_shows_the_last_seconds_of_its_odometry(rng, tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    att = _run(store, "t1", "trailer", {})
    assert instrument_view(store, "t1", "trailer", {})["received"] == 0  # nothing yet: said, not an error
    rate = 10.0
    n = int(rng.integers(400, 1200))
    t = 100.0 + np.arange(n) / rate
    psi = np.radians(rng.uniform(-20, 20)) * np.sin(0.1 * t)
    for a in range(0, n, 50):
        sl = slice(a, a + 50)
        store.append_samples("t1", "odometry", 0, att, {"t": t[sl], "v": np.full(t[sl].size, 1.2),
                                                        "kappa": 0.1 * np.sin(0.1 * t[sl]), "psi": psi[sl]})
    v = instrument_view(store, "t1", "trailer", {})
    assert v["kind"] == "odometry" and v["received"] == n
    assert v["t"][-1] == 0.0 and v["t"][0] >= -ODOMETRY_WINDOW_S and len(v["t"]) <= 300
    assert all(np.diff(v["t"]) > 0)
    # the first shown sample is the stream's (the view's times are rounded to 1 ms: the nearest one)
    k = int(np.argmin(np.abs((t - t[-1]) - v["t"][0])))
    assert abs(v["psi_deg"][0] - float(np.degrees(psi[k]))) <= 5e-4 + 1e-12  # shown to 1 mdeg
    store.close()


def test_an_iso_run_keeps_the_tracker_s_own_view(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    _run(store, "i1", "iso9283", {})
    assert instrument_view(store, "i1", "iso9283", {}) is None
    store.close()


def test_a_run_this_server_drives_is_done_on_the_page_only_with_its_verdict(rng, tmp_path):
    """The runner marks the run done after its last step; the front door stores the verdict after that. While
    this server's thread is still at it the page says running, so that "done" always comes with its verdict."""
    import threading

    from app.web.live import LiveRun, WebOperator
    from station.runner import RunControl

    store = RunStore(tmp_path / "v.sqlite")
    _run(store, "v1", "iso9283", {})
    control = RunControl()
    live = LiveRun("v1", control, WebOperator(control))
    deciding = threading.Event()
    live.thread = threading.Thread(target=deciding.wait, args=(30.0,), daemon=True)
    live.thread.start()
    store.set_run_status("v1", "done")  # the last step is done; the verdict is not stored yet
    st = run_state(store, "v1", live)
    assert st["status"] == "running" and st["verdict"] is None
    verdict = str(rng.choice(["PASS", "FAIL"]))
    store.put_result("v1", "verdict", {"verdict": verdict, "reasons": ["drawn"], "conformant": True, "exit_code": 0})
    deciding.set()
    live.thread.join(5.0)
    st = run_state(store, "v1", live)
    assert st["status"] == "done" and st["verdict"] == verdict.lower() and st["reasons"] == ["drawn"]
    assert run_state(store, "v1", None)["status"] == "done"  # a run no thread of this server drives: the store's
    store.close()
