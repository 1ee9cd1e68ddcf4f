"""JSON snapshots of the station and of one run, as the pages show them.

The store is the source of truth (a run started from the CLI looks the same
as one started here); the live run adds what only its server knows: the
pending prompt, paused, why it could not start. Snapshots are plain dicts,
compared as JSON by the event stream to send only changes.
"""

from __future__ import annotations

import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from station.report import NO_LIMITS
from station.store import RunStore, StepRecord
from station.verdict import Outcome, combine, outcome_of
from app.web.instrument_view import instrument_view
from app.web.live import LiveRun, RunHub


@lru_cache(maxsize=64)
def _step_names(procedure: str, params_json: str) -> tuple[str, ...]:
    """The names of a run's steps, rebuilt from its stored plan (cached: the plan never changes)."""
    import json

    from procedures.registry import get_procedure

    try:
        return tuple(s.name for s in get_procedure(procedure).build(json.loads(params_json)).steps)
    except Exception:  # an unknown or old procedure: show the journaled steps only
        return ()


def decided(store: RunStore, run_id: str) -> dict | None:
    """The run's stored verdict ``{"verdict", "reasons", ...}`` (procedures.decision), if it has one."""
    try:
        return store.result(run_id, "verdict")
    except Exception:  # noqa: BLE001 - a run stored before verdicts were, or not finished
        return None


def verdict(store: RunStore, run_id: str, steps: list[StepRecord] | None = None) -> str | None:
    """The run's verdict as the page shows it (:attr:`station.verdict.Outcome.word`: 'pass', 'fail', 'not decided',
    'aborted') or None (nothing judged): its stored verdict, else its report's, else its characteristics' one
    (runs stored before verdicts were)."""
    return None if (o := run_outcome(store, run_id, steps)) is None else o.word


def run_outcome(store: RunStore, run_id: str, steps: list[StepRecord] | None = None) -> Outcome | None:
    """The run's stored :class:`Outcome` (``verdict`` result, else the report step's, else its rows'; None: nothing
    judged); an aborted or failed run without a stored verdict is ABORTED."""
    d = decided(store, run_id)
    if d and d.get("verdict"):
        return Outcome.parse(d["verdict"])
    rec = store.run(run_id)
    if rec.status in ("failed", "aborted"):
        return Outcome.ABORTED
    for s in reversed(steps if steps is not None else store.steps(run_id)):
        if s.name == "report" and s.status == "done" and s.output and s.output.get("verdict"):
            if s.output["verdict"] == NO_LIMITS:
                break  # nothing judged (its rows say the same)
            return Outcome.parse(s.output["verdict"])
    judged = [c["passed"] for c in store.characteristics(run_id) if c["passed"] is not None]
    return combine(map(outcome_of, judged)) if judged else None


def report_path(steps: list[StepRecord]) -> Path | None:
    """The HTML report a run's ``report`` step wrote, if it is there."""
    for s in reversed(steps):
        if s.name == "report" and s.status == "done" and s.output and s.output.get("report"):
            p = Path(s.output["report"])
            return p if p.is_file() else None
    return None


def run_state(store: RunStore, run_id: str, live: LiveRun | None, now: float | None = None) -> dict:
    """Everything the run page shows. StoreError if the run is unknown (unless it failed to start here)."""
    import json

    now = time.time() if now is None else now
    try:
        rec = store.run(run_id)
    except Exception:
        if live is None:
            raise
        # the front door refused before the run was created (preflight, config): show why
        return {"run_id": run_id, "procedure": None, "status": "not started" if live.finished else "starting",
                "live": not live.finished, "paused": False, "held": False, "prompt": live.operator.prompt,
                "error": live.error, "output": live.output, "steps": [], "current": None, "n_done": 0,
                "n_steps": 0, "elapsed_s": now - live.started_at, "remaining_s": None, "results": [],
                "verdict": None, "report": False, "serial": None, "model": None, "tracker": None,
                "instrument": None}
    journal = store.steps(run_id)
    names = list(_step_names(rec.procedure, json.dumps(rec.params, sort_keys=True)))
    latest: dict[int, StepRecord] = {}
    attempts: dict[int, int] = {}
    done_durations = []
    for s in journal:
        latest[s.idx] = s
        attempts[s.idx] = attempts.get(s.idx, 0) + 1
        if s.status == "done" and s.ended_at is not None:
            done_durations.append(s.ended_at - s.started_at)
        while len(names) <= s.idx:
            names.append(f"step {len(names) + 1}")
    ever_done = {s.idx for s in journal if s.status == "done"}
    steps = []
    current = None
    driven = live is not None and not live.finished
    for i, name in enumerate(names):
        s = latest.get(i)
        state = s.status if s else "pending"
        if state == "running" and not (rec.status == "running"):
            state = "interrupted"
        row = {"idx": i, "name": name, "state": state, "attempts": attempts.get(i, 0),
               "started_at": s.started_at if s else None, "ended_at": s.ended_at if s else None,
               "duration_s": (s.ended_at - s.started_at) if s and s.ended_at else
               (now - s.started_at if s and state == "running" else None),
               "message": s.message if s else None}
        steps.append(row)
        if state == "running" and (current is None or row["started_at"] >= current["started_at"]):
            current = row
    n_done = len(ever_done)
    pending = len(names) - n_done
    last_t = max([s.ended_at or s.started_at for s in journal], default=rec.created_at)
    elapsed = (now if rec.status == "running" else last_t) - rec.created_at
    mean_step = sum(done_durations) / len(done_durations) if done_durations else None
    remaining = mean_step * pending if (mean_step is not None and rec.status == "running") else None
    finished = rec.status in ("done", "failed", "aborted")
    return {
        # a run this server drives is done once its verdict is stored too (the front door stores it after the
        # last step): until then the page says running, so that a "done" always comes with its verdict
        "run_id": run_id, "procedure": rec.procedure,
        "status": "running" if driven and rec.status == "done" else rec.status, "serial": rec.serial,
        "model": rec.model, "live": driven, "paused": bool(driven and live.control.paused),
        "held": bool(driven and live.control.held),
        "prompt": live.operator.prompt if driven else None,
        "error": (live.error if live else None) or _last_error(journal, rec.status),
        "output": live.output if (live and live.finished) else "",
        "steps": steps, "current": current, "n_done": n_done, "n_steps": len(names),
        "detail": live.detail if driven else "",
        "elapsed_s": elapsed, "remaining_s": remaining,
        "results": store.characteristics(run_id) if finished or n_done == len(names) else [],
        "verdict": verdict(store, run_id, journal), "reasons": (decided(store, run_id) or {}).get("reasons", []),
        "report": report_path(journal) is not None,
        "tracker": _tracker(store, run_id, journal, current) if rec.status == "running" else None,
        "instrument": instrument_view(store, run_id, rec.procedure, rec.params or {}),
    }


def _tracker(store: RunStore, run_id: str, journal: list[StepRecord], current: dict | None) -> dict | None:
    """The live plot of the step going now, if it streams the tracker (``tracker`` samples)."""
    from app.web.tracker_view import tracker_window

    if current is None:
        return None
    s = store.samples(run_id, "tracker", finished_only=False, steps=[current["idx"]])
    if not s:
        return None
    outputs = {j.name: j.output for j in journal if j.status == "done" and j.output}
    reg = outputs.get("register base frame") or {}
    poses = (outputs.get("check programs") or {}).get("poses_mm") or {}
    view = tracker_window(s["t"], np.column_stack([s["x"], s["y"], s["z"]]), s["status"],
                          poses_mm=np.array(list(poses.values()), dtype=float).reshape(-1, 3) if poses else None,
                          R=reg.get("R"), t_mm=reg.get("t_mm"))
    view["received"] = store.sample_count(run_id, "tracker")
    view["step"] = current["name"]
    return view


def _last_error(journal: list[StepRecord], status: str) -> str | None:
    if status not in ("failed", "aborted"):
        return None
    for s in reversed(journal):
        if s.status in ("failed", "aborted") and s.message:
            return s.message
    return None


def station_state(cfg, store: RunStore, hub: RunHub, limit: int = 50) -> dict:
    """Devices, robots, and the latest ``limit`` runs of the store with their verdicts."""
    from station.device_urls import SCHEMES

    active = hub.active()
    # the robots' controllers (the FTP+Modbus controller or a UR cobot): what the active run moves to
    robot_devices = {r.controller for r in cfg.robots.values()}
    moving_to = ""
    if active is not None and active.detail.startswith("->"):
        moving_to = active.detail[2:].strip()
    stored = store.runs()
    faults, last_armed = device_faults(cfg, store, stored)
    # connected by this session (a resumed run connects again; an earlier session's step does not count)
    connected = active is not None and any(
        s.name.startswith("connect") and s.status == "done" and s.started_at >= active.started_at
        for s in store.steps(active.run_id))
    devices = []
    for name, dev in cfg.devices.items():
        scheme = str(dev.url).split("://", 1)[0].lower()
        fault = faults.get(name)
        if not hub.arm:
            state = "not used (runs use the fake cell)"
        elif active is not None:
            state = f"{'connected, ' if connected else 'connecting, '}in use by run {active.run_id}"
        elif fault is not None and fault["run_id"] == last_armed:
            state = "faulted"
        else:
            state = "idle"
        devices.append({
            "name": name, "url": _redact(dev.url),
            "kind": SCHEMES[scheme].description if scheme in SCHEMES else "",
            "state": state, "last_fault": fault,
            "target": moving_to if name in robot_devices else ""})
    robots = [{"key": key, "model": r.model, "serial": r.serial, "overhaul_state": r.overhaul_state}
              for key, r in cfg.robots.items()]
    runs = []
    for rec in reversed(stored[-limit:]):
        live = hub.live(rec.run_id)
        runs.append({"run_id": rec.run_id, "procedure": rec.procedure, "serial": rec.serial,
                     "status": rec.status, "created_at": rec.created_at,
                     "live": bool(live and not live.finished), "verdict": verdict(store, rec.run_id)})
    return {"station": cfg.station.name, "armed": hub.arm, "devices": devices, "robots": robots, "runs": runs,
            "active": active.run_id if active else None}


def device_faults(cfg, store: RunStore, runs: list | None = None,
                  limit: int = 50) -> tuple[dict[str, dict], str | None]:
    """``({device name: its last fault}, the newest run on the configured devices)``, from the store (``runs``:
    its runs, oldest first, when the caller has read them).

    A fault is a failed step of one of the ``limit`` newest runs on the configured devices (armed: its
    plan has no fake cell) whose error came through the driver of the
    device's URL scheme: ``run_id``, ``step``, ``at`` (epoch s) and
    ``message``. Dry runs use the fake cell's devices and are not counted.
    Two configured devices of one driver share its faults.
    """
    from station.device_urls import SCHEMES

    module_of = {}
    for name, dev in cfg.devices.items():
        row = SCHEMES.get(str(dev.url).split("://", 1)[0].lower())
        if row is not None and row.driver:
            module_of[name] = row.driver.split(":", 1)[0]
    out: dict[str, dict] = {}
    last_armed = None
    runs = store.runs() if runs is None else runs
    armed = [rec for rec in reversed(runs) if (rec.params or {}).get("fake") is None][:limit]
    for rec in armed:
        last_armed = last_armed or rec.run_id
        for step in reversed(store.steps(rec.run_id)):
            err = (step.output or {}).get("error") if step.status == "failed" else None
            if not err:
                continue
            for name, module in module_of.items():
                if name not in out and module in (err.get("drivers") or []):
                    at = step.ended_at or step.started_at
                    out[name] = {"run_id": rec.run_id, "step": step.name, "at": at,
                                 "when": time.strftime("%Y-%m-%d %H:%M", time.localtime(at)),
                                 "message": step.message or err.get("type", "")}
        if len(out) == len(module_of):
            break
    return out, last_armed


def _redact(url: str) -> str:
    """A device URL without any secret: a ``user:secret@`` part, a ``password=`` option however spelt
    (percent-escapes decoded first). The config refuses both (:mod:`station.device_urls`); this is the
    page's own guard."""
    import re
    from urllib.parse import unquote

    text = unquote(str(url))
    text = re.sub(r"(://[^/@?#]*?):[^/@?#]*@", r"\1:***@", text)
    return re.sub(r"(?i)((?:^|[?&;])\s*(?:password|pass|passwd|pwd)\s*=)[^&;#]*", r"\1***", text)
