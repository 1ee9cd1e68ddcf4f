"""The odometry unit in lockstep (a dry run's cell): stepped by its driver's sync sentence, so a seed gives the
same samples at any load and pace; judged on the wire by pyserial and pynmea2, and through the whole run."""

from __future__ import annotations

import sys
import threading
import time

import numpy as np
import pynmea2
import pytest
import serial

from app.assemble import RunRequest, run_procedure
from drivers.nmea_codec import encode_curvature_command, encode_sync
from drivers.odometry import LISTEN_SLICE_S, OdometryDriver
from drivers.transport import SerialTransport
from fakes.odometry import OdometryFake
from fakes.sim.clock import SimClock
from fakes.sim.trailer import SimTrailer
from procedures.trailer import COLUMNS
from station.config import config_from_dict
from station.errors import ConfigError
from station.store import RunStore


def _fake(rng, *, faults=None, scale=None):
    clock = SimClock(time_scale=scale or float(rng.uniform(50.0, 400.0)), start=float(rng.uniform(0, 100)),
                     lockstep=True)
    trailer = SimTrailer(clock, rng=np.random.default_rng(rng.integers(2**32)))
    fake = OdometryFake(trailer, clock, faults=faults, rng=np.random.default_rng(rng.integers(2**32)),
                        lockstep=True)
    return clock, fake


def _line(port) -> bytes:
    line = port.readline()
    assert line.endswith(b"\r\n"), line
    return line


def _sample_t(line: bytes) -> float:
    msg = pynmea2.parse(line.decode("ascii").strip(), check=True)
    assert isinstance(msg, pynmea2.ProprietarySentence) and msg.manufacturer == "ODO" and msg.data[0] == ""
    return float(msg.data[1])


def test_the_unit_holds_the_clock_at_its_newest_sample_until_the_host_has_it(rng):
    rate = float(rng.choice([5.0, 10.0, 20.0]))
    clock, fake = _fake(rng, faults={"rate_hz": str(rate)})
    t0 = clock.now()
    port = serial.Serial(fake.endpoint["device"], timeout=5.0)
    try:
        time.sleep(0.1)
        assert clock.now() == t0  # nobody asked: a lockstep world stands still
        port.write(encode_sync("a1", None))
        first = _line(port)
        t1 = _sample_t(first)
        assert t1 == pytest.approx(t0 + 1 / rate, abs=1e-3)
        other = clock.schedule(t1 + 5.0)  # another part of the world wants to run on
        time.sleep(0.2)  # tens of simulated seconds at this pace, were the clock not held
        assert abs(clock.now() - t1) < 1e-3  # held at the sample (sent to the millisecond)
        port.write(encode_sync("a1", None))  # the host says it has none: the newest again, as it was
        assert _line(port) == first
        port.write(encode_sync("a1", t1))
        t2 = _sample_t(_line(port))
        assert t2 == pytest.approx(t1 + 1 / rate, abs=1e-3)
        port.write(encode_sync("a1", t1))  # stale (a lost sample, or a slow host): sample 2 again
        assert _sample_t(_line(port)) == t2
        # a command read before the sync is latched by the next cycle: its reply, then the sample
        port.write(encode_curvature_command(0.01) + encode_sync("a1", t2))
        ack = pynmea2.parse(_line(port).decode().strip(), check=True)
        t3 = _sample_t(_line(port))
        assert ack.data[:2] == ["A", "C"] and float(ack.data[2]) == t3 == pytest.approx(t2 + 1 / rate, abs=1e-3)
        # another host (a new token): its first sample is the next cycle's, not a repeat
        port.write(encode_sync("b2", None))
        assert _sample_t(_line(port)) == pytest.approx(t3 + 1 / rate, abs=1e-3)
        assert fake.stats["resent_samples"] == 2
        time.sleep(0.1)
        assert clock.now() < t1 + 5.0  # still held for host b2
        port.write(encode_sync("a1", None, end=True))  # a host that left already: nothing changes
        time.sleep(0.1)
        assert clock.now() < t1 + 5.0
        port.write(encode_sync("b2", None, end=True))
        # the host is gone: the unit holds nothing and the world runs to what it scheduled
        assert clock.sleep_until(t1 + 5.0) and clock.now() >= t1 + 5.0
    finally:
        port.close()
    other.cancel()
    fake.close()


@pytest.mark.parametrize("faults", [{"drop_rate": "0.1", "checksum_rate": "0.1"}, {"stall": "STALL"}],
                         ids=["lossy-line", "stalled-line"])
def test_every_cycle_reaches_the_driver_once_on_a_lossy_or_stalled_line(rng, faults):
    """Lost sentences are asked for again and repeats dropped: consecutive cycles, none twice, none missing
    (but those of the stall, when the line is dead and the unit runs on)."""
    rate = 10.0
    stall = None
    if "stall" in faults:
        stall = (float(rng.uniform(2.0, 5.0)), float(rng.uniform(1.0, 4.0)))
        faults = {"stall": f"{stall[0]}:{stall[1]}"}
    clock, fake = _fake(rng, faults=faults, scale=200.0)
    t0 = clock.now()
    drv = OdometryDriver.open(fake.endpoint["device"], timeout_s=5.0, ack_timeout_s=0.1, lockstep=True)
    try:
        drv.command_speed(1.0)
        ts = []
        for k in range(120):
            if k == 40:
                drv.command_curvature(float(rng.uniform(-0.05, 0.05)))
            ts.append(drv.read_sample().t_s)
    finally:
        drv.close()
        fake.close()
    ticks = np.rint((np.array(ts) - t0) * rate).astype(int)
    assert np.allclose(np.array(ts) - t0, ticks / rate, atol=1e-3)
    expected = np.arange(ticks[0], ticks[0] + 200)
    if stall is not None:
        rel = expected / rate
        expected = expected[(rel < stall[0]) | (rel >= stall[0] + stall[1])]
    assert ticks.tolist() == expected[:ticks.size].tolist()
    if stall is None:
        assert fake.stats["corrupted"] + fake.stats["dropped_chars"] > 0
        assert fake.stats["resent_samples"] > 0 and drv.command_stats.syncs > ticks.size


class _HostAway(SerialTransport):
    """A busy host: right after a sync has gone out, the station's thread does not run for ``away_s``."""

    def __init__(self, port: str, away_s: float, times: int) -> None:
        super().__init__(port, baudrate=57600)
        self.away_s, self.left = away_s, times

    def write(self, data: bytes, timeout_s: float) -> None:
        super().write(data, timeout_s)
        if data.startswith(b"$PODOS") and b",END*" not in data and self.left > 0:
            self.left -= 1
            time.sleep(self.away_s)


def test_a_reply_that_came_while_the_host_was_away_is_no_timeout(rng):
    """The driver's deadlines are the host's wall clock. When its thread does not run for longer than a
    deadline after a sync (a busy machine), the unit's reply is already waiting when it runs again: the
    driver reads it instead of reporting a silent unit (a resumed dry run failed this way under load) or
    sending the command again."""
    rate = 10.0
    clock, fake = _fake(rng, faults={"rate_hz": str(rate)}, scale=200.0)
    timeout_s = float(rng.uniform(0.1, 0.3))
    away = _HostAway(fake.endpoint["device"], away_s=timeout_s + float(rng.uniform(0.1, 0.3)), times=3)
    drv = OdometryDriver(away, timeout_s=timeout_s, ack_timeout_s=timeout_s, lockstep=True)
    try:
        t_v = drv.command_speed(0.5)  # away after the command's sync: its ack and sample wait on the line
        ts = [drv.read_sample().t_s for _ in range(3)]  # away after the next two syncs
    finally:
        drv.close()
        fake.close()
    assert away.left == 0
    assert ts[0] == pytest.approx(t_v, abs=1e-3)
    assert np.allclose(np.diff(ts), 1 / rate, atol=1e-3)  # consecutive cycles, each once
    assert drv.command_stats.lost == 0 and drv.command_stats.sent == 1 and drv.command_stats.syncs == 3
    assert fake.stats["resent_samples"] == 0 and drv.command_stats.repeats == 0


def test_a_process_that_did_not_run_for_longer_than_the_timeout_still_gets_its_sample(rng):
    """While the driver waits, the whole process (the station and the simulated unit with it) does not run
    for longer than the sample timeout: a thread holds the interpreter, as a busy host or a long garbage
    collection would (soak runs failed so). That time is not the unit's silence: of one gap between two
    looks at the line only LISTEN_SLICE_S counts, and the sample comes when the process runs again."""
    clock, fake = _fake(rng, faults={"rate_hz": "2"}, scale=1.0)  # a cycle takes 0.5 s
    timeout_s = LISTEN_SLICE_S + 1.0  # the gap's slice and a cycle fit
    drv = OdometryDriver.open(fake.endpoint["device"], timeout_s=timeout_s, ack_timeout_s=0.5, lockstep=True)
    freeze_s = timeout_s + float(rng.uniform(0.3, 0.6))

    def hold_the_interpreter() -> None:
        while drv.command_stats.syncs < syncs + 1:  # the driver has asked for the next cycle and waits
            time.sleep(0.001)
        old = sys.getswitchinterval()
        sys.setswitchinterval(freeze_s)
        try:
            end = time.monotonic() + freeze_s
            while time.monotonic() < end:
                pass
        finally:
            sys.setswitchinterval(old)

    try:
        first = drv.read_sample()
        syncs = drv.command_stats.syncs
        hog = threading.Thread(target=hold_the_interpreter)
        t0 = time.monotonic()
        hog.start()
        second = drv.read_sample()
        waited = time.monotonic() - t0
        hog.join()
    finally:
        drv.close()
        fake.close()
    assert waited > timeout_s  # on the wall clock the wait outlasted the timeout
    assert second.t_s == pytest.approx(first.t_s + 0.5, abs=1e-3)


def test_the_lockstep_option_of_the_device_url_is_checked():
    with pytest.raises(ConfigError, match="lockstep must be 0 or 1"):
        OdometryDriver.from_url("nmea:///dev/null?lockstep=yes")


def _trailer_run(tmp_path, name, seed, lengths, time_scale):
    cfg = config_from_dict({
        "station": {"name": "yard", "store_path": str(tmp_path / f"{name}.sqlite"),
                    "report_dir": str(tmp_path / name)},
        "devices": {"odo": {"url": "nmea:///dev/ttyS1"}},
        "trailer": {"odometry": "odo", "serial": "TR-1", "commands": [["H", 0.18]], "settle_s": 5.0,
                    "duration_s": 25.0},
    })
    out = run_procedure(RunRequest(cfg, "trailer", run_id=name, yes=True, quiet=True, time_scale=time_scale, seed=seed,
                                   fake_options={"true_lengths_m": list(lengths)}, config_dir=tmp_path))
    with RunStore(tmp_path / f"{name}.sqlite") as store:
        assert out.status == "done", [s.message for s in store.steps(name) if s.message]
        return store.samples(name, "odometry"), store.result(name, "trailer")["result"]


def test_a_dry_run_gives_the_same_record_at_any_load_and_pace(rng, tmp_path):
    """The same seed, once nearly unpaced on an idle process, once paced with a thread that holds the interpreter
    busy: the same samples bit for bit, so the same link lengths."""
    seed = int(rng.integers(2**31))
    lengths = (float(rng.uniform(1.2, 1.3)), float(rng.uniform(2.4, 2.55)))
    a, res_a = _trailer_run(tmp_path, "idle", seed, lengths, 1000.0)
    stop = threading.Event()

    def busy():
        while not stop.is_set():
            sum(i * i for i in range(2000))

    hog = threading.Thread(target=busy, daemon=True)
    interval = sys.getswitchinterval()
    sys.setswitchinterval(0.001)  # the hog yields the interpreter every ms, not every 5: the same load, sooner
    hog.start()
    try:
        b, res_b = _trailer_run(tmp_path, "busy", seed, lengths, float(rng.uniform(15.0, 40.0)))
    finally:
        stop.set()
        hog.join()
        sys.setswitchinterval(interval)
    assert a["t"].size > 250
    for col in COLUMNS:  # what the unit measured, the set points, the phases
        assert np.array_equal(a[col], b[col]), col
    assert (res_a["L1_m"], res_a["L2_m"]) == (res_b["L1_m"], res_b["L2_m"])
