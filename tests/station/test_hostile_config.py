"""Hostile configs (issue reproducers): every one a clean refusal, exit 2, one `station: error` line."""

from __future__ import annotations

import copy
import json

import pytest

from fakes.cells import demo_config
from app.cli import main


def _write(tmp_path, data, name="c.json") -> str:
    p = tmp_path / name
    p.write_text(data if isinstance(data, str) else json.dumps(data))
    return str(p)


def _refused(capsys, argv, match: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.startswith("station: error:") and match in err, err


@pytest.mark.parametrize("name, text, match", [
    ("deep.json", "[" * 1200 + "]" * 1200, "nested too deeply"),
    ("deep.toml", "a = " + "[" * 1200 + "]" * 1200, "nested too deeply"),
    ("big.json", '{"station": {"name": ' + "9" * 5000 + "}}", "more than 4300 digits"),
    ("big.toml", "x = " + "9" * 5000, "more than 4300 digits"),
    ("nested.json", json.dumps({"station": {"name": "x"}, "devices": {}, "robots": {"r": {"a": [[[[[[[[[[[[[1]]]]]]]]]]]]]}}}),
     "levels deep"),
])
def test_unparseable_configs(tmp_path, capsys, name, text, match):
    _refused(capsys, ["run", "iso9283", "--config", _write(tmp_path, text, name), "--yes"], match)


@pytest.mark.parametrize("path, value, match", [
    (("iso9283", "inset_mm"), float("inf"), "iso9283.inset_mm"),
    (("iso9283", "speed_percent"), 1e-300, "iso9283.speed_percent"),
    (("iso9283", "vap_offset_mm"), 1e308, "iso9283.vap_offset_mm"),
    (("iso9283", "cube_corners_mm"), [[float("nan"), 0.0, 0.0]] * 8, "cube_corners_mm"),
    (("robots", "r1", "payload_kg"), 1e308, "payload_kg"),
    (("trailer",), {"odometry": "odo", "method": "M99"}, "unknown trailer method 'M99'"),
    (("trailer",), {"odometry": "odo", "commands": [["C", float("nan")]]}, "trailer.commands"),
    (("station", "store_path"), "a\u0000b.sqlite", "control characters"),
])
def test_values_no_run_could_use_are_refused_at_load(tmp_path, capsys, path, value, match):
    d = copy.deepcopy(demo_config(tmp_path, cycles=3, vap_cycles=3, rate_hz=100))
    node = d
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    # json.dumps writes NaN/Infinity, which Python's JSON reader takes: the config must refuse them itself
    _refused(capsys, ["run", "iso9283", "--config", _write(tmp_path, d), "--yes"], match)


def test_a_store_under_a_file_is_refused_with_its_path(tmp_path, capsys):
    (tmp_path / "plain").write_text("not a folder")
    d = demo_config(tmp_path, cycles=3, vap_cycles=3, rate_hz=100)
    d["station"]["store_path"] = str(tmp_path / "plain" / "s.sqlite")
    _refused(capsys, ["run", "iso9283", "--config", _write(tmp_path, d), "--yes"], "is a file, not a folder")
