"""Where a run's devices come from: the device set a run is assembled with.

A procedure never opens hardware by itself. The front door that assembles a
run (``station run``, the acceptance API, the pytest plugin, a test) hands the
application layer a :class:`DeviceSet`: one entry per *role* the procedure
uses (``tracker``, ``controller``, ``odometry``), each either

* a device URL (the configured devices with ``--arm``, or the fake cell's
  loopback/pty endpoints otherwise), opened here by the matching driver, or
* a driver object that is already open (a test or script injects it; its
  owner closes it).

The drivers are the only code that speaks to a device; this module only
chooses which one, from the role.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from station.device_urls import parse_device_url
from station.errors import ConfigError


def _open_tracker(url: str, *, timeout_s: float | None = None, **options):
    from drivers.tracker_url import open_tracker

    if timeout_s is not None:
        options["reply_timeout_s"] = timeout_s
    return open_tracker(url, **options)


def _open_controller(url: str, *, timeout_s: float | None = None, **options):
    from drivers.controller import ControllerDriver

    if timeout_s is not None:
        options["timeout_s"] = timeout_s
    return ControllerDriver.from_url(url, **options)


def _open_odometry(url: str, *, timeout_s: float | None = None, **options):
    from drivers.odometry import OdometryDriver

    if timeout_s is not None:
        options["timeout_s"] = timeout_s
    return OdometryDriver.open(url, **options)


def _open_scanner(url: str, *, timeout_s: float | None = None, **options):
    from drivers.scanner import ScannerDriver

    if timeout_s is not None:
        options["timeout_s"] = timeout_s
    return ScannerDriver.from_url(url, **options)


#: device kind (of the URL's scheme, :mod:`station.device_urls`) -> how it is opened (the driver
#: module that speaks its protocol);
#: ``timeout_s`` (the config's ``devices.*.timeout_s``) becomes the driver's reply timeout
OPENERS: dict[str, Callable[..., Any]] = {
    "tracker": _open_tracker,
    "controller": _open_controller,
    "odometry": _open_odometry,
    "scanner": _open_scanner,
}


@dataclass
class DeviceSet:
    """The devices of one run, by role.

    Attributes
    ----------
    urls : dict
        ``role -> URL`` of the devices to open.
    options : dict
        ``role -> keyword options`` for the driver (e.g. a controller's ``register_map``).
    drivers : dict
        ``role -> driver`` already open (injected; not closed by the run).
    time_scale : float
        Simulated seconds per real second of the devices (1 for real hardware).
    armed : bool
        True for real hardware (the configured devices with ``--arm``).
    """

    urls: dict[str, str] = field(default_factory=dict)
    options: dict[str, dict] = field(default_factory=dict)
    drivers: dict[str, Any] = field(default_factory=dict)
    time_scale: float = 1.0
    armed: bool = False

    def roles(self) -> set[str]:
        return set(self.urls) | set(self.drivers)

    def describe(self, role: str) -> str:
        if role in self.drivers:
            return f"{role}: injected {type(self.drivers[role]).__name__}"
        return f"{role}: {self.urls.get(role, '(none)')}"

    def open(self, role: str, **options) -> tuple[Any, bool]:
        """``(driver, owned)``: the injected driver (not owned) or a new one opened from the URL (owned)."""
        if role in self.drivers:
            return self.drivers[role], False
        if role not in self.urls:
            have = ", ".join(sorted(self.roles())) or "none"
            raise ConfigError(f"the run needs a {role} device; the device set has {have}")
        url = self.urls[role]
        kind = parse_device_url(url).kind
        if kind not in OPENERS:
            raise ConfigError(f"{role}: no driver in this station opens {kind} URLs ({url}); "
                              f"drivers exist for {', '.join(sorted(OPENERS))}")
        return OPENERS[kind](url, **{**self.options.get(role, {}), **options}), True


def configured_devices(cfg, roles: Mapping[str, str]) -> DeviceSet:
    """The configured devices (real hardware: ``armed``) for ``role -> device name in the config``."""
    urls, options = {}, {}
    for role, name in roles.items():
        dev = cfg.device(name)
        urls[role] = dev.url
        options[role] = {"timeout_s": float(dev.timeout_s)}
        if getattr(dev, "register_map", None) is not None:
            options[role]["register_map"] = dev.register_map
    return DeviceSet(urls=urls, options=options, time_scale=1.0, armed=True)
