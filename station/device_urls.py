"""The one table of devices: URL scheme -> grammar, defaults, driver class and fake.

In the manner of pyserial's ``serial_for_url``: each row names the scheme's
driver class (``"module:Class"``, resolved and built by
:func:`drivers.registry.device_for_url` through the class's
``from_url(url, *, timeout_s, **options)``) and the fake that speaks its
protocol (the name :mod:`fakes.registry` serves it under and the module that
starts it). The core only names them here; it imports neither. A new
instrument is one driver, one fake and one row.

The config validation (:mod:`station.config`) and every driver's ``from_url``
parse device URLs here, so a default documented in the table is the default
used, and a URL the config accepts is one a driver opens. A URL is parsed
once: :func:`parse_device_url` hands a :class:`DeviceURL` back unchanged
(after checking its scheme), so the parsed URL travels to the transport.

=================  ==========================================  =========================================
scheme             device                                      address, defaults, options
=================  ==========================================  =========================================
``emscon``         laser tracker, Leica emScon TPI over TCP    ``emscon://HOST[:PORT]``, port 700
``geocom``         tracker / total station, GeoCOM, serial     ``geocom:///dev/ttyX[?baud=N]``, 115200 baud
``geocom+socket``  GeoCOM over a TCP serial bridge             ``geocom+socket://HOST:PORT`` (port required)
``modbus+ftp``     robot controller: FTP upload + Modbus TCP   ``modbus+ftp://HOST[:FTP_PORT]``, FTP 21;
                                                               ``modbus_port`` (502), ``user``
                                                               (anonymous), ``password_env`` or
                                                               ``password_file``, ``dir``
``ur``             UR-style cobot (RTDE, dashboard, script)    ``ur://HOST[?rtde_hz=N]``; the ports are fixed
                                                               by ur_rtde; RTDE output 500 Hz (a CB3: 125);
                                                               ``lockstep=1``: the simulated controller only
``nmea``           trailer odometry, NMEA 0183 over serial     ``nmea:///dev/ttyX[?baud=N]``, 57600 baud;
                                                               ``lockstep=1``: the simulated unit only
``forcegauge``     force gauge / load-cell indicator, ASCII    ``forcegauge:///dev/ttyX[?baud=N]``, 9600 baud
                   request/reply over serial (``?`` -> ``12.34
                   N``, ``Z`` zero, unit select; grammar in
                   :mod:`drivers.forcegauge_codec`)
``ply``            3D scanner clouds: PLY files in a folder    ``ply:///path/to/folder``
``fake``           a device of the station's own fake set      ``fake://NAME``
=================  ==========================================  =========================================

Unknown schemes and unknown options are refused, naming them.

Secrets: a device URL never carries a password (it would be stored with the
run's configuration, pushed to the central store, shown on the page). As for
the store (:mod:`station.store_url`), ``password_env=VAR`` names an
environment variable and ``password_file=PATH`` a file (first line) that
holds it; :meth:`DeviceURL.password` reads it when the driver connects. A
``password=`` option (however spelt) and a ``user:secret@`` part are refused.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

from station.errors import ConfigError


@dataclass(frozen=True)
class Scheme:
    """One row of the table.

    ``address`` is ``"host"`` (TCP host, optional port), ``"path"`` (a serial
    device or folder) or ``"name"`` (a fake's name). ``options`` maps each
    allowed query option to its default (None: no default, optional).
    """

    name: str
    kind: str
    description: str
    address: str
    default_port: int | None = None
    port_required: bool = False
    port_allowed: bool = True
    options: dict[str, str | None] = field(default_factory=dict)
    #: options that must be positive integers
    int_options: tuple[str, ...] = ()
    #: what the path of a ``"path"`` address is, and an example
    path_what: str = "serial device path"
    path_example: str = "/dev/ttyUSB0"
    #: the driver class, ``"package.module:Class"`` (None: no driver, e.g. ``fake://``)
    driver: str | None = None
    #: the fake that speaks this protocol: its name (``station fakes serve NAME``) and module
    fake: str | None = None
    fake_module: str | None = None


SCHEMES: dict[str, Scheme] = {s.name: s for s in (
    Scheme("emscon", "tracker", "laser tracker (Leica emScon TPI over TCP)", "host", default_port=700,
           driver="drivers.emscon:EmsconTracker", fake="tracker-emscon", fake_module="fakes.emscon"),
    Scheme("geocom", "tracker", "tracker/total station (Leica GeoCOM over serial)", "path",
           options={"baud": "115200"}, int_options=("baud",),
           driver="drivers.geocom:GeoComTracker", fake="tracker-geocom", fake_module="fakes.geocom"),
    Scheme("geocom+socket", "tracker", "tracker/total station (Leica GeoCOM over a TCP serial bridge)", "host",
           port_required=True, driver="drivers.geocom:GeoComTracker", fake="tracker-geocom",
           fake_module="fakes.geocom"),
    Scheme("modbus+ftp", "controller", "robot controller (FTP upload + Modbus TCP)", "host", default_port=21,
           options={"modbus_port": "502", "user": "anonymous", "password_env": None, "password_file": None,
                    "dir": ""},
           int_options=("modbus_port",),
           driver="drivers.controller:ControllerDriver", fake="controller", fake_module="fakes.controller"),
    Scheme("ur", "controller", "UR-style cobot (ur_rtde)", "host", port_allowed=False,
           options={"rtde_hz": "500", "lockstep": None}, int_options=("rtde_hz",),
           driver="drivers.ur:URDriver", fake="ur", fake_module="fakes.ur"),
    Scheme("nmea", "odometry", "trailer odometry (NMEA 0183 over serial)", "path",
           options={"baud": "57600", "lockstep": None}, int_options=("baud",),
           driver="drivers.odometry:OdometryDriver", fake="odometry", fake_module="fakes.odometry"),
    Scheme("forcegauge", "forcegauge", "force gauge / load-cell indicator (ASCII request/reply over serial)",
           "path", options={"baud": "9600"}, int_options=("baud",),
           driver="drivers.forcegauge:ForceGauge", fake="forcegauge", fake_module="fakes.forcegauge"),
    Scheme("ply", "scanner", "3D scanner point clouds (PLY files in a folder)", "path",
           path_what="folder path", path_example="/data/scans",
           driver="drivers.scanner:ScannerDriver", fake="scanner", fake_module="fakes.scanner_folder"),
    Scheme("fake", "fake", "simulated device of the station's own fake set", "name"),
)}


@dataclass(frozen=True)
class DeviceURL:
    """A parsed device URL with the table's defaults filled in."""

    raw: str
    scheme: str
    host: str | None = None
    port: int | None = None
    path: str | None = None
    options: dict[str, str] = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return SCHEMES[self.scheme].kind

    @property
    def is_loopback(self) -> bool:
        return self.host is not None and (self.host == "localhost" or self.host.startswith("127."))

    def int_option(self, name: str) -> int:
        return int(self.options[name])

    def flag_option(self, name: str) -> bool:
        """An option that is ``0`` or ``1`` (absent: 0); ConfigError names anything else."""
        value = self.options.get(name)
        if value in (None, "0"):
            return False
        if value == "1":
            return True
        raise ConfigError(f"device URL {self.raw!r}: {name} must be 0 or 1, got {value!r}")

    def password(self) -> str:
        """The password named by ``password_env`` or ``password_file``, read now ("" when neither is given)."""
        env, path = self.options.get("password_env"), self.options.get("password_file")
        if env:
            value = os.environ.get(env)
            if value is None:
                raise ConfigError(f"device URL {self.scheme}://{self.host}: password_env names {env!r}, "
                                  "which is not set")
            return value
        if path:
            try:
                return Path(path).read_text(encoding="utf-8").splitlines()[0].strip()
            except (OSError, UnicodeDecodeError, IndexError):
                raise ConfigError(f"device URL {self.scheme}://{self.host}: cannot read password_file "
                                  f"{path!r}") from None
        return ""


def parse_device_url(url: "str | DeviceURL", *, scheme: str | tuple[str, ...] | None = None) -> DeviceURL:
    """Parse and check a device URL against the table; ConfigError names what is wrong.

    ``scheme`` restricts the accepted schemes (a driver passes the ones it speaks).
    A :class:`DeviceURL` (already parsed) is returned as it is once its scheme is checked.
    """
    wanted = (scheme,) if isinstance(scheme, str) else scheme
    if isinstance(url, DeviceURL):
        if wanted is not None and url.scheme not in wanted:
            raise ConfigError(f"device URL {url.raw!r}: expected a {' or '.join(wanted)} URL, got {url.scheme!r}")
        return url
    if not isinstance(url, str) or "://" not in url:
        raise ConfigError(f"device URL {url!r} must look like scheme://host:port or scheme:///dev/...")
    if len(url) > 2048 or any(ord(c) < 32 or ord(c) == 127 for c in url):
        raise ConfigError(f"device URL {url[:60]!r}: control characters or over 2048 characters")
    try:
        parts = urlsplit(url)
    except ValueError as exc:  # e.g. an unbalanced [ of an IPv6 host
        raise ConfigError(f"device URL {url!r}: {exc}") from None
    name = parts.scheme.lower()
    if name not in SCHEMES:
        raise ConfigError(f"device URL {url!r}: unknown scheme {name!r} (known: {', '.join(SCHEMES)})")
    if wanted is not None and name not in wanted:
        raise ConfigError(f"device URL {url!r}: expected a {' or '.join(wanted)} URL, got {name!r}")
    sch = SCHEMES[name]
    try:
        port = parts.port
    except ValueError as exc:
        raise ConfigError(f"device URL {url!r}: bad port ({exc})") from None
    try:
        query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise ConfigError(f"device URL {url!r}: malformed query {parts.query!r}") from None
    given = {k: unquote(v[-1]) for k, v in query.items()}
    if parts.password is not None or any(k.strip().lower() in ("password", "pass", "passwd", "pwd") for k in given):
        raise ConfigError(f"device URL of {name}://{parts.hostname or ''}: a password in the URL is refused (it "
                          "would be stored with every run and shown on the page); name it with "
                          "?password_env=VAR or ?password_file=PATH")
    if given.get("password_env") and given.get("password_file"):
        raise ConfigError(f"device URL of {name}://{parts.hostname or ''}: give password_env or password_file, "
                          "not both")
    unknown = sorted(set(given) - set(sch.options))
    if unknown:
        allowed = ", ".join(sch.options) or "none"
        raise ConfigError(f"device URL {url!r}: unknown option(s) {', '.join(unknown)} for {name} (allowed: {allowed})")
    options = {k: v for k, v in sch.options.items() if v is not None}
    options.update(given)
    for key in sch.int_options:
        value = options.get(key)
        if value is not None and not (value.isascii() and value.isdigit() and len(value) <= 9 and int(value) > 0):
            raise ConfigError(f"device URL {url!r}: {key} must be a positive integer, got {value!r}")
    host, path = parts.hostname, parts.path or None
    if sch.address == "host":
        if not host:
            raise ConfigError(f"device URL {url!r}: {name} needs a host, e.g. {name}://10.0.0.5")
        if port is not None and not sch.port_allowed:
            raise ConfigError(f"device URL {url!r}: {name} takes no port (the protocol fixes its ports)")
        if port is None and sch.port_required:
            raise ConfigError(f"device URL {url!r}: {name} needs a port, e.g. {name}://{host}:4001")
        port = port if port is not None else sch.default_port
    elif sch.address == "path":
        if not path or host:
            raise ConfigError(f"device URL {url!r}: {name} needs a {sch.path_what} and no host, "
                              f"e.g. {name}://{sch.path_example}")
    else:  # name
        if not (host or path):
            raise ConfigError(f"device URL {url!r}: {name} needs a device name, e.g. {name}://tracker-emscon")
    return DeviceURL(raw=url, scheme=name, host=host, port=port, path=path, options=options)


__all__ = ["SCHEMES", "Scheme", "DeviceURL", "parse_device_url"]
