"""Dialect-neutral motion program model.

A :class:`Program` is what the procedures ask a robot controller to do: move
to named targets (Cartesian or joint), stop exactly there (``fine``), dwell,
repeat a body ``n`` times and count the cycles. The dialect generators
(:mod:`station.programs.rapid`, :mod:`station.programs.krl`) turn it into
program text, and the safety gate (:mod:`station.safety`) checks it before
anything is uploaded or moved.

Everything that can reach program text is validated here, once:

* identifiers (program and target names) match ``[A-Za-z][A-Za-z0-9_]*``
  (ASCII only, at most :data:`MAX_NAME_LEN` characters, not a keyword of
  either dialect); names are compared case-insensitively because both
  RAPID and KRL are case-insensitive;
* numbers are finite and bounded (:data:`MAX_ABS_VALUE`);
* free text (titles, descriptions) is printable ASCII without line breaks,
  so a comment can never end early and start code.

Units: positions in mm, joint angles in degrees (as on the teach pendant and
in the files), speeds as a fraction of the robot's rated speed, dwell in s.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from typing import Iterator, Union

import numpy as np

from station.errors import ConfigError

#: longest user identifier; generators add a two-character prefix and KRL
#: allows 24 characters per name
MAX_NAME_LEN = 20
#: largest magnitude of any number written into a program (mm, deg, s)
MAX_ABS_VALUE = 1.0e5
#: longest free text (RAPID strings hold at most 80 characters)
MAX_TEXT_LEN = 80
#: most repetitions of a loop body
MAX_CYCLES = 10000
#: largest corner zone (blend radius), mm
MAX_ZONE_MM = 500.0
#: largest programmed speed of the tool's turn, deg/s
MAX_ORI_SPEED_DEG_S = 3600.0
#: the wrist's axes (joints 4-6, 0-based), whose slowest speed limit is the rated speed of the tool's turn
WRIST_AXES = (3, 4, 5)


def rated_ori_speed_deg_s(robot) -> float:
    """Rated speed of the tool's turn, deg/s: the slowest wrist axis's speed limit (a turn of the tool about
    its point takes at least the wrist's own turn; the station's convention, not a catalogue figure)."""
    return float(np.degrees(np.min(np.asarray(robot.joint_speed_limits_rad_s, float)[list(WRIST_AXES)])))


#: how a move gets to its target: joint-interpolated, straight line, arc through a via point
INTERPOLATIONS = ("joint", "linear", "circular")

_IDENT_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*", re.ASCII)
_TEXT_RE = re.compile(r"[\x20-\x7e]*", re.ASCII)

#: keywords of RAPID and KRL (lower case) that no user name may take
RESERVED_WORDS = frozenset(
    """
    and backward case connect const default div do else elseif endfor endfunc endif
    endmodule endproc endrecord endtest endtrap endwhile error exit false for from
    func goto if inout local mod module nostepin not noview or pers proc raise
    readonly record retry return step sysmodule test then to trap true trynext
    undo var viewonly while xor main
    def end deffct endfct decl int real bool char struc enum signal global
    continue halt wait sec ptp lin circ ptp_rel lin_rel loop endloop repeat until
    switch endswitch interrupt brake resume trigger when delay distance pulse
    e6pos e6axis pos axis frame out in anout anin ext dat public enddat
    robtarget jointtarget speeddata zonedata tooldata wobjdata num string
    tool0 wobj0 fine movej movel moveabsj waittime accset velset setgo setdo
    confj confl tpwrite
    """.split()
)


def check_name(name: object, what: str) -> str:
    """Return ``name`` if it is a safe identifier, else raise ConfigError.

    Parameters
    ----------
    name : object
        Candidate identifier (from a config file, so untrusted).
    what : str
        What the name is for, used in the error message.
    """
    if not isinstance(name, str):
        raise ConfigError(f"{what}: name must be a string, got {type(name).__name__}")
    if not _IDENT_RE.fullmatch(name):
        raise ConfigError(
            f"{what}: name {name!r} is not an identifier "
            "(ASCII letter first, then letters, digits or '_')"
        )
    if len(name) > MAX_NAME_LEN:
        raise ConfigError(f"{what}: name {name!r} is longer than {MAX_NAME_LEN} characters")
    if name.lower() in RESERVED_WORDS:
        raise ConfigError(f"{what}: name {name!r} is a reserved word of RAPID or KRL")
    return name


def check_text(text: object, what: str) -> str:
    """Return ``text`` if it is printable ASCII of at most 80 characters."""
    if not isinstance(text, str):
        raise ConfigError(f"{what}: text must be a string, got {type(text).__name__}")
    if not _TEXT_RE.fullmatch(text):
        bad = next(c for c in text if not ("\x20" <= c <= "\x7e"))
        raise ConfigError(
            f"{what}: text contains {bad!r} (only printable ASCII, no line breaks or control characters)"
        )
    if len(text) > MAX_TEXT_LEN:
        raise ConfigError(f"{what}: text is longer than {MAX_TEXT_LEN} characters")
    return text


def check_number(value: object, what: str, *, lo: float = -MAX_ABS_VALUE, hi: float = MAX_ABS_VALUE) -> float:
    """Return ``value`` as a finite float inside ``[lo, hi]`` or raise ConfigError."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ConfigError(f"{what}: must be a number, got {type(value).__name__} {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise ConfigError(f"{what}: must be finite, got {x!r}")
    if not lo <= x <= hi:
        raise ConfigError(f"{what}: {x!r} is outside [{lo:g}, {hi:g}]")
    return x


def _vector(values: object, n: int, what: str) -> tuple[float, ...]:
    try:
        arr = np.asarray(values, dtype=object).reshape(-1)
    except Exception as exc:  # noqa: BLE001 - any malformed input is a config error
        raise ConfigError(f"{what}: not a vector of {n} numbers ({exc})") from None
    if arr.shape != (n,):
        raise ConfigError(f"{what}: needs {n} numbers, got {arr.size}")
    return tuple(check_number(v, f"{what}[{i}]") for i, v in enumerate(arr))


def quat_from_matrix(rot: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion ``(w, x, y, z)`` of a 3x3 rotation matrix (w >= 0)."""
    r = np.asarray(rot, dtype=float)
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        raise ConfigError(f"rotation must be a finite 3x3 matrix, got shape {r.shape}")
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise ConfigError("rotation matrix is not orthonormal with determinant +1")
    # Shepperd's method: pick the largest diagonal term for stability
    tr = np.trace(r)
    k = int(np.argmax([tr, r[0, 0], r[1, 1], r[2, 2]]))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = (0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s)
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = ((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s)
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = ((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = ((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s)
    qa = np.asarray(q)
    qa = qa / np.linalg.norm(qa)
    if qa[0] < 0:
        qa = -qa
    return tuple(float(v) for v in qa)  # type: ignore[return-value]


def matrix_from_quat(quat_wxyz: tuple[float, float, float, float]) -> np.ndarray:
    """3x3 rotation matrix of a unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = quat_wxyz
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@dataclass(frozen=True)
class CartesianTarget:
    """A named tool pose in the robot base frame.

    Attributes
    ----------
    name : str
        Identifier (validated, see :func:`check_name`).
    xyz_mm : tuple of 3 float
        Tool point position, mm.
    quat_wxyz : tuple of 4 float
        Tool orientation as a unit quaternion (normalised on construction).
    label : str
        Free text for comments and reports (printable ASCII).
    """

    name: str
    xyz_mm: tuple[float, float, float]
    quat_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    label: str = ""

    def __post_init__(self) -> None:
        check_name(self.name, "target")
        object.__setattr__(self, "xyz_mm", _vector(self.xyz_mm, 3, f"target {self.name} xyz_mm"))
        q = np.asarray(_vector(self.quat_wxyz, 4, f"target {self.name} quat_wxyz"))
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > 1e-3:
            raise ConfigError(f"target {self.name} quat_wxyz: norm {norm:.6g} is not 1 (unit quaternion expected)")
        q = q / norm
        if q[0] < 0:
            q = -q
        object.__setattr__(self, "quat_wxyz", tuple(float(v) for v in q))
        check_text(self.label, f"target {self.name} label")

    @property
    def pose(self) -> np.ndarray:
        """4x4 homogeneous pose (mm)."""
        t = np.eye(4)
        t[:3, :3] = matrix_from_quat(self.quat_wxyz)
        t[:3, 3] = self.xyz_mm
        return t


@dataclass(frozen=True)
class JointTarget:
    """A named joint configuration, degrees (joints 1..6)."""

    name: str
    q_deg: tuple[float, float, float, float, float, float]
    label: str = ""

    def __post_init__(self) -> None:
        check_name(self.name, "joint target")
        object.__setattr__(
            self, "q_deg", _vector(self.q_deg, 6, f"joint target {self.name} q_deg")
        )
        for i, v in enumerate(self.q_deg):
            if abs(v) > 720.0:
                raise ConfigError(f"joint target {self.name} q_deg[{i}]: {v} deg is beyond +-720 deg")
        check_text(self.label, f"joint target {self.name} label")

    @property
    def q_rad(self) -> np.ndarray:
        return np.radians(np.asarray(self.q_deg))


Target = Union[CartesianTarget, JointTarget]


@dataclass(frozen=True)
class Move:
    """Move to ``target`` and stop there exactly (``fine``).

    Attributes
    ----------
    target : CartesianTarget or JointTarget
    interpolation : {"joint", "linear"}
        Joint-interpolated (MoveJ / MoveAbsJ, PTP) or straight line (MoveL,
        LIN). A linear move needs a Cartesian target.
    speed_frac : float
        Fraction of the rated speed in (0, 1]: of the rated TCP speed for a
        linear move, of every joint's speed limit for a joint move.
    source_line : int or None
        Line of the program text this instruction was rendered to (filled by
        the generators; the safety gate names it).
    zone_mm : float
        Corner zone (blend radius), mm: 0 is an exact stop (``fine``); a
        positive radius lets the path round the corner to the next move
        within that distance of the target (RAPID zonedata, KRL ``C_DIS``,
        URScript ``r``). Only linear and circular moves blend.
    via : CartesianTarget or None
        The circle point of a ``"circular"`` move (the arc runs from where
        the move starts through ``via`` to ``target``).
    ori_speed_deg_s : float or None
        Programmed speed of the tool's turn on a linear move, deg/s (RAPID
        ``speeddata``'s ``v_ori``, KRL ``$VEL.ORI1``; URScript's ``v`` of a
        ``movel`` that only turns). None: the controller's default. It
        times a move that only turns the tool (its point held), and any
        linear move whose turn is slower than its line.
    """

    target: Target
    interpolation: str = "joint"
    speed_frac: float = 1.0
    source_line: int | None = None
    zone_mm: float = 0.0
    via: CartesianTarget | None = None
    ori_speed_deg_s: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.target, (CartesianTarget, JointTarget)):
            raise ConfigError(f"move target must be a CartesianTarget or JointTarget, got {type(self.target).__name__}")
        if self.interpolation not in INTERPOLATIONS:
            raise ConfigError(f"move to {self.target.name}: interpolation must be one of {', '.join(INTERPOLATIONS)}, "
                              f"got {self.interpolation!r}")
        if self.interpolation != "joint" and isinstance(self.target, JointTarget):
            raise ConfigError(f"move to {self.target.name}: a {self.interpolation} move needs a Cartesian target")
        if (self.interpolation == "circular") != isinstance(self.via, CartesianTarget):
            raise ConfigError(f"move to {self.target.name}: a circular move needs a Cartesian via point, "
                              "and only a circular move has one")
        v = check_number(self.speed_frac, f"move to {self.target.name} speed_frac", lo=0.0, hi=1.0)
        if v <= 0.0:
            raise ConfigError(f"move to {self.target.name} speed_frac: must be > 0")
        object.__setattr__(self, "speed_frac", v)
        z = check_number(self.zone_mm, f"move to {self.target.name} zone_mm", lo=0.0, hi=MAX_ZONE_MM)
        if z > 0 and self.interpolation == "joint":
            raise ConfigError(f"move to {self.target.name}: only linear and circular moves blend (zone_mm {z:g})")
        object.__setattr__(self, "zone_mm", z)
        if self.ori_speed_deg_s is not None:
            w = check_number(self.ori_speed_deg_s, f"move to {self.target.name} ori_speed_deg_s", lo=0.0,
                             hi=MAX_ORI_SPEED_DEG_S)
            if w <= 0.0 or self.interpolation != "linear":
                raise ConfigError(f"move to {self.target.name}: ori_speed_deg_s must be > 0, and only on a linear "
                                  f"move (got {w:g} on a {self.interpolation} move)")
            object.__setattr__(self, "ori_speed_deg_s", w)


@dataclass(frozen=True)
class Dwell:
    """Stay still for ``seconds`` (ISO 9283 stop for pose extraction)."""

    seconds: float
    source_line: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "seconds", check_number(self.seconds, "dwell seconds", lo=0.0, hi=3600.0))


@dataclass(frozen=True)
class CycleMark:
    """Publish the number of the cycle just finished (the loop counter; 1 outside a loop)."""

    source_line: int | None = None


Instruction = Union[Move, Dwell, CycleMark]


@dataclass(frozen=True)
class Loop:
    """Repeat ``body`` ``count`` times (no nested loops)."""

    count: int
    body: tuple[Instruction, ...]
    source_line: int | None = None

    def __post_init__(self) -> None:
        if isinstance(self.count, bool) or not isinstance(self.count, (int, np.integer)):
            raise ConfigError(f"loop count must be an integer, got {self.count!r}")
        if not 1 <= int(self.count) <= MAX_CYCLES:
            raise ConfigError(f"loop count {self.count} is outside [1, {MAX_CYCLES}]")
        object.__setattr__(self, "count", int(self.count))
        body = tuple(self.body)
        if not body:
            raise ConfigError("loop body is empty")
        for ins in body:
            if not isinstance(ins, (Move, Dwell, CycleMark)):
                raise ConfigError(f"loop body may hold Move, Dwell and CycleMark only, got {type(ins).__name__}")
        object.__setattr__(self, "body", body)


Statement = Union[Move, Dwell, CycleMark, Loop]


@dataclass(frozen=True)
class Program:
    """A motion program for one robot.

    Attributes
    ----------
    name : str
        Program (module) name, an identifier; the file name derives from it.
    robot_name : str
        Name of the robot model the program is for (``RobotSpec.name``); the
        safety gate refuses a program made for another robot.
    rated_tcp_speed_mm_s : float
        Rated TCP speed of that robot; ``speed_frac`` refers to it.
    accel_frac : float
        Fraction of the rated acceleration used for every move, (0, 1].
    statements : tuple
        Moves, dwells, cycle marks and loops, in order.
    title : str
        Free text shown on the pendant and written in the header.
    rated_tcp_accel_mm_s2 : float or None
        Rated TCP acceleration; dialects that state the Cartesian acceleration
        in absolute units (KRL ``$ACC.CP``) need it.
    """

    name: str
    robot_name: str
    rated_tcp_speed_mm_s: float
    statements: tuple[Statement, ...]
    accel_frac: float = 1.0
    title: str = ""
    rated_tcp_accel_mm_s2: float | None = None

    def __post_init__(self) -> None:
        check_name(self.name, "program")
        if self.rated_tcp_accel_mm_s2 is not None:
            acc = check_number(self.rated_tcp_accel_mm_s2, "program rated_tcp_accel_mm_s2", lo=0.0)
            if acc <= 0:
                raise ConfigError("program rated_tcp_accel_mm_s2: must be > 0")
            object.__setattr__(self, "rated_tcp_accel_mm_s2", acc)
        check_text(self.robot_name, "program robot_name")
        v = check_number(self.rated_tcp_speed_mm_s, "program rated_tcp_speed_mm_s", lo=0.0)
        if v <= 0:
            raise ConfigError("program rated_tcp_speed_mm_s: must be > 0")
        object.__setattr__(self, "rated_tcp_speed_mm_s", v)
        a = check_number(self.accel_frac, "program accel_frac", lo=0.0, hi=1.0)
        if a <= 0:
            raise ConfigError("program accel_frac: must be > 0")
        object.__setattr__(self, "accel_frac", a)
        check_text(self.title, "program title")
        stmts = tuple(self.statements)
        for s in stmts:
            if not isinstance(s, (Move, Dwell, CycleMark, Loop)):
                raise ConfigError(f"program {self.name}: unknown statement {type(s).__name__}")
        if not any(isinstance(s, Move) or (isinstance(s, Loop) and any(isinstance(b, Move) for b in s.body)) for s in stmts):
            raise ConfigError(f"program {self.name}: has no move")
        object.__setattr__(self, "statements", stmts)
        self.targets()  # refuses two different targets under one name

    def targets(self) -> dict[str, Target]:
        """Every target by name, in first-use order; ConfigError on a name clash."""
        out: dict[str, Target] = {}
        seen: dict[str, str] = {}
        for ins in iter_instructions(self.statements):
            if not isinstance(ins, Move):
                continue
            for t in ((ins.via, ins.target) if ins.via is not None else (ins.target,)):
                key = t.name.lower()
                if key in seen:
                    prev = out[seen[key]]
                    if prev != t:
                        raise ConfigError(
                            f"program {self.name}: two different targets named {t.name!r} "
                            "(names are case-insensitive)"
                        )
                    continue
                seen[key] = t.name
                out[t.name] = t
        return out

    def zones_mm(self) -> list[float]:
        """Distinct corner zones (blend radii > 0), mm, in first-use order."""
        out: list[float] = []
        for ins in iter_instructions(self.statements):
            if isinstance(ins, Move) and ins.zone_mm > 0 and ins.zone_mm not in out:
                out.append(ins.zone_mm)
        return out

    def speed_fracs(self) -> list[float]:
        """Distinct speed fractions, in first-use order."""
        out: list[float] = []
        for ins in iter_instructions(self.statements):
            if isinstance(ins, Move) and ins.speed_frac not in out:
                out.append(ins.speed_frac)
        return out


def iter_instructions(statements: tuple[Statement, ...]) -> Iterator[Instruction]:
    """Instructions in text order, loop bodies once (not unrolled)."""
    for s in statements:
        if isinstance(s, Loop):
            yield from s.body
        else:
            yield s


@dataclass(frozen=True)
class Stop:
    """One place where the program stands still after a fine move (a stop).

    ``cycle`` is 1-based inside a loop, 0 outside; ``approach_from`` is the
    target of the move before the stopping move (the vAP direction), or None.
    """

    index: int
    target: Target
    cycle: int
    dwell_s: float
    source_line: int | None
    approach_from: Target | None = None


def expected_stops(program: Program) -> list[Stop]:
    """The stops the program makes, in execution order (loops unrolled).

    A stop is a move followed by a dwell; procedures use this list to label the
    attained poses they extract from the tracker stream (seed 000 sec. 3.1.3).
    """
    out: list[Stop] = []

    prev: list[Target | None] = [None, None]  # targets of the last two moves

    def walk(body: tuple[Instruction, ...], cycle: int) -> None:
        last: Move | None = None
        for ins in body:
            if isinstance(ins, Move):
                last = ins
                prev[:] = [prev[1], ins.target]
            elif isinstance(ins, Dwell) and last is not None:
                out.append(Stop(len(out), last.target, cycle, ins.seconds, last.source_line, prev[0]))
                last = None

    pending: list[Instruction] = []
    for s in program.statements:
        if isinstance(s, Loop):
            walk(tuple(pending), 0)
            pending = []
            for c in range(1, s.count + 1):
                walk(s.body, c)
        else:
            pending.append(s)
    walk(tuple(pending), 0)
    return out


@dataclass(frozen=True)
class RenderedProgram:
    """Program text in one dialect, ready for upload.

    Attributes
    ----------
    dialect : {"rapid", "krl"}
    files : dict of str to str
        File name -> text (RAPID: one ``.mod``; KRL: ``.src`` and ``.dat``).
    main_file : str
        The file the controller selects and whose lines ``program`` names.
    program : Program
        The program with every ``source_line`` set to its line in ``main_file``.
    """

    dialect: str
    files: dict[str, str] = field(default_factory=dict)
    main_file: str = ""
    program: Program | None = None

    @property
    def text(self) -> str:
        return self.files[self.main_file]


def with_lines(program: Program, lines: list[int]) -> Program:
    """Copy of ``program`` with ``source_line`` set.

    ``lines`` lists, in text order, the line of each top-level statement, and
    for a loop its ``FOR`` line followed by the lines of its body.
    """
    it = iter(lines)
    new: list[Statement] = []
    for s in program.statements:
        if isinstance(s, Loop):
            line = next(it)
            body = tuple(replace(b, source_line=next(it)) for b in s.body)
            new.append(replace(s, body=body, source_line=line))
        else:
            new.append(replace(s, source_line=next(it)))
    return replace(program, statements=tuple(new))


def check_unique_identifiers(program_name: str, declared: list[tuple[str, str]]) -> None:
    """ConfigError when two of ``declared`` (identifier, what it is) are the same name.

    RAPID and KRL identifiers are case-insensitive, so ``V_1`` and ``v_1``
    clash; a controller refuses a module that declares a name twice (a
    program named ``v_1`` beside the generated speed ``v_1``, or ``n_cycle``
    beside the loop counter).
    """
    seen: dict[str, str] = {}
    for ident, what in declared:
        key = ident.lower()
        if key in seen:
            raise ConfigError(f"program {program_name}: {seen[key]} and {ident!r} ({what}) are the same "
                              f"identifier to the controller; choose another name")
        seen[key] = f"{ident!r} ({what})"

