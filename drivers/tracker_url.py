"""Open a laser tracker by its device URL: the scheme picks the driver.

``emscon://HOST[:PORT]`` speaks Leica emScon TPI over TCP
(:mod:`drivers.emscon`); ``geocom:///dev/ttyUSB0?baud=...`` and
``geocom+socket://HOST:PORT`` speak GeoCOM (:mod:`drivers.geocom`). Kept apart
from :mod:`drivers.tracker` (the interface both drivers implement) so that
the interface does not import its implementations.
"""

from __future__ import annotations

from drivers.tracker import Tracker
from station.device_urls import parse_device_url


def tracker_class(url: str) -> type:
    """The driver class for ``url`` by its scheme (nothing is opened)."""
    u = parse_device_url(url, scheme=("emscon", "geocom", "geocom+socket"))
    if u.scheme == "emscon":
        from drivers.emscon import EmsconTracker

        return EmsconTracker
    from drivers.geocom import GeoComTracker

    return GeoComTracker


def open_tracker(url: str, **options) -> Tracker:
    """A tracker driver for a device URL (not yet connected); ``options`` go to the driver's constructor.

    ``emscon://HOST[:PORT]`` -> EmsconTracker; ``geocom:///dev/ttyUSB0?baud=N``
    or ``geocom+socket://HOST:PORT`` -> GeoComTracker.
    """
    return tracker_class(url).from_url(url, **options)
