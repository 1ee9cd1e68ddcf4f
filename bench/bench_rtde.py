"""RTDE state stream of the UR fake: 500 Hz for 60 s of simulated time.

Run by hand::

    .venv/bin/python bench/bench_rtde.py [--time-scale 4] [--seconds 60] [--rate 500]

Two clients, one after the other, each for ``--seconds`` simulated seconds
while the simulated UR5e sweeps between two poses:

1. a raw RTDE client (the project's codec) that decodes every data package
   of ``ur_rtde``'s default 58-variable recipe: packages received vs sent by
   the fake (exact: the client pauses the stream and reads up to the pause
   reply), timestamp gaps, and how late each package arrives (host time
   after its simulated timestamp);
2. ``ur_rtde``'s own ``RTDEReceiveInterface`` through the driver's sidecar
   process: distinct samples the driver obtained vs packages sent.
   ``ur_rtde`` keeps only the newest package when several are queued, so
   this counts what a state client sees, not what the wire carried.
"""

from __future__ import annotations

import argparse
import os
import socket
import struct
import sys
import time

import numpy as np

try:
    import fakes  # noqa: F401
except ModuleNotFoundError:  # run from a checkout without an installed package
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from drivers.ur import RtdeSidecar  # noqa: E402
from fakes import rtde_protocol as rp  # noqa: E402
from fakes.sim.world import make_world  # noqa: E402
from fakes.ur import start_fake  # noqa: E402

#: ur_rtde 1.6's default output list for an e-Series controller (58 variables)
UR_RTDE_DEFAULT = (
    "timestamp,target_q,target_qd,target_qdd,target_current,target_moment,actual_q,actual_qd,actual_current,"
    "joint_control_output,actual_TCP_pose,actual_TCP_speed,actual_TCP_force,target_TCP_pose,target_TCP_speed,"
    "actual_digital_input_bits,joint_temperatures,actual_execution_time,robot_mode,joint_mode,safety_mode,"
    "actual_tool_accelerometer,speed_scaling,target_speed_fraction,actual_momentum,actual_main_voltage,"
    "actual_robot_voltage,actual_robot_current,actual_joint_voltage,actual_digital_output_bits,runtime_state,"
    "standard_analog_input0,standard_analog_input1,standard_analog_output0,standard_analog_output1,"
    "robot_status_bits,safety_status_bits,ft_raw_wrench,payload,payload_cog,payload_inertia,"
    "output_int_register_2,output_int_register_12,output_int_register_13,output_int_register_14,"
    "output_int_register_15,output_int_register_16,output_int_register_17,output_int_register_18,"
    "output_int_register_19,output_double_register_12,output_double_register_13,output_double_register_14,"
    "output_double_register_15,output_double_register_16,output_double_register_17,output_double_register_18,"
    "output_double_register_19"
).split(",")


def keep_moving(world, until_s: float) -> None:
    q0 = np.asarray(world.robot.home_q_rad, dtype=float)
    q1 = q0 + np.array([0.6, -0.3, 0.4, 0.3, 0.5, 0.8])
    t = world.clock.now()
    i = 0
    while t < until_s:
        m = world.arm.move_joint(q1 if i % 2 == 0 else q0, speed_frac=0.3, accel_frac=0.5)
        t = m.t_end
        i += 1


def raw_client(host: str, world, fake, rate_hz: float, seconds: float) -> dict:
    clock = world.clock
    scale = clock.time_scale
    s = socket.create_connection((host, 30004), timeout=10)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    buf = bytearray()

    def packets():
        while True:
            n, p = rp.decode(buf)
            if n:
                del buf[:n]
                yield p
            else:
                buf.extend(s.recv(1 << 20))

    it = packets()

    def ask(cmd, payload=b""):
        s.sendall(rp.encode(cmd, payload))
        for p in it:
            if p.command == cmd:
                return p

    ask(rp.CMD_REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2))
    ask(rp.CMD_GET_URCONTROL_VERSION)
    reply = ask(rp.CMD_SETUP_OUTPUTS, struct.pack(">d", rate_hz) + ",".join(UR_RTDE_DEFAULT).encode())
    types = reply.payload[1:].decode().split(",")
    recipe = rp.Recipe(reply.payload[0], UR_RTDE_DEFAULT, types)
    sent0 = fake.packets_sent
    s.sendall(rp.encode(rp.CMD_START))
    ts, lag_s = [], []
    t_first = None
    paused = False
    for p in it:
        if p.command == rp.CMD_DATA_PACKAGE:
            t = struct.unpack_from(">d", p.payload, 1)[0]
            now = clock.now()
            ts.append(t)
            lag_s.append((now - t) / scale)
            if t_first is None:
                t_first = t
            elif not paused and t - t_first >= seconds - 0.5 / rate_hz:
                s.sendall(rp.encode(rp.CMD_PAUSE))
                paused = True
        elif p.command == rp.CMD_PAUSE:
            break
    s.close()
    time.sleep(0.2)
    sent = fake.packets_sent - sent0
    ts = np.array(ts)
    gaps = np.round(np.diff(ts) * rate_hz).astype(int)
    lag = np.array(lag_s) * 1000.0
    return {
        "sent": sent,
        "received": len(ts),
        "bytes_per_package": recipe.packet_size,
        "span_s": ts[-1] - ts[0],
        "missing_in_sequence": int(np.sum(gaps - 1)),
        "lag_ms": (np.median(lag), np.percentile(lag, 99), lag.max()),
    }


def ur_rtde_client(host: str, world, fake, rate_hz: float, seconds: float) -> dict:
    side = RtdeSidecar(host, rate_hz, poll_s=1e-4)
    t0 = time.monotonic()
    side.start(30.0)
    setup_s = time.monotonic() - t0
    sent0 = fake.packets_sent
    rows = []
    t_start = None
    while True:
        r, dropped, connected = side.drain()
        if len(r):
            rows.append(r)
            if t_start is None:
                t_start = r[0, 0]
            if r[-1, 0] - t_start >= seconds:
                break
        if not connected:
            break
        time.sleep(0.05)
    side.close()
    time.sleep(0.2)
    sent = fake.packets_sent - sent0
    t = np.concatenate(rows)[:, 0]
    t = t[t - t_start <= seconds]
    gaps = np.round(np.diff(t) * rate_hz).astype(int)
    expected = int(round(seconds * rate_hz)) + 1
    return {
        "handshake_s": setup_s,
        "sent_total": sent,
        "expected_in_window": expected,
        "seen": len(t),
        "max_gap_packages": int(gaps.max()) if len(gaps) else 0,
        "gaps_gt1": int(np.sum(gaps > 1)),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--time-scale", type=float, default=4.0)
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per client")
    ap.add_argument("--rate", type=float, default=500.0, help="RTDE output frequency, Hz")
    args = ap.parse_args()
    world = make_world(robot="ur5e", seed=0, time_scale=args.time_scale)
    fake = start_fake(world)
    host = fake.endpoint["host"]
    print(f"UR fake on {host}, {args.rate:g} Hz, {args.seconds:g} s simulated per client, time_scale {args.time_scale:g}")
    try:
        keep_moving(world, world.clock.now() + 2.5 * args.seconds + 30)
        t0 = time.monotonic()
        raw = raw_client(host, world, fake, args.rate, args.seconds)
        wall = time.monotonic() - t0
        print("raw RTDE client (every package decoded, ur_rtde's 58-variable recipe):")
        print(f"  packages sent {raw['sent']}, received {raw['received']}, "
              f"lost {raw['sent'] - raw['received']} ({raw['bytes_per_package']} B each)")
        print(f"  simulated span {raw['span_s']:.3f} s = {raw['span_s'] * args.rate + 1:.0f} periods; "
              f"missing in the timestamp sequence: {raw['missing_in_sequence']}")
        med, p99, mx = raw["lag_ms"]
        print(f"  arrival after the sample's time (host ms): median {med:.2f}, p99 {p99:.2f}, max {mx:.2f}")
        print(f"  wall time {wall:.1f} s, {raw['received'] / wall:.0f} packages/s, "
              f"{raw['received'] * raw['bytes_per_package'] / wall / 1e6:.2f} MB/s")
        t0 = time.monotonic()
        ur = ur_rtde_client(host, world, fake, args.rate, args.seconds)
        wall = time.monotonic() - t0
        print("ur_rtde RTDEReceiveInterface (driver sidecar, 12-variable recipe):")
        print(f"  handshake {ur['handshake_s']:.2f} s; packages sent {ur['sent_total']} "
              f"(window of {args.seconds:g} s: {ur['expected_in_window']})")
        print(f"  distinct samples seen by the driver {ur['seen']} "
              f"({100.0 * ur['seen'] / ur['expected_in_window']:.1f} % of the window); "
              f"gaps > 1 period {ur['gaps_gt1']}, largest {ur['max_gap_packages']} periods")
        print(f"  wall time {wall:.1f} s")
    finally:
        fake.close()
        world.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
