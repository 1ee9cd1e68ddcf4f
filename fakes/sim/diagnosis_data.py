"""Simulated arm measurements with chosen error effects switched on, for the diagnosis.

A true arm (nominal table + the effects of an :class:`EffectSet`) visits
random poses one after another (so each joint's last motion direction is the
sign of its step from the previous pose), stops with the repeatability
scatter of :func:`realistic_stop_sigma_rad` and is measured by an instrument
in a random frame with isotropic noise. Rows come out in measurement order,
with ``t`` (s since the arm started working), ``temperature`` (degC: 20 +
the warm-up rise + sensor noise) and ``load`` (kg) as the arm CSV has them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fakes.sim.arm_measurements import instrument_frame, random_poses
from station.models import kinematics as kin
from station.models.effects import EffectContext, EffectSet, motion_directions

__all__ = ["ArmDataset", "simulate_arm_data"]


@dataclass(frozen=True)
class ArmDataset:
    q_rad: np.ndarray
    xyz_mm: np.ndarray
    t_s: np.ndarray
    temperature_c: np.ndarray
    load_kg: np.ndarray
    base_T: np.ndarray
    effects: EffectSet
    noise_mm: float
    stop_sigma_rad: np.ndarray

    def true_points(self, robot, effects: EffectSet | None = None) -> np.ndarray:
        """Noise-free points of the true arm (or with ``effects`` instead) at the same rows."""
        return _points(robot, self.effects if effects is None else effects, self.q_rad, self.t_s,
                       self.load_kg, self.base_T, np.zeros((self.q_rad.shape[0], 6)))


def _points(robot, effects, q, t, load, base_T, stop_offsets):
    ctx = EffectContext(robot=robot, last_dir=motion_directions(q), warmup_s=t, payload_kg=float(load[0]))
    dh_eff, q_eff = effects.apply(robot.dh_nominal, q, ctx)
    p = kin.tool_position(dh_eff, q_eff + stop_offsets)
    return p @ base_T[:3, :3].T + base_T[:3, 3]


def simulate_arm_data(robot, effects: EffectSet, rng: np.random.Generator, *, n: int = 200,
                      noise_mm: float | None = None, stop_sigma_mm: float | None = None,
                      seconds_per_pose: float = 30.0, load_kg: float = 0.0, span_rad: float = 2.6) -> ArmDataset:
    """Measure the true arm (nominal + ``effects``) at ``n`` random poses in order.

    ``noise_mm`` (1-sigma per coordinate) defaults to U(0.01, 0.025) mm (a
    laser tracker a few metres away); ``stop_sigma_mm`` to the realistic
    repeatability scatter of :func:`realistic_stop_sigma_rad`.
    """
    from station.models.effects import realistic_stop_sigma_rad

    q = random_poses(robot.joint_limits_rad, n, rng, span_rad=span_rad)
    t = np.cumsum(rng.uniform(0.6, 1.4, n) * seconds_per_pose)
    load = np.full(n, float(load_kg))
    base_T = instrument_frame(rng)
    sig_q = realistic_stop_sigma_rad(robot, rng, stop_sigma_mm)
    noise = float(rng.uniform(0.01, 0.025)) if noise_mm is None else float(noise_mm)
    stops = rng.normal(0.0, 1.0, (n, 6)) * sig_q
    pts = _points(robot, effects, q, t, load, base_T, stops) + rng.normal(0.0, noise, (n, 3))
    thermal = effects.effect("thermal_drift")
    dT = thermal.temperature_rise_K(effects.get("thermal_drift"), EffectContext(warmup_s=t), n) \
        if effects.is_enabled("thermal_drift") else np.zeros(n)
    temp = 20.0 + dT + rng.normal(0.0, 0.05, n)
    return ArmDataset(q, pts, t, temp, load, base_T, effects, noise, sig_q)
