"""The fake's URScript subset: splitting the script stream and compiling programs."""

from __future__ import annotations

import math

import pytest

from fakes.urscript import Pose, ScriptError, ScriptSplitter, parse_program


def test_def_block_with_keywords_poses_and_comments():
    text = (
        "def station_move_7():  # header comment\n"
        "  write_output_integer_register(12, 7)\n"
        "  movej([0.1, -1.5, 1.2e0, -pi/2, -1.57, 0], a=1.4, v=1.05)\n"
        "  movel(p[0.3, -0.2, 0.4, 3.14, 0, 0], 1.2, 0.25, t=0, r=0.001)\n"
        '  textmsg("reached # not a comment")\n'
        "  write_output_integer_register(13, 7)\n"
        "end"
    )
    prog = parse_program(text)
    assert prog.name == "station_move_7"
    names = [c.name for c in prog.statements]
    assert names == ["write_output_integer_register", "movej", "movel", "textmsg", "write_output_integer_register"]
    movej = prog.statements[1]
    assert movej.args[0][3] == pytest.approx(-math.pi / 2) and movej.kwargs == {"a": 1.4, "v": 1.05}
    movel = prog.statements[2]
    assert isinstance(movel.args[0], Pose) and movel.args[0].values[0] == 0.3
    assert movel.args[1:] == (1.2, 0.25) and movel.kwargs == {"t": 0.0, "r": 0.001}
    assert prog.statements[3].args == ("reached # not a comment",)
    assert [c.line for c in prog.statements] == [2, 3, 4, 5, 6]


@pytest.mark.parametrize(
    "text, match",
    [
        ("servoj([0,0,0,0,0,0])", r"unsupported function servoj"),
        ("def p():\n  movej([0,0,0,0,0,0])\n  set_tcp(p[0,0,0.1,0,0,0])\nend", r"line 3: unsupported function set_tcp"),
        ("def p():\n  if True:\n    sleep(1)\n  end\nend", r"line 2: unsupported block statement 'if'"),
        ("def p():\n  x = 3\nend", r"line 2: unsupported statement 'x'"),
        ("movej([0,0,0,0,0])", r"6 joint angles"),
        ("movej([0,0,0,0,0,0], v=-1)", r"argument v must be a number >= 0"),
        ("movej([0,0,0,0,0,0], speed=1)", r"has no argument 'speed'"),
        ("movel(p[0,0,0,0,0])", r"needs 6 numbers"),
        ("write_output_integer_register(48, 1)", r"address 48 outside 0..47"),
        ("write_output_integer_register(3, 0.5)", r"32-bit integer"),
        ("movej(get_actual_joint_positions())", r"unsupported name 'get_actual_joint_positions'"),
        ("def p():\n  movej([0,0,0,0,0,0])\n", r"missing 'end'"),
        ("sec p():\n  sleep(1)\nend", r"unsupported program header"),
        ("sleep(1) sleep(2)", r"unexpected 'sleep'"),
    ],
)
def test_refusals_name_line_and_reason(text, match):
    with pytest.raises(ScriptError, match=match):
        parse_program(text)


def test_splitter_programs_across_chunk_boundaries():
    stream = (
        b"movej([0,0,0,0,0,0])\n\n"
        b"def a():\n  sleep(1)\n  # end of nothing\nend\n"
        b"stopj(2)\n"
        b"def b():\n  sleep(2)\nend\n"
    )
    for step in (1, 3, 7, len(stream)):
        sp = ScriptSplitter()
        out = []
        for i in range(0, len(stream), step):
            out += sp.feed(stream[i:i + step])
        assert [parse_program(t).name for t in out] == ["script", "a", "script", "b"], step
        assert [len(parse_program(t).statements) for t in out] == [1, 1, 1, 1]
        assert not sp.pending()


def test_splitter_counts_nested_blocks_so_the_compiler_refuses_them():
    sp = ScriptSplitter()
    out = sp.feed(b"def a():\n  while True:\n    sleep(1)\n  end\nend\n")
    assert len(out) == 1 and out[0].endswith("end\nend")
    with pytest.raises(ScriptError, match="line 2: unsupported block statement 'while'"):
        parse_program(out[0])


def test_splitter_bounds_its_buffer():
    sp = ScriptSplitter(max_bytes=100)
    with pytest.raises(ScriptError, match="longer than 100 bytes"):
        sp.feed(b"x" * 101)
    sp.feed(b"def a():\n")
    with pytest.raises(ScriptError, match="program longer than 100 bytes"):
        for _ in range(20):
            sp.feed(b"  sleep(1)\n")
    assert sp.feed(b"sleep(1)\n") == ["sleep(1)"]
