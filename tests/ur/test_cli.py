"""``station fakes serve ur``: endpoint JSON line first, then serves until interrupted."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time

import pytest

from tests.ur.conftest import ROOT, run_probe


def test_station_fakes_serve_ur_prints_endpoint_and_serves_ur_rtde():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([ROOT, env.get("PYTHONPATH", "")])
    p = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "fakes", "serve", "ur", "--robot", "ur5e", "--time-scale", "4",
         "--fault", "dashboard_refuse=shutdown"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
    )
    try:
        deadline = time.monotonic() + 30
        line = ""
        while not line and time.monotonic() < deadline:
            r, _, _ = select.select([p.stdout], [], [], 0.2)
            if r:
                line = p.stdout.readline()
            assert p.poll() is None, p.stderr.read()
        endpoint = json.loads(line)
        assert endpoint["rtde"] == 30004 and endpoint["dashboard"] == 29999 and endpoint["script"] == 30003
        assert endpoint["host"].startswith("127.")
        report = run_probe(endpoint["host"], 500.0, 0.2)
        assert "error" not in report and len(report["rows"]) > 5
        assert report["robot_mode"] == 7
    finally:
        p.send_signal(signal.SIGINT)
        try:
            rc = p.wait(15)
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert rc == 0


def _serve(*extra):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([ROOT, env.get("PYTHONPATH", "")])
    p = subprocess.Popen([sys.executable, "-m", "app.cli", "fakes", "serve", "ur", *extra],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    deadline = time.monotonic() + 30
    line = ""
    while not line and time.monotonic() < deadline:
        r, _, _ = select.select([p.stdout], [], [], 0.2)
        if r:
            line = p.stdout.readline()
        assert p.poll() is None, p.stderr.read()
    return p, json.loads(line)


def _stop(p):
    p.send_signal(signal.SIGINT)
    try:
        return p.wait(15)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


def test_the_ur_fake_with_no_options_is_a_ur_that_ur_rtde_moves(rng):
    """Default recipe at 500 Hz, then a ScriptClient movej to an ordinary UR joint target, read back."""
    import numpy as np
    import script_client

    p, endpoint = _serve()
    try:
        host = endpoint["host"]
        before = run_probe(host, 500.0, 0.3, min_rows=20)  # on a busy host: on until a consecutive pair
        assert "error" not in before and before["robot_mode"] == 7 and before["runtime_state"] == 1
        rows = np.array(before["rows"])
        # a UR5e's TCP is within its 850 mm reach of the base (an industrial arm's is metres away)
        assert np.linalg.norm(rows[-1, 7:10]) < 0.9
        # 500 Hz: sample k is the state at t0 + k / 500 s of the device clock. The probe polls
        # ur_rtde's latest sample and misses some on a busy machine, so the steps it sees are whole
        # multiples of 2 ms, and the shortest one is 2 ms (a 250 Hz stream would have none)
        k = np.diff(rows[:, 0]) * 500.0
        assert np.all(np.round(k) >= 1) and np.abs(k - np.round(k)).max() < 1e-3, k
        assert np.round(k).min() == 1
        home = np.array([0.0, -1.57, 1.57, -1.57, -1.57, 0.0])
        target = home + rng.uniform(-0.3, 0.3, 6)
        sc = script_client.ScriptClient(host, 5, 11)
        sc.connect()
        # a controller runs a script line when its line end arrives
        sc.sendScriptCommand("movej([" + ",".join(f"{v:.6f}" for v in target) + "], a=1.4, v=1.05)\n")
        deadline = time.monotonic() + 20
        q = None
        while time.monotonic() < deadline:
            after = run_probe(host, 500.0, 0.1)
            q = np.array(after["rows"][-1][1:7])
            if np.max(np.abs(q - target)) < 1e-3 and after["runtime_state"] == 1:
                break
            time.sleep(0.3)
        assert q is not None and np.max(np.abs(q - target)) < 1e-3, (q, target)
        # a target outside a UR's joint limits (+-2 pi) is refused: the program stops, nothing moves
        bad = target.copy()
        bad[int(rng.integers(6))] = float(rng.choice([-1.0, 1.0])) * rng.uniform(6.4, 9.0)
        sc.sendScriptCommand("movej([" + ",".join(f"{v:.6f}" for v in bad) + "], a=1.4, v=1.05)\n")
        time.sleep(0.5)
        after = run_probe(host, 500.0, 0.2)
        assert after["runtime_state"] == 1 and after["safety_mode"] == 1
        assert np.max(np.abs(np.array(after["rows"][-1][1:7]) - target)) < 1e-3  # still at the last target
        sc.disconnect()
    finally:
        assert _stop(p) == 0
