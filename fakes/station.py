"""The fake station: one simulated cell with its devices on loopback.

One world (arm with realistic errors, tracker measurement model, one clock)
and the fakes that speak the real protocols around it:

* the emScon tracker server (``fakes.emscon``) on 127.0.0.1, ephemeral port;
* the robot controller (``fakes.controller``): FTP server + Modbus TCP server
  + the RAPID interpreter moving the simulated arm.

:meth:`FakeStation.config_dict` gives a station config whose device URLs
point at these fakes, so the procedure runs through the real drivers over
real sockets. Used by ``station demo``, ``station run`` without ``--arm``,
``station fakes serve station`` and the test fixtures.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from fakes import controller as controller_fake
from fakes import emscon as emscon_fake
from fakes.sim.world import World, make_world

#: cube of seed 000 Table 1 (mm, robot base frame) shrunk by this much gives the workspace box
WORKSPACE_MARGIN_MM = 300.0
SEED_CUBE_MIN = (-600.0, 1100.0, 800.0)
SEED_CUBE_MAX = (600.0, 2300.0, 2000.0)


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


class FakeStation:
    """A running fake cell; ``close()`` stops every server and joins its threads."""

    def __init__(self, world: World, *, host: str | None = None, faults: Mapping[str, str] | None = None) -> None:
        t_faults, c_faults = _split_faults(faults)
        # the device buffer is a real-time property of the tracker: in accelerated time a
        # host hiccup of 0.1 s would otherwise overflow a 2 s (simulated) buffer
        scale = getattr(world.clock, "time_scale", 1.0)
        if math.isfinite(scale):
            t_faults.setdefault("device_buffer_s", str(max(2.0, 3.0 * scale)))
        self.world = world
        self._owns_world = False
        # the controller's programs schedule the cell's time; the stream follows it (lockstep)
        self.tracker = emscon_fake.start_fake(world, host=host, faults=t_faults, drives_clock=False)
        try:
            self.controller = controller_fake.start_fake(world, host=host, faults=c_faults)
        except BaseException:
            self.tracker.close()
            raise
        te = self.tracker.endpoint
        self.tracker_url = f"emscon://{te['host']}:{te['port']}"
        self.controller_url = self.controller.url
        self.endpoint = {
            "robot": world.robot.name,
            "tracker": self.tracker_url,
            "controller": self.controller_url,
            "time_scale": getattr(world.clock, "time_scale", None),
        }

    @classmethod
    def start(cls, *, seed: int = 0, time_scale: float = 20.0, robot: str = "industrial-3100",
              faults: Mapping[str, str] | None = None, **world_kwargs) -> "FakeStation":
        world = make_world(robot=robot, seed=seed, time_scale=time_scale, **world_kwargs)
        try:
            station = cls(world, faults=faults)
        except BaseException:
            world.close()
            raise
        station._owns_world = True
        return station

    def config_dict(self, *, name: str = "fake-cell", store_path: str = "station.sqlite",
                    report_dir: str = "reports", serial: str = "SIM-0001", overhaul_state: str = "after",
                    iso9283: Mapping | None = None, limits: Mapping | None = None) -> dict:
        """A station config (dict) with the fakes' URLs, ready for :func:`station.config.config_from_dict`."""
        lo = [c - WORKSPACE_MARGIN_MM for c in SEED_CUBE_MIN]
        hi = [c + WORKSPACE_MARGIN_MM for c in SEED_CUBE_MAX]
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
