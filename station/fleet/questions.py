"""Fleet questions on a store (the central one, or any): across stations, robots and overhauls.

* :func:`robot_history` — one robot's values of a characteristic across its
  runs, stations and overhauls;
* :func:`run_values` — one number per finished run: the worst pose's value
  (the one a verdict turns on) and its limit;
* :func:`since_overhaul` — per robot: the first run after its last recorded
  overhaul (an event: :meth:`~station.store.RunStore.record_overhaul`; a
  robot with none counts from its first run on record), its latest run, the
  change between them and the trend since;
* :func:`over_limits_now` — robots whose latest finished run is over a limit;
* :func:`limit_decisions_now` — the same, split by the run's decision rule
  (ISO 14253-1) into non-conformance proven and not decided (a figure in its
  guard band, on either side of the limit);
* :func:`drifting` — robots of a model whose characteristic grows with time
  since their last overhaul, by the trend test of :mod:`station.fleet.trend`
  with false-discovery control across the model's robots.

A robot is its model and serial, in every question here as in the store.
Each is one SQL query and vectorised arithmetic, so a fleet of a thousand
robots with fifty runs each answers in well under a second
(``bench/bench_store.py``). Times are epoch seconds as stored; slopes are per
year (365.25 days).
"""

from __future__ import annotations

import numpy as np

from station.characteristics import from_their_cycles
from station.errors import ConfigError
from station.fleet.trend import benjamini_hochberg, trends
from station.store import RunStore, StoreError
from station.verdict import Outcome

YEAR_S = 365.25 * 86400.0


def robot_history(store: RunStore, serial: str, name: str, pose: str | None = None, *,
                  model: str | None = None) -> list[dict]:
    """Every finished run's values of ``name`` for robot (``model``, ``serial``), any station, oldest first.

    ``model`` may be left out while one model has that serial. Each row also
    says whether the run came after the robot's last recorded overhaul
    (``since_overhaul``).
    """
    if not store.robot_models(serial):
        return []  # no robot of that serial
    model, serial = store.resolve_robot(serial, model)
    sql = ("SELECT r.run_id, r.station, b.model, r.created_at, r.overhaul_state, c.pose, c.value, c.limit_value, c.passed"
           " FROM characteristics c JOIN runs r ON r.run_id=c.run_id JOIN robots b ON b.robot_id=r.robot_id"
           " WHERE b.serial=? AND b.model=? AND c.name=? AND r.status='done'")
    args: list = [serial, model, name]
    if pose is not None:
        sql += " AND c.pose=?"
        args.append(pose)
    sql += " ORDER BY r.created_at, r.run_id, c.pose"
    keys = ("run_id", "station", "model", "created_at", "overhaul_state", "pose", "value", "limit", "passed")
    last = _last_overhauls(store).get((model, serial))
    out = []
    for row in store.backend.query(sql, tuple(args)):
        d = dict(zip(keys, row))
        d["passed"] = None if d["passed"] is None else bool(d["passed"])
        d["since_overhaul"] = last is None or d["created_at"] >= last["at"]
        out.append(d)
    return out


def _last_overhauls(store: RunStore) -> dict[tuple[str, str], dict]:
    """(model, serial) -> the robot's last recorded overhaul."""
    out: dict[tuple[str, str], dict] = {}
    for o in store.overhauls():  # oldest first: the last one wins
        out[(o["model"], o["serial"])] = o
    return out


def run_values(store: RunStore, name: str, *, model: str | None = None, serial: str | None = None) -> list[dict]:
    """One row per finished run with ``name``: worst value over its poses, the tightest limit, over or not."""
    sql = ("SELECT b.serial, b.model, r.station, r.run_id, r.created_at, r.overhaul_state, MAX(c.value),"
           " MIN(c.limit_value), MAX(CASE WHEN c.limit_value IS NOT NULL AND c.value > c.limit_value THEN 1 ELSE 0 END)"
           " FROM characteristics c JOIN runs r ON r.run_id=c.run_id JOIN robots b ON b.robot_id=r.robot_id"
           " WHERE c.name=? AND r.status='done' AND c.value IS NOT NULL")
    args: list = [name]
    if model is not None:
        sql += " AND b.model=?"
        args.append(model)
    if serial is not None:
        sql += " AND b.serial=?"
        args.append(serial)
    sql += (" GROUP BY b.serial, b.model, r.station, r.run_id, r.created_at, r.overhaul_state"
            " ORDER BY b.serial, r.created_at, r.run_id")
    keys = ("serial", "model", "station", "run_id", "created_at", "overhaul_state", "value", "limit", "over")
    out = []
    for row in store.backend.query(sql, tuple(args)):
        d = dict(zip(keys, row))
        d["over"] = bool(d["over"])
        out.append(d)
    return out


def _since_last_overhaul(rows: list[dict], last: dict[tuple[str, str], dict]) -> dict[tuple[str, str], list[dict]]:
    """Per robot (model, serial), its runs done at or after its last recorded overhaul (all its runs when
    none is recorded); a robot overhauled after its latest run has none."""
    out: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        key = (r["model"], r["serial"])
        o = last.get(key)
        runs = out.setdefault(key, [])
        if o is None or r["created_at"] >= o["at"]:
            runs.append(r)
    return {k: v for k, v in out.items() if v}


def parse_when(text: str, what: str = "date") -> float:
    """``YYYY-MM-DD`` or ``YYYY-MM-DDTHH:MM[:SS]`` (local time) as epoch seconds; ConfigError naming ``what``
    otherwise (the date of an overhaul as an operator types it)."""
    from datetime import datetime

    for fmt in ("%Y-%m-%d", "%Y-%m-%dT%H:%M", "%Y-%m-%dT%H:%M:%S", "%Y-%m-%d %H:%M"):
        try:
            return datetime.strptime(str(text).strip(), fmt).timestamp()
        except ValueError:
            continue
    from station.shown import quoted

    raise ConfigError(f"{what} {quoted(text)} is not YYYY-MM-DD or YYYY-MM-DDTHH:MM")


def since_overhaul(store: RunStore, name: str, *, model: str | None = None) -> list[dict]:
    """Per robot: the first run after its last recorded overhaul (the baseline), its latest run, the change
    between them and the trend per year since (one-sided test for an increase).

    ``overhaul_at`` / ``overhaul_what`` / ``overhaul_ticket`` describe that
    overhaul (None for a robot with none recorded: its first run on record
    is the baseline). A robot overhauled after its latest run is left out
    until it is measured again.
    """
    rows = run_values(store, name, model=model)
    last = _last_overhauls(store)
    since = _since_last_overhaul(rows, last)
    out = []
    keys = sorted(since)
    if not keys:
        return out
    g = np.concatenate([[i] * len(since[k]) for i, k in enumerate(keys)])
    t = np.concatenate([[r["created_at"] for r in since[k]] for k in keys])
    y = np.concatenate([[r["value"] for r in since[k]] for k in keys])
    tr = trends(g, t / YEAR_S, y)
    idx = {int(gi): i for i, gi in enumerate(tr.groups)}
    for j, key in enumerate(keys):
        runs, i = since[key], idx[j]
        first, latest = runs[0], runs[-1]
        o = last.get(key)
        out.append({"serial": key[1], "model": key[0], "station": latest["station"],
                    "overhaul_at": None if o is None else o["at"], "overhaul_what": None if o is None else o["what"],
                    "overhaul_ticket": None if o is None else o["ticket"],
                    "baseline_run": first["run_id"], "baseline_state": first["overhaul_state"],
                    "baseline_value": first["value"], "latest_run": latest["run_id"], "latest_value": latest["value"],
                    "change": latest["value"] - first["value"], "runs_since": len(runs),
                    "slope_per_year": None if np.isnan(tr.slope[i]) else float(tr.slope[i]),
                    "p_increase": float(tr.p[i]), "limit": latest["limit"], "over_now": latest["over"]})
    return out


def drifting(store: RunStore, name: str, *, model: str | None = None, q_max: float = 0.05,
             min_runs: int = 5) -> list[dict]:
    """Robots (of ``model``, or every model) whose ``name`` grows since their last overhaul.

    Per robot with at least ``min_runs`` runs since, the one-sided trend test
    of :func:`station.fleet.trend.trends`; the p-values of a model's robots
    become Benjamini-Hochberg q-values and a robot drifts when ``q <= q_max``.
    Returns the drifting robots, largest slope first, with slope, p and q.
    """
    if not 0 < q_max < 1:
        raise ConfigError(f"q_max must be between 0 and 1, got {q_max}")
    if min_runs < 3:
        raise ConfigError(f"min_runs must be at least 3 (a slope and its scatter), got {min_runs}")
    rows = [r for r in since_overhaul(store, name, model=model) if r["runs_since"] >= min_runs]
    out = []
    for m in sorted({r["model"] for r in rows}):
        group = [r for r in rows if r["model"] == m]
        q = benjamini_hochberg(np.array([r["p_increase"] for r in group]))
        for r, qi in zip(group, q):
            if qi <= q_max:
                out.append({**r, "q": float(qi)})
    return sorted(out, key=lambda r: -(r["slope_per_year"] or 0.0))


def _latest_limited(store: RunStore, name: str | None, condition: str) -> list[dict]:
    """The values with a limit (and ``condition`` on ``c``) in each robot's latest finished run with ``name``
    (or with any characteristic): model, serial, station, run_id, created_at, pose, name, value, unit, limit."""
    name_filter = " AND c2.name=?" if name else ""
    sql = (
        "WITH latest AS (SELECT r.robot_id, MAX(r.created_at) AS t FROM runs r WHERE r.status='done'"
        " AND EXISTS (SELECT 1 FROM characteristics c2 WHERE c2.run_id=r.run_id" + name_filter + ")"
        " GROUP BY r.robot_id)"
        " SELECT b.model, b.serial, r.station, r.run_id, r.created_at, c.pose, c.name, c.value, c.unit, c.limit_value"
        " FROM latest l JOIN runs r ON r.robot_id=l.robot_id AND r.created_at=l.t AND r.status='done'"
        " JOIN robots b ON b.robot_id=r.robot_id JOIN characteristics c ON c.run_id=r.run_id"
        " WHERE c.limit_value IS NOT NULL AND " + condition + (" AND c.name=?" if name else "") +
        " ORDER BY b.serial, c.name, c.pose")
    args = (name, name) if name else ()
    keys = ("model", "serial", "station", "run_id", "created_at", "pose", "name", "value", "unit", "limit")
    return [dict(zip(keys, row)) for row in store.backend.query(sql, args)]


def over_limits_now(store: RunStore, name: str | None = None) -> list[dict]:
    """Every value over its limit in each robot's latest finished run (with ``name``, or of any kind)."""
    return _latest_limited(store, name, "c.value > c.limit_value")


def limit_decisions_now(store: RunStore, name: str | None = None) -> dict[str, list[dict]]:
    """Each robot's latest finished run, by the decision its verdicts carry: ``{"proven": [...], "not_decided": [...]}``.

    A run analysed with a decision rule stored each verdict's outcome and U in its ``iso9283`` result: a
    failed one is non-conformance proven (under ``guarded``: figure - U beyond the limit), a figure in its
    guard band is not decided.  A run without a rule is judged as :func:`over_limits_now` does (value over
    the limit: proven, rule ``None``).  Rows as :func:`over_limits_now` plus ``rule``, ``decision`` (a
    :class:`station.verdict.Outcome`, read from the stored verdict's text) and ``U`` (k = 2, the figure's unit).
    """
    rows = _latest_limited(store, name, "c.value IS NOT NULL")
    verdicts: dict[str, dict] = {}
    out: dict[str, list[dict]] = {"proven": [], "not_decided": []}
    for r in rows:  # loop over the limited values of the latest runs
        if r["run_id"] not in verdicts:
            verdicts[r["run_id"]] = _stored_verdicts(store, r["run_id"])
        v = verdicts[r["run_id"]].get((r["name"], r["pose"]))
        if v is not None and v.get("rule") is not None:
            unit = r["name"].rsplit("_", 1)[-1]
            r.update(rule=v["rule"], decision=Outcome.parse(v["outcome"]) if v.get("outcome") else None,
                     U=v.get(f"U_{unit}"))
        else:
            r.update(rule=None, decision=Outcome.FAIL if r["value"] > r["limit"] else Outcome.PASS, U=None)
        if r["decision"] is Outcome.FAIL:
            out["proven"].append(r)
        elif r["decision"] is Outcome.NOT_DECIDED:
            out["not_decided"].append(r)
    return out


def decisions_as_json(rows: list[dict]) -> list[dict]:
    """Rows of :func:`limit_decisions_now` as the commands' JSON gives them: each ``decision`` in its stored
    lower-case word (:attr:`station.verdict.Outcome.word`)."""
    return [{**r, "decision": r["decision"] and r["decision"].word} if "decision" in r else r for r in rows]


def _stored_verdicts(store: RunStore, run_id: str) -> dict:
    """``{(characteristic, subject): verdict JSON}`` of a run's stored ISO 9283 result (empty without one)."""
    try:
        res = store.result(run_id, "iso9283")
    except StoreError:  # a run of another procedure, or stored before its analysis
        return {}
    vs = from_their_cycles((res.get("pose") or {}).get("verdicts", []), (res.get("vap") or {}).get("verdicts", []),
                           key=lambda v: v.get("characteristic"))
    return {(v.get("characteristic"), v.get("subject")): v for v in vs}
