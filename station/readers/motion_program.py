"""A lab's motion program: poses, order, moves, dwell, cycles, payload, tracker rate (TOML or JSON).

``station simulate iso9283 --program FILE`` replays it on the simulated cell
(:mod:`fakes.sim.program_run`); ``station diagnose motion --program FILE``
reads the same file for what the recording's clock is checked against (its
dwell and, when stated, its rate). The grammar (also in the README's file
formats section), TOML shown; the JSON form has the same keys::

    robot = "ur5e"              # optional: the robot model (else --robot)
    rate_hz = 333.333           # tracker rate, 10-3000 Hz (default 1000)
    cycles = 3                  # times the order is run, 1-100 (default 3)
    dwell_s = 2.0               # dwell after every move, 0-60 s (default 0.5)
    wait_s = 2.0                # wait at the start pose while recording, 0-600 s (default 4)
    payload_kg = 0.0            # mass at the tool, 0 to the robot's rated payload (default 0)
    speed_pct = 100             # the controller's speed override, 1-100 %: speeds x f, accelerations x f^2,
                                # so every move keeps its shape and takes 1/f the time (default 100)
    start = "P1"                # pose the arm waits at before the first move (default: the order's last)
    order = ["P2", "P1"]        # one cycle: pose names, or tables {to = "P2", type = "linear", speed = 250}

    [move]                      # defaults of every move of the order
    type = "joint"              # joint | linear
    speed = 60.0                # deg/s of the leading joint (joint) or mm/s of the tool (linear)
    acceleration = 80.0         # deg/s^2 or mm/s^2
    profile = "trapezoid"       # trapezoid | s-curve

    [poses.P1]
    joints_deg = [0, -90, 90, -90, -90, 0]
    [poses.P2]
    xyz_mm = [400.0, 100.0, 300.0]   # base frame; the tool's orientation is the one nominal IK finds for the
                                     # first Cartesian pose from the home pose (as the ISO run's)

Without ``speed`` / ``acceleration`` / ``profile`` a move takes the robot's
controller defaults (:func:`fakes.sim.program_run.move_defaults`: a UR's
``movej`` 60 deg/s, 80 deg/s^2, ``movel`` 250 mm/s, 1200 mm/s^2, trapezoid;
another arm's rated speed, S-curve). Every key is checked: a missing,
unknown, mistyped or out-of-range one is refused with
:class:`~station.errors.ConfigError` naming the file and the key (exit 2),
before anything is simulated.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass
from numbers import Integral, Real
from pathlib import Path

from station.errors import ConfigError
from station.numeric import short_repr
from station.readers.text import read_small_text
from station.tracker_rates import TRACKER_RATE_RANGE_HZ

__all__ = ["MotionProgram", "ProgramMove", "read_motion_program", "parse_motion_program", "MOVE_TYPES",
           "PROGRAM_PROFILES", "MAX_PROGRAM_BYTES"]

MOVE_TYPES = ("joint", "linear")
#: profile names of the file -> the motion model's (station.models.motion.PROFILE_KINDS)
PROGRAM_PROFILES = {"trapezoid": "trapezoid", "s-curve": "scurve"}
#: largest program file read, bytes
MAX_PROGRAM_BYTES = 1 << 20
#: most poses and most moves in one cycle
MAX_POSES = 100
MAX_ORDER = 200
MAX_CYCLES = 100
MAX_DWELL_S = 60.0
MAX_WAIT_S = 600.0
#: bounds of the speeds and accelerations a file may state (the robot's own limits are checked at replay)
MAX_JOINT_SPEED_DEG_S = 1000.0
MAX_JOINT_ACCEL_DEG_S2 = 100_000.0
MAX_TCP_SPEED_MM_S = 10_000.0
MAX_TCP_ACCEL_MM_S2 = 1_000_000.0
MAX_ABS_POSITION_MM = 100_000.0
MAX_ABS_JOINT_DEG = 720.0
MAX_PAYLOAD_KG = 10_000.0

_TOP_KEYS = ("robot", "rate_hz", "cycles", "dwell_s", "wait_s", "payload_kg", "speed_pct", "start", "order", "move",
             "poses")
_MOVE_KEYS = ("type", "speed", "acceleration", "profile")


@dataclass(frozen=True)
class ProgramMove:
    """One move of the cycle: to pose ``to``; ``None`` fields take the controller's defaults."""

    to: str
    type: str
    speed: float | None
    acceleration: float | None
    profile: str | None  # the motion model's name ("trapezoid" / "scurve")


@dataclass(frozen=True)
class MotionProgram:
    """A parsed, checked program (units in the names; speeds in deg/s or mm/s by move type)."""

    source: str
    robot: str | None
    rate_hz: float
    cycles: int
    dwell_s: float
    wait_s: float
    payload_kg: float
    speed_pct: float
    start: str
    order: tuple[ProgramMove, ...]
    poses: dict  # name -> ("joints_deg" | "xyz_mm", (float, ...))
    #: the file states its tracker rate (else rate_hz is the replay's default, no fact about a recording)
    rate_stated: bool = False

    @property
    def pose_names(self) -> list[str]:
        return list(self.poses)


def _where(src: str, key: str) -> str:
    return f"program {src}: `{key}`"


def _real(v, src, key, lo, hi, unit="") -> float:
    if isinstance(v, bool) or not isinstance(v, Real):
        raise ConfigError(f"{_where(src, key)} must be a number within {lo:g}-{hi:g}{unit}, got {short_repr(v)}")
    x = float(v) if abs(v) < 1e300 else math.inf
    if not (math.isfinite(x) and lo <= x <= hi):
        raise ConfigError(f"{_where(src, key)} must be within {lo:g}-{hi:g}{unit}, got {short_repr(v)}")
    return x


def _positive(v, src, key, hi, unit) -> float:
    x = _real(v, src, key, 0.0, hi, unit)
    if x <= 0:
        raise ConfigError(f"{_where(src, key)} must be > 0{unit}, got {short_repr(v)}")
    return x


def _int(v, src, key, lo, hi) -> int:
    if isinstance(v, bool) or not isinstance(v, Integral) or not lo <= v <= hi:
        raise ConfigError(f"{_where(src, key)} must be an integer within {lo}-{hi}, got {short_repr(v)}")
    return int(v)


def _name(v, src, key) -> str:
    if not isinstance(v, str) or not v.strip() or len(v) > 64 or any(c in v for c in ",\n\r\"'"):
        raise ConfigError(f"{_where(src, key)} must be a pose name (1-64 characters, no commas or quotes), "
                          f"got {short_repr(v)}")
    return v


def _table(v, src, key) -> dict:
    if not isinstance(v, dict):
        raise ConfigError(f"{_where(src, key)} must be a table (an object), got {type(v).__name__}")
    return v


def _unknown(d: dict, known, src, prefix="") -> None:
    extra = [k for k in d if k not in known]
    if extra:
        raise ConfigError(f"{_where(src, prefix + str(extra[0]))} is not a key of a program "
                          f"(known{' under ' + prefix.rstrip('.') if prefix else ''}: {', '.join(known)})")


def _move_fields(d: dict, src: str, key: str) -> dict:
    out = {}
    if "type" in d:
        if not isinstance(d["type"], str) or d["type"] not in MOVE_TYPES:
            raise ConfigError(f"{_where(src, key + '.type')} must be one of {', '.join(MOVE_TYPES)}, "
                              f"got {short_repr(d['type'])}")
        out["type"] = d["type"]
    if "profile" in d:
        if not isinstance(d["profile"], str) or d["profile"] not in PROGRAM_PROFILES:
            raise ConfigError(f"{_where(src, key + '.profile')} must be one of {', '.join(PROGRAM_PROFILES)}, "
                              f"got {short_repr(d['profile'])}")
        out["profile"] = PROGRAM_PROFILES[d["profile"]]
    for k in ("speed", "acceleration"):
        if k in d:
            out[k] = d[k]  # checked once the move's type is known
    return out


def _check_rates(m: dict, src: str, key: str) -> None:
    joint = m["type"] == "joint"
    unit_v, unit_a = (" deg/s", " deg/s^2") if joint else (" mm/s", " mm/s^2")
    if m.get("speed") is not None:
        m["speed"] = _positive(m["speed"], src, key + ".speed",
                               MAX_JOINT_SPEED_DEG_S if joint else MAX_TCP_SPEED_MM_S, unit_v)
    if m.get("acceleration") is not None:
        m["acceleration"] = _positive(m["acceleration"], src, key + ".acceleration",
                                      MAX_JOINT_ACCEL_DEG_S2 if joint else MAX_TCP_ACCEL_MM_S2, unit_a)


def _pose(name: str, d, src: str):
    key = f"poses.{name}"
    d = _table(d, src, key)
    _unknown(d, ("joints_deg", "xyz_mm"), src, key + ".")
    kinds = [k for k in ("joints_deg", "xyz_mm") if k in d]
    if len(kinds) != 1:
        raise ConfigError(f"{_where(src, key)} needs exactly one of joints_deg (6 angles) or xyz_mm (3 "
                          f"coordinates), got {', '.join(kinds) or 'neither'}")
    kind = kinds[0]
    n, most = (6, MAX_ABS_JOINT_DEG) if kind == "joints_deg" else (3, MAX_ABS_POSITION_MM)
    v = d[kind]
    if not isinstance(v, list) or len(v) != n:
        raise ConfigError(f"{_where(src, key + '.' + kind)} must be a list of {n} numbers, got {short_repr(v)}")
    unit = " deg" if kind == "joints_deg" else " mm"
    return kind, tuple(_real(x, src, f"{key}.{kind}[{i}]", -most, most, unit) for i, x in enumerate(v))


def parse_motion_program(obj, source: str = "<program>") -> MotionProgram:
    """Check a program's parsed TOML/JSON object (see the module docstring); ConfigError naming the key."""
    src = source
    d = _table(obj, src, "(top level)")
    _unknown(d, _TOP_KEYS, src)
    for req in ("poses", "order"):
        if req not in d:
            raise ConfigError(f"{_where(src, req)} is missing (a program names its poses and their order)")
    robot = d.get("robot")
    if robot is not None and (not isinstance(robot, str) or not robot):
        raise ConfigError(f"{_where(src, 'robot')} must be a robot model name, got {short_repr(robot)}")
    rate = _real(d.get("rate_hz", 1000.0), src, "rate_hz", *TRACKER_RATE_RANGE_HZ, " Hz")
    cycles = _int(d.get("cycles", 3), src, "cycles", 1, MAX_CYCLES)
    dwell = _real(d.get("dwell_s", 0.5), src, "dwell_s", 0.0, MAX_DWELL_S, " s")
    wait = _real(d.get("wait_s", 4.0), src, "wait_s", 0.0, MAX_WAIT_S, " s")
    payload = _real(d.get("payload_kg", 0.0), src, "payload_kg", 0.0, MAX_PAYLOAD_KG, " kg")
    pct = _real(d.get("speed_pct", 100.0), src, "speed_pct", 1.0, 100.0, " %")
    poses_d = _table(d["poses"], src, "poses")
    if not 1 <= len(poses_d) <= MAX_POSES:
        raise ConfigError(f"{_where(src, 'poses')} must name 1-{MAX_POSES} poses, got {len(poses_d)}")
    poses = {_name(k, src, f"poses.{k}"): _pose(k, v, src) for k, v in poses_d.items()}
    defaults = _move_fields(_table(d.get("move", {}), src, "move"), src, "move")
    _unknown(_table(d.get("move", {}), src, "move"), _MOVE_KEYS, src, "move.")
    order_l = d["order"]
    if not isinstance(order_l, list) or not 1 <= len(order_l) <= MAX_ORDER:
        raise ConfigError(f"{_where(src, 'order')} must be a list of 1-{MAX_ORDER} moves (pose names or tables), "
                          f"got {short_repr(order_l)}")
    order = []
    for i, item in enumerate(order_l):
        key = f"order[{i}]"
        if isinstance(item, str):
            item = {"to": item}
        item = _table(item, src, key)
        _unknown(item, ("to",) + _MOVE_KEYS, src, key + ".")
        if "to" not in item:
            raise ConfigError(f"{_where(src, key + '.to')} is missing (the pose the move goes to)")
        to = _name(item["to"], src, key + ".to")
        if to not in poses:
            raise ConfigError(f"{_where(src, key + '.to')} names pose {to!r}, which `poses` does not define "
                              f"(defined: {', '.join(poses)})")
        m = {"type": "joint", "speed": None, "acceleration": None, "profile": None, **defaults,
             **_move_fields(item, src, key)}
        _check_rates(m, src, key if any(k in item for k in ("speed", "acceleration")) else "move")
        order.append(ProgramMove(to, m["type"], m["speed"], m["acceleration"], m["profile"]))
    start = _name(d.get("start", order[-1].to), src, "start")
    if start not in poses:
        raise ConfigError(f"{_where(src, 'start')} names pose {start!r}, which `poses` does not define")
    return MotionProgram(src, robot, rate, cycles, dwell, wait, payload, pct, start, tuple(order), poses,
                         rate_stated="rate_hz" in d)


def read_motion_program(path) -> MotionProgram:
    """Read and check a program file (``.json``: JSON; otherwise TOML, or JSON when it starts with ``{``)."""
    p = Path(path)
    text = read_small_text(p, MAX_PROGRAM_BYTES, f"--program {p}", "a program is a few dozen lines", ConfigError)
    as_json = p.suffix.lower() == ".json" or text.lstrip().startswith("{")
    try:
        obj = json.loads(text) if as_json else tomllib.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"--program {p}: line {exc.lineno}: not JSON ({exc.msg})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"--program {p}: not TOML ({exc})") from None
    except (ValueError, RecursionError) as exc:
        raise ConfigError(f"--program {p}: not {'JSON' if as_json else 'TOML'} ({str(exc)[:80]})") from None
    return parse_motion_program(obj, str(p))
