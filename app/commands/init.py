"""`station init [--out station.toml]`: a ready station config for the fake cell.

The file names every device as the station's own fake (``fake://...``), one
robot, and the ISO 9283, trailer and arm-calibration sections with short runs,
so that ``station run iso9283|trailer|arm-calibration --config station.toml``
works at once on the simulated cell; it is the config the README's examples
use. An existing file is never overwritten (``--force`` to replace it).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from station.errors import ConfigError

TEMPLATE = """\
# A station on the fake cell, written by `station init`. Every device is the station's own
# fake (fake://...): the real drivers talk to simulators on loopback or a pty. For a real cell
# give the devices' URLs (e.g. emscon://10.0.0.5:700, modbus+ftp://10.0.0.7, nmea:///dev/ttyS1)
# and run with --arm. Units are in the key names.

[station]
name = "fake cell"
store_path = "station.sqlite"      # runs, journal, raw samples, results (SQLite, beside this file)
report_dir = "reports"

[devices.tracker]
url = "fake://tracker-emscon"

[devices.controller]
url = "fake://controller"

[devices.odometry]
url = "fake://odometry"

[devices.gauge]                    # force gauge of the static compliance test (forcegauge:///dev/ttyUSB1?baud=9600)
url = "fake://forcegauge"

[robots.r1]
model = "industrial-3100"          # rb5-850, rb5-850-as-built, ur5e, ur10e, industrial-3100
serial = "DEMO-0001"
overhaul_state = "after"
payload_kg = 0.0
controller = "controller"

[robots.r1.workspace]              # the safety gate's box (robot base frame) and caps
min_mm = [-900.0, 800.0, 500.0]
max_mm = [900.0, 2600.0, 2300.0]
max_tcp_speed_mm_s = 2000.0

[robots.r1.limits]                 # the manufacturer's figures: verdicts
rp_limit_mm = 0.5
ap_limit_mm = 5.0
vap_limit_mm = 2.0
ad_limit_mm = 2.0

[iso9283]                          # a short run; ISO 9283 itself asks for 30 cycles
cycles = 3
vap_cycles = 3
tracker_rate_hz = 100.0

[arm_calibration]
train_poses = 31
test_poses = 9

[trailer]
odometry = "odometry"
serial = "TR-DEMO"
nominal_L1_m = 1.25
nominal_L2_m = 2.48
method = "dynamic"
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("init", help="write a ready station.toml for the fake cell",
                       description="Write a station config for the fake cell (every device simulated), ready for "
                       "station run, station store and station serve --config.")
    p.add_argument("--out", default="station.toml", metavar="FILE", help="the file to write (default station.toml)")
    p.add_argument("--force", action="store_true", help="replace an existing file")
    p.set_defaults(func=_init)


def _init(args: argparse.Namespace) -> int:
    from station.config import load_config
    from station.readers.out_files import check_output, output_file

    out = check_output(args.out, "--out")  # nothing but a regular file is replaced, and that only with --force
    if out.exists() and not args.force:
        raise ConfigError(f"{out} exists; not overwritten (--force replaces it)")
    with tempfile.TemporaryDirectory(prefix="station-init-") as d:
        probe = Path(d) / "station.toml"
        probe.write_text(TEMPLATE, encoding="utf-8")
        load_config(probe)  # the template is a valid config (guards it against the schema)
    with output_file(out, "--out") as fh:
        fh.write(TEMPLATE)
    print(f"wrote {out}: the fake cell (tracker, controller, odometry simulated)")
    print(f"next: station run iso9283 --config {out}   (or trailer, arm-calibration)")
    return 0
