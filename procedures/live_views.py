"""Each procedure's live view of its instrument, read from the store while the run goes on.

A procedure's :class:`~procedures.registry.ProcedureSpec` names its view
(``live_view``); the run page (:mod:`app.web.instrument_view`) shows what it
returns. The ISO 9283 run has none here: the page draws the tracker's stream
itself (:mod:`app.web.tracker_view`). The arm calibration measures one point
per pose with the tracker or one corner per pose with the scanner; the trailer
calibration streams odometry.
"""

from __future__ import annotations

import math

import numpy as np

from station.store import RunStore

#: seconds of an odometry stream shown
ODOMETRY_WINDOW_S = 30.0
#: most points of a stream sent to the page
MAX_POINTS = 300


def _finite(x) -> float | None:
    return float(x) if x is not None and math.isfinite(float(x)) else None


def arm_calibration_view(store: RunStore, run_id: str, params: dict, *, tracker_stream: str,
                         scanner_stream: str) -> dict:
    """Poses measured of those planned, the last one, and (scanner) the corners not found; the
    calibration's streams are named by its spec."""
    scanner = params.get("instrument") == "scanner"
    stream = scanner_stream if scanner else tracker_stream
    planned = len(params.get("q_deg") or ())
    s = store.samples(run_id, stream, finished_only=False)
    n = 0 if not s else int(s["pose"].size)
    out = {"kind": "scanner" if scanner else "tracker", "stream": stream, "planned": planned, "measured": n,
           "title": "Scanner: corner of the jig per pose" if scanner else "Tracker: one point per pose",
           "last": None, "not_found": []}
    if n:
        k = n - 1
        out["last"] = {"pose": int(s["pose"][k]) + 1, "x": _finite(s["x"][k]), "y": _finite(s["y"][k]),
                       "z": _finite(s["z"][k])}
        if scanner:
            out["not_found"] = [int(p) + 1 for p, f in zip(s["pose"], s["found"]) if f < 0.5]
    return out


def odometry_view(store: RunStore, run_id: str, params: dict | None = None) -> dict:
    """The odometry stream's last :data:`ODOMETRY_WINDOW_S` seconds: speed, curvature, joint angle."""
    s = store.samples(run_id, "odometry", finished_only=False)
    out = {"kind": "odometry", "title": "Odometry, last seconds", "received": 0, "t": [], "v_m_s": [],
           "kappa_1_m": [], "psi_deg": []}
    if not s or not s["t"].size:
        return out
    t = np.asarray(s["t"], float)
    keep = np.flatnonzero(t >= t.max() - ODOMETRY_WINDOW_S)
    keep = keep[::-1][:: max(1, -(-keep.size // MAX_POINTS))][::-1]  # thinned, the newest sample kept
    out.update(received=int(t.size), t=(t[keep] - t.max()).round(3).tolist(),
               v_m_s=np.asarray(s["v"], float)[keep].round(4).tolist(),
               kappa_1_m=np.asarray(s["kappa"], float)[keep].round(5).tolist(),
               psi_deg=np.degrees(np.asarray(s["psi"], float)[keep]).round(3).tolist())
    return out


__all__ = ["arm_calibration_view", "odometry_view", "ODOMETRY_WINDOW_S", "MAX_POINTS"]
