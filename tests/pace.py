"""The pace of the lockstep fake cells in this suite.

The emScon tracker, the controller and the scanner fakes share one lockstep
:class:`~fakes.sim.clock.SimClock`: a seed gives the same samples, stops and
figures at any pace (``tests/sim/test_lockstep.py``), so the suite runs them
as fast as the station and the fakes go. A time scale is only an upper bound
on that pace; ``1e4`` never binds on this machine. Tests that need wall time
to act while a run moves (a signal at a random moment, a person's click, a
real-time client such as ``ur_rtde``) set their own.
"""

from fakes.station import LOCKSTEP_RTDE_HZ

#: simulated seconds per real second at most, for lockstep cells
LOCKSTEP = 1e4

#: the UR fake's clock runs paced while ur_rtde (a real-time client) is served, not in lockstep: at 15x its
#: 500 Hz RTDE stream and the driver's sidecar keep up on a 2-core host beside two busy processes
UR = 15.0

#: a UR cell (lockstep) streams RTDE one data package at a time, each waiting for the driver to say it kept the
#: one before (``fakes.station.LOCKSTEP_RTDE_HZ``, 10 Hz; the procedures read the joints at rest); the stream
#: holds the clock, so a time scale only bounds the pace
UR_RTDE_HZ = LOCKSTEP_RTDE_HZ
UR_AT_RTDE_HZ = 40.0
