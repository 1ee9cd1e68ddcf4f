"""Fake cells that serve a procedure's devices, one per procedure kind.

A procedure's registry entry names its cell here (``"fakes.cells:iso9283_cell"``);
the front door that assembles a run without ``--arm`` starts it. Each cell
takes the run's stored plan (``params``) and the fake's own parameters
(``fake``: ``seed``, ``time_scale``, and what the cell adds), and returns an
object with ``urls`` (device role -> endpoint), ``time_scale`` and ``close()``.
The same parameters give the same simulated cell, so a resumed run meets the
robot it started with; ``fake["start_s"]`` (set by a resume) starts the cell's
clock after everything the run stored, so its device time goes on.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path


@dataclass
class FakeCell:
    """A running fake cell: the endpoints of its devices and how to stop it."""

    urls: dict[str, str]
    time_scale: float
    _close: Callable[[], None]
    #: ``hand(operator) -> operator``: a cell whose simulated world acts on the operator's answers (the loads
    #: of a static compliance test) wraps the run's operator with it; None: the operator is left alone
    hand: Callable | None = None
    #: ``carry() -> dict``: what of the simulated world a cell started again to resume the run carries on (fake
    #: options: the arm's temperature rise, ``arm_rise``); None: nothing
    carry: Callable | None = None

    def close(self) -> None:
        self._close()

    def __enter__(self) -> "FakeCell":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: the fake options that shape the simulated world (``make_world`` keywords), e.g. an arm whose stops scatter
#: more (``stop_sigma_mm``, mm per coordinate at home), a tracker whose beam is broken (``beam_breaks``, pairs of
#: simulated s), an arm with a flaw on one joint (``joint_defect``, :mod:`fakes.sim.joint_defect`), an arm that
#: warms with its motion so (``warmup``: ``[dT_max_K, tau_s]``, a drift test's truth, :mod:`fakes.sim.heat`) or one that moves as a
#: diagnosed motion model says (``motion_model``: its file, as the config's ``robots.X.motion_model`` resolved it);
#: ``arm_rise`` is what a cell that ran before left (:meth:`fakes.sim.world.World.carried`), set by a resume
WORLD_OPTIONS = ("stop_sigma_mm", "beam_breaks", "joint_defect", "tracker_mpe_a_um", "tracker_mpe_b_um_per_m",
                 "warmup", "motion_model", "arm_rise")


def _world_options(fake: Mapping) -> dict:
    """The ``make_world`` keywords of a fake's parameters (a motion model's file read and checked)."""
    world = {k: fake[k] for k in WORLD_OPTIONS if k in fake}
    if world.get("motion_model") is not None:
        from station.models.motion_model_file import read_motion_model

        world["motion_model"] = read_motion_model(world["motion_model"])
    return world


def iso9283_cell(params: Mapping, fake: Mapping) -> FakeCell:
    """The simulated arm of the plan's model with its controller and emScon tracker on loopback
    (``fake``: seed, time scale, any of :data:`WORLD_OPTIONS`, and for a UR the RTDE frequency its driver
    asks for, ``rtde_hz``)."""
    from fakes.station import FakeStation

    world = _world_options(fake)
    station = FakeStation.start(seed=int(fake["seed"]), time_scale=float(fake["time_scale"]),
                                robot=params["robot"], payload_kg=float(params.get("payload_kg", 0.0)),
                                start_s=float(fake.get("start_s", 0.0)), rtde_hz=fake.get("rtde_hz"), **world)
    return FakeCell({"tracker": station.tracker_url, "controller": station.controller_url},
                    float(fake["time_scale"]), station.close, carry=station.world.carried)


def compliance_cell(params: Mapping, fake: Mapping) -> FakeCell:
    """The ISO cell with a force gauge on a pty in the load path, and the simulated operator's hand
    (:class:`fakes.sim.hand.SimulatedHand`) that applies the loads the run asks for to the simulated arm."""
    from fakes.forcegauge import start_fake
    from fakes.sim.hand import SimulatedHand
    from fakes.station import FakeStation

    world = _world_options(fake)
    station = FakeStation.start(seed=int(fake["seed"]), time_scale=float(fake["time_scale"]),
                                robot=params["robot"], payload_kg=float(params.get("payload_kg", 0.0)),
                                start_s=float(fake.get("start_s", 0.0)), **world)
    try:
        gauge = start_fake(station.world, faults=fake.get("gauge_faults"))
    except BaseException:
        station.close()
        raise

    def close() -> None:
        try:
            gauge.close()
        finally:
            station.close()

    arm, rng = station.world.arm, station.world.rng
    return FakeCell({"tracker": station.tracker_url, "controller": station.controller_url, "gauge": gauge.url},
                    float(fake["time_scale"]), close, hand=lambda operator: SimulatedHand(operator, arm, rng))


def arm_calibration_cell(params: Mapping, fake: Mapping) -> FakeCell:
    """The arm-calibration cell: with the tracker, the ISO cell; with the scanner (``params["instrument"]``), the
    simulated arm and controller with the world's scanner answering in a hot folder of its own (removed at close).

    The world's scanner stands where :func:`scanner_calibration_config` says (its default pose);
    ``fake["scanner_faults"]`` schedules the fake scanner's faults (:mod:`fakes.scanner_folder`).
    """
    if params.get("instrument", "tracker") != "scanner":
        return iso9283_cell(params, fake)
    import shutil
    import tempfile

    from fakes.scanner_folder import start_fake
    from fakes.station import FakeStation

    station = FakeStation.start(seed=int(fake["seed"]), time_scale=float(fake["time_scale"]), robot=params["robot"],
                                start_s=float(fake.get("start_s", 0.0)))
    folder = Path(tempfile.mkdtemp(prefix="fake-scanner-"))
    try:
        scanner = start_fake(station.world, folder, faults=fake.get("scanner_faults"))
    except BaseException:
        station.close()
        shutil.rmtree(folder, ignore_errors=True)
        raise

    def close() -> None:
        try:
            scanner.close()
            station.close()
        finally:
            shutil.rmtree(folder, ignore_errors=True)

    return FakeCell({"scanner": scanner.url, "controller": station.controller_url}, float(fake["time_scale"]), close)


def default_scanner_pose(robot: str, working_distance_mm: float = 700.0) -> tuple[list[float], list[float]]:
    """(eye, look-at) of the fake world's default scanner, base frame mm: the home feature point and
    ``working_distance_mm`` along the home tool z from it (as :func:`fakes.sim.world.make_world` places it)."""
    from station.models import kinematics as kin
    from station.models.jig import CornerJig
    from station.models.robots import get_robot

    spec = get_robot(robot)
    T = kin.fk(spec.dh_nominal, spec.home_q_rad)
    fp = T[:3, :3] @ CornerJig().feature_point_tool_mm + T[:3, 3]
    eye = fp + working_distance_mm * T[:3, 2]
    return [float(v) for v in eye], [float(v) for v in fp]


def scanner_calibration_config(out: Path, *, train_poses: int = 31, test_poses: int = 9) -> dict:
    """A station config for the scanner-based arm calibration on the fake cell (URLs replaced at start)."""
    d = demo_config(out, cycles=3, vap_cycles=3, rate_hz=100.0)
    d["devices"] = {"scanner": {"url": "fake://scanner"}, "controller": {"url": "fake://controller"}}
    eye, look_at = default_scanner_pose(d["robots"]["r1"]["model"])
    d["arm_calibration"] = {"instrument": "scanner", "instrument_mm": eye, "instrument_look_at_mm": look_at,
                            "train_poses": train_poses, "test_poses": test_poses}
    return d


def trailer_cell(params: Mapping, fake: Mapping) -> FakeCell:
    """The simulated trailer with its NMEA odometry on a pty (``true_lengths_m`` picks its links)."""
    from fakes.odometry import start_fake
    from fakes.sim.trailer import SimTrailer
    from fakes.sim.world import make_world

    world = make_world(seed=int(fake["seed"]), time_scale=float(fake["time_scale"]), effects=None,
                       start_s=float(fake.get("start_s", 0.0)))
    try:
        if fake.get("true_lengths_m"):
            L1, L2 = fake["true_lengths_m"]
            world.trailer = SimTrailer(world.clock, L1_m=L1, L2_m=L2, rng=world.rng)
        handle = start_fake(world, lockstep=True)  # stepped by its driver: the same seed, the same samples
    except BaseException:
        world.close()
        raise

    def close() -> None:
        try:
            handle.close()
        finally:
            world.close()

    return FakeCell({"odometry": f"nmea://{handle.endpoint['device']}?lockstep=1"}, float(fake["time_scale"]),
                    close)


def demo_config(out: Path, *, cycles: int, vap_cycles: int, rate_hz: float, robot: str = "industrial-3100") -> dict:
    """The demo station's config; device URLs are replaced by the fakes' at start.

    ``robot`` picks the arm and with it the controller's fake (:func:`fakes.station.robot_fake`: a UR model
    gets the UR fake, ``ur://``); the workspace box is the seed's cube in that arm's workspace, grown by a
    margin (:func:`fakes.station.workspace_box`).
    """
    from fakes.station import robot_fake, workspace_box
    from station.models.robots import get_robot

    spec = get_robot(robot)
    lo, hi = workspace_box(spec)
    return {
        "station": {"name": "demo cell", "store_path": str(out / "station.sqlite"), "report_dir": str(out / "reports")},
        "devices": {"tracker": {"url": "fake://tracker-emscon"}, "controller": {"url": f"fake://{robot_fake(robot)}"}},
        "robots": {
            "r1": {
                "model": robot, "serial": "DEMO-0001", "overhaul_state": "after", "payload_kg": 0.0,
                "controller": "controller",
                "workspace": {"min_mm": lo, "max_mm": hi, "max_tcp_speed_mm_s": float(spec.max_tcp_speed_mm_s)},
                "limits": {"rp_limit_mm": 0.5, "ap_limit_mm": 5.0, "vap_limit_mm": 2.0, "ad_limit_mm": 2.0},
            }
        },
        "iso9283": {"cycles": cycles, "vap_cycles": vap_cycles, "tracker_rate_hz": rate_hz,
                    # a cobot's joint-2 circle about P1 stays inside its (smaller) box over +/- 20 deg
                    **({"axis_sweep_deg": [25.0, 20.0]} if robot_fake(robot) == "ur" else {})},
    }
