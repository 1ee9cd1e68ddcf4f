"""What the run page shows of a procedure's instrument: the view its spec names (pure of the page).

Each procedure measures with its own instrument and says in its
:class:`~procedures.registry.ProcedureSpec` (``live_view``) what the page
shows of it (:mod:`procedures.live_views`); a procedure without one (the ISO
9283 run) is drawn from the tracker's stream (:mod:`app.web.tracker_view`).
"""

from __future__ import annotations

from procedures.live_views import ODOMETRY_WINDOW_S
from procedures.registry import get_procedure
from station.store import RunStore


def instrument_view(store: RunStore, run_id: str, procedure: str, params: dict) -> dict | None:
    """The panel of a procedure measured by something else than the tracker's stream (None: the tracker's
    own view, or nothing to show)."""
    view = get_procedure(procedure).live_view
    return None if view is None else view(store, run_id, params)


__all__ = ["instrument_view", "ODOMETRY_WINDOW_S"]
