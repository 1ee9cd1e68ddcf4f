"""Who may act: CSRF token and Origin on POSTs, Host on loopback, the access token everywhere; bad input named."""

import html
import ipaddress

import pytest

from station.errors import ConfigError
from app.web.security import Guard, is_loopback
from tests.web.conftest import Client


def test_a_post_without_the_token_or_from_another_site_is_refused_and_starts_nothing(served, client):
    assert client.post("/runs", {"procedure": "iso9283"}, csrf=False)[0] == 403
    assert client.request("POST", "/runs", {"procedure": "iso9283", "csrf": "x" * 43})[0] == 403
    status, _, text = client.post("/runs", {"procedure": "iso9283"}, headers={"Origin": "http://evil.example"})
    assert status == 403 and "cross-site" in text
    assert client.post("/runs", {"procedure": "iso9283"}, headers={"Origin": "null"})[0] == 403
    assert served.store.runs() == [] and served.hub.active() is None


def test_a_foreign_host_name_is_refused_on_loopback(client):
    # a site whose name resolves to 127.0.0.1 (DNS rebinding) sends its own name as Host
    status, _, _ = client.request("GET", "/", headers={"Host": f"rebind.example:{client.port}"})
    assert status == 421
    assert client.get("/")[0] == 200


def test_every_request_needs_the_access_token_loopback_included(served):
    token = served.guard.access_token
    client = Client(served.url, access=False)
    assert client.get("/")[0] == 401
    assert client.get("/runs/x/state")[0] == 401
    assert client.post("/runs", {"procedure": "iso9283"}, csrf=False)[0] == 401
    assert client.get("/?token=wrong")[0] == 401
    status, headers, _ = client.get(f"/?token={token}")
    cookie = f"station_access_{served.port}"
    assert status == 303 and headers["set-cookie"].startswith(f"{cookie}=")
    assert "samesite=strict" in headers["set-cookie"].lower() and "httponly" in headers["set-cookie"].lower()
    assert client.request("GET", "/", headers={"Cookie": f"{cookie}={token}"})[0] == 200
    # the token is in the printed URL
    assert served.url.endswith(f"?token={token}")


def test_guard_basics():
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("192.168.1.10") and not is_loopback("10.0.0.5")
    g = Guard("192.168.1.10", 8700)
    assert g.access_token and len(g.access_token) >= 24 and g.host_ok("anything:1")
    assert len(Guard("127.0.0.1").access_token) >= 24
    assert g.post_problem("h:1", None, g.csrf_token) is None
    assert g.post_problem("h:1", "http://h:1", g.csrf_token) is None
    assert "CSRF" in g.post_problem("h:1", "http://h:1", None)


def test_bad_input_is_named(served, client):
    status, _, text = client.post("/runs", {"procedure": "nosuch"})
    assert status == 400 and "unknown procedure 'nosuch'" in html.unescape(text) and "'nosuch'" not in text
    status, _, text = client.post("/runs", {"procedure": "iso9283", "seed": "abc"})
    assert status == 400 and "seed must be an integer" in text
    status, _, text = client.post("/runs", {"procedure": "iso9283", "robot": "r9"})
    assert status == 400 and "r9" in text
    assert client.get("/runs/NOPE")[0] == 404
    assert client.post("/runs/NOPE/abort")[0] == 409
    assert client.post("/runs/NOPE/resume")[0] == 404
    status, _, text = client.post("/runs/NOPE/answer", {"prompt_id": "x", "answer": "yes"})
    assert status == 400 and "prompt_id" in text
    status, _, text = client.post("/runs/NOPE/answer", {"prompt_id": "1", "answer": "maybe"})
    assert status == 400 and "answer must be" in text
    assert served.store.runs() == []


def test_serve_refuses_a_bad_port(tmp_path):
    from station.config import load_config
    from app.web.server import WebServer
    from tests.web.conftest import demo_station_config

    with pytest.raises(ConfigError, match="port"):
        WebServer(load_config(demo_station_config(tmp_path)), tmp_path, port=70000)


def test_station_serve_refuses_bad_arguments_writing_nothing(tmp_path, capsys):
    from app.cli import main

    out = tmp_path / "demo"
    assert main(["serve", "--demo", "--out", str(out), "--port", "70000"]) == 2
    assert main(["serve", "--demo", "--out", str(out), "--time-scale", "0"]) == 2
    assert main(["serve", "--demo", "--out", str(out), "--arm"]) == 2
    for wildcard in (str(ipaddress.IPv4Address(0)), "::"):  # every interface: never; name the LAN address
        assert main(["serve", "--demo", "--out", str(out), "--host", wildcard]) == 2
    err = capsys.readouterr().err
    assert "--port must be" in err and "--time-scale must be" in err and "--arm" in err
    assert err.count("would listen on every interface") == 2
    assert not out.exists()
