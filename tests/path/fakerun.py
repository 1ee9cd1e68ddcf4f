"""Run an ISO path programme on a simulated world through the fake controller's RAPID interpreter (offline clock),
and read back what the arm did: commanded and true TCP, the tracker's stream, the truth the tracker would read."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fakes.rapid_interp import RapidRun, compile_rapid
from station.models import kinematics as kin
from station.programs import render_rapid
from station.safety import SafetyGate, default_limits

RATE_HZ = 1000.0


@dataclass
class PathRun:
    t: np.ndarray  # sample times from the end of the approach to the end of the programme, s
    commanded: np.ndarray  # the controller's TCP (nominal model of the commanded joints), base frame, mm
    true: np.ndarray  # the arm's true TCP, base frame, mm
    measured: np.ndarray  # the tracker's stream, taken back into the base frame by the true registration
    read_truth: np.ndarray  # what the tracker reads of the true TCP, its noise aside (base frame)
    noise_sd_mm: float  # one reading's sd about the truth (white and wander together)
    noise: object  # the tracker's noise model (TrackerNoise: white, wander and its time)


def run(world, path_test) -> PathRun:
    gate = SafetyGate(world.robot, default_limits(world.robot))
    compiled = compile_rapid(render_rapid(path_test.program).text, world.robot, gate,
                             q_start=world.arm.commanded_q_rad(world.clock.now()))
    t0 = float(world.clock.now())
    RapidRun(world, compiled, gate, lambda p: None).run()
    t1 = float(world.clock.now())
    approach = next(m for m in world.arm.moves if m.t_start >= t0 - 1e-9 and m.kind == "joint")
    t = np.arange(approach.t_end, t1 + 0.2, 1.0 / RATE_HZ)
    tr = world.tracker
    xyz, valid = world.tracker_source().measure(t)
    assert valid.all()
    T = world.base_T_tracker
    back = lambda p: p @ T[:3, :3].T + T[:3, 3]  # noqa: E731
    read = tr.reading(tr.to_tracker_frame(world.arm.tool_position_mm(t - tr.latency_s)))
    noise = float(np.hypot(tr.noise.white_um, tr.noise.wander_um)) * 1e-3
    return PathRun(t, kin.tool_position(world.robot.dh_nominal, world.arm.commanded_q_rad(t)),
                   world.arm.tool_position_mm(t), back(xyz), back(read), noise, tr.noise)
