"""6-DoF over emScon (a T-Mac on the tool): the ProbeContinuousResultT codec, the driver's 6D continuous
time stream against the fake over loopback, and malformed 6-DoF packets refused naming what is wrong."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from drivers import emscon_codec as ec
from drivers.emscon import EmsconTracker
from drivers.transport import tcp_factory
from fakes.emscon import start_fake
from fakes.sim.six_dof import matrices_to_quat_wxyz
from station.analysis.iso9283.orientation import quat_to_matrices
from station.errors import ProtocolError
from station.models.rotation import rotvec_of, rotvec_to_matrix

from .conftest import CircleSource, CircleWorld

RATE = 500.0


class TurningSource(CircleSource):
    """The circle's target turning as it goes: about an axis drawn per test, an angle growing with time."""

    def __init__(self, clock, rate_hz, axis, **kw) -> None:
        super().__init__(clock, rate_hz, **kw)
        self.axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)

    def orientation(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float).reshape(-1)
        return rotvec_to_matrix(np.outer(0.3 + 0.2 * np.sin(t), self.axis))


class TurningWorld(CircleWorld):
    def __init__(self, axis, **kw) -> None:
        super().__init__(rate_hz=RATE, **kw)
        self.source = TurningSource(self.clock, RATE, axis)


@pytest.fixture
def rig():
    made = []

    def make(axis, faults=None):
        world = TurningWorld(axis)
        fake = start_fake(world, faults=faults)
        tracker = EmsconTracker(tcp_factory(fake.endpoint["host"], fake.endpoint["port"]))
        made.append((fake, tracker))
        tracker.connect(timeout_s=10)
        return world, fake, tracker

    yield make
    for fake, tracker in made:
        tracker.close()
        fake.close()


def _angle_between(Ra, Rb) -> np.ndarray:
    return np.linalg.norm(rotvec_of(np.swapaxes(Ra, 1, 2) @ Rb), axis=1)


def _packet(rng, n=4):
    R = rotvec_to_matrix(rng.normal(0, 1.0, (n, 3)))
    t_us = np.sort(rng.integers(0, 10**9, n))
    return ec.ProbeContinuousResult.from_arrays(t_us, rng.normal(0, 1000, (n, 3)), matrices_to_quat_wxyz(R)), R


def test_a_6dof_packet_decodes_to_what_was_encoded(rng):
    frame, R = _packet(rng)
    back = ec.decode_packet(frame.encode())
    assert isinstance(back, ec.ProbeContinuousResult)
    assert len(frame.encode()) == ec.PROBE_HEADER_BYTES + 212 * 4
    np.testing.assert_array_equal(back.xyz, frame.xyz)
    np.testing.assert_array_equal(back.t_s, frame.t_s)
    assert np.max(_angle_between(quat_to_matrices(back.quat_wxyz), R)) < 1e-12
    assert back.meas_mode == ec.MeasMode.SIX_DOF_CONTINUOUS_TIME


def test_malformed_6dof_packets_are_refused_naming_what_is_wrong(rng):
    frame, _ = _packet(rng)
    good = frame.encode()
    j = int(rng.integers(0, 4))
    q_off = ec.PROBE_HEADER_BYTES + 212 * j + 20 + 10 * 8  # sample j's Quaternion0
    bad = bytearray(good)
    struct.pack_into("<d", bad, q_off, struct.unpack_from("<d", bad, q_off)[0] + 0.05)
    with pytest.raises(ProtocolError, match=f"sample {j} has quaternion .* not a unit quaternion"):
        ec.decode_packet(bytes(bad))
    nan = bytearray(good)
    struct.pack_into("<d", nan, q_off, float("nan"))
    with pytest.raises(ProtocolError, match=f"sample {j} has quaternion"):
        ec.decode_packet(bytes(nan))
    count = bytearray(good)
    struct.pack_into("<i", count, 12, 5)  # lNumberOfResults
    with pytest.raises(ProtocolError, match="declares 5 samples but its 916 bytes hold 4"):
        ec.decode_packet(bytes(count))
    short = bytearray(good[:-8])
    struct.pack_into("<i", short, 0, len(short))
    with pytest.raises(ProtocolError, match="is not 68 \\+ 212 n"):
        ec.decode_packet(bytes(short))
    trig = bytearray(good)
    struct.pack_into("<i", trig, ec.PROBE_HEADER_BYTES + 212 * j + 4, 7)  # triggerStatus
    with pytest.raises(ProtocolError, match=f"sample {j} has .*triggerStatus 7"):
        ec.decode_packet(bytes(trig))
    # a sample the tracker flags as not measured (Error6D) may carry any quaternion: not malformed
    flagged = bytearray(bad)
    struct.pack_into("<i", flagged, ec.PROBE_HEADER_BYTES + 212 * j + 8, 0b11)
    assert isinstance(ec.decode_packet(bytes(flagged)), ec.ProbeContinuousResult)


def test_the_6d_stream_carries_the_targets_orientation_at_each_device_time(rig, rng):
    world, fake, tracker = rig(rng.normal(size=3))
    tracker.start_stream(RATE, six_dof=True)
    quats, ts, xs = [], [], []
    t_end = world.clock.now() + 2.0
    while world.clock.now() < t_end:
        b = tracker.read_samples(0.05)
        if len(b):
            assert b.quat_wxyz is not None and b.quat_wxyz.shape == (len(b), 4)
            quats.append(b.quat_wxyz), ts.append(b.t_s), xs.append(b.xyz_mm)
    record = tracker.stop_stream()
    t = np.concatenate(ts)
    assert record.received >= len(t) >= 0.9 * 2.0 * RATE and record.rejected == 0
    np.testing.assert_allclose(np.concatenate(xs), world.source.truth(t), rtol=0, atol=1e-9)
    err = _angle_between(quat_to_matrices(np.concatenate(quats)), world.source.orientation(t))
    assert np.max(err) < 1e-9


def test_a_position_only_stream_of_the_same_tracker_has_no_orientation(rig, rng):
    world, fake, tracker = rig(rng.normal(size=3))
    tracker.start_stream(RATE)
    batches = []
    t_end = world.clock.now() + 1.0
    while world.clock.now() < t_end:
        batches.append(tracker.read_samples(0.05))
    record = tracker.stop_stream()
    batches.append(tracker.read_samples(0.0))
    assert sum(len(b) for b in batches) == record.received > 0.8 * RATE
    assert all(b.quat_wxyz is None for b in batches)
    assert "probe_packets" not in fake.stats


def test_malformed_6dof_packets_from_the_device_are_skipped_and_named(rig, rng):
    every = int(rng.integers(2, 5))
    world, fake, tracker = rig(rng.normal(size=3), faults={"bad_quaternion": str(every)})
    tracker.start_stream(RATE, six_dof=True)
    quats, ts = [], []
    t_end = world.clock.now() + 2.0
    while world.clock.now() < t_end:
        b = tracker.read_samples(0.05)
        if len(b):
            quats.append(b.quat_wxyz), ts.append(b.t_s)
    record = tracker.stop_stream()
    bad = fake.stats["bad_quaternions"]
    assert bad >= 2 and record.rejected_frames >= bad
    assert any("not a unit quaternion" in reason for _, reason in tracker.rejections)
    t = np.concatenate(ts)
    # every sample taken is the truth: none of a malformed packet got through
    assert np.max(_angle_between(quat_to_matrices(np.concatenate(quats)), world.source.orientation(t))) < 1e-9
    # the refused packets' samples are missing from the grid, not taken
    assert record.grid_points - record.received >= bad
