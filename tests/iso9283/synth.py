"""Synthetic tracker streams with known truth, for the ISO 9283 analysis tests.

A programme is a list of stops (target position, dwell, label).  The commanded
reference moves between targets along straight lines with trapezoidal speed
profiles; every axis follows it through the same second-order servo
(natural frequency ``wn_hz``, damping ``zeta``), so a stop overshoots and
settles and a straight reference stays straight.  The true rest position of
each stop is its target (the servo has unit gain), which is where the truth
lives: commanded pose + systematic offset (+ per-direction offset) + random
scatter (+ drift).  The tracker adds white noise, drops samples in beam
breaks and may jitter its timestamps.

Vectorised (numpy + scipy.signal.lfilter): an hour at 1 kHz takes about a
second to generate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from station.analysis.iso9283.poses import TABLE2_POSES_MM

NAMES5 = ("P1", "P2", "P3", "P4", "P5")


@dataclass
class Programme:
    """Stops of a robot programme: targets are the *true* rest positions."""

    target_mm: np.ndarray  # (K, 3)
    dwell_s: np.ndarray  # (K,) 0 = fly through (no stop)
    pose: np.ndarray  # (K,) commanded pose index or -1 (e.g. approach start points)
    cycle: np.ndarray  # (K,)
    direction: np.ndarray  # (K,) approach direction label, -1 for none
    target_abc_rad: np.ndarray | None = None  # (K, 3)


@dataclass
class Stream:
    t: np.ndarray  # (N,) s
    xyz: np.ndarray  # (N, 3) mm, measured
    clean: np.ndarray  # (N, 3) mm, true tool position
    valid: np.ndarray | None  # (N,) bool or None
    abc: np.ndarray | None  # (N, 3) rad, measured
    prog: Programme
    t_arrive: np.ndarray  # (K,) end of the commanded profile of each stop's move
    t_depart: np.ndarray  # (K,) start of the next move
    t_move_start: np.ndarray  # (K,) start of the move into each stop
    start_mm: np.ndarray  # (3,) rest position before the first move
    info: dict = field(default_factory=dict)


def trapezoid(tau, dist, vmax, amax):
    """Travelled distance of a trapezoidal (or triangular) profile at tau, vectorised.

    Returns (s, T) with T the profile duration(s).
    """
    dist = np.asarray(dist, dtype=float)
    ta = np.minimum(vmax / amax, np.sqrt(dist / amax))
    vp = amax * ta
    tc = np.where(vp > 0, (dist - vp * ta) / np.where(vp > 0, vp, 1.0), 0.0)
    T = 2 * ta + tc
    tau = np.clip(tau, 0.0, T)
    s = np.where(
        tau < ta,
        0.5 * amax * tau**2,
        np.where(tau < ta + tc, 0.5 * amax * ta**2 + vp * (tau - ta), dist - 0.5 * amax * (T - tau) ** 2),
    )
    return s, T


def servo_filter(r, rate_hz, wn_hz, zeta):
    """Second-order unit-gain servo wn^2 / (s^2 + 2 zeta wn s + wn^2) on each column of r."""
    wn = 2 * np.pi * wn_hz
    b, a, _ = signal.cont2discrete(([wn**2], [1.0, 2 * zeta * wn, wn**2]), 1.0 / rate_hz, method="bilinear")
    b = np.ravel(b)
    zi = signal.lfilter_zi(b, a)
    out = np.empty_like(r)
    for k in range(r.shape[1]):  # loop over axes
        out[:, k], _ = signal.lfilter(b, a, r[:, k], zi=zi * r[0, k])
    return out


def iso_cycle_programme(
    rng,
    *,
    commanded=TABLE2_POSES_MM,
    order=(1, 2, 3, 4, 0),
    n_cycles=30,
    dwell_s=0.5,
    offsets_mm=None,
    scatter_mm=0.03,
    skip=(),
    drift_mm_per_cycle=None,
    abc_commanded_rad=None,
    abc_offset_rad=None,
    abc_scatter_rad=0.0,
):
    """The seed's cycle (start at rest at P1, then P2, P3, P4, P5, P1; n times).

    ``skip``: (cycle, pose index) pairs the robot flies through without a stop.
    """
    c = np.asarray(commanded, dtype=float)
    P = c.shape[0]
    off = np.zeros((P, 3)) if offsets_mm is None else np.asarray(offsets_mm, dtype=float)
    pose = np.tile(np.asarray(order), n_cycles)
    cyc = np.repeat(np.arange(n_cycles), len(order))
    K = pose.size
    tgt = c[pose] + off[pose] + rng.normal(0.0, scatter_mm, (K, 3))
    if drift_mm_per_cycle is not None:
        tgt += cyc[:, None] * np.asarray(drift_mm_per_cycle, dtype=float)[None, :]
    dwell = np.full(K, float(dwell_s))
    for cy, p in skip:
        dwell[(cyc == cy) & (pose == p)] = 0.0
    abc = None
    if abc_commanded_rad is not None:
        ac = np.asarray(abc_commanded_rad, dtype=float)
        ao = np.zeros((P, 3)) if abc_offset_rad is None else np.asarray(abc_offset_rad, dtype=float)
        abc = ac[pose] + ao[pose] + rng.normal(0.0, abc_scatter_rad, (K, 3))
    return Programme(tgt, dwell, pose, cyc, np.full(K, -1), abc)


def multidirection_programme(rng, *, commanded, pose, dir_offsets_mm, n_each=10, approach_mm=150.0,
                             dwell_s=0.5, scatter_mm=0.03, base_offset_mm=(0, 0, 0)):
    """Approaches to one pose from -x, -y, -z (start points off the pose), n_each times each.

    ``dir_offsets_mm`` (3, 3): systematic offset of the attained pose per direction.
    """
    c = np.asarray(commanded, dtype=float)[pose]
    tg, dw, po, cy, di = [], [], [], [], []
    for j in range(n_each):
        for d in range(3):
            e = np.zeros(3)
            e[d] = 1.0
            tg.append(c - approach_mm * e)
            dw.append(dwell_s)
            po.append(-1)
            cy.append(j)
            di.append(-1)
            tg.append(c + np.asarray(base_offset_mm) + np.asarray(dir_offsets_mm[d]) + rng.normal(0, scatter_mm, 3))
            dw.append(dwell_s)
            po.append(pose)
            cy.append(j)
            di.append(d)
    return Programme(np.array(tg), np.array(dw), np.array(po), np.array(cy), np.array(di))


def render(
    rng,
    prog: Programme,
    *,
    start_mm,
    rate_hz=200.0,
    speed_mm_s=1000.0,
    accel_mm_s2=4000.0,
    wn_hz=6.0,
    zeta=0.5,
    noise_mm=0.01,
    start_rest_s=1.0,
    end_rest_s=None,
    beam_breaks=(),
    breaks_as_status=False,
    jitter_frac=0.0,
    abc_noise_rad=0.0,
    start_abc_rad=None,
):
    """Sample the programme: reference, servo, tracker noise, beam breaks.

    ``beam_breaks``: (t_start, duration) pairs; samples inside are dropped
    (or kept with NaN and ``valid`` False when ``breaks_as_status``).
    """
    start = np.asarray(start_mm, dtype=float)
    tg = prog.target_mm
    K = tg.shape[0]
    prev = np.vstack([start[None, :], tg[:-1]])
    vec = tg - prev
    dist = np.linalg.norm(vec, axis=1)
    _, T = trapezoid(np.zeros(K), dist, speed_mm_s, accel_mm_s2)
    dur = T + prog.dwell_s
    t_ms = start_rest_s + np.concatenate([[0.0], np.cumsum(dur)[:-1]])  # move starts
    t_arr = t_ms + T
    t_dep = t_arr + prog.dwell_s
    t_end = t_dep[-1] + (max(prog.dwell_s[-1], 0.5) if end_rest_s is None else end_rest_s)
    n = int(np.floor(t_end * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    m = np.searchsorted(t_ms, t, side="right") - 1  # move index per sample, -1 before the first
    mm = np.maximum(m, 0)
    s, _ = trapezoid(t - t_ms[mm], dist[mm], speed_mm_s, accel_mm_s2)
    frac = np.where(dist[mm] > 0, s / np.where(dist[mm] > 0, dist[mm], 1.0), 1.0)
    frac = np.where(m >= 0, frac, 0.0)
    ref = np.where(m[:, None] >= 0, prev[mm] + frac[:, None] * vec[mm], start[None, :])
    clean = servo_filter(ref, rate_hz, wn_hz, zeta)
    if jitter_frac:  # sampling instants off the grid: positions interpolated to them
        tj = t + rng.uniform(-jitter_frac, jitter_frac, n) / rate_hz
        tj[0], tj[-1] = t[0], t[-1]
        clean = np.stack([np.interp(tj, t, clean[:, k]) for k in range(3)], axis=1)
        t = tj
    xyz = clean + rng.normal(0.0, noise_mm, clean.shape)
    abc = None
    if prog.target_abc_rad is not None:
        a0 = np.zeros(3) if start_abc_rad is None else np.asarray(start_abc_rad, dtype=float)
        aprev = np.vstack([a0[None, :], prog.target_abc_rad[:-1]])
        aref = np.where(m[:, None] >= 0, aprev[mm] + frac[:, None] * (prog.target_abc_rad - aprev)[mm], a0[None, :])
        abc = servo_filter(aref, rate_hz, wn_hz, zeta) + rng.normal(0.0, abc_noise_rad, aref.shape)
    keep = np.ones(n, bool)
    for t0, d in beam_breaks:
        keep &= ~((t >= t0) & (t < t0 + d))
    valid = None
    if breaks_as_status:
        valid = keep
        xyz[~keep] = np.nan
    else:
        t, xyz, clean = t[keep], xyz[keep], clean[keep]
        abc = None if abc is None else abc[keep]
    return Stream(t, xyz, clean, valid, abc, prog, t_arr, t_dep, t_ms, start,
                  info=dict(rate_hz=rate_hz, noise_mm=noise_mm, wn_hz=wn_hz, zeta=zeta))


def iso_stream(rng, *, n_cycles=30, rate_hz=200.0, offsets_mm=None, scatter_mm=0.03, noise_mm=0.01,
               dwell_s=0.5, wn_hz=6.0, zeta=0.5, skip=(), beam_breaks=(), **kw):
    """The seed's 5-pose cycle, rendered; start at rest at the true P1 (cycle -1)."""
    prog = iso_cycle_programme(rng, n_cycles=n_cycles, offsets_mm=offsets_mm, scatter_mm=scatter_mm,
                               dwell_s=dwell_s, skip=skip,
                               **{k: kw.pop(k) for k in list(kw) if k in ("drift_mm_per_cycle", "abc_commanded_rad",
                                                                      "abc_offset_rad", "abc_scatter_rad")})
    c = np.asarray(TABLE2_POSES_MM)
    start = c[0] + (0 if offsets_mm is None else np.asarray(offsets_mm)[0])
    return render(rng, prog, start_mm=start, rate_hz=rate_hz, noise_mm=noise_mm, wn_hz=wn_hz, zeta=zeta,
                  beam_breaks=beam_breaks, **kw)


def random_offsets(rng, scale_mm=3.0, P=5):
    """Systematic attained-pose offsets per pose, like seed Table 3 (a few mm)."""
    return rng.normal(0.0, scale_mm, (P, 3))


@dataclass
class Counted:
    """The stops the analysis counts in a seed-cycle stream: the rest before the first move, then the programme's.

    The rest stands at the true start (P1, which the seed's cycle P2, P3, P4, P5, P1 puts right before
    the first moved stop): it ends the cycle before the first, cycle -1. ``index`` maps each counted
    stop to its programme stop (-1 for the rest).
    """

    target_mm: np.ndarray
    pose: np.ndarray
    cycle: np.ndarray
    t_arrive: np.ndarray
    t_depart: np.ndarray
    index: np.ndarray


def counted_stops(s: Stream, start_pose: int = 0) -> Counted:
    prog = s.prog
    j = np.arange(prog.pose.size)
    return Counted(
        target_mm=np.vstack([s.start_mm[None, :], prog.target_mm]),
        pose=np.concatenate([[start_pose], prog.pose]),
        cycle=np.concatenate([[-1], prog.cycle]),
        t_arrive=np.concatenate([[s.t[0]], s.t_arrive]),
        t_depart=np.concatenate([[s.t_move_start[0]], s.t_depart]),
        index=np.concatenate([[-1], j]),
    )
