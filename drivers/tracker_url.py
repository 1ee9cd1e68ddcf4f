"""Open a laser tracker by its device URL: the scheme picks the driver.

``emscon://HOST[:PORT]`` speaks Leica emScon TPI over TCP
(:mod:`drivers.emscon`); ``geocom:///dev/ttyUSB0?baud=...`` and
``geocom+socket://HOST:PORT`` speak GeoCOM (:mod:`drivers.geocom`). Kept apart
from :mod:`drivers.tracker` (the interface both drivers implement) so that
the interface does not import its implementations.
"""

from __future__ import annotations

from drivers.tracker import Tracker


def open_tracker(url: str, **options) -> Tracker:
    """A tracker driver for a device URL (not yet connected).

    ``emscon://HOST[:PORT]`` (TCP, port 700 by default) -> EmsconTracker;
    ``geocom:///dev/ttyUSB0?baud=115200`` or ``geocom+socket://HOST:PORT`` ->
    GeoComTracker. ``options`` go to the driver's constructor.
    """
    from drivers.transport import parse_device_url, serial_factory, tcp_factory

    scheme, opts = parse_device_url(url)
    if scheme in ("emscon", "tcp"):
        from drivers.emscon import EmsconTracker

        return EmsconTracker(tcp_factory(opts["host"], opts["port"]), **options)
    from drivers.geocom import GeoComTracker

    return GeoComTracker(serial_factory(opts["serial"], baudrate=opts["baudrate"]), **options)


def tracker_class(url: str) -> type:
    """The driver class that :func:`open_tracker` uses for ``url`` (nothing is opened)."""
    from drivers.transport import parse_device_url

    scheme, _ = parse_device_url(url)
    if scheme in ("emscon", "tcp"):
        from drivers.emscon import EmsconTracker

        return EmsconTracker
    from drivers.geocom import GeoComTracker

    return GeoComTracker
