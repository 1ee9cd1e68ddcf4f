"""Tracker streams of straight moves with hidden motion effects, written independently of the diagnosis's model.

The diagnosis predicts an approach in closed form (station.models.approach_response);
this generator integrates the physics numerically instead, on a 10 kHz grid
(Tustin-discretised transfer functions, then sampled at the tracker's rate):

* the command: a trapezoidal speed profile along a straight line between
  poses (each stop's target scattered by a few micrometres);
* the position loop: ``s = (2 zeta w p + w^2) / (p^2 + 2 zeta w p + w^2) s_cmd``
  (``p`` the Laplace variable), i.e. a PD loop with velocity reference;
* a structural mode of the tool against the axis, driven by the axis's
  actual acceleration: ``q = -g p^2 / (p^2 + 2 zm wm p + wm^2) s``;
* creep: friction holds the axis ``A`` short while it moves (reached over
  ``TAU_IN_S``); once it stops after the command's end (its velocity reaches
  zero or reverses, or it crawls below ``STICK_MM_S``) the integral action
  pulls it in as ``exp(-t / tau)``. (A rule of speed below 0.5 mm/s alone
  made the stick bimodal on about 1 % of the draws: where the loop's speed at
  the command's end has a shallow minimum near the threshold, a few
  micrometres of target scatter decided between sticking at once and at the
  overshoot 0.1 s later, which no creep model of a single delay can follow);
* tracker drift: a smooth wander of the reading, three sinusoids per axis
  with periods of 30-90 s (a few micrometres a second, as a lab's tracker at rest);
* white noise of a micrometre or so per axis.

Everything is drawn from the caller's generator before any effect is
switched, so the same draws with an effect switched off give the same stream
without it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

FINE_HZ = 10_000.0
RATE_HZ = 1000.0 / 3.0
TAU_IN_S = 0.03
STICK_MM_S = 0.05


@dataclass
class Truth:
    servo_hz: float
    servo_zeta: float
    creep_mm: float = 0.0
    creep_tau_s: float = 0.15
    mode_hz: float = 10.0
    mode_zeta: float = 0.07
    mode_mm_per_mm_s2: float = 0.0  # quasi-static deflection per unit deceleration, s^2
    drift_mm: float = 0.0           # amplitude of each sinusoid of the wander
    noise_mm: float = 1e-3
    effects: list = field(default_factory=list)


@dataclass
class Stream:
    t_s: np.ndarray
    xyz_mm: np.ndarray
    poses_mm: np.ndarray
    names: list
    truth: Truth
    dwell_s: float
    speed_mm_s: float
    accel_mm_s2: float


def _tf(num, den, fine_hz):
    b, a = signal.bilinear(num, den, fine_hz)
    return b, a


def draw(rng, *, effects=(), underdamped=False, cycles=8, dwell_s=2.0, rate_hz=RATE_HZ):
    """The draws of a stream (a dict), effects switched on by name: creep, structural_mode, tracker_drift."""
    centre = np.array([400.0, 100.0, 300.0]) + rng.uniform(-50, 50, 3)
    poses = centre + rng.uniform(-200, 200, (4, 3))
    d = {
        "poses": poses,
        "servo_hz": rng.uniform(6.0, 15.0),
        "servo_zeta": rng.uniform(0.15, 0.35) if underdamped else rng.uniform(0.6, 1.1),
        "speed": rng.uniform(200.0, 500.0),
        "accel": rng.uniform(1000.0, 2500.0),
        "scatter": rng.normal(0.0, 0.005, (4 * cycles + 1, 3)),
        "creep_mm": rng.uniform(0.02, 0.06) * rng.choice([1.0, 1.0]),
        "creep_tau_s": rng.uniform(0.1, 0.25),
        "mode_hz": rng.uniform(8.0, 14.0),
        "mode_zeta": rng.uniform(0.05, 0.1),
        "mode_amp_mm": rng.uniform(0.015, 0.05) * rng.choice([-1.0, 1.0]),
        "drift_mm": rng.uniform(0.008, 0.02),
        "drift_periods": rng.uniform(30.0, 90.0, (3, 3)),
        "drift_phase": rng.uniform(0, 2 * np.pi, (3, 3)),
        "noise_mm": rng.uniform(0.5e-3, 1.5e-3),
        "noise_seed": int(rng.integers(2**31)),
        "rest0": rng.uniform(1.0, 2.0),
        "cycles": cycles, "dwell_s": dwell_s, "rate_hz": rate_hz, "effects": tuple(effects),
    }
    return d


def drift_at(d: dict, t) -> np.ndarray:
    """The drawn tracker drift (``draw(..., effects=("tracker_drift",))``) at times ``t``: (len(t), 3) mm."""
    t = np.asarray(t, dtype=float)
    arg = 2 * np.pi * t[:, None, None] / d["drift_periods"][None] + d["drift_phase"][None]
    return d["drift_mm"] * np.sin(arg).sum(axis=2)


def make_stream(d: dict, fine_hz: float = FINE_HZ) -> Stream:
    eff = set(d["effects"])
    truth = Truth(d["servo_hz"], d["servo_zeta"], noise_mm=d["noise_mm"], effects=sorted(eff))
    w = 2 * np.pi * d["servo_hz"]
    z = d["servo_zeta"]
    servo = _tf([2 * z * w, w * w], [1.0, 2 * z * w, w * w], fine_hz)
    if "structural_mode" in eff:
        wm = 2 * np.pi * d["mode_hz"]
        G = d["mode_amp_mm"] / d["accel"]  # deflection per unit deceleration, s^2
        mode = _tf([-G * wm * wm, 0.0, 0.0], [1.0, 2 * d["mode_zeta"] * wm, wm * wm], fine_hz)
        truth.mode_hz, truth.mode_zeta, truth.mode_mm_per_mm_s2 = d["mode_hz"], d["mode_zeta"], G
    if "creep" in eff:
        truth.creep_mm, truth.creep_tau_s = d["creep_mm"], d["creep_tau_s"]
    names = ["P1", "P2", "P3", "P4"]
    order = [0] + [j for _ in range(d["cycles"]) for j in (1, 2, 3, 0)]
    targets = d["poses"][order] + d["scatter"][: len(order)]
    v, a = d["speed"], d["accel"]
    t_fine, p_fine = [np.array([0.0])], [targets[0][None]]
    t0 = d["rest0"]
    for k in range(1, len(order)):
        P0, P1 = targets[k - 1], targets[k]
        D = float(np.linalg.norm(P1 - P0))
        u = (P1 - P0) / D
        ta = min(v / a, np.sqrt(D / a))
        vp = a * ta
        tc = (D - vp * ta) / vp
        T = 2 * ta + tc
        tt = np.arange(0.0, T + d["dwell_s"], 1.0 / fine_hz)
        tq = np.clip(tt, 0, T)
        s_cmd = np.where(tq < ta, 0.5 * a * tq ** 2,
                         np.where(tq < ta + tc, 0.5 * a * ta ** 2 + vp * (tq - ta), D - 0.5 * a * (T - tq) ** 2))
        s = signal.lfilter(*servo, s_cmd)
        along = s.copy()
        if "structural_mode" in eff:
            along += signal.lfilter(*mode, s)
        if "creep" in eff:
            vel = np.gradient(s, 1.0 / fine_hz)
            c = -d["creep_mm"] * (1.0 - np.exp(-tt / TAU_IN_S))
            after = np.flatnonzero((tt > T) & ((np.abs(vel) < STICK_MM_S) | (vel <= 0.0)))
            if after.size:
                i = int(after[0])
                c[i:] = c[i] * np.exp(-(tt[i:] - tt[i]) / d["creep_tau_s"])
            along += c
        t_fine.append(t0 + tt)
        p_fine.append(P0 + along[:, None] * u)
        t0 += tt[-1] + 1.0 / fine_hz
    tf = np.concatenate(t_fine)
    pf = np.concatenate(p_fine)
    t = np.arange(0.0, tf[-1], 1.0 / d["rate_hz"])
    xyz = np.stack([np.interp(t, tf, pf[:, j]) for j in range(3)], axis=1)
    if "tracker_drift" in eff:
        truth.drift_mm = d["drift_mm"]
        xyz += drift_at(d, t)
    xyz += np.random.default_rng(d["noise_seed"]).normal(0.0, d["noise_mm"], xyz.shape)
    return Stream(t, xyz, d["poses"], names, truth, d["dwell_s"], v, a)
