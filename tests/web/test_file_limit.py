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



def _close(socks, proc) -> None:
    """Close the slow clients, then let the served child end (killed, and the test failed, if it will not)."""
    for s in socks:
        s.close()
    proc.stdin.close()
    try:
        proc.wait(60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise

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
            _close(socks, proc)
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


def test_a_lowered_connection_cap_is_raised_back_in_steps_while_descriptors_are_free(rng):
    """``relax_cap``: after a full table lowered the cap, it goes back up at most every CAP_LOOK_S, by at most
    a quarter of itself and by no more than the descriptors free beyond the headroom; it stays down while
    none are; back at max_connections() it is no longer lowered. Free counts drawn."""
    from types import SimpleNamespace

    from app.web.server import CAP_LOOK_S, CAP_RAISE_FRACTION, FD_HEADROOM, MIN_CONNECTIONS, max_connections, \
        relax_cap

    top = max_connections()
    st = SimpleNamespace(connection_cap=MIN_CONNECTIONS, cap_looked_at=0.0)
    t = 0.0
    assert relax_cap(st, now=t + 0.5 * CAP_LOOK_S, free=lambda: 10**6) == MIN_CONNECTIONS  # too soon
    assert relax_cap(st, now=t + CAP_LOOK_S, free=lambda: FD_HEADROOM) == MIN_CONNECTIONS  # none beyond headroom
    assert relax_cap(st, now=t + 2 * CAP_LOOK_S, free=lambda: None) == MIN_CONNECTIONS  # cannot tell: stays
    t += 2 * CAP_LOOK_S
    caps = [MIN_CONNECTIONS]
    while getattr(st, "connection_cap", None) is not None:
        t += CAP_LOOK_S * float(rng.uniform(1.0, 2.0))
        free = FD_HEADROOM + int(rng.integers(1, 200))
        cap = relax_cap(st, now=t, free=lambda: free)
        step = cap - caps[-1]
        assert 1 <= step <= min(free - FD_HEADROOM, max(1, int(caps[-1] * CAP_RAISE_FRACTION))), (caps[-1], cap, free)
        caps.append(cap)
        assert len(caps) < 10_000
    assert caps[-1] == top and relax_cap(st, now=t + 10 * CAP_LOOK_S, free=lambda: 0) == top


#: the child of the file-limit tests, answering on stdin: ``release`` closes the descriptors it held (the
#: station's other files), ``cap`` prints the connection cap now (-1: not lowered)
CHILD_CAP = CHILD.replace("sys.stdin.read()\n", """for line in sys.stdin:
    if line.strip() == "release":
        while held:
            os.close(held.pop())
        print("released", flush=True)
    elif line.strip() == "cap":
        print(getattr(server.server.server_state, "connection_cap", None) or -1, flush=True)
""")


def test_the_page_serves_as_many_connections_again_once_descriptors_are_free(tmp_path):
    """A flood fills the file table and lowers the connection cap; once the flood and the station's other
    files are closed, the token holder's next requests (a new connection each) raise it back, a step per
    CAP_LOOK_S (1 s; lowered here to 0.05 s in the child), until it is no longer lowered."""
    soft, hard, free = 200, 256, 40
    assert "for line in sys.stdin" in CHILD_CAP
    child = CHILD_CAP.replace("from app.web.server import WebServer",
                              "import app.web.server as s; s.CAP_LOOK_S = 0.05\nfrom app.web.server import WebServer")
    socks: list[socket.socket] = []
    log_path = tmp_path / "server.log"
    with open(log_path, "w") as log:
        proc = subprocess.Popen([sys.executable, "-c", child, str(demo_station_config(tmp_path)), str(soft),
                                 str(hard), str(free)], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=log, text=True)

        def ask(what: str) -> str:
            proc.stdin.write(what + "\n")
            proc.stdin.flush()
            return proc.stdout.readline().strip()

        try:
            info = json.loads(proc.stdout.readline())
            token_holder = Client(info["url"])
            assert token_holder.get("/")[0] == 200
            assert ask("cap") == "-1"
            socks += _slow_clients(info["port"], 300)
            assert token_holder.get("/")[0] == 200
            lowered = int(ask("cap"))
            assert lowered > 0, log_path.read_text()[-2000:]  # the table was full: the cap went down
            for s in socks:
                s.close()
            socks.clear()
            assert ask("release") == "released"
            caps = [lowered]
            for _ in range(2000):  # bounded: each request is a new connection, each may raise the cap a step
                assert token_holder.get("/robots/DEMO-0001")[0] == 200
                cap = int(ask("cap"))
                if cap != caps[-1]:
                    caps.append(cap)
                if cap == -1:
                    break
            print("connection caps", caps)
            assert caps[-1] == -1, caps  # no longer lowered
            steps = caps[:-1]
            assert len(steps) >= 3 and steps == sorted(steps), caps  # in steps, up
            assert all(b - a <= max(1, a // 4) for a, b in zip(steps, steps[1:])), caps
        finally:
            _close(socks, proc)
