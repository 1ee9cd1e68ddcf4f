"""Arm calibration on a UR keeps its moves within the TCP speed cap instead of being refused.

A UR5e's joints turn fast for its size: at the default 20 % some long joint moves of a drawn calibration plan
are estimated above the 1 m/s TCP cap (at HEAD 2978242, 4 to 8 poses of a plan were refused at preflight
unless the user found `speed_percent = 10`). Each move's speed is now the plan's, or less for a move that
would pass the cap (:func:`procedures.arm_calibration.move_speed_frac`).
"""

from pathlib import Path

import numpy as np

import procedures.arm_calibration as ac
from fakes.cells import demo_config
from station.config import config_from_dict


def test_a_ur_calibration_plan_chooses_each_moves_speed_within_the_cap(rng):
    d = demo_config(Path("unused"), cycles=3, vap_cycles=2, rate_hz=100.0, robot="ur5e")
    speed = float(rng.uniform(20.0, 60.0))
    d["arm_calibration"] = {"train_poses": 23, "test_poses": 8, "poses_per_step": 4, "candidates": 600,
                            "speed_percent": speed}
    plan = ac.plan_from_config(config_from_dict(d, "UR5e calibration"),
                               selection_seed=int(rng.integers(0, 2**32)))
    assert ac.check_programs(plan) == []
    gate = plan.gate()
    w, _ = ac.plan_path_deg(plan)
    slowed = 0
    for k in range(len(plan.q_deg)):
        moves = [s for s in ac.pose_program(plan, k, gate).statements if hasattr(s, "speed_frac")]
        for m, qa, qb in zip(moves, w[2 * k: 2 * k + 2], w[2 * k + 1: 2 * k + 3]):
            at_plan = gate.joint_move_peak_tcp_speed(np.radians(qa), np.radians(qb), plan.speed_frac)
            chosen = gate.joint_move_peak_tcp_speed(np.radians(qa), np.radians(qb), m.speed_frac)
            assert chosen <= gate.max_tcp_speed_mm_s
            if at_plan <= ac.SPEED_CAP_MARGIN * gate.max_tcp_speed_mm_s:
                assert m.speed_frac == plan.speed_frac  # only the moves that need it are slower
            else:
                slowed += 1
                assert m.speed_frac < plan.speed_frac
    print(f"speed {speed:.0f} %: {slowed} of {2 * len(plan.q_deg)} moves slowed to the cap")
