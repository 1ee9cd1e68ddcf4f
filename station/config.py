"""Station configuration: devices by URL, robots, limits.

A config is a TOML (or JSON) file validated into :class:`StationConfig`
before anything starts. Every key carries its unit in its name
(``rp_limit_mm``, ``speed_percent``); unknown keys are refused, which is how
a value written in the wrong unit (``rp_limit_um``) is caught. Errors are
:class:`~station.errors.ConfigError` naming the field path, e.g.
``robots.r1.limits.rp_limit_mm: Input should be greater than 0``.

Device URLs (``scheme://host:port`` or ``scheme:///dev/tty?baud=N``) follow the
one table of schemes and defaults in :mod:`station.device_urls` (emscon,
geocom, geocom+socket, modbus+ftp, ur, nmea, ply, fake); the drivers open them
with the same parser.
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from station.characteristics import config_limit_keys, robot_limit_keys
from station.errors import ConfigError, DataError
from station.models.robots import get_robot
from station.models.trailer import ESTIMATORS
from station.protocols.handshake import RegisterMap
from station.readers.once import read_bytes
from station.store_url import parse_pg_url
from station.verdict import MARGINAL_FRACTION

# the device-URL grammar is one table, shared with the drivers
from station.device_urls import DeviceURL, parse_device_url
from station.tracker_rates import TRACKER_RATE_RANGE_HZ


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)  # no NaN or inf anywhere


#: the slowest speed a generated program may ask for, percent of rated (controllers refuse a zero speed)
MIN_SPEED_PERCENT = 0.5

PositiveMM = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class DeviceConfig(_Strict):
    url: str
    timeout_s: float = Field(5.0, gt=0, allow_inf_nan=False)
    #: Modbus register layout of a ``modbus+ftp`` controller (default: the documented one)
    register_map: RegisterMap | None = None
    #: the tracker measures a 6-DoF target on the tool (a Leica T-Mac over emScon, its frame calibrated to the
    #: TCP): the ISO 9283 procedure then streams in the 6D continuous time mode and states orientation AP, RP
    six_dof: bool = False
    #: standard deviation of each angle of a 6-DoF reading, deg (the uncertainty of the orientation figures)
    angle_sd_deg: float = Field(0.01, gt=0, le=1, allow_inf_nan=False)

    @model_validator(mode="after")
    def _map_only_for_controllers(self) -> "DeviceConfig":
        if self.register_map is not None and not self.url.lower().startswith("modbus+ftp:"):
            raise ValueError("register_map applies to modbus+ftp controllers only")
        if self.six_dof and parse_device_url(self.url).scheme != "emscon":
            raise ValueError(f"six_dof needs an emScon tracker (a 6-DoF target over the emScon 6D modes); "
                             f"{parse_device_url(self.url).scheme}:// measures positions only")
        if "angle_sd_deg" in self.model_fields_set and not self.six_dof:
            raise ValueError("angle_sd_deg applies to a 6-DoF tracker only (six_dof: true)")
        return self

    @field_validator("url")
    @classmethod
    def _check_url(cls, v: str) -> str:
        try:
            parse_device_url(v)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        return v

    @property
    def parsed(self) -> DeviceURL:
        return parse_device_url(self.url)


class LimitsConfig(_Strict):
    """Acceptance limits (manufacturer's figures); None = report only.

    One key per limited characteristic of the ISO 9283 table
    (:mod:`station.characteristics`: ``ap_limit_mm`` for ``AP_mm``, ...,
    every key ``station analyze iso9283 --limit`` accepts), the drift
    programme's (``dap_limit_mm``, ``drp_limit_mm``, and per angle of a 6-DoF
    target ``dapa_limit_deg`` ... ``drpc_limit_deg``), and the POS/PST band
    ``pos_band_mm``. A key the table lacks is refused, naming it; so is a
    value that is not a number > 0.
    """

    model_config = ConfigDict(extra="allow", frozen=True, allow_inf_nan=False)
    __pydantic_extra__: dict[str, PositiveMM | None]

    pos_band_mm: PositiveMM | None = None

    @model_validator(mode="wrap")
    @classmethod
    def _known_keys(cls, data, handler):
        if isinstance(data, dict):
            known = robot_limit_keys()
            bad = [k for k in data if k not in known and k not in cls.model_fields]
            if bad:
                why = PydanticCustomError(
                    "unknown_limit", "unknown limit (keys carry their unit; known: {known})",
                    {"known": ", ".join(sorted([*known, *cls.model_fields]))})
                raise ValidationError.from_exception_data(
                    cls.__name__, [InitErrorDetails(type=why, loc=(k,), input=data[k]) for k in bad])
        return handler(data)

    def __getattr__(self, name: str):
        try:
            return super().__getattr__(name)
        except AttributeError:
            if name in robot_limit_keys():
                return None  # a limit not configured
            raise

    def by_characteristic(self, programme: str = "pose") -> dict[str, float]:
        """``{characteristic key: limit}`` of the limits given (``{"AP_mm": 5.0}``) that ``programme`` judges (the
        pose test's, or the drift programme's), in the table's order."""
        given = self.model_extra or {}
        return {key: float(given[k]) for k, key in config_limit_keys(programme).items() if given.get(k) is not None}


class WorkspaceConfig(_Strict):
    min_mm: tuple[float, float, float]
    max_mm: tuple[float, float, float]
    max_tcp_speed_mm_s: PositiveMM = 2000.0
    max_speed_percent: float = Field(100.0, ge=MIN_SPEED_PERCENT, le=100)
    max_accel_percent: float = Field(100.0, gt=0, le=100)

    @model_validator(mode="after")
    def _box(self) -> "WorkspaceConfig":
        for i, (lo, hi) in enumerate(zip(self.min_mm, self.max_mm)):
            if not (math.isfinite(lo) and math.isfinite(hi)) or lo >= hi:
                raise ValueError(f"workspace axis {'xyz'[i]}: min_mm {lo} must be < max_mm {hi}")
        return self


class MeasurementConfig(_Strict):
    """A plant's own measurement (:class:`station.measurements.Measurement`): limits in ``unit``."""

    name: str = Field(min_length=1, max_length=64)
    of: str = Field(min_length=1, max_length=64)
    unit: str = "mm"
    low: float | None = None
    high: float | None = None
    marginal: float = Field(0.0, ge=0)
    pose: str | None = None
    description: str = ""

    @model_validator(mode="after")
    def _limits(self) -> "MeasurementConfig":
        if self.low is None and self.high is None:
            raise ValueError(f"measurement {self.name!r}: give a limit (low and/or high, in {self.unit})")
        if self.low is not None and self.high is not None and self.low > self.high:
            raise ValueError(f"measurement {self.name!r}: low {self.low:g} > high {self.high:g}")
        return self


#: a plant's measurements per procedure name: ``[[measurements.iso9283]]`` tables
Measurements = dict[str, list[MeasurementConfig]]


class MountingConfig(_Strict):
    """The mounting a robot stands on (its base plate or pedestal in the cell), for ISO 9283 7.8: robots of one
    model exchanged on one mounting are compared in the mounting's frame, not each in its own registered one.

    ``frame``: a frame file (``p_tracker = R @ p_mounting + t_mm``, the form ``station run`` writes beside its
    report as ``<run>.frame.json``) giving the mounting's frame in the tracker's, the tracker left standing
    where it stood when it was measured; typically the first robot's registered frame, kept for the others.
    Without it a run takes its own registered frame as the mounting's (the first robot's run). A path relative
    to the config file's folder; read when the config is, and kept here as the absolute path it resolved to."""

    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9._-]+$")
    frame: str | None = Field(None, min_length=1, max_length=4096)

    @field_validator("frame")
    @classmethod
    def _readable_frame(cls, v: str | None, info) -> str | None:
        if v is None:
            return v
        from station.readers.registration_files import read_frame_json

        path, (R, _, _) = _read_named_file(v, info, read_frame_json)
        if np.abs(R.T @ R - np.eye(3)).max() > FRAME_ROTATION_TOL or np.linalg.det(R) <= 0:
            raise ValueError(f"file {path}: key 'R' is not a rotation (R^T R = I, det R = +1 within "
                             f"{FRAME_ROTATION_TOL:g})")
        return str(path.resolve())


def _read_named_file(v: str, info, read):
    """``(path, read(path))`` of a file a config names (relative to the config's folder, the validation
    context's ``base_dir``); a file ``read`` refuses is a ValueError naming it."""
    base = (info.context or {}).get("base_dir")
    path = _under(Path(base) if base is not None else Path.cwd(), v)
    try:
        return path, read(path)
    except (ConfigError, DataError) as exc:
        raise ValueError(f"file {path}: {exc}") from None


#: how far from a rotation a mounting frame's R may be (the rounding of a frame file's numbers)
FRAME_ROTATION_TOL = 1e-6


class RobotConfig(_Strict):
    model: str
    serial: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9._-]+$")
    overhaul_state: Literal["before", "after", "new", "in-service"] = "in-service"
    payload_kg: float = Field(0.0, ge=0, le=10_000, allow_inf_nan=False)
    #: the stop scatter of this robot's simulated arm (a fake cell), mm, 1 sigma per coordinate of the tool at
    #: home (None: drawn from the model's range, station.models.robots.RobotSpec.stop_scatter_mm)
    stop_scatter_mm: float | None = Field(None, ge=0, le=1, allow_inf_nan=False)
    #: a diagnosed motion model of this robot (``station diagnose motion --model-out``) its simulated arm (a fake
    #: cell) runs with: its loop, creep, structural mode and the tracker's drift. A path relative to the config
    #: file's folder; checked when the config is read, and kept here as the absolute path it resolved to
    motion_model: str | None = Field(None, min_length=1, max_length=4096)
    controller: str
    #: the mounting this robot stands on (ISO 9283 7.8 exchangeability; None: not recorded, not comparable)
    mounting: MountingConfig | None = None
    workspace: WorkspaceConfig
    limits: LimitsConfig = LimitsConfig()
    #: this robot's own measurements per procedure, added to the station's
    measurements: Measurements = Field(default_factory=dict)

    @field_validator("motion_model")
    @classmethod
    def _readable_motion_model(cls, v: str | None, info) -> str | None:
        if v is None:
            return v
        from station.models.motion_model_file import read_motion_model

        path, _ = _read_named_file(v, info, read_motion_model)
        return str(path.resolve())

    @field_validator("model")
    @classmethod
    def _known_model(cls, v: str) -> str:
        try:
            get_robot(v)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        return v


class ISOProcedureConfig(_Strict):
    """Parameters of the ISO 9283 procedure (seed 000 sec. 2-3)."""

    cube_corners_mm: list[tuple[float, float, float]] | None = None
    inset_mm: float = Field(100.0, gt=0, le=1000)
    cycles: int = Field(30, ge=2, le=1000)
    dwell_s: float = Field(0.5, gt=0, le=60)
    speed_percent: float = Field(100.0, ge=MIN_SPEED_PERCENT, le=100)
    tracker_rate_hz: float = Field(100.0, ge=TRACKER_RATE_RANGE_HZ[0], le=TRACKER_RATE_RANGE_HZ[1])
    vap_cycles: int = Field(30, ge=2, le=1000)
    vap_offset_mm: float = Field(100.0, gt=0, le=1000)
    distance_cycles: int = Field(10, ge=2, le=1000)
    mpt_repeats: int = Field(3, ge=1, le=100)
    #: how the tracker is tied to the robot base: circles of joints 1 and 2 (ISO/TR 13309 practice) or a
    #: rigid best fit over the inset cube corners (absorbs part of the robot's error into the frame)
    registration: Literal["axes", "best-fit"] = "axes"
    #: half ranges of the joint-1 and joint-2 sweeps of the axis registration, deg, and points per sweep
    axis_sweep_deg: tuple[float, float] = (25.0, 30.0)
    axis_sweep_points: int = Field(13, ge=5, le=61)

    @field_validator("axis_sweep_deg")
    @classmethod
    def _sweep(cls, v):
        if not all(2.0 <= a <= 90.0 for a in v):
            raise ValueError(f"axis_sweep_deg half ranges must be in [2, 90] deg, got {v}")
        return v

    @field_validator("cube_corners_mm")
    @classmethod
    def _eight(cls, v):
        if v is not None and len(v) != 8:
            raise ValueError(f"cube_corners_mm needs 8 corners C1..C8, got {len(v)}")
        return v


class DriftProgrammeConfig(_Strict):
    """The ISO 9283 drift programme (``station run iso9283-drift``): a visit of ``cycles_per_visit`` pose cycles
    every ``interval_s`` over ``span_s`` from a cold start, at ``poses`` (default every pose of the cube); its
    limits are the robot's ``dap_limit_mm`` and ``drp_limit_mm``. Without this section the programme is not
    offered."""

    span_s: float = Field(8 * 3600.0, gt=0, le=7 * 86400.0)
    interval_s: float = Field(600.0, ge=60.0, le=86400.0)
    cycles_per_visit: int = Field(10, ge=2, le=100)
    poses: list[str] | None = None


class PathProgrammeConfig(_Strict):
    """The ISO 9283 path test (``station run iso9283-path``, clauses 8.2-8.6): each of ``path_kinds`` at each of
    ``path_speed_fracs`` of the rated speed, ``path_cycles`` times, in the pose test's cube (edge
    ``path_side_mm``, default the pose cube's), the blended rectangle's corner zone ``blend_mm``; limits of path
    figures in ``path_limits`` (``{"CR_mm" = 2.0, "rectangle_blend_100.CO_mm" = 1.0}``) beside the robot's AT/RT.
    ``path_kinds`` may add ``weaving`` (``weave_*``), ``reorientation`` and ``reorientation_held`` (the tool turned
    about its held point, with a 6-DoF target; both ``reorient_deg``), which the default kinds leave out. Without this section the path test is not offered (its default plan runs for an hour)."""

    path_cycles: int = Field(10, ge=2, le=100)
    path_speed_fracs: list[Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)]] = Field(
        default_factory=lambda: [1.0, 0.5, 0.1], min_length=1, max_length=10)
    path_kinds: list[str] | None = Field(None, min_length=1, max_length=20)
    blend_mm: float = Field(20.0, ge=0, le=500, allow_inf_nan=False)
    path_side_mm: float | None = Field(None, gt=0, le=3000, allow_inf_nan=False)
    path_limits: dict[str, Annotated[float, Field(ge=0, allow_inf_nan=False)]] = Field(default_factory=dict)
    #: the reorientation paths' turn either side of the programmes' orientation, deg (clause 8.3)
    reorient_deg: float | None = Field(None, gt=0, le=90, allow_inf_nan=False)
    #: the weaving path (clause 11): amplitude and frequency of the weave, speed along its base, periods, and
    #: points per period (4, 8 or 12)
    weave_amplitude_mm: float | None = Field(None, gt=0, le=50, allow_inf_nan=False)
    weave_frequency_Hz: float | None = Field(None, gt=0, le=20, allow_inf_nan=False)
    weave_speed_mm_s: float | None = Field(None, gt=0, le=500, allow_inf_nan=False)
    weave_periods: int | None = Field(None, ge=2, le=100)
    weave_points_per_period: int | None = Field(None, ge=4, le=12)


class ArmCalibrationConfig(_Strict):
    """The arm calibration of seed 002 (poses chosen for observability), with a tracker or a 3D scanner.

    With ``instrument = "scanner"`` the arm carries the corner jig into the
    field of a fixed 3D scanner (device role ``scanner``, a ``ply://`` hot
    folder); ``instrument_mm`` is then the scanner's eye and
    ``instrument_look_at_mm`` a point on its optical axis (both approximate,
    robot base frame: they choose the poses, the identification finds the
    exact scanner <- base transform).
    """

    #: what measures the tool: the tracker (reflector on the flange) or the scanner (corner jig on the tool)
    instrument: Literal["tracker", "scanner"] = "tracker"

    #: distance errors (seed eq. (9)-(16)) or absolute positions (also identifies the tracker <- base transform)
    method: Literal["distance", "absolute"] = "absolute"
    #: training poses, the first of them the reference (seed: 1 + 50), and test poses drawn apart (seed: 13)
    train_poses: int = Field(51, ge=8, le=2000)
    test_poses: int = Field(13, ge=0, le=2000)
    #: D-optimal choice from the candidates, or random ones
    selection: Literal["d-optimal", "random"] = "d-optimal"
    candidates: int = Field(1500, ge=50, le=20000)
    #: tool tilt from the base orientation of the ISO programs (tool down), deg
    tilt_deg: float = Field(35.0, ge=0, le=90)
    #: where the tracker stands, robot base frame (mm): with it, poses whose reflector faces away are not chosen
    instrument_mm: tuple[float, float, float] | None = None
    reflector_half_angle_deg: float = Field(30.0, gt=0, le=90)
    #: scanner only: a point on its optical axis, robot base frame (mm)
    instrument_look_at_mm: tuple[float, float, float] | None = None
    #: scanner only: field width at the working distance, working distance, measurable depths (mm)
    scanner_fov_mm: float = Field(450.0, gt=0, le=5000)
    scanner_working_distance_mm: float = Field(700.0, gt=0, le=10000)
    scanner_depth_range_mm: tuple[float, float] = (450.0, 1100.0)
    #: scanner only: the jig corner is seen when the tool z axis points at the scanner within this (deg)
    jig_half_angle_deg: float = Field(30.0, gt=0, le=60)
    #: scanner only: how long a capture may take before the scanner counts as not answering (s)
    scan_timeout_s: float = Field(30.0, gt=0, le=600)
    dwell_s: float = Field(0.3, gt=0, le=60)
    measure_s: float = Field(0.2, gt=0, le=60)
    speed_percent: float = Field(20.0, ge=MIN_SPEED_PERCENT, le=100)
    poses_per_step: int = Field(8, ge=1, le=200)
    #: UR only: the controller's calibration (a ``calibration.conf`` [mounting] section, as a run writes it)
    #: the identification starts from instead of the nominal model; a run on a UR identifies a plain DH
    #: model (no beta) and writes its deltas beside the model file
    ur_calibration: str | None = None
    #: limit of the test poses' mean |error| after calibration (a characteristic with a verdict), mm
    test_error_limit_mm: float | None = Field(None, gt=0, allow_inf_nan=False)

    @model_validator(mode="after")
    def _scanner(self) -> "ArmCalibrationConfig":
        if self.instrument != "scanner":
            return self
        if self.instrument_mm is None or self.instrument_look_at_mm is None:
            raise ValueError("instrument = 'scanner' needs instrument_mm (the scanner's eye) and "
                             "instrument_look_at_mm (a point on its optical axis), robot base frame, mm")
        if math.dist(self.instrument_mm, self.instrument_look_at_mm) < 1.0:
            raise ValueError("instrument_look_at_mm must lie away from instrument_mm (it gives the optical axis)")
        near, far = self.scanner_depth_range_mm
        if not 0 < near < far:
            raise ValueError(f"scanner_depth_range_mm must be (near, far) with 0 < near < far, got {(near, far)}")
        return self


class TrailerConfig(_Strict):
    """The trailer calibration of seed 003 (lengths m, curvature 1/m, speed m/s)."""

    odometry: str = Field(description="device name of the odometry (nmea://...)")
    serial: str = Field("TRAILER-0001", min_length=1, max_length=64, pattern=r"^[A-Za-z0-9._-]+$")
    nominal_L1_m: float = Field(1.25, gt=0, allow_inf_nan=False)
    nominal_L2_m: float = Field(2.48, gt=0, allow_inf_nan=False)
    commands: list[tuple[Literal["H", "C", "L"], float]] = [("H", 0.2), ("C", 0.2), ("L", 0.2)]
    v_m_s: float = Field(1.0, gt=0, le=3.0)
    settle_s: float = Field(20.0, ge=0, le=1e4)
    duration_s: float = Field(63.0, gt=0, le=1e4)
    method: str = "dynamic"
    #: |L1 - nominal_L1_m| and |L2 - nominal_L2_m| of the estimate must stay within this (verdicts), m
    length_tolerance_m: float | None = Field(None, gt=0, allow_inf_nan=False)
    #: how a length error is judged against the tolerance with its U = 2 sigma of the estimate (ISO 14253-1):
    #: ``guarded`` (conformance proven when error + U is within, non-conformance when error - U is beyond, else
    #: NOT DECIDED) or ``simple`` (the error against the tolerance; a straddling U makes it marginal)
    decision_rule: Literal["simple", "guarded"] = "guarded"

    @field_validator("method")
    @classmethod
    def _method(cls, v):
        if v not in ESTIMATORS:
            raise ValueError(f"unknown trailer method {v!r}; one of {', '.join(ESTIMATORS)}")
        return v

    @model_validator(mode="after")
    def _links(self) -> "TrailerConfig":
        if self.nominal_L2_m <= self.nominal_L1_m:
            raise ValueError(f"nominal_L2_m {self.nominal_L2_m} must exceed nominal_L1_m {self.nominal_L1_m} (seed 003 eq. (25))")
        if not self.commands:
            raise ValueError("commands must list at least one (kind, M)")
        return self


class UncertaintyConfig(_Strict):
    """The uncertainty budget of the ISO 9283 figures and the decision rule (ISO 14253-1).

    ``simple``: the figure against the limit (u and U shown); ``guarded``: conformance only when
    figure + U is within the limit, non-conformance only when figure - U is beyond, else not decided.
    The tracker's term is ``a + b R`` per coordinate, an MPE read as a k = 2 bound (``tracker_kind = "mpe"``)
    or a standard deviation (``"sd"``).
    """

    decision_rule: Literal["simple", "guarded"] = "simple"
    tracker_a_um: float = Field(15.0, ge=0, le=10_000, allow_inf_nan=False)
    tracker_b_um_per_m: float = Field(6.0, ge=0, le=10_000, allow_inf_nan=False)
    tracker_kind: Literal["mpe", "sd"] = "mpe"
    #: uncertainty of the air temperature of the tracker's refraction compensation, K
    temperature_u_K: float = Field(0.0, ge=0, le=100, allow_inf_nan=False)
    mc_trials: int = Field(20_000, ge=200, le=10_000_000)
    mc_seed: int = Field(0, ge=0)

    def budget_kwargs(self) -> dict:
        """Keyword arguments of :class:`station.analysis.uncertainty.Budget`."""
        return {"instrument_a_um": self.tracker_a_um, "instrument_b_um_per_m": self.tracker_b_um_per_m,
                "instrument_kind": self.tracker_kind, "temperature_u_K": self.temperature_u_K,
                "trials": self.mc_trials, "seed": self.mc_seed}


class StationSection(_Strict):
    name: str = Field(min_length=1)
    store_path: str = Field("station.sqlite", min_length=1, max_length=4096)
    #: the plant's central store the station forwards its runs to (``postgresql://user@host:port/db``,
    #: password by ``?password_env=VAR`` or ``?password_file=PATH``, never in the URL); None: local only
    store_url: str | None = None
    report_dir: str = Field("reports", min_length=1, max_length=4096)
    #: the plant's guard band: a passing figure within this fraction of its limit (or whose U carries it over
    #: the limit) is flagged marginal (station.analysis.decision.marginal_reason); 0 keeps only the U test
    marginal_fraction: float = Field(MARGINAL_FRACTION, ge=0, lt=1, allow_inf_nan=False)

    @field_validator("store_path", "report_dir")
    @classmethod
    def _plain_path(cls, v):
        bad = [c for c in v if ord(c) < 32 or ord(c) == 127]
        if bad:
            raise ValueError(f"a path cannot hold control characters (found {bad[0]!r})")
        return v

    @field_validator("store_url")
    @classmethod
    def _check_store_url(cls, v: str | None) -> str | None:
        if v is None:
            return v
        try:
            parse_pg_url(v)
        except ConfigError as exc:
            raise ValueError(str(exc).removeprefix("store_url: ")) from None
        return v

    def store_file(self, base: Path) -> Path:
        """The store's path; a relative one is relative to ``base`` (the config's folder)."""
        return _under(base, self.store_path)

    def report_folder(self, base: Path) -> Path:
        """The report folder; a relative one is relative to ``base``."""
        return _under(base, self.report_dir)


def _under(base: Path, path: str) -> Path:
    p = Path(path)
    return p if p.is_absolute() else Path(base) / p


class StationConfig(_Strict):
    station: StationSection
    devices: dict[str, DeviceConfig]
    robots: dict[str, RobotConfig] = Field(default_factory=dict)
    iso9283: ISOProcedureConfig = ISOProcedureConfig()
    arm_calibration: ArmCalibrationConfig = ArmCalibrationConfig()
    iso9283_drift: DriftProgrammeConfig | None = None
    iso9283_path: PathProgrammeConfig | None = None
    trailer: TrailerConfig | None = None
    #: the plant's measurements per procedure (every robot)
    measurements: Measurements = Field(default_factory=dict)

    def measurements_for(self, procedure: str, robot: str | None = None) -> list[dict]:
        """The plant's measurements of ``procedure`` for ``robot``: the station's, then the robot's."""
        ms = list(self.measurements.get(procedure, []))
        if robot is not None and robot in self.robots:
            ms += self.robots[robot].measurements.get(procedure, [])
        return [m.model_dump() for m in ms]
    #: the uncertainty of the ISO 9283 figures and the decision rule; None: figures against limits only
    uncertainty: UncertaintyConfig | None = None

    @model_validator(mode="after")
    def _references(self) -> "StationConfig":
        if self.trailer is not None and self.trailer.odometry not in self.devices:
            raise ValueError(f"trailer.odometry names device {self.trailer.odometry!r}, which is not in devices "
                             f"({', '.join(sorted(self.devices)) or 'none'})")
        for rname, robot in self.robots.items():
            if robot.controller not in self.devices:
                raise ValueError(
                    f"robots.{rname}.controller names device {robot.controller!r}, "
                    f"which is not in devices ({', '.join(sorted(self.devices)) or 'none'})"
                )
        return self

    def device(self, name: str) -> DeviceConfig:
        try:
            return self.devices[name]
        except KeyError:
            raise ConfigError(f"devices.{name}: no such device (have {', '.join(sorted(self.devices))})") from None


def _format_validation_error(exc: ValidationError, source: str) -> str:
    lines = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown field (keys carry their unit, e.g. *_mm, *_s, *_percent; check spelling and unit)"
        elif err["type"] == "missing":
            msg = "missing required field"
        lines.append(f"{loc}: {msg}")
    return f"{source}: invalid station config:\n  " + "\n  ".join(lines)


def config_from_dict(data: dict, source: str = "config", base_dir: str | Path | None = None) -> StationConfig:
    """Validate a dict into a StationConfig or raise ConfigError naming every bad field; relative file paths
    (``robots.X.motion_model``) are read from ``base_dir`` (default the working folder)."""
    try:
        return StationConfig.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as exc:
        raise ConfigError(_format_validation_error(exc, source)) from None


def load_config(path: str | Path) -> StationConfig:
    """Read a TOML or JSON station config; ConfigError names the file and field."""
    path = Path(path)
    try:  # one bounded read: a pipe or a device (/dev/zero) given as the config is not read for ever
        text = read_bytes(path, MAX_CONFIG_BYTES, "not a station config")
    except DataError as exc:
        raise ConfigError(str(exc).replace("cannot read", "cannot read config")) from None
    kind = "JSON" if path.suffix.lower() == ".json" else "TOML"
    try:
        if kind == "JSON":
            data = json.loads(text)
        else:
            data = tomllib.loads(text.decode("utf-8"))
    except (tomllib.TOMLDecodeError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid {kind}: {exc}") from exc
    except RecursionError:
        raise ConfigError(f"{path}: nested too deeply to be a station config") from None
    except ValueError as exc:  # e.g. an integer of thousands of digits
        why = "an integer of more than 4300 digits" if "digits" in str(exc) else str(exc)[:120]
        raise ConfigError(f"{path}: not a valid {kind} value: {why}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: top level must be a table")
    depth = _depth(data)
    if depth > MAX_CONFIG_DEPTH:
        raise ConfigError(f"{path}: nested {depth} levels deep; a station config has at most {MAX_CONFIG_DEPTH}")
    return config_from_dict(data, str(path), base_dir=path.parent)


#: bounds on what a config file can be (a real one is a few KiB and 4-5 levels deep)
MAX_CONFIG_BYTES = 1 << 20
MAX_CONFIG_DEPTH = 12


def _depth(value, level: int = 0) -> int:
    """Nesting depth of tables and arrays (stops counting past the limit)."""
    if level > MAX_CONFIG_DEPTH:
        return level
    if isinstance(value, dict):
        return max((_depth(v, level + 1) for v in value.values()), default=level + 1)
    if isinstance(value, list):
        return max((_depth(v, level + 1) for v in value), default=level + 1)
    return level
