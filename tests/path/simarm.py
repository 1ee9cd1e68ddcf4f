"""A simulated arm following commanded paths, and its truth: the tests' own world, not the analysis's.

Written apart from station.analysis.path: the arm's motion is built forward
(a speed profile with a ramp, per-cycle speed error and servo ripple; a
lateral path error that is a static offset, a bend along the path and a
per-cycle scatter; rounded corners with an overshoot after them; a weave with
its own amplitude and frequency errors), the tracker adds white noise, and
the truth of each figure is the standard's definition applied to the
noise-free motion.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

RATE_HZ = 1000.0
ACCEL = 4000.0  # mm/s^2


@dataclass
class Sim:
    t: np.ndarray
    true: np.ndarray
    meas: np.ndarray
    path: dict  # the path file's entry
    truth: dict = field(default_factory=dict)
    abc: np.ndarray | None = None


def _along(rng, L, v_c, n_cycles, rate=RATE_HZ, fine=10):
    """Per cycle: sample times, arc length u(t), speed; speed error per cycle, ripple on the cruise.

    A ramp up at ACCEL to the cruise (the cycle's speed with a sine ripple), then a constant deceleration
    from where the remaining length needs it to a stop at L.
    """
    dt = 1.0 / (rate * fine)
    av = rng.uniform(-0.03, 0.03)
    rv = rng.uniform(0.001, 0.008)
    out = []
    for _ in range(n_cycles):  # loop over cycles
        vj = v_c * (1 + av + rv * rng.standard_normal())
        r, fr, ph = rng.uniform(0.002, 0.015), rng.uniform(2.0, 8.0), rng.uniform(0, 2 * np.pi)
        T = 2.0 * L / vj + 1.0
        t = np.arange(0.0, T, dt)
        v = np.minimum(ACCEL * t, vj * (1 + r * np.sin(2 * np.pi * fr * t + ph)))
        u = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
        i = int(np.argmax(v ** 2 >= 2 * ACCEL * (L - u)))  # where the braking must start
        tb = t[i:] - t[i]
        vb = v[i] - ACCEL * tb
        stop = int(np.argmax(vb <= 0)) if np.any(vb <= 0) else vb.size
        v = np.concatenate([v[:i], vb[:stop]])
        u = np.concatenate([u[:i], u[i] + v[i] * tb[:stop] - 0.5 * ACCEL * tb[:stop] ** 2])
        t = t[:v.size]
        out.append((t[::fine], np.minimum(u[::fine], L), v[::fine]))
    return out


def _frame(d):
    d = d / np.linalg.norm(d)
    a = np.array([1.0, 0, 0]) if abs(d[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    return d, e1, np.cross(d, e1)


def _stack(parts, rng, noise):
    t0, ts, ps = 0.0, [], []
    for t, p in parts:  # loop over cycles
        ts.append(t + t0)
        ps.append(p)
        t0 = ts[-1][-1] + 0.5  # a pause between cycles (the return move is not sampled)
    true = np.concatenate(ps)
    return np.concatenate(ts), true, true + rng.standard_normal(true.shape) * noise


def iso_at_rt(cross):
    """The standard's AT, RT of crossings (n, m, 3) against commanded points at the origin of each plane's offsets."""
    bary = cross.mean(axis=0)
    at = np.linalg.norm(bary, axis=1).max()
    if cross.shape[0] < 2:  # one cycle: no spread to state (RT undefined)
        return float(at), float("nan")
    l = np.linalg.norm(cross - bary, axis=2)
    return float(at), float((l.mean(axis=0) + 3 * l.std(axis=0, ddof=1)).max())


def _true_speed(t, p):
    """The speed of the noise-free motion: a five-point central difference of the true positions (uniform
    1 kHz; its error goes as the fourth power of the step)."""
    h = float(np.median(np.diff(t)))
    v = np.gradient(p, t, axis=0)
    v[2:-2] = (p[:-4] - 8 * p[1:-3] + 8 * p[3:-1] - p[4:]) / (12 * h)
    return np.linalg.norm(v, axis=1)


def _velocity_truth(cycles, L, v_c, window=(0.25, 0.75)):
    means, ranges = [], []
    for t, u, v in cycles:  # loop over cycles (v: the true speed along the attained path)
        w = (u >= window[0] * L) & (u <= window[1] * L)
        means.append(v[w].mean())
        ranges.append(np.ptp(v[w]))
    means = np.array(means)
    rv = 3 * means.std(ddof=1) / v_c * 100 if means.size > 1 else float("nan")  # one cycle: no spread
    return {"AV_percent": (means.mean() - v_c) / v_c * 100, "RV_percent": rv,
            "FV_percent": max(ranges) / v_c * 100}


def _lateral(rng, n_cycles):
    """Lateral error functions of the fraction along the path (2 components), per cycle."""
    static = rng.uniform(0.05, 0.4) * rng.standard_normal(2) / np.sqrt(2)
    bend = rng.uniform(0.0, 0.3) * rng.standard_normal(2) / np.sqrt(2)
    rep = rng.uniform(0.01, 0.05)
    per = [rep * rng.standard_normal(2) for _ in range(n_cycles)]
    wob = [rep * 0.5 * rng.standard_normal(2) for _ in range(n_cycles)]
    return lambda j, f: (static[None] + bend[None] * np.sin(np.pi * f)[:, None] + per[j][None]
                         + wob[j][None] * np.sin(2 * np.pi * f)[:, None])


def line(rng, *, n_cycles=10, noise=0.01, v_c=None, L=None, start=None):
    L = L or rng.uniform(300, 700)
    v_c = v_c or rng.uniform(100, 500)
    start = np.array([800.0, -200, 400]) if start is None else start
    d, e1, e2 = _frame(rng.standard_normal(3))
    lat = _lateral(rng, n_cycles)
    cyc = _along(rng, L, v_c, n_cycles)
    parts = []
    for j, (t, u, v) in enumerate(cyc):  # loop over cycles
        o = lat(j, u / L)
        parts.append((t, start + u[:, None] * d + o[:, :1] * e1 + o[:, 1:] * e2))
    cyc = [(t, u, _true_speed(t, p)) for (t, u, _), (_, p) in zip(cyc, parts)]
    tt, true, meas = _stack(parts, rng, noise)
    sp = np.linspace(0.05 * L, 0.95 * L, 50)
    cross = np.stack([lat(j, sp / L) for j in range(n_cycles)])
    cross = np.concatenate([cross, np.zeros((*cross.shape[:2], 1))], axis=2)
    at, rt = iso_at_rt(cross)
    path = {"name": "line", "kind": "line", "start_mm": start.tolist(), "end_mm": (start + L * d).tolist(),
            "velocity_mm_s": v_c}
    return Sim(tt, true, meas, path, {"AT_mm": at, "RT_mm": rt, **_velocity_truth(cyc, L, v_c)})


def circle(rng, *, n_cycles=10, noise=0.01, v_c=None, R=None, centre=None):
    R = R or rng.uniform(20, 200)
    v_c = v_c or rng.uniform(50, 300)
    centre = np.array([600.0, 300, 500]) if centre is None else centre
    nrm, e1, e2 = _frame(rng.standard_normal(3))
    L = 2 * np.pi * R
    lat = _lateral(rng, n_cycles)
    cyc = _along(rng, L, v_c, n_cycles)
    parts = []
    for j, (t, u, v) in enumerate(cyc):  # loop over cycles
        o = lat(j, u / L)
        phi = u / R
        radial = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
        parts.append((t, centre + (R + o[:, :1]) * radial + o[:, 1:] * nrm))
    cyc = [(t, u, _true_speed(t, p)) for (t, u, _), (_, p) in zip(cyc, parts)]
    tt, true, meas = _stack(parts, rng, noise)
    sp = L * (np.arange(50) + 0.5) / 50
    cross = np.stack([lat(j, sp / L) for j in range(n_cycles)])
    cross = np.concatenate([cross, np.zeros((*cross.shape[:2], 1))], axis=2)
    at, rt = iso_at_rt(cross)
    pts = [centre + R * e1, centre + R * (np.cos(2) * e1 + np.sin(2) * e2), centre + R * (np.cos(4) * e1 + np.sin(4) * e2)]
    path = {"name": "circle", "kind": "arc", "full": True, "points_mm": [p.tolist() for p in pts],
            "velocity_mm_s": v_c}
    return Sim(tt, true, meas, path, {"AT_mm": at, "RT_mm": rt, **_velocity_truth(cyc, L, v_c)})


def _rounded_rectangle(C, rho, amp, lam, step=0.02):
    """Dense true path of a cycle: corners rounded by arcs of radius rho[k], an outward damped overshoot
    of amplitude amp[k] after each; returns points (M, 3)."""
    pts = []
    for k in range(4):  # loop over edges k -> k+1
        a, b = C[k], C[(k + 1) % 4]
        t = (b - a) / np.linalg.norm(b - a)
        tp = (a - C[k - 1]) / np.linalg.norm(a - C[k - 1])  # the previous edge's direction: outward here
        Le = np.linalg.norm(b - a)
        ra, rb = rho[k], rho[(k + 1) % 4]
        q = np.arange(ra, Le - rb, step)
        x = q - ra
        over = amp[k] * np.exp(-x / lam) * np.sin(np.pi * x / (2 * lam)) if k != 0 else 0 * x
        pts.append(a[None] + q[:, None] * t + over[:, None] * tp)
        cen = b - rb * t + rb * (C[(k + 2) % 4] - b) / np.linalg.norm(C[(k + 2) % 4] - b)
        t2 = (C[(k + 2) % 4] - b) / np.linalg.norm(C[(k + 2) % 4] - b)
        th = np.linspace(0, np.pi / 2, max(int(rb * np.pi / 2 / step), 3))
        # arc from (b - rb t) to (b + rb t2) about cen
        pts.append(cen[None] - rb * np.cos(th)[:, None] * t2 + rb * np.sin(th)[:, None] * t)
    return np.concatenate(pts)


def rectangle(rng, *, n_cycles=10, noise=0.01, v_c=None, blend=None, origin=None, sides_mm=(100, 300),
              blend_mm=(1.0, 5.0)):
    """A rectangle's cycles, each from the end of its start corner's blend (no lead-in): sides drawn in
    ``sides_mm``, a blended corner's radius in ``blend_mm`` (5 % from corner to corner)."""
    a, b = rng.uniform(*sides_mm), rng.uniform(*sides_mm)
    v_c = v_c or rng.uniform(100, 400)
    blend = bool(rng.integers(2)) if blend is None else blend
    o = np.array([700.0, 0, 200]) if origin is None else origin
    _, e1, e2 = _frame(rng.standard_normal(3))
    C = np.stack([o, o + a * e1, o + a * e1 + b * e2, o + b * e2])
    lam = rng.uniform(2, 10)
    base_rho = rng.uniform(*blend_mm) if blend else rng.uniform(0.05, 0.3)
    base_amp = rng.uniform(0.0, 0.05) if blend else rng.uniform(0.05, 0.5)
    cr, co, parts = [], [], []
    for j in range(n_cycles):  # loop over cycles
        rho = base_rho * (1 + 0.05 * rng.standard_normal(4))
        amp = base_amp * (1 + 0.1 * rng.standard_normal(4)).clip(0)
        P = _rounded_rectangle(C, rho, amp, lam)
        seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
        s = np.concatenate([[0], np.cumsum(seg)])
        cyc = _along(rng, s[-1], v_c, 1)[0]
        u = cyc[1]
        Pt = np.stack([np.interp(u, s, P[:, i]) for i in range(3)], axis=1)
        parts.append((cyc[0], Pt))
        for k in (1, 2, 3):  # the standard's CR, CO on the dense true path
            cr.append(np.linalg.norm(P - C[k], axis=1).min())
            t1 = (C[k] - C[k - 1]) / np.linalg.norm(C[k] - C[k - 1])
            t2 = (C[(k + 1) % 4] - C[k]) / np.linalg.norm(C[(k + 1) % 4] - C[k])
            q = (P - C[k]) @ t2
            e2n = np.linalg.norm(C[(k + 1) % 4] - C[k])
            after = (q > 0) & (q <= 0.5 * e2n) & (np.abs((P - C[k]) @ t1) < 0.25 * e2n)
            co.append(max(0.0, ((P - C[k]) @ t1)[after].max()))
    tt, true, meas = _stack(parts, rng, noise)
    path = {"name": "rectangle", "kind": "rectangle", "corners_mm": C.tolist(), "blend_mm": base_rho if blend else 0.0}
    return Sim(tt, true, meas, path, {"CR_mm": max(cr), "CO_mm": max(co)})


def weave(rng, *, n_cycles=10, noise=0.01, v_c=None, start=None):
    L = rng.uniform(200, 400)
    v_c = v_c or rng.uniform(20, 60)
    A_c, F_c = rng.uniform(1.0, 5.0), rng.uniform(1.0, 5.0)
    eA, eF = rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05)
    start = np.array([900.0, 400, 300]) if start is None else start
    d, e1, e2 = _frame(rng.standard_normal(3))
    cyc = _along(rng, L, v_c, n_cycles)
    parts, amps, freqs = [], [], []
    lag = rng.uniform(0, 0.2) * rng.standard_normal(2)
    for t, u, v in cyc:  # loop over cycles
        Aj, Fj = A_c * (1 + eA + 0.003 * rng.standard_normal()), F_c * (1 + eF + 0.002 * rng.standard_normal())
        amps.append(Aj)
        freqs.append(Fj)
        y = Aj * np.sin(2 * np.pi * Fj * t + rng.uniform(0, 2 * np.pi))
        parts.append((t, start + u[:, None] * d + (y + lag[0])[:, None] * e1 + lag[1] * e2))
    tt, true, meas = _stack(parts, rng, noise)
    path = {"name": "weave", "kind": "weaving", "start_mm": start.tolist(), "end_mm": (start + L * d).tolist(),
            "direction_mm": e1.tolist(), "amplitude_mm": A_c, "frequency_Hz": F_c, "velocity_mm_s": v_c}
    return Sim(tt, true, meas, path, {"WS_percent": (np.mean(amps) - A_c) / A_c * 100,
                                      "WF_percent": (np.mean(freqs) - F_c) / F_c * 100})


KINDS = {"line": line, "circle": circle, "rectangle": rectangle, "weave": weave}


def whole_test(rng, *, n_cycles=10, noise=0.01):
    """Every path of a path test one after the other in one stream (apart in space): a line, a large and a
    small circle, a rectangle with sharp corners and one with blends, a weave. Returns (t, meas, paths, truths)."""
    sims = [line(rng, n_cycles=n_cycles, noise=noise, v_c=250.0, L=500.0, start=np.array([800.0, -600, 400])),
            circle(rng, n_cycles=n_cycles, noise=noise, v_c=250.0, R=150.0, centre=np.array([600.0, 300, 500])),
            circle(rng, n_cycles=n_cycles, noise=noise, v_c=250.0, R=25.0, centre=np.array([1200.0, 300, 500])),
            rectangle(rng, n_cycles=n_cycles, noise=noise, v_c=250.0, blend=False, origin=np.array([0.0, 0, 0])),
            rectangle(rng, n_cycles=n_cycles, noise=noise, v_c=250.0, blend=True, origin=np.array([0.0, 1500, 0])),
            weave(rng, n_cycles=n_cycles, noise=noise, v_c=40.0, start=np.array([-800.0, -800, 300]))]
    names = ["line", "circle_large", "circle_small", "rectangle_sharp", "rectangle_blend", "weave"]
    t0, ts, ps, paths, truths = 0.0, [], [], [], {}
    for name, sim in zip(names, sims):  # loop over paths
        ts.append(sim.t + t0)
        ps.append(sim.meas)
        t0 = ts[-1][-1] + 1.0
        paths.append({**sim.path, "name": name})
        truths[name] = sim.truth
    return np.concatenate(ts), np.concatenate(ps), paths, truths


def reorientation(rng, *, n_cycles=10, noise=0.01, turn_deg=None):
    """The tool point held while the angles turn (clause 8.3): the point wanders with the turn (a static
    offset, a bend with the angle, a per-cycle scatter); truth from the true points at the turned angles."""
    p0 = np.array([700.0, 100, 600])
    a0 = rng.uniform(-30, 30, 3)
    turn = rng.uniform(20, 60) * rng.standard_normal(3) / np.sqrt(3) if turn_deg is None else turn_deg
    lat = _lateral(rng, n_cycles)
    _, e1, e2 = _frame(rng.standard_normal(3))
    Lt = float(np.linalg.norm(turn))
    cyc = _along(rng, Lt, rng.uniform(20, 60), n_cycles)
    parts, abcs = [], []
    for j, (t, u, _) in enumerate(cyc):  # loop over cycles (u: the angle turned, deg)
        o = lat(j, u / Lt)
        parts.append((t, p0 + o[:, :1] * e1 + o[:, 1:] * e2))
        abcs.append(a0 + (u / Lt)[:, None] * turn)
    tt, true, meas = _stack(parts, rng, noise)
    sp = np.linspace(0.05 * Lt, 0.95 * Lt, 50)
    cross = np.stack([lat(j, sp / Lt) for j in range(n_cycles)])
    at, rt = iso_at_rt(np.concatenate([cross, np.zeros((*cross.shape[:2], 1))], axis=2))
    path = {"name": "reorient", "kind": "reorientation", "point_mm": p0.tolist(), "start_abc_deg": a0.tolist(),
            "end_abc_deg": (a0 + turn).tolist()}
    return Sim(tt, true, meas, path, {"AT_mm": at, "RT_mm": rt}, abc=np.concatenate(abcs))
