"""Exchangeability (ISO 9283 7.8) of robots of one model, from the ISO 9283 runs in a store.

Each robot (model and serial) is taken with its latest finished ISO 9283 run
that stored its analysis. Its barycentre at each pose is the mean of the
attained positions the run stored, carried from its registered base frame
into the mounting frame the run stored with its registration (the robot's
``mounting`` in the station config), with the standard uncertainty per
coordinate of ``sqrt(s^2 / n + u_T^2)``: the attained positions' scatter
``s`` (the mean of the three coordinates' variances) over their number, and
the tracker's accuracy at the pose (the run's stated budget, else the
default ``a + b R``; the registration's error does not enter: one frame for
every robot). The runs must be one test programme
(:func:`station.analysis.iso9283.exchangeability.conditions_problems`) on
one mounting in one frame (:func:`~station.analysis.iso9283.exchangeability.mounting_problems`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from station.analysis.iso9283.exchangeability import (Exchangeability, MountingFrame, RobotPoses,
                                                      conditions_problems, exchangeability, mounting_problems)
from station.errors import ConfigError, DataError
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


def _register_output(store: RunStore, run) -> dict:
    out = {}
    for step in store.steps(run.run_id):
        if step.name == "register base frame" and step.status == "done" and step.output:
            out = step.output
    return out


def run_mounting(store: RunStore, run) -> MountingFrame | None:
    """The mounting frame a run stored with its registration (None: measured without one)."""
    m = _register_output(store, run).get("mounting")
    if not m:
        return None
    try:
        return MountingFrame.from_dict(m)
    except DataError as exc:
        raise ConfigError(f"run {run.run_id} ({run.serial}): {exc}") from None


def robot_poses(store: RunStore, run, mounting: MountingFrame) -> RobotPoses:
    """One run's barycentres in the mounting's frame and their standard uncertainty per pose: the attained
    positions the run stored (in its registered base frame) carried back into the tracker's frame by its
    registration and into the mounting's by ``mounting``; the tracker's accuracy at each pose from the run's
    budget (the station's stated tracker, else the default ``a + b R``)."""
    from station.analysis.uncertainty import Budget

    poses = store.result(run.run_id, PROCEDURE)["pose"]["poses"]
    out = _register_output(store, run)
    try:
        R, t = np.asarray(out["R"], dtype=float), np.asarray(out["t_mm"], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise ConfigError(f"run {run.run_id} ({run.serial}): no stored registration to carry its positions into "
                          "the mounting's frame") from None
    budget = Budget(**(store.run(run.run_id).params.get("uncertainty") or {}))
    tracker_mm = mounting.from_tracker(np.zeros(3))
    bary, u, u_scatter = {}, {}, {}
    for name, pose in poses.items():
        att = pose.get("attained") or {}
        xyz = np.column_stack([att.get("x_mm", []), att.get("y_mm", []), att.get("z_mm", [])]).astype(float)
        if xyz.shape[0] < 2:
            raise ConfigError(f"run {run.run_id} ({run.serial}): pose {name} has {xyz.shape[0]} attained positions; "
                              "a barycentre and its scatter need 2")
        in_mounting = mounting.from_tracker(xyz @ R.T + t)
        bary[name] = in_mounting.mean(axis=0)
        var = float(np.mean(in_mounting.var(axis=0, ddof=1)))
        u_scatter[name] = math.sqrt(var / xyz.shape[0])
        # the tracker at the origin of the budget's frame: the accuracy a + b R at the pose's range R
        from_tracker = bary[name] - tracker_mm
        u_tracker = math.hypot(float(budget.accuracy_sd_mm(from_tracker)),
                               budget.scale_sd() * float(np.linalg.norm(from_tracker)))
        u[name] = math.hypot(u_scatter[name], u_tracker)
    return RobotPoses(run.serial, run.run_id, bary, u, u_scatter)


def fleet_exchangeability(store: RunStore, *, model: str | None = None,
                          serials: list[str] | None = None) -> tuple[Exchangeability, dict]:
    """E of the robots chosen (``model``, or ``serials``) in their mounting's frame, and ``serial -> run_id`` of
    the runs it rests on.

    ConfigError, naming the reason, when fewer than two robots have runs, the runs are not one programme
    (poses, payload, speed, dwell, cycles, model), or not on one mounting in one frame
    (:func:`~station.analysis.iso9283.exchangeability.mounting_problems`)."""
    runs = latest_iso_runs(store, model=model, serials=serials)
    if len(runs) < 2:
        what = f"model {model}" if model is not None else "those serials"
        raise ConfigError(f"exchangeability needs finished ISO 9283 runs of at least 2 robots of {what}, "
                          f"found {len(runs)}")
    serial_count = {}
    for m, s in runs:
        serial_count[s] = serial_count.get(s, 0) + 1
    ordered = sorted(runs.items())
    who = {key: (key[1] if serial_count[key[1]] == 1 else f"{key[0]}/{key[1]}") for key, _ in ordered}
    plans = {who[key]: store.run(r.run_id).params for key, r in ordered}
    problems = conditions_problems(plans)
    if problems:
        raise ConfigError("the runs are not one test programme on one model; exchangeability refused: "
                          + "; ".join(problems))
    frames = {who[key]: run_mounting(store, r) for key, r in ordered}
    poses_mm = list(next(iter(plans.values()))["poses_mm"].values())
    problems = mounting_problems(frames, poses_mm)
    if problems:
        raise ConfigError("the runs are not on one mounting in one frame; exchangeability refused: "
                          + "; ".join(problems))
    result = exchangeability([robot_poses(store, r, frames[who[key]]) for key, r in ordered])
    result = replace(result, mounting=next(iter(frames.values())).name)
    return result, {s: r.run_id for (_, s), r in ordered}


__all__ = ["latest_iso_runs", "run_mounting", "robot_poses", "fleet_exchangeability"]
