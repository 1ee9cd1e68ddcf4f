"""No secret in any record (issue 24, item 13).

A run configured with secrets the way the README shows (the controller's FTP
password by ``password_file``, the central store's by ``password_env``) is
run on the fake cell, pushed to a real PostgreSQL server, exported, and shown
on the page; then the local SQLite store (file and WAL bytes), the central
store (every row of every table), what the run printed and logged, every file
under the station's folder (reports, exports) and the page's HTML are
searched for each secret. The secrets are drawn anew each run.
"""

from __future__ import annotations

import http.client
import io
import json
import logging
import secrets
from types import SimpleNamespace
from urllib.parse import urlsplit

import pytest

import fakes.controller
from fakes.cells import demo_config
from app.assemble import RunRequest, run_procedure
from app.cli import main
from station.config import config_from_dict, load_config
from station.errors import ConfigError
from tests.store.pgserver import PASSWORD_ENV
from tests.pace import LOCKSTEP


def _pg_text(url: str) -> str:
    """Every row of every table of the central store, as text."""
    import psycopg

    from station.store_url import parse_pg_url

    with psycopg.connect(**parse_pg_url(url).connect_kwargs()) as conn:
        tables = [r[0] for r in conn.execute(
            "SELECT quote_ident(table_schema) || '.' || quote_ident(table_name) FROM information_schema.tables "
            "WHERE table_schema NOT IN ('pg_catalog', 'information_schema')")]
        assert tables
        out = []
        for t in tables:
            out += [r[0] for r in conn.execute(f"SELECT t::text FROM {t} t")]
    return "\n".join(out)


def _page(url: str, paths: list[str]) -> str:
    """The page's answers to ``paths``, asked with the access token of the printed ``url`` (as its cookie)."""
    parts = urlsplit(url)
    token = dict(p.split("=", 1) for p in parts.query.split("&") if "=" in p).get("token")
    html = []
    for path in paths:
        con = http.client.HTTPConnection(parts.hostname, parts.port, timeout=20)
        try:
            con.request("GET", path, headers={"Cookie": f"station_access_{parts.port}={token}"} if token else {})
            resp = con.getresponse()
            body = resp.read().decode("utf-8", "replace")
            assert resp.status == 200, (path, resp.status, body[:300])
            html.append(body)
        finally:
            con.close()
    return "\n".join(html)


def test_no_secret_reaches_a_record_a_log_the_page_or_an_export(test_seed, tmp_path, pg_url, monkeypatch, caplog):
    seed = test_seed  # the session's seed for this test (printed on failure, --seed replays)
    print(f"cell seed {seed}")
    ftp_file_secret = "fileSecret" + secrets.token_hex(8)  # the configured controller's password (its file)
    ftp_fake_secret = "fakeSecret" + secrets.token_hex(8)  # the fake controller's, which the driver logs in with
    pg_secret = __import__("os").environ[PASSWORD_ENV]  # the central store's (pgserver sets it)
    monkeypatch.setattr(fakes.controller, "secrets", SimpleNamespace(token_hex=lambda n: ftp_fake_secret))
    secret_dir = tmp_path / "secrets"
    secret_dir.mkdir()
    (secret_dir / "ftp.pass").write_text(ftp_file_secret + "\n")
    station_dir = tmp_path / "station"
    station_dir.mkdir()
    d = demo_config(station_dir, cycles=2, vap_cycles=2, rate_hz=100)
    d["station"]["store_url"] = pg_url
    d["devices"]["controller"]["url"] = (f"modbus+ftp://127.0.0.1:2121?modbus_port=1502&user=station"
                                         f"&password_file={secret_dir / 'ftp.pass'}")
    cfg_path = station_dir / "station.json"
    cfg_path.write_text(json.dumps(d))
    cfg = load_config(cfg_path)
    caplog.set_level(logging.DEBUG)
    out = io.StringIO()
    code = run_procedure(RunRequest(cfg, "iso9283", stdout=out, run_id="s1", yes=True, quiet=True, time_scale=LOCKSTEP,
                                    seed=seed, config_dir=station_dir))
    assert code.status == "done", out.getvalue()  # its verdict is the drawn cell's (the secrets are the point)
    assert "central store:" in out.getvalue()
    for fmt in ("csv", "parquet"):
        assert main(["store", "export", "s1", "--config", str(cfg_path), "--out", str(station_dir / f"x-{fmt}"),
                     "--format", fmt]) == 0
    assert main(["store", "export", "s1", "--config", str(cfg_path), "--central", "--out",
                 str(station_dir / "x-central"), "--format", "csv"]) == 0
    from app.web.server import WebServer

    with WebServer(cfg, station_dir, host="127.0.0.1", port=0).start() as server:
        html = _page(server.url, ["/", "/runs/s1", "/runs/s1/state", "/runs/s1/report", "/robots/DEMO-0001"])
    assert "s1" in html and "controller" in html
    files = {p: p.read_bytes() for p in station_dir.rglob("*") if p.is_file()}
    assert any(p.suffix == ".parquet" for p in files) and any(p.suffix == ".html" for p in files)
    assert any(p.name.startswith("station.sqlite") for p in files)
    central = _pg_text(pg_url)
    assert "s1" in central
    texts = {"printed": out.getvalue(), "logged": caplog.text, "page": html, "central store": central}
    for secret in (ftp_file_secret, ftp_fake_secret, pg_secret):
        for what, text in texts.items():
            assert secret not in text, f"a secret in the {what}"
        for path, data in files.items():
            assert secret.encode() not in data, f"a secret in {path}"


@pytest.mark.parametrize("url", [
    "modbus+ftp://10.0.0.7?modbus_port=502&user=station&password=hunter2",
    "modbus+ftp://10.0.0.7?modbus_port=502&user=station&pass%77ord=hunter2",
    "modbus+ftp://station:hunter2@10.0.0.7?modbus_port=502",
    "modbus+ftp://10.0.0.7?password_env=A&password_file=/b",
])
def test_a_device_password_in_the_url_is_refused(tmp_path, url):
    d = demo_config(tmp_path, cycles=2, vap_cycles=2, rate_hz=100)
    d["devices"]["controller"]["url"] = url
    with pytest.raises(ConfigError) as exc:
        config_from_dict(d)
    assert "hunter2" not in str(exc.value)


@pytest.mark.parametrize("url", ["postgresql://station%3Ahunter2@db.plant/metrology",
                                 "postgresql://station@db.plant/metrology%3Ahunter2",
                                 "postgresql://station@db.plant/metrology?pass%77ord=hunter2"])
def test_a_store_url_hiding_a_secret_is_refused(tmp_path, url):
    d = demo_config(tmp_path, cycles=2, vap_cycles=2, rate_hz=100)
    d["station"]["store_url"] = url
    with pytest.raises(ConfigError) as exc:
        config_from_dict(d)
    assert "hunter2" not in str(exc.value)


def test_the_driver_reads_the_password_from_its_file_or_variable(tmp_path, monkeypatch):
    from station.device_urls import parse_device_url

    secret = secrets.token_hex(8)
    (tmp_path / "pw").write_text(secret + "\nignored\n")
    assert parse_device_url(f"modbus+ftp://h?password_file={tmp_path / 'pw'}").password() == secret
    monkeypatch.setenv("STATION_TEST_FTP_PW", secret)
    assert parse_device_url("modbus+ftp://h?password_env=STATION_TEST_FTP_PW").password() == secret
    with pytest.raises(ConfigError, match="not set"):
        parse_device_url("modbus+ftp://h?password_env=STATION_TEST_UNSET_PW").password()
    assert parse_device_url("modbus+ftp://h").password() == ""


def test_the_page_redacts_what_it_shows():
    from app.web.state import _redact

    for url in ("modbus+ftp://u:hunter2@h:21", "modbus+ftp://h?pass%77ord=hunter2&dir=d",
                "modbus+ftp://h?PASSWORD=hunter2"):
        assert "hunter2" not in _redact(url)
