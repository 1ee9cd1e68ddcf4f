"""Mode and state numbers of a UR controller (RTDE outputs ``robot_mode``, ``safety_mode``,
``runtime_state``, ``joint_mode``; the dashboard's ``robotmode``/``safetymode`` replies
print the names)."""

from __future__ import annotations

from enum import IntEnum


class RobotMode(IntEnum):
    NO_CONTROLLER = -1
    DISCONNECTED = 0
    CONFIRM_SAFETY = 1
    BOOTING = 2
    POWER_OFF = 3
    POWER_ON = 4
    IDLE = 5
    BACKDRIVE = 6
    RUNNING = 7
    UPDATING_FIRMWARE = 8


class SafetyMode(IntEnum):
    NORMAL = 1
    REDUCED = 2
    PROTECTIVE_STOP = 3
    RECOVERY = 4
    SAFEGUARD_STOP = 5
    SYSTEM_EMERGENCY_STOP = 6
    ROBOT_EMERGENCY_STOP = 7
    VIOLATION = 8
    FAULT = 9


class RuntimeState(IntEnum):
    STOPPED = 1
    PLAYING = 2
    PAUSED = 4


class JointMode(IntEnum):
    POWER_OFF = 238
    IDLE = 255
    RUNNING = 253


#: bits of ``safety_status_bits``
SAFETY_BIT_PROTECTIVE = 1 << 2
SAFETY_BITS_EMERGENCY = (1 << 5) | (1 << 6) | (1 << 7)

#: A simulated controller in lockstep with its world (the station's fake cells) streams RTDE one data package
#: at a time while a client owns ``input_double_register_{LOCKSTEP_STORED_REGISTER}``: the client writes there
#: the ``timestamp`` of the newest package it has kept, and the next one is sent (and the simulated clock let
#: past it) only then. So a client that keeps only the newest package (``ur_rtde``'s receive interface) still
#: sees every one, and which packages a run stores does not depend on the host. 22: the last register of
#: ``ur_rtde``'s ``RTDEIOInterface`` lower range (18-22). A real controller has no such rule.
LOCKSTEP_STORED_REGISTER = 22
