"""`station fakes serve tracker-emscon|tracker-geocom`: endpoint first, real protocol behind it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from drivers.tracker_url import open_tracker


def _serve(*args):
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "fakes", "serve", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=os.path.dirname(os.path.dirname(os.path.dirname(__file__))))
    line = proc.stdout.readline()
    if not line:
        proc.kill()
        raise AssertionError(f"no endpoint line; stderr: {proc.communicate(timeout=10)[1]}")
    return proc, json.loads(line)


def _stop(proc):
    proc.send_signal(signal.SIGINT)
    try:
        assert proc.wait(timeout=15) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("name, url", [
    ("tracker-emscon", "emscon://{host}:{port}"),
    ("tracker-geocom", "geocom://{device}"),
])
def test_serve_prints_the_endpoint_and_serves(name, url):
    proc, endpoint = _serve(name, "--time-scale", "20", "--fault", "slow_reply_s=0.01")
    try:
        if name == "tracker-emscon":
            assert endpoint["host"] == "127.0.0.1" and endpoint["port"] > 0
        with open_tracker(url.format(**endpoint)) as tracker:
            tracker.connect(timeout_s=20)
            m = tracker.measure_stationary(0.05)
            assert np.all(np.isfinite(m.xyz_mm)) and np.linalg.norm(m.xyz_mm) > 100
    finally:
        _stop(proc)


def test_serve_refuses_an_unknown_fault():
    proc = subprocess.run([sys.executable, "-m", "app.cli", "fakes", "serve", "tracker-emscon",
                           "--fault", "bogus=1"], capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and "unknown fault 'bogus'" in proc.stderr
