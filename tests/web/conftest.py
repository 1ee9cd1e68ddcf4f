"""A real `station serve` (uvicorn on a loopback port) over a small demo station, and a plain HTTP client."""

from __future__ import annotations

import http.client
import json
import time
from pathlib import Path
from urllib.parse import parse_qs, urlencode, urlsplit

import pytest

#: small runs: 2 pose + 2 vAP cycles at 40x real time finish in ~10 s
CYCLES, VAP_CYCLES, TIME_SCALE = 2, 2, 40.0

#: the longest a browser's page may take to show what the server holds, ms (Playwright's waits): generous, because
#: this host's disk can hold one commit of the server's store for tens of seconds under load (a soak saw 20-30 s);
#: a page that never shows it (a lost press, a dead live update) fails all the same, only later
PAGE_MS = 90_000


def demo_station_config(out: Path) -> Path:
    from fakes.cells import demo_config

    path = out / "station.json"
    path.write_text(json.dumps(demo_config(out, cycles=CYCLES, vap_cycles=VAP_CYCLES, rate_hz=100.0)))
    return path


class Client:
    """HTTP on the server's loopback port; POSTs carry the page's CSRF token unless told otherwise.

    Every request carries the access token of the printed URL as the page's cookie (``access=False``: none).
    """

    def __init__(self, url: str, *, access: bool = True) -> None:
        parts = urlsplit(url)
        self.host, self.port = parts.hostname, parts.port
        self.csrf = None
        token = parse_qs(parts.query).get("token", [None])[0]
        self.cookie = f"station_access_{self.port}={token}" if (token and access) else None

    def request(self, method: str, path: str, body: dict | None = None, headers: dict | None = None):
        con = http.client.HTTPConnection(self.host, self.port, timeout=PAGE_MS / 1000)  # a commit may stall
        try:
            data = urlencode(body).encode() if body is not None else None
            hdrs = {"Content-Type": "application/x-www-form-urlencoded"} if data is not None else {}
            if self.cookie:
                hdrs["Cookie"] = self.cookie
            con.request(method, path, body=data, headers={**hdrs, **(headers or {})})
            resp = con.getresponse()
            return resp.status, dict(resp.getheaders()), resp.read().decode()
        finally:
            con.close()

    def get(self, path: str):
        return self.request("GET", path)

    def page_csrf(self) -> str:
        status, _, html = self.get("/")
        assert status == 200
        marker = "name='csrf-token' content='"
        return html.split(marker, 1)[1].split("'", 1)[0]

    def post(self, path: str, fields: dict | None = None, *, csrf: bool = True, headers: dict | None = None):
        body = dict(fields or {})
        if csrf:
            self.csrf = self.csrf or self.page_csrf()
            body["csrf"] = self.csrf
        return self.request("POST", path, body, headers)

    def state(self, run_id: str) -> dict:
        status, _, text = self.get(f"/runs/{run_id}/state")
        assert status == 200, text
        return json.loads(text)

    def start(self, seed: int) -> str:
        status, headers, text = self.post("/runs", {"procedure": "iso9283", "robot": "r1", "seed": seed})
        assert status == 303, text
        return headers["location"].rsplit("/", 1)[1]

    def wait(self, run_id: str, cond, timeout_s: float = 30.0, what: str = "") -> dict:
        t_end = time.monotonic() + timeout_s
        while True:
            st = self.state(run_id)
            if cond(st):
                return st
            if time.monotonic() > t_end:
                raise AssertionError(f"timed out waiting for {what}: status {st['status']}, "
                                     f"current {st['current']}, error {st['error']}")
            time.sleep(0.05)

    def answer_prompts(self, run_id: str, n: int, answer: str = "yes") -> list[str]:
        asked = []
        for _ in range(n):
            st = self.wait(run_id, lambda s: s["prompt"] is not None, 20, "a prompt")
            asked.append(st["prompt"]["message"])
            status, _, text = self.post(f"/runs/{run_id}/answer", {"prompt_id": st["prompt"]["id"], "answer": answer})
            assert status == 303, text
        return asked

    def first_event(self, path: str, timeout_s: float = 5.0) -> tuple[str, str]:
        """The first server-sent event on ``path``: (event, data)."""
        con = http.client.HTTPConnection(self.host, self.port, timeout=timeout_s)
        try:
            con.request("GET", path, headers={"Cookie": self.cookie} if self.cookie else {})
            resp = con.getresponse()
            assert resp.status == 200 and resp.getheader("content-type").startswith("text/event-stream")
            event, data = "", []
            while True:
                line = resp.fp.readline().decode().rstrip("\n")
                if line.startswith("event: "):
                    event = line[7:]
                elif line.startswith("data: "):
                    data.append(line[6:])
                elif line == "" and data:
                    return event, "\n".join(data)
        finally:
            con.close()


@pytest.fixture
def seed(test_seed) -> int:
    """A fresh simulated cell every run (the test's seed: printed with a failing test's output)."""
    s = test_seed
    print(f"cell seed {s}")
    return s


@pytest.fixture
def served(tmp_path, request):
    """`station serve` on 127.0.0.1, any free port, over the small demo station in ``tmp_path``.

    Its runs go at ``TIME_SCALE`` (slow enough to pause, abort or watch one); a test that only waits
    for the end marks itself ``@pytest.mark.pace(LOCKSTEP)`` (the same run, as fast as it goes).
    """
    from station.config import load_config
    from app.web.server import WebServer

    marker = request.node.get_closest_marker("pace")
    pace = marker.args[0] if marker else TIME_SCALE
    cfg_path = demo_station_config(tmp_path)
    server = WebServer(load_config(cfg_path), tmp_path, host="127.0.0.1", port=0, time_scale=pace).start()
    server.config_path = cfg_path
    try:
        yield server
    finally:
        server.close()


@pytest.fixture
def client(served) -> Client:
    return Client(served.url)
