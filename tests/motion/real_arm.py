"""A look-alike of issue 42's real UR arm measured by a tracker, written independently of the diagnosis.

The lab recorded a UR arm's joint moves P1 <-> P2 (UR's default ``movej``,
60 deg/s and 80 deg/s^2 on a trapezoid, 2 s waits, 3 cycles, at 100 % and
50 % speed) with a Leica tracker at 1000/3 Hz, exported by SpatialAnalyzer
with 1 s PC stamps. What it showed, and what this generator puts in (every
parameter drawn at random around the issue's figures):

* a well damped joint loop (12-20 Hz, damping 0.75-1.0) following the
  command's path parameter;
* a slow final creep: the joints lag the path by what reads as ``A``
  (0.1-0.3 mm at the tool) while moving, and once the path parameter's speed
  falls below :data:`STICK_MM_S` the integral action pulls them in as
  ``exp(-t / tau)``, ``tau`` 0.12-0.2 s (the arm arrives short and creeps in);
* a lightly damped structural mode (9-10 Hz, damping 0.06-0.12) of the tool
  driven by the tool's actual acceleration, ringing ~0.3 s after arrival,
  5-15 um at 100 % speed (a quarter of it at 50 %: the deceleration is);
* stop scatter of 4-7 um per axis (RP 0.012-0.024 mm over 3 cycles);
* the tracker's reading: white 0.5-0.7 um per axis plus a wander (a
  first-order Gauss-Markov process, sd 2-3 um, correlation time 1-3 s).

None of it uses the station's closed forms: the loop and the mode are
Tustin-discretised transfer functions integrated on a 5 kHz grid, the arm's
path is the UR5e's forward kinematics of the joints (a curve, not a line),
and the wander is simulated sample by sample. The recording is written as a
SpatialAnalyzer export with a PC clock's 1 s stamps (:func:`write_export`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from tests.iso9283.ur_lookalike import RATE_HZ, joint_profile, pc_stamps, tool_points, write_lab_export

FINE_HZ = 5000.0
#: the path speed (at the tool) below which the joints stick and the integral action takes over, mm/s
STICK_MM_S = 0.5
#: the lag while moving builds up over this time constant, s
TAU_IN_S = 0.03
UR_SPEED_DEG_S, UR_ACCEL_DEG_S2 = 60.0, 80.0


@dataclass
class RealArm:
    """A recording of the look-alike and its truth."""

    t_s: np.ndarray            # (N,) true sample times, s
    xyz_mm: np.ndarray         # (N, 3) the tracker's readings
    poses_mm: np.ndarray       # (2, 3) commanded P1, P2 in the tracker frame
    q_deg: np.ndarray          # (2, 6) commanded joints of P1, P2
    speed: float               # the speed override (1.0 or 0.5)
    wait_s: float
    cycles: int
    per_stamp: np.ndarray      # samples of each PC stamp
    truth: dict = field(default_factory=dict)


def draw(rng, *, speed=1.0, cycles=3, wait_s=2.0) -> dict:
    """The look-alike's parameters (see the module docstring)."""
    return {
        "q1_deg": np.array([-81.25, -100.0, 100.0, -90.0, -90.0, 0.0]) + rng.uniform(-3, 3, 6),
        "dq_deg": np.array([162.5 + rng.uniform(-5, 5), rng.uniform(-15, 15), rng.uniform(-15, 15),
                            rng.uniform(-10, 10), 0.0, 0.0]),
        "servo_hz": rng.uniform(12.0, 20.0), "servo_zeta": rng.uniform(0.75, 1.0),
        "creep_mm": rng.uniform(0.1, 0.3), "creep_tau_s": rng.uniform(0.12, 0.2),
        "mode_hz": rng.uniform(9.0, 10.0), "mode_zeta": rng.uniform(0.06, 0.12),
        # the ring's amplitude after a stop at 100 % speed, mm (its gain: this over the tool's deceleration)
        "ring_mm": rng.uniform(0.005, 0.015),
        "scatter_mm": rng.uniform(0.004, 0.007),
        "white_mm": rng.uniform(0.5e-3, 0.7e-3), "wander_mm": rng.uniform(2e-3, 3e-3),
        "wander_tau_s": rng.uniform(1.0, 3.0),
        "rest0_s": rng.uniform(1.5, 3.0), "overhead_s": rng.uniform(0.0, 0.08, 2 * cycles),
        "yaw_deg": rng.uniform(0, 360), "offset_mm": np.array([3400.0, rng.uniform(-500, 500),
                                                               rng.uniform(-800, -200)]),
        "cmd_error_mm": rng.uniform(-0.05, 0.05, (2, 3)),
        "seed": int(rng.integers(2**31)),
        "speed": speed, "cycles": cycles, "wait_s": wait_s,
    }


def _tf(num, den):
    return signal.bilinear(num, den, FINE_HZ)


def make(d: dict, effects=("creep", "structural_mode")) -> RealArm:
    """The recording of the draws ``d`` with the arm's effects ``effects`` switched on (the tracker's noise and
    wander always)."""
    eff = set(effects)
    rng = np.random.default_rng(d["seed"])
    f = d["speed"]
    v, a = UR_SPEED_DEG_S * f, UR_ACCEL_DEG_S2 * f * f
    q1, dq = np.radians(d["q1_deg"]), np.radians(d["dq_deg"])
    lead = float(np.max(np.abs(d["dq_deg"])))
    _, T = joint_profile(0.0, lead, v, a)
    n_moves = 2 * d["cycles"]
    dwell = d["wait_s"] + d["overhead_s"]
    t_end = d["rest0_s"] + n_moves * T + dwell.sum()
    tf = np.arange(0.0, t_end, 1.0 / FINE_HZ)
    # the command's path parameter: 0 at P1, 1 at P2
    s_cmd = np.zeros(tf.size)
    starts, t0 = [], d["rest0_s"]
    for m in range(n_moves):
        frac, _ = joint_profile(tf - t0, lead, v, a)
        on = tf >= t0
        s_cmd[on] = frac[on] if m % 2 == 0 else 1.0 - frac[on]
        starts.append(t0)
        t0 += T + dwell[m]
    w = 2 * np.pi * d["servo_hz"]
    z = d["servo_zeta"]
    b, a_ = _tf([2 * z * w, w * w], [1.0, 2 * z * w, w * w])
    s = signal.lfilter(b, a_, s_cmd)
    # the tool's speed along the path per unit of the path parameter at each end, mm
    ends = tool_points(np.stack([q1 + e * dq for e in (0.0, 1e-4, 1.0 - 1e-4, 1.0)]))
    L_end = {0: np.linalg.norm(ends[1] - ends[0]) / 1e-4, 1: np.linalg.norm(ends[3] - ends[2]) / 1e-4}
    # the tool's deceleration at the end of a move at 100 % (mm per degree of the leading joint x deg/s^2)
    decel_100 = 0.5 * (L_end[0] + L_end[1]) / lead * UR_ACCEL_DEG_S2
    d["mode_gain_s2"] = d["ring_mm"] / decel_100
    if "creep" in eff:
        sp = np.abs(np.gradient(s, 1.0 / FINE_HZ))
        for m, ts in enumerate(starts):
            to = 1 if m % 2 == 0 else 0
            sign = 1.0 if to == 1 else -1.0
            nxt = starts[m + 1] if m + 1 < n_moves else tf[-1] + 1.0
            on = (tf >= ts) & (tf < nxt)
            c = d["creep_mm"] * (1.0 - np.exp(-(tf[on] - ts) / TAU_IN_S))
            tt = tf[on]
            stuck = np.flatnonzero((tt > ts + T) & (sp[on] * L_end[to] < STICK_MM_S))
            if stuck.size:
                i = int(stuck[0])
                c[i:] = c[i] * np.exp(-(tt[i:] - tt[i]) / d["creep_tau_s"])
            s[on] -= sign * c / L_end[to]
    # the tool's path at the fine grid's every 5th point (1 kHz), the mode driven by its acceleration
    k = 5
    tk = tf[::k]
    c_, s_ = np.cos(np.radians(d["yaw_deg"])), np.sin(np.radians(d["yaw_deg"]))
    R = np.array([[c_, -s_, 0.0], [s_, c_, 0.0], [0.0, 0.0, 1.0]])
    xyz = tool_points(q1 + s[::k, None] * dq) @ R.T + d["offset_mm"]
    if "structural_mode" in eff:
        wm, zm, G = 2 * np.pi * d["mode_hz"], d["mode_zeta"], d["mode_gain_s2"]
        bm, am = signal.bilinear([-G * wm * wm, 0.0, 0.0], [1.0, 2 * zm * wm, wm * wm], FINE_HZ / k)
        xyz = xyz + np.stack([signal.lfilter(bm, am, xyz[:, j] - xyz[0, j]) for j in range(3)], axis=1)
    # where each stop ends about its pose (scatter), blended over the move
    scatter = rng.normal(0.0, d["scatter_mm"], (n_moves + 1, 3))
    off = np.tile(scatter[0], (tk.size, 1))
    for m, ts in enumerate(starts):
        frac, _ = joint_profile(tk - ts, lead, v, a)
        on = tk >= ts
        off[on] = scatter[m] + frac[on, None] * (scatter[m + 1] - scatter[m])
    xyz += off
    t = np.arange(int(tk[-1] * RATE_HZ)) / RATE_HZ
    out = np.stack([np.interp(t, tk, xyz[:, j]) for j in range(3)], axis=1)
    # the tracker: white noise and a Gauss-Markov wander, sample by sample
    phi = np.exp(-1.0 / (RATE_HZ * d["wander_tau_s"]))
    e = rng.normal(0.0, d["wander_mm"] * np.sqrt(1.0 - phi * phi), out.shape)
    e[0] = rng.normal(0.0, d["wander_mm"], 3)
    wander = signal.lfilter([1.0], [1.0, -phi], e, axis=0)
    out += wander + rng.normal(0.0, d["white_mm"], out.shape)
    q_deg = np.stack([d["q1_deg"], d["q1_deg"] + d["dq_deg"]])
    cmd = tool_points(np.radians(q_deg)) @ R.T + d["offset_mm"] + d["cmd_error_mm"]
    truth = {k_: d[k_] for k_ in ("servo_hz", "servo_zeta", "creep_mm", "creep_tau_s", "mode_hz", "mode_zeta",
                                  "mode_gain_s2", "white_mm", "wander_mm", "wander_tau_s")}
    truth.update(effects=sorted(eff), move_s=float(T), decel_mm_s2=float(decel_100 * f * f))
    return RealArm(t, out, cmd, q_deg, f, d["wait_s"], d["cycles"], pc_stamps(rng, t.size), truth)


def write_export(path, ra: RealArm):
    """The recording as the lab's SpatialAnalyzer export (1 s PC stamps, 66-444 samples a stamp)."""
    from tests.iso9283.ur_lookalike import LabLookalike

    return write_lab_export(path, LabLookalike(ra.xyz_mm, ra.poses_mm, ra.per_stamp, 0.0, np.array([]), 0))


def write_poses(path, ra: RealArm):
    path.write_text("name,x,y,z\n" + "".join(f"{n},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f}\n"
                                               for n, p in zip(("P1", "P2"), ra.poses_mm)))
    return path


def write_program(path, ra: RealArm, *, rate_hz: float | None = None):
    """The lab's program (``simulate iso9283 --program``): P1 <-> P2 by UR's default movej, the waits, cycles,
    the speed override; the tracker's rate only when given (else the recording's clock is to be checked)."""
    j = lambda q: "[" + ", ".join(f"{x:.6f}" for x in q) + "]"  # noqa: E731
    text = (('robot = "ur5e"\n' f"cycles = {ra.cycles}\ndwell_s = {ra.wait_s:g}\nwait_s = 2.0\n"
             f"speed_pct = {100.0 * ra.speed:g}\nstart = \"P1\"\norder = [\"P2\", \"P1\"]\n")
            + (f"rate_hz = {rate_hz:.6f}\n" if rate_hz is not None else "")
            + '[move]\ntype = "joint"\nspeed = 60\nacceleration = 80\nprofile = "trapezoid"\n'
            + f"[poses.P1]\njoints_deg = {j(ra.q_deg[0])}\n[poses.P2]\njoints_deg = {j(ra.q_deg[1])}\n")
    path.write_text(text)
    return path


def read_dry_run(out):
    """A ``simulate iso9283 --out OUT`` run as the diagnosis reads a stream: the valid samples' times and
    positions, the commanded poses and their names."""
    a = np.loadtxt(out / "stream.csv", delimiter=",", skiprows=1)
    rows = [ln.split(",") for ln in (out / "poses.csv").read_text().splitlines()[1:]]
    ok = a[:, 4] == 0
    return a[ok, 0], a[ok, 1:4], np.array([[float(v) for v in r[1:4]] for r in rows]), [r[0] for r in rows]
