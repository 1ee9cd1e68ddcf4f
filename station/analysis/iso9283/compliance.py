"""ISO 9283 clause 10, static compliance: displacement per unit load, per direction of the base frame.

A load is applied at the mechanical interface (the tool) in steps up to the
rated load and back down, in each of +x, -x, +y, -y, +z, -z of the robot's
base frame; at each step the load (a force gauge in the load path) and the
tool's position (a tracker) are read. The arm's compliance in a direction
is the slope of the displacement *along that direction* against the load::

    d_i = u . (p_i - p_0)          mm, u the unit direction of the load
    d_i = a + s F_i + e_i          least squares over the loading and unloading steps
    compliance = s                 mm/N

``s`` carries its standard error from the fit's residuals (``n - 2``
degrees of freedom), which holds the instruments' noise and whatever the
line does not (hysteresis between loading and unloading), and the
gauge's relative uncertainty ``u_F_rel`` (a force read 1 % high gives a
slope 1 % low): ``u(s)^2 = se^2 + (s u_F_rel)^2``, ``U = 2 u`` (k = 2).
Hysteresis is stated too: the largest gap between the unloading and the
loading displacement at one load level.

The figure is :data:`COMPLIANCE` (one row per direction); pure functions,
arrays in, results out.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from station import characteristics as table
from station.errors import ConfigError, DataError, InsufficientDataError

#: the figure (its row of the characteristics table)
COMPLIANCE = table.get("compliance_mm_per_N", "compliance")

#: the directions of the test, base frame: name -> unit vector
DIRECTIONS: dict[str, tuple[float, float, float]] = {
    "+x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0), "+z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0),
}


#: how the station asks the operator for a load (the simulated operator of the fake cell reads it back)
_LOAD_PROMPT = ("Pull the tool along {direction} of the robot base frame until the force gauge reads "
                "{load:.0f} N, hold it still, then confirm")
_LOAD_PROMPT_RE = re.compile(r"along ([+-][xyz]) of the robot base frame until the force gauge reads "
                             r"(\d+(?:\.\d*)?) N")


def load_prompt(direction: str, load_N: float) -> str:
    """The operator's prompt for ``load_N`` newtons along ``direction`` (0: take every load off the tool)."""
    if direction not in DIRECTIONS:
        raise ConfigError(f"direction {direction!r} is not one of {', '.join(DIRECTIONS)}")
    return _LOAD_PROMPT.format(direction=direction, load=float(load_N))


def parse_load_prompt(message: str) -> tuple[str, float] | None:
    """``(direction, load_N)`` asked by a prompt of :func:`load_prompt`; None for any other prompt."""
    m = _LOAD_PROMPT_RE.search(message)
    return None if m is None else (m.group(1), float(m.group(2)))


def load_levels_N(rated_load_N: float, steps: int = 10) -> np.ndarray:
    """The load programme of one direction: 0, 1/steps, ..., 1 of the rated load and back down to 0, N."""
    if not (isinstance(rated_load_N, (int, float)) and math.isfinite(rated_load_N) and rated_load_N > 0):
        raise ConfigError(f"rated_load_N must be a number > 0, got {rated_load_N!r}")
    if not (isinstance(steps, int) and 2 <= steps <= 100):
        raise ConfigError(f"steps must be an integer within 2-100, got {steps!r}")
    up = np.linspace(0.0, float(rated_load_N), steps + 1)
    return np.concatenate([up, up[-2::-1]])


@dataclass(frozen=True)
class DirectionCompliance:
    """The compliance in one direction with its uncertainty and the data of its plot."""

    direction: str
    compliance_mm_per_N: float
    se_mm_per_N: float
    u_mm_per_N: float
    U_mm_per_N: float
    intercept_mm: float
    hysteresis_mm: float
    residual_sd_mm: float
    load_N: tuple[float, ...]
    displacement_mm: tuple[float, ...]
    #: True for a step on the way up (the first half), False on the way down
    loading: tuple[bool, ...]
    max_load_N: float

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


def direction_compliance(direction: str, load_N, position_mm, loading, *, u_F_rel: float = 0.005
                         ) -> DirectionCompliance:
    """The compliance in ``direction`` from one load programme.

    Parameters
    ----------
    direction : str
        A key of :data:`DIRECTIONS`.
    load_N : array_like, shape (n,)
        The gauge's reading at each step (the load's magnitude, N).
    position_mm : array_like, shape (n, 3)
        The tool's position at each step, base frame, mm; the first step is the unloaded reference.
    loading : array_like of bool, shape (n,)
        True on the way up, False on the way down.
    u_F_rel : float
        Relative standard uncertainty of the gauge's readings.
    """
    if direction not in DIRECTIONS:
        raise ConfigError(f"direction {direction!r} is not one of {', '.join(DIRECTIONS)}")
    F = np.asarray(load_N, dtype=float).reshape(-1)
    P = np.asarray(position_mm, dtype=float)
    up = np.asarray(loading, dtype=bool).reshape(-1)
    if P.shape != (F.size, 3) or up.size != F.size:
        raise DataError(f"{direction}: {F.size} loads need {F.size} positions (n, 3) and {F.size} loading flags, "
                        f"got {P.shape} and {up.size}")
    if not (np.all(np.isfinite(F)) and np.all(np.isfinite(P))):
        raise DataError(f"{direction}: a load or a position is not finite")
    if not (isinstance(u_F_rel, (int, float)) and 0 <= u_F_rel < 1):
        raise ConfigError(f"u_F_rel must be within [0, 1), got {u_F_rel!r}")
    if F.size < 4:
        raise InsufficientDataError(f"{direction}: {F.size} load steps; a slope and its standard error need 4")
    spread = float(np.ptp(F))
    if spread <= 0.0 or spread < 0.2 * float(np.max(np.abs(F))):
        raise InsufficientDataError(f"{direction}: the loads span {spread:.3g} N; no slope can be fitted")
    u = np.asarray(DIRECTIONS[direction])
    d = (P - P[0]) @ u
    A = np.column_stack([np.ones_like(F), F])
    coef, *_ = np.linalg.lstsq(A, d, rcond=None)
    resid = d - A @ coef
    dof = F.size - 2
    s2 = float(resid @ resid) / dof
    cov = s2 * np.linalg.inv(A.T @ A)
    slope, se = float(coef[1]), math.sqrt(max(float(cov[1, 1]), 0.0))
    uc = math.hypot(se, slope * u_F_rel)
    return DirectionCompliance(
        direction=direction, compliance_mm_per_N=slope, se_mm_per_N=se, u_mm_per_N=uc, U_mm_per_N=2.0 * uc,
        intercept_mm=float(coef[0]), hysteresis_mm=_hysteresis(F, d, up), residual_sd_mm=math.sqrt(s2),
        load_N=tuple(F.tolist()), displacement_mm=tuple(d.tolist()), loading=tuple(bool(b) for b in up),
        max_load_N=float(np.max(F)))


def _hysteresis(F: np.ndarray, d: np.ndarray, up: np.ndarray) -> float:
    """The largest |unloading - loading| displacement at one load, the loading branch interpolated, mm."""
    if not (up.any() and (~up).any()):
        return float("nan")
    order = np.argsort(F[up], kind="stable")
    Fu, du = F[up][order], d[up][order]
    down = ~up
    inside = (F[down] >= Fu[0]) & (F[down] <= Fu[-1])
    if not inside.any():
        return float("nan")
    gap = d[down][inside] - np.interp(F[down][inside], Fu, du)
    return float(np.max(np.abs(gap)))


def characteristic_rows(results: list[DirectionCompliance]) -> list[dict]:
    """The store's rows of :data:`COMPLIANCE`: one per direction (``pose`` is the direction)."""
    return [{"pose": r.direction, "name": COMPLIANCE.key, "value": r.compliance_mm_per_N, "unit": COMPLIANCE.unit,
             "limit": None, "passed": None} for r in results]


__all__ = ["DIRECTIONS", "COMPLIANCE", "load_prompt", "parse_load_prompt", "load_levels_N", "DirectionCompliance", "direction_compliance",
           "characteristic_rows"]
