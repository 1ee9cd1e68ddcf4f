"""The force gauge: its codec, its fake judged by an independent pyserial client, the driver against the fake,
and fault injection (no reply, garbage, overload)."""

from __future__ import annotations

import numpy as np
import pytest
import serial

from drivers.forcegauge import ForceGauge, GaugeOverload
from drivers.forcegauge_codec import Ack, ErrorReply, Overload, Reading, Text, encode_command, parse_reply
from fakes.forcegauge import start_fake
from fakes.sim.world import make_world
from station.errors import ConfigError, DeviceFault, DeviceTimeout, ProtocolError


@pytest.fixture
def world(test_seed):
    w = make_world("industrial-3100", seed=test_seed, time_scale=50.0, effects=None)
    yield w
    w.close()


# ----------------------------------------------------------------------------- codec
def test_codec_reads_each_kind_of_reply_and_converts_units():
    r = parse_reply(b"-18.78 lbF")
    assert isinstance(r, Reading) and r.unit == "lbF" and r.force_N == pytest.approx(-18.78 * 4.4482216)
    assert parse_reply(b"0.512 kN").force_N == pytest.approx(512.0)
    assert parse_reply(b"4.285 N").force_N == pytest.approx(4.285)
    assert parse_reply(b"12.5 kgF").force_N == pytest.approx(12.5 * 9.80665)
    assert isinstance(parse_reply(b"OVER"), Overload)
    assert isinstance(parse_reply(b"R"), Ack)
    err = parse_reply(b"*10")
    assert isinstance(err, ErrorReply) and err.meaning == "illegal command"
    assert parse_reply(b"FG-2500") == Text("FG-2500")
    assert encode_command("?") == b"?\r"
    with pytest.raises(ConfigError, match="not one of"):
        encode_command("FIRE")


@pytest.mark.parametrize("line, why", [
    (b"12.34", "no unit"), (b"12.34 furlong", "unknown unit"), (b"\xff\xfe", "not ASCII"), (b"", "empty"),
    (b"1" * 80, "longer than"), (b"12\x01 N", "control characters"), (b"#$%!", "neither a reading"),
])
def test_codec_refuses_what_is_no_reply(line, why):
    with pytest.raises(ValueError, match=why):
        parse_reply(line)


# ----------------------------------------------------------------------------- the fake, judged by pyserial
def test_fake_speaks_the_protocol_to_an_independent_pyserial_client(world, rng):
    """A few lines of pyserial, no station code: ask, read the reply, check it against the world's load."""
    load = rng.uniform(50.0, 2000.0) * np.array([0.0, 0.0, 1.0])
    with start_fake(world) as fake:
        port = serial.Serial(fake.endpoint["device"], 9600, timeout=2.0)
        try:
            def ask(cmd: bytes) -> str:
                port.write(cmd + b"\r")
                line = port.readline()
                assert line.endswith(b"\r\n"), line
                return line[:-2].decode("ascii")

            assert ask(b"RM") == "FG-2500"
            assert ask(b"Z") == "R"  # tare at no load
            value, unit = ask(b"?").split()
            assert unit == "N" and abs(float(value)) < 0.5
            world.arm.apply_tcp_force(load)
            value, unit = ask(b"?").split()
            assert unit == "N" and float(value) == pytest.approx(load[2], abs=0.5)
            assert ask(b"KN") == "R"
            value, unit = ask(b"?").split()
            assert unit == "kN" and float(value) == pytest.approx(load[2] / 1000.0, abs=1e-3)
            assert ask(b"LAUNCH") == "*10"
        finally:
            port.close()


def test_driver_reads_the_load_after_zero_whatever_the_unit(world, rng):
    load = rng.uniform(10.0, 2000.0)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    with start_fake(world) as fake, ForceGauge.from_url(fake.url, timeout_s=2.0) as gauge:
        assert gauge.connect() == {"model": "FG-2500", "serial": "G-0042"}
        offset = gauge.read_force_N()  # an untared gauge reads its own zero offset (up to 3 N)
        gauge.zero()
        assert abs(gauge.read_force_N()) < 0.3
        world.arm.apply_tcp_force(load * direction)
        for unit in ("N", "kgF", "lbF", "kN"):
            gauge.set_unit(unit)
            mean, sd = gauge.read_force_avg_N(4)
            assert mean == pytest.approx(load, abs=0.3 + 0.01 * (unit == "kN")), unit
        with pytest.raises(ConfigError, match="not one of"):
            gauge.set_unit("stone")
    assert abs(offset) <= 3.3


# ----------------------------------------------------------------------------- fault injection
def test_no_reply_is_a_timeout_naming_the_gauge(world):
    with start_fake(world, faults={"no_reply": "always"}) as fake:
        gauge = ForceGauge.from_url(fake.url, timeout_s=0.3)
        with pytest.raises(DeviceTimeout, match=f"no reply from force gauge on .*{fake.endpoint['device']}.*'RM'"):
            gauge.connect()
        gauge.close()


def test_every_third_request_unanswered_times_out_once_and_the_next_is_answered(world):
    with start_fake(world, faults={"no_reply": "3"}) as fake, ForceGauge.from_url(fake.url, timeout_s=0.3) as g:
        g.connect()  # requests 1, 2
        with pytest.raises(DeviceTimeout, match="'\\?'"):
            g.read_force_N()  # request 3: silence
        assert np.isfinite(g.read_force_N())  # request 4: answered, no stale reply in between
        assert fake.stats["unanswered"] == 1


def test_garbage_is_a_refused_reply_naming_the_gauge_and_the_next_reading_is_clean(world):
    with start_fake(world, faults={"garbage": "3"}) as fake, ForceGauge.from_url(fake.url, timeout_s=1.0) as g:
        g.connect()
        with pytest.raises(ProtocolError, match=f"force gauge on .*{fake.endpoint['device']}.*refused reply"):
            g.read_force_N()
        g.zero()
        assert abs(g.read_force_N()) < 0.3
        assert fake.stats["garbage"] == 1


def test_overload_is_a_fault_naming_the_gauge(world, rng):
    capacity = float(rng.uniform(100.0, 500.0))
    with start_fake(world, faults={"capacity_N": str(capacity)}) as fake, \
            ForceGauge.from_url(fake.url, timeout_s=1.0) as g:
        g.connect()
        g.zero()
        world.arm.apply_tcp_force([0.0, 0.99 * capacity, 0.0])
        assert g.read_force_N() == pytest.approx(0.99 * capacity, abs=0.3)
        world.arm.apply_tcp_force([0.0, -1.01 * capacity, 0.0])
        with pytest.raises(GaugeOverload, match="force gauge on .*overload") as info:
            g.read_force_N()
        assert isinstance(info.value, DeviceFault)


def test_unknown_fault_is_refused_naming_it(world):
    with pytest.raises(ConfigError, match="unknown force gauge fault.*smoke"):
        start_fake(world, faults={"smoke": "1"})


def _pause_before_reply(monkeypatch, pause_s: float, *, lose: bool = False) -> dict:
    """Once ``hold["armed"]``, the fake's next request is answered after this host was stopped for ``pause_s``
    (the fake's thread stops the whole process, itself and the driver included), then 0.1 s later: the gauge
    answered in a third of the timeout, late only by the host's absence. ``lose``: then it stays silent."""
    import time

    from fakes import forcegauge as fake_gauge
    from tests.host_pause import pause_host

    hold = {"armed": False, "taken": 0}
    original = fake_gauge.ForceGaugeFake._request

    def held(fake, command):
        if hold["armed"] and not hold["taken"]:
            hold["taken"] += 1
            time.sleep(0.05)  # the driver is waiting for the reply by now (its request reached the fake at once)
            pause_host(pause_s)
            if lose:
                fake.stats["unanswered"] += 1
                return None
            time.sleep(0.1)  # the gauge's own reply time after the host runs again, a third of the timeout
        return original(fake, command)

    monkeypatch.setattr(fake_gauge.ForceGaugeFake, "_request", held)
    return hold


def test_a_host_that_did_not_run_is_not_a_gauge_that_did_not_answer(world, monkeypatch, rng):
    """Issue 46: the reply wait counts the gauge's silence, not the time this host was stopped (1.5-2.5x the
    timeout, at the moment the gauge answers); a gauge that then stays silent still times out, naming the
    request, after the pause and its whole timeout."""
    import time

    timeout = 0.3
    pause = float(rng.uniform(1.5, 2.5)) * timeout
    hold = _pause_before_reply(monkeypatch, pause)
    with start_fake(world) as fake, ForceGauge.from_url(fake.url, timeout_s=timeout) as g:
        g.connect()
        hold["armed"] = True
        assert np.isfinite(g.read_force_N())
        assert hold["taken"] == 1 and fake.stats["unanswered"] == 0
    hold = _pause_before_reply(monkeypatch, pause, lose=True)
    with start_fake(world) as fake, ForceGauge.from_url(fake.url, timeout_s=timeout) as g:
        g.connect()
        hold["armed"] = True
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match="'\\?' within 0.3 s"):
            g.read_force_N()
        assert time.monotonic() - t0 >= pause + timeout - 0.06
        assert np.isfinite(g.read_force_N())  # the next request is answered
