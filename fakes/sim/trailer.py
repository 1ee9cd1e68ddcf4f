"""The simulated two-link trailer robot (seed 003, Fig. 3) on the world clock.

:class:`SimTrailer` integrates the real nonholonomic kinematics in time —
the pose of the front unit and the joint-angle dynamics (D) of
:mod:`station.models.trailer` — as the clock advances. It takes curvature
commands (set points, or the H, C, L profiles of seed para. [0127]) and a
speed, and it has two sensors: path curvature of the front axle and joint
angle, each with Gaussian noise and optional offset and gain errors
(:class:`~station.models.trailer.SensorModel`).

Like a real odometry unit, the curvature and speed sensors report averages
over the interval since their previous reading (heading change over distance
travelled, distance over time), not instantaneous values; the joint-angle
sensor reads the angle at the sample time.

Thread-safe: a fake's streaming thread and its command thread may call it at
once. Time never runs backwards: a call for a time already integrated uses
the integrated state.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from station.errors import ConfigError, DataError
from station.numeric import finite_number
from station.models.trailer import (
    COMMAND_KINDS, COMMAND_OMEGA_RAD_S, DEFAULT_L1_M, DEFAULT_L2_M, PATENT_NOISE_SIGMA,
    PSI_LIMIT_RAD, SensorModel, check_curvature_command, check_lengths, command_curvature,
)

#: largest speed the simulated drive accepts, m/s
MAX_SPEED_M_S = 3.0
#: default curvature rate limit of the front unit's steering, 1/(m s)
DEFAULT_CURVATURE_RATE = 0.2


@dataclass(frozen=True)
class TrailerState:
    """True state at ``t_s``: front-axle pose, joint angle, inputs."""

    t_s: float
    x_m: float
    y_m: float
    theta1_rad: float
    psi_rad: float
    kappa_1_m: float
    v_m_s: float


@dataclass(frozen=True)
class SensorReading:
    """One odometry sample as the sensors report it."""

    t_s: float
    v_m_s: float
    kappa_1_m: float
    psi_rad: float


@dataclass(frozen=True)
class _Profile:
    kind: str
    M: float
    omega: float
    t0: float
    t_end: float

    def at(self, t: float) -> float:
        tau = min(max(t, self.t0), self.t_end) - self.t0
        wt = self.omega * tau
        if self.kind == "H":
            return self.M * math.sin(wt)
        if self.kind == "C":
            return self.M * math.tanh(wt)
        return self.M * (wt / math.pi - 1.0)


class SimTrailer:
    """A simulated two-link nonholonomic trailer robot.

    Parameters
    ----------
    clock : SimClock or ManualClock
        The world clock (``now()``).
    L1_m, L2_m : float
        True link lengths (seed para. [0132]: 1.25 m and 2.48 m).
    v_m_s : float
        Initial speed of the front axle, m/s (>= 0: reverse is unstable).
    noise : float, SensorModel or None
        Sensor model; a number is the Gaussian sigma of both sensors. The
        default is the seed's noise level (0.03 / sqrt(3), see
        :data:`station.models.trailer.PATENT_NOISE_SIGMA`).
    rng : numpy.random.Generator, optional
        Noise source (the world's ``rng``); a fresh one if omitted.
    psi0_rad : float
        Initial joint angle.
    max_step_s : float
        Largest RK4 step of the integrator, s.
    psi_limit_rad : float
        Joint-angle limit used to refuse commands (seed: 45 deg).
    max_curvature_rate : float
        The steering follows the commanded curvature at most this fast,
        1/(m s) (an actuator cannot jump; ``inf`` allows steps). The seed's
        profiles change far slower (``M w`` <= 0.02) and are followed exactly.
    steering_gain : float
        Actual path curvature = gain x the (rate-limited) command: a drive
        whose steering is off by a few percent.
    """

    def __init__(self, clock, L1_m: float = DEFAULT_L1_M, L2_m: float = DEFAULT_L2_M,
                 v_m_s: float = 1.0, noise=PATENT_NOISE_SIGMA, rng: np.random.Generator | None = None,
                 *, psi0_rad: float = 0.0, max_step_s: float = 0.02,
                 psi_limit_rad: float = PSI_LIMIT_RAD,
                 max_curvature_rate: float = DEFAULT_CURVATURE_RATE, steering_gain: float = 1.0) -> None:
        self._L1, self._L2 = check_lengths(L1_m, L2_m)
        if not hasattr(clock, "now"):
            raise ConfigError(f"clock must have now(), got {clock!r}")
        self.clock = clock
        self.sensors = SensorModel.from_noise(noise)
        self.rng = rng if rng is not None else np.random.default_rng()
        if not (isinstance(max_step_s, (int, float)) and 0 < max_step_s <= 1.0):
            raise ConfigError(f"max_step_s must be in (0, 1] s, got {max_step_s!r}")
        if not (isinstance(psi_limit_rad, (int, float)) and 0 < psi_limit_rad < math.pi / 2):
            raise ConfigError(f"psi_limit_rad must be in (0, pi/2), got {psi_limit_rad!r}")
        if not (isinstance(psi0_rad, (int, float)) and abs(psi0_rad) < psi_limit_rad):
            raise ConfigError(f"psi0_rad must be a number within +-{psi_limit_rad:.4f} rad, got {psi0_rad!r}")
        if not (isinstance(max_curvature_rate, (int, float)) and max_curvature_rate > 0):
            raise ConfigError(f"max_curvature_rate must be > 0 (inf for steps), got {max_curvature_rate!r}")
        self._rate = float(max_curvature_rate)
        if not (isinstance(steering_gain, (int, float)) and 0.5 <= steering_gain <= 2.0):
            raise ConfigError(f"steering_gain must be in [0.5, 2], got {steering_gain!r}")
        self._gain = float(steering_gain)
        self._max_step = float(max_step_s)
        self._psi_limit = float(psi_limit_rad)
        self._lock = threading.RLock()
        self._t = float(clock.now())
        self._x = self._y = self._theta = self._s = 0.0
        self._psi = float(psi0_rad)
        self._last_read: tuple[float, float, float] | None = None  # (t, theta, s) of the last reading
        self._kappa_cmd = 0.0
        self._kappa = 0.0  # the steering's command (rate-limited); path curvature = gain x this
        self._profile: _Profile | None = None
        self._v = self._check_speed(v_m_s)

    # -- parameters -----------------------------------------------------------------
    @property
    def L1_m(self) -> float:
        return self._L1

    @property
    def L2_m(self) -> float:
        return self._L2

    @property
    def t_s(self) -> float:
        """Simulated time up to which the state is integrated."""
        with self._lock:
            return self._t

    # -- commands -------------------------------------------------------------------
    def command_curvature(self, kappa_1_m: float, t_s: float | None = None) -> float:
        """Hold curvature ``kappa_1_m`` from ``t_s`` (default now); returns the time applied.

        Raises CurvatureBoundError / JointAngleLimitError (the command is
        refused and the previous one stays) if it passes eq. (25) or drives
        the steady joint angle beyond the limit.
        """
        k = finite_number(kappa_1_m, "kappa_1_m")
        check_curvature_command(np.array([k]), self._L1, self._L2, self._psi_limit)
        with self._lock:
            t = self._advance_locked(t_s)
            self._profile = None
            self._kappa_cmd = k
            return t

    def command_speed(self, v_m_s: float, t_s: float | None = None) -> float:
        """Drive at ``v_m_s`` from ``t_s`` (default now); returns the time applied."""
        v = self._check_speed(v_m_s)
        with self._lock:
            t = self._advance_locked(t_s)
            self._v = v
            return t

    def set_profile(self, kind: str, M: float, *, duration_s: float = 63.0, t0_s: float | None = None,
                    omega_rad_s: float = COMMAND_OMEGA_RAD_S) -> float:
        """Run command ``kind`` (H, C, L of para. [0127]) of amplitude ``M`` from ``t0_s``.

        The curvature is ``command_curvature(kind, M, t - t0)`` for
        ``0 <= t - t0 <= duration_s`` and holds its end value afterwards. The
        whole profile is checked against eq. (25) and the joint-angle limit
        before it starts. Returns the start time.
        """
        if kind not in COMMAND_KINDS:
            raise ConfigError(f"kind must be one of {COMMAND_KINDS}, got {kind!r}")
        if not (isinstance(duration_s, (int, float)) and 0 < duration_s < 1e6):
            raise ConfigError(f"duration_s must be in (0, 1e6), got {duration_s!r}")
        tau = np.linspace(0.0, float(duration_s), 2001)
        check_curvature_command(command_curvature(kind, float(M), tau, omega_rad_s),
                                self._L1, self._L2, self._psi_limit)
        with self._lock:
            t0 = self._advance_locked(t0_s)
            self._profile = _Profile(kind, float(M), float(omega_rad_s), t0, t0 + float(duration_s))
            return t0

    # -- state and sensors ------------------------------------------------------------
    def advance_to(self, t_s: float | None = None) -> float:
        """Integrate up to ``t_s`` (default now); returns the integrated time."""
        with self._lock:
            return self._advance_locked(t_s)

    def state(self, t_s: float | None = None) -> TrailerState:
        """True state at ``t_s`` (default now)."""
        with self._lock:
            t = self._advance_locked(t_s)
            return TrailerState(t, self._x, self._y, self._theta, self._psi, self._gain * self._kappa, self._v)

    def read_sensors(self, t_s: float | None = None) -> SensorReading:
        """One noisy sample at ``t_s`` (default now): curvature and speed averaged
        since the previous reading, joint angle at ``t_s``."""
        with self._lock:
            t = self._advance_locked(t_s)
            kappa, v = self._odometry_locked(t)
            k, p = self.sensors.measure(kappa, self._psi, self.rng)
            return SensorReading(t, v, float(k), float(p))

    def _odometry_locked(self, t: float) -> tuple[float, float]:
        """Curvature and speed over the interval since the last reading (instantaneous
        for the first reading or when the trailer did not move)."""
        last, self._last_read = self._last_read, (t, self._theta, self._s)
        if last is None or t <= last[0]:
            return self._gain * self._kappa, self._v
        ds = self._s - last[2]
        v = ds / (t - last[0])
        kappa = (self._theta - last[1]) / ds if ds > 1e-9 else self._gain * self._kappa
        return kappa, v

    def record(self, t_s, repeats: int | None = None) -> dict[str, np.ndarray]:
        """Integrate through sample times ``t_s`` and sample the sensors there.

        Parameters
        ----------
        t_s : array_like, shape (N,)
            Non-decreasing sample times, not before the integrated time.
        repeats : int, optional
            Draw ``repeats`` independent sensor-noise realisations of the same
            run (measured arrays then have shape ``(repeats, N)``).

        Returns
        -------
        dict
            ``t``, ``v`` (speed over the interval), ``kappa_true`` (curvature
            over the interval, what the sensor measures before its errors),
            ``kappa_inst`` (curvature at ``t``), ``psi_true``, ``kappa_cmd``
            (the rate-limited command over the interval, before the steering
            gain) (N,), and the measured ``kappa``, ``psi`` ((N,) or
            (repeats, N)).
        """
        t = np.asarray(t_s, dtype=float)
        if t.ndim != 1 or t.size == 0 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
            raise DataError("t_s must be a non-empty, finite, non-decreasing 1-D array")
        if repeats is not None and (not isinstance(repeats, int) or repeats < 1):
            raise ConfigError(f"repeats must be an integer >= 1, got {repeats!r}")
        n = t.size
        k_true, k_inst, p_true, v = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        with self._lock:
            if t[0] < self._t - 1e-12:
                raise DataError(f"cannot record at t={t[0]} s: already integrated to {self._t} s")
            for i in range(n):  # sequential in time: integration
                ti = self._advance_locked(float(t[i]))
                k_true[i], v[i] = self._odometry_locked(ti)
                k_inst[i], p_true[i] = self._gain * self._kappa, self._psi
            shape = (n,) if repeats is None else (repeats, n)
            km, pm = self.sensors.measure(np.broadcast_to(k_true, shape), np.broadcast_to(p_true, shape),
                                          self.rng)
        return {"t": t.copy(), "v": v, "kappa_true": k_true, "kappa_inst": k_inst, "psi_true": p_true,
                "kappa_cmd": k_true / self._gain,
                "kappa": np.asarray(km, dtype=float), "psi": np.asarray(pm, dtype=float)}

    # -- internals --------------------------------------------------------------------
    def _check_speed(self, v_m_s) -> float:
        v = finite_number(v_m_s, "v_m_s")
        if not 0.0 <= v <= MAX_SPEED_M_S:
            raise ConfigError(f"v_m_s must be in [0, {MAX_SPEED_M_S}] m/s (reverse motion of a "
                              f"trailer is unstable), got {v_m_s!r}")
        return v

    def _target_at(self, t: float) -> float:
        return self._profile.at(t) if self._profile is not None else self._kappa_cmd

    def _advance_locked(self, t_s: float | None) -> float:
        target = float(self.clock.now()) if t_s is None else finite_number(t_s, "t_s")
        if target <= self._t:
            return self._t
        L1, L2, v, rate = self._L1, self._L2, self._v, self._rate
        n = max(1, math.ceil((target - self._t) / self._max_step))
        h = (target - self._t) / n
        x, y, th, p, t, k = self._x, self._y, self._theta, self._psi, self._t, self._kappa
        s0 = self._s
        tgt = self._target_at

        gain = self._gain

        def rates(th_, p_, kc_):
            k_ = gain * kc_  # path curvature
            return (v * math.cos(th_), v * math.sin(th_), v * k_,
                    v / L2 * (k_ * (L2 + L1 * math.cos(p_)) - math.sin(p_)))

        def rk4(h_, th_, p_, ka, kb_, kd):  # one step with the curvature ka -> kb_ -> kd (start, mid, end)
            a = rates(th_, p_, ka)
            b = rates(th_ + 0.5 * h_ * a[2], p_ + 0.5 * h_ * a[3], kb_)
            c = rates(th_ + 0.5 * h_ * b[2], p_ + 0.5 * h_ * b[3], kb_)
            d = rates(th_ + h_ * c[2], p_ + h_ * c[3], kd)
            return tuple(h_ / 6.0 * (a[j] + 2 * b[j] + 2 * c[j] + d[j]) for j in range(4))

        for _ in range(n):  # sequential in time: integration
            # actual curvature: rate-limited towards the target
            k_end = tgt(t + h)
            k1 = k + max(-rate * h, min(rate * h, k_end - k))
            if abs(k1 - k_end) < 1e-15 and abs(k - tgt(t)) < 1e-15:
                parts = ((h, k, tgt(t + 0.5 * h), k_end),)  # tracking: follow the profile exactly
            elif self._profile is None and abs(k1 - k_end) < 1e-15:
                # a set point the steering reaches inside this step: the ramp ends where the rate says
                # (at once for an unlimited rate), not at the step's end; then the set point holds
                d_ramp = min(h, abs(k_end - k) / rate)
                parts = ((d_ramp, k, 0.5 * (k + k_end), k_end), (h - d_ramp, k_end, k_end, k_end))
            else:  # at the rate limit throughout the step (linear in time)
                parts = ((h, k, 0.5 * (k + k1), k1),)
            for hp, ka, kb, kd in parts:
                if hp <= 0.0:
                    continue
                dx, dy, dth, dp = rk4(hp, th, p, ka, kb, kd)
                x, y, th, p = x + dx, y + dy, th + dth, p + dp
                k = kd
            t += h
        self._kappa = k
        self._s = s0 + v * (target - self._t)
        self._x, self._y, self._theta, self._psi, self._t = x, y, th, p, target
        return target


def record_commands(commands, *, L1_m: float = DEFAULT_L1_M, L2_m: float = DEFAULT_L2_M,
                    v_m_s: float = 1.0, noise=PATENT_NOISE_SIGMA, rng: np.random.Generator | None = None,
                    repeats: int | None = None, settle_s: float = 20.0, duration_s: float = 63.0,
                    rate_hz: float = 10.0, curvature_rate: float = 0.1,
                    steering_gain: float = 1.0) -> dict[str, np.ndarray]:
    """Offline run of a sequence of commands on a :class:`SimTrailer` (manual clock).

    Each command ``(kind, M)`` first holds its initial curvature for
    ``settle_s`` (so the joint angle starts settled), then runs its profile
    for ``duration_s``; samples every ``1/rate_hz`` s throughout, one
    continuous record.

    Returns
    -------
    dict
        As :meth:`SimTrailer.record`, plus ``segment`` (N,) int — index of the
        command, ``phase`` (N,) int — 0 settling, 1 profile, and ``t_profile``
        (N,) — time since the start of the segment's profile (negative while
        settling).
    """
    from fakes.sim.clock import ManualClock

    if not (isinstance(rate_hz, (int, float)) and 0 < rate_hz <= 1000):
        raise ConfigError(f"rate_hz must be in (0, 1000], got {rate_hz!r}")
    if not (isinstance(settle_s, (int, float)) and settle_s >= 0):
        raise ConfigError(f"settle_s must be >= 0, got {settle_s!r}")
    commands = list(commands)
    if not commands:
        raise ConfigError("commands must name at least one (kind, M)")
    clock = ManualClock()
    trailer = SimTrailer(clock, L1_m, L2_m, v_m_s, noise, rng, max_curvature_rate=curvature_rate,
                         steering_gain=steering_gain)
    dt = 1.0 / rate_hz
    n_settle = int(round(settle_s * rate_hz))
    n_prof = int(round(duration_s * rate_hz)) + 1
    parts = []
    t_now = 0.0
    for seg, (kind, M) in enumerate(commands):
        k0 = float(command_curvature(kind, M, np.array([0.0]))[0])
        trailer.command_curvature(k0, t_now)
        if n_settle:
            ts = t_now + dt * np.arange(n_settle)
            rec = trailer.record(ts, repeats)
            parts.append((rec, seg, 0, ts - (t_now + n_settle * dt)))
            t_now += n_settle * dt
        trailer.set_profile(kind, M, duration_s=(n_prof - 1) * dt, t0_s=t_now)
        ts = t_now + dt * np.arange(n_prof)
        rec = trailer.record(ts, repeats)
        parts.append((rec, seg, 1, ts - t_now))
        t_now = ts[-1] + dt
    out = {key: np.concatenate([p[0][key] for p in parts], axis=-1) for key in parts[0][0]}
    out["segment"] = np.concatenate([np.full(p[0]["t"].size, p[1]) for p in parts])
    out["phase"] = np.concatenate([np.full(p[0]["t"].size, p[2]) for p in parts])
    out["t_profile"] = np.concatenate([p[3] for p in parts])
    return out


__all__ = ["SimTrailer", "TrailerState", "SensorReading", "MAX_SPEED_M_S", "record_commands"]
