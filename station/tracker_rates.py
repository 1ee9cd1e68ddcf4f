"""The tracker output rates the station supports, in one place.

Every front door and layer that takes a tracker rate (the config, ``station simulate``, the simulated
world and its tracker, the extraction of attained poses, the time base of a lab's file) checks it against
:data:`TRACKER_RATE_RANGE_HZ`; it sits at the bottom of the core so that the config takes it from below.
"""

#: the lowest and highest tracker output rate the station supports, Hz (seed 000 samples at 100 Hz; emScon
#: trackers stream up to 3000 Hz)
TRACKER_RATE_RANGE_HZ: tuple[float, float] = (10.0, 3000.0)

__all__ = ["TRACKER_RATE_RANGE_HZ"]
