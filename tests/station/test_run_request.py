"""A run is asked for with one RunRequest; options that contradict each other are refused there.

Each contradiction is refused when the request is made, with ConfigError naming
the options, so nothing is recorded and nothing moves; at the CLI it is exit 2
and the store is not even opened.
"""

import dataclasses
import json
import math

import pytest

from app.assemble import RunRequest
from app.cli import main
from fakes.cells import demo_config
from procedures.devices import DeviceSet
from station.config import config_from_dict
from station.errors import ConfigError
from station.runner import ScriptedOperator


@pytest.fixture
def cfg(tmp_path):
    return config_from_dict(demo_config(tmp_path, cycles=2, vap_cycles=2, rate_hz=100.0), "test config")


@pytest.mark.parametrize("kwargs, named", [
    (dict(procedure=None), "name a procedure"),
    (dict(procedure=None, resume="r1", run_id="r2"), "run_id 'r2'"),
    (dict(procedure=None, resume="r1", plan_overrides={"cycles": 3}), "plan_overrides cannot be given with resume"),
    (dict(procedure=None, resume="r1", acceptance={"require_conformance": True}), "--require-iso"),
    (dict(procedure=None, resume="r1", fake_options={"rtde_hz": 125}), "fake_options cannot be given with resume"),
    (dict(yes=True, operator=ScriptedOperator(True)), "give yes (--yes) or an operator"),
    (dict(arm=True, devices=DeviceSet(urls={})), "give arm (the configured devices) or devices"),
    (dict(arm=True, fake_options={"rtde_hz": 125}), "with arm no fake cell is started"),
    (dict(devices=DeviceSet(urls={}), fake_options={"rtde_hz": 125}), "with devices no fake cell is started"),
    (dict(time_scale=0.0), "time_scale (--time-scale) must be a number > 0, got 0.0"),
    (dict(time_scale=-2.0), "got -2.0"),
    (dict(time_scale=math.nan), "got nan"),
    (dict(time_scale="fast"), "got 'fast'"),
    (dict(time_scale=True), "got True"),
    (dict(seed=1.5), "seed (--seed) must be a whole number, got 1.5"),
])
def test_each_contradiction_is_refused_naming_it(cfg, kwargs, named):
    with pytest.raises(ConfigError) as ei:
        RunRequest(cfg, **{"procedure": "iso9283", **kwargs})
    assert named in str(ei.value)


def test_every_contradiction_of_a_request_is_named_at_once(cfg):
    with pytest.raises(ConfigError) as ei:
        RunRequest(cfg, None, resume="r1", run_id="r2", yes=True, operator=ScriptedOperator(True), seed=0.5)
    text = str(ei.value)
    assert "run_id 'r2'" in text and "not both" in text and "seed" in text


def test_a_consistent_request_is_taken_and_kept_as_made(cfg):
    # a resume may name its own id and its stored procedure; the pace may change on a resume
    req = RunRequest(cfg, "iso9283", resume="r1", run_id="r1", time_scale=5)
    assert (req.procedure, req.resume, req.run_id, req.time_scale) == ("iso9283", "r1", "r1", 5)
    # the fields are the old keywords of run_procedure
    names = [f.name for f in dataclasses.fields(RunRequest) if f.name != "_"]
    assert names[:2] == ["config", "procedure"] and {"robot", "arm", "yes", "seed", "json_out", "devices",
                                                     "operator", "control", "stdout", "progress",
                                                     "acceptance", "plan_overrides", "fake_options"} <= set(names)
    with pytest.raises(dataclasses.FrozenInstanceError):
        req.arm = True


@pytest.mark.parametrize("flags, named", [
    (["--resume", "r1", "--run-id", "r2"], "run_id 'r2' (--run-id) with resume 'r1'"),
    (["--resume", "r1", "--require-iso"], "--require-iso"),
    (["iso9283", "--yes", "--answers", "ANSWERS"], "give yes (--yes) or an operator (--answers"),
    ([], "name a procedure"),
])
def test_station_run_refuses_contradicting_flags_before_opening_the_store(tmp_path, capsys, flags, named):
    conf = tmp_path / "station.json"
    conf.write_text(json.dumps(demo_config(tmp_path, cycles=2, vap_cycles=2, rate_hz=100.0), default=str))
    answers = tmp_path / "answers.txt"
    answers.write_text("yes\n" * 5)
    argv = ["run", *[str(answers) if f == "ANSWERS" else f for f in flags], "--config", str(conf), "--quiet"]
    assert main(argv) == 2
    assert named in capsys.readouterr().err
    assert not (tmp_path / "station.sqlite").exists()
