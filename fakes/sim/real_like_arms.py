"""Simulated measurement sets that look like real lab data of industrial arms.

What the lab's own sets look like, and these reproduce:

* 30-60 poses; either one joint moved at a time from a home pose (sweeps,
  the last joint last: ``fanuc_like``) or poses spread over the joint space
  (``rokae_like``);
* the vendor's nominal model misses the measured points by 2-3 mm (after
  the best rigid placement), the true arm differing by build tolerances of
  a few tenths of a millimetre and a few hundredths of a degree, plus a
  tool offset known to a millimetre or two;
* measurement noise 0.05-0.15 mm per coordinate: a tracker with three
  reflectors on the flange (the tool point is their centroid, each measured
  with the noise) or one 6-DoF target;
* hidden effects drawn at random (none, one or two): gravity compliance of
  joints 2 and 3 from a mass distribution along the links (not the
  diagnosis' basis), first-harmonic encoder eccentricity, backlash against
  the direction of the last motion; each with a tool-point RMS of
  U(0.5, 1.5) times the noise.

With ``n_unseen`` the set is followed by that many more poses of the same arm,
instrument and hidden effects, measured after it (spread poses like the set's;
for sweeps, one joint at a time within the sweeps' spans): a yardstick of
unseen poses larger than a split's few (``LookalikeSet.n_set`` is the set's
size, its first rows). The generator draws everything from the given
``rng``; a test prints the seed it made the ``rng`` from. Units: mm, rad
inside; rows in measurement order with ``t`` in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fakes.sim.arm_measurements import instrument_frame
from station.models import kinematics as kin
from station.models.effects import motion_directions

__all__ = ["LookalikeSet", "fanuc_like", "rokae_like", "FANUC_LIKE_DEG", "ROKAE_LIKE_DEG"]

#: a FANUC-class 20 kg arm (a, alpha, d, theta, beta; mm, deg): offsets a1, a3 and a long forearm
FANUC_LIKE_DEG = np.array([[150.0, -90, 525, 0, 0], [790, 0, 0, -90, 0], [150, -90, 0, 0, 0],
                           [0, 90, 860, 0, 0], [0, -90, 0, 0, 0], [0, 0, 100, 0, 0], [0, 0, 120, 0, 0]])
#: a ROKAE-class 7 kg arm
ROKAE_LIKE_DEG = np.array([[0.0, -90, 380, 0, 0], [420, 0, 0, -90, 0], [0, -90, 0, 0, 0],
                           [0, 90, 400, 0, 0], [0, -90, 0, 0, 0], [0, 0, 136, 0, 0], [0, 0, 80, 0, 0]])
FANUC_LIMITS_DEG = np.array([[-170, 170], [-100, 160], [-70, 180], [-190, 190], [-140, 140], [-360, 360]])
ROKAE_LIMITS_DEG = np.array([[-170, 170], [-120, 120], [-120, 120], [-170, 170], [-120, 120], [-360, 360]])


@dataclass(frozen=True)
class LookalikeSet:
    name: str
    dh_nominal: np.ndarray
    dh_true: np.ndarray
    joint_limits_rad: np.ndarray
    q_rad: np.ndarray
    xyz_mm: np.ndarray
    t_s: np.ndarray
    base_T: np.ndarray
    noise_mm: float
    target: str                      # "three reflectors" or "6-DoF target"
    hidden: list = field(default_factory=list)   # [(effect, joint)], what the generator put in
    joint_offsets_rad: np.ndarray | None = None  # the hidden effects' dq (N, 6)
    n_set: int | None = None         # the calibration set's poses (the first rows); the rest: unseen checks

    @property
    def unseen(self) -> np.ndarray:
        """Rows of the poses measured after the set (empty without ``n_unseen``)."""
        n = self.q_rad.shape[0] if self.n_set is None else self.n_set
        return np.arange(n, self.q_rad.shape[0])

    def true_points(self, rows=None) -> np.ndarray:
        rows = np.arange(self.q_rad.shape[0]) if rows is None else rows
        dq = self.joint_offsets_rad[rows] if self.joint_offsets_rad is not None else 0.0
        p = kin.tool_position(self.dh_true, self.q_rad[rows] + dq)
        return p @ self.base_T[:3, :3].T + self.base_T[:3, 3]


def _true_table(dh_nom: np.ndarray, rng, target_mm: tuple, q_probe) -> np.ndarray:
    """Build tolerances scaled so the nominal model misses by U(target_mm) mm RMS after a rigid fit."""
    from station.analysis.arm.identification import rigid_fit

    d = np.zeros_like(dh_nom)
    d[:, [0, 2]] = rng.normal(0.0, 0.4, (7, 2))
    d[:, [1, 3]] = np.radians(rng.normal(0.0, 0.06, (7, 2)))
    d[6, [0, 2]] = rng.normal(0.0, 1.0, 2)
    for i in range(5):
        if abs(math.sin(dh_nom[i, 1])) < 0.1:
            d[i, 4] = math.radians(rng.normal(0.0, 0.03))
    want = rng.uniform(*target_mm)
    p_nom = kin.tool_position(dh_nom, q_probe)

    def miss(scale):
        p = kin.tool_position(dh_nom + scale * d, q_probe)
        T = rigid_fit(p_nom, p)
        return float(np.sqrt(np.mean(np.sum((p - (p_nom @ T[:3, :3].T + T[:3, 3])) ** 2, axis=1))))

    s = want / max(miss(1.0), 1e-9)
    s *= want / max(miss(s), 1e-9)
    return dh_nom + s * d


def _link_mass_torques(dh, q) -> np.ndarray:
    """Gravity torques (N m) of masses along the links (not the diagnosis' elbow/TCP basis)."""
    F = kin.frames(dh, q)
    masses = [(2, 0.5, 25.0), (3, 0.0, 12.0), (4, 0.5, 10.0), (7, 0.0, 6.0)]  # (frame, fraction back to previous, kg)
    tau = np.zeros((q.shape[0], 6))
    z = F[:, :6, :3, 2]
    o = F[:, :6, :3, 3]
    for fi, back, m in masses:
        c = (1 - back) * F[:, fi, :3, 3] + back * F[:, fi - 1, :3, 3]
        lever = np.cross(z, c[:, None, :] - o)[:, :, 2] * 1e-3
        t = 9.80665 * m * lever
        t[:, fi:] = 0.0
        tau += t
    return tau


def _hidden(rng, q, dh_true, noise_mm, motion_order: bool, max_effects: int = 2, n_set: int | None = None):
    """Random hidden joint effects: (list of (effect, joint), dq (N, 6)); each sized on the set's first
    ``n_set`` poses (all without)."""
    n_eff = int(rng.integers(0, max_effects + 1))
    pool = [("joint_compliance", 2), ("joint_compliance", 3)]
    pool += [("encoder_eccentricity", j) for j in range(1, 6)]
    if motion_order:
        pool += [("backlash", j) for j in (1, 2, 3)]
    picks = [pool[i] for i in rng.choice(len(pool), n_eff, replace=False)]
    dq = np.zeros_like(q)
    tau = _link_mass_torques(dh_true, q)
    dirs = motion_directions(q)
    out = []
    for effect, j in picks:
        shape = np.zeros_like(q)
        if effect == "joint_compliance":
            shape[:, j - 1] = -tau[:, j - 1]
        elif effect == "encoder_eccentricity":
            ph = rng.uniform(0, 2 * np.pi)
            shape[:, j - 1] = np.sin(q[:, j - 1] + ph)
        else:
            shape[:, j - 1] = -dirs[:, j - 1]
        J = kin.joint_jacobian(dh_true, q)[:, :3, :]
        disp = np.einsum("nij,nj->ni", J, shape)
        rms = float(np.sqrt(np.mean(np.sum(disp[:n_set] ** 2, axis=1))))
        if rms <= 1e-12:
            continue
        want = rng.uniform(0.5, 1.5) * noise_mm * math.sqrt(3.0)
        dq += shape * (want / rms)
        out.append((effect, j))
    return out, dq


def _measure(dh_true, q, dq, B, noise, target, rng):
    p = kin.tool_position(dh_true, q + dq) @ B[:3, :3].T + B[:3, 3]
    if target == "three reflectors":
        return p + rng.normal(0.0, noise, (3,) + p.shape).mean(axis=0)  # the centroid of three noisy reflectors
    return p + rng.normal(0.0, noise, p.shape)


def _sweeps(home_deg, limits_deg, n, rng, joint_order=(0, 1, 2, 3, 4, 5), n_unseen: int = 0) -> np.ndarray:
    """``n`` poses moving one joint at a time from ``home_deg`` (evenly over a span per joint), then
    ``n_unseen`` poses each moving one joint (drawn at random) to a random angle within that joint's span."""
    per = [n // 6 + (1 if k < n % 6 else 0) for k in range(6)]
    rows, spans = [], {}
    for k, j in enumerate(joint_order):
        lo, hi = limits_deg[j]
        span = min(hi - lo, 240.0) * rng.uniform(0.5, 0.8)
        mid = home_deg[j]
        spans[j] = (max(lo + 5, mid - span / 2), min(hi - 5, mid + span / 2))
        vals = np.linspace(*spans[j], per[k])
        for v in vals:
            qq = np.array(home_deg, dtype=float)
            qq[j] = v
            rows.append(qq)
    for _ in range(n_unseen):
        j = int(rng.choice(joint_order))
        qq = np.array(home_deg, dtype=float)
        qq[j] = rng.uniform(*spans[j])
        rows.append(qq)
    return np.radians(np.array(rows))


def fanuc_like(rng, *, n: int = 36, noise_mm: float | None = None, hidden: bool = True,
               nominal_mm: tuple = (2.0, 3.0), n_unseen: int = 0) -> LookalikeSet:
    """One joint at a time from a home pose, J1 to J6 (the J6 sweep last), three reflectors on the flange;
    ``nominal_mm``: range of the nominal model's RMS miss after a rigid fit."""
    dh_nom = kin.dh_from_degrees(FANUC_LIKE_DEG)
    lim = np.radians(FANUC_LIMITS_DEG)
    home = np.array([0.0, 10.0, 10.0, 0.0, -45.0, 0.0]) + rng.normal(0, 5, 6)
    q = _sweeps(home, FANUC_LIMITS_DEG, n, rng, n_unseen=n_unseen)
    return _finish("fanuc-like", dh_nom, lim, q, rng, noise_mm, "three reflectors", hidden, motion_order=True,
                   nominal_mm=nominal_mm, n_set=n)


def rokae_like(rng, *, n: int = 50, noise_mm: float | None = None, hidden: bool = True,
               n_unseen: int = 0) -> LookalikeSet:
    """Poses spread over the joint space, a 6-DoF target, ~2.2-2.5 mm nominal error."""
    dh_nom = kin.dh_from_degrees(ROKAE_LIKE_DEG)
    lim = np.radians(ROKAE_LIMITS_DEG)
    span = np.radians([150, 70, 70, 150, 90, 170])
    centre = np.radians([0, 0, 20, 0, 30, 0])
    q = centre + rng.uniform(-1, 1, (n + n_unseen, 6)) * span
    q = np.clip(q, lim[:, 0] + 0.05, lim[:, 1] - 0.05)
    return _finish("rokae-like", dh_nom, lim, q, rng, noise_mm, "6-DoF target", hidden, motion_order=True,
                   nominal_mm=(2.2, 2.5), n_set=n)


def _finish(name, dh_nom, lim, q, rng, noise_mm, target, hidden, *, motion_order, nominal_mm=(2.0, 3.0),
            n_set=None):
    noise = float(rng.uniform(0.05, 0.15)) if noise_mm is None else float(noise_mm)
    probe = np.radians(rng.uniform(-60, 60, (200, 6)))
    dh_true = _true_table(dh_nom, rng, nominal_mm, probe)
    B = instrument_frame(rng)
    eff, dq = _hidden(rng, q, dh_true, noise, motion_order, n_set=n_set) if hidden else ([], np.zeros_like(q))
    xyz = _measure(dh_true, q, dq, B, noise, target, rng)
    t = np.cumsum(rng.uniform(20.0, 40.0, q.shape[0]))
    return LookalikeSet(name, dh_nom, dh_true, lim, q, xyz, t, B, noise, target, eff, dq, n_set)


#: the hidden effects of a lab-shaped set (issue 43): gravity compliance or first-harmonic encoder eccentricity
#: of the shoulder or the elbow
LAB_EFFECTS = (("joint_compliance", 2), ("joint_compliance", 3), ("encoder_eccentricity", 2),
               ("encoder_eccentricity", 3))


@dataclass(frozen=True)
class LabSet:
    """A lab-shaped calibration set and unseen poses of the same arm: ``q_rad``/``xyz_mm`` the measured poses,
    ``q_unseen_rad``/``xyz_unseen_mm`` more poses of the same arm and instrument; ``hidden`` [(effect, joint)];
    ``effect_column`` (N + N_unseen,) the hidden joint error's shape in q (rad per unit, measured poses first)."""

    robot: object
    dh_nominal: np.ndarray
    dh_true: np.ndarray
    q_rad: np.ndarray
    xyz_mm: np.ndarray
    q_unseen_rad: np.ndarray
    xyz_unseen_mm: np.ndarray
    base_T: np.ndarray
    noise_mm: float
    hidden: list
    effect_column: np.ndarray | None = None


def lab_shaped(rng, hidden=None, *, n: int = 40, n_unseen: int = 120, noise_mm: float = 0.05,
               strength=(1.2, 2.0), span_rad: float = 2.6, joint_error_rad: float | None = None) -> LabSet:
    """An RB5-850 as built (seed 002 Table 3) against its nominal table (Table 2), measured at ``n`` spread poses
    with ``noise_mm`` per coordinate, and ``n_unseen`` more poses of the same arm and instrument. ``hidden``: one
    (effect, joint) of :data:`LAB_EFFECTS` (None: none), its tool-point RMS ``U(strength)`` times the noise's 3-D
    RMS (or, with ``joint_error_rad``, its largest joint error over the poses that); compliance is the mass
    model's gravity torque of the true table, eccentricity ``sin(q_j + phi)``."""
    from fakes.sim.arm_measurements import random_poses
    from station.models.robots import get_robot, gravity_torques

    robot, truth = get_robot("rb5-850"), get_robot("rb5-850-as-built")
    q_all = random_poses(robot.joint_limits_rad, n + n_unseen, rng, span_rad=span_rad)
    B = instrument_frame(rng)
    dq = np.zeros_like(q_all)
    col = None
    if hidden is not None:
        effect, j = hidden
        if effect == "joint_compliance":
            col = -gravity_torques(robot, truth.dh_nominal, q_all)[:, j - 1]
        elif effect == "encoder_eccentricity":
            col = np.sin(q_all[:, j - 1] + rng.uniform(0.0, 2.0 * np.pi))
        else:
            raise ValueError(f"lab_shaped: hidden effect {effect!r} is not one of {LAB_EFFECTS}")
        J = kin.joint_jacobian(truth.dh_nominal, q_all[:n])[:, :3, j - 1]
        rms = float(np.sqrt(np.mean(np.sum((J * col[:n, None]) ** 2, axis=1))))
        size = rng.uniform(*strength) * noise_mm * math.sqrt(3.0) / rms
        dq[:, j - 1] = col * (size if joint_error_rad is None else joint_error_rad / np.max(np.abs(col)))
    p = kin.tool_position(truth.dh_nominal, q_all + dq) @ B[:3, :3].T + B[:3, 3]
    p = p + rng.normal(0.0, noise_mm, p.shape)
    return LabSet(robot, robot.dh_nominal, truth.dh_nominal, q_all[:n], p[:n], q_all[n:], p[n:], B, noise_mm,
                  [] if hidden is None else [tuple(hidden)], col)
