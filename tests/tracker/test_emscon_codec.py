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
    step = chunk or len(data)
    return _decode_parts([data[i:i + step] for i in range(0, len(data), step)])


def _decode_parts(parts, *, quiet_after_each: bool = False):
    """Feed the byte strings ``parts`` one read each, as the driver's reader does: every read decoded
    while data flows (a multi result waits for what follows it), then the link goes quiet (what is
    complete is final), then a packet still waiting for its tail is given up. ``quiet_after_each``:
    the link also goes quiet (for less than the stall time) after every part. Returns (frames,
    garbage bytes, left)."""
    buf, frames, garbage = bytearray(), [], 0

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

    for part in parts:
        buf += part
        drain(flowing=True)
        if quiet_after_each:
            drain(flowing=False)
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

    Also the cut whose missing tail is exactly as long as the next packet,
    which then fills it: that packet starts inside the glued multi result and
    runs to the next header, which gives the truncation away (it used to be
    left out of the draw, and the next packet was lost to wrong samples).
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
                exact = len(wire) - len(frames[i + 1].encode())
                wire = wire[: exact if exact >= 8 and rng.random() < 0.25 else int(rng.choice(lengths))]
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


def _last_packet(n: int = 9) -> ec.MultiMeasResult:
    """A short data packet as StopMeasurement flushes it: ``n`` samples on the 1 ms grid after 16 s."""
    t_us = 16_000_000 + 1000 * np.arange(n)
    a = t_us * 1e-6
    return ec.MultiMeasResult.from_arrays(t_us, np.column_stack([1800 + 300 * np.cos(a), -250 + 300 * np.sin(a),
                                                                 420 + 30 * np.sin(2 * a)]))


#: how the bytes of "truncated packet, reply" reach the reader: in one read; the truncated packet and the
#: reply in separate reads; separate reads with the link quiet in between; one byte a read
_ARRIVALS = {
    "together": lambda cut, rest: ([cut + rest], False),
    "apart": lambda cut, rest: ([cut, rest], False),
    "apart_quiet": lambda cut, rest: ([cut, rest], True),
    "bytewise": lambda cut, rest: ([bytes([b]) for b in cut + rest], False),
}


@pytest.mark.parametrize("arrival", sorted(_ARRIVALS))
@pytest.mark.parametrize("missing", range(0, 41))
def test_truncated_last_packet_is_never_completed_by_the_stop_reply(missing, arrival):
    """The last data packet of a stream - the one StopMeasurement flushes - cut ``missing`` bytes short,
    then the reply to StopMeasurement, then nothing: its samples are never delivered, the reply is.

    Why: with 8 to 16 bytes missing the 16-byte reply completed the packet (its bytes land in the last
    sample's doubles, which no body check can judge) and, nothing following to contradict it, the
    glued multi result was delivered as if whole - samples the device never sent whole (the e2e
    truncation test once received 1409 of 1400 samples sent: a 9-sample flush packet cut 8..16 bytes
    short) - and the swallowed reply cost a StopMeasurement retry. The reply that starts inside the
    multi result and runs exactly to the end of what arrived gives the truncation away. ``missing`` 0
    is the whole packet: it is delivered (nothing of a whole packet is lost). The other lengths: the
    reply leaves bytes that cannot start a packet after the multi result (fewer than 8 missing) or
    the multi result waits for a tail that never comes and is given up when the link is quiet.
    """
    packet = _last_packet().encode()
    reply = ec.CommandReply(ec.Command.STOP_MEASUREMENT, 0)
    cut = packet[:len(packet) - missing]
    parts, quiet = _ARRIVALS[arrival](cut, reply.encode())
    frames, garbage, left = _decode_parts(parts, quiet_after_each=quiet)
    assert left == 0
    _check_last_packet_outcome(missing, cut, reply, frames, garbage)


@pytest.mark.parametrize("reply_read", range(8, 16))
@pytest.mark.parametrize("missing", range(0, 41))
def test_truncated_last_packet_is_never_completed_by_a_stop_reply_that_arrives_in_two_reads(missing, reply_read):
    """As above, the reply split over two reads with the link quiet in between, the first read ending
    ``reply_read`` bytes into it (its header arrived): the cut packet is complete before the reply
    is, so what follows it cannot be judged yet; the reply's header inside it holds it back until the
    rest shows the reply whole. (Not covered: a cut in the packet's last 7 bytes and a read that ends
    before the reply's 8 header bytes have arrived, the link quiet there - nothing to judge by yet.)
    """
    packet = _last_packet().encode()
    reply = ec.CommandReply(ec.Command.STOP_MEASUREMENT, 0)
    cut = packet[:len(packet) - missing]
    wire = reply.encode()
    frames, garbage, left = _decode_parts([cut + wire[:reply_read], wire[reply_read:]], quiet_after_each=True)
    assert left == 0
    _check_last_packet_outcome(missing, cut, reply, frames, garbage)


def _check_last_packet_outcome(missing, cut, reply, frames, garbage):
    if missing == 0:
        assert len(frames) == 2 and _same(frames[0], _last_packet()) and frames[1] == reply
        assert garbage == 0
    else:
        assert frames == [reply]  # no MultiMeasResult: the cut packet's samples are lost, not delivered
        assert garbage == len(cut)


@pytest.mark.parametrize("arrival", ["together", "per_packet", "per_packet_quiet"])
@pytest.mark.parametrize("filler", ["status_change", "next_packet", "status_change_and_reply"])
@pytest.mark.parametrize("then", ["more_data", "nothing"])
def test_truncated_packet_whose_missing_tail_is_exactly_the_next_packets_is_rejected(filler, then, arrival):
    """A data packet whose missing tail is exactly as long as the packet(s) after it, which then
    complete it: they are packets again, the cut packet is rejected.

    Why: the status change the beam break sends (12 bytes), a whole next data packet, or a status
    change and a reply land only in the cut packet's last doubles or in sample slots that happen to
    check out; the bytes after the glued multi result are a plausible header (the next packet) or
    nothing, so the check of what follows cannot see it. Before, the cut packet came out whole with
    wrong values in it and the packet(s) it swallowed were lost (a beam-break event, a reply, a whole
    packet of samples). The packet that starts inside the multi result and runs to a plausible header
    or to the end of what arrived shows the truncation, whatever the reads.
    """
    first = _last_packet(5)
    victim = ec.MultiMeasResult.from_arrays(16_005_000 + 1000 * np.arange(40), first.xyz[[0]].repeat(40, 0) + 0.5)
    fillers = {
        "status_change": [ec.StatusChangePacket(ec.SystemStatusChange.MEAS_STATUS_NOT_READY)],
        "next_packet": [ec.MultiMeasResult.from_arrays(16_045_000 + 1000 * np.arange(3), np.ones((3, 3)))],
        "status_change_and_reply": [ec.StatusChangePacket(ec.SystemStatusChange.MEAS_STATUS_READY),
                                    ec.CommandReply(ec.Command.GET_SYSTEM_STATUS, 0, tuple(range(10)))],
    }[filler]
    after = [ec.MultiMeasResult.from_arrays(16_050_000 + 1000 * np.arange(4), np.full((4, 3), 7.0))] \
        if then == "more_data" else []
    missing = sum(len(f.encode()) for f in fillers)
    wires = [first.encode(), victim.encode()[:-missing], *(f.encode() for f in fillers + after)]
    if arrival == "together":
        parts, quiet = [b"".join(wires)], False
    else:
        parts, quiet = wires, arrival == "per_packet_quiet"
    frames, garbage, left = _decode_parts(parts, quiet_after_each=quiet)
    expected = [first, *fillers, *after]
    assert left == 0 and garbage == len(wires[1])
    assert len(frames) == len(expected) and all(_same(a, b) for a, b in zip(expected, frames))


@pytest.mark.parametrize("after_end", range(0, 8))
@pytest.mark.parametrize("missing", [8, 12, 16, 36, 100])
def test_truncated_packet_read_to_just_past_its_declared_end_while_the_link_pauses_is_rejected(missing, after_end):
    """A data packet cut ``missing`` bytes short, then the next data packet whole; a read ends
    ``after_end`` bytes past the end the cut packet declares, and the link pauses there (a busy
    sender: the reader's quiet decode runs) before the rest arrives. The cut packet is rejected and
    the next one delivered whole.

    Why: too few bytes followed the glued multi result to judge them as a header, so it was taken as
    final and its samples delivered - wrong in their last slots - while the next packet was lost as
    garbage (e2e, every packet cut 16 bytes short, under load: one packet's samples received although
    none was sent whole). The next packet's header and count inside the glued multi result hold it
    back until the next packet's rest shows it.
    """
    first = _last_packet(5)
    victim = ec.MultiMeasResult.from_arrays(16_005_000 + 1000 * np.arange(100), first.xyz[[0]].repeat(100, 0) + 0.5)
    nxt = ec.MultiMeasResult.from_arrays(16_105_000 + 1000 * np.arange(100), np.full((100, 3), 7.0))
    cut = victim.encode()[:-missing]
    data = first.encode() + cut + nxt.encode()
    end = len(first.encode()) + len(victim.encode()) + after_end  # where the cut packet's declared length ends
    frames, garbage, left = _decode_parts([data[:end], data[end:]], quiet_after_each=True)
    assert left == 0 and garbage == len(cut)
    assert len(frames) == 2 and _same(frames[0], first) and _same(frames[1], nxt)


@pytest.mark.parametrize("arrival", ["together", "per_packet", "per_packet_quiet"])
@pytest.mark.parametrize("missing", [8, 16, 40])
def test_a_run_of_truncated_packets_is_rejected_whole(missing, arrival):
    """Four data packets in a row each cut ``missing`` bytes short, then the reply to StopMeasurement:
    none of their samples is delivered, the reply is.

    Why: the packet that starts inside a cut packet is cut short itself, so it is followed by bytes
    that cannot start a packet; when it had arrived whole before the one before it was judged (a
    reader that lags behind reads the run at once) it did not count as a packet starting inside, and
    the first cut packet was delivered (e2e, every packet cut 16 bytes short, under load). A multi
    result's header and first sample now vouch for it whatever follows.
    """
    t0 = 16_000_000
    wires = [ec.MultiMeasResult.from_arrays(t0 + 1000 * (100 * i + np.arange(100)), np.full((100, 3), float(i + 1)))
             .encode()[:-missing] for i in range(4)]
    reply = ec.CommandReply(ec.Command.STOP_MEASUREMENT, 0)
    wires.append(reply.encode())
    parts = [b"".join(wires)] if arrival == "together" else wires
    frames, garbage, left = _decode_parts(parts, quiet_after_each=arrival == "per_packet_quiet")
    assert left == 0
    assert frames == [reply] and garbage == sum(len(w) for w in wires[:-1])


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
