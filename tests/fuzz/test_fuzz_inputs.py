"""Property-based fuzzing of everything that reads outside input (hypothesis; examples drawn anew each run).

Each property: any input ends in a result or in the project's own error
(a :class:`~station.errors.StationError`), never a foreign exception; valid
input survives a round trip; decoders give the same result however the
bytes are split. The budget keeps the whole file to a few seconds; the long
run with its figures is ``bench/bench_fuzz.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import emscon_codec as ec
from drivers.geocom_codec import parse_reply, split_values
from drivers.odometry import NmeaDecoder, encode_sentence
from drivers.ply import parse_ply, write_ply
from station.config import config_from_dict
from station.device_urls import parse_device_url
from station.errors import StationError
from station.programs.program import CartesianTarget, JointTarget, Move, Program
from station.programs.rapid import render_rapid

FUZZ = settings()  # the budget comes from the loaded profile (tests/fuzz/conftest.py)


def _ours(fn, *args, **kwargs):
    """Call ``fn``; our own errors are refusals, anything else fails the property."""
    try:
        return fn(*args, **kwargs)
    except StationError:
        return None


# -- emScon -------------------------------------------------------------------------------
_PACKETS = [ec.StatusChangePacket(27).encode(),
            ec.MultiMeasResult.from_arrays(np.array([1000, 2000]), [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]).encode()]


@FUZZ
@given(st.lists(st.one_of(st.sampled_from(_PACKETS), st.binary(max_size=40)), max_size=20),
       st.lists(st.integers(1, 64), min_size=1, max_size=8))
def test_emscon_decoder_never_raises_and_any_split_decodes_alike(parts, cuts):
    data = b"".join(parts)

    def decode_all(chunks):
        rx, frames = bytearray(), []
        for c in chunks:
            rx += c
            view, off = memoryview(bytes(rx)), 0
            while True:
                n, f = ec.decode(view[off:], from_server=True)
                if n == 0:
                    break
                off += n
                frames.append(f)
            del rx[:off]
        return frames, bytes(rx)

    whole = decode_all([data])
    chunks, i, k = [], 0, 0
    while i < len(data):
        step = cuts[k % len(cuts)]
        chunks.append(data[i:i + step])
        i, k = i + step, k + 1
    split = decode_all(chunks)
    kinds = lambda fs: [type(f).__name__ for f in fs if not isinstance(f, ec.Garbage)]  # noqa: E731
    assert kinds(split[0]) == kinds(whole[0])


# -- GeoCOM -------------------------------------------------------------------------------
@FUZZ
@given(st.one_of(st.binary(max_size=80),
                 st.builds(lambda a, b, c, vals: f"%R1P,{a},{b}:{c},{vals}".encode(),
                           st.integers(-5, 70000), st.integers(-5, 70000), st.integers(-5, 70000),
                           st.text(alphabet="0123456789.,-+e\"x ", max_size=60))))
def test_geocom_reply_parser_refuses_cleanly(line):
    r = _ours(parse_reply, line)
    if r is not None:
        assert isinstance(r.values, tuple)


_plain_value = st.text(alphabet=st.characters(blacklist_characters=',"\r\n', blacklist_categories=("Cs",)),
                      max_size=12)
_quoted_value = st.text(alphabet=st.characters(blacklist_characters='"\r\n', blacklist_categories=("Cs",)),
                        max_size=12).map(lambda t: f'"{t}"')
_values = st.lists(st.one_of(_plain_value, _quoted_value, st.integers(-2**31, 2**31 - 1).map(str),
                             st.floats(allow_nan=False, allow_infinity=False).map(repr)), min_size=1, max_size=8)


@FUZZ
@given(st.integers(0, 70000), st.integers(0, 2**15 - 1), st.integers(0, 70000),
       st.lists(st.one_of(st.integers(-2**31, 2**31 - 1).map(str), st.floats(allow_nan=False).map(repr),
                          st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789 .,-_", max_size=12)
                          .map(lambda t: f'"{t}"')), max_size=8))
def test_geocom_reply_parser_accepts_every_valid_reply_exactly(com_rc, trid, rc, values):
    line = f"%R1P,{com_rc},{trid}:{rc}" + "".join("," + v for v in values)
    reply = parse_reply(line.encode("latin-1"))
    assert (reply.com_rc, reply.trid, reply.rc, reply.values) == (com_rc, trid, rc, tuple(values))


@FUZZ
@given(st.text(max_size=60))
def test_geocom_value_splitter_refuses_cleanly(text):
    _ours(split_values, text)


@FUZZ
@given(_values)
def test_geocom_value_splitter_gives_back_every_value_of_a_valid_list(values):
    assert split_values(",".join(values)) == tuple(values)


# -- NMEA ---------------------------------------------------------------------------------
@FUZZ
@given(st.lists(st.one_of(st.binary(max_size=50),
                          st.builds(lambda t, k, p: encode_sentence(["PODO", f"{t:.3f}", "1.0", f"{k:.6f}", f"{p:.6f}"]),
                                    st.floats(0, 1e4), st.floats(-1, 1), st.floats(-3, 3))), max_size=15),
       st.integers(1, 30))
def test_nmea_decoder_never_raises_and_keeps_every_valid_sentence(parts, step):
    data = b"".join(parts)
    whole = NmeaDecoder()
    a = whole.feed(data)
    split = NmeaDecoder()
    b = []
    for i in range(0, len(data), step):
        b += split.feed(data[i:i + step])
    assert a == b


# -- device URLs, configs -------------------------------------------------------------------
@FUZZ
@given(st.one_of(st.text(max_size=60),
                 st.builds(lambda s, h, p, q: f"{s}://{h}:{p}{q}",
                           st.sampled_from(["emscon", "geocom", "geocom+socket", "modbus+ftp", "ur", "nmea", "ply",
                                            "fake", "http", ""]),
                           st.text(max_size=20), st.one_of(st.integers(-10, 70000), st.text(max_size=6)),
                           st.text(max_size=20))))
def test_device_url_parser_refuses_cleanly(url):
    _ours(parse_device_url, url)


_host = st.one_of(st.builds(lambda a, b, c: f"127.{a}.{b}.{c}", *[st.integers(0, 255)] * 3),
                  st.from_regex(r"[a-z][a-z0-9-]{0,14}[a-z0-9]", fullmatch=True))
_path = st.lists(st.from_regex(r"[A-Za-z0-9_.-]{1,10}", fullmatch=True).filter(lambda p: p not in (".", "..")),
                 min_size=1, max_size=4).map(lambda parts: "/" + "/".join(parts))


@FUZZ
@given(st.sampled_from(["emscon", "geocom+socket", "modbus+ftp", "ur"]), _host, st.integers(1, 65535),
       st.integers(1, 10**9 - 1))
def test_device_url_parser_accepts_every_valid_host_url(scheme, host, port, n):
    with_port = scheme != "ur"
    url = f"{scheme}://{host}" + (f":{port}" if with_port else "") + ("?modbus_port=%d" % n if scheme == "modbus+ftp" else "")
    u = parse_device_url(url)
    assert (u.scheme, u.host, u.port, u.path) == (scheme, host, port if with_port else None, None)
    if scheme == "modbus+ftp":
        assert u.int_option("modbus_port") == n


@FUZZ
@given(st.sampled_from(["geocom", "nmea", "ply"]), _path, st.integers(1, 10**9 - 1))
def test_device_url_parser_accepts_every_valid_path_url(scheme, path, baud):
    query = f"?baud={baud}" if scheme != "ply" else ""
    u = parse_device_url(f"{scheme}://{path}{query}")
    assert (u.scheme, u.host, u.path) == (scheme, None, path)
    if scheme != "ply":
        assert u.int_option("baud") == baud


_json = st.recursive(st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                               st.text(max_size=10)),
                     lambda inner: st.one_of(st.lists(inner, max_size=4),
                                             st.dictionaries(st.text(max_size=12), inner, max_size=4)),
                     max_leaves=30)


@FUZZ
@given(st.dictionaries(st.sampled_from(["station", "devices", "robots", "iso9283", "trailer", "arm_calibration",
                                        "other"]), _json, max_size=5))
def test_config_loader_refuses_cleanly(data):
    _ours(config_from_dict, data)


@FUZZ
@given(st.integers(2, 1000), st.integers(2, 1000), st.floats(10.0, 3000.0), st.floats(0.001, 10.0),
       st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789-", min_size=1, max_size=20),
       st.floats(-500.0, 500.0), st.floats(1.0, 500.0))
def test_config_loader_accepts_every_valid_config(cycles, vap_cycles, rate_hz, rp_limit, serial, x0, size):
    from pathlib import Path

    from fakes.cells import demo_config

    data = demo_config(Path("/tmp/station-fuzz"), cycles=cycles, vap_cycles=vap_cycles, rate_hz=rate_hz)
    robot = data["robots"]["r1"]
    robot["serial"] = serial
    robot["limits"]["rp_limit_mm"] = rp_limit
    robot["workspace"]["min_mm"][0], robot["workspace"]["max_mm"][0] = x0, x0 + size
    cfg = config_from_dict(data)
    assert (cfg.iso9283.cycles, cfg.iso9283.vap_cycles, cfg.iso9283.tracker_rate_hz) == (cycles, vap_cycles, rate_hz)
    assert cfg.robots["r1"].serial == serial and cfg.robots["r1"].limits.rp_limit_mm == rp_limit


# -- PLY ----------------------------------------------------------------------------------
@FUZZ
@given(st.binary(max_size=300))
def test_ply_parser_refuses_random_bytes_cleanly(data):
    _ours(parse_ply, b"ply\n" + data)


@FUZZ
@given(st.lists(st.tuples(*[st.floats(-1e6, 1e6, allow_nan=False)] * 3), max_size=30),
       st.booleans(), st.sampled_from(["float", "double"]))
def test_ply_round_trip_of_any_finite_cloud(tmp_path_factory, pts, binary, dtype):
    path = tmp_path_factory.mktemp("ply") / "c.ply"
    a = np.array(pts, dtype=float).reshape(-1, 3)
    write_ply(path, a, binary=binary, dtype=dtype)
    b = parse_ply(path.read_bytes())
    want = a.astype(np.float32).astype(float) if dtype == "float" else a
    np.testing.assert_array_equal(b, want)


# -- program generator ------------------------------------------------------------------------
@FUZZ
@given(st.text(alphabet="abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_", min_size=1, max_size=20),
       st.lists(st.tuples(st.floats(-3000, 3000), st.floats(-3000, 3000), st.floats(-3000, 3000)), min_size=1,
                max_size=4),
       st.floats(0.0, 1.5))
def test_program_generator_refuses_or_renders_what_parses_back(name, points, speed):
    from fakes.rapid_interp import parse_rapid

    def build():
        moves = tuple(Move(CartesianTarget(f"P{i + 1}", p, (0.0, 0.0, 1.0, 0.0)), "joint", speed)
                      for i, p in enumerate(points))
        moves += (Move(JointTarget("J1", (0.0, 10.0, -10.0, 0.0, 30.0, 0.0)), "joint", speed),)
        return render_rapid(Program(name=name, robot_name="r", rated_tcp_speed_mm_s=1000.0, statements=moves,
                                    accel_frac=0.5))

    rendered = _ours(build)
    if rendered is not None:
        module = parse_rapid(rendered.files[rendered.main_file])
        assert module is not None
        assert math.isfinite(speed) and speed > 0
    elif name[0].isalpha() and 0.0 < speed <= 1.0:
        # a valid name, targets and speed: refusing it is a bug (only names that clash with what the
        # generator declares itself may be refused)
        with pytest.raises(StationError, match="same identifier|reserved word"):
            build()


_PROGRAM = {"robot": "ur5e", "rate_hz": 333.333, "cycles": 3, "dwell_s": 2.0, "wait_s": 2.0, "payload_kg": 0.0,
            "speed_pct": 100, "start": "P1", "order": ["P2", {"to": "P1", "type": "joint", "speed": 30.0}],
            "move": {"type": "joint", "speed": 60.0, "acceleration": 80.0, "profile": "trapezoid"},
            "poses": {"P1": {"joints_deg": [-80.0, -100.0, 100.0, -90.0, -90.0, 0.0]},
                      "P2": {"xyz_mm": [400.0, 100.0, 300.0]}}}


#: every value of the program above, by its keys
_PROGRAM_PATHS = [(k,) for k in _PROGRAM] + [("order", 0), ("order", 1), ("order", 1, "to"), ("order", 1, "type"),
                                             ("order", 1, "speed")] \
    + [("move", k) for k in _PROGRAM["move"]] + [("poses", "P1"), ("poses", "P2"), ("poses", "P1", "joints_deg"),
                                                 ("poses", "P2", "xyz_mm")] \
    + [("poses", "P1", "joints_deg", i) for i in range(6)] + [("poses", "P2", "xyz_mm", i) for i in range(3)]


@FUZZ
@given(data=st.data())
def test_fuzz_a_program_with_one_value_replaced_is_read_or_refused_naming_it(data):
    """Any one value of a good motion program replaced by junk: the program is read, or refused with a
    ConfigError that names the file (never another exception)."""
    import copy

    from station.errors import ConfigError
    from station.readers.motion_program import parse_motion_program

    prog = copy.deepcopy(_PROGRAM)
    path = data.draw(st.sampled_from(_PROGRAM_PATHS))
    junk = data.draw(st.one_of(st.none(), st.booleans(), st.integers(-10**30, 10**30), st.floats(allow_nan=True),
                               st.text(max_size=20), st.lists(st.floats(-1e6, 1e6), max_size=8),
                               st.dictionaries(st.text(max_size=5), st.integers(), max_size=3)))
    node = prog
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = junk
    try:
        parse_motion_program(prog, "fuzz.toml")
    except ConfigError as exc:
        assert "program fuzz.toml: `" in str(exc), str(exc)
