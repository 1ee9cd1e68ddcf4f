"""The rest before the first move is a stop of its pose; every stop left out of a statistic says why.

A lab program runs P1, P2, P3, P4, P5 from rest at P1 (its first P1 is no move): without the rest P1
has a stop fewer than the others and the first P1->P2 posing time is missing.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from station.analysis.iso9283.characteristics import analyze_iso9283
from station.analysis.iso9283.poses import TABLE2_POSES_MM
from app.cli import main

from .labfiles import ap_ref, rp_ref, write_poses, write_stream_csv
from station.analysis.iso9283.extraction import STATUS_ASSIGNED, extract_attained_poses

from .conftest import chi3_q
from .synth import NAMES5, Programme, counted_stops, iso_cycle_programme, iso_stream, random_offsets, render

CMD = np.array(TABLE2_POSES_MM)
SERVO = dict(wn_hz=10.0, zeta=0.8)


def lab_stream(rng, n):
    prog = iso_cycle_programme(rng, n_cycles=n, order=(0, 1, 2, 3, 4), scatter_mm=0.02, dwell_s=0.5)
    # the robot stands at the first P1 when the recording starts: its first move is no move
    return render(rng, prog, start_mm=prog.target_mm[0], rate_hz=100.0, noise_mm=0.005, **SERVO), prog


def test_lab_program_starting_at_rest_gets_every_stop_and_the_first_posing_time(tmp_path, rng, capsys):
    n = int(rng.integers(4, 7))  # P5->P1 needs its 3 posing times for MPT (the last cycle ends at P5)
    s, prog = lab_stream(rng, n)
    S = write_stream_csv(tmp_path / "S.csv", s.t, s.xyz)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc = main(["analyze", "iso9283", "--stream", str(S), "--poses", str(P), "--order", "P1,P2,P3,P4,P5",
               "--initial-rest", "count", "--limit", "MPT_s=100", "--json", str(tmp_path / "r.json")])
    out = capsys.readouterr().out
    assert rc == 0
    d = json.loads((tmp_path / "r.json").read_text())
    for p, name in enumerate(NAMES5):
        pj = d["poses"][name]
        assert pj["n_cycles"] == n and pj["attained"]["cycle"] == list(range(n))
        rows = np.array(pj["attained"]["row"])
        xyz = np.round(s.xyz, 6)
        assert abs(pj["AP_mm"] - ap_ref(xyz[rows], CMD[p])) < 1e-5
        assert abs(pj["RP_mm"] - rp_ref(xyz[rows])) < 1e-5
        assert np.allclose(s.clean[rows], prog.target_mm[prog.pose == p], atol=0.01)  # each the true stop
    mpt = {(m["from"], m["to"]): m for m in d["MPT"]}
    assert mpt[("P1", "P2")]["n_available"] == n  # the first one starts at the rest
    assert d["extraction"]["initial_rest"]["counted"] is True
    assert "left out:" in out and "P1 cycle 0 from POS, PST: the rest before the first move" in out
    # without it: P1 one stop fewer, one posing time fewer
    rc = main(["analyze", "iso9283", "--stream", str(S), "--poses", str(P), "--order", "P1,P2,P3,P4,P5",
               "--initial-rest", "skip", "--json", str(tmp_path / "q.json")])
    capsys.readouterr()
    q = json.loads((tmp_path / "q.json").read_text())
    assert q["poses"]["P1"]["n_cycles"] == n - 1
    assert {(m["from"], m["to"]): m["n_available"] for m in q["MPT"]}[("P1", "P2")] == n - 1


def test_a_rest_at_a_pose_the_order_does_not_put_first_is_listed_not_counted(rng):
    s, _ = lab_stream(rng, 3)
    # order P2, P3, P4, P5, P1 with the stream's cycles starting at P1: the rest at P1 is followed by P2, and
    # P1 comes right before P2 in this order: counted (cycle -1); with P3 first it is not
    count = dict(initial_rest_stop=True)
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, order=["P2", "P3", "P4", "P5", "P1"], extraction=count)
    assert res.extraction.stops.initial[0] and res.poses["P1"].attained_cycle[0] == -1
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, order=["P1", "P3", "P2", "P4", "P5"], extraction=count)
    st = res.extraction.stops
    assert st.initial[0] and st.status[0] == 4  # INITIAL_REST
    (lo,) = [x for x in res.left_out if x.statistics == "all" and x.row == st.row[0]]
    assert "does not put P1 right before the first stop (P2)" in lo.reason
    assert res.to_dict()["extraction"]["other_stops"][0]["status"] == "initial_rest"


def test_a_lead_in_from_another_side_is_listed_with_its_reason(tmp_path, rng, capsys):
    n = 5
    prog = iso_cycle_programme(rng, n_cycles=n, scatter_mm=0.02, dwell_s=0.5)
    k = int(np.flatnonzero((prog.pose == 2) & (prog.cycle == int(rng.integers(1, n - 1))))[0])
    # fly through a point 200 mm beside P3 (no dwell): the final approach comes from that side
    side = np.cross(CMD[2] - CMD[1], [0.0, 0.0, 1.0])
    via = prog.target_mm[k] + 200.0 * side / np.linalg.norm(side)
    ins = lambda a, v: np.insert(a, k, v, axis=0)  # noqa: E731
    prog2 = Programme(ins(prog.target_mm, via), ins(prog.dwell_s, 0.0), ins(prog.pose, -1), ins(prog.cycle, -1),
                      ins(prog.direction, -1))
    s = render(rng, prog2, start_mm=CMD[0], rate_hz=100.0, noise_mm=0.005, **SERVO)
    S = write_stream_csv(tmp_path / "S.csv", s.t, s.xyz)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc = main(["analyze", "iso9283", "--stream", str(S), "--poses", str(P), "--json", str(tmp_path / "r.json")])
    out = capsys.readouterr().out
    assert rc == 0
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["poses"]["P3"]["n_cycles"] == n - 1 and d["poses"]["P3"]["n_directions"] == 2
    (lo,) = [x for x in d["left_out"] if x["pose"] == "P3"]
    assert lo["cycle"] == int(prog.cycle[k]) and lo["statistics"].startswith("AP, RP, POS, PST")
    assert "approached from" in lo["reason"] and "main direction" in lo["reason"]
    assert f"left out: row {lo['row']} " in out and "approached from" in out


@pytest.mark.parametrize("rate", [100.0, 1000.0])
def test_the_seed_cycle_with_the_rest_counted_against_the_truth(rng, rate):
    """Seed 3.1.3: rest at P1, then P2, P3, P4, P5, P1. Counted, the rest ends cycle -1; the library's
    default (the seed's convention) leaves it out and the stops are those of the deceleration phases."""
    noise = 0.005
    s = iso_stream(rng, n_cycles=4, rate_hz=rate, offsets_mm=random_offsets(rng), scatter_mm=0.02, noise_mm=noise,
                   wn_hz=8.0, zeta=0.8)
    ex = extract_attained_poses(s.t, s.xyz, CMD, names=NAMES5, initial_rest_stop=True)
    c = counted_stops(s)
    st = ex.stops
    a = st.status == STATUS_ASSIGNED
    assert st.initial[0] and a.sum() == c.pose.size and ex.order == (1, 2, 3, 4, 0) and ex.n_cycles == 4
    assert st.pose[a].tolist() == c.pose.tolist() and st.cycle[a].tolist() == c.cycle.tolist()
    truth = s.clean[st.row[a]]
    assert np.linalg.norm(truth - c.target_mm, axis=1).max() < 0.02
    assert np.linalg.norm(st.position_mm[a] - truth, axis=1).max() < chi3_q(1e-6) * noise
    assert np.all(st.t_s[a] >= c.t_arrive) and np.all(st.t_s[a][:-1] <= c.t_depart[:-1])
    plain = extract_attained_poses(s.t, s.xyz, CMD, names=NAMES5)
    assert not plain.stops.initial.any() and plain.stops.n == st.n - 1
    assert np.array_equal(plain.stops.row, st.row[1:])
