"""The fake controller's RAPID interpreter: parsing, refusals that name the line."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.rapid_interp import RapidError, RapidSafetyError, compile_rapid
from station.programs import JointTarget, Loop, Move

EAX = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"
DOWN = "[0,1,0,0]"  # tool pointing down (w, x, y, z)


def module(body: str, decls: str = "") -> str:
    """A handwritten module; ``body`` lines start at line 4 + the number of decl lines."""
    return f"MODULE HAND\n  ! handwritten\n{decls}  PROC main()\n{body}  ENDPROC\nENDMODULE\n"


def robtarget(name: str, xyz) -> str:
    return f"  CONST robtarget {name} := [[{xyz[0]},{xyz[1]},{xyz[2]}],{DOWN},[0,0,0,0],{EAX}];\n"


def test_handwritten_program_compiles(robot, gate):
    decls = robtarget("pA", (0, 1700, 1400)) + robtarget("pB", (300, 1500, 1200))
    body = (
        "    AccSet 50, 100;\n"
        "    MoveJ pA, v500, fine, tool0;\n"
        "    FOR i FROM 1 TO 4 DO\n"
        "      MoveL pB, [800,500,5000,1000], fine, tool0 \\WObj:=wobj0;\n"
        "      WaitTime 0.25;\n"
        "      MoveL pA, vmax, fine, tool0;\n"
        "      WaitTime 0.5 * 2;\n"
        "      SetGO go_cycle_count, i;\n"
        "    ENDFOR\n"
        "    MoveAbsJ [[90,0,10,0,80,90],[9E9,9E9,9E9,9E9,9E9,9E9]], v100, fine, tool0;\n"
    )
    text = module(body, decls)
    c = compile_rapid(text, robot, gate)
    p = c.program
    assert p.accel_frac == pytest.approx(0.5)
    first, loop, last = p.statements
    assert isinstance(first, Move) and first.interpolation == "joint" and first.source_line == 7
    assert first.speed_frac == pytest.approx(500 / robot.max_tcp_speed_mm_s)
    assert isinstance(loop, Loop) and loop.count == 4 and loop.source_line == 8
    kinds = [(type(b).__name__, b.source_line) for b in loop.body]
    assert kinds == [("Move", 9), ("Dwell", 10), ("Move", 11), ("Dwell", 12), ("CycleMark", 13)]
    assert loop.body[0].speed_frac == pytest.approx(800 / robot.max_tcp_speed_mm_s)
    assert loop.body[2].speed_frac == pytest.approx(1.0)
    assert loop.body[3].seconds == pytest.approx(1.0)
    assert isinstance(last.target, JointTarget) and np.allclose(last.target.q_deg, [90, 0, 10, 0, 80, 90])


@pytest.mark.parametrize(
    "body, line, match",
    [
        ("    MoveL pA, v500, fine, tool0\n    WaitTime 1;\n", 6, "expected ','"),
        ("    MoveL pA, v500, z7, tool0;\n", 5, "unknown zone z7"),
        ("    MoveJ pA, v500, z10, tool0;\n", 5, "only MoveL and MoveC blend"),
        ("    MoveL pA, v500, fine, tool1;\n", 5, "only tool0"),
        ("    MoveL pB, v500, fine, tool0;\n", 5, "unknown robtarget pB"),
        ("    Stop;\n", 5, "Stop is not supported"),
        ("    WaitTime -1;\n", 5, "outside"),
        ("    TPWrite \"" + "x" * 81 + "\";\n", 5, "at most 80"),
        ("    FOR i FROM 1 TO 3 DO\n      FOR j FROM 1 TO 2 DO\n      ENDFOR\n    ENDFOR\n", 6, "nested FOR"),
        ("    FOR i FROM 0 TO 3 DO\n      WaitTime 1;\n    ENDFOR\n", 5, "FROM 1 TO"),
        ("    SetGO do_other, 1;\n", 5, "only the signal go_cycle_count"),
        ("    MoveL pA, v500, fine, tool0 \\Conc;\n", 5, "not supported"),
        ("    MoveL pA, v500, fine, tool0; @\n", 5, "unexpected character"),
        ("    ConfL \\On;\n", 5, "only \\\\Off"),
    ],
)
def test_errors_name_the_line(robot, body, line, match):
    text = module(body, robtarget("pA", (0, 1700, 1400)))
    with pytest.raises(RapidError, match=match) as ei:
        compile_rapid(text, robot)
    assert ei.value.line == line
    assert str(ei.value).startswith(f"line {line}:")


def test_non_ascii_and_structure_errors(robot):
    with pytest.raises(RapidError) as ei:
        compile_rapid(module("    WaitTime 1;\n").encode() + b"! \xe4\n", robot)
    assert ei.value.line == 7
    with pytest.raises(RapidError, match="no PROC main"):
        compile_rapid("MODULE X\n PROC other()\n  WaitTime 1;\n ENDPROC\nENDMODULE\n", robot)
    with pytest.raises(RapidError, match="missing ENDMODULE"):
        compile_rapid("MODULE X\n PROC main()\n  WaitTime 1;\n ENDPROC\n", robot)
    with pytest.raises(RapidError, match="has no motion"):
        compile_rapid(module("    WaitTime 1;\n"), robot)


def test_unsafe_programs_are_refused_with_their_line(rng, robot, gate):
    x_out = float(gate.box_max[0] + rng.uniform(10, 300))
    decls = robtarget("pA", (0, 1700, 1400)) + robtarget("pOut", (x_out, 1700, 1400))
    body = "    MoveJ pA, v200, fine, tool0;\n    FOR i FROM 1 TO 2 DO\n      WaitTime 0.5;\n      MoveL pOut, v200, fine, tool0;\n    ENDFOR\n"
    with pytest.raises(RapidSafetyError, match="outside the workspace box") as ei:
        compile_rapid(module(body, decls), robot, gate)
    assert ei.value.line == 9
    # a speed over the rated one is refused by the interpreter itself
    too_fast = f"    MoveL pA, [{robot.max_tcp_speed_mm_s * 1.5:g},500,5000,1000], fine, tool0;\n"
    with pytest.raises(RapidSafetyError, match="exceeds the rated") as ei:
        compile_rapid(module(too_fast, decls), robot, gate)
    assert ei.value.line == 6
    # a quaternion that is not a unit quaternion is a program error
    bad = "  CONST robtarget pQ := [[0,1700,1400],[1,1,0,0],[0,0,0,0]," + EAX + "];\n"
    with pytest.raises(RapidError, match="not 1") as ei:
        compile_rapid(module("    MoveL pQ, v100, fine, tool0;\n", bad), robot, gate)
    assert ei.value.line == 5
