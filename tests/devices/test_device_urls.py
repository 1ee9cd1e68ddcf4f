"""One device-URL grammar: the table's defaults are the ones the drivers use, and every
scheme with a driver opens against its fake, with the config's ``timeout_s`` reaching it."""

from __future__ import annotations

import os
import re
import select
import socket
import termios
import threading
import tty

import numpy as np
import pytest

from procedures.devices import configured_devices
from station.config import config_from_dict
from station.device_urls import SCHEMES, parse_device_url
from station.errors import ConfigError

EXAMPLES = {
    "emscon": "emscon://10.0.0.5",
    "geocom": "geocom:///dev/ttyUSB0",
    "geocom+socket": "geocom+socket://10.0.0.6:4001",
    "modbus+ftp": "modbus+ftp://10.0.0.7",
    "ur": "ur://10.0.0.9",
    "nmea": "nmea:///dev/ttyS1",
    "ply": "ply:///data/scans",
    "fake": "fake://tracker-emscon",
}


def test_every_scheme_of_the_table_parses_with_its_defaults():
    assert set(EXAMPLES) == set(SCHEMES)
    for name, url in EXAMPLES.items():
        u = parse_device_url(url)
        sch = SCHEMES[name]
        assert u.scheme == name and u.kind == sch.kind
        assert u.options == {k: v for k, v in sch.options.items() if v is not None}
        if sch.default_port is not None:
            assert u.port == sch.default_port
        with pytest.raises(ConfigError, match=re.escape(f"unknown option(s) colour for {name}")):
            parse_device_url(url + "?colour=red")
        for opt in sch.int_options:
            with pytest.raises(ConfigError, match=f"{opt} must be a positive integer"):
                parse_device_url(f"{url}?{opt}=fast")
    # the documented defaults
    assert parse_device_url("geocom:///dev/ttyUSB0").int_option("baud") == 115200
    assert parse_device_url("nmea:///dev/ttyS1").int_option("baud") == 57600
    assert parse_device_url("modbus+ftp://h").int_option("modbus_port") == 502
    assert parse_device_url("emscon://h").port == 700


@pytest.mark.parametrize("url, why", [
    ("laser://1.2.3.4", "unknown scheme 'laser'"), ("emscon", "must look like scheme://"),
    ("emscon://:700", "needs a host"), ("emscon://h:99999", "bad port"), ("ur://h:30004", "takes no port"),
    ("geocom+socket://h", "needs a port"), ("nmea://host", "serial device path"),
    ("ply://host", "folder path"), ("fake://", "device name"), ("modbus+ftp://h?modbus_port=0", "positive integer"),
])
def test_bad_urls_are_refused_naming_the_problem(url, why):
    with pytest.raises(ConfigError, match=why):
        parse_device_url(url)
    with pytest.raises(ConfigError, match=why):
        config_from_dict({"station": {"name": "x"}, "devices": {"d": {"url": url}}, "robots": {}})


class _TcpToPty:
    """A TCP serial bridge in front of a pty (what a serial device server does on the plant floor)."""

    def __init__(self, device: str) -> None:
        self.fd = os.open(device, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd, termios.TCSANOW)
        self.srv = socket.create_server(("127.0.0.1", 0))
        self.port = self.srv.getsockname()[1]
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._run)
        self._th.start()

    def _run(self) -> None:
        self.srv.settimeout(0.2)
        conn = None
        while not self._stop.is_set() and conn is None:
            try:
                conn, _ = self.srv.accept()
            except TimeoutError:
                continue
        while conn is not None and not self._stop.is_set():
            ready, _, _ = select.select([conn, self.fd], [], [], 0.1)
            if conn in ready:
                data = conn.recv(4096)
                if not data:
                    break
                os.write(self.fd, data)
            if self.fd in ready:
                try:
                    conn.sendall(os.read(self.fd, 4096))
                except OSError:
                    break
        if conn is not None:
            conn.close()

    def close(self) -> None:
        self._stop.set()
        self._th.join(5)
        self.srv.close()
        os.close(self.fd)


@pytest.fixture
def world(test_seed):
    from fakes.sim.world import make_world

    w = make_world("industrial-3100", seed=test_seed, time_scale=20.0,
                   effects=None)
    yield w
    w.close()


def test_each_scheme_opens_against_its_fake_with_the_configured_timeout(rng, world, tmp_path):
    from fakes import controller as controller_fake
    from fakes import emscon as emscon_fake
    from fakes import geocom as geocom_fake
    from fakes import odometry as odometry_fake
    from station.models.robots import get_robot
    from station.safety import SafetyGate, SafetyLimits

    timeouts = {k: float(np.round(rng.uniform(1.0, 9.0), 3)) for k in ("em", "gc", "gs", "ctrl", "odo")}
    em = emscon_fake.start_fake(world)
    gc = geocom_fake.start_fake(world)
    gc2 = geocom_fake.start_fake(world)
    ctrl = controller_fake.start_fake(world)
    odo = odometry_fake.start_fake(world)
    bridge = _TcpToPty(gc2.endpoint["device"])
    opened = []
    try:
        devices = {
            "em": f"emscon://{em.endpoint['host']}:{em.endpoint['port']}",
            "gc": f"geocom://{gc.endpoint['device']}",  # no baud: the table's 115200
            "gs": f"geocom+socket://127.0.0.1:{bridge.port}",
            "ctrl": ctrl.url,
            "odo": f"nmea://{odo.endpoint['device']}",
        }
        cfg = config_from_dict({"station": {"name": "x"}, "robots": {},
                                "devices": {k: {"url": u, "timeout_s": timeouts[k]} for k, u in devices.items()}})
        ds = configured_devices(cfg, {role: role for role in devices})
        robot = get_robot("industrial-3100")
        gate = SafetyGate(robot, SafetyLimits(workspace_min_mm=(-3000.0,) * 3, workspace_max_mm=(3000.0,) * 3,
                                              max_tcp_speed_mm_s=2000.0))
        for role in ("em", "gc", "gs"):
            drv, owned = ds.open(role)
            opened.append(drv)
            assert owned and drv.reply_timeout_s == timeouts[role]
            info = drv.connect()
            assert info is not None
            m = drv.measure_stationary(duration_s=0.1)
            assert np.all(np.isfinite(m.xyz_mm))
        assert opened[1]._transport.baudrate == 115200  # the default of the table reached the line
        drv, _ = ds.open("ctrl", gate=gate)
        opened.append(drv)
        assert drv.timeout_s == timeouts["ctrl"]
        drv.connect()
        assert drv.status() is not None
        drv, _ = ds.open("odo")
        opened.append(drv)
        assert drv.timeout_s == timeouts["odo"]
        sample = drv.read_sample()
        assert np.isfinite(sample.t_s)
    finally:
        for d in opened:
            d.close()
        bridge.close()
        for f in (odo, ctrl, gc2, gc, em):
            f.close()
