"""Open a laser tracker by its device URL (the tracker rows of :mod:`drivers.registry`).

``emscon://HOST[:PORT]`` speaks Leica emScon TPI over TCP
(:mod:`drivers.emscon`); ``geocom:///dev/ttyUSB0?baud=...`` and
``geocom+socket://HOST:PORT`` speak GeoCOM (:mod:`drivers.geocom`). Kept apart
from :mod:`drivers.tracker` (the interface both drivers implement) so that
the interface does not import its implementations.
"""

from __future__ import annotations

from drivers.registry import device_for_url, driver_class
from drivers.tracker import Tracker
from station.device_urls import SCHEMES, parse_device_url

TRACKER_SCHEMES = tuple(n for n, s in SCHEMES.items() if s.kind == "tracker")


def tracker_class(url) -> type:
    """The driver class for ``url`` by its scheme (nothing is opened)."""
    return driver_class(parse_device_url(url, scheme=TRACKER_SCHEMES))


def open_tracker(url, *, timeout_s: float | None = None, **options) -> Tracker:
    """A tracker driver for a device URL (not yet connected); ``options`` go to the driver's constructor."""
    return device_for_url(parse_device_url(url, scheme=TRACKER_SCHEMES), timeout_s=timeout_s, **options)
