"""Laser tracker measurement model: what the instrument reports for a reflector.

Given the reflector's true position in the robot base frame, the model
returns what a tracker standing somewhere in the cell reports:

* **frame**: coordinates in the tracker's own frame. ``base_T_tracker`` is the
  tracker's pose in the robot base frame (unknown to the station, which finds
  it by registration): ``p_tracker = inv(base_T_tracker) . p_base``.
* **accuracy**: the maximum permissible error of a coordinate is specified as
  ``MPE(R) = a + b R`` (e.g. 15 um + 6 um/m, ``R`` the tracker-reflector
  distance), the usual form of tracker data sheets (ASME B89.4.19 /
  ISO 10360-10), read as a 2-sigma (k = 2) bound on each coordinate
  (``sigma(R) = (a + b R) / 2``, :meth:`TrackerModel.sigma_mm`). Within one
  measurement session it is a **systematic** error of the instrument's frame,
  drawn once from the seed: an offset (sd ``a / 2`` per coordinate), a scale
  error and three small angles (sd ``b / 2`` ppm and urad each), so a reading
  is ``(1 + s) p + omega x p + o``; it does not scatter from sample to sample.
* **reading noise**: white + slow wander (eq. (N1) of
  :mod:`station.models.tracker_noise`; default the measured Leica figures:
  0.6 um white, 2 um wander with a 1 s correlation time), per coordinate,
  whatever the distance. The wander is a Gauss-Markov process drawn by
  index (:mod:`fakes.sim.wander`).
* **time**: the device samples on its own grid ``t_dev = k / rate_hz``; its
  clock runs ``clock_offset_s`` ahead of the world's (``t_dev = t_sim +
  offset``), and each sample shows the reflector as it was ``latency_s``
  before its stamp (default the noise model's ``latency_s``). Noise is tied to the grid index ``k`` (block-seeded), so
  the same instant measured twice gives the same value and a stream does not
  depend on how it is chunked.
* **beam breaks**: scheduled intervals ``(t_start, t_end)`` (simulated time)
  and random ones (a Poisson process of ``random_breaks_per_hour`` with
  durations uniform in ``random_break_duration_s``, drawn per 60 s block
  from the seed, so they are reproducible). A sample inside a break is
  invalid: ``valid = False`` and NaN coordinates.

The rate must be within 10-3000 Hz (the station's supported tracker rates).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from typing import Callable

import numpy as np

from fakes.sim.wander import WanderDraws
from station.errors import ConfigError, DataError
from station.models.tracker_noise import TrackerNoise, default_tracker_noise
from station.numeric import finite_number
from station.tracker_rates import TRACKER_RATE_RANGE_HZ

__all__ = ["TrackerModel", "RATE_RANGE_HZ"]

#: supported output rates, Hz
RATE_RANGE_HZ = TRACKER_RATE_RANGE_HZ

_NOISE_BLOCK = 65536  # grid samples per noise block
_BREAK_BLOCK_S = 60.0  # seconds per random-break block
_CACHE = 8
_EPOCH_BLOCK = 4096  # samples per noise block of an epoch


def _check_transform(T, name: str) -> np.ndarray:
    try:
        arr = np.array(T, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"`{name}` must be a numeric (4, 4) transform: {exc}") from exc
    if arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"`{name}` must be a finite (4, 4) transform, got shape {arr.shape}")
    R = arr[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-9 or np.linalg.det(R) < 0 or np.any(arr[3] != [0, 0, 0, 1]):
        raise ConfigError(f"`{name}` must be a rigid transform (proper rotation, last row 0 0 0 1)")
    return arr


class TrackerModel:
    """Laser tracker measurement model (see the module docstring).

    Parameters
    ----------
    base_T_tracker : array_like, shape (4, 4)
        Tracker pose in the robot base frame (mm).
    rate_hz : float
        Output rate, 10-3000 Hz.
    mpe_a_um : float
        Constant term of the MPE, micrometres.
    mpe_b_um_per_m : float
        Distance term of the MPE, micrometres per metre.
    latency_s : float, optional
        Age of the position shown by a sample, relative to its stamp (>= 0;
        default the noise model's).
    clock_offset_s : float
        Device clock minus world clock, s.
    beam_breaks : iterable of (float, float)
        Scheduled breaks ``(t_start, t_end)`` in simulated time.
    random_breaks_per_hour : float
        Mean number of random breaks per hour (0: none).
    random_break_duration_s : (float, float)
        Range of random break durations.
    seed : int
        Seed of the noise, the systematic error and the random breaks.
    noise : TrackerNoise, optional
        Reading noise (default :func:`station.models.tracker_noise.default_tracker_noise`).
    systematic : bool
        Draw the session's systematic accuracy error (False: readings are true but for the noise).
    """

    def __init__(
        self,
        base_T_tracker,
        rate_hz: float = 1000.0,
        *,
        mpe_a_um: float = 15.0,
        mpe_b_um_per_m: float = 6.0,
        latency_s: float | None = None,
        clock_offset_s: float = 0.0,
        beam_breaks=(),
        random_breaks_per_hour: float = 0.0,
        random_break_duration_s=(0.05, 0.5),
        seed: int = 0,
        noise: TrackerNoise | None = None,
        systematic: bool = True,
    ) -> None:
        self.base_T_tracker = _check_transform(base_T_tracker, "base_T_tracker")
        self.tracker_T_base = np.linalg.inv(self.base_T_tracker)
        rate = finite_number(rate_hz, "rate_hz", positive=True)
        if not (RATE_RANGE_HZ[0] <= rate <= RATE_RANGE_HZ[1]):
            raise ConfigError(f"`rate_hz` must be within {RATE_RANGE_HZ[0]:g}-{RATE_RANGE_HZ[1]:g} Hz, got {rate_hz!r}")
        self.rate_hz = rate
        self.mpe_a_um = finite_number(mpe_a_um, "mpe_a_um", nonneg=True)
        self.mpe_b_um_per_m = finite_number(mpe_b_um_per_m, "mpe_b_um_per_m", nonneg=True)
        if noise is None:
            noise = default_tracker_noise()
        if not isinstance(noise, TrackerNoise):
            raise ConfigError(f"`noise` must be a TrackerNoise, got {type(noise).__name__}")
        self.noise = noise
        self.latency_s = noise.latency_s if latency_s is None else finite_number(latency_s, "latency_s", nonneg=True)
        self.clock_offset_s = finite_number(clock_offset_s, "clock_offset_s")
        self.random_breaks_per_hour = finite_number(random_breaks_per_hour, "random_breaks_per_hour", nonneg=True)
        try:
            lo, hi = (float(x) for x in random_break_duration_s)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"`random_break_duration_s` must be (min, max) seconds: {exc}") from exc
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
            raise ConfigError(f"`random_break_duration_s` must satisfy 0 < min <= max, got {random_break_duration_s!r}")
        self.random_break_duration_s = (lo, hi)
        if not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ConfigError(f"`seed` must be a non-negative integer, got {seed!r}")
        self.seed = int(seed)
        self._lock = threading.Lock()
        self._breaks = np.zeros((0, 2))
        for t0, t1 in beam_breaks:
            self.add_beam_break(t0, t1)
        self._noise_cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._break_cache: OrderedDict[int, np.ndarray] = OrderedDict()
        tau = 0.0 if noise.wander_tau_s is None else noise.wander_tau_s * self.rate_hz
        self._wander_grid = WanderDraws(self.seed, 4, tau, _NOISE_BLOCK)
        self._wander_epoch = WanderDraws(self.seed, 6, tau, _EPOCH_BLOCK, cache=4 * _CACHE)
        # the session's accuracy error: drawn once (its own stream of the seed), fixed for the session
        sys_rng = np.random.default_rng([self.seed, 5])
        self.systematic = bool(systematic)
        draw = sys_rng.standard_normal(7) if self.systematic else np.zeros(7)
        self.systematic_offset_mm = draw[:3] * self.mpe_a_um * 1e-3 / 2.0
        self.systematic_scale = float(draw[3]) * self.mpe_b_um_per_m * 1e-6 / 2.0
        self.systematic_rotvec_rad = draw[4:] * self.mpe_b_um_per_m * 1e-6 / 2.0

    # ------------------------------------------------------------ noise model
    def sigma_mm(self, distance_mm) -> np.ndarray:
        """1-sigma accuracy per coordinate at a distance: ``(a + b R) / 2`` in mm (the sd the session's
        systematic error is drawn with; the reading noise is :attr:`noise`)."""
        R_m = np.asarray(distance_mm, dtype=float) * 1e-3
        return (self.mpe_a_um + self.mpe_b_um_per_m * R_m) * 1e-3 / 2.0

    # ------------------------------------------------------------------ time
    def device_time(self, t_sim) -> np.ndarray:
        """Device timestamps of world times: ``t_sim + clock_offset_s``."""
        return np.asarray(t_sim, dtype=float) + self.clock_offset_s

    def sample_times(self, t_start: float, t_end: float) -> np.ndarray:
        """World times of the device's grid samples in ``[t_start, t_end)``.

        Sample ``k`` is stamped ``k / rate_hz`` on the device clock.
        """
        a = finite_number(t_start, "t_start")
        b = finite_number(t_end, "t_end")
        if b <= a:
            return np.zeros(0)
        k0 = math.ceil((a + self.clock_offset_s) * self.rate_hz - 1e-9)
        k1 = math.ceil((b + self.clock_offset_s) * self.rate_hz - 1e-9)
        return np.arange(k0, k1) / self.rate_hz - self.clock_offset_s

    def _grid_index(self, t_sim: np.ndarray) -> np.ndarray:
        return np.rint((t_sim + self.clock_offset_s) * self.rate_hz).astype(np.int64)

    def _noise_block(self, b: int) -> np.ndarray:
        with self._lock:
            blk = self._noise_cache.get(b)
            if blk is not None:
                self._noise_cache.move_to_end(b)
                return blk
        rng = np.random.default_rng([self.seed, 1, b + (1 << 40)])
        blk = rng.standard_normal((_NOISE_BLOCK, 3))
        with self._lock:
            self._noise_cache[b] = blk
            while len(self._noise_cache) > _CACHE:
                self._noise_cache.popitem(last=False)
        return blk

    def unit_noise(self, t_sim) -> np.ndarray:
        """Standard normal noise (N, 3) tied to the grid index of each time."""
        t = np.asarray(t_sim, dtype=float).reshape(-1)
        k = self._grid_index(t)
        blocks = np.floor_divide(k, _NOISE_BLOCK)
        out = np.empty((t.size, 3))
        for b in np.unique(blocks):  # one block per 65536 samples
            sel = blocks == b
            out[sel] = self._noise_block(int(b))[k[sel] - int(b) * _NOISE_BLOCK]
        return out

    # ------------------------------------------------------------ beam breaks
    def add_beam_break(self, t_start: float, t_end: float) -> None:
        """Schedule a beam break over ``[t_start, t_end)`` (simulated time)."""
        a = finite_number(t_start, "t_start")
        b = finite_number(t_end, "t_end")
        if b <= a:
            raise ConfigError(f"a beam break must end after it starts, got ({t_start!r}, {t_end!r})")
        with self._lock:
            self._breaks = np.concatenate([self._breaks, [[a, b]]])

    @property
    def beam_breaks(self) -> np.ndarray:
        """Scheduled breaks (M, 2)."""
        with self._lock:
            return self._breaks.copy()

    def random_breaks(self, t_start: float, t_end: float) -> np.ndarray:
        """Random breaks (M, 2) that overlap ``[t_start, t_end]``."""
        if self.random_breaks_per_hour <= 0 or t_end < t_start:
            return np.zeros((0, 2))
        lam = self.random_breaks_per_hour * _BREAK_BLOCK_S / 3600.0
        lo, hi = self.random_break_duration_s
        b0 = math.floor(t_start / _BREAK_BLOCK_S) - math.ceil(hi / _BREAK_BLOCK_S)
        b1 = math.floor(t_end / _BREAK_BLOCK_S)
        out = []
        for b in range(b0, b1 + 1):  # one entry per 60 s block
            with self._lock:
                blk = self._break_cache.get(b)
            if blk is None:
                rng = np.random.default_rng([self.seed, 2, b + (1 << 40)])
                n = rng.poisson(lam)
                starts = (b + rng.random(n)) * _BREAK_BLOCK_S
                blk = np.stack([starts, starts + rng.uniform(lo, hi, n)], axis=1) if n else np.zeros((0, 2))
                with self._lock:
                    self._break_cache[b] = blk
                    while len(self._break_cache) > 4 * _CACHE:
                        self._break_cache.popitem(last=False)
            out.append(blk)
        allb = np.concatenate(out) if out else np.zeros((0, 2))
        keep = (allb[:, 1] > t_start) & (allb[:, 0] <= t_end)
        return allb[keep]

    def broken(self, t_sim) -> np.ndarray:
        """True where the beam is broken at world time ``t_sim`` (N,)."""
        t = np.asarray(t_sim, dtype=float).reshape(-1)
        if t.size == 0:
            return np.zeros(0, dtype=bool)
        intervals = np.concatenate([self.beam_breaks, self.random_breaks(float(t.min()), float(t.max()))])
        if intervals.size == 0:
            return np.zeros(t.size, dtype=bool)
        order = np.argsort(intervals[:, 0])
        starts = intervals[order, 0]
        ends = np.maximum.accumulate(intervals[order, 1])
        i = np.searchsorted(starts, t, side="right") - 1
        return (i >= 0) & (t < ends[np.maximum(i, 0)])

    # ----------------------------------------------------------- measurement
    def to_tracker_frame(self, p_base_mm) -> np.ndarray:
        """Base-frame points (N, 3) in the tracker frame."""
        p = np.asarray(p_base_mm, dtype=float)
        T = self.tracker_T_base
        # element by element, not a matrix product: BLAS rounds a row differently by where it falls in the
        # batch, and the batches of a stream depend on the host's timing (a resumed run's sample differed by
        # one ulp under load); each point here is the same whatever batch carries it
        R = T[:3, :3]
        return p[:, :1] * R[:, 0] + p[:, 1:2] * R[:, 1] + p[:, 2:3] * R[:, 2] + T[:3, 3]

    def reading(self, p_tracker_mm) -> np.ndarray:
        """What the tracker reads, noise aside, for true tracker-frame points (N, 3): the session's systematic
        error ``(1 + s) p + omega x p + o`` applied (element by element, the same whatever batch holds a point)."""
        p = np.asarray(p_tracker_mm, dtype=float)
        w = self.systematic_rotvec_rad
        cross = np.stack([w[1] * p[:, 2] - w[2] * p[:, 1], w[2] * p[:, 0] - w[0] * p[:, 2],
                          w[0] * p[:, 1] - w[1] * p[:, 0]], axis=1)
        return p + self.systematic_scale * p + cross + self.systematic_offset_mm

    def unit_wander(self, t_sim) -> np.ndarray:
        """Unit-variance wander (N, 3) tied to the grid index of each time (:mod:`fakes.sim.wander`)."""
        t = np.asarray(t_sim, dtype=float).reshape(-1)
        return self._wander_grid.at(self._grid_index(t))

    def epoch_noise(self, t_sim, epoch, epoch_starts, keys: dict) -> tuple[np.ndarray, np.ndarray]:
        """Standard normal white noise and unit-variance wander ((N, 3) each) drawn per epoch and sample index
        within it.

        Sample ``i`` at ``t_sim[i]`` belongs to epoch ``epoch[i]`` (e.g. the
        arm's move in progress) with key ``keys[epoch[i]]`` (tuple of ints) that
        started at ``epoch_starts[i]``; its noise is drawn from the stream of
        ``(seed, key)`` at the index ``round((t - start) * rate_hz)``. The same
        epoch measured in another world of the same seed, at another time, gets
        the same noise: a resumed run's samples match those of the run left
        alone. Each index within an epoch is one independent white draw; the
        wander is one Gauss-Markov process per epoch (it starts afresh with a
        move: the arm is moving then).
        """
        t = np.asarray(t_sim, dtype=float).reshape(-1)
        rel = np.rint((t - np.asarray(epoch_starts, dtype=float)) * self.rate_hz).astype(np.int64)
        epoch = np.asarray(epoch).reshape(-1)
        blocks = np.floor_divide(rel, _EPOCH_BLOCK)
        out = np.empty((t.size, 3))
        wander = np.empty((t.size, 3))
        for e in np.unique(epoch):  # one pass per epoch and noise block in the batch (a few), not per sample
            in_e = epoch == e
            for b in np.unique(blocks[in_e]):
                sel = in_e & (blocks == b)
                out[sel] = self._epoch_block(keys[int(e)], int(b))[rel[sel] - int(b) * _EPOCH_BLOCK]
            wander[in_e] = self._wander_epoch.at(rel[in_e], tuple(int(v) for v in keys[int(e)]))
        return out, wander

    def _epoch_block(self, key: tuple, b: int) -> np.ndarray:
        ck = ("epoch", key, b)
        with self._lock:
            blk = self._noise_cache.get(ck)
            if blk is not None:
                self._noise_cache.move_to_end(ck)
                return blk
        blk = np.random.default_rng([self.seed, 3, *(int(v) + (1 << 40) for v in key), b + (1 << 40)]) \
            .standard_normal((_EPOCH_BLOCK, 3))
        with self._lock:
            self._noise_cache[ck] = blk
            while len(self._noise_cache) > 4 * _CACHE:
                self._noise_cache.popitem(last=False)
        return blk

    def measure(self, t_sim, position_fn: Callable[[np.ndarray], np.ndarray], *,
                noise_fn: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Measure the reflector at world times ``t_sim``.

        Parameters
        ----------
        t_sim : array_like, shape (N,)
            Sample times (normally :meth:`sample_times`).
        position_fn : callable
            ``position_fn(t (N,)) -> (N, 3)`` true reflector position in the
            robot base frame, mm.
        noise_fn : callable, optional
            ``noise_fn(t (N,)) -> ((N, 3), (N, 3))`` standard normal white
            noise and unit-variance wander (default :meth:`unit_noise` and
            :meth:`unit_wander`, per grid index).

        Returns
        -------
        xyz_mm : ndarray, shape (N, 3)
            Measured coordinates in the tracker frame; NaN where invalid.
        valid : ndarray of bool, shape (N,)
        """
        t = np.asarray(t_sim, dtype=float).reshape(-1)
        if not np.all(np.isfinite(t)):
            raise DataError("`t_sim` contains non-finite times")
        p_base = np.asarray(position_fn(t - self.latency_s), dtype=float).reshape(t.size, 3)
        p = self.to_tracker_frame(p_base)
        white, wander = (self.unit_noise(t), self.unit_wander(t)) if noise_fn is None else noise_fn(t)
        nz = self.noise
        xyz = self.reading(p) + (nz.white_um * 1e-3) * white + (nz.wander_um * 1e-3) * wander
        valid = ~self.broken(t)
        xyz[~valid] = np.nan
        return xyz, valid

    def describe(self) -> dict:
        """JSON-able description of the model (truth for people and tests)."""
        return {
            "base_T_tracker": self.base_T_tracker.tolist(),
            "rate_hz": self.rate_hz,
            "mpe_a_um": self.mpe_a_um,
            "mpe_b_um_per_m": self.mpe_b_um_per_m,
            "mpe_convention": "MPE = 2 sigma per coordinate, a systematic error of the session",
            "systematic": {"offset_mm": self.systematic_offset_mm.tolist(), "scale": self.systematic_scale,
                           "rotvec_rad": self.systematic_rotvec_rad.tolist()},
            "noise": self.noise.to_dict(),
            "latency_s": self.latency_s,
            "clock_offset_s": self.clock_offset_s,
            "beam_breaks": self.beam_breaks.tolist(),
            "random_breaks_per_hour": self.random_breaks_per_hour,
        }
