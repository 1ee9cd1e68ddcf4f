"""A look-alike of a lab's SpatialAnalyzer export of a UR arm measured by a tracker, written independently
of the station's simulator: a UR5e joint move P1 <-> P2 on a trapezoidal profile (60 deg/s, 80 deg/s^2),
2 s waits, 3 cycles, sampled at 1000/3 Hz with micrometre noise, stamped by a PC clock of 1 s resolution
that stamps on receipt (66-444 samples a stamp, falling behind the tracker)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta

import numpy as np

#: UR5e Denavit-Hartenberg parameters (standard convention), mm and rad
UR5E_A = (0.0, -425.0, -392.2, 0.0, 0.0, 0.0)
UR5E_D = (162.5, 0.0, 0.0, 133.3, 99.7, 99.6)
UR5E_ALPHA = (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0)
RATE_HZ = 1000.0 / 3.0


def tool_points(q_rad):
    """The flange centre (M, 3) mm of joint angles (M, 6)."""
    q = np.atleast_2d(q_rad)
    T = np.tile(np.eye(4), (q.shape[0], 1, 1))
    for j in range(6):
        c, s = np.cos(q[:, j]), np.sin(q[:, j])
        ca, sa = np.cos(UR5E_ALPHA[j]), np.sin(UR5E_ALPHA[j])
        A = np.zeros((q.shape[0], 4, 4))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = c, -s * ca, s * sa, UR5E_A[j] * c
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = s, c * ca, -c * sa, UR5E_A[j] * s
        A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa, ca, UR5E_D[j]
        A[:, 3, 3] = 1.0
        T = T @ A
    return T[:, :3, 3]


def joint_profile(tau, dist_deg, v=60.0, a=80.0):
    """Fraction of the move done at tau (s) on a trapezoidal profile of the leading joint; and its duration."""
    ta = min(v / a, np.sqrt(dist_deg / a))
    vp = a * ta
    tc = (dist_deg - vp * ta) / vp
    T = 2 * ta + tc
    tau = np.clip(tau, 0.0, T)
    s = np.where(tau < ta, 0.5 * a * tau ** 2,
                 np.where(tau < ta + tc, 0.5 * a * ta ** 2 + vp * (tau - ta), dist_deg - 0.5 * a * (T - tau) ** 2))
    return s / dist_deg, T


@dataclass
class LabLookalike:
    xyz_mm: np.ndarray  # (N, 3) measured, tracker frame
    poses_mm: np.ndarray  # (2, 3) commanded P1, P2 in the tracker frame
    per_stamp: np.ndarray  # samples of each stamp
    move_s: float  # duration of each move's profile
    dwell_s: np.ndarray  # true time of every stop between moves (wait + overhead), s
    n_moves: int
    clean_mm: np.ndarray | None = None  # (N, 3) the path without the tracker's noise

    def samples_outside(self, radius_mm: float) -> np.ndarray:
        """Each move's samples from the last inside its start rest's radius to the first inside the next's, on
        the noise-free path: what a move between rests takes in samples (the ends of the profile inside the radii
        are slow where the flange starts near a joint's axis, so less than the profile's samples)."""
        p = self.clean_mm
        still = np.linalg.norm(np.diff(p, axis=0), axis=1) == 0.0
        edges = np.flatnonzero(np.diff(still.astype(np.int8)))  # rows where the tool starts or stops moving
        out = []
        for a, b in zip(edges[0::2] + 1, edges[1::2] + 1):
            seg = p[a - 1: b + 2]
            first_b = int(np.flatnonzero(np.linalg.norm(seg - seg[-1], axis=1) <= radius_mm)[0])
            last_a = int(np.flatnonzero(np.linalg.norm(seg[:first_b] - seg[0], axis=1) <= radius_mm)[-1])
            out.append(first_b - last_a)
        return np.array(out)


def lab_lookalike(rng, *, cycles=3, wait_s=2.0, speed=1.0) -> LabLookalike:
    """The stream at 1000/3 Hz and a PC clock's stamps drawn at random (see the module docstring)."""
    q1 = np.radians([-80.0, -100.0, 100.0, -90.0, -90.0, 0.0] + rng.uniform(-5, 5, 6))
    dq = np.radians([rng.uniform(140.0, 170.0), rng.uniform(-25, 25), rng.uniform(-25, 25), rng.uniform(-20, 20),
                     0.0, 0.0])
    lead = float(np.degrees(np.max(np.abs(dq))))
    _, T = joint_profile(0.0, lead, 60.0 * speed, 80.0 * speed ** 2)
    rest0 = rng.uniform(1.0, 3.0)
    waits = wait_s + rng.uniform(0.0, 0.08, 2 * cycles)  # the controller's overhead after each wait
    t_end = rest0 + 2 * cycles * T + waits.sum()
    t = np.arange(int(t_end * RATE_HZ)) / RATE_HZ
    frac = np.zeros(t.size)  # 0 at P1, 1 at P2
    scatter = rng.normal(0.0, 0.008, (2 * cycles + 1, 3))  # where each stop ends, about the pose, mm
    stop_off = np.tile(scatter[0], (t.size, 1))
    t0 = rest0
    for m in range(2 * cycles):
        f, _ = joint_profile(t - t0, lead, 60.0 * speed, 80.0 * speed ** 2)
        inside = t >= t0
        frac[inside] = f[inside] if m % 2 == 0 else 1.0 - f[inside]
        stop_off[inside] = scatter[m] + f[inside, None] * (scatter[m + 1] - scatter[m])
        t0 += T + waits[m]
    q = q1 + frac[:, None] * dq
    c, s = np.cos(np.radians(rng.uniform(0, 360))), np.sin(np.radians(rng.uniform(0, 360)))
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    off = np.array([3400.0, rng.uniform(-500, 500), rng.uniform(-800, -200)])
    clean = tool_points(q) @ R.T + off + stop_off
    sigma = rng.uniform(0.3e-3, 1e-3)
    xyz = clean + rng.normal(0.0, sigma, clean.shape)
    cmd = tool_points(np.stack([q1, q1 + dq])) @ R.T + off + rng.uniform(-0.05, 0.05, (2, 3))
    return LabLookalike(xyz, cmd, pc_stamps(rng, t.size), float(T), waits[:-1], 2 * cycles, clean)


def pc_stamps(rng, n: int) -> np.ndarray:
    """Samples per stamp of a PC clock stamping ``n`` samples: 1 s apart, each on a burst of 66-444 samples, most
    bursts small (the logger falls behind), one of 66 and one of 444 somewhere."""
    per, z, med = [], 0.0, rng.uniform(100.0, 150.0)
    i66, i444 = rng.choice(np.arange(1, n // 444 - 1), 2, replace=False)  # whole stamps, whatever follows
    while sum(per) < n:  # the logger's pace wanders slowly (a log-normal AR(1) process)
        z = 0.9 * z + 0.44 * rng.normal(0.0, 0.45)
        per.append(int(np.clip(round(med * np.exp(z)), 66, 444)))
        if len(per) - 1 in (i66, i444):
            per[-1] = 66 if len(per) - 1 == i66 else 444
    per[-1] = n - (sum(per) - per[-1])  # the last stamp: the samples left (a part of a second)
    return np.array(per)


def write_lab_export(path, la: LabLookalike, t0=datetime(2025, 3, 11, 14, 7, 52)):
    """The export in the shape a lab's SpatialAnalyzer writes (see /work/shared/samples)."""
    lines = ["// SpatialAnalyzer SA 2024.2.0923.4 ( x64 )  ", "// Points Relative to Coordinate Frame 'A::WORLD'",
             "// AXES = CARTESIAN: X,  Y,  Z (mm)"]
    k = 0
    for j, m in enumerate(la.per_stamp):
        stamp = (t0 + timedelta(seconds=j)).strftime("%m/%d/%y %H:%M:%S")
        for _ in range(int(m)):
            x, y, z = la.xyz_mm[k]
            lines.append(f"Traj,  P1,  {k},  {x:.6f},  {y:.6f},  {z:.6f},  {stamp}")
            k += 1
    path.write_text("\n".join(lines) + "\n")
    return path
