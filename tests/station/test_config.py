import json

import pytest

from station.config import config_from_dict, load_config
from station.device_urls import parse_device_url
from station.errors import ConfigError

GOOD = """
[station]
name = "cell-7"
store_path = "station.sqlite"

[devices.tracker]
url = "emscon://127.0.0.1:700"

[devices.ctrl]
url = "modbus+ftp://127.0.0.1"

[devices.odo]
url = "nmea:///dev/ttyS1?baud=57600"

[robots.r1]
model = "industrial-3100"
serial = "NA8608-0042"
overhaul_state = "after"
payload_kg = 100.0
controller = "ctrl"

[robots.r1.workspace]
min_mm = [-800.0, 900.0, 600.0]
max_mm = [800.0, 2500.0, 2200.0]

[robots.r1.limits]
rp_limit_mm = 0.5
"""


def test_good_config_loads(tmp_path):
    p = tmp_path / "station.toml"
    p.write_text(GOOD)
    cfg = load_config(p)
    assert cfg.robots["r1"].limits.rp_limit_mm == 0.5
    assert cfg.devices["odo"].parsed.options["baud"] == "57600"
    assert cfg.devices["tracker"].parsed.port == 700
    assert cfg.iso9283.cycles == 30


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda t: t.replace('url = "emscon://127.0.0.1:700"', 'url = "telnet://127.0.0.1:700"'), "devices.tracker.url"),
        (lambda t: t.replace('model = "industrial-3100"\n', ""), "robots.r1.model"),
        (lambda t: t.replace("rp_limit_mm = 0.5", "rp_limit_um = 500"), "robots.r1.limits.rp_limit_um"),
        (lambda t: t.replace("rp_limit_mm = 0.5", "rp_limit_mm = -0.5"), "robots.r1.limits.rp_limit_mm"),
        (lambda t: t.replace('controller = "ctrl"', 'controller = "plc"'), "names device 'plc'"),
        (lambda t: t.replace('model = "industrial-3100"', 'model = "robby-9000"'), "robby-9000"),
        (lambda t: t.replace("max_mm = [800.0, 2500.0, 2200.0]", "max_mm = [800.0, 800.0, 2200.0]"), "workspace axis y"),
        (lambda t: t.replace('serial = "NA8608-0042"', 'serial = "x; DROP TABLE runs"'), "robots.r1.serial"),
        (lambda t: t.replace('url = "nmea:///dev/ttyS1?baud=57600"', 'url = "nmea:///dev/ttyS1?baud=fast"'), "baud"),
    ],
)
def test_malformed_config_refused_naming_field(tmp_path, edit, field):
    p = tmp_path / "station.toml"
    p.write_text(edit(GOOD))
    with pytest.raises(ConfigError) as exc:
        load_config(p)
    assert field in str(exc.value)


def test_unparseable_files_refused(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("[station\nname=")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(p)
    j = tmp_path / "s.json"
    j.write_text(json.dumps([1, 2]))
    with pytest.raises(ConfigError, match="top level"):
        load_config(j)
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "missing.toml")


def test_device_urls():
    assert parse_device_url("geocom:///dev/ttyUSB0?baud=115200").path == "/dev/ttyUSB0"
    assert parse_device_url("ur://10.0.0.9").host == "10.0.0.9"
    with pytest.raises(ConfigError, match="needs a host"):
        parse_device_url("emscon://:700")
    with pytest.raises(ConfigError, match="serial device path"):
        parse_device_url("nmea://host")
    with pytest.raises(ConfigError, match="unknown scheme 'http'"):
        parse_device_url("http://x")


def test_config_from_dict_lists_every_bad_field():
    with pytest.raises(ConfigError) as exc:
        config_from_dict({"station": {}, "devices": {}, "robots": {}, "extra": 1})
    msg = str(exc.value)
    assert "station.name: missing required field" in msg and "extra: unknown field" in msg
