"""ABB RAPID generator for :class:`~station.programs.program.Program`.

Output: one module file ``<NAME>.mod`` holding the targets as ``CONST``
data, one ``speeddata`` per speed used and ``PROC main()``::

    MODULE ISO_P1P5
        CONST robtarget p_P1 := [[0,1700,1400],[1,0,0,0],[0,0,0,0],[9E+09,...]];
        CONST speeddata v_1 := [2300,500,5000,1000];
        PROC main()
            TPWrite "ISO 9283 P1..P5";
            ConfJ \\Off;
            ConfL \\Off;
            AccSet 100, 100;
            SetGO go_cycle_count, 0;
            MoveJ p_P1, v_1, fine, tool0;
            FOR n_cycle FROM 1 TO 30 DO
                MoveL p_P2, v_1, fine, tool0;
                WaitTime 0.5;
                ...
                SetGO go_cycle_count, n_cycle;
            ENDFOR
        ENDPROC
    ENDMODULE

Conventions the controller (and the station's fake) rely on:

* a move ends with ``fine`` (exact stop: ISO 9283 measures attained poses
  at rest) unless it has a corner zone (``zone_mm``), written as a
  ``zonedata`` ``z_1``, ``z_2`` ... of that radius (path tests: cornering);
  a circular move is ``MoveC via, to, ...``;
* ``ConfJ \\Off`` / ``ConfL \\Off``: the controller takes the joint solution
  closest to the current one, which is also what the safety gate assumes
  when it solves the inverse kinematics from the previous target;
* speed is ``speeddata`` whose ``v_tcp`` is ``speed_frac`` x the rated TCP
  speed and ``v_ori`` the move's ``ori_speed_deg_s`` (500 deg/s, RAPID's
  predefined speeds' value, when it has none); for joint moves the controller scales every joint's speed by the
  same fraction;
* ``AccSet`` takes the acceleration in percent (RAPID limits it to
  20..100 %, so a lower fraction is refused);
* the group output ``go_cycle_count`` (to be defined in the controller's I/O
  configuration and mapped to the Modbus cycle counter) carries the number of
  finished cycles.

Strings follow RAPID's rules: a ``"`` is written ``""`` and a ``\\`` is
written ``\\\\``; only printable ASCII reaches the text (validated in the
model), so no name, title or value from a config can close a string or a
comment and start code.
"""

from __future__ import annotations

from station.errors import ConfigError
from station.programs.program import (
    check_unique_identifiers,
    CartesianTarget,
    CycleMark,
    Dwell,
    JointTarget,
    Loop,
    Move,
    Program,
    RenderedProgram,
    check_text,
    iter_instructions,
    with_lines,
)

#: name of the group output that publishes the finished cycle count
CYCLE_SIGNAL = "go_cycle_count"
#: RAPID FOR loop counter
LOOP_COUNTER = "n_cycle"
#: speeddata's v_ori (the tool's turn, deg/s) of a move that programmes none: RAPID's predefined speeds' value
DEFAULT_V_ORI = 500.0
#: predefined RAPID external-axis value "not used"
NO_EAX = "9E+09"
INDENT = "    "


def fmt_num(x: float, decimals: int) -> str:
    """A RAPID/KRL number literal with at most ``decimals`` decimals."""
    s = f"{float(x):.{decimals}f}"
    if "." in s:
        s = s.rstrip("0").rstrip(".")
    if s in ("-0", ""):
        s = "0"
    return s


def rapid_string(text: str) -> str:
    """Quote ``text`` as a RAPID string literal (``"`` -> ``""``, ``\\`` -> ``\\\\``)."""
    check_text(text, "RAPID string")
    return '"' + text.replace("\\", "\\\\").replace('"', '""') + '"'


def rapid_comment(text: str) -> str:
    """A ``!`` comment; the text is printable ASCII without line breaks."""
    return "! " + check_text(text, "RAPID comment")


def robtarget_name(t: CartesianTarget) -> str:
    return "p_" + t.name


def jointtarget_name(t: JointTarget) -> str:
    return "j_" + t.name


def _robtarget(t: CartesianTarget) -> str:
    pos = ",".join(fmt_num(v, 3) for v in t.xyz_mm)
    rot = ",".join(fmt_num(v, 9) for v in t.quat_wxyz)
    eax = ",".join([NO_EAX] * 6)
    return f"CONST robtarget {robtarget_name(t)} := [[{pos}],[{rot}],[0,0,0,0],[{eax}]];"


def _jointtarget(t: JointTarget) -> str:
    q = ",".join(fmt_num(v, 4) for v in t.q_deg)
    eax = ",".join([NO_EAX] * 6)
    return f"CONST jointtarget {jointtarget_name(t)} := [[{q}],[{eax}]];"


def _speeds(program: Program) -> list[tuple[float, float | None]]:
    """Distinct ``(speed_frac, ori_speed_deg_s)`` of the program's moves, in first-use order (one speeddata each)."""
    out: list[tuple[float, float | None]] = []
    for ins in iter_instructions(program.statements):
        if isinstance(ins, Move) and (ins.speed_frac, ins.ori_speed_deg_s) not in out:
            out.append((ins.speed_frac, ins.ori_speed_deg_s))
    return out


def _speed_name(i: int) -> str:
    return f"v_{i + 1}"


def _zone_name(i: int) -> str:
    return f"z_{i + 1}"


def _zonedata(r_mm: float) -> str:
    """``zonedata`` of a blend radius: [finep, pzone_tcp, pzone_ori, pzone_eax, zone_ori, zone_leax, zone_reax]
    with the orientation and external-axis zones in the proportions of RAPID's predefined zones."""
    r = fmt_num(r_mm, 3)
    big, small = fmt_num(1.5 * r_mm, 3), fmt_num(0.15 * r_mm, 3)
    return f"[FALSE,{r},{big},{big},{small},{big},{small}]"


def render_rapid(program: Program) -> RenderedProgram:
    """Render ``program`` as an ABB RAPID module.

    Parameters
    ----------
    program : Program
        Validated program model.

    Returns
    -------
    RenderedProgram
        ``files == {"<NAME>.mod": text}``; ``program`` carries the line of
        every instruction (1-based) so the safety gate can name it.
    """
    if not isinstance(program, Program):
        raise ConfigError(f"render_rapid needs a Program, got {type(program).__name__}")
    if program.accel_frac < 0.2:
        raise ConfigError(
            f"program {program.name}: accel_frac {program.accel_frac:g} is below RAPID's AccSet minimum of 20 %"
        )
    speeds = _speeds(program)
    zones = program.zones_mm()
    check_unique_identifiers(program.name, [
        (program.name, "the module"), ("main", "the main routine"), (LOOP_COUNTER, "the loop counter"),
        (CYCLE_SIGNAL, "the cycle signal"),
        *[((robtarget_name(t) if isinstance(t, CartesianTarget) else jointtarget_name(t)), f"target {t.name}")
          for t in program.targets().values()],
        *[(_speed_name(i), "a speed") for i in range(len(speeds))],
        *[(_zone_name(i), "a zone") for i in range(len(zones))]])
    lines: list[str] = []
    stmt_lines: list[int] = []

    def emit(text: str, depth: int = 0) -> int:
        lines.append(INDENT * depth + text)
        return len(lines)

    emit(f"MODULE {program.name}")
    if program.title:
        emit(rapid_comment(program.title), 1)
    emit(rapid_comment(f"robot {program.robot_name}, rated TCP speed {fmt_num(program.rated_tcp_speed_mm_s, 1)} mm/s"), 1)
    emit(rapid_comment("generated by the robot metrology station; do not edit"), 1)
    for t in program.targets().values():
        if t.label:
            emit(rapid_comment(f"{t.name}: {t.label}"), 1)
        emit(_robtarget(t) if isinstance(t, CartesianTarget) else _jointtarget(t), 1)
    for i, (frac, ori) in enumerate(speeds):
        v_tcp = frac * program.rated_tcp_speed_mm_s
        turn = "" if ori is None else f", the tool's turn {fmt_num(ori, 3)} deg/s"
        emit(
            f"CONST speeddata {_speed_name(i)} := [{fmt_num(v_tcp, 3)},{fmt_num(DEFAULT_V_ORI if ori is None else ori, 3)},"
            f"5000,1000]; ! {fmt_num(frac * 100, 3)} % of rated speed{turn}",
            1,
        )
    for i, r in enumerate(zones):
        emit(f"CONST zonedata {_zone_name(i)} := {_zonedata(r)}; ! corner zone {fmt_num(r, 3)} mm", 1)
    emit("PROC main()", 1)
    if program.title:
        emit(f"TPWrite {rapid_string(program.title)};", 2)
    emit("ConfJ \\Off;", 2)
    emit("ConfL \\Off;", 2)
    emit(f"AccSet {fmt_num(program.accel_frac * 100, 3)}, 100;", 2)
    emit(f"SetGO {CYCLE_SIGNAL}, 0;", 2)

    def instruction(ins, depth: int, counter: str | None) -> int:
        if isinstance(ins, Move):
            speed = _speed_name(speeds.index((ins.speed_frac, ins.ori_speed_deg_s)))
            t = ins.target
            if isinstance(t, JointTarget):
                return emit(f"MoveAbsJ {jointtarget_name(t)}, {speed}, fine, tool0;", depth)
            zone = _zone_name(zones.index(ins.zone_mm)) if ins.zone_mm > 0 else "fine"
            if ins.interpolation == "circular":
                return emit(f"MoveC {robtarget_name(ins.via)}, {robtarget_name(t)}, {speed}, {zone}, tool0;", depth)
            op = "MoveL" if ins.interpolation == "linear" else "MoveJ"
            return emit(f"{op} {robtarget_name(t)}, {speed}, {zone}, tool0;", depth)
        if isinstance(ins, Dwell):
            return emit(f"WaitTime {fmt_num(ins.seconds, 3)};", depth)
        if isinstance(ins, CycleMark):
            return emit(f"SetGO {CYCLE_SIGNAL}, {counter if counter else 1};", depth)
        raise ConfigError(f"RAPID: cannot render {type(ins).__name__}")

    for s in program.statements:
        if isinstance(s, Loop):
            stmt_lines.append(emit(f"FOR {LOOP_COUNTER} FROM 1 TO {s.count} DO", 2))
            for b in s.body:
                stmt_lines.append(instruction(b, 3, LOOP_COUNTER))
            emit("ENDFOR", 2)
        else:
            stmt_lines.append(instruction(s, 2, None))
    emit("ENDPROC", 1)
    emit("ENDMODULE")
    text = "\n".join(lines) + "\n"
    file_name = f"{program.name}.mod"
    return RenderedProgram("rapid", {file_name: text}, file_name, with_lines(program, stmt_lines))
