"""The pace of the lockstep fake cells in this suite.

The emScon tracker, the controller and the scanner fakes share one lockstep
:class:`~fakes.sim.clock.SimClock`: a seed gives the same samples, stops and
figures at any pace (``tests/sim/test_lockstep.py``), so the suite runs them
as fast as the station and the fakes go. A time scale is only an upper bound
on that pace; ``1e4`` never binds on this machine. Tests that need wall time
to act while a run moves (a signal at a random moment, a person's click, a
real-time client such as ``ur_rtde``) set their own.
"""

#: simulated seconds per real second at most, for lockstep cells
LOCKSTEP = 1e4

#: the UR fake's clock runs paced while ur_rtde (a real-time client) is served, not in lockstep: at 15x its
#: 500 Hz RTDE stream and the driver's sidecar keep up on a 2-core host beside two busy processes
UR = 15.0

#: a UR cell whose driver asks for the RTDE stream at 125 Hz (``ur://HOST?rtde_hz=125``, a CB3's rate; the
#: procedures read the joints at rest) sends a quarter of the packets per simulated second: at 40x that is
#: 5,000 packets per real second against 7,500 at 500 Hz and 15x
UR_RTDE_HZ = 125
UR_AT_RTDE_HZ = 40.0
