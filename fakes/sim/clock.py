"""The simulated world's one clock, in lockstep with every fake.

Every fake and every simulated device reads time from the same
:class:`SimClock`, so their timestamps share one truth. The clock does not
run on the host's wall clock; it is advanced, like the physics of a
software-in-the-loop simulator, only as far as every participant allows:

* **demands** (:meth:`SimClock.sleep_until`, :meth:`SimClock.schedule`): a
  fake that waits for a simulated instant (the controller's interpreter for
  the end of a move or dwell, the tracker for the end of a stationary
  measurement or of its initialisation) asks the clock to run up to it. The
  clock runs toward the earliest demand ahead of it and stops *exactly* on
  it. With no demand ahead a **lockstep** clock stands still: nothing in the
  cell is scheduled, so nothing changes while the station thinks, uploads a
  program or commits samples, however long the host takes for it;
* **caps** (:meth:`SimClock.producer`): a fake that produces a stream of
  simulated time (the tracker's samples, the UR's RTDE packages while the
  driver says which it kept) holds the clock at the end of what
  it has sent plus one packet. A late producer thread, or a consumer that
  stopped reading (the socket's buffers fill and the send blocks), stalls
  simulated time instead of losing samples or shortening a dwell.

``time_scale`` only paces the clock against the host's monotonic clock: it
never runs faster than ``time_scale`` simulated seconds per real second
(``math.inf``: as fast as the participants go), and a slower host only makes
it run slower; it never skips or shortens simulated time. A seed therefore
gives the same events at the same simulated instants, at any load and any
time scale.

A clock made with ``lockstep=False`` (the default when a fake or a test
builds one on its own) also has a standing demand at +inf: it runs on paced
against the wall whenever nothing caps it, as a real-time device does. A fake
driven by an outside real-time client (the UR fake's RTDE servo loop, the
odometry fake's NMEA line) keeps a lockstep clock running the same way while
it serves, with :meth:`SimClock.keep_running`.

:class:`ManualClock` moves only when told (offline simulation, unit tests).
"""

from __future__ import annotations

import itertools
import math
import threading
import time

from station.errors import ConfigError

#: longest host wait between two looks at the clock of a blocked waiter, s
_POLL_S = 0.01


def _check_scale(time_scale) -> float:
    if isinstance(time_scale, bool) or not isinstance(time_scale, (int, float)) or math.isnan(time_scale) \
            or time_scale <= 0:
        raise ConfigError(f"time_scale must be a number > 0 (inf: as fast as possible), got {time_scale!r}")
    return float(time_scale)


class Demand:
    """A scheduled instant the clock runs up to (:meth:`SimClock.schedule`); ``cancel()`` withdraws it."""

    def __init__(self, clock: "SimClock", key: int) -> None:
        self._clock, self._key = clock, key

    def cancel(self) -> None:
        self._clock._drop("_demands", self._key)


class Producer:
    """A fake that streams simulated time: the clock never passes :meth:`hold_until`'s instant.

    ``hold_until(t)`` after every send (``t``: the instant at which the next
    piece is due); ``release()`` when the stream ends.
    """

    def __init__(self, clock: "SimClock", key: int, name: str) -> None:
        self._clock, self._key, self.name = clock, key, name

    def hold_until(self, t_sim: float) -> None:
        self._clock._set("_caps", self._key, float(t_sim))

    def release(self) -> None:
        self._clock._drop("_caps", self._key)


class SimClock:
    """Simulated time in seconds, advanced in lockstep with the fakes (module docstring).

    Parameters
    ----------
    time_scale : float
        Most simulated seconds per real second (> 0; ``math.inf`` unpaced).
    start : float
        Simulated time at construction, s.
    lockstep : bool
        True: stand still while nothing is scheduled (the world's clock).
        False: run on paced whenever nothing caps it.
    """

    def __init__(self, time_scale: float = 1.0, start: float = 0.0, *, lockstep: bool = False) -> None:
        self._scale = _check_scale(time_scale)
        if not (isinstance(start, (int, float)) and math.isfinite(start)):
            raise ConfigError(f"start must be finite, got {start!r}")
        self._t = float(start)
        self._wall = time.monotonic()
        self._cond = threading.Condition(threading.Lock())
        self._keys = itertools.count()
        self._demands: dict[int, float] = {}
        self._caps: dict[int, float] = {}
        self.lockstep = bool(lockstep)
        if not self.lockstep:
            self._demands[next(self._keys)] = math.inf

    # ------------------------------------------------------------ reading
    @property
    def time_scale(self) -> float:
        return self._scale

    def now(self) -> float:
        """Current simulated time, s (advanced as far as the pace and the participants allow)."""
        with self._cond:
            return self._advance()

    def real_seconds(self, dt_sim: float) -> float:
        """Host seconds that ``dt_sim`` simulated seconds take at most at full pace."""
        return max(0.0, dt_sim) / self._scale

    def idle(self) -> bool:
        """True when nothing is scheduled ahead: a lockstep clock stands still."""
        with self._cond:
            return not any(d > self._t for d in self._demands.values())

    # ------------------------------------------------------------ the advance
    def _limit(self) -> float:
        ahead = [d for d in self._demands.values() if d > self._t]
        if not ahead:
            return self._t
        limit = min(ahead)
        if self._caps:
            limit = min(limit, min(self._caps.values()))
        return limit

    def _advance(self) -> float:
        """Move the clock toward its limit at no more than the pace (caller holds the lock)."""
        wall = time.monotonic()
        limit = self._limit()
        if limit > self._t:
            t = limit if math.isinf(self._scale) else self._t + (wall - self._wall) * self._scale
            if math.isfinite(t):  # unpaced and uncapped (a standing demand at inf) does not run away
                self._t = min(limit, t)
            spent = [k for k, d in self._demands.items() if d <= self._t]
            for k in spent:  # demands reached: their waiters return, scheduled ones are done
                del self._demands[k]
        self._wall = wall
        return self._t

    def _look_again_s(self, now: float) -> float:
        """Host seconds a waiter sleeps before it looks at the clock again (caller holds the lock): until
        the clock can be at its limit at full pace, at most :data:`_POLL_S`."""
        step = self._limit() - now
        return max(1e-4, _POLL_S if step <= 0 else min(_POLL_S, step / self._scale))

    def _set(self, table: str, key: int, value: float) -> None:
        with self._cond:
            self._advance()  # time passed so far is credited under the old limits
            getattr(self, table)[key] = value
            self._cond.notify_all()

    def _drop(self, table: str, key: int) -> None:
        with self._cond:
            self._advance()
            getattr(self, table).pop(key, None)
            self._cond.notify_all()

    # ------------------------------------------------------------ participants
    def schedule(self, t_sim: float) -> Demand:
        """Let the clock run up to ``t_sim`` without blocking (something in the world happens then)."""
        key = next(self._keys)
        self._set("_demands", key, float(t_sim))
        return Demand(self, key)

    def keep_running(self) -> Demand:
        """A standing demand: the clock runs on paced until the returned handle is cancelled."""
        return self.schedule(math.inf)

    def producer(self, name: str = "") -> Producer:
        """A stream of simulated time that holds the clock (see :class:`Producer`)."""
        return Producer(self, next(self._keys), name)

    # ------------------------------------------------------------ waiting
    def sleep(self, dt_sim: float) -> None:
        """Block for ``dt_sim`` simulated seconds."""
        if dt_sim > 0:
            self.sleep_until(self.now() + dt_sim)

    def sleep_until(self, t_sim: float, stop: threading.Event | None = None) -> bool:
        """Run the clock up to ``t_sim`` and block until it is there; False if ``stop`` was set first."""
        t_sim = float(t_sim)
        key = next(self._keys)
        with self._cond:
            self._demands[key] = t_sim
            self._cond.notify_all()
            try:
                while True:
                    now = self._advance()
                    if now >= t_sim:
                        return True
                    if stop is not None and stop.is_set():
                        return False
                    self._cond.wait(self._look_again_s(now))
            finally:
                self._demands.pop(key, None)
                self._cond.notify_all()

    def wait_for(self, t_sim: float, timeout_s: float) -> bool:
        """Block until the clock is at ``t_sim`` or ``timeout_s`` real seconds passed; True if it is there.

        Unlike :meth:`sleep_until` it asks nothing of the clock: a producer waits so for the instant of its
        next piece while others run the clock."""
        t_sim = float(t_sim)
        end = time.monotonic() + max(0.0, timeout_s)
        with self._cond:
            while True:
                now = self._advance()
                if now >= t_sim:
                    return True
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(min(left, self._look_again_s(now)))

    def set_time_scale(self, time_scale: float) -> None:
        """Change the pace without a jump in simulated time."""
        scale = _check_scale(time_scale)
        with self._cond:
            self._advance()
            self._scale = scale


def keep_running(clock) -> Demand | None:
    """``clock.keep_running()`` for a fake driven by an outside real-time client (None: a clock without it)."""
    fn = getattr(clock, "keep_running", None)
    return fn() if callable(fn) else None


def stop_running(demand: Demand | None) -> None:
    """Withdraw what :func:`keep_running` returned (None: nothing)."""
    if demand is not None:
        demand.cancel()


class ManualClock:
    """A clock that moves only when told: offline simulation and unit tests.

    Same interface as :class:`SimClock`; ``sleep`` and ``sleep_until`` advance
    the time at once instead of blocking; producers and demands are accepted
    and have no effect.
    """

    time_scale = math.inf
    lockstep = True

    def __init__(self, start: float = 0.0) -> None:
        if not math.isfinite(start):
            raise ConfigError(f"start must be finite, got {start!r}")
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        return self._t

    def real_seconds(self, dt_sim: float) -> float:
        return 0.0

    def idle(self) -> bool:
        return True

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

    def wait_for(self, t_sim: float, timeout_s: float) -> bool:
        return self._t >= float(t_sim)

    def schedule(self, t_sim: float) -> Demand:
        return Demand(self, 0)

    def keep_running(self) -> Demand:
        return Demand(self, 0)

    def producer(self, name: str = "") -> Producer:
        return Producer(self, 0, name)

    def _set(self, table: str, key: int, value: float) -> None:
        pass

    def _drop(self, table: str, key: int) -> None:
        pass
