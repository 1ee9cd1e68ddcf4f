"""Forward kinematics: seed 002 eq. (3) and (5) against hand numbers and an
independent composition of elementary transforms."""

from __future__ import annotations

import numpy as np
import pytest

from station.errors import ConfigError, DataError
from station.models.kinematics import (
    dh_from_degrees,
    dh_to_degrees,
    fk,
    frames,
    link_transforms,
    tool_position,
)
from station.models.robots import get_robot

from .conftest import perturbed_dh, random_q


def rot(axis, ang):
    c, s = np.cos(ang), np.sin(ang)
    T = np.eye(4)
    if axis == "x":
        T[1:3, 1:3] = [[c, -s], [s, c]]
    elif axis == "y":
        T[0, 0], T[0, 2], T[2, 0], T[2, 2] = c, s, -s, c
    else:
        T[0:2, 0:2] = [[c, -s], [s, c]]
    return T


def trans(axis, dist):
    T = np.eye(4)
    T["xyz".index(axis), 3] = dist
    return T


def reference_fk(dh, q):
    """One pose, written as the product Rz Tz Tx Rx Ry per row (seed 002 eq. (3))."""
    T = np.eye(4)
    for i in range(7):
        a, al, d, th, be = dh[i]
        th = th + (q[i] if i < 6 else 0.0)
        T = T @ rot("z", th) @ trans("z", d) @ trans("x", a) @ rot("x", al) @ rot("y", be)
    return T


def test_rb5_zero_pose_by_hand():
    # q = 0: the arm stands upright; z = d1 + a2 + a3 + d5, the offsets d4,
    # d6 and the jig (TCP d) all point along -y (seed 002 Table 2).
    dh = get_robot("rb5-850").dh_nominal
    T = fk(dh, np.zeros(6))
    assert T.shape == (4, 4)
    np.testing.assert_allclose(T[:3, 3], [0.0, -(110.7 + 94.7 + 88.0), 169.2 + 425.0 + 392.0 + 110.7], atol=1e-9)
    # tool z axis along +y (the jig offset d = -88 then points along -y)
    np.testing.assert_allclose(T[:3, 2], [0.0, 1.0, 0.0], atol=1e-12)


def test_ur5e_zero_pose_matches_published_dh():
    # Universal Robots' published UR5e DH: at q = 0 the arm is stretched
    # along -x: x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
    T = fk(get_robot("ur5e").dh_nominal, np.zeros((1, 6)))
    assert T.shape == (1, 4, 4)
    np.testing.assert_allclose(T[0, :3, 3], [-425.0 - 392.2, -(133.3 + 99.6), 162.5 - 99.7], atol=1e-9)


def test_ur5e_shoulder_up_pose_by_hand():
    # q2 = -90 deg lifts the upper arm and forearm vertical; q4 = -90 deg
    # puts the wrist back: z = d1 + |a2| + |a3| + d5, x = 0... computed by hand:
    q = np.deg2rad([0.0, -90.0, 0.0, -90.0, 0.0, 0.0])
    p = tool_position(get_robot("ur5e").dh_nominal, q)
    np.testing.assert_allclose(p, [0.0, -(133.3 + 99.6), 162.5 + 425.0 + 392.2 + 99.7], atol=1e-9)


def test_link_transform_is_eq3_product(rng):
    dh = perturbed_dh(rng, get_robot("rb5-850").dh_nominal, ang_sigma_rad=0.3)
    q = rng.uniform(-np.pi, np.pi, 6)
    A = link_transforms(dh, q)
    for i in range(7):
        a, al, d, th, be = dh[i]
        th = th + (q[i] if i < 6 else 0.0)
        ref = rot("z", th) @ trans("z", d) @ trans("x", a) @ rot("x", al) @ rot("y", be)
        np.testing.assert_allclose(A[i], ref, atol=1e-12)


def test_vectorised_fk_equals_reference(rng, robot):
    dh = perturbed_dh(rng, robot.dh_nominal, ang_sigma_rad=0.05)
    q = random_q(rng, robot, 50)
    T = fk(dh, q)
    assert T.shape == (50, 4, 4)
    ref = np.stack([reference_fk(dh, qi) for qi in q])
    np.testing.assert_allclose(T, ref, atol=1e-9)
    np.testing.assert_allclose(tool_position(dh, q), ref[:, :3, 3], atol=1e-9)


def test_per_sample_dh(rng):
    robot = get_robot("ur10e")
    n = 20
    dh = perturbed_dh(rng, robot.dh_nominal, n=n)
    q = random_q(rng, robot, n)
    T = fk(dh, q)
    ref = np.stack([reference_fk(dh[i], q[i]) for i in range(n)])
    np.testing.assert_allclose(T, ref, atol=1e-9)
    # one q broadcast over per-sample tables
    T1 = fk(dh, q[0])
    ref1 = np.stack([reference_fk(dh[i], q[0]) for i in range(n)])
    np.testing.assert_allclose(T1, ref1, atol=1e-9)


def test_frames_chain(rng):
    dh = get_robot("rb5-850-as-built").dh_nominal
    q = rng.uniform(-3, 3, (5, 6))
    F = frames(dh, q)
    assert F.shape == (5, 8, 4, 4)
    np.testing.assert_allclose(F[:, 0], np.broadcast_to(np.eye(4), (5, 4, 4)))
    np.testing.assert_allclose(F[:, 7], fk(dh, q), atol=1e-12)
    R = F[:, :, :3, :3]
    np.testing.assert_allclose(np.einsum("nkji,nkjl->nkil", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_as_built_differs_from_nominal_by_table3():
    nom = get_robot("rb5-850").dh_nominal
    built = get_robot("rb5-850-as-built").dh_nominal
    np.testing.assert_allclose(dh_to_degrees(built)[1], [427.82, 0.1016, 0.0, -90.326, 0.073734])
    np.testing.assert_allclose(dh_to_degrees(built)[6], [0, 0, -89.256, 0, 0])
    np.testing.assert_allclose(dh_to_degrees(nom)[3], [0.0, 90.0, -110.7, 90.0, 0.0])
    d = np.linalg.norm(tool_position(built, np.zeros(6)) - tool_position(nom, np.zeros(6)))
    assert 1.0 < d < 20.0  # mm-level, as the seed's 4 mm max distance errors suggest


def test_beta_is_a_rotation_about_the_intermediate_y_axis(rng):
    # Changing beta_i rotates everything after frame i about the y axis of
    # frame (Rz Tz Tx Rx) -- the Hayati parallel-axis parameter of eq. (3).
    dh = get_robot("rb5-850").dh_nominal.copy()
    q = rng.uniform(-2, 2, 6)
    beta = rng.uniform(0.05, 0.2)
    dh_b = dh.copy()
    dh_b[1, 4] = beta
    F = frames(dh, q)
    M = F[1] @ rot("z", dh[1, 3] + q[1]) @ trans("z", dh[1, 2]) @ trans("x", dh[1, 0]) @ rot("x", dh[1, 1])
    expected = M @ rot("y", beta) @ np.linalg.inv(M) @ F[7]
    np.testing.assert_allclose(fk(dh_b, q), expected, atol=1e-9)
    # the tool moves on a circle about that axis: chord = 2 sin(beta/2) * radius
    axis = M[:3, 1]
    r = F[7][:3, 3] - M[:3, 3]
    radius = np.linalg.norm(r - axis * (axis @ r))
    chord = np.linalg.norm(fk(dh_b, q)[:3, 3] - F[7][:3, 3])
    np.testing.assert_allclose(chord, 2 * np.sin(beta / 2) * radius, rtol=1e-9)


def test_dh_from_degrees_converts_angle_columns():
    table = np.arange(35, dtype=float).reshape(7, 5)
    out = dh_from_degrees(table)
    np.testing.assert_allclose(out[:, [0, 2]], table[:, [0, 2]])
    np.testing.assert_allclose(out[:, [1, 3, 4]], np.deg2rad(table[:, [1, 3, 4]]))
    np.testing.assert_allclose(dh_to_degrees(out), table)


@pytest.mark.parametrize(
    "dh, q, match",
    [
        (np.zeros((6, 5)), np.zeros(6), "dh"),
        (np.zeros((7, 4)), np.zeros(6), "dh"),
        (np.full((7, 5), np.nan), np.zeros(6), "dh"),
        (np.zeros((7, 5)), np.zeros(5), "q_rad"),
        (np.zeros((7, 5)), np.zeros((3, 7)), "q_rad"),
        (np.zeros((7, 5)), [[0, 0, 0, np.inf, 0, 0]], "q_rad"),
        (np.zeros((7, 5)), "abc", "q_rad"),
        (np.zeros((4, 7, 5)), np.zeros((3, 6)), "q_rad"),
    ],
)
def test_bad_input_is_refused_naming_the_argument(dh, q, match):
    with pytest.raises(DataError, match=match):
        fk(dh, q)


def test_bad_degree_table_is_config_error():
    with pytest.raises(ConfigError, match="dh_table"):
        dh_from_degrees(np.zeros((7, 6)))
    bad = np.zeros((7, 5))
    bad[3, 1] = np.nan
    with pytest.raises(ConfigError, match=r"dh_table.*\(3, 1\)"):
        dh_from_degrees(bad)


def test_empty_batch():
    assert fk(np.zeros((7, 5)), np.zeros((0, 6))).shape == (0, 4, 4)


def test_industrial_zero_pose_by_hand():
    # q = 0: upper arm vertical, forearm horizontal along +x, tool along +x:
    # x = a1 + d4 + d6 + tool, z = d1 + a2 + a3 (forearm offset -41 mm).
    T = fk(get_robot("industrial-3100").dh_nominal, np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [350.0 + 1400.0 + 240.0 + 100.0, 0.0, 675.0 + 1350.0 - 41.0], atol=1e-9)
    np.testing.assert_allclose(T[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)
