"""Interpreter of the ABB RAPID subset the station generates, on the simulated arm.

The controller fake (:mod:`fakes.controller`) loads an uploaded ``.mod`` file
with :func:`compile_rapid`, which tokenises and parses the text on its own
(it does not reuse the station's generator), checks it against the
controller's safety gate and turns it into the dialect-neutral
:class:`~station.programs.program.Program` with the line of every
instruction; :class:`RapidRun` then executes that program on
``world.arm``.

Subset understood (anything else is a :class:`RapidError` naming the line)::

    MODULE name [(SYSMODULE, NOSTEPIN, ...)]
      [LOCAL] CONST|VAR|PERS robtarget|jointtarget|speeddata|num name := value;
      PROC main()
        MoveJ  robtarget, speed, fine, tool0 [\\WObj:=wobj0];
        MoveL  robtarget, speed, zone, tool0 [\\WObj:=wobj0];
        MoveC  robtarget, robtarget, speed, zone, tool0 [\\WObj:=wobj0];
        MoveAbsJ jointtarget, speed, fine, tool0;
        WaitTime seconds;
        AccSet acc_percent, ramp_percent;
        ConfJ \\Off;   ConfL \\Off;
        SetGO go_cycle_count, 0 | loop counter;
        TPWrite "text";
        FOR i FROM 1 TO n DO ... ENDFOR      (one level, constant bounds)
      ENDPROC
    ENDMODULE

Targets may be named data or inline aggregates; speeds may be named
``speeddata``, the predefined ``v5`` ... ``v7000`` or ``vmax``; zones
``fine``, the predefined ``z0`` ... ``z200`` or ``zonedata`` (its TCP radius
rounds the corner; only ``MoveL``/``MoveC`` blend). A run of blended moves
is interpolated as one path (:mod:`station.models.cartesian_path`). Only
``tool0``/``wobj0`` are supported. Strings follow RAPID: ``""`` is a quote, ``\\\\`` a backslash,
``\\hh`` a character code; comments run from ``!`` to the end of the line.
"""

from __future__ import annotations

import math
import re
import threading
import zlib
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from fakes.sim import path_follow
from station.errors import ConfigError, DataError, SafetyError, StationError
from station.programs.builders import rated_tcp_accel_mm_s2
from station.programs.rapid import DEFAULT_V_ORI
from station.programs.program import (
    CartesianTarget,
    CycleMark,
    Dwell,
    JointTarget,
    Loop,
    MAX_ORI_SPEED_DEG_S,
    MAX_ZONE_MM,
    Move,
    Program,
    check_name,
)

#: the controller's interpolation tick, s: a program starts on a multiple of it
IPO_TICK_S = 0.02
#: largest program file the fake accepts, bytes
MAX_PROGRAM_BYTES = 1 << 20
#: group output mapped to the Modbus cycle counter
CYCLE_SIGNAL = "go_cycle_count"

_TOKEN_RE = re.compile(
    r"""
     (?P<ws>[ \t\r\f]+)
    |(?P<nl>\n)
    |(?P<comment>![^\n]*)
    |(?P<string>"(?:[^"\\\n]|""|\\\\|\\[0-9A-Fa-f]{2})*")
    |(?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)
    |(?P<ident>[A-Za-z][A-Za-z0-9_]*)
    |(?P<op>:=|[;,\[\]()\\:+\-*/])
    """,
    re.VERBOSE | re.ASCII,
)
_PREDEFINED_SPEEDS = {f"v{n}" for n in (5, 10, 20, 30, 40, 50, 60, 80, 100, 150, 200, 300, 400, 500, 600, 800, 1000, 1500, 2000, 2500, 3000, 4000, 5000, 6000, 7000)}
#: RAPID's predefined zones: name -> TCP zone radius, mm
_PREDEFINED_ZONES = {f"z{n}": float(n) for n in (0, 1, 5, 10, 15, 20, 30, 40, 50, 60, 80, 100, 150, 200)}
_KEYWORDS = {"module", "endmodule", "proc", "endproc", "for", "from", "to", "step", "do", "endfor", "const", "var", "pers", "local"}


class RapidError(StationError, ValueError):
    """The program text is not valid in the supported subset; ``line`` names where."""

    def __init__(self, line: int, message: str) -> None:
        super().__init__(f"line {line}: {message}")
        self.line = line


class RapidSafetyError(SafetyError):
    """The controller's safety gate refused the program; ``line`` names where."""

    def __init__(self, line: int, message: str) -> None:
        super().__init__(message)
        self.line = line


@dataclass
class _Tok:
    kind: str
    text: str
    line: int


def tokenize(text: str) -> list[_Tok]:
    """RAPID tokens with their 1-based line numbers (comments dropped)."""
    out: list[_Tok] = []
    line = 1
    pos = 0
    n = len(text)
    while pos < n:
        m = _TOKEN_RE.match(text, pos)
        if m is None:
            raise RapidError(line, f"unexpected character {text[pos]!r}")
        kind = m.lastgroup
        if kind == "nl":
            line += 1
        elif kind not in ("ws", "comment"):
            out.append(_Tok(kind, m.group(), line))
        pos = m.end()
    out.append(_Tok("eof", "", line))
    return out


def unquote(tok: str, line: int) -> str:
    """Value of a RAPID string literal token."""
    body = tok[1:-1]
    out: list[str] = []
    i = 0
    while i < len(body):
        c = body[i]
        if c == '"':  # the tokenizer only lets "" through
            out.append('"')
            i += 2
        elif c == "\\":
            if body[i + 1] == "\\":
                out.append("\\")
                i += 2
            else:
                out.append(chr(int(body[i + 1 : i + 3], 16)))
                i += 3
        else:
            out.append(c)
            i += 1
    s = "".join(out)
    if len(s) > 80:
        raise RapidError(line, f"string of {len(s)} characters (RAPID strings hold at most 80)")
    return s


# ---------------------------------------------------------------------- syntax tree
@dataclass
class Expr:
    """Expression node: ("num", value) | ("id", name) | ("str", s) | ("neg", e) | (op, a, b) | ("agg", [..])."""

    kind: str
    args: tuple
    line: int


@dataclass
class Instr:
    name: str
    args: list[Expr]
    switches: dict[str, Expr | None]
    line: int


@dataclass
class ForLoop:
    var: str
    start: Expr
    stop: Expr
    step: Expr | None
    body: list
    line: int


@dataclass
class Decl:
    storage: str
    type: str
    name: str
    value: Expr | None
    line: int


@dataclass
class Module:
    name: str
    decls: dict[str, Decl]
    procs: dict[str, list]
    proc_lines: dict[str, int]


class _Parser:
    def __init__(self, toks: list[_Tok]) -> None:
        self.toks = toks
        self.i = 0

    @property
    def tok(self) -> _Tok:
        return self.toks[self.i]

    def next(self) -> _Tok:
        t = self.toks[self.i]
        self.i += 1
        return t

    def is_kw(self, word: str) -> bool:
        return self.tok.kind == "ident" and self.tok.text.lower() == word

    def expect_kw(self, word: str) -> _Tok:
        if not self.is_kw(word):
            raise RapidError(self.tok.line, f"expected {word.upper()}, found {self.tok.text or 'end of file'!r}")
        return self.next()

    def expect_op(self, op: str) -> _Tok:
        if not (self.tok.kind == "op" and self.tok.text == op):
            raise RapidError(self.tok.line, f"expected {op!r}, found {self.tok.text or 'end of file'!r}")
        return self.next()

    def ident(self) -> str:
        t = self.tok
        if t.kind != "ident" or t.text.lower() in _KEYWORDS:
            raise RapidError(t.line, f"expected a name, found {t.text or 'end of file'!r}")
        if len(t.text) > 32:
            raise RapidError(t.line, f"name {t.text[:40]!r} is longer than 32 characters")
        self.next()
        return t.text

    # -- module
    def module(self) -> Module:
        self.expect_kw("module")
        name = self.ident()
        if self.tok.kind == "op" and self.tok.text == "(":
            self.next()
            while not (self.tok.kind == "op" and self.tok.text == ")"):
                if self.tok.kind == "eof":
                    raise RapidError(self.tok.line, "unterminated module attribute list")
                self.next()
            self.next()
        decls: dict[str, Decl] = {}
        procs: dict[str, list] = {}
        proc_lines: dict[str, int] = {}
        while not self.is_kw("endmodule"):
            t = self.tok
            if t.kind == "eof":
                raise RapidError(t.line, "missing ENDMODULE")
            if self.is_kw("proc"):
                line = self.next().line
                pname = self.ident()
                self.expect_op("(")
                self.expect_op(")")
                body = self.block(("endproc",))
                self.expect_kw("endproc")
                if pname.lower() in {p.lower() for p in procs}:
                    raise RapidError(line, f"procedure {pname} defined twice")
                procs[pname] = body
                proc_lines[pname] = line
            else:
                d = self.decl()
                if d.name.lower() in {k.lower() for k in decls}:
                    raise RapidError(d.line, f"{d.name} declared twice")
                decls[d.name] = d
        self.next()
        if self.tok.kind != "eof":
            raise RapidError(self.tok.line, f"text after ENDMODULE: {self.tok.text!r}")
        return Module(name, decls, procs, proc_lines)

    def decl(self) -> Decl:
        line = self.tok.line
        if self.is_kw("local"):
            self.next()
        if not (self.is_kw("const") or self.is_kw("var") or self.is_kw("pers")):
            raise RapidError(line, f"expected a declaration or PROC, found {self.tok.text!r}")
        storage = self.next().text.upper()
        dtype = self.ident().lower()
        name = self.ident()
        value = None
        if self.tok.kind == "op" and self.tok.text == ":=":
            self.next()
            value = self.value()
        elif storage == "CONST":
            raise RapidError(line, f"CONST {name} needs a value")
        self.expect_op(";")
        return Decl(storage, dtype, name, value, line)

    # -- statements
    def block(self, enders: tuple[str, ...]) -> list:
        out: list = []
        while not any(self.is_kw(e) for e in enders):
            if self.tok.kind == "eof":
                raise RapidError(self.tok.line, f"missing {enders[0].upper()}")
            out.append(self.statement())
        return out

    def statement(self):
        t = self.tok
        if self.is_kw("for"):
            self.next()
            var = self.ident()
            self.expect_kw("from")
            start = self.expr()
            self.expect_kw("to")
            stop = self.expr()
            step = None
            if self.is_kw("step"):
                self.next()
                step = self.expr()
            self.expect_kw("do")
            body = self.block(("endfor",))
            self.expect_kw("endfor")
            return ForLoop(var, start, stop, step, body, t.line)
        if t.kind != "ident" or t.text.lower() in _KEYWORDS:
            raise RapidError(t.line, f"expected an instruction, found {t.text or 'end of file'!r}")
        name = self.next().text
        args: list[Expr] = []
        switches: dict[str, Expr | None] = {}
        while not (self.tok.kind == "op" and self.tok.text == ";"):
            if self.tok.kind == "eof":
                raise RapidError(t.line, f"{name}: missing ';'")
            if self.tok.kind == "op" and self.tok.text == "\\":
                self.next()
                sw = self.ident()
                val = None
                if self.tok.kind == "op" and self.tok.text == ":=":
                    self.next()
                    val = self.value()
                switches[sw.lower()] = val
                continue
            if args or switches:
                self.expect_op(",")
                if self.tok.kind == "op" and self.tok.text == "\\":
                    continue
            args.append(self.value())
        self.next()
        return Instr(name, args, switches, t.line)

    # -- values
    def value(self) -> Expr:
        if self.tok.kind == "op" and self.tok.text == "[":
            line = self.next().line
            items = [self.value()]
            while self.tok.kind == "op" and self.tok.text == ",":
                self.next()
                items.append(self.value())
            self.expect_op("]")
            return Expr("agg", tuple(items), line)
        return self.expr()

    def expr(self) -> Expr:
        left = self.term()
        while self.tok.kind == "op" and self.tok.text in "+-":
            op = self.next()
            left = Expr(op.text, (left, self.term()), op.line)
        return left

    def term(self) -> Expr:
        left = self.factor()
        while self.tok.kind == "op" and self.tok.text in "*/":
            op = self.next()
            left = Expr(op.text, (left, self.factor()), op.line)
        return left

    def factor(self) -> Expr:
        t = self.tok
        if t.kind == "num":
            self.next()
            return Expr("num", (float(t.text),), t.line)
        if t.kind == "string":
            self.next()
            return Expr("str", (unquote(t.text, t.line),), t.line)
        if t.kind == "op" and t.text == "-":
            self.next()
            return Expr("neg", (self.factor(),), t.line)
        if t.kind == "op" and t.text == "+":
            self.next()
            return self.factor()
        if t.kind == "op" and t.text == "(":
            self.next()
            e = self.expr()
            self.expect_op(")")
            return e
        if t.kind == "ident" and t.text.lower() not in _KEYWORDS:
            self.next()
            return Expr("id", (t.text,), t.line)
        raise RapidError(t.line, f"expected a value, found {t.text or 'end of file'!r}")


def parse_rapid(text: str) -> Module:
    """Parse a RAPID module (syntax only)."""
    return _Parser(tokenize(text)).module()


# ---------------------------------------------------------------------- semantics
@dataclass
class CompiledProgram:
    """A RAPID module turned into a gated, executable program.

    Attributes
    ----------
    program : Program
        Neutral model with ``source_line`` = line in the RAPID text.
    messages : list of str
        ``TPWrite`` texts, in order.
    """

    program: Program
    messages: list[str] = field(default_factory=list)


class _Compiler:
    def __init__(self, module: Module, robot) -> None:
        self.m = module
        self.robot = robot
        self.rated = float(robot.max_tcp_speed_mm_s)
        self.decls = {k.lower(): v for k, v in module.decls.items()}
        self.accel_frac: float | None = None
        self.messages: list[str] = []
        self._targets: dict[tuple, object] = {}

    # values
    def num(self, e: Expr, env: dict[str, float] | None = None) -> float:
        k = e.kind
        if k == "num":
            return e.args[0]
        if k == "neg":
            return -self.num(e.args[0], env)
        if k in "+-*/" and len(e.args) == 2:
            a, b = self.num(e.args[0], env), self.num(e.args[1], env)
            if k == "/" and b == 0:
                raise RapidError(e.line, "division by zero")
            return {"+": a + b, "-": a - b, "*": a * b, "/": a / b if b else 0.0}[k]
        if k == "id":
            name = e.args[0].lower()
            if env and name in env:
                return env[name]
            d = self.decls.get(name)
            if d is None:
                raise RapidError(e.line, f"unknown name {e.args[0]}")
            if d.type != "num" or d.value is None:
                raise RapidError(e.line, f"{e.args[0]} is a {d.type}, a num is needed here")
            return self.num(d.value)
        raise RapidError(e.line, "a number is needed here")

    def agg(self, e: Expr, shape: tuple, what: str) -> list:
        """Nested aggregate of numbers with the given shape, e.g. (3, 4, 4, 6)."""
        if e.kind == "id":
            d = self.decls.get(e.args[0].lower())
            if d is None:
                raise RapidError(e.line, f"unknown {what} {e.args[0]}")
            if d.type != what or d.value is None:
                raise RapidError(e.line, f"{e.args[0]} is a {d.type}, a {what} is needed here")
            return self.agg(d.value, shape, what)
        if e.kind != "agg" or len(e.args) != len(shape):
            raise RapidError(e.line, f"{what} must be an aggregate of {len(shape)} parts")
        out = []
        for part, n in zip(e.args, shape):
            if part.kind != "agg" or len(part.args) != n:
                raise RapidError(part.line, f"{what}: a part must hold {n} numbers")
            vals = [self.num(v) for v in part.args]
            if not all(math.isfinite(v) for v in vals):
                raise RapidError(part.line, f"{what}: non-finite number")
            out.append(vals)
        return out

    def speed(self, e: Expr, line: int) -> tuple[float, float]:
        """``(v_tcp mm/s, v_ori deg/s)`` of a speed argument (the predefined speeds turn at 500 deg/s)."""
        if e.kind == "id":
            name = e.args[0].lower()
            if name not in self.decls:
                if name in _PREDEFINED_SPEEDS:
                    return float(name[1:]), DEFAULT_V_ORI
                if name == "vmax":
                    return self.rated, DEFAULT_V_ORI
        if e.kind == "id" or e.kind == "agg":
            d = self.decls.get(e.args[0].lower()) if e.kind == "id" else None
            if e.kind == "agg" or (d is not None and d.type == "speeddata"):
                v = self.agg_flat(e, 4, "speeddata")
                if v[0] <= 0:
                    raise RapidError(line, f"speeddata v_tcp {v[0]:g} must be > 0")
                if not 0 < v[1] <= MAX_ORI_SPEED_DEG_S:
                    raise RapidError(line, f"speeddata v_ori {v[1]:g} deg/s must be in (0, {MAX_ORI_SPEED_DEG_S:g}]")
                return v[0], v[1]
        raise RapidError(line, "speed argument must be speeddata")

    def agg_flat(self, e: Expr, n: int, what: str) -> list[float]:
        if e.kind == "id":
            d = self.decls.get(e.args[0].lower())
            if d is None or d.type != what or d.value is None:
                raise RapidError(e.line, f"{e.args[0]} is not a {what}")
            e = d.value
        if e.kind != "agg" or len(e.args) != n:
            raise RapidError(e.line, f"{what} must hold {n} numbers")
        return [self.num(v) for v in e.args]

    def target_name(self, e: Expr, prefix: str, line: int) -> str:
        if e.kind == "id":
            try:
                return check_name(e.args[0], "target")
            except ConfigError:
                pass
        return f"{prefix}{line}"

    # instructions
    def zone(self, e: Expr, line: int, name: str) -> float:
        """Blend radius of a zone argument, mm (0: ``fine``)."""
        if e.kind == "id":
            z = e.args[0].lower()
            if z == "fine":
                return 0.0
            if z not in self.decls and z in _PREDEFINED_ZONES:
                return _PREDEFINED_ZONES[z]
            d = self.decls.get(z)
            if d is None or d.type != "zonedata":
                raise RapidError(line, f"{name}: unknown zone {e.args[0]} (fine, z0 ... z200 or a zonedata)")
        elif e.kind != "agg":
            raise RapidError(line, f"{name}: the zone must be fine, a predefined zone or zonedata")
        if e.kind == "id":
            e = self.decls[e.args[0].lower()].value
        if e is None or e.kind != "agg" or len(e.args) != 7:
            raise RapidError(line, f"{name}: zonedata must hold [finep, pzone_tcp, ...] (7 values)")
        finep = e.args[0]
        if finep.kind != "id" or finep.args[0].lower() not in ("true", "false"):
            raise RapidError(line, f"{name}: zonedata's finep must be TRUE or FALSE")
        if finep.args[0].lower() == "true":
            return 0.0
        r = self.num(e.args[1])
        if not 0 <= r <= MAX_ZONE_MM:
            raise RapidError(line, f"{name}: zone radius {r:g} mm is outside [0, {MAX_ZONE_MM:g}]")
        return r

    def move(self, ins: Instr) -> Move:
        op = ins.name.lower()
        n_args = 5 if op == "movec" else 4
        if len(ins.args) != n_args:
            raise RapidError(ins.line, f"{ins.name} takes {'circle point, ' if op == 'movec' else ''}target, speed, "
                                       "zone, tool")
        via_e = ins.args[0] if op == "movec" else None
        target_e, speed_e, zone_e, tool_e = ins.args[-4:]
        zone_mm = self.zone(zone_e, ins.line, ins.name)
        if zone_mm > 0 and op not in ("movel", "movec"):
            raise RapidError(ins.line, f"{ins.name}: only MoveL and MoveC blend; use fine")
        if tool_e.kind != "id" or tool_e.args[0].lower() != "tool0":
            raise RapidError(ins.line, f"{ins.name}: only tool0 is supported")
        for sw, val in ins.switches.items():
            if sw != "wobj" or val is None or val.kind != "id" or val.args[0].lower() != "wobj0":
                raise RapidError(ins.line, f"{ins.name}: optional argument \\{sw} is not supported (only \\WObj:=wobj0)")
        v, v_ori = self.speed(speed_e, ins.line)
        frac = v / self.rated
        if frac > 1.0 + 1e-9:
            raise RapidSafetyError(
                ins.line, f"line {ins.line}: {ins.name} speed {v:g} mm/s exceeds the rated {self.rated:g} mm/s"
            )
        frac = min(frac, 1.0)
        label = target_e.args[0] if target_e.kind == "id" else f"inline target line {ins.line}"
        via = None
        if via_e is not None:
            try:
                pos, rot, _conf, _eax = self.agg(via_e, (3, 4, 4, 6), "robtarget")
                via = CartesianTarget(self.target_name(via_e, "C", ins.line), tuple(pos), tuple(rot),
                                      label=via_e.args[0] if via_e.kind == "id" else f"circle point line {ins.line}")
            except ConfigError as exc:
                raise RapidError(ins.line, str(exc)) from None
            key = ("p", via.xyz_mm, via.quat_wxyz)
            if self._targets.setdefault(via.name.lower(), key) != key:
                via = replace(via, name=f"C{ins.line}")
        try:
            if op == "moveabsj":
                (q, _eax) = self.agg(target_e, (6, 6), "jointtarget")
                key = ("j", tuple(q))
                target = JointTarget(self.target_name(target_e, "J", ins.line), tuple(q), label=label)
            else:
                pos, rot, _conf, _eax = self.agg(target_e, (3, 4, 4, 6), "robtarget")
                target = CartesianTarget(self.target_name(target_e, "T", ins.line), tuple(pos), tuple(rot), label=label)
                key = ("p", target.xyz_mm, target.quat_wxyz)
        except ConfigError as exc:
            raise RapidError(ins.line, str(exc)) from None
        # one name per distinct target (a name reused for other data gets the line)
        prev = self._targets.setdefault(target.name.lower(), key)
        if prev != key:
            target = replace(target, name=f"L{ins.line}")
        interp = {"movel": "linear", "movec": "circular"}.get(op, "joint")
        # the model's None is the dialect's default turn (what the generator writes for it)
        ori = v_ori if interp == "linear" and v_ori != DEFAULT_V_ORI else None
        try:
            return Move(target, interp, frac, source_line=ins.line, zone_mm=zone_mm, via=via, ori_speed_deg_s=ori)
        except ConfigError as exc:
            raise RapidError(ins.line, str(exc)) from None

    def instruction(self, ins: Instr, loop_var: str | None, top: bool):
        op = ins.name.lower()
        if op in ("movej", "movel", "movec", "moveabsj"):
            return self.move(ins)
        if op == "waittime":
            if len(ins.args) != 1 or ins.switches:
                raise RapidError(ins.line, "WaitTime takes one number")
            t = self.num(ins.args[0])
            if not 0 <= t <= 3600:
                raise RapidError(ins.line, f"WaitTime {t:g} s is outside [0, 3600]")
            return Dwell(t, source_line=ins.line)
        if op == "accset":
            if len(ins.args) != 2:
                raise RapidError(ins.line, "AccSet takes acceleration and ramp, in percent")
            acc, ramp = self.num(ins.args[0]), self.num(ins.args[1])
            if not (0 < acc <= 100 and 0 < ramp <= 100):
                raise RapidError(ins.line, f"AccSet {acc:g}, {ramp:g}: values must be in (0, 100] %")
            # RAPID takes values below 20 % as 20 %; the gate checks the highest in the program
            frac = max(acc, 20.0) / 100.0
            self.accel_frac = frac if self.accel_frac is None else max(self.accel_frac, frac)
            return None
        if op in ("confj", "confl"):
            if ins.args or set(ins.switches) != {"off"}:
                raise RapidError(ins.line, f"{ins.name}: only \\Off is supported")
            return None
        if op == "setgo":
            if len(ins.args) != 2 or ins.args[0].kind != "id" or ins.args[0].args[0].lower() != CYCLE_SIGNAL:
                raise RapidError(ins.line, f"SetGO: only the signal {CYCLE_SIGNAL} is configured")
            val = ins.args[1]
            if loop_var and val.kind == "id" and val.args[0].lower() == loop_var:
                return CycleMark(source_line=ins.line)
            n = self.num(val)
            if n == 0 and loop_var is None:
                return None  # reset at start: the controller zeroes the counter anyway
            if n == 1 and loop_var is None:
                return CycleMark(source_line=ins.line)
            raise RapidError(ins.line, f"SetGO {CYCLE_SIGNAL}: value must be the loop counter (or 0/1 outside a loop)")
        if op == "tpwrite":
            if len(ins.args) != 1 or ins.args[0].kind != "str":
                raise RapidError(ins.line, "TPWrite takes one string")
            self.messages.append(ins.args[0].args[0])
            return None
        raise RapidError(ins.line, f"instruction {ins.name} is not supported by this controller")

    def compile(self) -> CompiledProgram:
        procs = {k.lower(): v for k, v in self.m.procs.items()}
        if "main" not in procs:
            raise RapidError(1, "no PROC main()")
        for d in self.m.decls.values():
            if d.type not in ("robtarget", "jointtarget", "speeddata", "zonedata", "num"):
                raise RapidError(d.line, f"data type {d.type} is not supported")
        self.accel_frac = None
        statements: list = []
        for st in procs["main"]:
            if isinstance(st, ForLoop):
                if st.step is not None:
                    raise RapidError(st.line, "FOR ... STEP is not supported")
                a, b = self.num(st.start), self.num(st.stop)
                if a != 1 or b != int(b) or not 1 <= b <= 10000:
                    raise RapidError(st.line, "FOR must run FROM 1 TO a constant count in 1..10000")
                body = []
                for inner in st.body:
                    if isinstance(inner, ForLoop):
                        raise RapidError(inner.line, "nested FOR loops are not supported")
                    x = self.instruction(inner, st.var.lower(), False)
                    if x is not None:
                        body.append(x)
                if not body:
                    raise RapidError(st.line, "empty FOR loop")
                statements.append(Loop(int(b), tuple(body), source_line=st.line))
            else:
                x = self.instruction(st, None, True)
                if x is not None:
                    statements.append(x)
        if not any(isinstance(s, Move) or isinstance(s, Loop) for s in statements):
            raise RapidError(self.m.proc_lines.get("main", 1), "PROC main() has no motion")
        try:
            program = Program(
                name=check_name(self.m.name, "module") if len(self.m.name) <= 20 else "MODULE",
                robot_name=self.robot.name,
                rated_tcp_speed_mm_s=self.rated,
                statements=tuple(statements),
                accel_frac=self.accel_frac or 1.0,
                title=(self.messages[0] if self.messages else "")[:80],
                rated_tcp_accel_mm_s2=rated_tcp_accel_mm_s2(self.robot),
            )
        except ConfigError as exc:
            raise RapidError(1, str(exc)) from None
        return CompiledProgram(program, self.messages)


def compile_rapid(text: str | bytes, robot, gate=None, q_start=None) -> CompiledProgram:
    """Parse, check and compile a RAPID module for ``robot``.

    Parameters
    ----------
    text : str or bytes
        Module text (bytes must be ASCII).
    robot : RobotSpec
    gate : SafetyGate, optional
        The controller's own gate; when given the program must pass it.
    q_start : array_like, shape (6,), optional
        Joints the program starts from (for the gate).

    Raises
    ------
    RapidError
        Syntax or unsupported construct (``.line``).
    RapidSafetyError
        The gate refused the program (``.line`` is the offending line).
    """
    if isinstance(text, bytes):
        if len(text) > MAX_PROGRAM_BYTES:
            raise RapidError(1, f"program of {len(text)} bytes is larger than {MAX_PROGRAM_BYTES}")
        try:
            text = text.decode("ascii")
        except UnicodeDecodeError as exc:
            line = text[: exc.start].count(b"\n") + 1
            raise RapidError(line, f"byte 0x{text[exc.start]:02x} is not ASCII") from None
    compiled = _Compiler(parse_rapid(text), robot).compile()
    if gate is not None:
        try:
            gate.check_program(compiled.program, q_start=q_start)
        except SafetyError as exc:
            m = re.match(r"line (\d+)", str(exc))
            raise RapidSafetyError(int(m.group(1)) if m else 0, str(exc)) from exc
    return compiled


# ---------------------------------------------------------------------- execution
class ProgramStopped(Exception):
    """Internal: the interpreted program was stopped (command, fault or watchdog); not the station's RunAborted."""


@dataclass
class RunProgress:
    """What the run reports to the controller (written under its lock)."""

    line: int = 0
    cycle_count: int = 0
    moves_done: int = 0


class RapidRun:
    """Executes a compiled program on ``world.arm``.

    The run keeps one instruction queued ahead of the arm (like a
    controller's look-ahead): while move ``k`` executes, move ``k + 1`` (or
    the dwell after it) is planned and queued to start exactly when ``k``
    ends, so dwell times and stops are exact at any clock speed. Progress
    (line, finished moves, cycle count) is reported when an instruction
    *finishes* on the arm's clock, and a stop or fault lands inside the
    current move like on a controller.

    Parameters
    ----------
    world : World
        Supplies ``clock``, ``robot`` and ``arm``.
    compiled : CompiledProgram
    gate : SafetyGate
        Solves each Cartesian joint move's IK from the commanded joints.
    on_progress : callable(RunProgress)
        Called whenever the progress changes.
    fault_at_move : dict, optional
        ``{"protective_stop": n, "emergency_stop": m}``: halt in the middle
        of the n-th move (1-based, counted over the run).
    on_fault : callable(kind, line)
        Called when an injected fault halts the arm.
    run_no : int
        How many times the controller has started a program of this name (1 first).
    """

    def __init__(
        self,
        world,
        compiled: CompiledProgram,
        gate,
        on_progress: Callable[[RunProgress], None],
        *,
        fault_at_move: dict[str, int] | None = None,
        on_fault: Callable[[str, int], None] | None = None,
        run_no: int = 1,
    ) -> None:
        self.world = world
        # every move names itself to the arm (program, run of that program, cycle, instruction), so its
        # stopping error is the same in any world of the seed: a resumed run meets the same stops
        self._key = (zlib.crc32(compiled.program.name.encode()), int(run_no))
        self.arm = world.arm
        self.clock = world.clock
        self.program = compiled.program
        self.gate = gate
        self.on_progress = on_progress
        self.fault_at_move = dict(fault_at_move or {})
        self.on_fault = on_fault
        self.stop_event = threading.Event()
        self.progress = RunProgress()
        rated_acc = self.program.rated_tcp_accel_mm_s2 or rated_tcp_accel_mm_s2(world.robot)
        self._accel_mm_s2 = self.program.accel_frac * rated_acc
        self._queued_moves = 0
        #: instructions queued on the arm ahead of the one executing
        self.lookahead = 4

    def request_stop(self) -> None:
        self.stop_event.set()

    def _q_queue_end(self) -> np.ndarray:
        """Commanded joints at the end of the arm's queue (where the next move starts)."""
        moves = self.arm.moves
        if moves:
            return np.asarray(moves[-1].q_target_rad, dtype=float).reshape(6)
        return np.asarray(self.arm.commanded_q_rad(self.clock.now()), dtype=float).reshape(6)

    def _queue(self, ins, key=None) -> float:
        """Queue ``ins`` on the arm; return the simulated time it ends."""
        if isinstance(ins, Dwell) and ins.seconds > 0:
            self._t_last = float(self.arm.dwell(ins.seconds).t_end)
            return self._t_last
        if isinstance(ins, path_follow.Run):
            for m in ins.moves:
                self.gate.check_cartesian_target(m.target.pose, self.gate.describe(m), q_seed=self._q_queue_end())
            try:
                mv = path_follow.queue_run(self.arm, self.world.robot, ins,
                                           rated_tcp_speed_mm_s=self.program.rated_tcp_speed_mm_s,
                                           accel_mm_s2=self._accel_mm_s2,
                                           ripple=path_follow.ripple_of(self.world.seed, key), noise_key=key)
            except DataError as exc:
                raise SafetyError(f"{self.gate.describe(ins.moves[0])}: {exc}") from exc
            first = self._queued_moves + 1
            self._queued_moves += len(ins.moves)
            for kind, at in self.fault_at_move.items():
                if first <= at <= self._queued_moves:
                    self._fault_mid[at] = (kind, 0.5 * (float(mv.t_start) + float(mv.t_end)))
            self._t_last = self.arm.in_position_s()
            if self._t_last > mv.t_end:
                self.arm.dwell(self._t_last - float(mv.t_end), kind="settle")
            return self._t_last
        if not isinstance(ins, Move):
            return self._t_last  # instant: done when everything before it is
        t = ins.target
        label = self.gate.describe(ins)
        if isinstance(t, JointTarget):
            q = self.gate.check_joint_target(t.q_rad, label)
            mv = self.arm.move_joint(q, speed_frac=ins.speed_frac, accel_frac=self.program.accel_frac,
                                     noise_key=key)
        elif ins.interpolation == "joint":
            q = self.gate.check_cartesian_target(t.pose, label, q_seed=self._q_queue_end())
            mv = self.arm.move_joint(q, speed_frac=ins.speed_frac, accel_frac=self.program.accel_frac,
                                     noise_key=key)
        else:
            self.gate.check_cartesian_target(t.pose, label, q_seed=self._q_queue_end())
            # the tool turns at the speeddata's v_ori (a move that only turns: its point held)
            mv = self.arm.move_linear(
                t.pose, speed_mm_s=ins.speed_frac * self.program.rated_tcp_speed_mm_s, accel_mm_s2=self._accel_mm_s2,
                noise_key=key, orientation_speed_rad_s=math.radians(ins.ori_speed_deg_s or DEFAULT_V_ORI),
            )
        self._queued_moves += 1
        for kind, at in self.fault_at_move.items():
            if at == self._queued_moves:
                self._fault_mid[self._queued_moves] = (kind, 0.5 * (float(mv.t_start) + float(mv.t_end)))
        # a fine stop point: the program goes on when the arm is in position, not when its command arrived
        self._t_last = self.arm.in_position_s()  # never before the move's end
        if self._t_last > mv.t_end:
            self.arm.dwell(self._t_last - float(mv.t_end), kind="settle")
        return self._t_last

    def _finish(self, ins, t_end: float, cycle: int) -> None:
        """Wait until ``ins`` has ended on the arm, then report it."""
        n_moves = len(ins.moves) if isinstance(ins, path_follow.Run) else int(isinstance(ins, Move))
        if isinstance(ins, path_follow.Run):
            self.progress.line = ins.moves[-1].source_line or 0
            self.on_progress(self.progress)
        if isinstance(ins, (Move, Dwell)):
            self.progress.line = ins.source_line or 0
            self.on_progress(self.progress)
        done = self.progress.moves_done
        fault = next((self._fault_mid[k] for k in range(done + 1, done + n_moves + 1) if k in self._fault_mid), None)
        if fault is not None:
            kind, t_mid = fault
            if not self.clock.sleep_until(t_mid, self.stop_event):
                raise ProgramStopped()
            if kind == "emergency_stop" and hasattr(self.arm, "emergency_stop"):
                self.arm.emergency_stop()
            else:
                self.arm.protective_stop()
            if self.on_fault is not None:
                self.on_fault(kind, ins.source_line or 0)
            raise ProgramStopped()
        if not self.clock.sleep_until(t_end, self.stop_event) or self.stop_event.is_set():
            raise ProgramStopped()
        if n_moves:
            self.progress.moves_done += n_moves
        elif isinstance(ins, CycleMark):
            self.progress.cycle_count = cycle if cycle else 1
            self.progress.line = ins.source_line or 0
        self.on_progress(self.progress)

    def _stream(self):
        items = self._instructions()
        return path_follow.group_runs(items) if path_follow.is_path_program(self.program) else items

    def _instructions(self):
        for s in self.program.statements:
            if isinstance(s, Loop):
                for c in range(1, s.count + 1):
                    for b in s.body:
                        yield b, c
            else:
                yield s, 0

    def run(self) -> None:
        """Execute to the end; raises ProgramStopped when stopped, SafetyError on a refused move."""
        # the program starts on the controller's next interpolation tick: on a tracker's sample grid too
        # (20 ms is a whole number of 1, 2, 4, 5, 10 or 20 ms sample periods), so the stream samples
        # every run of a program at the same phase of its motion, whenever it starts
        t0 = math.ceil(float(self.clock.now()) / IPO_TICK_S - 1e-9) * IPO_TICK_S
        if not self.clock.sleep_until(t0, self.stop_event):
            raise ProgramStopped()
        self._t_last = float(self.clock.now())
        self._fault_mid: dict[int, tuple[str, float]] = {}
        pending: deque = deque()  # queued on the arm, not yet finished
        for index, item in enumerate(self._stream()):
            if self.stop_event.is_set():
                raise ProgramStopped()
            n_faults = len(self._fault_mid)
            pending.append((item[0], self._queue(item[0], (*self._key, item[1], index)), item[1]))
            # an injected fault move is queued: stop planning ahead so that nothing
            # delays the wait for the middle of that move
            limit = 0 if len(self._fault_mid) > n_faults else self.lookahead
            while len(pending) > limit:
                self._finish(*pending.popleft())
        while pending:
            self._finish(*pending.popleft())
