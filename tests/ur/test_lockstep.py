"""The UR cell in lockstep: its programs run the world's clock, which stands still between them, and its RTDE
stream holds the clock at the package the driver has not yet kept, so the same seed gives the same tracker
samples, RTDE readings, figures and controller states at any pace and load (ur_rtde judging the stream)."""

from __future__ import annotations

import numpy as np

from app.assemble import RunRequest, run_procedure
from fakes.station import FakeStation
from station.config import config_from_dict
from station.store import RunStore
from tests.pace import UR_RTDE_HZ
from tests.person import person_typing_yes
from tests.ur.test_iso_procedure import UR_ISO


class _Wire:
    """The project's RTDE codec as a bare client of a socket: what arrives, in order."""

    def __init__(self, sock) -> None:
        self.sock, self.buf = sock, bytearray()

    def until(self, command) -> tuple[list, object]:
        """The data packages that arrive before the first ``command`` packet, and that packet."""
        from fakes import rtde_protocol as rp

        data = []
        while True:
            n, p = rp.decode(self.buf)
            if not n:
                self.buf.extend(self.sock.recv(65536))
                continue
            del self.buf[:n]
            if p.command == command:
                return data, p
            if p.command == rp.CMD_DATA_PACKAGE:
                data.append(p)


def _run(tmp_path, name, seed, time_scale):
    with FakeStation.start(seed=seed, time_scale=time_scale, robot="ur5e", rtde_hz=UR_RTDE_HZ) as cell:
        assert cell.controller_url.endswith("lockstep=1") and cell.controller.lockstep
        d = cell.config_dict(store_path=str(tmp_path / f"{name}.sqlite"), report_dir=str(tmp_path / name),
                             iso9283={**UR_ISO, "cycles": 3, "vap_cycles": 2})
        out = run_procedure(RunRequest(config_from_dict(d), "iso9283", arm=True, operator=person_typing_yes(), quiet=True,
                                       run_id=name, config_dir=tmp_path))
    with RunStore(tmp_path / f"{name}.sqlite") as store:
        assert out.exit_code in (0, 1), [s.message for s in store.steps(name) if s.message]
        return (store.samples(name, "tracker"), store.samples(name, "robot"),
                {(c["pose"], c["name"]): c["value"] for c in store.characteristics(name)})


def test_a_ur_run_gives_the_same_samples_and_figures_at_any_pace_and_load(tmp_path, rng):
    """Twice, at paces 2-4 times apart (a late thread of a busy host is a slower pace here; the trailer's
    lockstep test holds the interpreter busy too)."""
    seed = int(rng.integers(2**31))
    tracker_a, robot_a, chars_a = _run(tmp_path, "fast", seed, float(rng.uniform(80.0, 120.0)))
    tracker_b, robot_b, chars_b = _run(tmp_path, "slow", seed, float(rng.uniform(25.0, 35.0)))
    assert tracker_a["t"].size > 1000 and robot_a["t"].size > 100
    # the RTDE readings too: the driver's receive process says which package it kept, and the stream sends the
    # next one (and lets the clock past it) only then; so every package of the run is stored, in both runs
    for stream_a, stream_b in ((tracker_a, tracker_b), (robot_a, robot_b)):
        assert set(stream_a) == set(stream_b)
        for col in stream_a:
            assert np.array_equal(stream_a[col], stream_b[col], equal_nan=True), col
    periods = np.round(np.diff(robot_a["t"]) * UR_RTDE_HZ)
    assert np.all(periods <= 1), "a package of the stream is missing"  # a stop's instant lies between two
    assert chars_a == chars_b


def test_the_stream_holds_the_clock_until_the_client_says_it_kept_a_package(rng):
    """On the wire (the project's RTDE codec as the client): while the client owns input register 22, the
    lockstep stream sends a new package only after the client wrote there the last one's timestamp, and the
    world's clock waits at the next package's instant meanwhile; a paused stream holds nothing."""
    import socket
    import struct

    from fakes import rtde_protocol as rp
    from fakes.sim.clock import SimClock
    from fakes.sim.world import make_world
    from fakes.ur import start_fake
    from station.protocols.ur import LOCKSTEP_STORED_REGISTER

    hz = float(rng.choice([5.0, 10.0, 25.0]))
    world = make_world(robot="ur5e", seed=int(rng.integers(2**31)), clock=SimClock(1e4, lockstep=True))
    fake = start_fake(world, lockstep=True)
    s = socket.create_connection((fake.endpoint["host"], 30004), timeout=5)
    wire = _Wire(s)
    out = rp.Recipe(1, ["timestamp"], ["DOUBLE"])
    kept = rp.Recipe(1, [f"input_double_register_{LOCKSTEP_STORED_REGISTER}"], ["DOUBLE"])

    def packets(until):
        """Package timestamps as they come, up to the first ``until`` command (a package: up to that one)."""
        data, last = wire.until(until)
        return [out.decode(p.payload)["timestamp"] for p in data + ([last] if until == rp.CMD_DATA_PACKAGE else [])]

    try:
        for cmd, payload in ((rp.CMD_REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2)),
                             (rp.CMD_SETUP_OUTPUTS, struct.pack(">d", hz) + b"timestamp"),
                             (rp.CMD_SETUP_INPUTS, kept.names[0].encode())):
            s.sendall(rp.encode(cmd, payload))
            packets(cmd)
        s.sendall(rp.encode(rp.CMD_START))
        packets(rp.CMD_START)
        t_first = packets(rp.CMD_DATA_PACKAGE)[-1]
        t_end = t_first + float(rng.uniform(1.0, 2.0))
        world.clock.schedule(t_end)  # something in the world wants the clock to run on
        assert not world.clock.wait_for(t_end, 0.3)  # not kept: held at the next package's instant
        assert world.clock.now() <= t_first + 1.0 / hz + 1e-9
        stamps = [t_first]
        while stamps[-1] < t_end - 1.0 / hz:
            s.sendall(kept.encode({kept.names[0]: stamps[-1]}))
            new = [t for t in packets(rp.CMD_DATA_PACKAGE) if t > stamps[-1]]
            while not new:  # repeats of the last one first
                new = [t for t in packets(rp.CMD_DATA_PACKAGE) if t > stamps[-1]]
            assert len(new) == 1  # one at a time
            stamps += new
        np.testing.assert_allclose(np.diff(stamps), 1.0 / hz, rtol=0, atol=1e-9)  # none skipped
        s.sendall(rp.encode(rp.CMD_PAUSE))
        packets(rp.CMD_PAUSE)
        t_on = world.clock.now() + float(rng.uniform(1.0, 3.0))
        world.clock.schedule(t_on)
        assert world.clock.wait_for(t_on, 5.0)  # paused: the stream holds the clock no more
    finally:
        s.close()
        fake.close()
        world.close()


def test_a_new_client_gets_no_state_older_than_its_stream(rng):
    """A client that starts streaming after a program stopped (a resumed station's new session) gets packages
    from its start on, not the older program-stop instants the stream keeps for the client that saw them: its
    first reading is where the arm stands now."""
    import socket
    import struct

    from fakes import rtde_protocol as rp
    from fakes.sim.clock import SimClock
    from fakes.sim.world import make_world
    from fakes.ur import start_fake
    from station.protocols.ur import LOCKSTEP_STORED_REGISTER

    world = make_world(robot="ur5e", seed=int(rng.integers(2**31)), clock=SimClock(1e4, lockstep=True))
    fake = start_fake(world, lockstep=True)
    host = fake.endpoint["host"]
    try:
        q0 = world.robot.home_q_rad + rng.uniform(-0.2, 0.2, 6)
        with socket.create_connection((host, 30003), timeout=5) as script:
            script.sendall(("movej([" + ", ".join(f"{v:.6f}" for v in q0) + "], a=1.0, v=0.5)\n").encode())
        with socket.create_connection((host, 29999), timeout=5) as dash:
            f = dash.makefile("rw")
            f.readline()  # greeting
            running = True
            for _ in range(2000):
                f.write("running\n")
                f.flush()
                running = f.readline().strip().endswith("true")
                if not running and fake.ctl.arm.queue_end_s > 0:
                    break
            assert not running
        t_on = world.clock.now() + float(rng.uniform(1.0, 3.0))  # the world runs on after the stop
        world.clock.schedule(t_on)
        assert world.clock.wait_for(t_on, 5.0)

        s = socket.create_connection((host, 30004), timeout=5)
        wire = _Wire(s)
        out = rp.Recipe(1, ["timestamp", "actual_q"], ["DOUBLE", "VECTOR6D"])

        with s:
            for cmd, payload in ((rp.CMD_REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2)),
                                 (rp.CMD_SETUP_OUTPUTS, struct.pack(">d", 10.0) + b"timestamp,actual_q"),
                                 (rp.CMD_SETUP_INPUTS, f"input_double_register_{LOCKSTEP_STORED_REGISTER}".encode())):
                s.sendall(rp.encode(cmd, payload))
                wire.until(cmd)
            t_start = world.clock.now()
            s.sendall(rp.encode(rp.CMD_START))
            first = out.decode(wire.until(rp.CMD_DATA_PACKAGE)[1].payload)
        assert first["timestamp"] >= t_start
        np.testing.assert_allclose(first["actual_q"], q0, atol=1e-3)
    finally:
        fake.close()
        world.close()
