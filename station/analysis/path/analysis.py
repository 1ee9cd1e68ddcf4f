"""All the path figures of one stream against its path file (ISO 9283 clauses 8.2-8.5, 11), with u and U.

:func:`analyze_paths` takes the stream's arrays (time, positions, validity,
angles) and the commanded paths, and gives each path its cycles, its
figures, their uncertainty, and what was left out and why: a cycle whose pass
broke (beam broken, out of the tube, turned back) is no cycle; a figure on the
clock (AV, RV, FV, WF) is refused on a clock that failed its check, and a
cycle with a jump of the clock is left out of it. :func:`verdicts` judges the
figures against limits.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from station.analysis.path.accuracy import at_rt, at_rt_uncertainty
from station.analysis.path.commanded import Arc, Line, PathSpec, Rectangle, Reorientation, Weaving
from station.analysis.path.cornering import CornerWindow, cornering, cornering_uncertainty
from station.analysis.path.figures import NAMES, SIGNED
from station.analysis.path.mc import DEFAULT_TRIALS
from station.analysis.path.noise import PathNoise
from station.analysis.path.passes import crossings, find_passes, project
from station.analysis.path.velocity import curvature_bias, path_velocity, speed, velocity_uncertainty
from station.analysis.path.weaving import fit_sine, weaving
from station.errors import ConfigError, DataError
from station.verdict import Outcome

#: fewest complete cycles for any figure
MIN_CYCLES = 2

#: a pass's sampling interval may wander this fraction from its median before its speed is refused
DT_TOLERANCE = 0.25

#: part of a weaving cycle (fractions of the base line) whose sine is fitted
WEAVE_WINDOW = (0.1, 0.9)


def figures_of(spec: PathSpec) -> tuple[str, ...]:
    """The figures a path of this kind gives."""
    g = spec.geometry
    if isinstance(g, Rectangle):
        return ("CR_mm", "CO_mm")
    if isinstance(g, Weaving):
        return ("WS_percent", "WF_percent")
    if isinstance(g, Reorientation):
        return ("AT_mm", "RT_mm")
    return ("AT_mm", "RT_mm") + (("AV_percent", "RV_percent", "FV_percent") if spec.velocity_mm_s else ())


@dataclass
class PathResult:
    name: str
    kind: str
    n_cycles: int
    figures: dict = field(default_factory=dict)  # name -> value or None
    uncertainty: dict = field(default_factory=dict)  # name -> FigureUncertainty
    refused: dict = field(default_factory=dict)  # name -> reason
    broken: list = field(default_factory=list)  # passes.Broken
    notes: list = field(default_factory=list)
    detail: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {"name": self.name, "kind": self.kind, "n_cycles": self.n_cycles}
        for k, v in self.figures.items():
            d[k] = None if v is None else round(float(v), 7)
        d["uncertainty"] = {k: fu.to_dict() for k, fu in self.uncertainty.items()}
        d["refused"] = dict(self.refused)
        d["broken_passes"] = [b.to_dict() for b in self.broken]
        d["notes"] = list(self.notes)
        d["detail"] = self.detail
        return d


def _noise(noise_sd_mm, points) -> PathNoise:
    if callable(noise_sd_mm):
        return PathNoise(float(np.mean(noise_sd_mm(points))))
    return PathNoise.of(noise_sd_mm)


def _dt_ok(t) -> tuple[float, str]:
    dt = np.diff(t)
    med = float(np.median(dt))
    if not med > 0:
        return med, "its time stamps do not advance"
    worst = float(np.max(np.abs(dt - med))) / med
    if worst > DT_TOLERANCE:
        return med, f"its sampling interval wanders {worst:.0%} from its median {med * 1e3:.3f} ms"
    return med, ""


def _window_rows(ps, a: float, b: float) -> slice:
    mx = np.maximum.accumulate(ps.s_mm)
    return slice(int(np.searchsorted(mx, a)), int(np.searchsorted(mx, b)))


def _accuracy(res, spec, t, xyz, passes, noise, kw, ds_mm):
    g = spec.geometry
    sp = spec.plane_s_mm()
    c = crossings(xyz, passes, sp)
    cmd = g.point_at(sp)
    acc = at_rt(c, cmd)
    normals = None if isinstance(g, Reorientation) else g.tangent_at(sp)
    sag = ds_mm ** 2 / (8 * g.radius_mm) / np.sqrt(3) if isinstance(g, Arc) else 0.0
    times = crossings(np.asarray(t, dtype=float)[:, None], passes, sp)[:, :, 0]
    res.uncertainty.update(at_rt_uncertainty(c, cmd, normals, noise, acc, spec.name, sampling_mm=sag, t_s=times,
                                             **kw))
    # AT, RT taken back to no noise (the ISO formula on the noisy crossings kept beside them)
    res.detail["as_measured"] = {"AT_mm": acc.AT_mm, "RT_mm": acc.RT_mm}
    res.figures["AT_mm"] = res.uncertainty["AT_mm"].value
    res.figures["RT_mm"] = res.uncertainty["RT_mm"].value if "RT_mm" in res.uncertainty else None
    res.detail["planes"] = {"s": [round(float(x), 4) for x in sp], "s_unit": "deg" if normals is None else "mm",
                            "AT_i_mm": [round(float(x), 6) for x in acc.AT_i_mm],
                            "RT_i_mm": None if acc.RT_i_mm is None else [round(float(x), 6) for x in acc.RT_i_mm]}


def _time_cycles(res, passes, t, clock_refused, jump_rows, figs):
    """The passes the clock can time, or None with the figures refused."""
    if clock_refused:
        for f in figs:
            res.refused[f] = clock_refused
        return None
    jr = np.asarray(list(jump_rows), dtype=np.int64)
    keep = []
    for ps in passes:  # loop over cycles
        if jr.size and np.any((jr > ps.i0) & (jr <= ps.i1)):
            res.notes.append(f"cycle {ps.cycle}: the clock jumps within it; left out of {', '.join(figs)}")
            continue
        keep.append(ps)
    if len(keep) < MIN_CYCLES:
        for f in figs:
            res.refused[f] = f"fewer than {MIN_CYCLES} cycles on a clock without jumps"
        return None
    return keep


def _velocity(res, spec, t, xyz, passes, noise, kw, clock_refused, jump_rows):
    figs = ("AV_percent", "RV_percent", "FV_percent")
    keep = _time_cycles(res, passes, t, clock_refused, jump_rows, figs)
    if keep is None:
        return
    L = spec.geometry.length_mm
    speeds, pieces = [], []
    for ps in keep:  # loop over cycles
        dt, why = _dt_ok(t[ps.rows])
        if why:
            res.notes.append(f"cycle {ps.cycle}: left out of the path velocity: {why}")
            continue
        v = speed(xyz[ps.rows], dt, noise.white_mm)
        if isinstance(spec.geometry, Arc):  # the filter's bias on the arc, at this cycle's own speed
            bias = curvature_bias(spec.geometry.radius_mm, float(np.mean(v)), dt)
            v = v / (1.0 + bias)
            res.detail.setdefault("curvature_bias", []).append(bias)
        win = _window_rows(ps, spec.velocity_window[0] * L, spec.velocity_window[1] * L)
        if win.stop - win.start < 5:
            res.notes.append(f"cycle {ps.cycle}: fewer than 5 samples in the velocity window; left out")
            continue
        speeds.append(v[win])
        pieces.append((v[win], dt))
    if len(speeds) < MIN_CYCLES:
        for f in figs:
            res.refused.setdefault(f, f"fewer than {MIN_CYCLES} cycles with a regular clock")
        return
    pv = path_velocity(speeds, spec.velocity_mm_s)
    res.uncertainty.update(velocity_uncertainty(pieces, spec.velocity_mm_s, noise, pv, spec.name, **kw))
    res.figures.update(AV_percent=pv.AV_percent, RV_percent=pv.RV_percent,
                       FV_percent=res.uncertainty["FV_percent"].value)  # FV taken back to no noise
    res.detail["as_measured"] = {"FV_percent": pv.FV_percent}
    res.detail["velocity"] = {"cycles": len(speeds), "mean_speed_mm_s": [round(float(x), 4) for x in pv.mean_speed_mm_s],
                              "range_mm_s": [round(float(x), 4) for x in pv.range_mm_s]}


def _cornering(res, spec, t, xyz, passes, noise, kw):
    g = spec.geometry
    cs, edges = g.corner_s_mm, g.edges_mm
    c = np.asarray(g.corners_mm, dtype=float)
    wins = []
    for ps in passes:  # loop over cycles
        for k in (1, 2, 3):  # loop over the corners inside a cycle
            rows = _window_rows(ps, cs[k] - 0.5 * edges[k - 1], cs[k] + 0.5 * edges[k])
            p = xyz[ps.i0:ps.i1 + 1][rows]
            if p.shape[0] < 3:
                res.notes.append(f"cycle {ps.cycle}, corner {k + 1}: fewer than 3 samples; left out")
                continue
            t1, t2 = g.tangent_at(cs[k] - 0.5 * edges[k - 1])[0], g.tangent_at(cs[k] + 0.5 * edges[k])[0]
            wins.append(CornerWindow(k + 1, ps.cycle, p, c[k], t1, t2, float(edges[k]),
                                     t[ps.i0:ps.i1 + 1][rows]))
    if not wins:
        res.refused.update(CR_mm="no corner with samples", CO_mm="no corner with samples")
        return
    cr = cornering(wins)
    res.uncertainty.update(cornering_uncertainty(wins, noise, cr, spec.name, **kw))
    # CO taken back to no noise
    res.detail["as_measured"] = {"CR_mm": cr.CR_mm, "CO_mm": cr.CO_mm}
    res.figures.update(CR_mm=res.uncertainty["CR_mm"].value, CO_mm=res.uncertainty["CO_mm"].value)
    res.detail["corners"] = [{"corner": a, "cycle": b, "CR_mm": round(float(x), 6), "CO_mm": round(float(y), 6)}
                             for (a, b), x, y in zip(cr.corners, cr.CR_jc_mm, cr.CO_jc_mm)]
    res.detail["blend_mm"] = float(g.blend_mm)


def _weaving(res, spec, t, xyz, passes, kw, clock_refused, jump_rows):
    g = spec.geometry
    L = g.length_mm
    fits = []
    for ps in passes:  # loop over cycles
        rows = _window_rows(ps, WEAVE_WINDOW[0] * L, WEAVE_WINDOW[1] * L)
        p, tt = xyz[ps.i0:ps.i1 + 1][rows], t[ps.i0:ps.i1 + 1][rows]
        if p.shape[0] < 10:
            res.notes.append(f"cycle {ps.cycle}: fewer than 10 samples to fit the weave; left out")
            continue
        fits.append((ps, fit_sine(tt, (p - g.base.start_mm) @ g.direction, g.frequency_Hz)))
    if len(fits) < MIN_CYCLES:
        res.refused.update(WS_percent=f"fewer than {MIN_CYCLES} cycles to fit",
                           WF_percent=f"fewer than {MIN_CYCLES} cycles to fit")
        return
    timed = _time_cycles(res, [ps for ps, _ in fits], t, clock_refused, jump_rows, ("WF_percent",))
    wr, u = weaving([f for _, f in fits], g.amplitude_mm, g.frequency_Hz, spec.name, frequency=False, k=kw["k"])
    res.figures["WS_percent"] = wr.WS_percent
    res.uncertainty.update(u)
    if timed is not None:
        ids = {ps.cycle for ps in timed}
        wr2, u2 = weaving([f for ps, f in fits if ps.cycle in ids], g.amplitude_mm, g.frequency_Hz, spec.name,
                          k=kw["k"])
        res.figures["WF_percent"] = wr2.WF_percent
        res.uncertainty["WF_percent"] = u2["WF_percent"]
    res.detail["weave"] = [{"cycle": ps.cycle, "amplitude_mm": round(f.amplitude_mm, 6),
                            "frequency_Hz": round(f.frequency_Hz, 6), "residual_rms_mm": round(f.rms_mm, 6)}
                           for ps, f in fits]


def analyze_path(spec: PathSpec, t_s, xyz_mm, valid, *, abc_deg=None, noise_sd_mm=0.0075, clock_refused: str = "",
                 jump_rows=(), trials: int = DEFAULT_TRIALS, seed: int = 0, k: float = 2.0) -> PathResult:
    """One path's figures. ``noise_sd_mm``: the instrument's per-coordinate reading noise: a white sd (a
    number, or a function of points (n, 3) -> sd (n,), e.g. ``Budget.instrument_sd_mm``), or white noise and a
    wander (a :class:`~station.models.tracker_noise.TrackerNoise` or
    :class:`~station.analysis.path.noise.PathNoise`), which the figures' re-measurement draws give its
    correlation in time."""
    t = np.asarray(t_s, dtype=float)
    xyz = np.asarray(xyz_mm, dtype=float)
    ok = np.asarray(valid, dtype=bool) & np.all(np.isfinite(xyz), axis=1)
    g = spec.geometry
    if isinstance(g, Reorientation):
        if abc_deg is None:
            raise DataError(f"path {spec.name!r} is a reorientation and the stream has no angles (columns a, b, c)")
        ok &= np.all(np.isfinite(abc_deg), axis=1)
    tube = spec.tube_mm + (g.amplitude_mm if isinstance(g, Weaving) else 0.0)
    win = None if spec.window_s is None else (t >= spec.window_s[0]) & (t <= spec.window_s[1])
    # only the rows in the path's box (its points every 1/200 of it, plus the tube) are projected
    box = g.point_at(np.linspace(0.0, g.length_mm, 201))
    lo_b, hi_b = box.min(axis=0) - tube - 1.0, box.max(axis=0) + tube + 1.0
    near = ok & np.all((xyz >= lo_b) & (xyz <= hi_b), axis=1) & (True if win is None else win)
    rows = np.flatnonzero(near)
    s, off = np.full(t.size, np.nan), np.full(t.size, np.inf)
    s[rows], off[rows] = project(g, xyz[rows], None if abc_deg is None else np.asarray(abc_deg, float)[rows])
    sp = spec.plane_s_mm()
    lo, hi = sp[0], sp[-1]
    if isinstance(g, Rectangle):
        # a cycle is marked a quarter along its first edge and a quarter before the end of its last: clear of
        # the start corner and its blend, and of the measured corners' windows (half an edge either side). At 1 %
        # of the length, a stream that began at the end of a 4.8 mm blend on a 440 mm rectangle began past the
        # mark: its first turn was lost and its last reported broken
        lo, hi = 0.25 * g.edges_mm[0], g.length_mm - 0.25 * g.edges_mm[-1]
    passes, broken = find_passes(s, off, ok, length=g.length_mm, closed=bool(getattr(g, "closed", False)),
                                 s_lo=lo, s_hi=hi, tube_mm=tube, in_window=near)
    res = PathResult(spec.name, spec.kind, len(passes), {f: None for f in figures_of(spec)}, broken=broken)
    res.detail["cycle_rows"] = [[int(p.i0), int(p.i1)] for p in passes]
    for b in broken:  # loop over broken passes
        res.notes.append(f"a pass from row {b.i0} is no cycle: it stopped at s = {b.s_mm:.2f} "
                         f"{'deg' if isinstance(g, Reorientation) else 'mm'}: {b.reason}")
    if len(passes) < MIN_CYCLES:
        why = (f"{len(passes)} complete cycle{'s' if len(passes) != 1 else ''} found (at least {MIN_CYCLES} needed; "
               f"samples within {tube:g} mm of the path, from its first normal plane to its last)")
        res.refused = {f: why for f in res.figures}
        return res
    noise = _noise(noise_sd_mm, g.point_at(sp))
    kw = {"trials": int(trials), "seed": int(seed), "k": float(k)}
    if isinstance(g, Rectangle):
        _cornering(res, spec, t, xyz, passes, noise, kw)
    elif isinstance(g, Weaving):
        _weaving(res, spec, t, xyz, passes, kw, clock_refused, jump_rows)
    else:
        ds = float(np.median(np.concatenate([np.abs(np.diff(p.s_mm)) for p in passes])))
        _accuracy(res, spec, t, xyz, passes, noise, kw, ds)
        if spec.velocity_mm_s and isinstance(g, (Line, Arc)):
            _velocity(res, spec, t, xyz, passes, noise, kw, clock_refused, jump_rows)
    res.detail["noise_sd_mm"] = noise.total_mm
    res.detail["noise"] = {"white_mm": noise.white_mm, "wander_mm": noise.wander_mm,
                           "wander_tau_s": noise.wander_tau_s}
    return res


def analyze_paths(specs: list[PathSpec], t_s, xyz_mm, valid, **kw) -> dict[str, PathResult]:
    """Every path of a path file; DataError when two paths claim the same samples (give them ``window_s``)."""
    out = {spec.name: analyze_path(spec, t_s, xyz_mm, valid, **kw) for spec in specs}
    spans = sorted((a, b, name) for name, r in out.items() for a, b in r.detail["cycle_rows"])
    for (a0, b0, n0), (a1, b1, n1) in zip(spans, spans[1:]):  # loop over neighbouring cycles
        if a1 <= b0 and n0 != n1:
            raise DataError(f"paths {n0!r} and {n1!r} both claim stream rows {a1}-{min(b0, b1)}: give each its "
                            f"window_s in the path file")
    return out


def check_limits(limits: dict, specs: list[PathSpec]) -> dict:
    """``{"FIG" or "path.FIG": limit}`` validated: known figures and paths, limits > 0."""
    names = {s.name for s in specs}
    for key, v in limits.items():
        path, _, fig = key.rpartition(".")
        if fig not in NAMES:
            raise ConfigError(f"--limit {key}: unknown figure {fig!r} (one of {', '.join(NAMES)})")
        if path and path not in names:
            raise ConfigError(f"--limit {key}: no path named {path!r} in the path file ({', '.join(sorted(names))})")
        if not (np.isfinite(v) and v > 0):
            raise ConfigError(f"--limit {key}: the limit must be > 0, got {v}")
    return dict(limits)


def verdicts(results: dict[str, PathResult], limits: dict) -> list[dict]:
    """One verdict per (path, figure) that a limit applies to: |value| <= limit for signed figures."""
    out = []
    for key, lim in limits.items():  # loop over limits
        path, _, fig = key.rpartition(".")
        hit = False
        for name, r in results.items():  # loop over paths
            if (path and name != path) or fig not in r.figures:
                continue
            hit = True
            v = r.figures[fig]
            fu = r.uncertainty.get(fig)
            if v is None:
                oc, why = Outcome.NOT_DECIDED, r.refused.get(fig, "not computed")
            else:
                oc = Outcome.PASS if (abs(v) if fig in SIGNED else v) <= lim else Outcome.FAIL
                why = ""
            out.append({"path": name, "characteristic": fig, "value": v, "limit": lim,
                        "U": None if fu is None else fu.U, "outcome": str(oc), "reason": why})
        if not hit:
            out.append({"path": path or None, "characteristic": fig, "value": None, "limit": lim, "U": None,
                        "outcome": str(Outcome.NOT_DECIDED), "reason": f"no path gives {fig}"})
    return out
