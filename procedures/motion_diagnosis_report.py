"""The HTML report of a motion diagnosis: measured, simulated and extended approach curves of held-out moves."""

from __future__ import annotations

from station.analysis.motion.diagnose import MotionDiagnosis
from station.report import Report, plot_xy

#: held-out moves drawn (the first of each destination pose, then in order)
MAX_CURVES = 6
#: the curves are drawn this long before and after the command's end, s
SHOW_S = (-0.1, 0.8)


def build_motion_report(res: MotionDiagnosis, *, title: str, facts: dict | None = None) -> Report:
    doc = res.to_json()
    figs = []
    first = {}
    for c in res.curves:
        first.setdefault(c["to"], c)
    chosen = list(first.values()) + [c for c in res.curves if c not in first.values()]
    for c in chosen[:MAX_CURVES]:
        m = (c["tau_s"] >= SHOW_S[0]) & (c["tau_s"] <= SHOW_S[1])
        tau = c["tau_s"][m]
        um = lambda x: 1000.0 * x[m]  # noqa: E731
        figs.append((f"Held-out move {c['move']} ({c['from']} -> {c['to']}): along the travel near the stop",
                     plot_xy([("measured", tau, um(c["measured"]), "."),
                              ("simulated (baseline)", tau, um(c["simulated"]), "-"),
                              ("extended", tau, um(c["extended"]), "-")],
                             xlabel="time from the command's end [s]", ylabel="position along the travel [um]",
                             title=f"move {c['move']}")))
    rows = []
    for k, s in enumerate(doc["steps"], 1):
        for name, val in s["params"].items():
            rows.append({"pose": f"{k}. {s['effect']}", "name": name, "value": val, "unit": "", "limit": None,
                         "passed": None})
    for p in doc["poses"]:
        for kind in ("measured", "simulated", "extended"):
            for key, val in p[kind].items():
                rows.append({"pose": p["pose"], "name": f"{key} ({kind})", "value": val, "unit": "",
                             "limit": None, "passed": None})
    held = ", ".join(f"{m['move']} ({m['from']}->{m['to']})" for m in doc["heldout_moves"])
    f = {"held-out RMS, simulation (baseline refit)": f"{doc['simulation_heldout_rms'] * 1000:.2f} um",
         "held-out RMS, extended model": f"{doc['final_heldout_rms'] * 1000:.2f} um ({doc['gain_percent']:.1f} % less)",
         "noise floor": f"{doc['noise_floor'] * 1000:.2f} um per sample along the travel",
         "named": ", ".join(s["effect"] for s in doc["steps"]) or "nothing",
         "held-out moves": held}
    if doc.get("time_refused"):
        f["time figures"] = f"refused: {doc['time_refused']}"
    f.update(facts or {})
    notes = [f"not testable: {k}: {why}" for k, why in doc["not_testable"].items()]
    return Report(title=title, facts=f, rows=rows, figures=figs, notes=notes)
