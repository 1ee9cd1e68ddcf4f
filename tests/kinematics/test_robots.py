"""Robot library: built-in arms, user tables, validation, gravity torques."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from station.errors import ConfigError, DataError
from station.models.kinematics import frames, tool_position
from station.models.robots import (
    GRAVITY_M_S2,
    ROBOT_NAMES,
    get_robot,
    gravity_torques,
    potential_energy,
    robot_from_table,
)

from .conftest import perturbed_dh, random_q

EPS = np.finfo(float).eps


def test_every_builtin_is_complete(robot):
    assert robot.dh_nominal.shape == (7, 5)
    assert robot.joint_limits_rad.shape == (6, 2)
    assert np.all(robot.joint_limits_rad[:, 0] < robot.joint_limits_rad[:, 1])
    assert robot.joint_speed_limits_rad_s.shape == (6,) and np.all(robot.joint_speed_limits_rad_s > 0)
    assert robot.joint_accel_limits_rad_s2.shape == (6,) and np.all(robot.joint_accel_limits_rad_s2 > 0)
    assert robot.max_tcp_speed_mm_s > 0 and robot.rated_payload_kg > 0
    assert robot.link_mass_kg.shape == (6,) and robot.link_mass_kg.sum() > 0
    assert robot.link_com_mm.shape == (6, 3)
    lim = robot.joint_limits_rad
    assert np.all((robot.home_q_rad >= lim[:, 0]) & (robot.home_q_rad <= lim[:, 1]))
    assert robot.description


def test_spec_is_frozen_and_read_only():
    r = get_robot("ur5e")
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.name = "x"
    with pytest.raises(ValueError):
        r.dh_nominal[0, 0] = 1.0
    # get_robot hands out independent, equal specs
    assert get_robot("ur5e") == r and hash(get_robot("ur5e")) == hash(r)
    assert get_robot("ur5e").dh_nominal is not r.dh_nominal
    assert get_robot("ur10e") != r
    assert dataclasses.replace(r, rated_payload_kg=4.0) != r


def test_published_numbers():
    ur5e, ur10e = get_robot("ur5e"), get_robot("ur10e")
    assert ur5e.rated_payload_kg == 5.0 and ur10e.rated_payload_kg == 12.5
    np.testing.assert_allclose(ur5e.link_mass_kg, [3.761, 8.058, 2.846, 1.37, 1.3, 0.365])
    np.testing.assert_allclose(ur10e.dh_nominal[:6, 0], [0, -612.7, -571.55, 0, 0, 0])
    np.testing.assert_allclose(np.rad2deg(ur10e.joint_speed_limits_rad_s[:2]), [120, 120])
    rb5 = get_robot("rb5-850")
    np.testing.assert_allclose(rb5.dh_nominal[6], [0, 0, -88.0, 0, 0])  # seed 002 Table 2 TCP row


def test_unknown_robot_lists_known_names():
    with pytest.raises(ConfigError) as info:
        get_robot("kr-999")
    msg = str(info.value)
    assert "kr-999" in msg
    for name in ROBOT_NAMES:
        assert name in msg
    with pytest.raises(ConfigError):
        get_robot(None)


def test_industrial_arm_workspace_holds_the_cube():
    # every cube point (seed 000 Table 1) is inside the sphere the wrist
    # centre can reach from the shoulder, with the reflector adapter
    r = get_robot("industrial-3100")
    F = frames(r.dh_nominal, np.zeros(6))
    shoulder = F[1, :3, 3]
    upper = r.dh_nominal[1, 0]
    fore = np.hypot(r.dh_nominal[2, 0], r.dh_nominal[3, 2])
    corners = np.array([[x, y, z] for x in (-600, 600) for y in (1100, 2300) for z in (800, 2000)], float)
    tool = r.dh_nominal[5, 2] + r.dh_nominal[6, 2]
    wrist = corners - [0, tool, 0]  # reflector facing +y
    # shoulder circle radius 350 about the base axis: worst case distance
    rad = np.hypot(wrist[:, 0], wrist[:, 1]) - shoulder[0]
    dist = np.hypot(rad, wrist[:, 2] - shoulder[2])
    assert np.all(dist < upper + fore) and np.all(dist > abs(upper - fore))


def _table(**over):
    base = dict(
        name="user-arm",
        dh_table_deg=[
            [0, -90, 169.2, 0, 0], [425, 0, 0, -90, 0], [392, 0, 0, 0, 0],
            [0, 90, -110.7, 90, 0], [0, -90, 110.7, 0, 0], [0, 0, -94.7, 0, 0], [0, 0, 0, 0, 0],
        ],
        joint_limits_deg=[[-360, 360]] * 6,
        joint_speed_limits_deg_s=[180] * 6,
        joint_accel_limits_deg_s2=[400] * 6,
        max_tcp_speed_mm_s=1000.0,
        rated_payload_kg=5.0,
    )
    base.update(over)
    return base


def test_robot_from_table_converts_units():
    r = robot_from_table(**_table())
    np.testing.assert_allclose(r.dh_nominal[1, 3], -np.pi / 2)
    np.testing.assert_allclose(r.joint_limits_rad[0], [-2 * np.pi, 2 * np.pi])
    np.testing.assert_allclose(r.joint_speed_limits_rad_s, np.pi)
    np.testing.assert_allclose(r.home_q_rad, 0.0)
    np.testing.assert_allclose(tool_position(r.dh_nominal, np.zeros(6))[1], -(110.7 + 94.7))


@pytest.mark.parametrize(
    "over, field",
    [
        (dict(dh_table_deg=np.zeros((6, 5))), "dh_table_deg"),
        (dict(dh_table_deg=np.full((7, 5), np.nan)), "dh_table_deg"),
        (dict(joint_limits_deg=[[10, -10]] * 6), "joint_limits_deg"),
        (dict(joint_limits_deg=[[-10, 10]] * 5), "joint_limits_deg"),
        (dict(joint_speed_limits_deg_s=[180] * 5 + [-1]), "joint_speed_limits_deg_s"),
        (dict(joint_accel_limits_deg_s2=[0] * 6), "joint_accel_limits_deg_s2"),
        (dict(max_tcp_speed_mm_s=-5.0), "max_tcp_speed_mm_s"),
        (dict(max_tcp_speed_mm_s=float("nan")), "max_tcp_speed_mm_s"),
        (dict(rated_payload_kg="heavy"), "rated_payload_kg"),
        (dict(link_mass_kg=[1, 1, 1, 1, 1, -1]), "link_mass_kg"),
        (dict(link_com_mm=np.zeros((6, 2))), "link_com_mm"),
        (dict(home_q_deg=[0, 0, 0, 0, 0, 400]), "home_q_rad"),
        (dict(name=""), "name"),
    ],
)
def test_bad_tables_are_refused_naming_the_field(over, field):
    with pytest.raises(ConfigError, match=field):
        robot_from_table(**_table(**over))


def test_direct_construction_is_validated():
    good = get_robot("rb5-850")
    with pytest.raises(ConfigError, match="dh_nominal"):
        dataclasses.replace(good, dh_nominal=np.zeros((7, 4)))
    with pytest.raises(ConfigError, match=r"joint_limits_rad.*joint 3"):
        lim = good.joint_limits_rad.copy()
        lim[2] = [1.0, -1.0]
        dataclasses.replace(good, joint_limits_rad=lim)
    with pytest.raises(ConfigError, match="joint_speed_limits_rad_s"):
        dataclasses.replace(good, joint_speed_limits_rad_s=np.full(6, np.inf))
    calibrated = good.with_dh(get_robot("rb5-850-as-built").dh_nominal, name="rb5-cal")
    assert calibrated.name == "rb5-cal" and calibrated.rated_payload_kg == good.rated_payload_kg


# --------------------------------------------------------------------------
# gravity
# --------------------------------------------------------------------------
@pytest.mark.parametrize("name", ROBOT_NAMES)
def test_gravity_torques_are_the_gradient_of_potential_energy(rng, name):
    # Central differences of V(q); V is a sum of heights of points rotating
    # about the joint axes, so |V'''| <= g * sum(m) * R and the FD error is
    # below h^2/6 * that + c * eps * |V|max / h.
    robot = get_robot(name)
    dh = perturbed_dh(rng, robot.dh_nominal)
    payload = rng.uniform(0, robot.rated_payload_kg)
    n, h = 15, 1e-5
    q = random_q(rng, robot, n)
    tau = gravity_torques(robot, dh, q, payload_kg=payload)
    assert tau.shape == (n, 6)
    E = np.eye(6) * h
    Vp = potential_energy(robot, dh, (q[:, None] + E).reshape(-1, 6), payload).reshape(n, 6)
    Vm = potential_energy(robot, dh, (q[:, None] - E).reshape(-1, 6), payload).reshape(n, 6)
    fd = (Vp - Vm) / (2 * h)
    R_m = 1e-3 * (np.abs(dh[:, [0, 2]]).sum() + np.abs(robot.link_com_mm).sum())
    scale = GRAVITY_M_S2 * (robot.link_mass_kg.sum() + payload) * R_m
    bound = h**2 / 6 * scale + 50 * EPS * scale / h
    assert np.abs(tau - fd).max() <= 4 * bound
    assert np.abs(tau - fd).max() <= 1e-6 * np.abs(tau).max()
    # joint 1 turns about the vertical base axis: gravity does no work on it
    np.testing.assert_allclose(tau[:, 0], 0.0, atol=1e-9 * scale)


def test_gravity_hand_computed_single_link():
    # Only link 2 has mass, at the middle of the 425 mm upper arm
    # (frame 2 sits at the elbow, x along the arm): holding torque at the
    # shoulder is m g (L/2) sin(q2) with q2 measured from vertical.
    r = robot_from_table(
        **_table(link_mass_kg=[0, 10.0, 0, 0, 0, 0], link_com_mm=[[0, 0, 0], [-212.5, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]])
    )
    q2 = np.deg2rad(np.array([0.0, 30.0, 90.0, -45.0]))
    q = np.zeros((4, 6))
    q[:, 1] = q2
    tau = gravity_torques(r, None, q)
    # joint 2 axis z1 = +y0; tilting the arm by q2 about +y0 moves the
    # centre towards +x and down, so V falls: dV/dq2 = -m g (L/2) sin(q2)
    np.testing.assert_allclose(tau[:, 1], -10.0 * GRAVITY_M_S2 * 0.2125 * np.sin(q2), atol=1e-9)
    np.testing.assert_allclose(tau[:, [0, 2, 3, 4, 5]], 0.0, atol=1e-9)


def test_payload_torque_hand_computed():
    # Massless UR5e at q = 0 (stretched along -x): a payload at the TCP
    # loads the shoulder with m g times the horizontal lever a2 + a3 = 817.2 mm.
    r = dataclasses.replace(get_robot("ur5e"), link_mass_kg=np.zeros(6))
    tau = gravity_torques(r, None, np.zeros(6), payload_kg=5.0)
    assert tau.shape == (6,)
    lever_m = 0.8172
    np.testing.assert_allclose(abs(tau[1]), 5.0 * GRAVITY_M_S2 * lever_m, rtol=1e-12)
    np.testing.assert_allclose(abs(tau[2]), 5.0 * GRAVITY_M_S2 * 0.3922, rtol=1e-12)


def test_gravity_bad_input():
    r = get_robot("ur5e")
    with pytest.raises(ConfigError, match="payload_kg"):
        gravity_torques(r, None, np.zeros(6), payload_kg=-1.0)
    with pytest.raises(DataError, match="q_rad"):
        gravity_torques(r, None, np.zeros((2, 5)))
    with pytest.raises(DataError, match="dh"):
        gravity_torques(r, np.zeros((7, 3)), np.zeros(6))


def test_the_controller_kind_is_the_arms_not_its_name():
    """What drives an arm (program upload, or a UR controller) is a field of its spec, checked on construction;
    the station's choices (the fake controller, UR calibration deltas) read it, not the name's first letters."""
    import dataclasses

    from fakes.station import robot_fake
    from procedures.arm_calibration import ArmCalPlan
    from station.errors import ConfigError
    from station.models.robots import CONTROLLER_KINDS, ROBOT_NAMES, get_robot

    kinds = {n: get_robot(n).controller for n in ROBOT_NAMES}
    assert set(kinds.values()) <= set(CONTROLLER_KINDS)
    assert kinds["ur5e"] == kinds["ur10e"] == "ur" and kinds["industrial-3100"] == "program-upload"
    assert {n: robot_fake(n) for n in ROBOT_NAMES} == {n: "ur" if k == "ur" else "controller" for n, k in kinds.items()}
    # an arm named "ur..." that is not driven as a UR is not calibrated as one
    urchin = dataclasses.replace(get_robot("ur5e"), name="urchin-1", controller="program-upload")
    assert ArmCalPlan.is_ur.fget(type("P", (), {"robot": urchin})()) is False
    assert ArmCalPlan.is_ur.fget(type("P", (), {"robot": get_robot("ur10e")})()) is True
    with pytest.raises(ConfigError, match="`controller` must be one of"):
        dataclasses.replace(get_robot("ur5e"), controller="kuka")
