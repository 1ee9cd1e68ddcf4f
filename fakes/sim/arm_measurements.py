"""Simulated arm calibration data: a true arm measured at random poses by an instrument.

The truth is a kinematic model (e.g. seed 002 Table 3, ``rb5-850-as-built``);
the instrument sits in a frame of its own (unknown to the calibration) and
adds isotropic noise. The file it makes is the arm measurement CSV that
``station calibrate arm --data`` reads.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from station.models import kinematics as kin


def random_poses(joint_limits_rad, n: int, rng: np.random.Generator, *, span_rad: float = 2.6) -> np.ndarray:
    """``n`` joint vectors (n, 6) drawn uniformly inside the limits, each joint within +-``span_rad``."""
    lim = np.asarray(joint_limits_rad, dtype=float)
    lo = np.maximum(lim[:, 0], -span_rad)
    hi = np.minimum(lim[:, 1], span_rad)
    return rng.uniform(lo, hi, (n, 6))


def instrument_frame(rng: np.random.Generator, *, distance_mm: float = 2000.0) -> np.ndarray:
    """A random instrument <- robot base transform (4, 4): any rotation, a few metres away."""
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.normal(0.0, distance_mm / np.sqrt(3), 3)
    return T


def measure(dh_true, q_rad, base_T, noise_mm: float, rng: np.random.Generator) -> np.ndarray:
    """Tool points (n, 3) of the true arm at ``q_rad`` in the instrument frame, with noise."""
    p = kin.tool_position(dh_true, q_rad)
    return p @ base_T[:3, :3].T + base_T[:3, 3] + rng.normal(0.0, noise_mm, p.shape)
