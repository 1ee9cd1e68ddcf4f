"""The inputs of ``station analyze``: limits, the stream and its time base, the registration.

This is the I/O boundary of the analyze commands: files are read through
:mod:`station.readers`, checked, and turned into the arrays the pure analyses
take; every problem is a :class:`~station.errors.DataError` or
:class:`~station.errors.ConfigError` naming the file (and line) or the option.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from station.errors import ConfigError, DataError


def parse_limits(items) -> dict[str, float]:
    """``--limit KEY=VALUE`` items to a dict (validated later against the known keys)."""
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(f"--limit must be KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"--limit {key.strip()}: {value!r} is not a number") from None
    return out


def check_positive(value, option: str) -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{option} must be a number > 0, got {value!r}")


@dataclass
class StreamInput:
    """A stream read and given its time base: ``t_s`` (N,), ``xyz_mm`` (N, 3), ``valid`` (N,)."""

    points: object  # station.readers.stream.PointStream
    t_s: np.ndarray
    time_base: dict
    notes: list[str] = field(default_factory=list)
    time_note: str = ""
    #: why no time figure may be stated (the clock failed its check); "" when they may
    refused: str = ""
    #: where the clock jumped (station.analysis.iso9283.clock_jumps.ClockJump): time figures across are refused
    jumps: tuple = ()

    @property
    def estimated_rate(self) -> bool:
        return self.time_base.get("source") in ("estimated_rate", "motion_rate")


def load_stream(path, fmt=None, group=None, rate_hz=None, date_order=None, *, command: str = "analyze",
                wait_s: float | None = None) -> StreamInput:
    """Read a stream in any known format and fix its time base (:func:`station.analysis.lab_files.stream_time_base`,
    the clock checked against the stream's motion; ``wait_s`` the program's wait at each stop, ``--dwell-s``).

    A per-pose reflector list given as a stream is refused (:func:`refuse_reflector_list`, ``command`` names
    the command in the message).
    """
    from station.analysis.iso9283.lab_files import stream_time_base
    from station.readers.sniff import read_stream_file

    check_positive(rate_hz, "--rate-hz")
    check_positive(wait_s, "--dwell-s")
    ps = read_stream_file(path, fmt, group=group, date_order=date_order)
    refuse_reflector_list(ps, command)
    tb = stream_time_base(ps.t_s, ps.n, rate_hz, line=ps.line, source=ps.source,
                          tcol="date time" if ps.fmt == "sa" else "t", xyz_mm=ps.xyz_mm, valid=ps.valid,
                          wait_s=wait_s)
    return StreamInput(ps, tb.t_s, tb.info, list(ps.notes) + tb.notes, tb.note, tb.refused, tb.jumps)


def refuse_reflector_list(ps, command: str) -> None:
    """A plain point list whose first column repeats a few ids (1, 2, 3, 1, 2, 3, ...) is a per-pose reflector
    list, not a stream: refused with what to do instead."""
    from station.analysis.iso9283.lab_files import repeating_ids

    ids = repeating_ids(ps.names) if ps.fmt == "points" else None
    if ids is not None:
        raise DataError(f"{ps.source}: the first column repeats {', '.join(ids)} every {len(ids)} rows: this is a "
                        f"per-pose reflector list (reflector, x, y, z once per cycle), not a stream of one point; "
                        f"'station {command}' would report the distance between the reflectors as noise. Analyse "
                        "it with 'station analyze iso9283 --stops FILE...' (one file per pose)")


def window_parameters(window_samples: int | None, rate_hz: float | None) -> dict:
    """Extraction options with every sample count fixed by ``--window-samples`` (needs ``--rate-hz``).

    The horizon 2M+1 = N samples (eq. (4), step Mp = M); the moving average
    over 2h+1 samples with h = M/2, the velocity of eq. (3) over M/5 samples
    and a dwell of 2M samples, as the defaults relate them; so the chosen
    samples do not depend on the rate given, and every time scales with it.
    """
    if window_samples is None:
        return {}
    if rate_hz is None:
        raise ConfigError("--window-samples needs --rate-hz (windows in samples on the sample-index time base)")
    N = int(window_samples)
    if N < 3 or N % 2 == 0:
        raise ConfigError(f"--window-samples must be an odd number >= 3, got {window_samples!r}")
    M = (N - 1) // 2
    h = max(1, int(round(M / 2)))
    lag = max(1, int(round(M / 5)))
    R = float(rate_hz)
    return dict(M=M, Mp=M, smooth_s=2.0 * h / R, velocity_step_s=lag / R, min_dwell_s=(2 * M - 0.5) / R)


def read_frame(frame_path=None, register_path=None, *, noise_mm: float, robot_error_mm: float | None,
               max_rms_mm: float | None, out) -> tuple[object | None, dict | None]:
    """The registration tracker <- base from ``--frame`` or ``--register`` (None without either).

    ``--register``: the rigid fit is printed (rms and each pair's residual) to
    ``out``; a fit rms above the allowance (:func:`rms_allowance_mm` from the
    tracker's noise and the robot's error, or ``max_rms_mm``) is refused.
    Returns the registration and its JSON.
    """
    from station.analysis.registration import fit_rigid, registration_from_transform, rms_allowance_mm
    from station.readers.registration_files import frame_info_text, read_frame_json, read_registration_csv

    if frame_path is not None and register_path is not None:
        raise ConfigError("give either --frame or --register, not both")
    if frame_path is not None:
        R, t, obj = read_frame_json(frame_path)
        try:
            reg = registration_from_transform(R, t)
        except DataError as exc:
            raise DataError(f"{frame_path}: {exc}") from None
        info = frame_info_text(obj)
        print(f"frame: {frame_path}" + (f" ({info})" if info else "") + "; poses taken in the robot base frame",
              file=out)
        return reg, {"source": "frame", "file": str(frame_path), "R": reg.R.tolist(), "t_mm": reg.t_mm.tolist()}
    if register_path is None:
        return None, None
    names, base, trk = read_registration_csv(register_path)
    try:
        reg = fit_rigid(base, trk)
    except DataError as exc:
        raise DataError(f"{register_path}: {exc}") from None
    check_positive(max_rms_mm, "--register-max-rms-mm")
    allow = max_rms_mm if max_rms_mm is not None else rms_allowance_mm(noise_mm, robot_error_mm)
    print(f"registration: {reg.n} point pairs from {register_path}, fit rms {reg.rms_mm:.4f} mm "
          f"(allowed {allow:.4f} mm)", file=out)
    for n, r in zip(names, reg.residuals_mm):
        print(f"  {n:<12} residual {r:.4f} mm", file=out)
    js = {"source": "register", "file": str(register_path), "R": reg.R.tolist(), "t_mm": reg.t_mm.tolist(),
          "rms_mm": reg.rms_mm, "allowed_rms_mm": allow,
          "residuals_mm": {n: float(r) for n, r in zip(names, reg.residuals_mm)}}
    if reg.rms_mm > allow:
        worst = int(np.argmax(reg.residuals_mm))
        why = (f"{max_rms_mm:g} mm (--register-max-rms-mm)" if max_rms_mm is not None else
               f"{allow:.4f} mm: 10 x sqrt(3) x the tracker's noise {noise_mm:.4g} mm"
               + ("" if robot_error_mm is None else f", or the AP limit {robot_error_mm:g} mm"))
        raise DataError(f"{register_path}: the registration's fit rms {reg.rms_mm:.4f} mm is far above what the "
                        f"points' noise explains ({why}); the largest residual is {names[worst]} "
                        f"{reg.residuals_mm[worst]:.4f} mm: are the pairs matched, in mm, in the right columns? "
                        "(if the base points are robot positions, their error counts: give --limit AP_mm=... or "
                        "--register-max-rms-mm)")
    return reg, js
