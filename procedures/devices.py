"""Where a run's devices come from: the device set a run is assembled with.

A procedure never opens hardware by itself. The front door that assembles a
run (``station run``, the acceptance API, the pytest plugin, a test) hands the
application layer a :class:`DeviceSet`: one entry per *role* the procedure
uses (``tracker``, ``controller``, ``odometry``), each either

* a device URL (the configured devices with ``--arm``, or the fake cell's
  loopback/pty endpoints otherwise), opened by the driver its scheme names
  (:func:`drivers.registry.device_for_url`, the one table), or
* a driver object that is already open (a test or script injects it; its
  owner closes it).

The drivers are the only code that speaks to a device; this module only
chooses which one, from the role.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from station.errors import ConfigError


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
        from drivers.registry import device_for_url

        try:
            return device_for_url(self.urls[role], **{**self.options.get(role, {}), **options}), True
        except ConfigError as exc:
            raise ConfigError(f"{role}: {exc}") from None


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
