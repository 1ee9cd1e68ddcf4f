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
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import emscon_codec as ec
from drivers.geocom import parse_reply, split_values
from drivers.odometry import NmeaDecoder, encode_sentence
from drivers.ply import parse_ply, write_ply
from station.config import config_from_dict
from station.device_urls import parse_device_url
from station.errors import StationError
from station.programs.model import CartesianTarget, JointTarget, Move, Program
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


@FUZZ
@given(st.text(max_size=60))
def test_geocom_value_splitter_refuses_cleanly(text):
    _ours(split_values, text)


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
