"""The page with its file table full (issue 47 item 6): a flood of slow clients on a process near its file
limit neither fills the log nor locks the token holder out.

The server runs in a child process whose limit is lowered there (``resource.setrlimit``) and whose
other files (a busy station's store, logs, devices) leave it only a few descriptors for connections.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

from app.web.listener import raise_file_limit
from tests.web.conftest import Client, demo_station_config

ROOT = Path(__file__).resolve().parents[2]

#: argv: station config, soft and hard file limits, descriptors left free once the server is up
CHILD = r"""
import json, os, resource, sys
from pathlib import Path
cfg, soft, hard, free = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
from station.config import load_config
from app.web.server import WebServer
server = WebServer(load_config(cfg), cfg.parent, port=0, time_scale=40.0).start()
held = []
while len(os.listdir("/proc/self/fd")) < hard - free:
    held.append(os.open(os.devnull, os.O_RDONLY))
print(json.dumps({"url": server.url, "port": server.port,
                  "soft": resource.getrlimit(resource.RLIMIT_NOFILE)[0]}), flush=True)
sys.stdin.read()
server.close()
"""


def _slow_clients(port: int, count: int) -> list[socket.socket]:
    """``count`` connections that send half a request head and wait (those the server refuses are left out)."""
    socks = []
    for _ in range(count):
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=10)
            s.sendall(b"GET / HTTP/1.1\r\n")
        except OSError:
            continue
        socks.append(s)
    return socks


def test_the_token_holder_is_served_and_the_log_stays_small_with_the_file_table_full(tmp_path):
    """1,300 slow clients at a limit of 1024 wrote 711,000 lines of EMFILE tracebacks in 25 s and kept the
    token holder waiting 7.2 s; here 40 free descriptors and 500 slow clients."""
    soft, hard, free = 200, 256, 40
    log_path = tmp_path / "server.log"
    socks: list[socket.socket] = []
    with open(log_path, "w") as log:
        proc = subprocess.Popen([sys.executable, "-c", CHILD, str(demo_station_config(tmp_path)), str(soft),
                                 str(hard), str(free)], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=log, text=True)
        try:
            line = proc.stdout.readline()
            assert line, log_path.read_text()[-2000:]
            info = json.loads(line)
            assert info["soft"] == hard  # raised to the hard limit at start
            token_holder = Client(info["url"])
            assert token_holder.get("/")[0] == 200  # the first page imports the procedures: before the flood
            socks +=  _slow_clients(info["port"], 300)
            assert token_holder.get("/")[0] == 200
            socks += _slow_clients(info["port"], 200)
            for _ in range(3):
                assert token_holder.get("/")[0] == 200
        finally:
            for s in socks:
                s.close()
            proc.stdin.close()
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                raise
    text = log_path.read_text()
    assert "accept() refused" in text and "EMFILE" in text, text[-2000:]  # the table was full indeed
    assert "Traceback" not in text, text[:3000]
    assert len(text.splitlines()) <= 10, text[:3000]


def test_the_soft_file_limit_is_raised_to_the_hard_one_where_allowed():
    import resource

    before = resource.getrlimit(resource.RLIMIT_NOFILE)
    try:
        hard = before[1]
        lower = min(before[0], 512) if hard == resource.RLIM_INFINITY else min(before[0], hard // 2)
        resource.setrlimit(resource.RLIMIT_NOFILE, (lower, hard))
        raised = raise_file_limit()
        assert raised > lower and resource.getrlimit(resource.RLIMIT_NOFILE)[0] == raised
        if hard != resource.RLIM_INFINITY:
            assert raised == hard
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, before)
