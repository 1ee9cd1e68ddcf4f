"""Program model, builders and the RAPID / KRL generators (pure, no network)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fakes.rapid_interp import compile_rapid, parse_rapid, tokenize, unquote
from station.errors import ConfigError
from station.programs import (
    CartesianTarget,
    Dwell,
    Loop,
    Move,
    Program,
    calibration_program,
    expected_stops,
    iso_pose_program,
    render_krl,
    render_rapid,
    vap_program,
)
from station.programs.krl import abc_deg_from_quat
from station.programs.program import matrix_from_quat, quat_from_matrix


def test_iso_cycle_rapid_structure(rng, robot, iso_poses):
    cycles = int(rng.integers(2, 40))
    frac = float(rng.uniform(0.1, 1.0))
    dwell = float(rng.uniform(0.2, 2.0))
    prog = iso_pose_program(robot, iso_poses, cycles=cycles, speed_frac=frac, dwell_s=dwell)
    r = render_rapid(prog)
    text = r.text
    lines = text.splitlines()
    assert r.main_file == "ISO_POSE.mod" and lines[0] == "MODULE ISO_POSE" and lines[-1] == "ENDMODULE"
    assert re.search(rf"FOR n_cycle FROM 1 TO {cycles} DO", text)
    # P2, P3, P4, P5, P1 in the loop body, each a fine linear move followed by the dwell
    body = text[text.index("FOR n_cycle") : text.index("ENDFOR")]
    moves = re.findall(r"MoveL p_(P\d), (v_\d), fine, tool0;", body)
    assert [p for p, _ in moves] == ["P2", "P3", "P4", "P5", "P1"]
    speed = moves[0][1]  # v_1 when the approach to P1 runs at the same speed (frac <= 0.2), else v_2
    assert all(v == speed for _, v in moves)
    assert body.count(f"WaitTime {dwell:.3f}".rstrip("0").rstrip(".")) == 5
    assert "SetGO go_cycle_count, n_cycle;" in body
    # speed: v_tcp is the fraction of the rated TCP speed
    v = re.search(rf"CONST speeddata {speed} := \[([0-9.]+),", text)
    assert float(v.group(1)) == pytest.approx(frac * robot.max_tcp_speed_mm_s, abs=1e-3)
    # every target written once with its position
    for name, xyz in iso_poses.items():
        m = re.search(rf"CONST robtarget p_{name} := \[\[([-0-9.,]+)\]", text)
        assert np.allclose([float(x) for x in m.group(1).split(",")], xyz)
    # the line map points at the instruction of each statement
    for s in r.program.statements:
        items = s.body if isinstance(s, Loop) else (s,)
        for ins in items:
            line = lines[ins.source_line - 1]
            if isinstance(ins, Move):
                assert f"p_{ins.target.name}," in line
            elif isinstance(ins, Dwell):
                assert line.strip().startswith("WaitTime")


def test_generated_rapid_compiles_back_to_the_same_program(rng, robot, iso_poses):
    """The fake's own RAPID parser reads the generator's text as the same motions."""
    names = list(iso_poses)
    sub = {n: iso_poses[n] for n in rng.choice(names, size=3, replace=False)}
    prog = vap_program(robot, sub, cycles=int(rng.integers(2, 9)), speed_frac=float(rng.uniform(0.2, 1.0)))
    r = render_rapid(prog)
    back = compile_rapid(r.text, robot).program
    assert back.accel_frac == pytest.approx(prog.accel_frac)

    def flat(p):
        out = []
        for s in p.statements:
            if isinstance(s, Loop):
                out.append(("loop", s.count, s.source_line))
                out += [_key(b) for b in s.body]
            else:
                out.append(_key(s))
        return out

    assert flat(back) == flat(r.program)
    # v_tcp is written with 3 decimals (mm/s)
    speeds = lambda p: [b.speed_frac for s in p.statements for b in getattr(s, "body", (s,)) if isinstance(b, Move)]  # noqa: E731
    assert np.allclose(speeds(back), speeds(r.program), atol=1e-3 / robot.max_tcp_speed_mm_s)


def _key(ins):
    if isinstance(ins, Move):
        t = ins.target
        pos = tuple(np.round(t.xyz_mm, 3)) if isinstance(t, CartesianTarget) else tuple(np.round(t.q_deg, 4))
        return ("move", ins.interpolation, pos, ins.source_line)
    if isinstance(ins, Dwell):
        return ("dwell", round(ins.seconds, 3), ins.source_line)
    return (type(ins).__name__, ins.source_line)


def test_expected_stops_and_vap_directions(rng, robot, iso_poses):
    cycles = int(rng.integers(2, 6))
    dist = float(rng.uniform(20, 150))
    dirs = tuple(rng.choice(["+", "-"]) + a for a in ("x", "y", "z"))
    sub = {n: iso_poses[n] for n in ("P1", "P2", "P4")}
    # with the default short dwell at each pre-point, every approach starts from rest there
    with_pre = expected_stops(vap_program(robot, sub, cycles=cycles, approach_mm=dist, directions=dirs))
    assert len(with_pre) == 2 * 3 * 3 * cycles
    assert all(s.target.name.startswith(tuple(sub)) and s.target.name not in sub for s in with_pre[0::2])
    prog = vap_program(robot, sub, cycles=cycles, approach_mm=dist, directions=dirs, pre_dwell_s=0.0)
    stops = expected_stops(prog)
    assert len(stops) == 3 * 3 * cycles
    assert [s.cycle for s in stops] == [c for c in range(1, cycles + 1) for _ in range(9)]
    for k, s in enumerate(stops):
        d = dirs[k % 3]
        axis = "xyz".index(d[1])
        step = np.subtract(s.target.xyz_mm, s.approach_from.xyz_mm)
        expect = np.zeros(3)
        expect[axis] = dist if d[0] == "+" else -dist
        assert np.allclose(step, expect)
        assert s.target.name == list(sub)[(k // 3) % 3]
    iso = expected_stops(iso_pose_program(robot, iso_poses, cycles=cycles))
    assert len(iso) == 1 + 5 * cycles
    assert [s.target.name for s in iso[:6]] == ["P1", "P2", "P3", "P4", "P5", "P1"]


def test_calibration_program_rapid_and_krl(rng, robot):
    n = int(rng.integers(3, 30))
    lo, hi = np.degrees(robot.joint_limits_rad).T
    q = rng.uniform(lo * 0.5, hi * 0.5, size=(n, 6))
    prog = calibration_program(robot, q, dwell_s=1.5)
    rapid = render_rapid(prog).text
    found = re.findall(r"CONST jointtarget j_Q(\d{4}) := \[\[([-0-9.,]+)\]", rapid)
    assert len(found) == n
    got = np.array([[float(x) for x in row.split(",")] for _, row in found])
    assert np.allclose(got, q, atol=5e-5)
    assert rapid.count("MoveAbsJ j_Q") == n
    krl = render_krl(prog)
    assert set(krl.files) == {"CALIB.src", "CALIB.dat"}
    axes = re.findall(r"DECL AXIS j_Q\d{4}=\{([^}]*)\}", krl.files["CALIB.dat"])
    vals = np.array([[float(p.split()[1]) for p in a.split(",")] for a in axes])
    assert np.allclose(vals, q, atol=5e-5)
    assert krl.files["CALIB.src"].count("PTP j_Q") == n


def test_krl_iso_cycle_and_abc_angles(rng, robot, iso_poses):
    frac = float(rng.uniform(0.1, 1.0))
    prog = iso_pose_program(robot, iso_poses, cycles=3, speed_frac=frac)
    k = render_krl(prog)
    src, dat = k.files["ISO_POSE.src"], k.files["ISO_POSE.dat"]
    assert "FOR n_cycle = 1 TO 3" in src and "ENDFOR" in src and src.rstrip().endswith("END")
    assert re.findall(r"LIN p_(P\d)", src) == ["P2", "P3", "P4", "P5", "P1"]
    v = float(re.search(r"\$VEL.CP = ([0-9.]+)", src).group(1))
    assert v == pytest.approx(frac * robot.max_tcp_speed_mm_s / 1000.0, abs=1e-4)  # m/s
    assert "SIGNAL CYCLE_COUNT $OUT[17] TO $OUT[32]" in dat
    lines = src.splitlines()
    for s in k.program.statements:
        for ins in s.body if isinstance(s, Loop) else (s,):
            if isinstance(ins, Move):
                assert lines[ins.source_line - 1].split()[-1] == f"p_{ins.target.name}"
    # KUKA A, B, C: R = Rz(A) Ry(B) Rx(C), for random orientations incl. near gimbal lock
    rots = Rotation.random(200, random_state=int(rng.integers(1 << 31)))
    mats = list(rots.as_matrix()) + [Rotation.from_euler("ZYX", [a, 90.0, c], degrees=True).as_matrix() for a, c in rng.uniform(-180, 180, (5, 2))]
    for m in mats:
        a, b, c = abc_deg_from_quat(quat_from_matrix(m))
        back = Rotation.from_euler("ZYX", [a, b, c], degrees=True).as_matrix()
        assert np.allclose(back, m, atol=1e-9)
        assert np.allclose(matrix_from_quat(quat_from_matrix(m)), m, atol=1e-12)


HOSTILE_NAMES = [
    "P1;\nMoveL p_X, v7000, fine, tool0",
    "P1 ",
    "P1!",
    "1P",
    "",
    "P1\r",
    "\u00c4P1",  # non-ASCII letter
    "P\u04401",  # Cyrillic lookalike
    "MODULE",
    "endproc",
    "EndFor",
    "DEF",
    "main",
    "P" * 21,
    'P1"',
    "P1\\Off",
]


@pytest.mark.parametrize("name", HOSTILE_NAMES)
def test_hostile_target_names_are_refused(robot, iso_poses, name):
    poses = dict(iso_poses)
    poses[name] = poses.pop("P3")
    with pytest.raises(ConfigError):
        iso_pose_program(robot, poses)


@pytest.mark.parametrize("name", HOSTILE_NAMES[:8] + ["ENDMODULE"])
def test_hostile_program_names_are_refused(robot, iso_poses, name):
    with pytest.raises(ConfigError):
        iso_pose_program(robot, iso_poses, name=name)


@pytest.mark.parametrize(
    "title",
    ["ok\nENDPROC", "ok\r\nMoveL p_P1, v7000, fine, tool0;", "tab\there", "nul\x00", "uml\u00e4ut", "x" * 81],
)
def test_hostile_titles_are_refused(robot, iso_poses, title):
    with pytest.raises(ConfigError):
        iso_pose_program(robot, iso_poses, title=title)


def test_quotes_and_backslashes_in_titles_stay_data(robot, iso_poses):
    """A title made to close the string and add code ends up as the exact string, nothing more."""
    title = '"; MoveL p_P1, v7000, z50, tool0; TPWrite "\\41" ! x'
    prog = iso_pose_program(robot, iso_poses, cycles=2, title=title)
    r = render_rapid(prog)
    compiled = compile_rapid(r.text, robot)
    assert compiled.messages == [title]
    assert _count_moves(compiled.program) == _count_moves(r.program)
    tpwrite = [t for t in tokenize(r.text) if t.kind == "string"]
    assert [unquote(t.text, t.line) for t in tpwrite] == [title]
    # the KRL header carries it as a comment only: one comment line, no new statements
    src = render_krl(prog).files["ISO_POSE.src"]
    assert [ln for ln in src.splitlines() if title in ln] == [f"  ; {title}"]


def _count_moves(program):
    n = 0
    for s in program.statements:
        for ins in s.body if isinstance(s, Loop) else (s,):
            n += isinstance(ins, Move)
    return n


@pytest.mark.parametrize(
    "bad",
    [float("nan"), float("inf"), -float("inf"), 1e12, "100", None, True, [1.0, 2.0]],
)
def test_bad_values_are_refused(robot, iso_poses, bad):
    poses = dict(iso_poses)
    poses["P2"] = (bad, 2200.0, 1900.0)
    with pytest.raises(ConfigError):
        iso_pose_program(robot, poses)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"cycles": 0},
        {"cycles": 10**6},
        {"cycles": 2.5},
        {"cycles": True},
        {"speed_frac": 0.0},
        {"speed_frac": 1.5},
        {"speed_frac": float("nan")},
        {"dwell_s": -0.1},
        {"accel_frac": 2.0},
        {"orientation": np.eye(3) * 2},
        {"orientation": (1.0, 1.0, 0.0, 0.0)},
    ],
)
def test_bad_program_parameters_are_refused(robot, iso_poses, kwargs):
    with pytest.raises(ConfigError):
        iso_pose_program(robot, iso_poses, **kwargs)


def test_same_name_two_targets_refused_case_insensitively(robot):
    a = CartesianTarget("Px", (0.0, 1700.0, 1400.0))
    b = CartesianTarget("PX", (0.0, 1700.0, 1500.0))
    with pytest.raises(ConfigError, match="two different targets"):
        Program("T", robot.name, 2000.0, (Move(a), Dwell(0.5), Move(b)))


def test_rapid_accel_below_20_percent_refused(robot, iso_poses):
    prog = iso_pose_program(robot, iso_poses, accel_frac=0.1)
    with pytest.raises(ConfigError, match="20 %"):
        render_rapid(prog)


def test_parser_reads_rapid_strings_exactly():
    m = parse_rapid('MODULE M\n PROC main()\n  TPWrite "a""b\\\\c\\41";\n ENDPROC\nENDMODULE\n')
    ins = m.procs["main"][0]
    assert ins.args[0].args[0] == 'a"b\\cA'


@pytest.mark.parametrize("render", ["rapid", "krl"])
@pytest.mark.parametrize("name", ["v_1", "V_1", "n_cycle", "N_CYCLE", "CYCLE_COUNT", "go_cycle_count", "main",
                                  "p_P1", "j_J1"])
def test_a_name_that_clashes_with_a_generated_identifier_is_refused(render, name):
    """Issue reproducer: program names like v_1 or n_cycle declared an identifier twice (controllers refuse)."""
    from station.programs.krl import CYCLE_SIGNAL as KRL_SIGNAL
    from station.programs.krl import render_krl
    from station.programs.program import CartesianTarget, JointTarget, Loop, Move, Program
    from station.programs.rapid import CYCLE_SIGNAL as RAPID_SIGNAL

    clashes = {"rapid": {"v_1", "n_cycle", RAPID_SIGNAL.lower(), "main", "p_p1", "j_j1"},
               "krl": {"n_cycle", KRL_SIGNAL.lower(), "p_p1", "j_j1"}}[render]
    statements = (Loop(2, (Move(CartesianTarget("P1", (500.0, 0.0, 800.0), (0.0, 0.0, 1.0, 0.0)), "joint", 0.5),
                           Move(JointTarget("J1", (0.0, -10.0, 10.0, 0.0, 20.0, 0.0)), "joint", 0.5))),)
    do = render_rapid if render == "rapid" else render_krl

    def build_and_render():
        return do(Program(name=name, robot_name="r", rated_tcp_speed_mm_s=1000.0, statements=statements,
                          accel_frac=0.5, rated_tcp_accel_mm_s2=5000.0))

    if name.lower() in clashes | {"main"}:  # 'main' is refused as a reserved word before rendering
        with pytest.raises(ConfigError, match=f"{name!r}.*(same identifier|reserved word)"):
            build_and_render()
    else:
        build_and_render()
