"""URScript as the UR fake understands it: the script port's framing and a parser.

The controller fake (:mod:`fakes.ur`) receives program text on the script
port; :class:`ScriptSplitter` cuts the byte stream into whole programs (a
``def name():`` block up to its ``end``, or one bare statement per line) and
:func:`parse_program` turns one into calls the interpreter runs (``movej``,
``movel``, ``speedj``, ``stopj``, ``sleep``, register writes, ...). What it
cannot run is refused with :class:`ScriptError`, naming the line, the way a
controller refuses a script that does not compile.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from station.errors import ProtocolError

MAX_SCRIPT_BYTES = 1 << 20


class ScriptError(ProtocolError):
    """A URScript program the fake cannot compile or run."""


@dataclass(frozen=True)
class Pose:
    """``p[x, y, z, rx, ry, rz]``: metres and an axis-angle rotation vector."""

    values: tuple


@dataclass(frozen=True)
class Call:
    """One statement: ``name(args, key=value)`` at ``line`` of its program."""

    name: str
    args: tuple
    kwargs: dict
    line: int


@dataclass(frozen=True)
class ScriptProgram:
    name: str
    statements: tuple
    text: str


_TOKEN = re.compile(
    r"\s*(?:(?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"
    r"|(?P<name>[A-Za-z_][A-Za-z_0-9]*)"
    r"|(?P<str>\"[^\"\\\n]*\")"
    r"|(?P<op>[\[\]\(\),=+\-*/]))"
)

_CONSTANTS = {"pi": math.pi, "True": True, "False": False}


def _tokenize(text: str, line: int) -> list[tuple[str, str]]:
    tokens, pos = [], 0
    text = text.rstrip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None or m.end() == pos:
            raise ScriptError(f"line {line}: cannot read {text[pos:pos + 20]!r}")
        kind = m.lastgroup
        tokens.append((kind, m.group(kind)))
        pos = m.end()
    return tokens


class _Parser:
    """Recursive descent over one statement: ``name(arg, ..., key=value)``."""

    def __init__(self, tokens, line):
        self.t, self.i, self.line = tokens, 0, line

    def peek(self):
        return self.t[self.i] if self.i < len(self.t) else (None, None)

    def take(self, value=None):
        tok = self.peek()
        if tok[0] is None or (value is not None and tok[1] != value):
            want = f"{value!r}" if value else "more input"
            raise ScriptError(f"line {self.line}: expected {want}, found {tok[1]!r}")
        self.i += 1
        return tok

    def statement(self) -> Call:
        kind, name = self.take()
        if kind != "name":
            raise ScriptError(f"line {self.line}: a statement must start with a function name, found {name!r}")
        if self.peek()[1] != "(":
            raise ScriptError(f"line {self.line}: unsupported statement {name!r} (only function calls)")
        self.take("(")
        args, kwargs = [], {}
        if self.peek()[1] != ")":
            while True:
                if self.peek()[0] == "name" and self.i + 1 < len(self.t) and self.t[self.i + 1][1] == "=":
                    key = self.take()[1]
                    self.take("=")
                    kwargs[key] = self.expr()
                else:
                    if kwargs:
                        raise ScriptError(f"line {self.line}: positional argument after keyword in {name}()")
                    args.append(self.expr())
                if self.peek()[1] == ",":
                    self.take(",")
                    continue
                break
        self.take(")")
        if self.peek()[0] is not None:
            raise ScriptError(f"line {self.line}: unexpected {self.peek()[1]!r} after {name}(...)")
        return Call(name, tuple(args), kwargs, self.line)

    def expr(self):
        val = self.term()
        while self.peek()[1] in ("+", "-"):
            op = self.take()[1]
            rhs = self.term()
            val = self._arith(val, rhs, op)
        return val

    def term(self):
        val = self.unary()
        while self.peek()[1] in ("*", "/"):
            op = self.take()[1]
            rhs = self.unary()
            val = self._arith(val, rhs, op)
        return val

    def _arith(self, a, b, op):
        if not (_is_number(a) and _is_number(b)):
            raise ScriptError(f"line {self.line}: arithmetic {op!r} needs numbers")
        if op == "/" and b == 0:
            raise ScriptError(f"line {self.line}: division by zero")
        return {"+": a + b, "-": a - b, "*": a * b, "/": a / b if op == "/" else 0}[op]

    def unary(self):
        if self.peek()[1] in ("-", "+"):
            op = self.take()[1]
            v = self.unary()
            if not _is_number(v):
                raise ScriptError(f"line {self.line}: unary {op!r} needs a number")
            return -v if op == "-" else v
        return self.atom()

    def atom(self):
        kind, val = self.take()
        if kind == "num":
            return float(val)
        if kind == "str":
            return val[1:-1]
        if val == "[":
            return self._list()
        if val == "(":
            v = self.expr()
            self.take(")")
            return v
        if kind == "name":
            if val == "p" and self.peek()[1] == "[":
                self.take("[")
                items = self._list()
                if len(items) != 6 or not all(_is_number(x) for x in items):
                    raise ScriptError(f"line {self.line}: a pose p[...] needs 6 numbers")
                return Pose(tuple(float(x) for x in items))
            if val in _CONSTANTS:
                return _CONSTANTS[val]
            raise ScriptError(f"line {self.line}: unsupported name {val!r} in an expression")
        raise ScriptError(f"line {self.line}: unexpected {val!r}")

    def _list(self):
        items = []
        if self.peek()[1] == "]":
            self.take("]")
            return items
        while True:
            items.append(self.expr())
            if self.peek()[1] == ",":
                self.take(",")
                continue
            self.take("]")
            return items


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


_DEF = re.compile(r"^def\s+([A-Za-z_][A-Za-z_0-9]*)\s*\(\s*\)\s*:\s*$")
_BLOCK_OPENERS = re.compile(r"^(def|sec|if|elif|else|while|for|thread)\b")


def _strip_comment(line: str) -> str:
    out, quoted = [], False
    for ch in line:
        if ch == '"':
            quoted = not quoted
        if ch == "#" and not quoted:
            break
        out.append(ch)
    return "".join(out).strip()


#: statement name -> (positional parameter names, required count)
_SIGNATURES = {
    "movej": (("q", "a", "v", "t", "r"), 1),
    "movel": (("pose", "a", "v", "t", "r"), 1),
    "movec": (("pose_via", "pose_to", "a", "v", "r", "mode"), 2),
    "stopj": (("a",), 1),
    "stopl": (("a",), 1),
    "sleep": (("t",), 1),
    "sync": ((), 0),
    "textmsg": (("s1", "s2"), 1),
    "write_output_integer_register": (("address", "value"), 2),
    "write_output_float_register": (("address", "value"), 2),
    "write_output_boolean_register": (("address", "value"), 2),
}


def bind_arguments(call: Call) -> dict:
    """Check a call against its signature; return ``{parameter: value}``."""
    if call.name not in _SIGNATURES:
        raise ScriptError(f"line {call.line}: unsupported function {call.name}()")
    params, required = _SIGNATURES[call.name]
    if len(call.args) > len(params):
        raise ScriptError(f"line {call.line}: {call.name}() takes at most {len(params)} arguments")
    bound = dict(zip(params, call.args))
    for k, v in call.kwargs.items():
        if k not in params:
            raise ScriptError(f"line {call.line}: {call.name}() has no argument {k!r}")
        if k in bound:
            raise ScriptError(f"line {call.line}: {call.name}() got {k!r} twice")
        bound[k] = v
    missing = [p for p in params[:required] if p not in bound]
    if missing:
        raise ScriptError(f"line {call.line}: {call.name}() needs {', '.join(missing)}")
    for k in ("a", "v", "t", "r"):
        if k in bound and not (_is_number(bound[k]) and math.isfinite(bound[k]) and bound[k] >= 0):
            raise ScriptError(f"line {call.line}: {call.name}() argument {k} must be a number >= 0")
    if call.name in ("movej", "movel"):
        target = bound["q" if call.name == "movej" else "pose"]
        if isinstance(target, Pose):
            pass
        elif isinstance(target, list) and len(target) == 6 and all(_is_number(x) for x in target):
            bound["q" if call.name == "movej" else "pose"] = [float(x) for x in target]
        else:
            raise ScriptError(f"line {call.line}: {call.name}() target must be 6 joint angles or a pose p[...]")
        vals = target.values if isinstance(target, Pose) else target
        if not all(math.isfinite(x) for x in vals):
            raise ScriptError(f"line {call.line}: {call.name}() target is not finite")
    if call.name == "movec":
        for k in ("pose_via", "pose_to"):
            if not (isinstance(bound[k], Pose) and all(math.isfinite(x) for x in bound[k].values)):
                raise ScriptError(f"line {call.line}: movec() {k} must be a finite pose p[...]")
        if bound.get("mode", 0) not in (0, 1):
            raise ScriptError(f"line {call.line}: movec() mode must be 0 (fixed orientation) or 1 (unconstrained)")
    if call.name == "sleep" and not (_is_number(bound["t"]) and bound["t"] >= 0 and math.isfinite(bound["t"])):
        raise ScriptError(f"line {call.line}: sleep() needs a time >= 0")
    if call.name.startswith("write_output_"):
        addr = bound["address"]
        if not (_is_number(addr) and float(addr).is_integer()):
            raise ScriptError(f"line {call.line}: {call.name}() address must be an integer")
        kind = call.name.split("_")[2]
        lo, hi = (64, 127) if kind == "boolean" else (0, 47)
        if not lo <= int(addr) <= hi:
            raise ScriptError(f"line {call.line}: {call.name}() address {int(addr)} outside {lo}..{hi}")
        val = bound["value"]
        if kind == "integer" and not (_is_number(val) and float(val).is_integer() and -2**31 <= val < 2**31):
            raise ScriptError(f"line {call.line}: {call.name}() value must be a 32-bit integer")
        if kind == "float" and not _is_number(val):
            raise ScriptError(f"line {call.line}: {call.name}() value must be a number")
        if kind == "boolean" and not isinstance(val, bool):
            raise ScriptError(f"line {call.line}: {call.name}() value must be True or False")
    return bound


def parse_program(text: str, default_name: str = "script") -> ScriptProgram:
    """Compile one program (a ``def`` block or a single statement line).

    Raises
    ------
    ScriptError
        Naming the line and what is not supported.
    """
    lines = text.split("\n")
    body = [(i + 1, _strip_comment(s)) for i, s in enumerate(lines)]
    body = [(n, s) for n, s in body if s]
    if not body:
        raise ScriptError("empty program")
    name = default_name
    m = _DEF.match(body[0][1])
    if m:
        name = m.group(1)
        if body[-1][1] != "end":
            raise ScriptError(f"program {name}: missing 'end'")
        body = body[1:-1]
    elif body[0][1].startswith(("def ", "sec ")):
        raise ScriptError(f"line {body[0][0]}: unsupported program header {body[0][1]!r} (only 'def name():')")
    statements = []
    for n, s in body:
        if _BLOCK_OPENERS.match(s) or s == "end":
            raise ScriptError(f"line {n}: unsupported block statement {s.split()[0]!r} (the fake runs straight-line programs)")
        call = _Parser(_tokenize(s, n), n).statement()
        bind_arguments(call)
        statements.append(call)
    return ScriptProgram(name, tuple(statements), text)


class ScriptSplitter:
    """Splits the script port's byte stream into whole programs.

    A ``def ...:`` line opens a block that the matching ``end`` closes (nested
    openers are counted so the compiler can refuse them by line); any other
    non-empty line outside a block is a program of its own.
    """

    def __init__(self, max_bytes: int = MAX_SCRIPT_BYTES) -> None:
        self._buf = b""
        self._block: list[str] | None = None
        self._depth = 0
        self._size = 0
        self.max_bytes = max_bytes

    def feed(self, data: bytes) -> list[str]:
        """Add bytes; return the programs completed by them (as text)."""
        self._buf += data
        if len(self._buf) > self.max_bytes:
            self._buf = b""
            self.reset()
            raise ScriptError(f"script line longer than {self.max_bytes} bytes")
        done: list[str] = []
        while b"\n" in self._buf:
            raw, self._buf = self._buf.split(b"\n", 1)
            line = raw.decode("utf-8", "replace").rstrip("\r")
            stripped = _strip_comment(line)
            if self._block is None:
                if not stripped:
                    continue
                if stripped.startswith(("def ", "sec ")):
                    self._block, self._depth, self._size = [line], 1, len(raw)
                else:
                    done.append(line)
                continue
            self._block.append(line)
            self._size += len(raw) + 1
            if self._size > self.max_bytes:
                self.reset()
                raise ScriptError(f"script program longer than {self.max_bytes} bytes")
            if _BLOCK_OPENERS.match(stripped) and not stripped.startswith(("elif", "else")):
                self._depth += 1
            elif stripped == "end":
                self._depth -= 1
                if self._depth == 0:
                    done.append("\n".join(self._block))
                    self._block = None
        return done

    def pending(self) -> bool:
        return self._block is not None

    def reset(self) -> None:
        self._block, self._depth, self._size = None, 0, 0


# ====================================================================== state
