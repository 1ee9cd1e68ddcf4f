"""Open any device by its URL: the scheme picks the driver class (pyserial's ``serial_for_url``).

The table is :data:`station.device_urls.SCHEMES` (one row per scheme: grammar,
defaults, driver class, fake). Here the row's ``driver`` (``"module:Class"``)
is imported on first use and built with the one signature every driver has::

    Driver.from_url(url, *, timeout_s=None, **options)

``url`` is parsed once, here, and the parsed :class:`~station.device_urls.DeviceURL`
is what ``from_url`` receives; ``timeout_s`` is the driver's reply timeout
(the config's ``devices.*.timeout_s``; None: the driver's own default);
``options`` are the driver's keyword options (a controller's ``gate`` and
``register_map``, ...).
"""

from __future__ import annotations

import importlib
from typing import Any

from station.device_urls import SCHEMES, DeviceURL, parse_device_url
from station.errors import ConfigError


def driver_class(url: "str | DeviceURL") -> type:
    """The driver class for ``url`` by its scheme (nothing is opened)."""
    u = parse_device_url(url)
    path = SCHEMES[u.scheme].driver
    if path is None:
        have = ", ".join(sorted(n for n, s in SCHEMES.items() if s.driver))
        raise ConfigError(f"device URL {u.raw!r}: no driver in this station opens {u.scheme} URLs "
                          f"(drivers exist for {have})")
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


def device_for_url(url: "str | DeviceURL", *, timeout_s: float | None = None, **options) -> Any:
    """A driver for ``url`` (not yet connected), built by its class's ``from_url``."""
    u = parse_device_url(url)
    return driver_class(u).from_url(u, timeout_s=timeout_s, **options)


def drivers() -> dict[str, str]:
    """``scheme -> "module:Class"`` of every scheme that has a driver."""
    return {n: s.driver for n, s in SCHEMES.items() if s.driver}


__all__ = ["device_for_url", "driver_class", "drivers"]
