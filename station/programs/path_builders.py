"""ISO 9283 path test programmes (path accuracy, also on reorientation, cornering, path velocity, weaving) as
dialect-neutral models.

The paths lie in the test plane: the diagonal plane of the test cube that
holds the base x axis (through the cube's centre, spanned by ``e_u = x`` and
``e_v = (y + z) / sqrt 2``; a rectangle ``side x side sqrt 2``). In plane
coordinates (mm from the centre):

* **line**: the plane's diagonal, 80 % of its length, driven from one end to
  the other and back, a short dwell at each end; it is written as two
  collinear halves blended at the middle (the controller passes the middle
  without slowing);
* **large circle**: diameter 80 % of the cube side, centred; **small circle**:
  a tenth of the large one's diameter; each as two ``MoveC`` half circles
  (the first blends into the second, tangentially), measured from the start
  round to 340 degrees (the cycles start and end at rest on the start point);
* **rectangle**: 80 % of the plane's extent, its corners driven in order
  with a corner zone ``blend_mm`` (cornering round-off CR) or ``fine``
  (0: exact stops, overshoot CO);
* **reorientation** (clause 8.3, path accuracy on reorientation): the line
  of the path accuracy test driven while the tool turns about its point, from
  ``-reorient_deg`` to ``+reorient_deg`` about the plane's ``e_u`` axis (the
  base x) through the tool point, the middle at the programmes' orientation;
  the controller turns the tool in proportion to the distance along each
  move. Its path file entry is the line (the position's AT and RT in the
  line's normal planes: what the turning wrist does to the path); without a
  ``velocity_mm_s`` (the joints may slow the line where the wrist turns fast).
  The held point's own test is ``reorientation_held``;
* **reorientation_held** (clause 8.3 with the tool's point held): the tool
  turns about the base x axis through its point, held at the plane's centre,
  from ``-reorient_deg`` to ``+reorient_deg`` and back, each turn one
  linear move that does not move the point (fine stops, a dwell at each
  end), at ``speed_frac`` of the rated turn
  (:func:`~station.programs.program.rated_ori_speed_deg_s`: RAPID
  ``v_ori``, KRL ``$VEL.ORI1``, URScript ``v`` in rad/s). Its path file
  entry is the ``reorientation`` kind: the point and the start and end
  angles a, b, c (``R = Rz(c) Ry(b) Rx(a)``, degrees), so the analysis states
  the held point's AT and RT (its deviation from the point over the turn,
  the normal "planes" are angles turned) from a 6-DoF stream;
* **weaving** (clause 11, weaving stroke and frequency errors WS, WF): a
  sine of amplitude ``weave_amplitude_mm`` (half the stroke) at
  ``weave_frequency_Hz`` across a base line along the plane's diagonal
  (``weave_periods`` wavelengths of ``weave_speed_mm_s / weave_frequency_Hz``,
  centred, entered and left along the base over ``WEAVE_LEAD_MM``), in the
  plane, normal to the base; realised as corner-zoned linear
  moves through ``weave_points_per_period`` vertices a period
  (:mod:`station.programs.weave`: the vertices' offset and zones chosen so the
  rounded path's fundamental is the commanded sine, one path speed so a period
  takes ``1 / weave_frequency_Hz``). The defaults, 2 mm at 1 Hz along
  10 mm/s, are the station's choice, not values of the standard. One
  programme, not one per path speed (its speed is the weave's own);

the others each at 100, 50 and 10 % of the rated speed, ``cycles`` times. Every
programme goes with its entry of the path file
(:mod:`station.analysis.path.path_file`): the commanded geometry and speed
the analysis measures against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scipy.spatial.transform import Rotation

from station.errors import ConfigError
from station.programs.builders import TOOL_DOWN, _orientation, _program, quat_from_matrix, rated_tcp_accel_mm_s2
from station.programs.program import (
    CartesianTarget,
    CycleMark,
    Dwell,
    Loop,
    Move,
    Program,
    check_number,
    rated_ori_speed_deg_s,
)
from station.programs.weave import design_weave

__all__ = ["PathTest", "PATH_KINDS", "ALL_PATH_KINDS", "SPEED_FRACS", "WEAVE_DEFAULTS", "iso_path_tests",
           "test_plane"]

#: the standard's path speeds, fractions of the rated speed
SPEED_FRACS = (1.0, 0.5, 0.1)
#: the path programmes a plan runs unless it says, in the order they run
PATH_KINDS = ("line", "circle_large", "circle_small", "rectangle_blend", "rectangle_fine")
#: every path programme there is (the reorientations and the weave on request)
ALL_PATH_KINDS = PATH_KINDS + ("reorientation", "weaving", "reorientation_held")
#: the weave's parameters unless given: amplitude mm, frequency Hz, base speed mm/s, periods, vertices a period
WEAVE_DEFAULTS = {"weave_amplitude_mm": 2.0, "weave_frequency_Hz": 1.0, "weave_speed_mm_s": 10.0,
                  "weave_periods": 10, "weave_points_per_period": 8}
#: the weave's straight lead-in and lead-out along its base, mm: more than an arm that is not calibrated is off
#: along it, so every cycle enters the woven part from before its first normal plane and leaves it after its last
WEAVE_LEAD_MM = 15.0
#: the reorientation's turn either side of the programmes' orientation, deg
REORIENT_DEG = 30.0
#: share of the plane the line and the rectangle span, and the large circle's diameter over the cube side
SPAN = 0.8
#: small circle diameter over the large one's
SMALL_CIRCLE = 0.1
#: where the circles' measured arc ends, degrees round from their start
OPEN_ARC_END_DEG = 340.0


@dataclass(frozen=True)
class PathTest:
    """One path programme and its path file entry (``path["name"]`` names it in results)."""

    kind: str
    speed_frac: float
    program: Program
    path: dict


def test_plane(centre_mm, side_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """``(centre, e_u, e_v, half extent along u, half extent along v)`` of the cube's diagonal test plane."""
    c = np.asarray(centre_mm, float).reshape(3)
    e_u = np.array([1.0, 0.0, 0.0])
    e_v = np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0)
    return c, e_u, e_v, 0.5 * side_mm, 0.5 * side_mm * math.sqrt(2.0)


def _pt(plane, u: float, v: float) -> np.ndarray:
    """A point of the plane, rounded to the micrometre the programme texts carry (so the path file's
    commanded geometry is the one the controller reads)."""
    c, e_u, e_v, _, _ = plane
    return np.round(c + u * e_u + v * e_v, 3) + 0.0


def _target(name: str, p, quat, label: str) -> CartesianTarget:
    return CartesianTarget(name, tuple(float(x) for x in p), quat, label=label)


def _line(plane, quat, v_frac, cycles, dwell, tag):
    _, _, _, hu, hv = plane
    a, b = _pt(plane, -SPAN * hu, -SPAN * hv), _pt(plane, SPAN * hu, SPAN * hv)
    start, mid, end = (_target(f"L{tag}_{n}", p, quat, f"line {n}") for n, p in
                       (("A", a), ("M", 0.5 * (a + b)), ("B", b)))
    body = [Move(mid, "linear", v_frac, zone_mm=1.0), Move(end, "linear", v_frac), dwell,
            Move(start, "linear", v_frac), dwell, CycleMark()]
    return start, body, {"kind": "line", "start_mm": a.tolist(), "end_mm": b.tolist()}


def _circle(plane, quat, v_frac, diameter, tag):
    r = 0.5 * diameter
    p0, p1, p2, p3 = (_pt(plane, r * math.cos(a), r * math.sin(a)) for a in (0, math.pi / 2, math.pi, 1.5 * math.pi))
    t0, t1, t2, t3 = (_target(f"C{tag}_{i}", p, quat, f"circle {i}") for i, p in enumerate((p0, p1, p2, p3)))
    body = [Move(t2, "circular", v_frac, zone_mm=1.0, via=t1), Move(t0, "circular", v_frac, via=t3)]
    # measured as an open arc from the start round to OPEN_ARC_END_DEG: a cycle starts and ends at rest on its
    # start point, so every pass enters the arc from below its first plane whatever the arm's own offset
    p_end = _pt(plane, r * math.cos(math.radians(OPEN_ARC_END_DEG)), r * math.sin(math.radians(OPEN_ARC_END_DEG)))
    return t0, body, {"kind": "arc", "points_mm": [p0.tolist(), p2.tolist(), p_end.tolist()]}


def _rectangle(plane, quat, v_frac, blend_mm, tag):
    _, _, _, hu, hv = plane
    uv = ((-1, -1), (1, -1), (1, 1), (-1, 1))
    pts = [_pt(plane, su * SPAN * hu, sv * SPAN * hv) for su, sv in uv]
    ts = [_target(f"R{tag}_{i + 1}", p, quat, f"rectangle corner {i + 1}") for i, p in enumerate(pts)]
    body = [Move(t, "linear", v_frac, zone_mm=blend_mm) for t in ts[1:]] + [Move(ts[0], "linear", v_frac)]
    return ts[0], body, {"kind": "rectangle", "corners_mm": [p.tolist() for p in pts], "blend_mm": blend_mm}


def _turned(quat, deg: float) -> tuple[float, float, float, float]:
    """``quat`` turned by ``deg`` about the base x axis (the plane's e_u) through the tool point."""
    w, x, y, z = quat
    R = Rotation.from_rotvec([math.radians(deg), 0.0, 0.0]) * Rotation.from_quat([x, y, z, w])
    return quat_from_matrix(R.as_matrix())


def _reorientation(plane, quat, v_frac, turn_deg, dwell, tag):
    _, _, _, hu, hv = plane
    a, b = _pt(plane, -SPAN * hu, -SPAN * hv), _pt(plane, SPAN * hu, SPAN * hv)
    start, mid, end = (_target(f"O{tag}_{n}", p, _turned(quat, d), f"reorientation {n} ({d:+g} deg about x)")
                       for n, p, d in (("A", a, -turn_deg), ("M", 0.5 * (a + b), 0.0), ("B", b, turn_deg)))
    body = [Move(mid, "linear", v_frac, zone_mm=1.0), Move(end, "linear", v_frac), dwell,
            Move(start, "linear", v_frac), dwell, CycleMark()]
    return start, body, {"kind": "line", "start_mm": a.tolist(), "end_mm": b.tolist()}


def _abc_deg(quat) -> list[float]:
    """Angles a, b, c of a tool orientation (``R = Rz(c) Ry(b) Rx(a)``), deg: the path file's convention."""
    w, x, y, z = quat
    return [float(v) for v in Rotation.from_quat([x, y, z, w]).as_euler("xyz", degrees=True)]


def _reorientation_held(plane, quat, v_frac, turn_deg, ori_deg_s, dwell, tag):
    """The tool turned about the base x axis through its point, held at the plane's centre."""
    c = _pt(plane, 0.0, 0.0)
    start, end = (_target(f"H{tag}_{n}", c, _turned(quat, d), f"held turn {n} ({d:+g} deg about x)")
                  for n, d in (("A", -turn_deg), ("B", turn_deg)))
    body = [Move(end, "linear", v_frac, ori_speed_deg_s=ori_deg_s), dwell,
            Move(start, "linear", v_frac, ori_speed_deg_s=ori_deg_s), dwell, CycleMark()]
    return start, body, {"kind": "reorientation", "point_mm": c.tolist(), "start_abc_deg": _abc_deg(start.quat_wxyz),
                         "end_abc_deg": _abc_deg(end.quat_wxyz)}


def _weaving(plane, quat, design, periods: int, dwell, rated_mm_s: float, tag):
    """The weave's targets along the plane's diagonal, centred, between a straight lead-in and lead-out of
    :data:`WEAVE_LEAD_MM`; its path file entry (kind weaving: the woven part)."""
    c, e_u, e_v, hu, hv = plane
    d = (hu * e_u + hv * e_v) / math.hypot(hu, hv)  # the base line's direction
    w = (-hv * e_u + hu * e_v) / math.hypot(hu, hv)  # across it, in the plane
    n = design.points_per_period
    length = periods * design.wavelength_mm
    room = 2 * SPAN * math.hypot(hu, hv) - 2 * WEAVE_LEAD_MM
    if length > room:
        raise ConfigError(f"a weave of weave_periods {periods} x {design.wavelength_mm:g} mm (weave_speed_mm_s / "
                          f"weave_frequency_Hz) is {length:g} mm long, more than the test plane's {room:.0f} mm "
                          f"(its diagonal less the lead-in and lead-out): fewer periods or a shorter wavelength")
    a = c - 0.5 * length * d
    pts = [np.round(a + (k * design.wavelength_mm / n) * d + design.offsets_mm[k % n] * w, 3) + 0.0
           for k in range(periods * n + 1)]
    lead_in, lead_out = (np.round(p, 3) + 0.0 for p in (pts[0] - WEAVE_LEAD_MM * d, pts[-1] + WEAVE_LEAD_MM * d))
    ts = [_target(f"W{tag}_{k}", p, quat, f"weave vertex {k}") for k, p in enumerate(pts)]
    t_in, t_out = (_target(f"W{tag}_{n}", p, quat, f"weave {n}") for n, p in (("IN", lead_in), ("OUT", lead_out)))
    frac = design.path_speed_mm_s / rated_mm_s
    body = [Move(t, "linear", frac, zone_mm=design.zones_mm[k % n]) for k, t in enumerate(ts)]
    body += [Move(t_out, "linear", frac), dwell, Move(t_in, "linear", frac), dwell, CycleMark()]
    t = (pts[-1] - pts[0]) / np.linalg.norm(pts[-1] - pts[0])  # the base as the texts carry it (micrometres)
    across = w - (w @ t) * t
    path = {"kind": "weaving", "start_mm": pts[0].tolist(), "end_mm": pts[-1].tolist(),
            "direction_mm": (across / np.linalg.norm(across)).tolist(), "amplitude_mm": design.amplitude_mm,
            "frequency_Hz": design.frequency_Hz}
    return t_in, body, path, frac


def iso_path_tests(robot, centre_mm, side_mm: float, *, cycles: int = 10, speed_fracs=SPEED_FRACS,
                   kinds=PATH_KINDS, blend_mm: float = 20.0, dwell_s: float = 0.3, approach_speed_frac: float = 0.2,
                   accel_frac: float = 1.0, orientation=None, tube_mm: float = 25.0,
                   reorient_deg: float = REORIENT_DEG, weave: dict | None = None) -> list[PathTest]:
    """The ISO 9283 path programmes for ``robot`` on the cube of ``side_mm`` about ``centre_mm``.

    Parameters
    ----------
    robot : RobotSpec
    centre_mm : (3,) float
        Cube centre, base frame.
    side_mm : float
        Cube edge.
    cycles : int
        Passes of each path (the standard: 10).
    speed_fracs : sequence of float
        Path speeds, fractions of the rated speed (the standard: 1, 0.5, 0.1).
    kinds : sequence of str
        Which of :data:`ALL_PATH_KINDS`.
    blend_mm : float
        Corner zone of ``rectangle_blend``.
    dwell_s : float
        Rest at the end of each cycle (and at the line's ends), s.
    tube_mm : float
        The path file's tube: samples farther from the commanded path belong
        to no pass. An arm that is not calibrated is off by millimetres
        everywhere; a rectangle's rounded corners add ``blend / (2 sqrt 2)``.
    reorient_deg : float
        The reorientations' turn either side of the middle, deg (0 < turn <= 90).
    weave : dict, optional
        The weave's parameters (keys of :data:`WEAVE_DEFAULTS`; the others their default).

    Returns
    -------
    list of PathTest
        In the order kinds x speeds (the weave once); each programme first
        moves (joint, at ``approach_speed_frac``) to its path's start, then
        loops the path.
    """
    side = check_number(side_mm, "side_mm", lo=1.0, hi=1e4)
    blend = check_number(blend_mm, "blend_mm", lo=0.0, hi=500.0)
    if blend <= 0:
        raise ConfigError("blend_mm must be > 0 (rectangle_fine is the rectangle without a zone)")
    bad = [k for k in kinds if k not in ALL_PATH_KINDS]
    if bad or not kinds:
        raise ConfigError(f"path kinds must be among {', '.join(ALL_PATH_KINDS)}, got {list(kinds)!r}")
    turn = check_number(reorient_deg, "reorient_deg", lo=0.0, hi=90.0)
    if ("reorientation" in kinds or "reorientation_held" in kinds) and turn <= 0:
        raise ConfigError("reorient_deg must be > 0 (the reorientation turns the tool)")
    wv = dict(WEAVE_DEFAULTS)
    unknown = sorted(set(weave or {}) - set(WEAVE_DEFAULTS))
    if unknown:
        raise ConfigError(f"weave: unknown parameters {unknown} (known: {', '.join(WEAVE_DEFAULTS)})")
    wv.update(weave or {})
    quat = _orientation(robot, TOOL_DOWN if orientation is None else orientation)
    plane = test_plane(centre_mm, side)
    dwell = Dwell(check_number(dwell_s, "dwell_s", lo=0.0, hi=60.0))
    rated = float(robot.max_tcp_speed_mm_s)
    out: list[PathTest] = []
    for kind in kinds:
        if kind == "weaving":
            out.append(_weave_test(robot, plane, quat, wv, cycles, dwell, approach_speed_frac, accel_frac, tube_mm))
            continue
        for frac in speed_fracs:
            f = check_number(frac, "speed fraction", lo=0.0, hi=1.0)
            if f <= 0:
                raise ConfigError("speed fractions must be > 0")
            pct = int(round(100 * f))
            tag = f"{ALL_PATH_KINDS.index(kind)}{pct}"
            if kind == "line":
                start, body, path = _line(plane, quat, f, cycles, dwell, tag)
            elif kind == "reorientation":
                start, body, path = _reorientation(plane, quat, f, turn, dwell, tag)
            elif kind == "reorientation_held":
                start, body, path = _reorientation_held(plane, quat, f, turn, f * rated_ori_speed_deg_s(robot), dwell,
                                                        tag)
            elif kind.startswith("circle"):
                d = SPAN * side * (SMALL_CIRCLE if kind == "circle_small" else 1.0)
                start, body, path = _circle(plane, quat, f, d, tag)
                body = body + [dwell, CycleMark()]
            else:
                start, body, path = _rectangle(plane, quat, f, blend if kind == "rectangle_blend" else 0.0, tag)
                body = body + [dwell, CycleMark()]
            name = f"{kind}_{pct}"
            tube = check_number(tube_mm, "tube_mm", lo=0.1, hi=1000.0)
            if kind == "rectangle_blend":
                tube += blend / (2.0 * math.sqrt(2.0))
            path = {"name": name, **path, "tube_mm": tube}
            if kind in ("line", "circle_large"):
                path["velocity_mm_s"] = f * rated
            statements = [Move(start, "joint", min(approach_speed_frac, f)), dwell, Loop(cycles, tuple(body))]
            short = "HELD_TURN" if kind == "reorientation_held" else kind.upper()[:12]
            program = _program(robot, f"ISO_{short}_{pct}", statements, accel_frac=accel_frac,
                               title=f"ISO 9283 path {kind} at {pct} % of rated speed")
            out.append(PathTest(kind, f, program, path))
    return out


def _weave_test(robot, plane, quat, wv, cycles, dwell, approach_speed_frac, accel_frac, tube_mm) -> PathTest:
    periods = wv["weave_periods"]
    if not (isinstance(periods, int) and 2 <= periods <= 1000):
        raise ConfigError(f"weave_periods must be an integer from 2 to 1000, got {periods!r}")
    design = design_weave(wv["weave_amplitude_mm"], wv["weave_frequency_Hz"], wv["weave_speed_mm_s"],
                          path_accel_mm_s2=accel_frac * rated_tcp_accel_mm_s2(robot),
                          points_per_period=wv["weave_points_per_period"])
    tag = f"{ALL_PATH_KINDS.index('weaving')}"
    start, body, path, frac = _weaving(plane, quat, design, periods, dwell, float(robot.max_tcp_speed_mm_s), tag)
    if frac > 1.0:
        raise ConfigError(f"the weave's path speed {design.path_speed_mm_s:g} mm/s exceeds the rated "
                          f"{robot.max_tcp_speed_mm_s:g} mm/s")
    path = {"name": "weaving", **path, "tube_mm": check_number(tube_mm, "tube_mm", lo=0.1, hi=1000.0)}
    statements = [Move(start, "joint", min(approach_speed_frac, 1.0)), dwell, Loop(cycles, tuple(body))]
    program = _program(robot, "ISO_WEAVING", statements, accel_frac=accel_frac,
                       title=f"ISO 9283 weaving {design.amplitude_mm:g} mm at {design.frequency_Hz:g} Hz along "
                             f"{design.base_speed_mm_s:g} mm/s")
    return PathTest("weaving", frac, program, path)
