"""The static fleet page: robots over limits now, drifting robots, trend plots per robot.

Written like the run reports (:mod:`station.report`): one self-contained
HTML file, inline SVG, nothing beside it.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from station.fleet import YEAR_S, drifting, limit_decisions_now, run_values, since_overhaul
from station.report import Report, plot_xy, render_html
from station.store import RunStore


def fleet_report(store: RunStore, name: str, *, q_max: float = 0.05, max_plots: int = 30) -> Report:
    """The fleet page's content for characteristic ``name``: over-limit rows, drifting robots, their trends."""
    decided = limit_decisions_now(store, name)
    over, undecided = decided["proven"], decided["not_decided"]
    drift = drifting(store, name, q_max=q_max)
    since = since_overhaul(store, name)
    runs = run_values(store, name)
    rep = Report(title=f"Fleet: {name}")
    rep.facts = {
        "store": store.name,
        "robots with a finished run": str(len(since)),
        "stations": ", ".join(sorted({r["station"] or "-" for r in runs})) or "-",
        "robots over a limit now": str(len({r["serial"] for r in over})),
        f"robots drifting (trend since last overhaul, false-discovery rate {q_max:g})": str(len(drift)),
    }
    if undecided:
        rep.facts["robots not decided now (a figure in its guard band, ISO 14253-1)"] = str(
            len({r["serial"] for r in undecided}))
    for r in over + undecided:
        row = {"pose": f"{r['serial']} ({r['model']}, {r['station'] or '-'}) {r['pose']}", "name": r["name"],
               "value": r["value"], "unit": r["unit"], "limit": r["limit"],
               "passed": False if r["decision"] == "fail" else None}
        if r["rule"] is not None:
            row.update(U=r["U"], decision=r["decision"])
        rep.rows.append(row)
    e = html.escape
    for d in drift:
        rep.notes.append(
            f"drifting: {e(d['serial'])} ({e(d['model'])}) {name} {d['slope_per_year']:+.3g} per year since run "
            f"{e(d['baseline_run'])} ({d['runs_since']} runs, q = {d['q']:.2g}); latest {d['latest_value']:.4g}"
            + (f", limit {d['limit']:.4g}" if d["limit"] is not None else ""))
    flagged = [d["serial"] for d in drift] + [r["serial"] for r in over]
    shown: list[str] = []
    for s in flagged:
        if s not in shown:
            shown.append(s)
    by_serial: dict[str, list[dict]] = {}
    for r in runs:
        by_serial.setdefault(r["serial"], []).append(r)
    for s in shown[:max_plots]:
        rr = by_serial.get(s, [])
        if not rr:
            continue
        t0 = rr[0]["created_at"]
        days = (np.array([r["created_at"] for r in rr]) - t0) / (YEAR_S / 365.25)
        vals = np.array([r["value"] for r in rr])
        series = [(f"{name}, worst pose", days, vals, "-")]
        lim = [r["limit"] for r in rr if r["limit"] is not None]
        if lim:
            series.append(("limit", days, np.full(days.size, min(lim)), "-"))
        marks = [i for i, r in enumerate(rr) if r["overhaul_state"] in ("after", "new")]
        if marks:
            series.append(("after overhaul / new", days[marks], vals[marks], "."))
        rep.figures.append((f"{s} ({rr[-1]['model']}): {name} per run since its first run on record",
                            plot_xy(series, xlabel="days since first run", ylabel=name, title=s)))
    if len(shown) > max_plots:
        rep.notes.append(f"{len(shown) - max_plots} more flagged robots not plotted")
    return rep


def write_fleet_page(store: RunStore, path: str | Path, name: str = "RP_mm", **kw) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render_html(fleet_report(store, name, **kw)), encoding="utf-8")
    return path
