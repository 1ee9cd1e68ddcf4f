"""The static fleet page: robots over limits now, drifting robots, trend plots per robot.

Written like the run reports (:mod:`station.report`): one self-contained
HTML file, inline SVG, nothing beside it.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from station.fleet.questions import YEAR_S, drifting, limit_decisions_now, run_values, since_overhaul
from station.report import Report, plot_xy, render_html
from station.store import RunStore
from station.verdict import Outcome


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
        "robots over a limit now": str(len({(r["model"], r["serial"]) for r in over})),
        f"robots drifting (trend since last overhaul, false-discovery rate {q_max:g})": str(len(drift)),
    }
    if undecided:
        rep.facts["robots not decided now (a figure in its guard band, ISO 14253-1)"] = str(
            len({(r["model"], r["serial"]) for r in undecided}))
    for r in over + undecided:
        row = {"pose": f"{r['serial']} ({r['model']}, {r['station'] or '-'}) {r['pose']}", "name": r["name"],
               "value": r["value"], "unit": r["unit"], "limit": r["limit"],
               "passed": False if r["decision"] is Outcome.FAIL else None}
        if r["rule"] is not None:
            row.update(U=r["U"], rule=r["rule"], outcome=r["decision"])
        rep.rows.append(row)
    # every other robot's latest run: its worst pose against its limit (the page's verdict is the fleet's)
    over_robots = {(r["model"], r["serial"]) for r in over + undecided}
    for r in since:
        if (r["model"], r["serial"]) in over_robots:
            continue
        rep.rows.append({"pose": f"{r['serial']} ({r['model']}, {r['station'] or '-'}) worst pose",
                         "name": name, "value": r["latest_value"], "unit": name.rpartition("_")[2] if "_" in name else "", "limit": r["limit"],
                         "passed": None if r["limit"] is None else not r["over_now"]})
    e = html.escape
    for d in drift:
        rep.notes.append(
            f"drifting: {e(d['serial'])} ({e(d['model'])}) {name} {d['slope_per_year']:+.3g} per year since run "
            f"{e(d['baseline_run'])} ({d['runs_since']} runs, q = {d['q']:.2g}); latest {d['latest_value']:.4g}"
            + (f", limit {d['limit']:.4g}" if d["limit"] is not None else ""))
    flagged = [(d["model"], d["serial"]) for d in drift] + [(r["model"], r["serial"]) for r in over]
    shown: list[tuple[str, str]] = []
    for key in flagged:
        if key not in shown:
            shown.append(key)
    by_robot: dict[tuple[str, str], list[dict]] = {}
    for r in runs:
        by_robot.setdefault((r["model"], r["serial"]), []).append(r)
    events: dict[tuple[str, str], list[float]] = {}
    for o in store.overhauls():
        events.setdefault((o["model"], o["serial"]), []).append(o["at"])
    for key in shown[:max_plots]:
        s = key[1]
        rr = by_robot.get(key, [])
        if not rr:
            continue
        t0 = rr[0]["created_at"]
        days = (np.array([r["created_at"] for r in rr]) - t0) / (YEAR_S / 365.25)
        vals = np.array([r["value"] for r in rr])
        series = [(f"{name}, worst pose", days, vals, "-")]
        lim = [r["limit"] for r in rr if r["limit"] is not None]
        if lim:
            series.append(("limit", days, np.full(days.size, min(lim)), "-"))
        # each recorded overhaul, marked on the first run after it
        marks = sorted({int(np.searchsorted([r["created_at"] for r in rr], at)) for at in events.get(key, [])})
        marks = [i for i in marks if i < len(rr)]
        if marks:
            series.append(("first run after an overhaul", days[marks], vals[marks], "."))
        rep.figures.append((f"{s} ({rr[-1]['model']}): {name} per run since its first run on record",
                            plot_xy(series, xlabel="days since first run", ylabel=name, title=s)))
    if len(shown) > max_plots:
        rep.notes.append(f"{len(shown) - max_plots} more flagged robots not plotted")
    rep.notes += exchangeability_notes(store)
    return rep


def exchangeability_notes(store: RunStore) -> list[str]:
    """Per model with ISO 9283 runs of two robots or more: its exchangeability (ISO 9283 7.8), or why not."""
    from station.errors import StationError
    from station.fleet.exchangeability import PROCEDURE, fleet_exchangeability

    robots: dict[str, set] = {}
    for run in store.runs():
        if run.procedure == PROCEDURE and run.status == "done" and run.model:
            robots.setdefault(run.model, set()).add(run.serial)
    notes = []
    for model, serials in sorted(robots.items()):
        if len(serials) < 2:
            continue
        try:
            res, runs = fleet_exchangeability(store, model=model)
        except StationError as exc:
            notes.append(f"exchangeability of {html.escape(model)}: not stated ({html.escape(str(exc))})")
            continue
        notes.append(f"exchangeability (ISO 9283 7.8) of {html.escape(model)}: E = {res.exchangeability_mm:.4f} mm "
                     f"+/- {res.U_mm:.2g} mm (k = 2) at {res.pose}, {len(runs)} robots, in the frame of mounting "
                     f"{html.escape(str(res.mounting))}")
    return notes


def write_fleet_page(store: RunStore, path: str | Path, name: str = "RP_mm", **kw) -> Path:
    path = Path(path)
    from station.readers.out_files import write_output

    write_output(path, render_html(fleet_report(store, name, **kw)), "--out")
    return path
