"""`station simulate iso9283 --program FILE`: a lab's program replayed on the simulated cell (issue 42 item 3).

The lab of issue 42: a UR arm, joint moves P1 <-> P2 over 162.5 deg with UR's default movej (60 deg/s,
80 deg/s^2, trapezoid), 2 s dwells, 3 cycles, a tracker at 333.3 Hz, at 100 % and 50 % speed.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from app.cli import main
from station.models.robots import get_robot
from station.readers.motion_program import parse_motion_program

from ..iso9283.conftest import chi3_q

RATE = 333.333


def lab_program(rng, speed_pct: float = 100.0, travel_deg: float = 162.5, cycles: int = 3) -> str:
    """The lab's program; the arm's other joints drawn at random about a reachable pose."""
    q = np.array([0.0, -100.0, 100.0, -90.0, -90.0, 0.0]) + rng.uniform(-10.0, 10.0, 6)
    p1, p2 = q.copy(), q.copy()
    p1[0], p2[0] = -travel_deg / 2, travel_deg / 2
    fmt = ", ".join
    return f"""# the lab of issue 42
robot = "ur5e"
rate_hz = {RATE}
cycles = {cycles}
dwell_s = 2.0
wait_s = 2.0
speed_pct = {speed_pct}
start = "P1"
order = ["P2", "P1"]

[move]
type = "joint"
profile = "trapezoid"

[poses.P1]
joints_deg = [{fmt(f'{v:.6f}' for v in p1)}]
[poses.P2]
joints_deg = [{fmt(f'{v:.6f}' for v in p2)}]
"""


def trapezoid_s(distance: float, v: float, a: float) -> float:
    return distance / v + v / a if distance >= v * v / a else 2.0 * math.sqrt(distance / a)


def replay(tmp_path, capsys, name, text, seed, *extra):
    prog = tmp_path / f"{name}.toml"
    prog.write_text(text)
    out = tmp_path / name
    assert main(["simulate", "iso9283", "--program", str(prog), "--out", str(out), "--seed", str(seed), *extra]) == 0
    capsys.readouterr()
    return out, json.loads((out / "truth.json").read_text())


def test_the_lab_replayed_at_100_and_50_percent(tmp_path, capsys, rng):
    """Every move takes UR's trapezoid over 162.5 deg (3.458 s at 100 %, twice that at 50 %: the samples of
    a move 2:1), and the station's analysis of the replayed stream finds each stop where the tracker read it
    (within its reading noise) and the RP the arm's scatter gives."""
    seed = int(rng.integers(0, 2**31))
    text = lab_program(rng)
    counts, wants = {}, {}
    for pct in (100.0, 50.0):
        out, truth = replay(tmp_path, capsys, f"lab{pct:g}", text.replace("speed_pct = 100.0", f"speed_pct = {pct}"),
                            seed)
        f = pct / 100.0
        # URScript's movej defaults, 1.05 rad/s and 1.4 rad/s^2: 3.45 s over 162.5 deg, as the lab's moves took
        want = trapezoid_s(162.5, math.degrees(1.05) * f, math.degrees(1.4) * f * f)
        assert pct != 100.0 or want == pytest.approx(3.45, abs=0.005)
        durations = np.array([s["t_end_s"] - s["t_start_s"] for s in truth["stops"]])
        np.testing.assert_allclose(durations, want, rtol=1e-9)
        wants[pct] = want
        assert len(truth["stops"]) == 6 and truth["world"]["profile"] == "trapezoid"
        data = np.genfromtxt(out / "stream.csv", delimiter=",", names=True)
        t_dev = data["t"]
        off = truth["stops"][0]["t_attained_device_s"] - truth["stops"][0]["t_attained_s"]
        counts[pct] = [int(np.count_nonzero((t_dev >= s["t_start_s"] + off) & (t_dev < s["t_end_s"] + off)))
                       for s in truth["stops"]]
        np.testing.assert_allclose(np.diff(t_dev), 1.0 / RATE, atol=1.5e-6)  # stamps of 1 us
        # the analysis of the replayed file
        assert main(["analyze", "iso9283", "--stream", str(out / "stream.csv"), "--poses", str(out / "poses.csv"),
                     "--order", "P2,P1", "--json", str(out / "r.json")]) == 0
        capsys.readouterr()
        res = json.loads((out / "r.json").read_text())
        noise = truth["world"]["tracker"]["noise"]
        sig_n = math.hypot(noise["white_um"], noise["wander_um"]) * 1e-3
        for name in ("P1", "P2"):
            stops = [s for s in truth["stops"] if s["pose"] == name]
            read = np.array([s["reading_tracker_mm"] for s in stops])
            p = res["poses"][name]
            att = np.column_stack([p["attained"]["x_mm"], p["attained"]["y_mm"], p["attained"]["z_mm"]])
            assert p["attained"]["cycle"] == [s["cycle"] - 1 for s in stops]
            delta = np.linalg.norm(att - read, axis=1).max()
            assert delta < chi3_q(1e-6) * sig_n, (name, delta, sig_n)
            # eq. (2) moves by at most (2 + 12 sqrt(n / (n - 1))) delta when every point moves by delta
            l = np.linalg.norm(read - read.mean(axis=0), axis=1)
            rp_read = l.mean() + 3 * l.std(ddof=1)
            n = len(stops)
            assert abs(p["RP_mm"] - rp_read) <= (2 + 12 * math.sqrt(n / (n - 1))) * delta + 1e-9
            # the readings' RP is the arm's own (the session's error is the same offset at every stop)
            assert rp_read == pytest.approx(truth["figures"][name]["RP_mm"], abs=1e-4)
    c100, c50 = np.array(counts[100.0]), np.array(counts[50.0])
    assert np.all(np.abs(c100 - wants[100.0] * RATE) <= 1)
    assert np.all(np.abs(c50 / c100 - 2.0) <= 2.0 / c100)


def test_ur_moves_default_to_movej_and_a_json_program_reads_the_same(tmp_path, rng):
    """A move without speed, acceleration or profile is a UR's default movej; TOML and JSON give one program."""
    import tomllib

    text = lab_program(rng)
    obj = tomllib.loads(text)
    a = parse_motion_program(obj, "a.toml")
    (tmp_path / "p.json").write_text(json.dumps(obj))
    from station.readers.motion_program import read_motion_program

    b = read_motion_program(tmp_path / "p.json")
    assert (a.order, a.poses, a.cycles, a.rate_hz, a.start) == (b.order, b.poses, b.cycles, b.rate_hz, b.start)
    from fakes.sim.program_run import _resolve

    moves = _resolve(a, get_robot("ur5e"))
    assert moves[0] == {"to": "P2", "type": "joint", "speed": pytest.approx(60.16, abs=0.01),
                        "acceleration": pytest.approx(80.21, abs=0.01), "profile": "trapezoid"}
    obj["speed_pct"] = 25
    slow = _resolve(parse_motion_program(obj, "b"), get_robot("ur5e"))[0]
    assert slow["speed"] == pytest.approx(moves[0]["speed"] / 4) and \
        slow["acceleration"] == pytest.approx(moves[0]["acceleration"] / 16)


BAD = [
    ('cycles = 3\nbogus = 1\norder = ["P1"]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n', "`bogus`"),
    ('order = ["P1"]\n', "`poses` is missing"),
    ('order = ["P9"]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n', "`order[0].to` names pose 'P9'"),
    ('order = [{to = "P1", speed = -5}]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n', "`order[0].speed`"),
    ('order = [{to = "P1", profile = "bang"}]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n',
     "`order[0].profile` must be one of trapezoid, s-curve"),
    ('order = ["P1"]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90]\n', "`poses.P1.joints_deg` must be a list of 6"),
    ('order = ["P1"]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\nxyz_mm = [1,2,3]\n', "exactly one of"),
    ('rate_hz = 5000\norder = ["P1"]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n', "`rate_hz` must be within"),
    ('cycles = 0\norder = ["P1"]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n', "`cycles` must be an integer"),
    ('speed_pct = 0\norder = ["P1"]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n', "`speed_pct`"),
    ('dwell_s = "2"\norder = ["P1"]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n', "`dwell_s`"),
    ('[move]\nspeed = 400\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n[poses.P2]\njoints_deg = [10,-90,90,-90,-90,0]'
     '\n', "`order` is missing"),
    ('order = ["P2"]\n[move]\nspeed = 400\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n[poses.P2]\n'
     'joints_deg = [10,-90,90,-90,-90,0]\n', "`order[0].speed` 400 deg/s is above the rated 180"),
    ('payload_kg = 6\norder = ["P1"]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,0]\n', "`payload_kg` 6 kg is above"),
    ('order = ["P1"]\n[poses.P1]\nxyz_mm = [5000, 0, 0]\n', "`poses.P1.xyz_mm`"),
    ('order = ["P1"]\n[poses.P1]\njoints_deg = [0,-90,90,-90,-90,900]\n', "`poses.P1.joints_deg[5]`"),
    ('order = [1, 2\n', "not TOML"),
]


@pytest.mark.parametrize("text, needle", BAD)
def test_a_bad_program_is_refused_naming_the_key(tmp_path, capsys, text, needle):
    prog = tmp_path / "bad.toml"
    prog.write_text('robot = "ur5e"\n' + text)
    out = tmp_path / "out"
    assert main(["simulate", "iso9283", "--program", str(prog), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert needle in err and str(prog) in err, err
    assert not out.exists()  # nothing written


def test_program_options_and_the_program_do_not_mix(tmp_path, capsys, rng):
    prog = tmp_path / "p.toml"
    prog.write_text(lab_program(rng))
    assert main(["simulate", "iso9283", "--program", str(prog), "--out", str(tmp_path / "o"), "--cycles", "5"]) == 2
    assert "--cycles and --program" in capsys.readouterr().err
    assert main(["simulate", "iso9283", "--program", str(prog), "--out", str(tmp_path / "o"), "--robot",
                 "ur10e"]) == 2
    assert "`robot` is 'ur5e' but --robot says 'ur10e'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_one_seed_one_stream_however_it_is_chunked(tmp_path, rng):
    """The same program and seed give the same bytes, measured in chunks of any length (the tracker's wander
    is drawn by index, not by the order the samples were asked for)."""
    from fakes.sim.program_run import simulate_program
    from station.readers.motion_program import read_motion_program

    prog = tmp_path / "p.toml"
    prog.write_text(lab_program(rng, cycles=1).replace(f"rate_hz = {RATE}", "rate_hz = 100"))
    program = read_motion_program(prog)
    seed = int(rng.integers(0, 2**31))
    a = simulate_program(tmp_path / "a", program, seed=seed)
    b = simulate_program(tmp_path / "b", program, seed=seed, chunk_s=float(rng.uniform(0.05, 3.0)))
    assert a["n_samples"] == b["n_samples"] > 0
    assert (tmp_path / "a" / "stream.csv").read_bytes() == (tmp_path / "b" / "stream.csv").read_bytes()
    c = simulate_program(tmp_path / "c", program, seed=seed + 1)
    assert (tmp_path / "c" / "stream.csv").read_bytes() != (tmp_path / "a" / "stream.csv").read_bytes()
    assert c["n_samples"] == a["n_samples"]
