"""``station fakes serve ur``: endpoint JSON line first, then serves until interrupted."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time

from tests.ur.conftest import ROOT, run_probe


def test_station_fakes_serve_ur_prints_endpoint_and_serves_ur_rtde():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([ROOT, env.get("PYTHONPATH", "")])
    p = subprocess.Popen(
        [sys.executable, "-m", "station.cli", "fakes", "serve", "ur", "--robot", "ur5e", "--time-scale", "4",
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
