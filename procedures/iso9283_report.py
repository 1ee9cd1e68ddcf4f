"""The HTML report of an ISO 9283 run: the seed's tables and figures.

Figures (seed 000): speed and the chosen extraction windows of the first
cycles (Figs. 3-4), the approach to P1 with the limit band (Figs. 5-6), the
attained-pose clusters per approach direction (Fig. 7), and per-pose
accuracy, repeatability, distance and posing time against the limits
(Table 3, Fig. 8).
"""

from __future__ import annotations

import numpy as np

from station import characteristics as table
from station.report import Report, plot_approach, plot_bars, plot_clusters, plot_intervals, plot_velocity_windows


def _rows_used(ex, idx):
    idx = np.asarray(idx, dtype=np.int64)
    return idx if ex.rows_used is None else np.asarray(ex.rows_used)[idx]


def _first_cycles_figure(t, xyz, main, n_cycles: int = 3) -> str | None:
    ex = main.extraction
    st = ex.stops
    if st.n == 0:
        return None
    k = min(st.n - 1, 5 * n_cycles)
    t_end = float(st.t_s[k]) + 0.5
    sel = t <= t_end
    ts, ps = t[sel], xyz[sel]
    if ts.size < 3:
        return None
    speed = np.linalg.norm(np.diff(ps, axis=0), axis=1) / np.diff(ts)
    first = _rows_used(ex, st.i_window_first[: k + 1])
    last = _rows_used(ex, st.i_window_last[: k + 1])
    windows = [(float(t[a]), float(t[b])) for a, b in zip(first, last)]
    return plot_velocity_windows(ts[1:], speed, windows, title=f"Speed, first {n_cycles} cycles, with the least-speed windows")


def _approach_figure(t, xyz, main, pose: str = "P1") -> str | None:
    pr = main.poses.get(pose)
    if pr is None or pr.overshoot is None or pr.overshoot.rows.size == 0:
        return None
    ov = pr.overshoot
    row = int(ov.rows[0])
    entry = int(ov.row_entry[0]) if ov.row_entry.size else -1
    settle = int(ov.row_settled[0]) if ov.row_settled.size else -1
    start = max(0, (entry if entry >= 0 else row) - 20)
    end = min(row, max(settle, entry, start) + 40)  # the approach and the settling, not the whole dwell
    seg = slice(start, end + 1)
    dist = np.linalg.norm(xyz[seg] - xyz[row], axis=1)
    return plot_approach(
        t[seg], dist, ov.band_mm, t_enter_s=float(t[entry]) if entry >= 0 else None,
        t_settle_s=float(t[settle]) if settle >= 0 else None,
        title=f"Approach to {pose}, first cycle (band {ov.band_mm:.3g} mm, {ov.band_source})",
    )


def _cluster_figures(vap_xyz, vap, plan) -> list[tuple[str, str]]:
    figs = []
    if vap is None:
        return figs
    for name, pr in vap.poses.items():
        groups = pr.multidirectional.groups
        if len(groups) < 2:
            continue
        clusters = {g.label: vap_xyz[np.asarray(g.rows, dtype=np.int64)] for g in groups}
        vap_txt = "n/a" if pr.multidirectional.vAP_mm is None else f"{pr.multidirectional.vAP_mm:.3f} mm"
        figs.append((f"Fig. 7: attained positions of {name} per approach direction (vAP = {vap_txt})",
                     plot_clusters(clusters, np.asarray(plan.poses_mm[name]), title=name)))
    return figs


def _with_decisions(rows, main, vap) -> list[dict]:
    """The stored rows with each verdict's rule, decision and U (k = 2) when a budget was stated."""
    vs = {(v.characteristic, v.subject): v
          for v in table.from_their_cycles(main.verdicts, vap.verdicts if vap is not None else ())}
    unc = dict(table.from_their_cycles((getattr(main, "uncertainties", {}) or {}).items(),
                                       (getattr(vap, "uncertainties", {}) or {}).items(), key=lambda kv: kv[0][0]))
    out = []
    for r in rows:
        v = vs.get((r["name"], r["pose"]))
        r = dict(r)
        fu = unc.get((r["name"], r["pose"]))
        if fu is not None:
            r.update(U=float(fu.U))
        if v is not None and v.rule is not None:
            fu = v.uncertainty
            r.update(rule=v.rule, U=None if fu is None else float(fu.U),
                     outcome=None if v.value is None else v.outcome)
        out.append(r)
    return out


def build_report(ctx, plan, run, rows, main, vap, *, streams, reg, vap_poses) -> Report:
    """The run's HTML report.

    ``streams`` is ``{"pose": (t, xyz), "vap": (t, xyz)}`` in the base frame,
    ``reg`` the base-frame registration, ``vap_poses`` the poses of the vAP cycles.
    """
    t, xyz = streams["pose"]
    vxyz = streams["vap"][1] if vap is not None else None
    facts = {
        "run": run.run_id,
        "robot": f"{run.model} serial {run.serial} ({run.overhaul_state})",
        "procedure": f"ISO 9283, {plan.cycles} pose cycles, {plan.vap_cycles} vAP cycles (poses {', '.join(vap_poses)}), "
                     f"{plan.speed_frac * 100:.0f} % speed, {plan.dwell_s} s dwell, tracker {plan.tracker_rate_hz:g} Hz",
        "base frame registration": (
            f"joint-1 and joint-2 circles, {reg.n} points, circle fit rms {reg.rms_mm:.3f} mm"
            if ctx.outputs["register base frame"].get("method", "best-fit") == "axes" else
            f"rigid best fit over {reg.n} points, rms {reg.rms_mm:.3f} mm (AP is relative to the best-fit frame, "
            f"which absorbs part of the robot's error)"),
        "registration uncertainty at the test poses (jackknife, 1 sigma)": ", ".join(
            f"{k} {v:.3f} mm" for k, v in ctx.outputs["register base frame"].get("uncertainty_at_poses_mm", {}).items()),
        "ISO conformant": "yes" if main.iso_conformant else "no: " + "; ".join(main.iso_reasons),
    }
    mount = ctx.outputs["register base frame"].get("mounting")
    if mount:
        facts["mounting (ISO 9283 7.8)"] = (
            f"{mount['name']}, its frame from {mount['from']}; the registered base lies up to "
            f"{mount['base_offset_mm']:.3f} mm from it at the test poses")
    if plan.orientation:
        facts["tool orientation"] = (
            f"6-DoF target on the tool (emScon 6D continuous time), angle reading sd {plan.angle_sd_deg:g} deg; "
            "a, b, c about the base x, y, z axes (R = Rz(c) Ry(b) Rx(a)) against the commanded tool-down "
            "orientation")
    figs: list[tuple[str, str]] = []
    f = _first_cycles_figure(t, xyz, main)
    if f:
        figs.append(("Figs. 3-4: speed of the tool point and the windows the attained poses were taken from", f))
    f = _approach_figure(t, xyz, main)
    if f:
        figs.append(("Figs. 5-6: approach to P1 with the limit band", f))
    figs += _cluster_figures(vxyz, vap, plan)
    rows = _with_decisions(rows, main, vap)
    rule = plan.decision_rule if plan.uncertainty is not None else None
    if rule is not None:
        facts["decision rule (ISO 14253-1)"] = (
            "guarded: conformance proven when figure + U <= limit, non-conformance when figure - U > limit, "
            "else not decided" if rule == "guarded" else "simple: the figure against the limit (U shown)")
        b = plan.uncertainty or {}
        facts["uncertainty budget"] = (
            f"tracker {b.get('instrument_a_um', 15.0):g} um + {b.get('instrument_b_um_per_m', 6.0):g} um/m "
            f"({b.get('instrument_kind', 'mpe')}), registration fit rms {reg.rms_mm:.3f} mm over {reg.n} points, "
            f"air temperature u {b.get('temperature_u_K', 0.0):g} K; GUM S1 Monte Carlo "
            f"({b.get('trials', 20000)} trials, seed {b.get('seed', 0)}), U = 2 u")
    by = {}
    for r in rows:
        by.setdefault(r["name"], []).append(r)
    for c in table.characteristics():
        rs = [r for r in by.get(c.key, []) if r["value"] is not None] if c.plotted else []
        if rs:
            title = f"{c.title} per {c.level}" + (f", {c.source}" if c.source else "")
            lim = next((r["limit"] for r in rs if r["limit"] is not None), None)
            ylabel = f"{c.symbol} [{c.unit}]"
            if rule is not None:
                figs.append((title + ", with U (k = 2) and the guard band", plot_intervals(
                    [r["pose"] for r in rs], [r["value"] for r in rs], [r.get("U") for r in rs], limit=lim,
                    ylabel=ylabel, title=title)))
            else:
                figs.append((title, plot_bars([r["pose"] for r in rs], [r["value"] for r in rs], limit=lim,
                                              ylabel=ylabel, title=title)))
    notes = list(main.warnings) + (list(vap.warnings) if vap is not None else [])
    shown = [r for r in rows if r["name"] != "n_cycles"]
    return Report(title=f"ISO 9283 run {run.run_id}", facts=facts, rows=shown, figures=figs, notes=notes)
