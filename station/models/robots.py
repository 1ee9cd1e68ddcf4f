"""Robot library: kinematic tables, limits and a simple mass model per arm.

A :class:`RobotSpec` bundles everything the station needs to know about an
arm: the nominal DH + Hayati table of seed 002 eq. (3) (``(7, 5)``, mm/rad,
columns ``[a, alpha, d, theta_offset, beta]``, rows joints 1..6 then TCP), joint
position/speed/acceleration limits, the maximum TCP speed, the rated payload
and a lumped mass model (one point mass per moving link) for gravity torques.

Mass-model convention: ``link_com_mm[j]`` is the centre of mass of link
``j + 1`` expressed in DH frame ``j + 1`` (the frame after row ``j + 1`` of the
table, i.e. the frame that moves with joint ``j + 1``), as in Universal
Robots' published dynamics table. The payload is a point mass at the TCP
origin (frame after the TCP row).

Built-in arms (:func:`get_robot`): ``"rb5-850"``, ``"rb5-850-as-built"``,
``"ur5e"``, ``"ur10e"``, ``"industrial-3100"``; :func:`robot_from_table`
builds one from a user table written in file units (degrees).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from station.errors import ConfigError
from station.models.kinematics import (
    N_JOINTS,
    _frames,
    _prepare,
    dh_from_degrees,
    validate_dh,
    validate_joint_limits,
)

__all__ = [
    "GRAVITY_M_S2",
    "RobotSpec",
    "CONTROLLER_KINDS",
    "ROBOT_NAMES",
    "get_robot",
    "robot_from_table",
    "gravity_torques",
    "potential_energy",
]

#: Standard gravity (m/s^2); gravity acts along -z of the robot base frame.
GRAVITY_M_S2 = 9.80665


def _vec(x, name: str, shape: tuple, *, positive=False, nonneg=False) -> np.ndarray:
    try:
        arr = np.array(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"`{name}` must be numeric: {exc}") from exc
    if arr.shape != shape:
        raise ConfigError(f"`{name}` must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"`{name}` contains non-finite values (NaN/inf)")
    if positive and np.any(arr <= 0):
        i = int(np.argmax(arr.reshape(-1) <= 0))
        raise ConfigError(f"`{name}` must be > 0, element {i} is {arr.reshape(-1)[i]!r}")
    if nonneg and np.any(arr < 0):
        i = int(np.argmax(arr.reshape(-1) < 0))
        raise ConfigError(f"`{name}` must be >= 0, element {i} is {arr.reshape(-1)[i]!r}")
    arr.setflags(write=False)
    return arr


#: the kinds of controller the station drives (:attr:`RobotSpec.controller`)
CONTROLLER_KINDS = ("program-upload", "ur")


@dataclass(frozen=True, eq=False)
class RobotSpec:
    """Everything the station knows about one arm (validated at construction).

    Attributes
    ----------
    name : str
    dh_nominal : ndarray, shape (7, 5)
        DH + Hayati table (seed 002 eq. (3)), mm/rad,
        ``[a, alpha, d, theta_offset, beta]``; rows joints 1..6, TCP.
    joint_limits_rad : ndarray, shape (6, 2)
        ``[min, max]`` per joint.
    joint_speed_limits_rad_s : ndarray, shape (6,)
    joint_accel_limits_rad_s2 : ndarray, shape (6,)
    max_tcp_speed_mm_s : float
    rated_payload_kg : float
    link_mass_kg : ndarray, shape (6,)
        Mass of each moving link (link j moves with joint j).
    link_com_mm : ndarray, shape (6, 3)
        Centre of mass of link j in DH frame j (see module docstring).
    home_q_rad : ndarray, shape (6,)
        A safe, non-singular home pose inside the limits.
    description : str
        Where the numbers come from.
    controller : {"program-upload", "ur"}
        The kind of controller the arm's maker ships, which decides how the
        station drives it (:data:`CONTROLLER_KINDS`): a program file uploaded
        (FTP) and started and watched (Modbus TCP), or a UR controller (RTDE,
        dashboard, URScript; calibration written as UR deltas).
    stop_scatter_mm : (float, float)
        Range of the arm's stop scatter, mm (1 sigma per coordinate of the
        TCP at home): a simulated arm of the model draws its scatter uniformly
        from it (:func:`station.models.effects.realistic_stop_sigma_rad`).
        ISO 9283 RP is about 3.6 times the scatter.

    Raises
    ------
    ConfigError
        On construction, for any wrong shape, non-finite value, negative or
        zero rate, ``min > max`` joint limit or home pose outside the limits;
        the message names the field.
    """

    name: str
    dh_nominal: np.ndarray
    joint_limits_rad: np.ndarray
    joint_speed_limits_rad_s: np.ndarray
    joint_accel_limits_rad_s2: np.ndarray
    max_tcp_speed_mm_s: float
    rated_payload_kg: float
    link_mass_kg: np.ndarray
    link_com_mm: np.ndarray
    home_q_rad: np.ndarray
    description: str = field(default="", compare=False)
    controller: str = "program-upload"
    stop_scatter_mm: tuple = (0.012, 0.04)

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.strip():
            raise ConfigError(f"`name` must be a non-empty string, got {self.name!r}")
        if self.controller not in CONTROLLER_KINDS:
            raise ConfigError(f"`controller` must be one of {', '.join(CONTROLLER_KINDS)}, got {self.controller!r}")
        try:
            lo, hi = (float(v) for v in self.stop_scatter_mm)
        except (TypeError, ValueError):
            raise ConfigError(f"`stop_scatter_mm` must be a (low, high) range in mm, got {self.stop_scatter_mm!r}") from None
        if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi <= 1.0):
            raise ConfigError(f"`stop_scatter_mm` must satisfy 0 <= low <= high <= 1 mm, got {self.stop_scatter_mm!r}")
        object.__setattr__(self, "stop_scatter_mm", (lo, hi))
        dh = validate_dh(self.dh_nominal, name="dh_nominal", error=ConfigError)
        if dh.ndim != 2:
            raise ConfigError(f"`dh_nominal` must have shape (7, 5), got {dh.shape}")
        dh = dh.copy()
        dh.setflags(write=False)
        lim = validate_joint_limits(self.joint_limits_rad, name="joint_limits_rad", error=ConfigError).copy()
        lim.setflags(write=False)
        sets = {
            "dh_nominal": dh,
            "joint_limits_rad": lim,
            "joint_speed_limits_rad_s": _vec(self.joint_speed_limits_rad_s, "joint_speed_limits_rad_s", (6,), positive=True),
            "joint_accel_limits_rad_s2": _vec(self.joint_accel_limits_rad_s2, "joint_accel_limits_rad_s2", (6,), positive=True),
            "link_mass_kg": _vec(self.link_mass_kg, "link_mass_kg", (6,), nonneg=True),
            "link_com_mm": _vec(self.link_com_mm, "link_com_mm", (6, 3)),
            "home_q_rad": _vec(self.home_q_rad, "home_q_rad", (6,)),
        }
        for name in ("max_tcp_speed_mm_s", "rated_payload_kg"):
            val = getattr(self, name)
            try:
                val = float(val)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"`{name}` must be a number, got {val!r}") from exc
            if not np.isfinite(val) or val < 0 or (name == "max_tcp_speed_mm_s" and val == 0):
                raise ConfigError(f"`{name}` must be a finite {'positive' if name.startswith('max') else 'non-negative'} number, got {val!r}")
            sets[name] = val
        home = sets["home_q_rad"]
        out = np.nonzero((home < lim[:, 0]) | (home > lim[:, 1]))[0]
        if out.size:
            j = int(out[0])
            raise ConfigError(
                f"`home_q_rad` joint {j + 1} = {home[j]:.6g} rad is outside "
                f"`joint_limits_rad` [{lim[j, 0]:.6g}, {lim[j, 1]:.6g}]"
            )
        for k, v in sets.items():
            object.__setattr__(self, k, v)

    def __eq__(self, other):
        if not isinstance(other, RobotSpec):
            return NotImplemented
        return all(
            np.array_equal(getattr(self, f.name), getattr(other, f.name))
            for f in fields(self)
            if f.compare
        )

    def __hash__(self):
        return hash((self.name, self.dh_nominal.tobytes(), self.joint_limits_rad.tobytes()))

    def with_dh(self, dh, name: str | None = None) -> "RobotSpec":
        """A copy with another (e.g. calibrated) DH table, re-validated."""
        from dataclasses import replace

        return replace(self, dh_nominal=dh, name=name or self.name)


# --------------------------------------------------------------------------
# user tables
# --------------------------------------------------------------------------
def robot_from_table(
    name: str,
    dh_table_deg,
    joint_limits_deg,
    joint_speed_limits_deg_s,
    joint_accel_limits_deg_s2,
    max_tcp_speed_mm_s: float,
    rated_payload_kg: float,
    link_mass_kg=None,
    link_com_mm=None,
    home_q_deg=None,
    description: str = "user table",
) -> RobotSpec:
    """Build a :class:`RobotSpec` from values in file units (mm, degrees).

    Parameters
    ----------
    name : str
    dh_table_deg : array_like, shape (7, 5)
        ``[a_mm, alpha_deg, d_mm, theta_offset_deg, beta_deg]`` like seed 002
        Table 2.
    joint_limits_deg : array_like, shape (6, 2)
    joint_speed_limits_deg_s, joint_accel_limits_deg_s2 : array_like, shape (6,)
    max_tcp_speed_mm_s, rated_payload_kg : float
    link_mass_kg : array_like, shape (6,), optional
        Default zeros (no gravity model).
    link_com_mm : array_like, shape (6, 3), optional
        Default zeros (each mass at its frame origin).
    home_q_deg : array_like, shape (6,), optional
        Default: middle of the joint limits.

    Returns
    -------
    RobotSpec

    Raises
    ------
    ConfigError
        Naming the field (``dh_table_deg``, ``joint_limits_deg`` ...).
    """
    dh = dh_from_degrees(dh_table_deg, name="dh_table_deg")
    lim = np.deg2rad(validate_joint_limits(joint_limits_deg, name="joint_limits_deg", error=ConfigError))
    spd = np.deg2rad(_vec(joint_speed_limits_deg_s, "joint_speed_limits_deg_s", (6,), positive=True))
    acc = np.deg2rad(_vec(joint_accel_limits_deg_s2, "joint_accel_limits_deg_s2", (6,), positive=True))
    mass = np.zeros(6) if link_mass_kg is None else link_mass_kg
    com = np.zeros((6, 3)) if link_com_mm is None else link_com_mm
    if home_q_deg is None:
        home = lim.mean(axis=1)
    else:
        home = np.deg2rad(_vec(home_q_deg, "home_q_deg", (6,)))
    return RobotSpec(
        name=name,
        dh_nominal=dh,
        joint_limits_rad=lim,
        joint_speed_limits_rad_s=spd,
        joint_accel_limits_rad_s2=acc,
        max_tcp_speed_mm_s=max_tcp_speed_mm_s,
        rated_payload_kg=rated_payload_kg,
        link_mass_kg=mass,
        link_com_mm=com,
        home_q_rad=home,
        description=description,
    )


# --------------------------------------------------------------------------
# built-in arms
# --------------------------------------------------------------------------
_D = np.deg2rad

# Seed 002 Table 2: nominal DH of the Rainbow Robotics RB5-850 (TCP row: the
# measuring jig, d = -88 mm). Columns a_mm, alpha_deg, d_mm, theta_offset_deg, beta_deg.
_RB5_NOMINAL_DEG = [
    [0.0, -90.0, 169.2, 0.0, 0.0],
    [425.0, 0.0, 0.0, -90.0, 0.0],
    [392.0, 0.0, 0.0, 0.0, 0.0],
    [0.0, 90.0, -110.7, 90.0, 0.0],
    [0.0, -90.0, 110.7, 0.0, 0.0],
    [0.0, 0.0, -94.7, 0.0, 0.0],
    [0.0, 0.0, -88.0, 0.0, 0.0],
]

# Seed 002 Table 3: calibrated ("as built") DH of the same arm.
_RB5_AS_BUILT_DEG = [
    [0.99473, -90.012, 169.2, 0.0, 0.0],
    [427.82, 0.1016, 0.0, -90.326, 0.073734],
    [393.42, -0.2404, 0.0, 0.3716, 0.0],
    [0.45798, 90.058, -110.92, 89.503, 0.0],
    [0.0, -90.375, 110.7, 0.1903, 0.0],
    [0.03181, 0.0, -95.957, 0.0, 0.0],
    [0.0, 0.0, -89.256, 0.0, 0.0],
]


def _rb5(name: str, table, description: str) -> RobotSpec:
    # Limits: Rainbow Robotics RB5-850 public datasheet (reach 850 mm,
    # payload 5 kg, weight ~21 kg, joint range +/-360 deg, joint speed
    # 180 deg/s, TCP speed 1 m/s). Accelerations are not published: a
    # collaborative-arm value of 400 deg/s^2 is assumed.
    # Mass model: ~21 kg total split over the links (approximation; the base
    # housing does not move); centres roughly mid-link in DH frame j.
    return RobotSpec(
        name=name,
        dh_nominal=dh_from_degrees(table),
        joint_limits_rad=np.tile(_D([-360.0, 360.0]), (6, 1)),
        joint_speed_limits_rad_s=_D(np.full(6, 180.0)),
        joint_accel_limits_rad_s2=_D(np.full(6, 400.0)),
        max_tcp_speed_mm_s=1000.0,
        rated_payload_kg=5.0,
        link_mass_kg=np.array([3.5, 6.5, 2.8, 1.3, 1.3, 0.5]),
        link_com_mm=np.array(
            [
                [0.0, 50.0, 0.0],
                [-212.5, 0.0, 60.0],
                [-196.0, 0.0, -40.0],
                [0.0, 0.0, 50.0],
                [0.0, 0.0, -40.0],
                [0.0, 0.0, -20.0],
            ]
        ),
        home_q_rad=_D([0.0, 0.0, 90.0, 0.0, 90.0, 0.0]),
        description=description,
    )


def _ur(name: str) -> RobotSpec:
    # Universal Robots, "DH parameters for calculations of kinematics and
    # dynamics" (support article, universal-robots.com): standard DH
    # (Rz(theta) Tz(d) Tx(a) Rx(alpha)) = seed 002 eq. (3) with beta = 0,
    # zero offsets; link masses and centres of mass from the same table, the
    # centres given in each link's DH frame (m there, mm here).
    # Limits: UR5e / UR10e datasheets (all joints +/-360 deg; TCP speed
    # 1 m/s; UR5e joints 180 deg/s; UR10e base and shoulder 120 deg/s, the
    # others 180 deg/s; payload 5 kg / 12.5 kg). Joint acceleration is not
    # published as a limit: 800 deg/s^2 is assumed (a typical
    # controller-side bound).
    if name == "ur5e":
        a = [0.0, -425.0, -392.2, 0.0, 0.0, 0.0]
        d = [162.5, 0.0, 0.0, 133.3, 99.7, 99.6]
        mass = [3.761, 8.058, 2.846, 1.37, 1.3, 0.365]
        com_m = [
            [0.0, -0.02561, 0.00193],
            [0.2125, 0.0, 0.11336],
            [0.15, 0.0, 0.0265],
            [0.0, -0.0018, 0.01634],
            [0.0, 0.0018, 0.01634],
            [0.0, 0.0, -0.001159],
        ]
        speed = [180.0] * 6
        payload = 5.0
        # stop scatter: a UR5e measured by a Leica tracker (issue 42) gave RP 0.012-0.024 mm at two poses; the
        # lab's program replayed on the simulated arm gives that RP with 5-11 um per coordinate at home
        scatter = (0.005, 0.011)
    else:
        a = [0.0, -612.7, -571.55, 0.0, 0.0, 0.0]
        d = [180.7, 0.0, 0.0, 174.15, 119.85, 116.55]
        mass = [7.369, 13.051, 3.989, 2.1, 1.98, 0.615]
        com_m = [
            [0.021, 0.0, 0.027],
            [0.38, 0.0, 0.158],
            [0.24, 0.0, 0.068],
            [0.0, 0.007, 0.018],
            [0.0, 0.007, 0.018],
            [0.0, 0.0, -0.026],
        ]
        speed = [120.0, 120.0, 180.0, 180.0, 180.0, 180.0]
        payload = 12.5
        # the UR5e's, widened by the data sheets' repeatability ratio (UR10e +/-0.05 mm, UR5e +/-0.03 mm)
        scatter = (0.008, 0.018)
    alpha = [90.0, 0.0, 0.0, 90.0, -90.0, 0.0]
    table = [[a[i], alpha[i], d[i], 0.0, 0.0] for i in range(6)] + [[0.0, 0.0, 0.0, 0.0, 0.0]]
    return RobotSpec(
        name=name,
        dh_nominal=dh_from_degrees(table),
        joint_limits_rad=np.tile(_D([-360.0, 360.0]), (6, 1)),
        joint_speed_limits_rad_s=_D(np.array(speed)),
        joint_accel_limits_rad_s2=_D(np.full(6, 800.0)),
        max_tcp_speed_mm_s=1000.0,
        rated_payload_kg=payload,
        link_mass_kg=np.array(mass),
        link_com_mm=1000.0 * np.array(com_m),
        home_q_rad=_D([0.0, -90.0, 90.0, -90.0, -90.0, 0.0]),
        description=f"Universal Robots {name.upper()} nominal DH and dynamics table (public)",
        controller="ur",
        stop_scatter_mm=scatter,
    )


def _industrial_3100() -> RobotSpec:
    # A 3.1 m reach, 210 kg payload class arm, after the public data of the
    # KUKA KR 210 R3100 ultra (KR QUANTEC family) as transcribed in the open
    # ARTE robotics toolbox (robots/KUKA/KR210_R3100_ULTRA): shoulder height
    # 675 mm, shoulder offset 350 mm, upper arm 1350 mm, forearm offset
    # -41 mm, forearm (elbow to wrist centre) 1400 mm, wrist centre to flange
    # 240 mm; reach to the wrist centre ~3100 mm. Joint convention: q2 = 0
    # upper arm vertical (+ leans forward), q3 = 0 forearm perpendicular to
    # it (+ folds down). Ranges are the datasheet's (A1 +/-185, A2 -140..-5,
    # A3 -120..+155, A4 +/-350, A5 +/-122.5, A6 +/-350 deg) re-expressed in
    # this convention (q2 = A2 + 90, q3 = A3 - 90); speeds are the
    # datasheet's (105, 101, 107, 136, 129, 206 deg/s). Not published and
    # assumed here: accelerations, the 2 m/s TCP speed limit and the mass
    # model (robot weight ~1.1 t, ~750 kg of it moving, lumped per link, the
    # counterbalance ignored). The TCP row is a 100 mm reflector adapter on
    # the flange. The seed 000 test cube (x -600..600, y 1100..2300,
    # z 800..2000 mm) lies in front of the arm along +y (home: q1 = 90 deg).
    table = [
        [350.0, -90.0, 675.0, 0.0, 0.0],
        [1350.0, 0.0, 0.0, -90.0, 0.0],
        [-41.0, -90.0, 0.0, 0.0, 0.0],
        [0.0, 90.0, 1400.0, 0.0, 0.0],
        [0.0, -90.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 240.0, 0.0, 0.0],
        [0.0, 0.0, 100.0, 0.0, 0.0],
    ]
    limits_deg = [
        [-185.0, 185.0],
        [-50.0, 85.0],
        [-210.0, 65.0],
        [-350.0, 350.0],
        [-122.5, 122.5],
        [-350.0, 350.0],
    ]
    return RobotSpec(
        name="industrial-3100",
        dh_nominal=dh_from_degrees(table),
        joint_limits_rad=_D(np.array(limits_deg)),
        joint_speed_limits_rad_s=_D(np.array([105.0, 101.0, 107.0, 136.0, 129.0, 206.0])),
        joint_accel_limits_rad_s2=_D(np.array([200.0, 200.0, 200.0, 300.0, 300.0, 400.0])),
        max_tcp_speed_mm_s=2000.0,
        rated_payload_kg=210.0,
        link_mass_kg=np.array([330.0, 190.0, 160.0, 45.0, 20.0, 5.0]),
        link_com_mm=np.array(
            [
                [-200.0, 225.0, 0.0],
                [-675.0, 0.0, 0.0],
                [0.0, 0.0, 400.0],
                [0.0, -300.0, 0.0],
                [0.0, 0.0, 80.0],
                [0.0, 0.0, -20.0],
            ]
        ),
        home_q_rad=_D([90.0, -11.0, 35.0, 0.0, -24.0, 180.0]),
        description="industrial 6-axis arm, 3.1 m reach / 210 kg class (KUKA KR 210 R3100 ultra public dimensions, approximated)",
    )


_BUILDERS = {
    "rb5-850": lambda: _rb5("rb5-850", _RB5_NOMINAL_DEG, "Rainbow Robotics RB5-850, seed 002 Table 2 (nominal)"),
    "rb5-850-as-built": lambda: _rb5(
        "rb5-850-as-built", _RB5_AS_BUILT_DEG, "Rainbow Robotics RB5-850 as built, seed 002 Table 3 (calibrated)"
    ),
    "ur5e": lambda: _ur("ur5e"),
    "ur10e": lambda: _ur("ur10e"),
    "industrial-3100": _industrial_3100,
}

#: Names accepted by :func:`get_robot`.
ROBOT_NAMES = tuple(_BUILDERS)


def get_robot(name: str) -> RobotSpec:
    """Return the built-in :class:`RobotSpec` called ``name``.

    Raises
    ------
    ConfigError
        Unknown name; the message lists the known ones.
    """
    try:
        builder = _BUILDERS[name]
    except (KeyError, TypeError):
        raise ConfigError(
            f"unknown robot {name!r}; known robots: {', '.join(ROBOT_NAMES)}"
        ) from None
    return builder()


# --------------------------------------------------------------------------
# gravity
# --------------------------------------------------------------------------
def _mass_points(robot: RobotSpec, F: np.ndarray, payload_kg: float):
    """Point masses (N, 7) and their base-frame positions (N, 7, 3) in mm."""
    n = F.shape[0]
    R = F[:, 1:7, :3, :3]
    o = F[:, 1:7, :3, 3]
    c = o + np.einsum("nkij,kj->nki", R, robot.link_com_mm)
    pts = np.concatenate([c, F[:, 7:8, :3, 3]], axis=1)
    m = np.concatenate([robot.link_mass_kg, [payload_kg]])
    return np.broadcast_to(m, (n, 7)), pts


def _check_payload(payload_kg) -> float:
    try:
        val = float(payload_kg)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"`payload_kg` must be a number, got {payload_kg!r}") from exc
    if not np.isfinite(val) or val < 0:
        raise ConfigError(f"`payload_kg` must be finite and >= 0, got {payload_kg!r}")
    return val


def potential_energy(robot: RobotSpec, dh, q_rad, payload_kg: float = 0.0) -> np.ndarray:
    """Gravitational potential energy of the links and payload (J).

    Parameters
    ----------
    robot : RobotSpec
        Supplies the mass model.
    dh : array_like, shape (7, 5) or (N, 7, 5), or None
        Kinematics (``None``: ``robot.dh_nominal``).
    q_rad : array_like, shape (N, 6) or (6,)
    payload_kg : float
        Point mass at the TCP origin.

    Returns
    -------
    V : ndarray, shape (N,) (or a 0-d array for a single pose)
    """
    dh = robot.dh_nominal if dh is None else dh
    dh, q, single = _prepare(dh, q_rad)
    m, pts = _mass_points(robot, _frames(dh, q), _check_payload(payload_kg))
    V = GRAVITY_M_S2 * 1e-3 * np.einsum("nk,nk->n", m, pts[:, :, 2])
    return V[0] if single else V


def gravity_torques(robot: RobotSpec, dh, q_rad, payload_kg: float = 0.0) -> np.ndarray:
    """Joint torques that hold the arm against gravity, ``g(q) = dV/dq`` (N m).

    Gravity acts along -z of the base frame. ``g(q)`` is the gravity term of
    ``tau = M(q) qdd + C(q, qd) qd + g(q)``: the torque each motor must
    supply to hold the pose; gravity itself loads joint ``i`` with
    ``-g_i(q)``. For joint ``i`` (axis ``z_{i-1}`` through ``o_{i-1}`` of the
    seed 002 eq. (3) chain) ``g_i = g . e_z . (z_{i-1} x sum_{j >= i} m_j
    (c_j - o_{i-1}))``.

    Parameters
    ----------
    robot : RobotSpec
        Supplies the mass model (link masses and centres).
    dh : array_like, shape (7, 5) or (N, 7, 5), or None
        Kinematics (``None``: ``robot.dh_nominal``).
    q_rad : array_like, shape (N, 6) or (6,)
    payload_kg : float
        Point mass at the TCP origin.

    Returns
    -------
    tau : ndarray, shape (N, 6) (or (6,) for a single pose)
        N m.
    """
    dh = robot.dh_nominal if dh is None else dh
    dh, q, single = _prepare(dh, q_rad)
    F = _frames(dh, q)
    m, pts = _mass_points(robot, F, _check_payload(payload_kg))
    n = q.shape[0]
    # suffix sums of m and m*c over the bodies that joint i moves (links i..6 + payload)
    mc = m[..., None] * pts  # (N, 7, 3)
    M_suf = np.cumsum(m[:, ::-1], axis=1)[:, ::-1][:, :N_JOINTS]  # (N, 6)
    MC_suf = np.cumsum(mc[:, ::-1], axis=1)[:, ::-1][:, :N_JOINTS]  # (N, 6, 3)
    z = F[:, :N_JOINTS, :3, 2]
    o = F[:, :N_JOINTS, :3, 3]
    r = MC_suf - M_suf[..., None] * o  # (N, 6, 3) first moment about o_{i-1}
    # e_z . (z x r) = z_x r_y - z_y r_x
    tau = GRAVITY_M_S2 * 1e-3 * (z[..., 0] * r[..., 1] - z[..., 1] * r[..., 0])
    tau = tau.reshape(n, N_JOINTS)
    return tau[0] if single else tau
