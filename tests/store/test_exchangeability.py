"""ISO 9283 7.8 exchangeability over stored ISO 9283 runs of several simulated robots of one model exchanged on one
mounting of one cell (the tracker left standing; each robot's base drawn off the plate by its mounting offset,
:mod:`fakes.sim.mounting`): the figure in the mounting's frame (the first robot's registered frame, kept for the
others through its frame file) equals the one computed from the simulated arms in the true mounting frame within
its uncertainty; runs without a mounting frame, on different mountings, in frames that are not one, or not one
test programme are refused with the reason."""

from __future__ import annotations

import copy
import json
import subprocess
import sys

import numpy as np
import pytest

from app.assemble import RunRequest, run_procedure
from fakes.sim.mounting import draw_base_offset, draw_mounting, in_mounting
from fakes.station import FakeStation
from procedures.devices import DeviceSet
from procedures.iso9283 import registration_of
from station.analysis.iso9283.exchangeability import (MAX_BASE_OFFSET_MM, MountingFrame, conditions_problems,
                                                      mounting_problems)
from station.config import config_from_dict
from station.errors import ConfigError
from station.fleet.exchangeability import fleet_exchangeability
from station.runner import ScriptedOperator
from station.store import RunStore
from tests.pace import LOCKSTEP

ROBOTS = 3  # on the mounting; one more robot of the model is measured without a mounting
CYCLES = 3
MODEL = "industrial-3100"
PLATE = "plate-A"


def _truth(store, run_id, world, mount_T_base, mounting_frame) -> dict:
    """Each pose's barycentre of the arm's true positions at the attained instants: in the true mounting frame
    (``"true"``), and as the run's tracker reads them (its session's systematic error, its noise aside) carried
    into the mounting frame the runs were measured in (``"read"``); and in the run's own registered frame
    (``"registered"``, what each robot's own registration makes of it)."""
    steps = store.steps(run_id)
    reg = registration_of({s.name: s.output for s in steps if s.status == "done"})
    T = world.tracker.tracker_T_base
    out = {"true": {}, "read": {}, "registered": {}}
    for name, pose in store.result(run_id, "iso9283")["pose"]["poses"].items():
        true_base = world.arm.tool_position_mm(np.asarray(pose["attained"]["t_s"]))
        read = world.tracker.reading(true_base @ T[:3, :3].T + T[:3, 3])
        out["true"][name] = in_mounting(mount_T_base, true_base).mean(axis=0)
        out["read"][name] = mounting_frame.from_tracker(read).mean(axis=0)
        out["registered"][name] = reg.to_base(read).mean(axis=0)
    return out


def _run(tmp, seed, serial, run_id, base_T_tracker, mounting):
    with FakeStation.start(seed=int(seed), time_scale=LOCKSTEP, base_T_tracker=base_T_tracker) as station:
        d = station.config_dict(store_path=str(tmp / "s.sqlite"), report_dir=str(tmp / "reports"),
                                serial=serial, iso9283={"cycles": CYCLES, "vap_cycles": 2})
        if mounting is not None:
            d["robots"]["r1"]["mounting"] = mounting
        devices = DeviceSet(urls={"tracker": station.tracker_url, "controller": station.controller_url},
                            time_scale=station.world.clock.time_scale)
        out = run_procedure(RunRequest(config_from_dict(d, base_dir=tmp), "iso9283", devices=devices,
                                       operator=ScriptedOperator(True), quiet=True, run_id=run_id, config_dir=tmp))
        assert out.status == "done", out.error
        return d, station.world


@pytest.fixture(scope="module")
def fleet(tmp_path_factory, request):
    """One cell (the tracker's pose on the mounting drawn once), three robots of one model set on its plate with
    drawn base offsets, each run once into one store: the first with the mounting named (its registered frame
    becomes the mounting's), the others with the first run's frame file; a fourth robot of the model measured
    without a mounting. Seeds drawn from the session's (--seed replays)."""
    from tests.seeding import session_seed

    tmp = tmp_path_factory.mktemp("fleet")
    rng = np.random.default_rng([session_seed(request.config), 7809])
    cell = draw_mounting(MODEL, rng)
    seeds = rng.integers(0, 2**31 - 1, ROBOTS + 1)
    offsets = [draw_base_offset(rng) for _ in range(ROBOTS + 1)]
    truths, cfg_dict, frame = {}, None, None
    for k in range(ROBOTS):
        serial = f"SIM-{k:04d}"
        mounting = {"name": PLATE} if k == 0 else {"name": PLATE, "frame": "reports/r0.frame.json"}
        cfg_dict, world = _run(tmp, seeds[k], serial, f"r{k}", cell.base_T_tracker(offsets[k]), mounting)
        with RunStore(tmp / "s.sqlite") as store:
            if k == 0:
                out = {s.name: s.output for s in store.steps("r0") if s.status == "done"}["register base frame"]
                frame = MountingFrame.from_dict(out["mounting"])
            truths[serial] = _truth(store, f"r{k}", world, offsets[k], frame)
    _run(tmp, seeds[ROBOTS], f"SIM-{ROBOTS:04d}", f"r{ROBOTS}", cell.base_T_tracker(offsets[ROBOTS]), None)
    return tmp, truths, cfg_dict, seeds, offsets


def _spread(G) -> float:
    G = np.asarray(G)
    return float(np.max(np.linalg.norm(G[:, None] - G[None], axis=2)))


def test_exchangeability_on_one_mounting_is_the_truths_within_its_uncertainty(fleet):
    tmp, truths, _, seeds, offsets = fleet
    serials = sorted(truths)
    print(f"robot seeds {list(map(int, seeds))}, base offsets "
          f"{[np.round(T[:3, 3], 3).tolist() for T in offsets[:ROBOTS]]} mm")
    with RunStore(tmp / "s.sqlite") as store:
        result, runs = fleet_exchangeability(store, serials=serials)
        frames = {s: {x.name: x.output for x in store.steps(runs[s]) if x.status == "done"}["register base frame"]
                  ["mounting"] for s in serials}
    assert sorted(runs) == serials and result.mounting == PLATE
    assert frames[serials[0]]["from"] == "this run's registered frame" and frames[serials[0]]["base_offset_mm"] < 1e-9
    for s in serials[1:]:
        assert frames[s]["from"].startswith("frame file ") and frames[s]["from"].endswith("r0.frame.json")
        assert 0 < frames[s]["base_offset_mm"] < MAX_BASE_OFFSET_MM
    worst_true, registered_away = 0.0, []
    for pose, p in result.per_pose.items():
        e_true = _spread([truths[s]["true"][pose] for s in serials])
        e_read = _spread([truths[s]["read"][pose] for s in serials])
        e_reg = _spread([truths[s]["registered"][pose] for s in serials])
        worst_true = max(worst_true, e_true)
        print(f"{pose}: E {p['exchangeability_mm']:.4f} mm (U {p['U_mm']:.4f}, scatter {p['U_scatter_mm']:.4f}); "
              f"truth on the mounting {e_true:.4f} mm, as the trackers read it {e_read:.4f} mm; in each robot's "
              f"registered frame {e_reg:.4f} mm")
        # what the tracker sessions read of the true positions differs from the figure by their noise alone
        assert abs(p["exchangeability_mm"] - e_read) <= p["U_scatter_mm"], (pose, p, e_read)
        # the truth in the mounting's frame, within U (the sessions' systematic errors are in U, not in U_scatter)
        assert abs(p["exchangeability_mm"] - e_true) <= p["U_mm"], (pose, p, e_true)
        assert p["U_scatter_mm"] <= p["U_mm"]
        registered_away.append(abs(e_reg - p["exchangeability_mm"]) > p["U_mm"])
    assert result.exchangeability_mm == max(p["exchangeability_mm"] for p in result.per_pose.values())
    assert abs(result.exchangeability_mm - worst_true) <= result.U_mm
    # one frame for all: the registrations' errors are out of U, which is the tracker's and the scatter's alone
    # (tens of micrometres) against robots of one model millimetres apart
    assert result.U_mm < 0.2 * result.exchangeability_mm
    # each robot in its own registered frame (the figure before the mounting was recorded) is another figure:
    # the registrations absorb the bases' offsets and the joint 1 and 2 zero offsets (millimetres on these arms)
    assert any(registered_away)


def test_runs_without_a_mounting_frame_are_refused_naming_them(fleet):
    tmp, truths, cfg_dict, _, _ = fleet
    unmounted = f"SIM-{ROBOTS:04d}"
    with RunStore(tmp / "s.sqlite") as store:
        with pytest.raises(ConfigError, match=f"not on one mounting.*without a mounting frame: {unmounted}"):
            fleet_exchangeability(store, model=MODEL)
        with pytest.raises(ConfigError, match=f"without a mounting frame: {unmounted}"):
            fleet_exchangeability(store, serials=[sorted(truths)[0], unmounted])
    cfg = tmp / "station.json"
    cfg.write_text(json.dumps(cfg_dict))
    bad = subprocess.run([sys.executable, "-m", "app.cli", "store", "exchangeability", "--config", str(cfg),
                          "--model", MODEL], capture_output=True, text=True)
    assert bad.returncode == 2 and f"without a mounting frame: {unmounted}" in bad.stderr, bad.stderr


def test_mounting_problems_name_what_differs(fleet, rng):
    tmp, truths, _, _, _ = fleet
    serials = sorted(truths)
    with RunStore(tmp / "s.sqlite") as store:
        frames = {s: MountingFrame.from_dict({x.name: x.output for x in store.steps(r.run_id) if x.status == "done"}
                                             ["register base frame"]["mounting"])
                  for s in serials for r in store.runs() if r.serial == s}
        poses = list(store.run("r0").params["poses_mm"].values())
    assert mounting_problems(frames, poses) == []
    other = dict(frames)
    other[serials[1]] = MountingFrame("plate-B", frames[serials[1]].R, frames[serials[1]].t_mm, 0.0)
    (why,) = mounting_problems(other, poses)
    assert why == f"measured on different mountings: {PLATE} ({serials[0]}, {serials[2]}); plate-B ({serials[1]})"
    # the frame measured again (another robot's registration given as the mounting's): not one frame
    moved = dict(frames)
    shift = rng.normal(0.0, 1.0, 3)
    f = frames[serials[2]]
    moved[serials[2]] = MountingFrame(PLATE, f.R, f.t_mm + shift, f.base_offset_mm)
    (why,) = mounting_problems(moved, poses)
    assert why.startswith(f"not one mounting frame: {serials[2]}'s puts the test poses up to "
                          f"{np.linalg.norm(shift):.4g} mm from {serials[0]}'s")
    # a base further from the frame than a robot on the mounting can be: the tracker moved
    far = dict(frames)
    far[serials[1]] = MountingFrame(PLATE, f.R, f.t_mm, MAX_BASE_OFFSET_MM * (1.0 + rng.uniform(0.01, 5.0)))
    (why,) = [p for p in mounting_problems(far, poses) if "further than" in p]
    assert f"{serials[1]} {far[serials[1]].base_offset_mm:.4g} mm" in why and "tracker moved" in why


def test_runs_that_are_not_one_programme_are_refused_with_the_reason(fleet):
    tmp, truths, _, _, _ = fleet
    with RunStore(tmp / "s.sqlite") as store:
        plans = {r.serial: r.params for r in store.runs() if r.serial in truths}
    plans_wo_mounting = {s: {k: v for k, v in p.items() if k != "mounting"} for s, p in plans.items()}
    assert conditions_problems(plans_wo_mounting) == []
    for key, change in (("payload_kg", 5.0), ("cycles", 30), ("speed_frac", 0.5), ("registration", "best-fit")):
        other = copy.deepcopy(plans)
        last = sorted(other)[-1]
        other[last][key] = change
        problems = conditions_problems(other)
        assert len(problems) == 1 and problems[0].startswith(f"{key} differs") and last in problems[0]
    moved = copy.deepcopy(plans)
    serial = sorted(moved)[1]
    moved[serial]["poses_mm"]["P3"][0] += 0.5  # another cube
    assert any(p.startswith("poses_mm differs") for p in conditions_problems(moved))
    with RunStore(tmp / "s.sqlite") as store:
        with pytest.raises(ConfigError, match="at least 2 robots of model ur5e, found 0"):
            fleet_exchangeability(store, model="ur5e")
        with pytest.raises(ConfigError, match="for serial\\(s\\) NOPE"):
            fleet_exchangeability(store, serials=[sorted(truths)[0], "NOPE"])


def test_the_command_states_the_figure_in_the_mountings_frame(fleet):
    tmp, truths, cfg_dict, _, _ = fleet
    cfg = tmp / "station.json"
    cfg.write_text(json.dumps(cfg_dict))
    serials = ",".join(sorted(truths))
    ok = subprocess.run([sys.executable, "-m", "app.cli", "store", "exchangeability", "--config", str(cfg),
                         "--serials", serials, "--json"], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    doc = json.loads(ok.stdout)
    assert doc["figure"] == "exchangeability_mm" and sorted(doc["runs"]) == sorted(truths)
    assert doc["mounting"] == PLATE
    text = subprocess.run([sys.executable, "-m", "app.cli", "store", "exchangeability", "--config", str(cfg),
                           "--serials", serials], capture_output=True, text=True)
    assert text.returncode == 0 and f"in the frame of mounting {PLATE}" in text.stdout
    bad = subprocess.run([sys.executable, "-m", "app.cli", "store", "exchangeability", "--config", str(cfg),
                          "--serials", sorted(truths)[0]], capture_output=True, text=True)
    assert bad.returncode == 2 and "at least 2 serials" in bad.stderr


def test_the_fleet_page_says_why_the_model_has_no_figure(fleet):
    from station.fleet.page import fleet_report

    tmp, _, _, _, _ = fleet
    with RunStore(tmp / "s.sqlite") as store:
        notes = fleet_report(store, "RP_mm").notes
    line = next(n for n in notes if n.startswith(f"exchangeability of {MODEL}: not stated"))
    assert f"without a mounting frame: SIM-{ROBOTS:04d}" in line


def test_a_mounting_frame_file_is_checked_when_the_config_is_read(tmp_path, rng):
    from station.config import MountingConfig

    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    good = tmp_path / "m.frame.json"
    good.write_text(json.dumps({"R": R.tolist(), "t_mm": [1.0, 2.0, 3.0]}))
    m = MountingConfig.model_validate({"name": PLATE, "frame": "m.frame.json"}, context={"base_dir": tmp_path})
    assert m.frame == str(good.resolve())
    sheared = tmp_path / "bad.frame.json"
    sheared.write_text(json.dumps({"R": (R * 1.01).tolist(), "t_mm": [1.0, 2.0, 3.0]}))
    for name, why in (("bad.frame.json", "key 'R' is not a rotation"), ("none.json", "none.json")):
        with pytest.raises(Exception, match=why):
            MountingConfig.model_validate({"name": PLATE, "frame": name}, context={"base_dir": tmp_path})
