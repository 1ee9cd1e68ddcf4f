"""The page as a network service (issue 24, items 9-12): where it listens, what it reads before it checks,
how long it waits for a slow client, who may use it on loopback."""

from __future__ import annotations

import ipaddress
import socket
import time

import pytest

from app.cli import main
from station.errors import ConfigError
from app.web import server as web_server
from app.web.security import listen_problem
from tests.web.conftest import Client, TIME_SCALE, demo_station_config


# -- item 9: the wildcard decided by the bound address ----------------------------------------------------------
WILDCARD = str(ipaddress.IPv4Address(0))  # built, not spelled


@pytest.mark.parametrize("host", ["0", "0.0", "000.000.000.000", "0x0", WILDCARD, "::", f"::ffff:{WILDCARD}", "",
                                  "*"])
def test_every_spelling_of_the_wildcard_is_refused(host, tmp_path, capsys):
    assert listen_problem(host)
    cfg = demo_station_config(tmp_path)
    assert main(["serve", "--config", str(cfg), "--host", host, "--port", "0"]) == 2
    assert "every interface" in capsys.readouterr().err


def test_the_server_itself_refuses_a_wildcard_bind(tmp_path):
    from station.config import load_config

    cfg = load_config(demo_station_config(tmp_path))
    for host in ("0", "0x0"):
        with pytest.raises(ConfigError, match="every interface"):
            web_server.WebServer(cfg, tmp_path, host=host, port=0)


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.0.5", "::1", "localhost"])
def test_loopback_addresses_may_listen(host):
    assert listen_problem(host) is None


def test_a_loopback_address_answers_on_the_url_it_printed(tmp_path):
    from station.config import load_config

    cfg = load_config(demo_station_config(tmp_path))
    with web_server.WebServer(cfg, tmp_path, host="127.0.0.5", port=0, time_scale=TIME_SCALE).start() as srv:
        assert srv.url.startswith(f"http://127.0.0.5:{srv.port}/?token=")
        client = Client(srv.url)
        assert client.get("/")[0] == 200
        # and a foreign Host is still refused
        assert client.request("GET", "/", headers={"Host": f"rebind.example:{srv.port}"})[0] == 421


# -- item 10: headers checked before a bounded body is read ---------------------------------------------------
def _raw(served, head: bytes, body: bytes = b"", timeout: float = 10.0) -> bytes:
    """Send a request head (and part of a body), return what the server answers (it may not wait for more)."""
    with socket.create_connection(("127.0.0.1", served.port), timeout=timeout) as s:
        s.sendall(head + body)
        out = b""
        while b"\r\n\r\n" not in out:
            chunk = s.recv(65536)
            if not chunk:
                break
            out += chunk
        return out


def _post_head(served, length: int, *, cookie: bool, origin: str | None = None, chunked: bool = False) -> bytes:
    lines = [b"POST /runs HTTP/1.1", b"Host: 127.0.0.1:%d" % served.port,
             b"Content-Type: application/x-www-form-urlencoded"]
    lines.append(b"Transfer-Encoding: chunked" if chunked else b"Content-Length: %d" % length)
    if cookie:
        lines.append(f"Cookie: station_access_{served.port}={served.guard.access_token}".encode())
    if origin:
        lines.append(b"Origin: " + origin.encode())
    return b"\r\n".join(lines) + b"\r\n\r\n"


def test_a_huge_post_is_answered_before_its_body_is_read(served):
    """A 1,000 MB POST without a token reached 1.2 GB RSS before its 403: now the answer comes first."""
    gb = 10**9
    assert _raw(served, _post_head(served, gb, cookie=False), b"a=1&" * 100).startswith(b"HTTP/1.1 401")
    assert _raw(served, _post_head(served, gb, cookie=True), b"a=1&" * 100).startswith(b"HTTP/1.1 413")
    assert _raw(served, _post_head(served, gb, cookie=True, origin="http://evil.example"),
                b"a=1&").startswith(b"HTTP/1.1 403")
    # no Content-Length (chunked): read up to the bound, then refused
    chunk = b"a=1&" * 2000
    body = (b"%x\r\n" % len(chunk) + chunk + b"\r\n") * 10
    assert _raw(served, _post_head(served, 0, cookie=True, chunked=True), body).startswith(b"HTTP/1.1 413")
    assert served.store.runs() == []


def test_a_form_of_many_fields_is_refused_quickly(served, client):
    """2x10^6 form fields took 9.4 s while every other request waited."""
    fields = {"procedure": "iso9283", "robot": "r1", "seed": "1", **{f"f{k}": "1" for k in range(500)}}
    status, _, text = client.post("/runs", fields)
    assert status in (400, 413) and served.store.runs() == []
    assert client.get("/")[0] == 200


# -- item 11: slow and idle connections time out, connections are capped ------------------------------------
def test_a_slow_request_head_is_closed(served, monkeypatch):
    monkeypatch.setattr(web_server, "HEAD_TIMEOUT_S", 0.5)
    with socket.create_connection(("127.0.0.1", served.port), timeout=10) as s:
        s.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1:%d\r\n" % served.port)
        closed = False
        for _ in range(100):  # a byte every 0.1 s: the head never completes
            try:
                s.sendall(b"X")
                s.settimeout(0.1)
                closed = s.recv(1) == b""
            except socket.timeout:
                pass
            except OSError:
                closed = True
            if closed:
                break
        assert closed, "the server still waits for a head trickled for 10 s"


def test_connections_beyond_the_cap_evict_the_oldest_waiting_one(served, client, monkeypatch):
    monkeypatch.setattr(web_server, "max_connections", lambda: 8)
    socks = []
    try:
        for _ in range(20):
            s = socket.create_connection(("127.0.0.1", served.port), timeout=5)
            s.sendall(b"GET / HTTP/1.1\r\n")  # a partial head
            socks.append(s)
            time.sleep(0.01)
        assert client.get("/")[0] == 200  # the page stays reachable
        time.sleep(0.2)
        closed = 0
        for s in socks:
            s.settimeout(0.5)
            try:
                closed += s.recv(1) == b""
            except socket.timeout:
                pass
            except OSError:
                closed += 1
        assert closed >= 12, closed
    finally:
        for s in socks:
            s.close()


# -- issue 47 item 7: the head limit holds however the head arrives ---------------------------------------------
def _padded_head(served, size: int) -> bytes:
    """A GET of the page with the access cookie, padded by one header to ``size`` bytes in all."""
    head = (b"GET / HTTP/1.1\r\nHost: 127.0.0.1:%d\r\nCookie: station_access_%d=%s\r\nConnection: close\r\n"
            % (served.port, served.port, served.guard.access_token.encode()))
    pad = size - len(head) - len(b"X-Pad: \r\n\r\n")
    return head + b"X-Pad: " + b"a" * pad + b"\r\n\r\n"


def _send_in_pieces(served, data: bytes, piece: int) -> bytes:
    with socket.create_connection(("127.0.0.1", served.port), timeout=30) as s:
        try:
            for k in range(0, len(data), piece):
                s.sendall(data[k:k + piece])
                time.sleep(0.002 if piece < len(data) else 0)
        except OSError:
            pass  # the server may close as soon as it has refused
        out = b""
        while True:
            try:
                chunk = s.recv(65536)
            except OSError:
                break
            if not chunk:
                break
            out += chunk
        return out


@pytest.mark.parametrize("size_kb", [17, 20, 60])
@pytest.mark.parametrize("piece", ["one write", "trickled"])
def test_a_request_head_over_the_limit_is_refused_however_it_arrives(served, size_kb, piece):
    """Heads of 20-60 KB in one write were answered 200: only a trickled head met the 16 KB limit."""
    data = _padded_head(served, size_kb * 1024)
    answer = _send_in_pieces(served, data, len(data) if piece == "one write" else 1024)
    assert answer.split(b"\r\n", 1)[0] in (b"HTTP/1.1 431 Request Header Fields Too Large",
                                             b"HTTP/1.1 400 Bad Request"), answer[:200]
    assert b"<html" not in answer.lower()


@pytest.mark.parametrize("piece", ["one write", "trickled"])
def test_a_request_head_under_the_limit_is_served(served, piece):
    data = _padded_head(served, web_server.MAX_HEAD_BYTES - 200)
    answer = _send_in_pieces(served, data, len(data) if piece == "one write" else 1024)
    assert answer.startswith(b"HTTP/1.1 200"), answer[:200]


def test_a_pipelined_second_head_over_the_limit_is_refused(served):
    """The second of two requests in one write is measured too, when its turn comes."""
    first = _padded_head(served, 1024).replace(b"Connection: close\r\n", b"")
    answer = _send_in_pieces(served, first + _padded_head(served, 40 * 1024), 10**6)
    assert answer.startswith(b"HTTP/1.1 200") and b"HTTP/1.1 431" in answer, answer[:100]


# -- item 12: no anonymous use on loopback; errors without the store's path --------------------------------
def test_an_unknown_run_id_answers_without_the_stores_path(served, client):
    store_dir = str(served.store.name).rsplit("/", 1)[0]
    for path in ("/runs/NOPE", "/runs/NOPE/state", "/runs/NOPE/events", "/runs/NOPE/report"):
        status, _, text = client.get(path)
        assert status == 404 and store_dir not in text and "NOPE" in text, (path, text[:200])
    status, _, text = client.post("/runs/NOPE/resume")
    assert status == 404 and store_dir not in text


def test_a_local_process_without_the_token_cannot_start_a_run(served):
    anon = Client(served.url, access=False)
    status, _, html = anon.get("/")
    assert status == 401 and served.guard.csrf_token not in html
    assert anon.request("POST", "/runs", {"procedure": "iso9283", "csrf": served.guard.csrf_token})[0] == 401
    assert served.store.runs() == [] and served.hub.active() is None
