"""The robot interface procedures program against, whatever the controller.

Two kinds of robot connection exist in the station:

* the **program-upload controller** (:class:`drivers.controller.ControllerDriver`):
  a whole program in the controller's dialect (ABB RAPID, KUKA KRL) goes up
  by FTP, is selected, started and watched over Modbus TCP;
* the **UR cobot** (:class:`drivers.ur.URDriver`): URScript sent to the
  controller's script port, state read back from RTDE, program state from the
  dashboard (``ur_rtde``).

What a procedure sees is the same for both: **a program, run whole**. The
unit of motion is the station's dialect-neutral :class:`~station.programs.program.Program`
(moves to named joint or Cartesian targets at a fraction of the rated speed,
fine stops, dwells, counted cycles). The driver checks *every* move of it with
the safety gate from the joints the robot reports, renders it in its own
dialect (RAPID/KRL files; one URScript ``def`` program) and runs it, reporting
progress as a :class:`RobotStatus`-like object (moves done, cycles done) to
``on_status`` while it runs, and returning when the arm has come to rest on
the last target. A single move (:meth:`Robot.move_to`) is a one-move program.
Every move ends in a fine stop (ISO 9283 measures attained poses at rest):
the model has no blending zones, and none is offered here.
Streaming one command at a time is the UR driver's own lower layer
(``move_joint``/``move_linear``) and stays inside the driver: a procedure
never depends on which of the two a robot does.

Errors (:mod:`station.errors`): ``SafetyError`` (nothing sent), ``DeviceNotReady``
(powered off, protective stop before the start), ``DeviceFault`` (protective or
emergency stop, controller fault during the run; robot halted),
``ConnectionLost`` (link dropped; motion halted if possible), ``DeviceError``
(program refused or stopped), ``DeviceTimeout``. After any of them the robot
is left at rest with no program running, and a new session's :meth:`take_over`
makes it ready again where it is the station's to do so.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class RobotReadings:
    """The arm's own readings since the previous call, in time order (controller time).

    Attributes
    ----------
    t_s : ndarray, shape (N,)
        Controller timestamps, s.
    q_rad : ndarray, shape (N, 6)
        Measured joint angles.
    tcp_xyz_mm : ndarray, shape (N, 3)
        TCP position the controller computes from them (its nominal kinematics), base frame.
    dropped, missed : int
        Counted, never hidden: samples lost to full buffers, and controller periods with no sample
        between two that arrived (a UR streams 500 Hz; a host reading slower sees the newest only).
    """

    t_s: np.ndarray
    q_rad: np.ndarray
    tcp_xyz_mm: np.ndarray
    #: samples lost to full buffers, and controller periods without a sample (sent faster than read)
    dropped: int = 0
    missed: int = 0

    def __len__(self) -> int:
        return len(self.t_s)

    def columns(self) -> dict[str, np.ndarray]:
        """``t, q1..q6 (deg), x, y, z (mm)``: the columns a run's ``robot`` stream keeps."""
        out = {"t": self.t_s}
        q = np.degrees(self.q_rad)
        for j in range(6):
            out[f"q{j + 1}"] = q[:, j]
        for k, c in enumerate("xyz"):
            out[c] = self.tcp_xyz_mm[:, k]
        return out


@runtime_checkable
class Robot(Protocol):
    """What the procedures call on a robot (implemented by the controller and the UR driver).

    ``gate`` is the :class:`~station.safety.SafetyGate` every target passes
    before it is sent.
    """

    gate: Any

    def connect(self) -> Any:
        """Open the connections; the robot does not move."""

    def close(self) -> None:
        """Close every connection (idempotent)."""

    def take_over(self) -> tuple[str, str]:
        """Make the robot the station's: stop what an earlier (dead) session left running and clear
        the faults that session caused; refuse (``DeviceFault``) a fault whose cause a person must clear.
        Returns ``(state summary, what was taken over or "")``."""

    def release(self) -> None:
        """Leave the robot at rest with no program of the station's running (connections kept)."""

    def run(self, program, *, timeout_s: float, on_status: Callable[[Any], None] | None = None) -> Any:
        """Gate, send and run a :class:`~station.programs.program.Program` (or a rendered one) whole; block until
        the arm rests on its last target. ``on_status`` gets the progress (``moves_done``, ``cycle_count``,
        ``line``) while it runs; the time it takes (the caller's journal, a disk stalled in a sync) does not count
        against ``timeout_s``. Returns the final status."""

    def move_to(self, target, *, speed_frac: float = 0.2, interpolation: str = "joint",
                timeout_s: float = 60.0) -> Any:
        """One move to a joint target (6,) rad or a Cartesian (4, 4) pose / (3,) position, mm; gated."""

    def wait_settled(self, timeout_s: float) -> Any:
        """Block until no program of the station's runs and the arm is at rest; the state then."""

    def joints_rad(self) -> np.ndarray:
        """The measured joint angles now (the controller's encoders), rad."""

    def tcp_mm(self) -> np.ndarray:
        """The TCP position the controller reports now (its nominal kinematics), base frame, mm."""

    def fault_state(self) -> str | None:
        """None when the robot may move; otherwise why not (protective stop, e-stop, fault, ...)."""

    def readings(self) -> RobotReadings | None:
        """The arm's own readings since the previous call (None: this connection gives only point reads)."""

    def stop(self) -> Any:
        """Halt the arm and stop the program now (no gate needed to stop)."""


__all__ = ["Robot", "RobotReadings"]
