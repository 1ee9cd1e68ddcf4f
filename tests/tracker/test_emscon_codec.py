"""emScon TPI codec: byte-exact packets, framing, resynchronisation, refusal of bad sizes.

Expected bytes are written out by hand from the TPI header layout
(little-endian, 4-byte fields, packet size first, then the data type).
"""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest

from drivers import emscon_codec as ec
from station.errors import ProtocolError


def hx(text: str) -> bytes:
    return bytes.fromhex(text.replace(" ", ""))


# -- commands (client -> server) ----------------------------------------------------

@pytest.mark.parametrize("packet, wire", [
    (ec.CommandPacket(ec.Command.GET_SYSTEM_STATUS), "0c000000 00000000 01000000"),
    (ec.CommandPacket(ec.Command.INITIALIZE), "0c000000 00000000 07000000"),
    (ec.CommandPacket(ec.Command.SET_UNITS, (1, 0, 0, 0, 0)),
     "20000000 00000000 05000000 01000000 00000000 00000000 00000000 00000000"),
    (ec.CommandPacket(ec.Command.SET_MEASUREMENT_MODE, (1,)), "10000000 00000000 18000000 01000000"),
    (ec.CommandPacket(ec.Command.SET_COORDINATE_SYSTEM_TYPE, (0,)), "10000000 00000000 1a000000 00000000"),
    (ec.CommandPacket(ec.Command.SET_STATIONARY_MODE_PARAMS, (500, 1)),
     "14000000 00000000 1c000000 f4010000 01000000"),
    (ec.CommandPacket(ec.Command.SET_CONTINUOUS_TIME_MODE_PARAMS, (2, 0, 0, 0)),
     "1c000000 00000000 1e000000 02000000 00000000 00000000 00000000"),
    (ec.CommandPacket(ec.Command.START_MEASUREMENT), "0c000000 00000000 31000000"),
    (ec.CommandPacket(ec.Command.STOP_MEASUREMENT), "0c000000 00000000 34000000"),
])
def test_command_bytes_and_back(packet, wire):
    assert packet.encode() == hx(wire)
    assert ec.decode_packet(hx(wire), from_server=False) == packet


def test_command_with_wrong_parameters_is_refused():
    with pytest.raises(ProtocolError, match="do not fit"):
        ec.CommandPacket(ec.Command.SET_UNITS, (1, 0)).encode()
    with pytest.raises(ProtocolError, match="takes no parameters"):
        ec.CommandPacket(ec.Command.START_MEASUREMENT, (1,)).encode()


# -- server -> client ----------------------------------------------------------------

def test_reply_error_and_status_change_bytes():
    assert ec.decode_packet(hx("10000000 00000000 31000000 00000000")) == ec.CommandReply(49, 0)
    assert ec.decode_packet(hx("10000000 01000000 31000000 14270000")) == ec.ErrorPacket(49, 10004)
    assert ec.decode_packet(hx("0c000000 08000000 19000000")) == ec.StatusChangePacket(25)
    for frame in (ec.CommandReply(49, 0), ec.ErrorPacket(49, 10004), ec.StatusChangePacket(27)):
        assert ec.decode_packet(frame.encode()) == frame


def test_system_status_reply():
    wire = hx("38000000 00000000 01000000 00000000"  # size 56, command reply, GetSystemStatus, OK
              "00000000 05000000 03000000 02000000"  # last status, TP initialised, laser ready, ADM ready
              "03000000 06000000 07000000"            # version 3.6.7
              "00000000 00000000 40e20100")           # weather, flags, serial 123456
    reply = ec.decode_packet(wire)
    assert reply == ec.CommandReply(1, 0, (0, 5, 3, 2, 3, 6, 7, 0, 0, 123456))
    assert reply.encode() == wire


def test_reply_with_wrong_data_size_is_garbage():
    wire = hx("14000000 00000000 01000000 00000000 05000000")  # GetSystemStatus with 4 data bytes
    with pytest.raises(ProtocolError, match="carries 4 data bytes, expected 40"):
        ec.decode_packet(wire)


def test_single_measurement_layout():
    values = [float(i + 1) for i in range(17)]
    wire = struct.pack("<ii", 156, 2) + struct.pack("<iii", 0, 0, 0) + struct.pack("<17d", *values)
    frame = ec.decode_packet(wire)
    assert isinstance(frame, ec.SingleMeasResult)
    assert frame.xyz == (1.0, 2.0, 3.0) and frame.std_xyz == (4.0, 5.0, 6.0)
    assert frame.std_total == 7.0 and frame.apriori_std_total == 14.0
    assert (frame.temperature, frame.pressure, frame.humidity) == (15.0, 16.0, 17.0)
    assert frame.encode() == wire


def test_multi_measurement_bytes():
    wire = hx("54000000 03000000"                      # 84 bytes = 48 + 36, MultiMeasResult
              "00000000 01000000 01000000 00000000"    # status, 1 result, continuous time, not try
              "0000000000003440 0000000000003440 0000000000003440"  # 20.0, 20.0, 20.0
              "01000000 07000000 20a10700"              # speed warning, 7 s, 500000 us
              "000000000000f03f 0000000000000040 000000000000e03f")  # 1.0, 2.0, 0.5
    frame = ec.decode_packet(wire)
    assert isinstance(frame, ec.MultiMeasResult)
    assert frame.meas_mode == 1 and frame.temperature == 20.0
    np.testing.assert_array_equal(frame.t_s, [7.5])
    np.testing.assert_array_equal(frame.xyz, [[1.0, 2.0, 0.5]])
    assert frame.samples["status"][0] == 1
    built = ec.MultiMeasResult.from_arrays([7_500_000], [[1.0, 2.0, 0.5]], 1, temperature=20.0,
                                           pressure=20.0, humidity=20.0)
    assert built.encode() == wire


def test_multi_count_must_match_size():
    good = ec.MultiMeasResult.from_arrays([1000, 2000], np.ones((2, 3))).encode()
    bad = bytearray(good)
    struct.pack_into("<i", bad, 12, 3)  # claims 3 results in a 2-result packet
    with pytest.raises(ProtocolError, match="declares 3 samples but its 120 bytes hold 2"):
        ec.decode_packet(bytes(bad))


# -- framing ----------------------------------------------------------------------------

def _stream_frames(rng, n_packets):
    frames, t0 = [], 0
    for i in range(n_packets):
        kind = rng.integers(0, 4)
        if kind == 0:
            frames.append(ec.StatusChangePacket(int(rng.choice([25, 27]))))
        elif kind == 1:
            frames.append(ec.CommandReply(int(rng.choice([5, 24, 49])), 0))
        else:
            n = int(rng.integers(1, 50))
            t_us = (t0 + np.arange(n)) * 1000
            t0 += n
            frames.append(ec.MultiMeasResult.from_arrays(t_us, rng.normal(size=(n, 3)) * 1e3))
    return frames


def _decode_all(data: bytes, chunk: int | None = None):
    """Feed ``data`` in chunks like the driver's reader; returns (frames, garbage bytes, left)."""
    buf, frames, garbage = bytearray(), [], 0
    step = chunk or len(data)

    def drain(flowing: bool) -> None:
        nonlocal garbage
        while True:
            consumed, frame = ec.decode(bytes(buf), require_successor=flowing)
            if consumed == 0:
                return
            del buf[:consumed]
            if isinstance(frame, ec.Garbage):
                garbage += frame.nbytes
            else:
                frames.append(frame)

    for i in range(0, len(data), step):
        buf += data[i:i + step]
        drain(flowing=True)
    drain(flowing=False)  # the link went quiet: what is complete is final
    while buf:  # and, as the driver does then, a packet still waiting for its tail is given up, the rest read
        consumed, frame = ec.skip_stalled(bytes(buf))
        del buf[:consumed]
        garbage += frame.nbytes
        drain(flowing=False)
    return frames, garbage, len(buf)


def _same(a, b) -> bool:
    if isinstance(a, ec.MultiMeasResult):
        return isinstance(b, ec.MultiMeasResult) and a.encode() == b.encode()
    return a == b


@pytest.mark.parametrize("chunk", [None, 1, 7, 1000])
def test_stream_decodes_in_any_chunking(chunk):
    frames = _stream_frames(np.random.default_rng(5), 12 if chunk == 1 else 40)
    got, garbage, left = _decode_all(b"".join(f.encode() for f in frames), chunk)
    assert garbage == 0 and left == 0
    assert len(got) == len(frames) and all(_same(a, b) for a, b in zip(frames, got))


def test_garbage_between_packets_is_skipped_and_counted_exactly(rng):
    frames = _stream_frames(rng, 60)
    data, injected = bytearray(), 0
    for f in frames:
        if rng.random() < 0.4:
            junk = rng.integers(0, 256, int(rng.integers(1, 80)), dtype=np.uint8).tobytes()
            data += junk
            injected += len(junk)
        data += f.encode()
    got, garbage, left = _decode_all(bytes(data), chunk=int(rng.integers(1, 300)))
    assert left == 0
    assert garbage == injected
    assert len(got) == len(frames) and all(_same(a, b) for a, b in zip(frames, got))


def test_truncated_packet_loses_only_itself(rng):
    """A packet cut short anywhere is rejected; the packets around it survive.

    The one cut no framing without a checksum can see - the missing tail is
    exactly as long as the next packet, which then fills it - is not drawn.
    A cut packet whose missing tail is longer than all that follows waits
    until the link goes quiet and is then given up (seed 1146845954).
    """
    for _ in range(40):
        frames = [f for f in _stream_frames(rng, 30) if isinstance(f, ec.MultiMeasResult)]
        victim = int(rng.integers(0, len(frames) - 1))
        data = bytearray()
        for i, f in enumerate(frames):
            wire = f.encode()
            if i == victim:
                lengths = np.arange(8, len(wire))
                lengths = lengths[len(wire) - lengths != len(frames[i + 1].encode())]
                wire = wire[: int(rng.choice(lengths))]
            data += wire
        got, garbage, left = _decode_all(bytes(data), chunk=int(rng.integers(1, 400)))
        expected = frames[:victim] + frames[victim + 1:]
        assert left == 0
        assert len(got) == len(expected) and all(_same(a, b) for a, b in zip(expected, got))


def test_truncated_last_packet_waits_then_is_skipped_when_the_link_is_quiet():
    wire = ec.MultiMeasResult.from_arrays([1000, 2000, 3000], np.ones((3, 3))).encode()
    cut = wire[:100]
    assert ec.decode(cut) == (0, None)  # could still be arriving
    consumed, frame = ec.skip_stalled(cut)
    assert consumed == 100 and isinstance(frame, ec.Garbage) and "100 of 156 bytes" in frame.reason


def test_flowing_reader_holds_a_multi_result_until_its_successor_shows():
    wire = ec.MultiMeasResult.from_arrays([1000], np.ones((1, 3))).encode()
    assert ec.decode(wire, require_successor=True) == (0, None)
    nxt = ec.CommandReply(52, 0).encode() + ec.StatusChangePacket(27).encode()
    consumed, frame = ec.decode(wire + nxt, require_successor=True)
    assert consumed == len(wire) and isinstance(frame, ec.MultiMeasResult)
    assert ec.decode(wire, require_successor=False)[0] == len(wire)


def test_huge_declared_length_is_refused_from_the_header():
    huge = struct.pack("<ii", 2**31 - 1, ec.DataType.MULTI_MEAS_RESULT)
    good = ec.StatusChangePacket(27).encode()
    t0 = time.perf_counter()
    consumed, frame = ec.decode(huge + good)
    assert time.perf_counter() - t0 < 0.5  # refused at once, nothing of that size allocated
    assert isinstance(frame, ec.Garbage) and consumed == 8
    assert "2147483647" in frame.reason and "limit" in frame.reason
    assert ec.decode(good) == (12, ec.StatusChangePacket(27))
    with pytest.raises(ProtocolError, match="exceeds the 1048576-byte limit"):
        ec.decode_packet(struct.pack("<ii", 1 << 21, ec.DataType.MULTI_MEAS_RESULT) + bytes(16))


@pytest.mark.parametrize("header, reason", [
    ((4, 8), "below the 12-byte minimum"),
    ((14, 8), "not a multiple of 4"),
    ((16, 99), "unknown packet type 99"),
    ((20, 8), "must be 12 bytes"),
    ((52, 3), r"not 48 \+ 36 n"),
    ((-12, 0), "below the 12-byte minimum"),
])
def test_malformed_sizes_name_the_problem(header, reason):
    with pytest.raises(ProtocolError, match=reason):
        ec.decode_packet(struct.pack("<ii", *header) + bytes(max(0, header[0] - 8)))


def test_need_more_and_leftover():
    wire = ec.CommandReply(49, 0).encode()
    assert ec.decode(wire[:7]) == (0, None)
    assert ec.decode(wire[:15]) == (0, None)
    with pytest.raises(ProtocolError, match="declares 16 bytes but only 15"):
        ec.decode_packet(wire[:15])
    with pytest.raises(ProtocolError, match="4 bytes left over"):
        ec.decode_packet(wire + b"\0\0\0\0")


def test_device_time_split_and_join():
    t_us = np.array([0, 999_999, 1_000_000, 123_456_789])
    s, us = ec.split_time_us(t_us)
    np.testing.assert_array_equal(s, [0, 0, 1, 123])
    np.testing.assert_array_equal(us, [0, 999_999, 0, 456_789])
    np.testing.assert_allclose(ec.join_time_s(s, us), t_us / 1e6, rtol=0, atol=1e-12)
    with pytest.raises(ProtocolError):
        ec.split_time_us([-1])


def _decode_view(data: bytes):
    view, off, frames = memoryview(data), 0, []
    while True:
        c, f = ec.decode(view[off:], from_server=True, require_successor=True)
        if c == 0:
            return frames, off
        off += c
        frames.append(f)


def test_resynchronisation_work_is_linear_in_the_bytes(monkeypatch):
    """Status changes each followed by 4 junk bytes (issue reproducer): every packet kept, and the header scan
    reads a bounded number of words per byte (it used to rescan the rest of the buffer at every skip)."""
    scanned = [0]
    real = ec._plausible_mask

    def counting(words, *a, **k):
        scanned[0] += words.size
        return real(words, *a, **k)

    monkeypatch.setattr(ec, "_plausible_mask", counting)
    pkt = bytes.fromhex("0c000000080000001b000000eeeeeeee")
    per_byte = []
    for reps in (256, 2048):
        scanned[0] = 0
        frames, used = _decode_view(pkt * reps)
        events = [f for f in frames if isinstance(f, ec.StatusChangePacket)]
        junk = [f for f in frames if isinstance(f, ec.Garbage)]
        assert len(events) == reps
        assert sum(g.nbytes for g in junk) == 4 * (reps - 1)
        per_byte.append(scanned[0] / (16 * reps))
    assert per_byte[1] < 1.2 * per_byte[0] + 1.0
