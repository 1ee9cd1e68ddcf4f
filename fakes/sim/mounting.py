"""One mounting in a simulated cell, and robots of one model exchanged on it (ISO 9283 7.8).

The mounting (the base plate or pedestal the robot is bolted to) has its own
frame; the tracker stands in the cell at ``mount_T_tracker``, drawn once per
cell as a world draws its tracker's pose (:func:`fakes.sim.world.draw_tracker_pose`).
A robot set on the plate sits off the plate's nominal by its base-mounting
offset ``mount_T_base``, drawn per robot (a translation and small angles: the
play of its bolts and dowels, the flatness under it), so the world of that
robot sees the tracker at ``base_T_tracker = inv(mount_T_base) mount_T_tracker``
(:meth:`Mounting.base_T_tracker`, the ``base_T_tracker`` of
:func:`~fakes.sim.world.make_world`) and a position ``p`` of its base frame
is ``mount_T_base p`` in the mounting's (:func:`in_mounting`): the truth the
station's exchangeability is compared with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fakes.sim.world import draw_tracker_pose, work_centre_mm
from station.models.robots import get_robot
from station.models.rotation import rotvec_to_matrix

__all__ = ["BASE_OFFSET_SD_MM", "BASE_YAW_SD_DEG", "BASE_TILT_SD_DEG", "Mounting", "draw_mounting",
           "draw_base_offset", "in_mounting"]

#: a robot's base on the plate: sd of its offset along each axis, mm, of its turn about the vertical and of its
#: tilts, deg (bolts through clearance holes, located by two dowels worn to a few tenths)
BASE_OFFSET_SD_MM = 0.3
BASE_YAW_SD_DEG = 0.02
BASE_TILT_SD_DEG = 0.005


@dataclass(frozen=True)
class Mounting:
    """A cell's mounting: the tracker's pose in the mounting's frame (4 x 4, mm)."""

    mount_T_tracker: np.ndarray

    def base_T_tracker(self, mount_T_base) -> np.ndarray:
        """The tracker's pose in the base frame of a robot set on the mounting at ``mount_T_base``."""
        return np.linalg.inv(np.asarray(mount_T_base, dtype=float)) @ self.mount_T_tracker


def draw_mounting(robot: str, rng: np.random.Generator) -> Mounting:
    """A cell for robots of model ``robot``: the tracker 2-4 m from the working volume (the plate's frame is the
    nominal base frame of a robot on it)."""
    return Mounting(draw_tracker_pose(work_centre_mm(get_robot(robot)), rng))


def draw_base_offset(rng: np.random.Generator) -> np.ndarray:
    """A robot's base on the plate, ``mount_T_base`` (4 x 4): offsets N(0, :data:`BASE_OFFSET_SD_MM`) along x, y,
    z, and a small rotation (a rotation vector) of tilts N(0, :data:`BASE_TILT_SD_DEG`) about x and y and a turn
    N(0, :data:`BASE_YAW_SD_DEG`) about z."""
    tilts = rng.normal(0.0, BASE_TILT_SD_DEG, 2)
    yaw = rng.normal(0.0, BASE_YAW_SD_DEG)
    T = np.eye(4)
    T[:3, :3] = rotvec_to_matrix(np.radians([tilts[0], tilts[1], yaw]))
    T[:3, 3] = rng.normal(0.0, BASE_OFFSET_SD_MM, 3)
    return T


def in_mounting(mount_T_base, p_base_mm) -> np.ndarray:
    """Positions (..., 3) of a robot's base frame in the mounting's frame, mm."""
    T = np.asarray(mount_T_base, dtype=float)
    return np.asarray(p_base_mm, dtype=float) @ T[:3, :3].T + T[:3, 3]
