"""The fake controller follows path programmes like an arm: corners rounded by their zone, a servo that lags
more the faster the path, the interpolator's speed ripple; the tracker's stream of it gives each path figure
within its U of the figure of what the tracker reads of the true motion, noise aside."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fakes.sim.clock import ManualClock
from fakes.sim.path_follow import ripple_of
from fakes.sim.world import ISO_CUBE_CENTRE_MM, make_world
from station.analysis.path.analysis import analyze_path
from station.analysis.path.path_file import parse_paths
from station.models.cartesian_path import circle_through
from station.programs.path_builders import iso_path_tests
from tests.path import fakerun


def _test(world, kind, frac, side, **kw):
    return iso_path_tests(world.robot, ISO_CUBE_CENTRE_MM, side, cycles=kw.pop("cycles", 2), speed_fracs=(frac,),
                          kinds=(kind,), **kw)[0]


def _radial(points, path):
    c, r, u, w = circle_through(*np.asarray(path["points_mm"]))
    n = np.cross(u, w)
    d = points - c
    return np.linalg.norm(d - (d @ n)[:, None] * n, axis=1) - r


def test_the_zone_rounds_the_corner_and_the_servo_lags_more_when_faster(test_seed, rng):
    world = make_world("industrial-3100", seed=test_seed, clock=ManualClock(), effects=None)
    side = float(rng.uniform(300.0, 450.0))
    blend = float(np.round(rng.uniform(5.0, 40.0), 3))
    pt = _test(world, "rectangle_blend", 0.1, side, blend_mm=blend)
    r = fakerun.run(world, pt)
    corner = np.asarray(pt.path["corners_mm"][2])
    # the controller's path passes blend / (2 sqrt 2) from a right-angled corner (the Bezier's midpoint), up to
    # what the axes' cubic spline through the interpolation knots (h mm apart at the apex) makes of a curve of
    # radius blend / sqrt 2 there: of order (5/384) h^4 / R^3 times the Bezier's curvature change, measured at
    # most 0.031 h^4 / R^3 over 30 draws of 5-12 mm zones (CI seed 2906433913: an 8 mm zone, h 3.05 mm, 0.011 mm
    # outside the Bezier, which a fixed 0.01 mm refused)
    d = np.linalg.norm(r.commanded - corner, axis=1)
    i = int(np.argmin(d))
    h = 0.5 * float(np.linalg.norm(r.commanded[i + 1] - r.commanded[i - 1])) * fakerun.RATE_HZ * world.arm.ipo_period_s
    R = blend / math.sqrt(2)
    apex = blend / (2 * math.sqrt(2))
    assert abs(d[i] - apex) <= 0.002 + 0.06 * h ** 4 / R ** 3, (d[i], apex, h)
    # the servo: the true path leaves the commanded one, by more on a circle driven faster
    lag = {}
    for frac in (0.1, 0.5):
        pc = _test(world, "circle_large", frac, side)
        rc = fakerun.run(world, pc)
        moving = np.linalg.norm(np.gradient(rc.commanded, axis=0), axis=1) * fakerun.RATE_HZ > 0.5 * frac * 2000.0
        assert np.max(np.abs(_radial(rc.commanded[moving], pc.path))) < 0.01  # the interpolator is on the circle
        lag[frac] = float(np.max(np.abs(_radial(rc.true[moving], pc.path))))
    # servo error follows the joints' acceleration, ~v^2/R: the speed ratio is at least 2.5 after the
    # curvature limit, so at least 6 in the lag; a lag that did not grow with speed fails
    assert lag[0.5] > 4.0 * lag[0.1] > 0.0, lag


def test_the_interpolator_ripples_the_path_speed(test_seed, rng):
    world = make_world("industrial-3100", seed=test_seed, clock=ManualClock(), effects=None)
    side = float(rng.uniform(350.0, 450.0))
    # at 10 % of the rated speed the cruise between 0.3 and 0.7 of the line lasts about a second: two periods or
    # more of the slowest ripple (2 Hz). At 50 % it lasted 0.2 s, one period of a 5.2 Hz ripple, and a sine that
    # short is half the constant and the trend (amplitude 0.0026 fitted against 0.0034, CI seed 1517814602)
    pt = _test(world, "line", 0.1, side, cycles=1)
    r = fakerun.run(world, pt)
    a, b = (np.asarray(pt.path[k]) for k in ("start_mm", "end_mm"))
    u = (r.commanded - a) @ (b - a) / np.linalg.norm(b - a) ** 2
    v = np.linalg.norm(np.gradient(r.commanded, axis=0), axis=1) * fakerun.RATE_HZ
    forward = np.gradient(u) > 0
    cruise = forward & (u > 0.3) & (u < 0.7)
    ripple = ripple_of(world.seed)
    t = r.t[cruise]
    assert np.ptp(t) * ripple.frequency_Hz >= 1.8, (np.ptp(t), ripple.frequency_Hz)
    X = np.column_stack([np.ones(t.size), t - t.mean(), np.sin(2 * np.pi * ripple.frequency_Hz * t),
                         np.cos(2 * np.pi * ripple.frequency_Hz * t)])
    coef = np.linalg.lstsq(X, v[cruise], rcond=None)[0]
    assert coef[0] == pytest.approx(0.1 * world.robot.max_tcp_speed_mm_s, rel=0.002)
    assert math.hypot(coef[2], coef[3]) / coef[0] == pytest.approx(ripple.amplitude, rel=0.1)


def _weave(rng) -> dict:
    return {"weave_amplitude_mm": float(rng.uniform(1.0, 3.0)), "weave_frequency_Hz": float(rng.uniform(0.6, 1.5)),
            "weave_speed_mm_s": float(rng.uniform(8.0, 15.0)), "weave_periods": 6,
            "weave_points_per_period": int(rng.choice([4, 8, 12]))}


@pytest.mark.parametrize("kind", ["line", "rectangle_blend", "circle_small", "weaving", "reorientation"])
def test_the_tracker_stream_gives_each_figure_within_U_of_the_truth(kind, test_seed, rng):
    world = make_world("industrial-3100", seed=test_seed, clock=ManualClock())
    pt = _test(world, kind, 0.5, float(rng.uniform(350.0, 450.0)), cycles=3, blend_mm=float(rng.uniform(5, 40)),
               weave=_weave(rng), reorient_deg=float(rng.uniform(10.0, 30.0)))
    r = fakerun.run(world, pt)
    spec = parse_paths({"paths": [pt.path]})[0]
    ok = np.ones(r.t.size, bool)
    measured = analyze_path(spec, r.t, r.measured, ok, noise_sd_mm=r.noise, trials=60, seed=test_seed)
    truth = analyze_path(spec, r.t, r.read_truth, ok, noise_sd_mm=1e-6, trials=10, seed=test_seed)
    assert measured.n_cycles == truth.n_cycles == 3, measured.notes
    assert set(measured.figures) == set(truth.figures) and measured.figures
    for name, value in measured.figures.items():
        # 2U (four standard uncertainties): the U of one draw covers its truth about 95 % of the time (the
        # bench measures that); a figure off by its bias, or a U that is not of the noise, fails this
        assert abs(value - truth.figures[name]) <= 2 * measured.uncertainty[name].U, (name, value,
                                                                                     truth.figures[name])
    if kind == "rectangle_blend":  # an arm off by millimetres: the round-off is not the commanded one
        assert truth.figures["CR_mm"] > 0


def test_the_controller_weaves_the_commanded_sine_and_the_servo_widens_it(test_seed, rng):
    """What the controller commands (its interpolator's path through the blended vertices) is the commanded sine:
    its WS and WF are within 1 % and 0.5 % of it (over 13 draws of 1-3 mm at 0.6-1.5 Hz along 8-15 mm/s with
    4, 8 or 12 vertices a period they were within 0.5 % and 0.32 %: the vertices' corners rounded and the speed
    capped in the sharpest of them; with the vertices at the amplitude, not wider, WS would be -5 to -20 %, and a
    speed that were the base's, not the path's, would put WF at -20 % and more). The true arm overshoots the
    crests a little (the servo's lag turns into a wider weave: WS 1-4 % in those draws)."""
    world = make_world("industrial-3100", seed=test_seed, clock=ManualClock())
    wv = _weave(rng)
    pt = _test(world, "weaving", 1.0, 400.0, cycles=2, weave=wv)
    r = fakerun.run(world, pt)
    spec = parse_paths({"paths": [pt.path]})[0]
    ok = np.ones(r.t.size, bool)
    cmd = analyze_path(spec, r.t, r.commanded, ok, noise_sd_mm=1e-6, trials=10, seed=test_seed)
    true = analyze_path(spec, r.t, r.true, ok, noise_sd_mm=1e-6, trials=10, seed=test_seed)
    assert cmd.n_cycles == true.n_cycles == 2, (cmd.notes, true.notes)
    assert abs(cmd.figures["WS_percent"]) < 1.0 and abs(cmd.figures["WF_percent"]) < 0.5, (cmd.figures, wv)
    assert true.figures["WS_percent"] > cmd.figures["WS_percent"], (true.figures, cmd.figures)
    for f in cmd.detail["weave"]:  # each cycle's own frequency too
        assert f["frequency_Hz"] == pytest.approx(wv["weave_frequency_Hz"], rel=0.005)


def test_the_reorientation_turns_the_tool_while_the_point_keeps_to_the_line(test_seed, rng):
    """The controller turns the tool through the commanded angle, about the base x axis, along the line, and its
    point stays on the line."""
    world = make_world("industrial-3100", seed=test_seed, clock=ManualClock(), effects=None)
    turn = float(rng.uniform(15.0, 30.0))
    pt = _test(world, "reorientation", 0.5, 400.0, cycles=2, reorient_deg=turn)
    r = fakerun.run(world, pt)
    spec = parse_paths({"paths": [pt.path]})[0]
    g = spec.geometry
    s = (r.commanded - g.start_mm) @ g.tangent_at(0.0)[0]
    off = np.linalg.norm(r.commanded - g.point_at(np.clip(s, 0.0, g.length_mm)), axis=1)
    assert np.max(off) < 0.01
    from station.models import kinematics as kin

    R = kin.fk(world.robot.dh_nominal, world.arm.commanded_q_rad(r.t))[:, :3, :3]
    ends = [int(np.argmin(np.abs(s - x))) for x in (0.0, g.length_mm)]
    rel = R[ends[1]] @ R[ends[0]].T
    angle = math.degrees(math.acos(np.clip((np.trace(rel) - 1.0) / 2.0, -1.0, 1.0)))
    axis = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
    assert angle == pytest.approx(2 * turn, abs=0.05)
    assert abs(axis[0]) / np.linalg.norm(axis) > 0.9999  # about the base x axis


@pytest.mark.parametrize("robot", ["industrial-3100", "ur5e"])
def test_the_held_turn_keeps_the_point_commanded_and_the_servo_leaves_it_more_when_faster(robot, test_seed, rng):
    """A move that only turns the tool: the interpolator keeps the TCP on its point while the tool slerps through
    the commanded turn about the base x axis at no more than the programmed turn's speed; a perfect arm's servo
    leaves the point while the wrist turns, by more the faster it turns, and comes back to it at rest."""
    from scipy.spatial.transform import Rotation

    from station.models import kinematics as kin
    from station.programs.program import rated_ori_speed_deg_s

    turn = float(rng.uniform(10.0, 30.0))
    side = float(rng.uniform(200.0, 400.0))
    lag, peak = {}, {}
    for frac in (0.1, float(rng.uniform(0.6, 1.0))):
        world = make_world(robot, seed=test_seed, clock=ManualClock(), effects=None, stop_sigma_mm=None)
        home = kin.fk(world.robot.dh_nominal, world.robot.home_q_rad)
        centre, rot = (ISO_CUBE_CENTRE_MM, None) if robot != "ur5e" else (home[:3, 3], home[:3, :3])
        pt = iso_path_tests(world.robot, centre, side, cycles=1, speed_fracs=(frac,), kinds=("reorientation_held",),
                            reorient_deg=turn, orientation=rot, dwell_s=2.0)[0]  # the approach settles
        r = fakerun.run(world, pt)
        p = np.asarray(pt.path["point_mm"])
        assert np.max(np.linalg.norm(r.commanded - p, axis=1)) < 1e-3  # the interpolator holds the point
        R = kin.fk(world.robot.dh_nominal, world.arm.commanded_q_rad(r.t))[:, :3, :3]
        rv = np.degrees(Rotation.from_matrix(R @ R[0].T).as_rotvec())  # the turn since the first sample
        assert np.max(np.abs(rv[:, 1:])) < 1e-3  # about the base x axis only
        assert np.ptp(rv[:, 0]) == pytest.approx(2 * turn, abs=1e-3)  # through the commanded turn
        w = frac * rated_ori_speed_deg_s(world.robot)
        peak[frac] = float(np.max(np.abs(np.gradient(rv[:, 0], r.t)))) / w
        # never faster than programmed (an axis may slow it), up to what the axes' cubic spline through the 20 ms
        # knots makes of the profile's corners (1.1 % on the UR5e, whose wrist turns at 180 deg/s)
        assert peak[frac] <= 1.02, (peak, w)
        off = np.linalg.norm(r.true - p, axis=1)
        assert off[-1] < 1e-3  # at rest on the point again
        t0 = next(m.t_start for m in world.arm.moves if m.kind == "linear")  # after the approach has settled
        assert np.max(off[(r.t > t0 - 0.1) & (r.t < t0)]) < 1e-3  # and on it before
        lag[frac] = float(np.max(off[r.t >= t0]))
    print(f"{robot}: turn {2 * turn:.1f} deg, peak speed / programmed {peak}, servo's largest lag {lag} mm")
    # the turn's acceleration is the path's share (the same at every speed: the lag while it ramps is too); what
    # the wrist's curved joint paths ask of the servo at cruise grows as the square of the speed
    slow, fast = lag[0.1], max(v for k, v in lag.items() if k != 0.1)
    assert fast > 1.2 * slow > 0.0, lag  # 1.6 to 4.3 times over 12 draws (0.6-1.0 against 0.1)
    assert peak[0.1] == pytest.approx(1.0, rel=0.02)  # slowly: the programmed turn, no axis slows it
