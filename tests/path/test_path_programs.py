"""The ISO 9283 path programmes: what the generators write (RAPID, KRL, URScript), what the controller's own
parser reads back, and what the safety gate refuses."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from fakes.rapid_interp import RapidSafetyError, compile_rapid
from station.errors import ConfigError, SafetyError
from station.analysis.path.path_file import parse_paths
from station.models.robots import get_robot
from station.programs import render_krl, render_rapid
from station.programs.program import CartesianTarget, Loop, Move, Program
from station.programs.path_builders import PATH_KINDS, SPEED_FRACS, iso_path_tests
from station.programs.urscript import executed, render_urscript
from station.safety import SafetyGate, SafetyLimits, default_limits

CENTRE = (0.0, 1700.0, 1400.0)


@pytest.fixture(scope="module")
def robot():
    return get_robot("industrial-3100")


def _urscript(gate, robot, program) -> str:
    """The URScript of ``program``, its moves' joints gated one after another from home (every loop pass)."""
    qs, q = [], robot.home_q_rad
    for m in executed(program):
        if isinstance(m, Move):
            q = gate.check_move(m, q, program)[0]
            qs.append(q)
    return render_urscript(program, np.array(qs), robot=robot, seq=3).text


def _loop_moves(program):
    return [b for s in program.statements if isinstance(s, Loop) for b in s.body if isinstance(b, Move)]


def test_every_path_and_speed_is_a_programme_with_its_path_entry(robot, rng):
    side = float(rng.uniform(400.0, 700.0))
    blend = float(rng.uniform(5.0, 40.0))
    tests = iso_path_tests(robot, CENTRE, side, cycles=10, blend_mm=blend)
    assert [(t.kind, t.speed_frac) for t in tests] == [(k, f) for k in PATH_KINDS for f in SPEED_FRACS]
    specs = parse_paths({"paths": [t.path for t in tests]})  # the analysis reads every entry
    assert len({s.name for s in specs}) == len(tests)
    rated = robot.max_tcp_speed_mm_s
    for t in tests:
        moves = _loop_moves(t.program)
        assert all(m.speed_frac == t.speed_frac for m in moves)
        loop = next(s for s in t.program.statements if isinstance(s, Loop))
        assert loop.count == 10
        if t.kind == "rectangle_blend":
            assert [m.zone_mm for m in moves] == [blend, blend, blend, 0.0]
            assert t.path["blend_mm"] == blend
        if t.kind == "rectangle_fine":
            assert all(m.zone_mm == 0 for m in moves)
        if t.kind.startswith("circle"):
            d = 0.8 * side * (0.1 if t.kind == "circle_small" else 1.0)
            ends = np.array([moves[0].target.xyz_mm, moves[1].target.xyz_mm])
            assert np.linalg.norm(ends[0] - ends[1]) == pytest.approx(d, abs=2e-3)  # two half circles
            assert [m.interpolation for m in moves] == ["circular", "circular"]
        if "velocity_mm_s" in t.path:
            assert t.path["velocity_mm_s"] == pytest.approx(t.speed_frac * rated)
        # every target lies in the test plane through the centre (x and the (y + z) diagonal)
        for m in moves:
            p = np.asarray(m.target.xyz_mm) - CENTRE
            assert abs(p[1] - p[2]) < 1e-6 and np.all(np.abs(p) <= side / 2 + 1e-6)


def test_rapid_text_is_read_back_by_the_controller_with_zones_and_circles(robot, rng):
    blend = float(np.round(rng.uniform(5.0, 40.0), 3))
    gate = SafetyGate(robot, default_limits(robot))
    for t in iso_path_tests(robot, CENTRE, 600.0, cycles=3, speed_fracs=(0.5,), blend_mm=blend):
        rendered = render_rapid(t.program)
        text = rendered.text
        back = compile_rapid(text, robot, gate).program
        mine, theirs = _loop_moves(t.program), _loop_moves(back)
        assert [(m.interpolation, m.zone_mm, m.target.xyz_mm) for m in mine] == \
               [(m.interpolation, m.zone_mm, m.target.xyz_mm) for m in theirs]
        assert [m.via.xyz_mm for m in theirs if m.via] == [m.via.xyz_mm for m in mine if m.via]
        for m in theirs:
            assert m.speed_frac == pytest.approx(0.5)
        lines = text.splitlines()
        for m in back.statements[2].body:
            if isinstance(m, Move):
                assert lines[m.source_line - 1].strip().startswith(("MoveL", "MoveC"))
        if t.kind == "rectangle_blend":
            assert re.search(rf"CONST zonedata z_1 := \[FALSE,{blend:g},", text)
            assert text.count(", z_1, tool0;") == 3
        if t.kind.startswith("circle"):
            assert len(re.findall(r"^\s*MoveC p_\w+, p_\w+, v_\d, (z_1|fine), tool0;$", text, re.M)) == 2


def test_krl_and_urscript_blend_and_circle(robot, rng):
    blend = float(np.round(rng.uniform(5.0, 40.0), 3))
    gate = SafetyGate(robot, default_limits(robot))
    tests = {t.kind: t for t in iso_path_tests(robot, CENTRE, 600.0, cycles=2, speed_fracs=(0.1,), blend_mm=blend)}
    src = render_krl(tests["rectangle_blend"].program).text
    assert f"$APO.CDIS = {blend:g}" in src
    assert len(re.findall(r"^\s*LIN p_\w+ C_DIS$", src, re.M)) == 3
    assert len(re.findall(r"^\s*LIN p_\w+$", src, re.M)) == 1  # the last corner stops
    circ = render_krl(tests["circle_large"].program).text
    assert len(re.findall(r"^\s*CIRC p_\w+, p_\w+( C_DIS)?$", circ, re.M)) == 2
    for kind in ("rectangle_blend", "circle_small"):
        prog = tests[kind].program
        q, qs = robot.home_q_rad, []
        for m in executed(prog):
            if isinstance(m, Move):
                q = gate.check_move(m, q, prog)[0]
                qs.append(q)
        ur = render_urscript(prog, np.array(qs), robot=robot, seq=5).text
        if kind == "rectangle_blend":
            rs = [float(x) for x in re.findall(r"movel\(p\[[^\]]+\], a=[^,]+, v=[^,]+, r=([0-9.e-]+)\)", ur)]
            assert rs == pytest.approx([blend / 1000.0] * 3 * 2)  # three blended corners, two cycles
        else:
            calls = re.findall(r"movec\(p\[([^\]]+)\], p\[([^\]]+)\], a=[^,]+, v=([0-9.e-]+)", ur)
            assert len(calls) == 4
            via = np.array([float(x) for x in calls[0][0].split(",")[:3]]) * 1000.0
            m = _loop_moves(prog)[0]
            assert np.allclose(via, m.via.xyz_mm, atol=1e-6)
            assert float(calls[0][2]) == pytest.approx(0.1 * robot.max_tcp_speed_mm_s / 1000.0)


def test_the_gate_refuses_an_arc_outside_the_box_and_too_fast_a_path(robot):
    t = iso_path_tests(robot, CENTRE, 600.0, cycles=2, speed_fracs=(1.0,), kinds=("circle_large",))[0]
    start = t.program.statements[0].target
    # an arc from 30 to 150 degrees in the x-z plane: its top (90 degrees) is above its three points
    c, r = np.array(CENTRE), 200.0
    at = lambda deg: tuple(c + r * np.array([math.cos(math.radians(deg)), 0.0, math.sin(math.radians(deg))]))  # noqa
    a, via, b = (CartesianTarget(n, at(d), start.quat_wxyz) for n, d in (("A", 30), ("V", 60), ("B", 150)))
    prog = Program("ARC", robot.name, robot.max_tcp_speed_mm_s,
                   (Move(a, "joint", 0.2), Move(b, "circular", 0.5, via=via)))
    top = CENTRE[2] + r
    box = SafetyLimits(workspace_min_mm=(-1000, 1000, 1000), workspace_max_mm=(1000, 2300, top - 10.0),
                       max_tcp_speed_mm_s=robot.max_tcp_speed_mm_s)
    text = render_rapid(prog).text
    with pytest.raises(RapidSafetyError, match="arc leaves the workspace") as ei:
        compile_rapid(text, robot, SafetyGate(robot, box))
    assert text.splitlines()[ei.value.line - 1].strip().startswith("MoveC")
    roomy = SafetyLimits(workspace_min_mm=(-1000, 1000, 1000), workspace_max_mm=(1000, 2300, top + 10.0),
                         max_tcp_speed_mm_s=robot.max_tcp_speed_mm_s)
    compile_rapid(text, robot, SafetyGate(robot, roomy))  # the same arc with its top inside passes
    slow = SafetyLimits(workspace_min_mm=(-3000, -3000, -3000), workspace_max_mm=(3000, 3000, 3000),
                        max_tcp_speed_mm_s=0.5 * robot.max_tcp_speed_mm_s)
    with pytest.raises(SafetyError, match="speed"):
        SafetyGate(robot, slow).check_program(t.program)


def test_bad_path_parameters_are_refused_by_name(robot):
    with pytest.raises(ConfigError, match="kinds"):
        iso_path_tests(robot, CENTRE, 600.0, kinds=("spiral",))
    with pytest.raises(ConfigError, match="blend_mm"):
        iso_path_tests(robot, CENTRE, 600.0, blend_mm=0.0)
    with pytest.raises(ConfigError, match="zone_mm"):
        Move(iso_path_tests(robot, CENTRE, 600.0, kinds=("line",))[0].program.statements[0].target, "joint",
             0.5, zone_mm=5.0)
    assert math.isfinite(iso_path_tests(robot, CENTRE, 600.0, kinds=("line",))[0].path["tube_mm"])


def _weave_draw(rng) -> dict:
    return {"weave_amplitude_mm": round(float(rng.uniform(1.0, 3.0)), 3),
            "weave_frequency_Hz": round(float(rng.uniform(0.6, 1.5)), 3),
            "weave_speed_mm_s": round(float(rng.uniform(8.0, 15.0)), 2), "weave_periods": int(rng.integers(3, 9)),
            "weave_points_per_period": int(rng.choice([4, 8, 12]))}


def test_the_weave_is_a_sine_of_blended_vertices_in_every_dialect(robot, rng):
    wv = _weave_draw(rng)
    A, F, vb, periods, n = (wv[k] for k in ("weave_amplitude_mm", "weave_frequency_Hz", "weave_speed_mm_s",
                                            "weave_periods", "weave_points_per_period"))
    t = iso_path_tests(robot, CENTRE, 600.0, cycles=2, kinds=("weaving",), weave=wv)[0]
    spec = parse_paths({"paths": [t.path]})[0]
    g = spec.geometry
    assert (g.amplitude_mm, g.frequency_Hz) == (A, F)
    lam = vb / F
    assert g.length_mm == pytest.approx(periods * lam, abs=3e-3)
    moves = _loop_moves(t.program)
    # lead-in to vertex 0, the vertices, the lead-out, the way back
    assert len(moves) == periods * n + 3 and all(m.interpolation == "linear" for m in moves)
    assert len({m.speed_frac for m in moves}) == 1
    verts = np.array([m.target.xyz_mm for m in moves[:periods * n + 1]])
    along = (verts - g.base.start_mm) @ g.base.tangent_at(0.0)[0]
    across = (verts - g.base.start_mm) @ g.direction
    k = np.arange(verts.shape[0])
    assert np.allclose(along, k * lam / n, atol=3e-3)
    # the vertices lie on one sine across the base, a little wider than the commanded (the corners round it)
    peak = float(np.max(across))
    assert np.allclose(across, peak * np.sin(2 * np.pi * k / n), atol=2e-3)
    assert A < peak < 1.5 * A
    # every zone rounds its vertex within a third of its shorter segment (no controller shrinks it)
    seg = np.linalg.norm(np.diff(verts, axis=0), axis=1)
    zones = np.array([m.zone_mm for m in moves[:periods * n + 1]])
    assert np.all(zones[1:-1] > 0) and np.all(zones[1:-1] <= np.minimum(seg[:-1], seg[1:]) / 3 + 1e-9)
    assert moves[-2].zone_mm == 0 and moves[-1].zone_mm == 0  # the lead-out and the way back stop
    gate = SafetyGate(robot, default_limits(robot))
    gate.check_program(t.program)
    back = compile_rapid(render_rapid(t.program).text, robot, gate).program
    theirs = _loop_moves(back)
    assert [(m.zone_mm, m.target.xyz_mm) for m in theirs] == [(m.zone_mm, m.target.xyz_mm) for m in moves]
    # the text carries the speed to the micrometre a second
    assert theirs[0].speed_frac == pytest.approx(moves[0].speed_frac, abs=5e-4 / robot.max_tcp_speed_mm_s)
    krl = render_krl(t.program).text
    assert len(re.findall(r"^\s*LIN p_\w+ C_DIS$", krl, re.M)) == periods * n + 1
    v_krl = float(re.search(r"\$VEL.CP = ([0-9.]+)", krl).group(1)) * 1000.0  # m/s
    assert v_krl == pytest.approx(moves[0].speed_frac * robot.max_tcp_speed_mm_s, abs=6e-4)
    ur = _urscript(gate, robot, t.program)
    rs = [float(x) for x in re.findall(r"movel\(p\[[^\]]+\], a=[^,]+, v=[^,]+, r=([0-9.e-]+)\)", ur)]
    assert rs == pytest.approx(list(zones / 1000.0) * 2)


def test_the_reorientation_drives_the_line_while_the_tool_turns_about_x(robot, rng):
    turn = float(np.round(rng.uniform(5.0, 30.0), 2))
    frac = float(rng.choice(SPEED_FRACS))
    t = iso_path_tests(robot, CENTRE, 600.0, cycles=2, kinds=("reorientation",), speed_fracs=(frac,),
                       reorient_deg=turn)[0]
    line = iso_path_tests(robot, CENTRE, 600.0, cycles=2, kinds=("line",), speed_fracs=(frac,))[0]
    assert t.path["kind"] == "line" and "velocity_mm_s" not in t.path
    assert (t.path["start_mm"], t.path["end_mm"]) == (line.path["start_mm"], line.path["end_mm"])
    mid, end, start = _loop_moves(t.program)
    assert [m.target.xyz_mm for m in (mid, end, start)] == [m.target.xyz_mm for m in _loop_moves(line.program)]
    R = {k: m.target.pose[:3, :3] for k, m in (("A", start), ("M", mid), ("B", end))}
    for key, sign in (("A", -1), ("B", 1)):  # each end turned by the turn about the base x axis
        rel = R[key] @ R["M"].T
        c, s = math.cos(math.radians(sign * turn)), math.sin(math.radians(sign * turn))
        assert np.allclose(rel, [[1, 0, 0], [0, c, -s], [0, s, c]], atol=1e-6)
    gate = SafetyGate(robot, default_limits(robot))
    gate.check_program(t.program)
    back = _loop_moves(compile_rapid(render_rapid(t.program).text, robot, gate).program)
    assert np.allclose([m.target.quat_wxyz for m in back], [m.target.quat_wxyz for m in (mid, end, start)],
                       atol=1e-8)
    dat = next(v for k, v in render_krl(t.program).files.items() if k.endswith(".dat"))
    bs = [float(x) for x in re.findall(r"DECL POS p_O\w+=\{[^}]*,C ([-0-9.]+)\}", dat)]
    assert sorted(abs(abs(b) - 180.0) for b in bs) == pytest.approx([0.0, turn, turn], abs=1e-4)


def test_the_held_turn_turns_the_tool_about_its_point_at_the_programmed_turn_in_every_dialect(robot, rng):
    """The held turn's two moves keep the point and turn the tool about the base x axis; RAPID writes the turn's
    speed as v_ori, KRL as $VEL.ORI1/2, URScript as movel's v in rad/s; the controller's parser reads v_ori back;
    the gate passes it, and refuses a turn faster than its cap."""
    from dataclasses import replace

    from station.analysis.iso9283.orientation import abc_of_matrices
    from station.programs.program import rated_ori_speed_deg_s

    turn = float(np.round(rng.uniform(5.0, 30.0), 2))
    frac = float(rng.choice(SPEED_FRACS))
    t = iso_path_tests(robot, CENTRE, 600.0, cycles=2, kinds=("reorientation_held",), speed_fracs=(frac,),
                       reorient_deg=turn)[0]
    w = frac * rated_ori_speed_deg_s(robot)
    end, start = _loop_moves(t.program)
    assert start.target.xyz_mm == end.target.xyz_mm == tuple(t.path["point_mm"])
    assert (start.ori_speed_deg_s, end.ori_speed_deg_s) == (w, w)
    rel = end.target.pose[:3, :3] @ start.target.pose[:3, :3].T
    c, s = math.cos(math.radians(2 * turn)), math.sin(math.radians(2 * turn))
    assert np.allclose(rel, [[1, 0, 0], [0, c, -s], [0, s, c]], atol=1e-6)
    # the path file's angles are the targets' (R = Rz(c) Ry(b) Rx(a))
    for key, m in (("start_abc_deg", start), ("end_abc_deg", end)):
        assert np.allclose(t.path[key], np.degrees(abc_of_matrices(m.target.pose[:3, :3]))[0], atol=1e-6)
    spec = parse_paths({"paths": [t.path]})[0]
    assert spec.kind == "reorientation" and spec.geometry.length_mm == pytest.approx(2 * turn, abs=1e-6)
    gate = SafetyGate(robot, default_limits(robot))
    gate.check_program(t.program)
    rapid = render_rapid(t.program).text
    assert re.search(rf"speeddata v_\d := \[{frac * robot.max_tcp_speed_mm_s:g},{round(w, 3):g},", rapid), rapid
    back = _loop_moves(compile_rapid(rapid, robot, gate).program)
    assert [m.ori_speed_deg_s for m in back] == pytest.approx([w, w])
    src = next(v for k, v in render_krl(t.program).files.items() if k.endswith(".src"))
    assert [float(x) for x in re.findall(r"\$VEL\.ORI[12] = ([0-9.]+)", src)] == pytest.approx([w] * 2, abs=1e-3)
    ur = _urscript(gate, robot, t.program)
    vs = [float(x) for x in re.findall(r"movel\(p\[[^\]]+\], a=[^,]+, v=([0-9.e-]+)\)", ur)]
    assert vs == pytest.approx([math.radians(w)] * 4)  # two cycles of two turns, each v in rad/s
    # a gate capped at half the speed: the turn at the full speed is refused though its line speed is under the cap
    tight = SafetyGate(robot, default_limits(robot).model_copy(update={"max_speed_frac": 0.5 * frac}))
    q_start = tight.check_cartesian_target(start.target.pose, "start", q_seed=robot.home_q_rad)
    tight.check_move(replace(end, speed_frac=0.4 * frac, ori_speed_deg_s=0.4 * w), q_start, t.program)
    with pytest.raises(SafetyError, match="the tool's turn .* deg/s exceeds the cap"):
        tight.check_move(replace(end, speed_frac=0.4 * frac), q_start, t.program)


def test_bad_weave_and_reorientation_parameters_are_refused_by_name(robot):
    def build(**kw):
        return iso_path_tests(robot, CENTRE, 600.0, **kw)

    with pytest.raises(ConfigError, match="weave_amplitude_mm 5 at weave_frequency_Hz 3"):
        build(kinds=("weaving",), weave={"weave_amplitude_mm": 5.0, "weave_frequency_Hz": 3.0})
    with pytest.raises(ConfigError, match="weave_periods 200"):
        build(kinds=("weaving",), weave={"weave_periods": 200})
    with pytest.raises(ConfigError, match="unknown parameters \\['weave_amp'\\]"):
        build(kinds=("weaving",), weave={"weave_amp": 2.0})
    with pytest.raises(ConfigError, match="weave_points_per_period"):
        build(kinds=("weaving",), weave={"weave_points_per_period": 6})
    with pytest.raises(ConfigError, match="weave_frequency_Hz"):
        build(kinds=("weaving",), weave={"weave_frequency_Hz": -1.0})
    for bad in (0.0, 120.0):
        with pytest.raises(ConfigError, match="reorient_deg"):
            build(kinds=("reorientation",), reorient_deg=bad)
        with pytest.raises(ConfigError, match="reorient_deg"):
            build(kinds=("reorientation_held",), reorient_deg=bad)
