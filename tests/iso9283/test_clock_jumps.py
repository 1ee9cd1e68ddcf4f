"""Clocks that jump (issue 47, item 11): a daylight-saving change or a wrong --date-order is a jump of the
clock, not a beam break: the time figures across it are refused (not decided, exit 3), the others stand as
on the true clock. A UTC leap second (23:59:60) is a second like the others."""

from __future__ import annotations

import json
import math
from datetime import datetime, timedelta

import numpy as np
import pytest

from app.cli import main
from station.analysis.iso9283.clock_jumps import clock_jumps
from station.analysis.iso9283.poses import TABLE2_POSES_MM

from .labfiles import write_poses, write_sa, write_stream_csv
from .synth import NAMES5, iso_stream, random_offsets

CMD = np.array(TABLE2_POSES_MM)
SA_HEADER_LINES = 4  # write_sa's comment lines: row i is on line i + 5
#: the limits every run is decided on; the rest before the first move counts (its move to P2 is the third MPT time)
LIMITS = ("--limit", "PST_s=5", "--limit", "MPT_s=20", "--initial-rest", "count")


def run(capsys, *argv):
    rc = main(["analyze", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def stream(rng, rate=100.0):
    return iso_stream(rng, n_cycles=3, rate_hz=rate, offsets_mm=random_offsets(rng), scatter_mm=0.02,
                      noise_mm=0.005, wn_hz=10.0, zeta=0.6)


def reference(tmp_path, capsys, s):
    """The analysis on the true clock (the project's CSV with the stream's own times)."""
    f = write_stream_csv(tmp_path / "true.csv", s.t, s.xyz)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, _, err = run(capsys, "iso9283", "--stream", f, "--poses", P, *LIMITS, "--json", tmp_path / "true.json")
    assert rc == 0, err
    return json.loads((tmp_path / "true.json").read_text())


def spans(a, b, r):
    return a >= 0 and b >= 0 and a < r <= b


def check_refused_across(d, ref, r):
    """Every PST and MPT whose interval holds row ``r`` is refused; every other one is as on the true clock."""
    refused = set(d["time_base"]["refused_figures"])
    for name, pr in ref["poses"].items():
        oc = pr["overshoot_per_cycle"]
        across = any(spans(min(e, a), max(s_, a), r) for e, s_, a in zip(oc["row_entry"], oc["row_settled"], oc["row"])
                     if e >= 0)
        if across:
            assert f"PST_s {name}" in refused and d["poses"][name]["PST_s"] is None
        if f"PST_s {name}" not in refused:
            assert d["poses"][name]["PST_s"] == pytest.approx(pr["PST_s"], abs=1e-6)
    for m, mr in zip(d["MPT"], ref["MPT"]):
        key = f"MPT_s {m['from']}->{m['to']}"
        if any(spans(a, b, r) for a, b in zip(mr["row_leave"], mr["row_settled"])):
            assert key in refused and m["MPT_s"] is None
        if key not in refused:
            assert m["MPT_s"] == pytest.approx(mr["MPT_s"], abs=1e-6)
    for v in d["verdicts"]:
        if f"{v['characteristic']} {v['subject']}" in refused:
            assert v["passed"] is None and "refused" in v["note"]


def sa_stamps(t_abs, t0):
    return [(t0 + timedelta(seconds=float(x))).strftime("%Y-%m-%d %H:%M:%S.%f")[:-4] for x in t_abs]


def test_a_daylight_saving_jump_refuses_the_time_figures_across_it(tmp_path, rng, capsys):
    s = stream(rng)
    ref = reference(tmp_path, capsys, s)
    n = s.t.size
    r = int(rng.integers(n // 3, 2 * n // 3))  # the first row after the clock moved on an hour
    t_pc = s.t - s.t[0] + np.where(np.arange(n) >= r, 3600.0, 0.0)
    f = write_sa(tmp_path / "dst.txt", s.xyz, stamps=sa_stamps(t_pc, datetime(2025, 3, 30, 1, 59, 30)))
    P = tmp_path / "P.csv"
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, *LIMITS, "--json", tmp_path / "r.json")
    line = r + SA_HEADER_LINES + 1
    assert f"note: line {line}, column 'date time': the clock jumps +3600.01 s (+1 h) here" in out
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["time_base"]["jumps"][0]["row"] == r
    check_refused_across(d, ref, r)
    if d["time_base"].get("refused_figures"):
        assert rc == 3 and "a time figure across a jump is not a measurement" in err
    else:  # the jump fell where no time figure is taken (a long rest): nothing changed
        assert rc == 0, err


def test_a_wrong_date_order_over_midnight_is_a_jump_the_right_one_is_the_true_clock(tmp_path, rng, capsys):
    s = stream(rng)
    ref = reference(tmp_path, capsys, s)
    n = s.t.size
    r = int(rng.integers(n // 3, 2 * n // 3))
    t0 = datetime(2025, 3, 11, 23, 59, 59) - timedelta(seconds=float(s.t[r] - s.t[0]))  # midnight at row r
    stamps = [(t0 + timedelta(seconds=float(x - s.t[0]))).strftime("%m/%d/%y %H:%M:%S.%f")[:-4] for x in s.t]
    f = write_sa(tmp_path / "midnight.txt", s.xyz, stamps=stamps)
    P = tmp_path / "P.csv"
    rc, _, err = run(capsys, "iso9283", "--stream", f, "--poses", P, *LIMITS)
    assert rc == 2 and "--date-order" in err  # the dates do not say their order
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, *LIMITS, "--date-order", "mdy", "--json",
                       tmp_path / "mdy.json")
    assert rc == 0, err
    d = json.loads((tmp_path / "mdy.json").read_text())
    assert "jumps" not in d["time_base"]
    for name in NAMES5:
        assert d["poses"][name]["PST_s"] == pytest.approx(ref["poses"][name]["PST_s"], abs=1e-6)
    assert [m["MPT_s"] for m in d["MPT"]] == pytest.approx([m["MPT_s"] for m in ref["MPT"]], abs=1e-6)
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, *LIMITS, "--date-order", "dmy", "--json",
                       tmp_path / "dmy.json")
    d = json.loads((tmp_path / "dmy.json").read_text())
    (jump,) = d["time_base"]["jumps"]
    first_new_day = int(np.flatnonzero(np.array([st.startswith("03/12") for st in stamps]))[0])
    assert jump["row"] == first_new_day and jump["step_s"] == pytest.approx(29 * 86400.0, abs=2.0)
    check_refused_across(d, ref, first_new_day)
    assert rc == (3 if d["time_base"].get("refused_figures") else 0), err


def test_a_beam_break_is_no_jump(rng):
    s = stream(rng)
    k = int(rng.integers(1, s.t_move_start.size - 1))  # samples lost in the middle of a move
    a = int(np.searchsorted(s.t, 0.5 * (s.t_move_start[k] + s.t_arrive[k])))
    keep = np.setdiff1d(np.arange(s.t.size), np.arange(a, a + int(rng.integers(10, 40))))
    assert clock_jumps(s.t[keep], s.xyz[keep]) == ()
    # the same step with no sample lost is a jump the motion shows
    t = s.t.copy()
    t[a:] += float(rng.uniform(0.3, 50.0))
    (j,) = clock_jumps(t, s.xyz)
    assert j.row == a and j.evidence == "moving"


def test_a_long_gap_at_rest_is_a_jump_only_in_whole_hours(rng):
    n = 4000
    t = np.arange(n) / 100.0
    xyz = np.array([100.0, 200.0, 300.0]) + rng.normal(0.0, 0.005, (n, 3))
    r = int(rng.integers(100, n - 100))
    for step, is_jump in ((3600.0 * int(rng.integers(1, 3)), True), (float(rng.uniform(60.0, 3000.0)), False)):
        tj = t.copy()
        tj[r:] += step
        found = clock_jumps(tj, xyz)
        assert (len(found) == 1 and found[0].row == r and found[0].evidence == "whole hours") == is_jump


def leap_stamp(x):
    """The UTC stamp of ``x`` seconds from 2016-12-31 00:00:00, through the leap second at its end."""
    day = 86400.0
    if x < day:
        return f"2016-12-31 {int(x // 3600):02d}:{int(x % 3600 // 60):02d}:{x % 60:05.2f}"
    if x < day + 1.0:
        return f"2016-12-31 23:59:{60.0 + (x - day):05.2f}"
    y = x - day - 1.0
    return f"2017-01-01 {int(y // 3600):02d}:{int(y % 3600 // 60):02d}:{y % 60:05.2f}"


def test_a_leap_second_is_a_second(tmp_path, rng, capsys):
    s = stream(rng)
    ref = reference(tmp_path, capsys, s)
    r = int(rng.integers(s.t.size // 4, 3 * s.t.size // 4))  # 23:59:60.00 falls on this row
    x = 86400.0 + np.round(s.t - s.t[r], 2)
    f = write_sa(tmp_path / "leap.txt", s.xyz, stamps=[leap_stamp(v) for v in x])
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", tmp_path / "P.csv", *LIMITS, "--json",
                       tmp_path / "r.json")
    assert rc == 0, err
    first_after = r + 100  # 00:00:00.00, one second of samples later
    assert f"note: line {first_after + SA_HEADER_LINES + 1}: a leap second (:60) before this line is counted" in out
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["time_base"] == {"source": "stamps", "rate_hz": None}
    for name in NAMES5:
        assert d["poses"][name]["PST_s"] == pytest.approx(ref["poses"][name]["PST_s"], abs=1e-6)
    assert [m["MPT_s"] for m in d["MPT"]] == pytest.approx([m["MPT_s"] for m in ref["MPT"]], abs=1e-6)


def test_a_leap_second_in_whole_second_stamps_holds_its_samples(tmp_path, rng, capsys):
    rate = 100.0
    s = stream(rng, rate)
    phase = float(rng.uniform(0, 1))
    r = int(rng.integers(s.t.size // 4, 3 * s.t.size // 4))
    x = 86400.0 + np.floor(s.t - s.t[r] + phase)
    f = write_sa(tmp_path / "leap1s.txt", s.xyz, stamps=[leap_stamp(v)[:-3] for v in x])
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", write_poses(tmp_path / "P.csv", NAMES5, CMD),
                       *LIMITS, "--json", tmp_path / "r.json")
    assert rc == 0, err
    tb = json.loads((tmp_path / "r.json").read_text())["time_base"]
    assert tb["source"] == "estimated_rate" and tb["varying_rows"] == []
    assert abs(tb["rate_hz"] - rate) <= tb["u_rate_hz"] + 1e-9


def test_a_hold_across_a_daylight_saving_jump_states_no_drift(tmp_path, rng, capsys):
    n = int(100.0 * rng.uniform(60, 120))
    t = np.arange(n) / 100.0
    xyz = np.array([900.0, 100.0, 400.0]) + rng.normal(0.0, 0.002, (n, 3))
    r = int(rng.integers(n // 4, 3 * n // 4))
    t_pc = t + np.where(np.arange(n) >= r, 3600.0, 0.0)
    f = write_sa(tmp_path / "hold.txt", xyz, stamps=sa_stamps(t_pc, datetime(2025, 3, 30, 1, 59, 0)))
    rc, out, err = run(capsys, "hold", "--stream", f, "--json", tmp_path / "h.json")
    assert rc == 3 and "a drift per minute across a jump is not a measurement" in err
    assert f"line {r + SA_HEADER_LINES + 1}" in err
    d = json.loads((tmp_path / "h.json").read_text())
    assert d["drift_mm_per_min"] is None and d["duration_s"] is None
    assert math.isfinite(d["noise_3d_mm"])


def test_a_leap_second_is_counted_and_a_rounded_sixtieth_second_is_not():
    from station.readers.date_time import parse_stamp, stamps_to_seconds

    leap = ["2016-12-31 23:59:59.50", "2016-12-31 23:59:60.00", "2016-12-31 23:59:60.50", "2017-01-01 00:00:00.00",
            "2017-01-01 00:00:00.50"]
    r = stamps_to_seconds([parse_stamp(x) for x in leap])
    assert r.t_s == pytest.approx([0.0, 0.5, 1.0, 1.5, 2.0]) and r.leap_rows == (3,)
    # whole seconds: the leap second's samples keep their own second
    r = stamps_to_seconds([parse_stamp(x) for x in ("12/31/16 23:59:59", "12/31/16 23:59:60", "12/31/16 23:59:60",
                                                     "01/01/17 00:00:00")], date_order="mdy")
    assert r.t_s == pytest.approx([0.0, 1.0, 1.0, 2.0])
    # a logger that writes 59.9996 s as 60.000 and goes on with the next minute: nothing to count
    r = stamps_to_seconds([parse_stamp(x) for x in ("2025-03-11 14:07:59.99", "2025-03-11 14:07:60.00",
                                                     "2025-03-11 14:08:00.01")])
    assert r.t_s == pytest.approx([0.0, 0.01, 0.02]) and r.leap_rows == ()
