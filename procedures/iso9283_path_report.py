"""The HTML report of an ISO 9283 path run (clauses 8.2-8.5).

Per path: the measured cycles against the commanded path in the path's plane, the deviation from the commanded
path along it per cycle (mm), and the speed along it per cycle against the commanded speed (mm/s); then the
figures table of every stored row with its U (k = 2) and verdict.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from station.analysis.path.commanded import Reorientation
from station.analysis.path.profiles import cycle_profiles, plane_axes
from station.report import Report, plot_xy

#: samples per cycle a plotted trace keeps at most
TRACE_POINTS = 1000


def _thin(*arrays, n: int = TRACE_POINTS):
    step = max(1, int(np.ceil(arrays[0].size / n)))
    return [a[::step] for a in arrays]


def path_figures(spec, result, t_s, xyz_mm) -> list[tuple[str, str]]:
    """The plots of one path: plane view, deviation along the path, speed along it (what has cycles)."""
    rows = result.detail.get("cycle_rows") or []
    if not rows or isinstance(spec.geometry, Reorientation):
        return []
    g = spec.geometry
    profiles = cycle_profiles(spec, t_s, xyz_mm, rows, noise_sd_mm=float(result.detail.get("noise_sd_mm", 0.0)))
    cmd = g.point_at(np.linspace(0.0, g.length_mm, 400))
    origin, e1, e2 = plane_axes(cmd, np.concatenate([p.xyz_mm for p in profiles]))
    view = [("commanded", (cmd - origin) @ e1, (cmd - origin) @ e2, "-")]
    view += [(f"cycle {p.cycle}", *_thin((p.xyz_mm - origin) @ e1, (p.xyz_mm - origin) @ e2), "-") for p in profiles]
    figs = [(f"{spec.name}: measured cycles against the commanded path, in the path's plane (a line's: along it "
             f"and across it where the measured path deviates most)",
             plot_xy(view, xlabel="along the plane's first axis [mm]", ylabel="second axis [mm]",
                     title=f"{spec.name}: path"))]
    dev = [(f"cycle {p.cycle}", *_thin(p.s_mm, p.deviation_mm), "-") for p in profiles]
    figs.append((f"{spec.name}: distance of the measured path from the commanded one along it, per cycle",
                 plot_xy(dev, xlabel="arc length along the commanded path [mm]", ylabel="deviation [mm]",
                         title=f"{spec.name}: deviation along the path")))
    sp = [(f"cycle {p.cycle}", *_thin(p.s_mm, p.speed_mm_s), "-") for p in profiles if p.speed_mm_s is not None]
    if sp:
        if spec.velocity_mm_s:
            sp.insert(0, (f"commanded {spec.velocity_mm_s:g} mm/s", np.array([0.0, g.length_mm]),
                          np.full(2, float(spec.velocity_mm_s)), "-"))
        figs.append((f"{spec.name}: speed of the tool point along the path, per cycle"
                     + (" against the commanded speed" if spec.velocity_mm_s else ""),
                     plot_xy(sp, xlabel="arc length along the commanded path [mm]", ylabel="speed [mm/s]",
                             title=f"{spec.name}: speed along the path")))
    return figs


def _with_u(rows, results: Mapping) -> list[dict]:
    out = []
    for r in rows:
        if r["name"] == "n_cycles":
            continue
        r = dict(r)
        res = results.get(r["pose"])
        fu = None if res is None else res.uncertainty.get(r["name"])
        if fu is not None:
            r["U"] = float(fu.U)
        out.append(r)
    return out


def build_report(plan, run, rows, specs: Mapping, results: Mapping, streams: Mapping) -> Report:
    """The run's report. ``specs`` ``{path: PathSpec}``, ``results`` ``{path: PathResult}``, ``streams``
    ``{path: (t_s, xyz_mm base frame, valid)}``."""
    facts = {
        "run": run.run_id,
        "robot": f"{run.model} serial {run.serial} ({run.overhaul_state})",
        "procedure": (f"ISO 9283 path test, {plan.path_cycles} cycles per path, paths "
                      f"{', '.join(results)}, tracker {plan.tracker_rate_hz:g} Hz"),
        "cycles found": ", ".join(f"{n} {r.n_cycles}" for n, r in results.items()),
    }
    figs: list[tuple[str, str]] = []
    notes: list[str] = []
    for name, res in results.items():  # loop over paths
        t, xyz, _valid = streams[name]  # the analysis's cycle rows index the whole stream
        figs += path_figures(specs[name], res, t, xyz)
        notes += [f"{name}: {n}" for n in res.notes]
        notes += [f"{name} {f}: not computed: {why}" for f, why in res.refused.items()]
    return Report(title=f"ISO 9283 path run {run.run_id}", facts=facts, rows=_with_u(rows, results), figures=figs,
                  notes=notes)
