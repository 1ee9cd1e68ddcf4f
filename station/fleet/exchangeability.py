"""Exchangeability (ISO 9283 7.8) of robots of one model, from the ISO 9283 runs in a store.

Each robot (model and serial) is taken with its latest finished ISO 9283 run
that stored its analysis. Its barycentre at each pose is the mean of the
attained positions the run stored (in its registered base frame), with the
standard uncertainty per coordinate of ``sqrt(s^2 / n + u_reg^2)``: the
attained positions' scatter ``s`` (the mean of the three coordinates'
variances) over their number, and the registration's jackknife error at
the pose (stored by the run's registration step; taken whole for one
coordinate, which overstates it). The runs must be one test programme
(:func:`station.analysis.iso9283.exchangeability.conditions_problems`); the
mounting is not recorded in the store and is taken as the same.
"""

from __future__ import annotations

import math

import numpy as np

from station.analysis.iso9283.exchangeability import (Exchangeability, RobotPoses, conditions_problems,
                                                      exchangeability)
from station.errors import ConfigError
from station.store import RunStore

PROCEDURE = "iso9283"


def latest_iso_runs(store: RunStore, *, model: str | None = None, serials: list[str] | None = None) -> dict:
    """``(model, serial) -> RunRecord``: each robot's latest done ISO 9283 run with a stored analysis."""
    if (model is None) == (serials is None):
        raise ConfigError("give --model or --serials (one of them)")
    wanted = None if serials is None else {s.strip() for s in serials if s.strip()}
    if wanted is not None and len(wanted) < 2:
        raise ConfigError(f"--serials needs at least 2 serials, got {sorted(wanted)}")
    latest: dict = {}
    for run in store.runs():
        if run.procedure != PROCEDURE or run.status != "done":
            continue
        if (model is not None and run.model != model) or (wanted is not None and run.serial not in wanted):
            continue
        try:
            store.result(run.run_id, PROCEDURE)
        except Exception:  # noqa: BLE001 - a run without a stored analysis has no barycentres
            continue
        key = (run.model, run.serial)
        if key not in latest or run.created_at >= latest[key].created_at:
            latest[key] = run
    if wanted is not None:
        missing = sorted(wanted - {s for _, s in latest})
        if missing:
            raise ConfigError(f"no finished ISO 9283 run with its analysis for serial(s) {', '.join(missing)}")
    return latest


def robot_poses(store: RunStore, run) -> RobotPoses:
    """One run's barycentres and their standard uncertainty per pose."""
    poses = store.result(run.run_id, PROCEDURE)["pose"]["poses"]
    reg = {}
    for step in store.steps(run.run_id):
        if step.name == "register base frame" and step.status == "done" and step.output:
            reg = step.output.get("uncertainty_at_poses_mm") or {}
    bary, u, u_scatter = {}, {}, {}
    for name, pose in poses.items():
        att = pose.get("attained") or {}
        xyz = np.column_stack([att.get("x_mm", []), att.get("y_mm", []), att.get("z_mm", [])]).astype(float)
        if xyz.shape[0] < 2:
            raise ConfigError(f"run {run.run_id} ({run.serial}): pose {name} has {xyz.shape[0]} attained positions; "
                              "a barycentre and its scatter need 2")
        bary[name] = xyz.mean(axis=0)
        var = float(np.mean(xyz.var(axis=0, ddof=1)))
        u_scatter[name] = math.sqrt(var / xyz.shape[0])
        u[name] = math.hypot(u_scatter[name], float(reg.get(name, 0.0)))
    return RobotPoses(run.serial, run.run_id, bary, u, u_scatter)


def fleet_exchangeability(store: RunStore, *, model: str | None = None,
                          serials: list[str] | None = None) -> tuple[Exchangeability, dict]:
    """E of the robots chosen (``model``, or ``serials``) and ``serial -> run_id`` of the runs it rests on.

    ConfigError, naming the reason, when fewer than two robots have runs or the runs are not one programme
    (poses, payload, speed, dwell, cycles, model)."""
    runs = latest_iso_runs(store, model=model, serials=serials)
    if len(runs) < 2:
        what = f"model {model}" if model is not None else "those serials"
        raise ConfigError(f"exchangeability needs finished ISO 9283 runs of at least 2 robots of {what}, "
                          f"found {len(runs)}")
    serial_count = {}
    for m, s in runs:
        serial_count[s] = serial_count.get(s, 0) + 1
    plans = {(s if serial_count[s] == 1 else f"{m}/{s}"): store.run(r.run_id).params for (m, s), r in runs.items()}
    problems = conditions_problems(plans)
    if problems:
        raise ConfigError("the runs are not one test programme on one model; exchangeability refused: "
                          + "; ".join(problems))
    ordered = sorted(runs.items())
    result = exchangeability([robot_poses(store, r) for _, r in ordered])
    return result, {s: r.run_id for (_, s), r in ordered}


__all__ = ["latest_iso_runs", "robot_poses", "fleet_exchangeability"]
