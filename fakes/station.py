"""The fake station: one simulated cell with its devices on loopback.

One world (arm with realistic errors, tracker measurement model, one clock)
and the fakes that speak the real protocols around it:

* the emScon tracker server (``fakes.emscon``) on 127.0.0.1, ephemeral port;
* the robot's controller, by the arm's make (:func:`robot_fake`): for an
  industrial arm the program-upload controller (``fakes.controller``: FTP
  server + Modbus TCP server + the RAPID interpreter moving the simulated
  arm), for a UR the UR controller (``fakes.ur``: RTDE, dashboard and script
  servers on a loopback address of its own, ``ur://127.0.0.N``).

Both are started by name from :mod:`fakes.registry`.

:meth:`FakeStation.config_dict` gives a station config whose device URLs
point at these fakes, so the procedure runs through the real drivers over
real sockets. Used by ``station demo``, ``station run`` without ``--arm``,
``station fakes serve station`` and the test fixtures.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from fakes.registry import start_named, url_of
from fakes.sim.world import World, make_world
from station.analysis.iso9283.poses import fit_cube_to_reach
from station.models.robots import get_robot
from station.programs.builders import TOOL_DOWN

#: cube of seed 000 Table 1 (mm, robot base frame) grown by this much gives the workspace box
#: (both scaled to the arm's size, :func:`station.analysis.iso_poses.fit_cube_to_reach`)
WORKSPACE_MARGIN_MM = 300.0
SEED_CUBE_MIN = (-600.0, 1100.0, 800.0)
SEED_CUBE_MAX = (600.0, 2300.0, 2000.0)


def robot_fake(robot_name: str) -> str:
    """The fake (by name, :mod:`fakes.registry`) of the controller an arm of this model has."""
    return "ur" if get_robot(robot_name).controller == "ur" else "controller"


def workspace_box(robot) -> tuple[list[float], list[float]]:
    """The safety gate's box of the fake cell: the seed's test cube in this arm's workspace
    (:func:`~station.analysis.iso_poses.fit_cube_to_reach`), grown by the margin scaled alike."""
    cube = fit_cube_to_reach(robot.dh_nominal, robot.joint_limits_rad, robot.home_q_rad, TOOL_DOWN)
    lo = cube.corners_mm.min(axis=0) - cube.scale * WORKSPACE_MARGIN_MM
    hi = cube.corners_mm.max(axis=0) + cube.scale * WORKSPACE_MARGIN_MM
    return [float(v) for v in lo], [float(v) for v in hi]


def _split_faults(faults: Mapping[str, str] | None) -> tuple[dict, dict]:
    """``tracker.KEY`` / ``controller.KEY`` -> the two fakes' fault dicts."""
    tracker, controller = {}, {}
    for key, value in (faults or {}).items():
        dev, sep, sub = key.partition(".")
        if not sep or dev not in ("tracker", "controller"):
            from station.errors import ConfigError

            raise ConfigError(f"fake station fault {key!r} must be tracker.KEY or controller.KEY")
        (tracker if dev == "tracker" else controller)[sub] = value
    return tracker, controller


#: the RTDE frequency a UR cell's driver asks for in lockstep unless told otherwise: there every data package
#: waits for the driver to say it kept the one before (:data:`station.protocols.ur.LOCKSTEP_STORED_REGISTER`), a
#: round trip between processes of about 0.9 ms on an idle host and 2-7 ms on a busy one
#: (``bench/bench_rtde_lockstep.py``), so the 500 Hz of an e-Series would make a dry run's ~100 simulated
#: seconds take a minute or more; the procedures read the joints at rest
LOCKSTEP_RTDE_HZ = 10

#: the time scale of a dry run nobody watches: the lockstep cells give the same samples and figures at any
#: pace (tests/sim/test_lockstep.py), so it only bounds the pace, and never binds on a 2-core host
FULL_PACE = 1e4


class FakeStation:
    """A running fake cell; ``close()`` stops every server and joins its threads."""

    def __init__(self, world: World, *, host: str | None = None, faults: Mapping[str, str] | None = None,
                 rtde_hz: int | None = None) -> None:
        t_faults, c_faults = _split_faults(faults)
        # the device buffer is a real-time property of the tracker: in accelerated time a
        # host hiccup of 0.1 s would otherwise overflow a 2 s (simulated) buffer
        scale = getattr(world.clock, "time_scale", 1.0)
        if math.isfinite(scale):
            t_faults.setdefault("device_buffer_s", str(max(2.0, 3.0 * scale)))
        self.world = world
        self._owns_world = False
        # the robot's programs schedule the cell's time; the stream follows it (lockstep)
        self.tracker = start_named("tracker-emscon", world, host=host, faults=t_faults, drives_clock=False)
        kind = robot_fake(world.robot.name)
        try:
            # the UR fake takes a loopback address of its own (ur_rtde fixes its ports)
            # the UR fake in lockstep with the cell's clock (its programs run it), as the controller's
            ur = {"lockstep": bool(getattr(world.clock, "lockstep", False))} if kind == "ur" else {}
            self.controller = start_named(kind, world, host=host if kind != "ur" else None, faults=c_faults, **ur)
        except BaseException:
            self.tracker.close()
            raise
        self.tracker_url = url_of("emscon", self.tracker)
        self.controller_url = url_of("ur" if kind == "ur" else "modbus+ftp", self.controller)
        if kind == "ur":  # the driver asks the UR for this RTDE frequency, and knows it is in lockstep
            if rtde_hz is None and self.controller.lockstep:
                rtde_hz = LOCKSTEP_RTDE_HZ
            query = ([f"rtde_hz={int(rtde_hz)}"] if rtde_hz is not None else []) + \
                (["lockstep=1"] if self.controller.lockstep else [])
            if query:
                self.controller_url += "?" + "&".join(query)
        self.endpoint = {
            "robot": world.robot.name,
            "tracker": self.tracker_url,
            "controller": self.controller_url,
            "time_scale": getattr(world.clock, "time_scale", None),
        }

    @classmethod
    def start(cls, *, seed: int = 0, time_scale: float = 20.0, robot: str = "industrial-3100",
              faults: Mapping[str, str] | None = None, rtde_hz: int | None = None,
              **world_kwargs) -> "FakeStation":
        world = make_world(robot=robot, seed=seed, time_scale=time_scale, **world_kwargs)
        try:
            station = cls(world, faults=faults, rtde_hz=rtde_hz)
        except BaseException:
            world.close()
            raise
        station._owns_world = True
        return station

    def config_dict(self, *, name: str = "fake-cell", store_path: str = "station.sqlite",
                    report_dir: str = "reports", serial: str = "SIM-0001", overhaul_state: str = "after",
                    iso9283: Mapping | None = None, limits: Mapping | None = None) -> dict:
        """A station config (dict) with the fakes' URLs, ready for :func:`station.config.config_from_dict`."""
        lo, hi = workspace_box(self.world.robot)
        return {
            "station": {"name": name, "store_path": store_path, "report_dir": report_dir},
            "devices": {
                "tracker": {"url": self.tracker_url},
                "controller": {"url": self.controller_url},
            },
            "robots": {
                "r1": {
                    "model": self.world.robot.name,
                    "serial": serial,
                    "overhaul_state": overhaul_state,
                    "controller": "controller",
                    "workspace": {"min_mm": lo, "max_mm": hi,
                                  "max_tcp_speed_mm_s": float(self.world.robot.max_tcp_speed_mm_s)},
                    "limits": dict(limits or {"rp_limit_mm": 0.5}),
                }
            },
            "iso9283": dict(iso9283 or {}),
        }

    def close(self) -> None:
        try:
            self.controller.close()
        finally:
            try:
                self.tracker.close()
            finally:
                if self._owns_world:
                    self.world.close()

    def __enter__(self) -> "FakeStation":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def start_fake(world, *, host=None, port=None, faults=None) -> FakeStation:
    """``station fakes serve station``: the whole fake cell around ``world``."""
    return FakeStation(world, host=host, faults=faults)
