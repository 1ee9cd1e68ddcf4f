"""Benchmark of the emScon tracker stream (run by hand, prints its figures).

    .venv/bin/python bench/bench_tracker_stream.py [--quick]

1. 1000 Hz for 60 s of simulated time, driver against the emScon fake
   measuring the simulated world over loopback: lost samples must be 0.
2. Highest sample rate sustained end to end without loss (fake + driver in
   one process on this machine): the device rate is 1000 Hz on the wire
   (whole milliseconds between points), so the world clock is sped up until
   the fake's device buffer overflows or the driver reports lost samples.
3. The driver alone: a replay server blasts pre-encoded MultiMeasResult
   packets over loopback; samples per second the driver decodes, validates
   and buffers, and CPU time per 1000 samples.
"""

from __future__ import annotations

import argparse
import socket
import threading
import time

import numpy as np

from drivers import emscon_codec as ec
from drivers.emscon import EmsconTracker
from drivers.transport import TcpTransport, tcp_factory


def _world(time_scale: float):
    try:
        from fakes.sim.world import make_world

        return make_world(seed=1, time_scale=time_scale)
    except ImportError:  # the world is not there yet: a still target on a SimClock
        from fakes.sim.clock import SimClock

        class _Source:
            def __init__(self):
                self.clock = SimClock(time_scale)
                self.rate_hz = 1000.0

            def measure(self, t):
                t = np.asarray(t, dtype=float)
                return np.tile([1500.0, 200.0, 300.0], (t.size, 1)), np.ones(t.size, bool)

        class _World:
            def __init__(self):
                self.source = _Source()
                self.clock = self.source.clock

            def tracker_source(self):
                return self.source

            def close(self):
                pass

        return _World()


def run_stream(time_scale: float, sim_seconds: float) -> dict:
    """Stream 1000 Hz through fake + driver for ``sim_seconds``; return figures."""
    from fakes.emscon import start_fake

    world = _world(time_scale)
    fake = start_fake(world)
    tracker = EmsconTracker(tcp_factory(fake.endpoint["host"], fake.endpoint["port"]))
    try:
        tracker.connect(timeout_s=30)
        cpu0, wall0 = time.process_time(), time.monotonic()
        tracker.start_stream(1000.0)
        t_end = world.clock.now() + sim_seconds
        n = 0
        while world.clock.now() < t_end:
            n += len(tracker.read_samples(0.05))
        record = tracker.stop_stream()
        n += len(tracker.read_samples(0.0))
        wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
    finally:
        tracker.close()
        fake.close()
        world.close()
    return {"received": record.received, "delivered": n, "lost": record.lost,
            "dropped_by_device": fake.stats["samples_dropped"], "grid_points": record.grid_points,
            "wall_s": wall, "cpu_s": cpu, "rate": record.received / wall}


class _ReplayServer:
    """Answers the connect/stream commands with OK and blasts pre-encoded samples."""

    def __init__(self, n_samples: int, per_packet: int = 1000) -> None:
        t_us = np.arange(n_samples, dtype=np.int64) * 1000 + 1_000_000
        xyz = np.column_stack([np.linspace(0, 1000, n_samples)] * 3)
        self.blob = b"".join(
            ec.MultiMeasResult.from_arrays(t_us[i:i + per_packet], xyz[i:i + per_packet]).encode()
            for i in range(0, n_samples, per_packet))
        self.n = n_samples
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(1)
        self.port = self.sock.getsockname()[1]
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        conn, _ = self.sock.accept()
        buf = b""
        with conn:
            while True:
                data = conn.recv(4096)
                if not data:
                    return
                buf += data
                while True:
                    consumed, frame = ec.decode(buf, from_server=False)
                    if not consumed:
                        break
                    buf = buf[consumed:]
                    if frame.command == ec.Command.GET_SYSTEM_STATUS:
                        conn.sendall(ec.CommandReply(1, 0, (0, 5, 3, 2, 3, 6, 0, 0, 0, 1)).encode())
                    else:
                        conn.sendall(ec.CommandReply(frame.command, 0).encode())
                    if frame.command == ec.Command.START_MEASUREMENT:
                        conn.sendall(self.blob)

    def close(self) -> None:
        self.sock.close()
        self.thread.join(timeout=5)


def driver_alone(n_samples: int) -> dict:
    server = _ReplayServer(n_samples)
    tracker = EmsconTracker(lambda: TcpTransport("127.0.0.1", server.port))
    try:
        tracker.connect(timeout_s=10)
        cpu0, wall0 = time.process_time(), time.monotonic()
        tracker.start_stream(1000.0)
        got = 0
        while got < n_samples:
            got += len(tracker.read_samples(1.0))
        wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
        record = tracker.stop_stream()
    finally:
        tracker.close()
        server.close()
    return {"samples": got, "lost": record.lost, "rate": got / wall, "cpu_ms_per_1000": 1e3 * cpu / got * 1000}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter runs")
    args = ap.parse_args()

    print("1) 1000 Hz, 60 s simulated, emScon fake + driver over loopback")
    r = run_stream(time_scale=10.0, sim_seconds=60.0)
    print(f"   received {r['received']} of {r['grid_points']} grid points, lost {r['lost']}, "
          f"device overflow {r['dropped_by_device']}, {r['wall_s']:.1f} s wall, "
          f"CPU {1e3 * r['cpu_s'] / max(r['received'], 1) * 1000:.2f} ms per 1000 samples (fake + driver)")
    print("   PASS: zero lost" if r["lost"] == 0 and r["dropped_by_device"] == 0 else "   FAIL: samples lost")

    print("2) highest rate sustained without loss, fake + driver (1000 Hz device, faster world clock)")
    best = None
    for scale in (10, 20, 40, 80, 160, 320, 640):
        sim = (2.0 if args.quick else 5.0) * scale
        r = run_stream(time_scale=float(scale), sim_seconds=sim)
        ok = r["lost"] == 0 and r["dropped_by_device"] == 0
        print(f"   x{scale:>4}: {r['rate']:>9.0f} samples/s real, lost {r['lost']}, "
              f"device overflow {r['dropped_by_device']} -> {'ok' if ok else 'LOSS'}")
        if not ok:
            break
        best = r["rate"]
    print(f"   highest sustained: {best or 0:.0f} samples/s")

    print("3) driver alone (replay server over loopback)")
    r = driver_alone(500_000 if args.quick else 2_000_000)
    print(f"   {r['samples']} samples at {r['rate']:.0f} samples/s, lost {r['lost']}, "
          f"CPU {r['cpu_ms_per_1000']:.3f} ms per 1000 samples")


if __name__ == "__main__":
    main()
