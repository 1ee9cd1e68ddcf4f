"""Benchmark: the operator's page's CPU cost while the tracker streams at 1 kHz.

Run by hand: ``.venv/bin/python bench/bench_web.py [--rate HZ] [--window S] [--watchers 0,1,4]``.

``station serve`` runs in this process over the demo station with the tracker
at ``--rate`` (1000 Hz) in real time (time scale 1): a run is started and its
prompts answered over HTTP, then, while the pose cycles stream, for each count
of watchers (pages following the run's event stream) the CPU time of the
server's threads (uvicorn's event loop and the worker threads that read the
store for the snapshots) is taken from ``/proc`` over ``--window`` seconds,
beside the CPU of everything else in the process (the run and the fake cell)
and the events each watcher received per second. The run is aborted at the
end. No assertion; the figures are printed.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path
from urllib.parse import urlencode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fakes.cells import demo_config  # noqa: E402
from station.config import config_from_dict  # noqa: E402
from app.web.server import WebServer  # noqa: E402

TICK = os.sysconf("SC_CLK_TCK")


def thread_cpu_s() -> dict[int, float]:
    """CPU seconds (user + system) of every thread of this process, by native id."""
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            fields = Path(f"/proc/self/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        out[int(tid)] = (int(fields[11]) + int(fields[12])) / TICK
    return out


def server_tids() -> set[int]:
    """uvicorn's thread and asyncio's worker threads (the snapshots are read there)."""
    return {t.native_id for t in threading.enumerate()
            if t.name == "web server" or t.name.startswith("asyncio")}


class Http:
    def __init__(self, port: int, cookie: str = "") -> None:
        self.port = port
        self.csrf = None
        self.cookie = cookie  # the page's access cookie (every request carries the token)

    def call(self, method: str, path: str, fields: dict | None = None):
        con = http.client.HTTPConnection("127.0.0.1", self.port, timeout=10)
        body = urlencode({**(fields or {}), "csrf": self.csrf}).encode() if method == "POST" else None
        con.request(method, path, body=body, headers={"Content-Type": "application/x-www-form-urlencoded",
                                                      "Cookie": self.cookie})
        r = con.getresponse()
        data = (r.status, dict(r.getheaders()), r.read().decode())
        con.close()
        return data


def watch(port: int, run_id: str, stop: threading.Event, counts: list, k: int, cookie: str = "") -> None:
    con = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    con.request("GET", f"/runs/{run_id}/events", headers={"Cookie": cookie})
    resp = con.getresponse()
    while not stop.is_set():
        line = resp.fp.readline()
        if not line:
            break
        if line.startswith(b"event: state"):
            counts[k] += 1
    con.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=1000.0, help="tracker rate, Hz")
    ap.add_argument("--window", type=float, default=10.0, help="seconds measured per watcher count")
    ap.add_argument("--watchers", default="0,1,4", help="watcher counts, comma-separated")
    args = ap.parse_args()
    watcher_counts = [int(x) for x in args.watchers.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        cycles = 2 + int(len(watcher_counts) * args.window / 12) + 2
        cfg = config_from_dict(demo_config(out, cycles=cycles, vap_cycles=2, rate_hz=args.rate), "bench config")
        server = WebServer(cfg, out, port=0, time_scale=1.0).start()
        try:
            cookie = f"{server.guard.cookie_name}={server.guard.access_token}"
            h = Http(server.port, cookie)
            h.csrf = server.guard.csrf_token
            status, hdrs, _ = h.call("POST", "/runs", {"procedure": "iso9283", "robot": "r1", "seed": 1})
            run_id = hdrs["location"].rsplit("/", 1)[1]

            def state():
                return json.loads(h.call("GET", f"/runs/{run_id}/state")[2])

            answered = 0
            while True:
                st = state()
                if st["prompt"]:
                    h.call("POST", f"/runs/{run_id}/answer", {"prompt_id": st["prompt"]["id"], "answer": "yes"})
                    answered += 1
                if st["current"] and st["current"]["name"].startswith("pose cycle"):
                    break
                if st["status"] not in ("running", "starting"):
                    raise SystemExit(f"run stopped before its cycles: {st}")
                time.sleep(0.1)
            print(f"run {run_id}: tracker {args.rate:g} Hz in real time, pose cycles streaming; "
                  f"{os.cpu_count()} CPUs")
            print(f"{'watchers':>8} {'server CPU %':>13} {'rest CPU %':>11} {'events/s per watcher':>21}")
            for n in watcher_counts:
                stop = threading.Event()
                counts = [0] * n
                threads = [threading.Thread(target=watch, args=(server.port, run_id, stop, counts, k, cookie))
                           for k in range(n)]
                for t in threads:
                    t.start()
                time.sleep(1.0)  # let the streams open
                c0 = thread_cpu_s()
                counts[:] = [0] * n
                t0 = time.monotonic()
                time.sleep(args.window)
                c1 = thread_cpu_s()
                wall = time.monotonic() - t0
                rates = [c / wall for c in counts]
                mine = server_tids()
                d = {tid: c1[tid] - c0.get(tid, 0.0) for tid in c1}
                srv = sum(v for tid, v in d.items() if tid in mine)
                rest = sum(v for tid, v in d.items() if tid not in mine)
                st = state()
                rate_txt = f"{min(rates):.1f}..{max(rates):.1f}" if rates else "-"
                print(f"{n:>8} {100 * srv / wall:>13.1f} {100 * rest / wall:>11.1f} {rate_txt:>21}"
                      f"   (step {st['current']['name'] if st['current'] else '-'})")
                stop.set()
                for t in threads:
                    t.join(30)
            h.call("POST", f"/runs/{run_id}/abort")
        finally:
            server.close()


if __name__ == "__main__":
    main()
