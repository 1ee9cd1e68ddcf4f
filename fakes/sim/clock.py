"""The simulated world's one clock.

Simulated time runs ``time_scale`` times faster than the host's monotonic
clock, so a 30-cycle ISO 9283 run (minutes of robot time) finishes in seconds.
Every fake and every simulated device reads time from the same ``SimClock``,
so their timestamps share one truth.
"""

from __future__ import annotations

import math
import threading
import time

from station.errors import ConfigError


class SimClock:
    """Simulated time in seconds, ``time_scale`` x faster than real time.

    Parameters
    ----------
    time_scale : float
        Simulated seconds per real second (> 0). 1.0 is real time.
    start : float
        Simulated time at construction, s.
    """

    def __init__(self, time_scale: float = 1.0, start: float = 0.0) -> None:
        if not (isinstance(time_scale, (int, float)) and math.isfinite(time_scale) and time_scale > 0):
            raise ConfigError(f"time_scale must be a finite number > 0, got {time_scale!r}")
        if not math.isfinite(start):
            raise ConfigError(f"start must be finite, got {start!r}")
        self._scale = float(time_scale)
        self._t0_sim = float(start)
        self._t0_real = time.monotonic()
        self._lock = threading.Lock()

    @property
    def time_scale(self) -> float:
        return self._scale

    def now(self) -> float:
        """Current simulated time, s."""
        return self._t0_sim + (time.monotonic() - self._t0_real) * self._scale

    def real_seconds(self, dt_sim: float) -> float:
        """Host seconds that ``dt_sim`` simulated seconds take."""
        return max(0.0, dt_sim) / self._scale

    def sleep(self, dt_sim: float) -> None:
        """Block for ``dt_sim`` simulated seconds."""
        if dt_sim > 0:
            time.sleep(dt_sim / self._scale)

    def sleep_until(self, t_sim: float, stop: threading.Event | None = None) -> bool:
        """Block until simulated time ``t_sim``; return False if ``stop`` was set first."""
        while True:
            left = t_sim - self.now()
            if left <= 0:
                return True
            real = left / self._scale
            if stop is not None:
                if stop.wait(min(real, 0.05)):
                    return False
            else:
                time.sleep(min(real, 0.05))

    def set_time_scale(self, time_scale: float) -> None:
        """Change the rate without a jump in simulated time."""
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise ConfigError(f"time_scale must be a finite number > 0, got {time_scale!r}")
        with self._lock:
            now_sim = self.now()
            self._t0_real = time.monotonic()
            self._t0_sim = now_sim
            self._scale = float(time_scale)


class ManualClock:
    """A clock that moves only when told: offline simulation and unit tests.

    Same interface as :class:`SimClock`; ``sleep`` and ``sleep_until`` advance
    the time at once instead of blocking.
    """

    time_scale = math.inf

    def __init__(self, start: float = 0.0) -> None:
        if not math.isfinite(start):
            raise ConfigError(f"start must be finite, got {start!r}")
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        return self._t

    def real_seconds(self, dt_sim: float) -> float:
        return 0.0

    def advance(self, dt_sim: float) -> None:
        if dt_sim < 0 or not math.isfinite(dt_sim):
            raise ConfigError(f"cannot advance a clock by {dt_sim!r} s")
        with self._lock:
            self._t += dt_sim

    def sleep(self, dt_sim: float) -> None:
        if dt_sim > 0:
            self.advance(dt_sim)

    def sleep_until(self, t_sim: float, stop: threading.Event | None = None) -> bool:
        with self._lock:
            self._t = max(self._t, float(t_sim))
        return True
