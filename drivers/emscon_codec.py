"""Leica emScon TPI packets: pure encode/decode, no I/O.

The subset a metrology station needs: packet header and framing, commands
(system status, units, initialise, measurement mode, stationary and
continuous-time parameters, coordinate system type, start/stop measurement),
their replies, error packets, system-status-change packets, and single and
multiple measurement results.

Wire layout (facts from the emScon TPI C headers, ``ES_C_API_Def.h``;
little-endian, structures packed to 4 bytes, ``long``/``enum``/``ES_BOOL`` are
4-byte signed integers)::

    PacketHeaderT      <ii   lPacketSize (whole packet, header included), type
    command (type 0)   header, <i command, parameters...
    reply   (type 0)   header, <i command, <i status, reply data...
    ErrorResponseT     header, <i command, <i status                    16 bytes
    SystemStatusChange header, <i event                                  12 bytes
    SingleMeasResultT  header, <i status, <i measMode, <i bIsTryMode,
                       17 x <d (Val1-3, Std1-3, StdTotal, PointingError1-3,
                       AprioriStd1-3, AprioriStdTotal, Temperature, Pressure,
                       Humidity)                                        156 bytes
    MultiMeasResultT   header, <i status, <i lNumberOfResults, <i measMode,
                       <i bIsTryMode, 3 x <d (Temperature, Pressure, Humidity)
                       then lNumberOfResults x MeasValueT           48 + 36 n bytes
    MeasValueT         <i status, <i lTime1, <i lTime2, 3 x <d (Val1-3)  36 bytes
    ProbeContinuousResultT (type 5, 6-DoF continuous: T-Mac / T-Probe)
                       header, <i status, <i lNumberOfResults, <i measMode,
                       <i bIsTryMode, <i iInternalProbeId, <i iFieldNumber,
                       <i tipStatus, <i iInternalTipAdapterId,
                       <i iTipAdapterInterface, 3 x <d (Temperature,
                       Pressure, Humidity), then lNumberOfResults x
                       ProbeMeasValueT                              68 + 212 n bytes
    ProbeMeasValueT    <i status, <i triggerStatus, <i lRotationStatus,
                       <i lTime1, <i lTime2, 24 x <d: Position1-3,
                       StdDevPosition1-3, StdDevPositionTotal,
                       CovarPosition12/13/23, Quaternion0-3,
                       RotationAngleX-Z, StdDevRotationAngleX-Z,
                       StdDevRotationAngleTotal, CovarRotationAngleXY/XZ/YZ 212 bytes

6-DoF rotation: the headers give four quaternion terms and three rotation
angles per sample without naming the convention; this station reads
``Quaternion0`` as the scalar part and the quaternion as the rotation of the
probe's frame into the tracker's (``p_tracker = R(q) p_probe + position``),
and requires it to be a unit quaternion (:data:`QUATERNION_NORM_TOL`): a
sample that is not is a malformed packet, refused with the sample named.

Device time of a continuous sample: the headers do not define ``lTime1`` /
``lTime2`` beyond two 4-byte integers; this station reads them as whole
seconds and microseconds of the tracker clock (:func:`split_time_us`,
:func:`join_time_s`), the only two places that know it.

Framing: :func:`decode` returns ``(consumed, frame)``; ``consumed == 0``
means "need more bytes". A header that cannot start a packet (size not a
multiple of 4, below 12, above ``max_packet_bytes``, unknown type, size wrong
for the type) or a body that fails validation yields a :class:`Garbage` frame
covering the bytes up to the next plausible header, so a reader resynchronises
and counts what it skipped. A huge declared length is refused from its 8
header bytes: nothing of that size is ever allocated. A multi result cut
short takes its missing tail from what follows it; a valid packet starting
inside it gives that away, and it is garbage too (:func:`_swallowed_packet`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from station.errors import ProtocolError

HEADER = struct.Struct("<ii")
HEADER_BYTES = HEADER.size
#: every packet carries at least header + one 4-byte field
MIN_PACKET_BYTES = 12
#: refuse any declared length above this (a 1000-sample multi result is 36 KB)
DEFAULT_MAX_PACKET_BYTES = 1 << 20
#: MultiMeasResultT up to (excluding) its first MeasValueT
MULTI_HEADER_BYTES = 48
#: ProbeContinuousResultT up to (excluding) its first ProbeMeasValueT
PROBE_HEADER_BYTES = 68
#: largest departure of a 6-DoF sample's quaternion norm from 1 (the doubles carry 1e-16; a probe's own
#: normalisation far better than this)
QUATERNION_NORM_TOL = 1e-6
#: ``ES_TriggerStatus`` and ``ES_MeasurementTipStatus`` of a 6-DoF result lie in these ranges
TRIGGER_STATUS_MAX = 1
TIP_STATUS_MAX = 2
SINGLE_MEAS_BYTES = 156
#: highest command id of TPI 3.6
MAX_COMMAND_ID = 142


class DataType(IntEnum):
    """``ES_DataType``: the second header field."""

    COMMAND = 0
    ERROR = 1
    SINGLE_MEAS_RESULT = 2
    MULTI_MEAS_RESULT = 3
    STATIONARY_PROBE_MEAS_RESULT = 4
    CONTINUOUS_PROBE_MEAS_RESULT = 5
    NIVEL_RESULT = 6
    REFLECTOR_POS_RESULT = 7
    SYSTEM_STATUS_CHANGE = 8
    SINGLE_MEAS_RESULT2 = 9
    MULTI_MEAS_RESULT2 = 10
    PROBE_POS_RESULT = 11


class Command(IntEnum):
    """``ES_Command`` ids of the subset."""

    GET_SYSTEM_STATUS = 1
    GET_TRACKER_STATUS = 2
    SET_UNITS = 5
    GET_UNITS = 6
    INITIALIZE = 7
    SET_MEASUREMENT_MODE = 24
    GET_MEASUREMENT_MODE = 25
    SET_COORDINATE_SYSTEM_TYPE = 26
    SET_STATIONARY_MODE_PARAMS = 28
    SET_CONTINUOUS_TIME_MODE_PARAMS = 30
    SET_SYSTEM_SETTINGS = 47
    START_MEASUREMENT = 49
    STOP_MEASUREMENT = 52


class MeasMode(IntEnum):
    """``ES_MeasMode`` (0..11 are valid on the wire; two are used here)."""

    STATIONARY = 0
    CONTINUOUS_TIME = 1
    #: ``ES_MM_6DContinuousTime``: a 6-DoF probe (T-Mac) streamed on the time grid, ProbeContinuousResultT
    SIX_DOF_CONTINUOUS_TIME = 7


MEAS_MODE_MAX = 11


class LengthUnit(IntEnum):
    METER = 0
    MILLIMETER = 1
    MICRON = 2
    FOOT = 3
    YARD = 4
    INCH = 5


#: millimetres per length unit
MM_PER_LENGTH_UNIT = {0: 1000.0, 1: 1.0, 2: 1e-3, 3: 304.8, 4: 914.4, 5: 25.4}
#: names accepted by :func:`length_unit_from_name`
LENGTH_UNIT_NAMES = {"m": 0, "mm": 1, "um": 2, "ft": 3, "yd": 4, "in": 5}


class AngleUnit(IntEnum):
    RADIAN = 0
    DEGREE = 1
    GON = 2


class TemperatureUnit(IntEnum):
    CELSIUS = 0
    FAHRENHEIT = 1


class PressureUnit(IntEnum):
    MBAR = 0
    HPASCAL = 1
    KPASCAL = 2
    MMHG = 3
    PSI = 4
    INH2O = 5
    INHG = 6


class CoordinateSystemType(IntEnum):
    RHR = 0
    LHRX = 1
    LHRY = 2
    LHRZ = 3
    CCW = 4
    CCC = 5
    SCW = 6
    SCC = 7


class TrackerProcessorStatus(IntEnum):
    NO_TP_FOUND = 0
    TP_FOUND = 1
    NB_OPEN = 2
    BOOTED = 3
    COMPENSATION_SET = 4
    INITIALIZED = 5


class MeasurementStatus(IntEnum):
    """``ES_MeasurementStatus`` of one continuous sample."""

    ALL_OK = 0
    SPEED_WARNING = 1
    SPEED_EXCEEDED = 2
    PRISM_ERROR = 3
    TRIGGER_TIME_VIOLATION = 4


MEASUREMENT_STATUS_MAX = 4


class SystemStatusChange(IntEnum):
    """``ES_SystemStatusChange`` values this station reacts to (others pass as ints)."""

    UNITS_CHANGED = 6
    MEASUREMENT_MODE_CHANGED = 17
    MEAS_STATUS_NOT_READY = 25
    MEAS_STATUS_BUSY = 26
    MEAS_STATUS_READY = 27
    SERVER_CLOSING = 998
    SERVER_STARTED = 999


#: ``ES_ResultStatus`` names for error messages
RESULT_STATUS_NAMES = {
    0: "AllOK", 1: "ServerBusy", 2: "NotImplemented", 3: "WrongParameter",
    4: "WrongParameter1", 5: "WrongParameter2", 6: "WrongParameter3", 7: "WrongParameter4",
    8: "WrongParameter5", 9: "WrongParameter6", 10: "WrongParameter7",
    23: "WrongCurrentReflector", 26: "NoTPFound", 28: "NoLastMeasuredPoint", 35: "UsageConflict",
    36: "Unknown", 38: "NoTrackerConnected", 39: "TrackerNotInitialized", 59: "InternalProcessActive",
    10004: "MeasurementStatusNotReady", 10005: "ADMStartUpBusy", 10009: "NoStationaryResult",
    10011: "MultiConnectionsNotAllowed", 10012: "SensorNotWarmedUp", 10013: "SensorNotStable",
    10014: "SystemNotReadyForMeasurement",
}
#: statuses meaning "the tracker is not (yet) ready" rather than "you asked wrong"
NOT_READY_STATUSES = frozenset({1, 38, 39, 59, 10004, 10005, 10012, 10013, 10014})


def status_name(status: int) -> str:
    """``"39 (TrackerNotInitialized)"``: a status with its TPI name when known."""
    name = RESULT_STATUS_NAMES.get(int(status))
    return f"{status} ({name})" if name else f"{status}"


#: struct format of each command's parameters (after the command id)
PARAM_FORMATS: dict[int, str] = {
    Command.GET_SYSTEM_STATUS: "",
    Command.GET_TRACKER_STATUS: "",
    Command.SET_UNITS: "<5i",  # length, angle, temperature, pressure, humidity unit
    Command.GET_UNITS: "",
    Command.INITIALIZE: "",
    Command.SET_MEASUREMENT_MODE: "<i",
    Command.GET_MEASUREMENT_MODE: "",
    Command.SET_COORDINATE_SYSTEM_TYPE: "<i",
    Command.SET_STATIONARY_MODE_PARAMS: "<2i",  # lMeasTime [ms], bUseADM
    # lTimeSeparation [ms], lNumberOfPoints (0 = endless), bUseRegion, regionType
    Command.SET_CONTINUOUS_TIME_MODE_PARAMS: "<4i",
    Command.SET_SYSTEM_SETTINGS: "<9i",
    Command.START_MEASUREMENT: "",
    Command.STOP_MEASUREMENT: "",
}

#: struct format of each reply's data (after command id and status)
REPLY_FORMATS: dict[int, str] = {
    # lastResultStatus, trackerProcessorStatus, laserStatus, admStatus,
    # version major/minor/build, weatherMonitorStatus, lFlagsValue, lTrackerSerialNumber
    Command.GET_SYSTEM_STATUS: "<10i",
    Command.GET_TRACKER_STATUS: "<i",
    Command.GET_UNITS: "<5i",
    Command.GET_MEASUREMENT_MODE: "<i",
}

#: replies to commands outside the subset may carry up to this many data bytes
#: (GetReflectors, the largest fixed reply of TPI 3.6, carries 84)
MAX_OTHER_REPLY_BYTES = 256
_REPLY_MAX = np.full(MAX_COMMAND_ID + 1, 16 + MAX_OTHER_REPLY_BYTES, dtype=np.int64)
for _cmd in PARAM_FORMATS:
    _REPLY_MAX[_cmd] = 16 + struct.calcsize(REPLY_FORMATS.get(_cmd, "<"))
#: bytes after a multi result that show whether a packet follows it
_SUCCESSOR_BYTES = 24
#: result statuses lie in 0..99 or ES_API_ERROR_OFFSET (10000) + 0..99
_STATUS_MAX = 10_099

#: one continuous sample, exactly as on the wire (36 bytes, no padding)
MEAS_VALUE_DTYPE = np.dtype([
    ("status", "<i4"), ("time1", "<i4"), ("time2", "<i4"),
    ("val1", "<f8"), ("val2", "<f8"), ("val3", "<f8"),
])
assert MEAS_VALUE_DTYPE.itemsize == 36

#: one 6-DoF continuous sample, exactly as on the wire (212 bytes, no padding)
PROBE_VALUE_DTYPE = np.dtype([
    ("status", "<i4"), ("trigger", "<i4"), ("rotation_status", "<i4"), ("time1", "<i4"), ("time2", "<i4"),
    ("position", "<f8", (3,)), ("std_position", "<f8", (4,)), ("covar_position", "<f8", (3,)),
    ("quaternion", "<f8", (4,)), ("rotation_angle", "<f8", (3,)), ("std_rotation_angle", "<f8", (4,)),
    ("covar_rotation_angle", "<f8", (3,)),
])
assert PROBE_VALUE_DTYPE.itemsize == 212

_I = struct.Struct("<i")
_II = struct.Struct("<ii")
_PROBE_HEAD = struct.Struct("<9i3d")
_SINGLE = struct.Struct("<iii17d")
_MULTI_HEAD = struct.Struct("<iiii3d")


def split_time_us(t_us) -> tuple[np.ndarray, np.ndarray]:
    """Device time in integer microseconds -> (lTime1 seconds, lTime2 microseconds)."""
    t_us = np.asarray(t_us, dtype=np.int64)
    if np.any(t_us < 0) or np.any(t_us >= (2**31) * 1_000_000):
        raise ProtocolError("device time must be within 0..2**31 s to fit lTime1")
    sec, usec = np.divmod(t_us, 1_000_000)
    return sec.astype(np.int32), usec.astype(np.int32)


def join_time_s(time1, time2) -> np.ndarray:
    """(lTime1, lTime2) -> device time in seconds (float64)."""
    return np.asarray(time1, dtype=np.float64) + np.asarray(time2, dtype=np.float64) * 1e-6


# ----------------------------------------------------------------------------- frames

@dataclass(frozen=True)
class CommandPacket:
    """A command from client to server. ``params`` follow :data:`PARAM_FORMATS`;
    ``raw`` holds parameter bytes that did not fit the known format."""

    command: int
    params: tuple = ()
    raw: bytes = b""

    def encode(self) -> bytes:
        fmt = PARAM_FORMATS.get(self.command)
        if self.raw:
            body = self.raw
        elif fmt is None:
            if self.params:
                raise ProtocolError(f"command {self.command} has no known parameter layout")
            body = b""
        else:
            try:
                body = struct.pack(fmt, *self.params) if fmt else b""
            except struct.error as exc:
                raise ProtocolError(f"command {self.command} parameters {self.params!r} do not fit "
                                    f"{fmt!r}: {exc}") from exc
            if not fmt and self.params:
                raise ProtocolError(f"command {self.command} takes no parameters")
        size = HEADER_BYTES + 4 + len(body)
        return HEADER.pack(size, DataType.COMMAND) + _I.pack(self.command) + body


@dataclass(frozen=True)
class CommandReply:
    """Server's answer to a command; ``values`` decoded by :data:`REPLY_FORMATS`."""

    command: int
    status: int
    values: tuple = ()
    raw: bytes = b""

    @property
    def ok(self) -> bool:
        return self.status == 0

    def encode(self) -> bytes:
        fmt = REPLY_FORMATS.get(self.command, "")
        body = self.raw or (struct.pack(fmt, *self.values) if (fmt and self.values) else b"")
        size = HEADER_BYTES + 8 + len(body)
        return HEADER.pack(size, DataType.COMMAND) + _II.pack(self.command, self.status) + body


@dataclass(frozen=True)
class ErrorPacket:
    """``ErrorResponseT``: a failed command or an unsolicited error."""

    command: int
    status: int

    def encode(self) -> bytes:
        return HEADER.pack(16, DataType.ERROR) + _II.pack(self.command, self.status)


@dataclass(frozen=True)
class StatusChangePacket:
    """``SystemStatusChangeT``: an event such as MeasStatus_NotReady (beam broken)."""

    event: int

    def encode(self) -> bytes:
        return HEADER.pack(12, DataType.SYSTEM_STATUS_CHANGE) + _I.pack(self.event)


@dataclass(frozen=True)
class SingleMeasResult:
    """``SingleMeasResultT``; ``values`` are the 17 doubles in wire order."""

    status: int
    meas_mode: int
    is_try_mode: bool
    values: tuple

    xyz = property(lambda self: self.values[0:3])
    std_xyz = property(lambda self: self.values[3:6])
    std_total = property(lambda self: self.values[6])
    pointing_error = property(lambda self: self.values[7:10])
    apriori_std = property(lambda self: self.values[10:13])
    apriori_std_total = property(lambda self: self.values[13])
    temperature = property(lambda self: self.values[14])
    pressure = property(lambda self: self.values[15])
    humidity = property(lambda self: self.values[16])

    def encode(self) -> bytes:
        if len(self.values) != 17:
            raise ProtocolError(f"SingleMeasResult needs 17 values, got {len(self.values)}")
        return (HEADER.pack(SINGLE_MEAS_BYTES, DataType.SINGLE_MEAS_RESULT)
                + _SINGLE.pack(self.status, self.meas_mode, int(self.is_try_mode), *self.values))


@dataclass(frozen=True, eq=False)
class MultiMeasResult:
    """``MultiMeasResultT`` with its samples as a :data:`MEAS_VALUE_DTYPE` array."""

    status: int
    meas_mode: int
    is_try_mode: bool
    temperature: float
    pressure: float
    humidity: float
    samples: np.ndarray = field(repr=False)

    @classmethod
    def from_arrays(cls, t_us, xyz, sample_status=0, *, meas_mode: int = MeasMode.CONTINUOUS_TIME,
                    status: int = 0, temperature: float = 20.0, pressure: float = 1013.25,
                    humidity: float = 50.0) -> "MultiMeasResult":
        """Build from device times (int microseconds, (N,)) and values (N, 3)."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        samples = np.zeros(len(xyz), dtype=MEAS_VALUE_DTYPE)
        samples["time1"], samples["time2"] = split_time_us(t_us)
        samples["status"] = sample_status
        samples["val1"], samples["val2"], samples["val3"] = xyz.T
        return cls(status, int(meas_mode), False, temperature, pressure, humidity, samples)

    @property
    def t_s(self) -> np.ndarray:
        return join_time_s(self.samples["time1"], self.samples["time2"])

    @property
    def xyz(self) -> np.ndarray:
        s = self.samples
        return np.column_stack([s["val1"], s["val2"], s["val3"]])

    def encode(self) -> bytes:
        samples = np.ascontiguousarray(self.samples, dtype=MEAS_VALUE_DTYPE)
        n = len(samples)
        size = MULTI_HEADER_BYTES + MEAS_VALUE_DTYPE.itemsize * n
        return (HEADER.pack(size, DataType.MULTI_MEAS_RESULT)
                + _MULTI_HEAD.pack(self.status, n, self.meas_mode, int(self.is_try_mode),
                                   self.temperature, self.pressure, self.humidity)
                + samples.tobytes())


@dataclass(frozen=True)
class ProbeContinuousResult:
    """``ProbeContinuousResultT`` (6-DoF continuous) with its samples as a :data:`PROBE_VALUE_DTYPE` array."""

    status: int
    meas_mode: int
    is_try_mode: bool
    probe_id: int
    field_number: int
    tip_status: int
    tip_adapter_id: int
    tip_adapter_interface: int
    temperature: float
    pressure: float
    humidity: float
    samples: np.ndarray = field(repr=False)

    @classmethod
    def from_arrays(cls, t_us, xyz, quat_wxyz, sample_status=0, *,
                    meas_mode: int = MeasMode.SIX_DOF_CONTINUOUS_TIME, status: int = 0, probe_id: int = 1,
                    temperature: float = 20.0, pressure: float = 1013.25,
                    humidity: float = 50.0) -> "ProbeContinuousResult":
        """Build from device times (int microseconds, (N,)), positions (N, 3) and unit quaternions (N, 4)."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        samples = np.zeros(len(xyz), dtype=PROBE_VALUE_DTYPE)
        samples["time1"], samples["time2"] = split_time_us(t_us)
        samples["status"] = sample_status
        samples["rotation_status"] = 1  # Status6D: the rotation is valid
        samples["position"] = xyz
        samples["quaternion"] = np.asarray(quat_wxyz, dtype=np.float64).reshape(-1, 4)
        return cls(status, int(meas_mode), False, int(probe_id), 0, 0, 0, 0, temperature, pressure, humidity,
                   samples)

    @property
    def t_s(self) -> np.ndarray:
        return join_time_s(self.samples["time1"], self.samples["time2"])

    @property
    def xyz(self) -> np.ndarray:
        return np.array(self.samples["position"])

    @property
    def quat_wxyz(self) -> np.ndarray:
        """(N, 4) unit quaternions, scalar first: the probe's frame into the tracker's."""
        return np.array(self.samples["quaternion"])

    def encode(self) -> bytes:
        samples = np.ascontiguousarray(self.samples, dtype=PROBE_VALUE_DTYPE)
        n = len(samples)
        size = PROBE_HEADER_BYTES + PROBE_VALUE_DTYPE.itemsize * n
        return (HEADER.pack(size, DataType.CONTINUOUS_PROBE_MEAS_RESULT)
                + _PROBE_HEAD.pack(self.status, n, self.meas_mode, int(self.is_try_mode), self.probe_id,
                                   self.field_number, self.tip_status, self.tip_adapter_id,
                                   self.tip_adapter_interface, self.temperature, self.pressure, self.humidity)
                + samples.tobytes())


@dataclass(frozen=True)
class ReflectorPosResult:
    status: int
    xyz: tuple

    def encode(self) -> bytes:
        return HEADER.pack(36, DataType.REFLECTOR_POS_RESULT) + struct.pack("<i3d", self.status, *self.xyz)


@dataclass(frozen=True)
class OtherPacket:
    """A well-framed packet of a type outside the subset (nivel, probe, ...)."""

    type: int
    payload: bytes

    def encode(self) -> bytes:
        return HEADER.pack(HEADER_BYTES + len(self.payload), self.type) + self.payload


@dataclass(frozen=True)
class Garbage:
    """``nbytes`` bytes that do not form a packet; ``reason`` says why."""

    nbytes: int
    reason: str


Frame = (CommandPacket | CommandReply | ErrorPacket | StatusChangePacket | SingleMeasResult
         | MultiMeasResult | ProbeContinuousResult | ReflectorPosResult | OtherPacket)


def encode(frame) -> bytes:
    """Bytes of one frame (each frame class also has ``.encode()``)."""
    try:
        return frame.encode()
    except AttributeError as exc:
        raise ProtocolError(f"cannot encode {type(frame).__name__}") from exc


# ----------------------------------------------------------------------------- decoding

#: exact sizes of fixed-size packets sent by a server
_FIXED_SIZES = {
    DataType.ERROR: 16,
    DataType.SINGLE_MEAS_RESULT: SINGLE_MEAS_BYTES,
    DataType.NIVEL_RESULT: 40,
    DataType.REFLECTOR_POS_RESULT: 36,
    DataType.SYSTEM_STATUS_CHANGE: 12,
    DataType.SINGLE_MEAS_RESULT2: 204,
}
_FIXED_SIZES_INT = tuple((int(k), int(v)) for k, v in _FIXED_SIZES.items())
_MULTI2_ITEM = 92
#: fixed packet size by packet type (0: not fixed), for vectorised lookups
_FIXED_SIZE_BY_TYPE = np.zeros(max(DataType) + 1, dtype=np.int32)
for _t, _s in _FIXED_SIZES.items():
    _FIXED_SIZE_BY_TYPE[_t] = _s
#: command ids of the subset, the only replies a resynchronisation takes
_SUBSET_COMMANDS = np.array(sorted(PARAM_FORMATS), dtype=np.int32)
_IS_SUBSET_COMMAND = np.zeros(MAX_COMMAND_ID + 1, dtype=bool)
_IS_SUBSET_COMMAND[_SUBSET_COMMANDS] = True


def _header_problem(size: int, ptype: int, from_server: bool, max_bytes: int) -> str | None:
    """Why (size, type) cannot start a packet, or None if it can."""
    if size > max_bytes:
        return f"declared packet length {size} bytes exceeds the {max_bytes}-byte limit"
    if size < MIN_PACKET_BYTES:
        return f"declared packet length {size} bytes is below the {MIN_PACKET_BYTES}-byte minimum"
    if size % 4:
        return f"declared packet length {size} bytes is not a multiple of 4"
    if not 0 <= ptype <= max(DataType):
        return f"unknown packet type {ptype}"
    if not from_server:
        return None if ptype == DataType.COMMAND else f"packet type {ptype} is not a command"
    fixed = _FIXED_SIZES.get(ptype)
    if fixed is not None and size != fixed:
        return f"packet type {ptype} must be {fixed} bytes, header says {size}"
    if ptype == DataType.COMMAND and size < 16:
        return f"command reply must be at least 16 bytes, header says {size}"
    if ptype == DataType.MULTI_MEAS_RESULT and (size < MULTI_HEADER_BYTES
                                                or (size - MULTI_HEADER_BYTES) % MEAS_VALUE_DTYPE.itemsize):
        return f"multi-measurement packet of {size} bytes is not 48 + 36 n"
    if ptype == DataType.MULTI_MEAS_RESULT2 and (size < MULTI_HEADER_BYTES
                                                 or (size - MULTI_HEADER_BYTES) % _MULTI2_ITEM):
        return f"multi-measurement-2 packet of {size} bytes is not 48 + 92 n"
    if ptype == DataType.CONTINUOUS_PROBE_MEAS_RESULT and (
            size < PROBE_HEADER_BYTES or (size - PROBE_HEADER_BYTES) % PROBE_VALUE_DTYPE.itemsize):
        return f"6-DoF continuous packet of {size} bytes is not 68 + 212 n"
    return None


#: plain ints of the packet types (the header scan compares whole arrays; enum lookups cost more than the scan)
_T_COMMAND, _T_ERROR = int(DataType.COMMAND), int(DataType.ERROR)
_T_MULTI_MEAS_RESULT, _T_MULTI_MEAS_RESULT2 = int(DataType.MULTI_MEAS_RESULT), int(DataType.MULTI_MEAS_RESULT2)
_T_SINGLE_MEAS_RESULT, _T_MAX = int(DataType.SINGLE_MEAS_RESULT), int(max(DataType))
_T_PROBE_CONTINUOUS = int(DataType.CONTINUOUS_PROBE_MEAS_RESULT)


def _plausible_mask(words: np.ndarray, from_server: bool, max_bytes: int) -> np.ndarray:
    """For each word offset j (but the last), could a packet start there?

    ``words`` is (..., n): every row is scanned alike (the four byte
    alignments of a window at once).

    Checks the header pair (size, type) and, where those words are present,
    the fields right after it: command ids within range, a multi result's
    count matching its size, measMode and bIsTryMode within their domains.
    """
    n = words.shape[-1]
    if n < 2:
        return np.zeros(words.shape[:-1] + (0,), dtype=bool)
    w = words.astype(np.int64)
    size, typ = w[..., :-1], w[..., 1:]
    idx = np.arange(n - 1)

    def field(k):  # word j + k of each candidate, and whether it has arrived
        vals = np.zeros(w.shape[:-1] + (n - 1,), dtype=np.int64)
        vals[..., : max(0, n - k)] = w[..., k:]
        return vals, idx < n - k

    ok = (size >= MIN_PACKET_BYTES) & (size <= max_bytes) & (size % 4 == 0)
    w2, a2 = field(2)
    cmd_ok = ~a2 | ((w2 >= 0) & (w2 <= MAX_COMMAND_ID))
    if not from_server:
        return ok & (typ == _T_COMMAND) & cmd_ok
    ok &= (typ >= 0) & (typ <= _T_MAX)
    for ptype, fixed in _FIXED_SIZES_INT:
        ok &= (typ != ptype) | (size == fixed)
    w3, a3 = field(3)
    status_ok = ~a3 | ((w3 >= 0) & (w3 <= _STATUS_MAX))
    reply_max = np.where(a2 & cmd_ok, _REPLY_MAX[np.clip(w2, 0, MAX_COMMAND_ID)], 16 + MAX_OTHER_REPLY_BYTES)
    ok &= (typ != _T_COMMAND) | ((size >= 16) & (size <= reply_max) & cmd_ok & status_ok)
    ok &= (typ != _T_ERROR) | (cmd_ok & status_ok & (~a3 | (w3 != 0)))
    w4, a4 = field(4)
    w5, a5 = field(5)
    body = size - MULTI_HEADER_BYTES
    multi_ok = ((body >= 0) & (body % MEAS_VALUE_DTYPE.itemsize == 0)
                & (~a3 | (w3 == body // MEAS_VALUE_DTYPE.itemsize))
                & (~a4 | ((w4 >= 0) & (w4 <= MEAS_MODE_MAX))) & (~a5 | ((w5 == 0) | (w5 == 1))))
    ok &= (typ != _T_MULTI_MEAS_RESULT) | multi_ok
    multi2_ok = (body >= 0) & (body % _MULTI2_ITEM == 0) & (~a3 | (w3 == body // _MULTI2_ITEM))
    ok &= (typ != _T_MULTI_MEAS_RESULT2) | multi2_ok
    single_ok = (~a3 | ((w3 >= 0) & (w3 <= MEAS_MODE_MAX))) & (~a4 | ((w4 == 0) | (w4 == 1)))
    ok &= (typ != _T_SINGLE_MEAS_RESULT) | single_ok
    pbody = size - PROBE_HEADER_BYTES
    probe_ok = ((pbody >= 0) & (pbody % PROBE_VALUE_DTYPE.itemsize == 0)
                & (~a3 | (w3 == pbody // PROBE_VALUE_DTYPE.itemsize))
                & (~a4 | ((w4 >= 0) & (w4 <= MEAS_MODE_MAX))) & (~a5 | ((w5 == 0) | (w5 == 1))))
    ok &= (typ != _T_PROBE_CONTINUOUS) | probe_ok
    return ok


def _plausible_at(buf, pos: int, from_server: bool, max_bytes: int) -> bool:
    count = min(6, (len(buf) - pos) // 4)
    if count < 2:
        return True  # not checkable yet
    words = np.frombuffer(buf, dtype="<i4", count=count, offset=pos)
    return bool(_plausible_mask(words, from_server, max_bytes)[0])


def _next_candidate(buf, start: int, from_server: bool, max_bytes: int, *,
                    stop: int | None = None, confirm: bool = False) -> int | None:
    """Offset in ``[start, stop)`` of the first plausible packet in ``buf``.

    Vectorised scan for plausible headers; a candidate must also pass the
    body checks :func:`decode` applies (or, when incomplete, the checks of
    what has arrived), otherwise it is a coincidence inside a body or inside
    garbage. With ``confirm`` the candidate must be complete and followed by
    a plausible header or the end of ``buf``, or be a multi result of which
    24 bytes or more have arrived, its header fields and first sample
    checking out (it may be cut short itself, whatever follows it).
    """
    n = len(buf)
    # scan windows that double in size: the work is linear in the distance to the next packet, so a
    # link that interleaves packets with junk costs linear, not quadratic, time
    lo = start
    width = 256
    while lo < n:
        hi = n if stop is None else min(n, stop + HEADER_BYTES)
        hi = min(hi, lo + width)
        found = _candidate_in(buf, lo, hi, n, from_server, max_bytes, stop, confirm)
        if found is not None:
            return found
        if hi >= n or (stop is not None and hi >= stop):
            return None
        lo = hi - (HEADER_BYTES - 1)  # a header may straddle the window's end
        lo = max(lo, start)
        width *= 2
    return None


#: bytes past a scan window that the header checks of :func:`_plausible_mask` may read
_LOOKAHEAD_BYTES = 64


def _alignment_words(buf, lo: int, count: int) -> np.ndarray:
    """The four byte alignments from ``lo`` as rows of one array (4, count): word j of row r starts at byte
    ``lo + r + 4 j`` (``buf`` holds at least ``lo + 4 count + 3`` bytes)."""
    rows = np.lib.stride_tricks.as_strided(np.frombuffer(buf, dtype=np.uint8, count=4 * count + 3, offset=lo),
                                           shape=(4, 4 * count), strides=(1, 1))
    return np.ascontiguousarray(rows).view("<i4")


def _candidate_in(buf, lo: int, hi: int, n: int, from_server: bool, max_bytes: int, stop, confirm) -> int | None:
    """The first plausible packet start in ``[lo, hi)``; the words checked reach past ``hi`` so a start near
    the window's end is judged on the same fields as anywhere else."""
    end = min(hi + _LOOKAHEAD_BYTES, n)
    if end < n:
        words = _alignment_words(buf, lo, (end - lo - 3) // 4)
        r_hit, j_hit = np.nonzero(_plausible_mask(words, from_server, max_bytes))
        hits_all = [lo + r_hit + 4 * j_hit]
    else:
        # the buffer's tail: each alignment as far as its bytes go (what has not arrived is not judged)
        hits_all = []
        for r in range(4):
            first = lo + ((r - lo) % 4)
            cnt = (n - first) // 4
            if cnt < 2:
                continue
            words = np.frombuffer(buf, dtype="<i4", count=cnt, offset=first)
            hits_all.append(first + 4 * np.flatnonzero(_plausible_mask(words, from_server, max_bytes)))
        if not hits_all:
            return None
    for pos in np.sort(np.concatenate(hits_all)):  # loops over candidates, not bytes
        pos = int(pos)
        if pos >= hi or (stop is not None and pos >= stop):
            break
        if _candidate_ok(buf, pos, n, from_server, max_bytes, confirm):
            return pos
    return None


def _candidate_ok(buf, pos: int, n: int, from_server: bool, max_bytes: int, confirm: bool) -> bool:
    """Whether the plausible header at ``pos`` starts a packet: its body (or what has arrived of it) passes
    the checks of :func:`decode`; with ``confirm`` see :func:`_next_candidate`."""
    size, ptype = HEADER.unpack_from(buf, pos)
    if ptype in (DataType.COMMAND, DataType.ERROR) and pos + 12 <= n \
            and _I.unpack_from(buf, pos + 8)[0] not in PARAM_FORMATS:
        return False  # resynchronise only onto replies to commands of the subset
    if confirm and ptype == DataType.MULTI_MEAS_RESULT and n - pos >= 24:
        # a multi result's header fields and first sample confirm it on their own: what follows it may not, as
        # it may be truncated itself (a run of cut packets)
        return _partial_problem(buf[pos:], min(n - pos, MULTI_HEADER_BYTES + MEAS_VALUE_DTYPE.itemsize),
                                size, ptype) is None
    end = pos + size
    if end <= n:
        if _decode_body(buf[pos:], size, ptype, from_server)[1] is not None:
            return False
        return not confirm or end + HEADER_BYTES > n or _plausible_at(buf, end, from_server, max_bytes)
    return not confirm and _partial_problem(buf[pos:], n - pos, size, ptype) is None


def _plausible_starts(buf, lo: int, stop: int, from_server: bool, max_bytes: int) -> list[int]:
    """Sorted offsets in ``[lo, stop)`` (``stop`` at most ``len(buf) - 7``) where :func:`_plausible_at` holds.

    For scanning the inside of a packet, which is usually clean: a cheap test of the header pair and of
    the command id of a reply, all four byte alignments as rows of one array, then the full field
    checks only where it passes.
    """
    n = len(buf)
    stop = min(stop, n - HEADER_BYTES + 1)
    count = (n - lo - 3) // 4  # words per alignment row
    found = []
    if count >= 2:
        w = _alignment_words(buf, lo, count)
        size, typ = w[:, :-1], w[:, 1:]
        cheap = (size >= MIN_PACKET_BYTES) & (size <= max_bytes) & ((size & 3) == 0)
        cheap &= ((typ >= 0) & (typ <= _T_MAX)) if from_server else (typ == _T_COMMAND)
        r_hit, j_hit = np.nonzero(cheap)
        pos = lo + r_hit + 4 * j_hit
        keep = pos < stop
        hs, ht = size[r_hit, j_hit], typ[r_hit, j_hit]
        if from_server:
            fixed = _FIXED_SIZE_BY_TYPE[ht]
            keep &= (fixed == 0) | (hs == fixed)
        # a reply or error packet is only taken for one to a command of the subset (see _candidate_ok)
        cmd = w[r_hit, np.minimum(j_hit + 2, count - 1)]
        keep &= ((ht != _T_COMMAND) & (ht != _T_ERROR)) | (j_hit + 2 >= count) \
            | _IS_SUBSET_COMMAND[np.clip(cmd, 0, MAX_COMMAND_ID)]
        pos, r_hit, j_hit = pos[keep], r_hit[keep], j_hit[keep]
        whole = j_hit + 5 < count  # all six words the full check reads are in the rows
        if whole.any():
            six = w[r_hit[whole, None], j_hit[whole, None] + np.arange(6)]
            found.extend(pos[whole][_plausible_mask(six, from_server, max_bytes)[:, 0]].tolist())
        found.extend(int(p) for p in pos[~whole] if _plausible_at(buf, int(p), from_server, max_bytes))
    # the last few offsets, whose header the rows do not hold whole
    for p in range(max(lo, lo + 4 * (count - 1)), stop):
        size, typ = HEADER.unpack_from(buf, p)
        if _header_problem(size, typ, from_server, max_bytes) is None and _plausible_at(buf, p, from_server, max_bytes):
            found.append(p)
    return sorted(set(found))


def _skip(buf, reason: str, from_server: bool, max_bytes: int, *,
          keep_tail: bool = True) -> tuple[int, Garbage]:
    """Garbage up to the next plausible header after offset 0."""
    nxt = _next_candidate(buf, 1, from_server, max_bytes)
    if nxt is None:  # keep the last 7 bytes: they may start a header
        nxt = max(1, len(buf) - (HEADER_BYTES - 1)) if keep_tail else len(buf)
    return nxt, Garbage(nxt, reason)


def _samples_problem(samples: np.ndarray) -> str | None:
    bad = ((samples["status"] < 0) | (samples["status"] > MEASUREMENT_STATUS_MAX)
           | (samples["time2"] < 0) | (samples["time2"] >= 1_000_000) | (samples["time1"] < 0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        return (f"multi result sample {i} has status {samples['status'][i]}, "
                f"lTime1 {samples['time1'][i]}, lTime2 {samples['time2'][i]}")
    return None


def _partial_problem(buf, n: int, size: int, ptype: int) -> str | None:
    """Validate what has arrived of an incomplete packet (catches truncation early)."""
    if ptype != DataType.MULTI_MEAS_RESULT or n < 24:
        return None
    status, count, mode, is_try = struct.unpack_from("<iiii", buf, 8)
    have = (size - MULTI_HEADER_BYTES) // MEAS_VALUE_DTYPE.itemsize
    if count != have:
        return f"multi result declares {count} samples but its {size} bytes hold {have}"
    if not 0 <= mode <= MEAS_MODE_MAX or is_try not in (0, 1):
        return f"multi result has measMode {mode}, bIsTryMode {is_try}"
    complete = (n - MULTI_HEADER_BYTES) // MEAS_VALUE_DTYPE.itemsize
    if complete > 0:
        return _samples_problem(np.frombuffer(buf, dtype=MEAS_VALUE_DTYPE, count=complete,
                                              offset=MULTI_HEADER_BYTES))
    return None


def skip_stalled(buf, *, from_server: bool = True,
                 max_packet_bytes: int = DEFAULT_MAX_PACKET_BYTES) -> tuple[int, Garbage]:
    """Give up on an incomplete packet at the start of ``buf``.

    For a reader whose link went quiet while :func:`decode` still waits for
    the rest of a packet (a truncated packet): the bytes up to the next
    plausible header (or all of them) become :class:`Garbage`.
    """
    if not len(buf):
        raise ProtocolError("nothing to skip")
    size = HEADER.unpack_from(buf, 0)[0] if len(buf) >= HEADER_BYTES else "?"
    if size != "?" and len(buf) >= size:  # held back by decode: a packet starting inside it never completed
        reason = f"multi result of {size} bytes held back for a packet inside it that never completed"
    else:
        reason = f"packet incomplete ({len(buf)} of {size} bytes)"
    return _skip(buf, f"{reason} when the link went quiet", from_server, max_packet_bytes, keep_tail=False)


def decode(buf, *, from_server: bool = True, max_packet_bytes: int = DEFAULT_MAX_PACKET_BYTES,
           require_successor: bool = False) -> tuple[int, object | None]:
    """Decode the packet at the start of ``buf``.

    Parameters
    ----------
    buf : bytes-like
        Received bytes (not modified, not retained).
    from_server : bool
        True for server->client packets (replies, results, events), False
        for client->server commands.
    max_packet_bytes : int
        Declared lengths above this are refused from the header alone.
    require_successor : bool
        Hold a complete multi result back (``(0, None)``) until 24 more bytes
        show what follows it. A reader sets this while data flows and clears
        it when the link is quiet. Either way a multi result inside which a
        valid packet starts (see :func:`_swallowed_packet`) was truncated -
        its declared length swallowed what followed it - and is rejected;
        while that packet has not all arrived the multi result is held back.

    Returns
    -------
    (consumed, frame)
        ``(0, None)`` when more bytes are needed; otherwise the bytes used
        and a frame (a :class:`Garbage` when they do not form a packet).
    """
    n = len(buf)
    if n < HEADER_BYTES:
        return 0, None
    size, ptype = HEADER.unpack_from(buf, 0)
    problem = _header_problem(size, ptype, from_server, max_packet_bytes)
    if problem is not None:
        return _skip(buf, problem, from_server, max_packet_bytes)
    if n < size:
        if not _plausible_at(buf, 0, from_server, max_packet_bytes):
            return _skip(buf, f"header ({size} bytes, type {ptype}) does not fit the fields after it",
                         from_server, max_packet_bytes)
        problem = _partial_problem(buf, n, size, ptype)
        if problem is not None:
            return _skip(buf, problem, from_server, max_packet_bytes)
        return 0, None
    frame, problem = _decode_body(buf, size, ptype, from_server)
    if problem is not None:
        return _skip(buf, problem, from_server, max_packet_bytes)
    if ptype in (DataType.MULTI_MEAS_RESULT, DataType.CONTINUOUS_PROBE_MEAS_RESULT) and from_server:
        if require_successor and n - size < _SUCCESSOR_BYTES:
            return 0, None  # too little follows to tell junk from a swallowed packet
        swallowed = _swallowed_packet(buf, size, from_server, max_packet_bytes)
        if swallowed is not None:
            inner, complete = swallowed
            if not complete:
                return 0, None  # a packet starts inside it: the rest of that packet will tell
            return inner, Garbage(inner, f"multi result of {size} bytes is truncated: a packet "
                                         f"starts inside it at byte {inner}")
    return size, frame


#: packet types an emScon server sends this station; a packet swallowed by a truncated multi result is looked
#: for among these (the others' headers check too few fields to tell them from sample data)
_SERVER_TYPES = frozenset({_T_COMMAND, _T_ERROR, int(DataType.SYSTEM_STATUS_CHANGE), _T_SINGLE_MEAS_RESULT,
                           _T_MULTI_MEAS_RESULT, _T_PROBE_CONTINUOUS})


def _swallowed_packet(buf, size: int, from_server: bool, max_bytes: int) -> tuple[int, bool] | None:
    """``(offset, complete)`` of a packet that the complete multi result at the start of ``buf`` swallowed,
    or None.

    A multi result cut short at byte ``cut`` takes its missing tail from
    whatever follows it, and its samples pass every body check when the
    swallowed bytes land in doubles only. When the tail reaches into the
    middle of a packet, the bytes after the multi result cannot start a
    packet (the check of old). When it ends on a packet boundary they are a
    plausible header or nothing at all: a truncated last packet whose tail is
    exactly the reply to StopMeasurement (or a status change and the reply),
    a status change mid-stream, the next data packet whole. And when the
    bytes arrive in reads that end just after the multi result, the link
    quiet in between, too little follows to judge. In every case the packet
    that starts at ``cut`` gives the truncation away: complete and valid (or
    a multi result whose header and first samples check out), running to a
    plausible header or to the end of the bytes received (``complete``
    True); or not all arrived yet, what has arrived plausible (``complete``
    False: wait for the rest, which confirms or refutes it). Sample data of a
    real packet holds no such packet (a header in doubles needs subnormal
    values, one on the time fields a reply to a command of the subset), so
    nothing a device sent whole is rejected.

    After implausible bytes a swallowed packet may be of any type (the check
    of old); otherwise it is one of the types a server sends
    (:data:`_SERVER_TYPES`). It may start in the multi result's last 7 bytes
    unless a plausible header follows the multi result.
    """
    n = len(buf)
    judged = n - size >= HEADER_BYTES  # a header's worth follows the multi result
    implausible = judged and not _plausible_at(buf, size, from_server, max_bytes)
    # a packet starting in the last 7 bytes makes a header that follows implausible; with fewer bytes after the
    # multi result there is nothing to judge, and a swallowed packet may start there as well
    stop = size - HEADER_BYTES + 1 if judged and not implausible else size
    pending = None
    for pos in _plausible_starts(buf, HEADER_BYTES, stop, from_server, max_bytes):
        declared, ptype = HEADER.unpack_from(buf, pos)
        ours = ptype in _SERVER_TYPES
        if not (implausible or ours):
            continue
        if _candidate_ok(buf, pos, n, from_server, max_bytes, confirm=True):
            return pos, True
        if pending is None and ours and pos + declared > n \
                and _candidate_ok(buf, pos, n, from_server, max_bytes, confirm=False):
            pending = pos
    return None if pending is None else (pending, False)


def _decode_body(buf, size: int, ptype: int, from_server: bool):
    if ptype == DataType.COMMAND:
        (command,) = _I.unpack_from(buf, 8)
        if not 0 <= command <= MAX_COMMAND_ID:
            return None, f"command id {command} outside 0..{MAX_COMMAND_ID}"
        if not from_server:
            body = bytes(buf[12:size])
            fmt = PARAM_FORMATS.get(command)
            if fmt is not None and struct.calcsize(fmt or "<") == len(body):
                return CommandPacket(command, struct.unpack(fmt, body) if fmt else ()), None
            return CommandPacket(command, (), body), None
        (status,) = _I.unpack_from(buf, 12)
        if not 0 <= status <= _STATUS_MAX:
            return None, f"reply to command {command} carries status {status}"
        body = bytes(buf[16:size])
        fmt = REPLY_FORMATS.get(command)
        if fmt is not None:
            want = struct.calcsize(fmt)
            if len(body) == want:
                return CommandReply(command, status, struct.unpack(fmt, body)), None
            if body or status == 0:
                return None, (f"reply to command {command} carries {len(body)} data bytes, "
                              f"expected {want}")
            return CommandReply(command, status), None
        if command in PARAM_FORMATS and body:
            return None, f"reply to command {command} carries {len(body)} unexpected data bytes"
        if len(body) > MAX_OTHER_REPLY_BYTES:
            return None, f"reply to command {command} carries {len(body)} data bytes (limit {MAX_OTHER_REPLY_BYTES})"
        return CommandReply(command, status, (), body), None
    if ptype == DataType.ERROR:
        command, status = _II.unpack_from(buf, 8)
        if not 0 <= command <= MAX_COMMAND_ID:
            return None, f"error packet names command id {command} outside 0..{MAX_COMMAND_ID}"
        if not 0 < status <= _STATUS_MAX:
            return None, f"error packet carries status {status}"
        return ErrorPacket(command, status), None
    if ptype == DataType.SYSTEM_STATUS_CHANGE:
        return StatusChangePacket(_I.unpack_from(buf, 8)[0]), None
    if ptype == DataType.SINGLE_MEAS_RESULT:
        status, mode, is_try, *values = _SINGLE.unpack_from(buf, 8)
        if not 0 <= mode <= MEAS_MODE_MAX or is_try not in (0, 1):
            return None, f"single result has measMode {mode}, bIsTryMode {is_try}"
        return SingleMeasResult(status, mode, bool(is_try), tuple(values)), None
    if ptype == DataType.MULTI_MEAS_RESULT:
        status, count, mode, is_try, temp, press, hum = _MULTI_HEAD.unpack_from(buf, 8)
        have = (size - MULTI_HEADER_BYTES) // MEAS_VALUE_DTYPE.itemsize
        if count != have:
            return None, (f"multi result declares {count} samples but its {size} bytes hold {have}")
        if not 0 <= mode <= MEAS_MODE_MAX or is_try not in (0, 1):
            return None, f"multi result has measMode {mode}, bIsTryMode {is_try}"
        samples = np.frombuffer(buf, dtype=MEAS_VALUE_DTYPE, count=count,
                                offset=MULTI_HEADER_BYTES).copy()
        problem = _samples_problem(samples)
        if problem is not None:
            return None, problem
        return MultiMeasResult(status, mode, bool(is_try), temp, press, hum, samples), None
    if ptype == DataType.CONTINUOUS_PROBE_MEAS_RESULT:
        return _decode_probe(buf, size)
    if ptype == DataType.REFLECTOR_POS_RESULT:
        status, *xyz = struct.unpack_from("<i3d", buf, 8)
        return ReflectorPosResult(status, tuple(xyz)), None
    return OtherPacket(ptype, bytes(buf[8:size])), None


def _decode_probe(buf, size: int):
    """A ``ProbeContinuousResultT``, or why its bytes are not one (the first bad field and sample named)."""
    status, count, mode, is_try, probe_id, field_no, tip, tip_id, tip_if, temp, press, hum = \
        _PROBE_HEAD.unpack_from(buf, 8)
    have = (size - PROBE_HEADER_BYTES) // PROBE_VALUE_DTYPE.itemsize
    if count != have:
        return None, f"6-DoF result declares {count} samples but its {size} bytes hold {have}"
    if not 0 <= mode <= MEAS_MODE_MAX or is_try not in (0, 1):
        return None, f"6-DoF result has measMode {mode}, bIsTryMode {is_try}"
    if not 0 <= tip <= TIP_STATUS_MAX:
        return None, f"6-DoF result has tipStatus {tip} (0..{TIP_STATUS_MAX})"
    samples = np.frombuffer(buf, dtype=PROBE_VALUE_DTYPE, count=count, offset=PROBE_HEADER_BYTES).copy()
    problem = _probe_samples_problem(samples)
    if problem is not None:
        return None, problem
    return ProbeContinuousResult(status, mode, bool(is_try), probe_id, field_no, tip, tip_id, tip_if, temp, press,
                                 hum, samples), None


def _probe_samples_problem(samples: np.ndarray) -> str | None:
    """Why a 6-DoF sample is malformed (status, trigger, time or quaternion out of its domain), or None."""
    bad = ((samples["status"] < 0) | (samples["status"] > MEASUREMENT_STATUS_MAX)
           | (samples["trigger"] < 0) | (samples["trigger"] > TRIGGER_STATUS_MAX)
           | (samples["time2"] < 0) | (samples["time2"] >= 1_000_000) | (samples["time1"] < 0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        return (f"6-DoF result sample {i} has status {samples['status'][i]}, triggerStatus "
                f"{samples['trigger'][i]}, lTime1 {samples['time1'][i]}, lTime2 {samples['time2'][i]}")
    q = samples["quaternion"]
    with np.errstate(invalid="ignore", over="ignore"):
        norm = np.sqrt(np.sum(q * q, axis=1))
    off = ~(np.abs(norm - 1.0) <= QUATERNION_NORM_TOL)  # NaN is off too
    # a sample the tracker flags as not measured (Status6D clear or Error6D set) may carry anything
    valid6d = (samples["rotation_status"] & 0b11) == 0b01
    off &= valid6d
    if off.any():
        i = int(np.flatnonzero(off)[0])
        return (f"6-DoF result sample {i} has quaternion {np.round(q[i], 9).tolist()} of norm {norm[i]:.9g}, "
                f"not a unit quaternion (tolerance {QUATERNION_NORM_TOL:g})")
    return None


def decode_packet(data, *, from_server: bool = True,
                  max_packet_bytes: int = DEFAULT_MAX_PACKET_BYTES):
    """Decode exactly one whole packet; ProtocolError if ``data`` is anything else."""
    consumed, frame = decode(data, from_server=from_server, max_packet_bytes=max_packet_bytes)
    if consumed == 0:
        have = len(data)
        if have < HEADER_BYTES:
            raise ProtocolError(f"{have} bytes cannot hold the {HEADER_BYTES}-byte packet header")
        size = HEADER.unpack_from(data, 0)[0]
        raise ProtocolError(f"packet declares {size} bytes but only {have} are present")
    if isinstance(frame, Garbage):
        raise ProtocolError(f"not an emScon packet: {frame.reason}")
    if consumed != len(data):
        raise ProtocolError(f"{len(data) - consumed} bytes left over after a {consumed}-byte packet")
    return frame


def length_unit_from_name(name: str) -> int:
    """``"mm"`` -> ``LengthUnit.MILLIMETER``; ConfigError-style ValueError otherwise."""
    from station.errors import ConfigError

    try:
        return LENGTH_UNIT_NAMES[name]
    except (KeyError, TypeError):
        raise ConfigError(f"length unit must be one of {sorted(LENGTH_UNIT_NAMES)}, got {name!r}") from None
