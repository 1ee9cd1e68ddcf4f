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
slope 1 % low): ``u(s)^2 = se^2 + (s u_F_rel)^2``.

The residuals do not show a tracker's slow wander: over a loading that
takes a few of its correlation times, the wander's excursion rises and
falls with the load (both are humps in time) and goes into the slope,
leaving the residuals small (on the simulated cell, with 2 um of wander
correlated over 1 s, the slope's error was 1.6 times the residual
standard error). A hold of as many stationary points at the unloaded pose,
taken at the pace of the loading, measures the readings' variance ``s_h^2``
on that time scale; the wander's correlation time is not known, so the
noise's share of the slope is the largest over correlations ``rho^|i - j|``
between readings ``i`` and ``j`` of the loading (rho in [0, 1))::

    c = row of the slope in (A^T A)^-1 A^T      A = [1, F]
    se_noise^2 = s_h^2 max_rho sum_ij c_i c_j rho^|i - j|

A constant (rho -> 1) drops out with the intercept, and white noise is
rho = 0. The larger of ``se`` and ``se_noise`` stands for the scatter
(each holds the white noise; the sum would count it twice):
``u(s)^2 = max(se, se_noise)^2 + (s u_F_rel)^2``, ``U = k u`` with ``k``
Student's t at 95 % for the Welch-Satterthwaite degrees of freedom
(``n - 2`` for ``se``, ``3 (n_h - 1)`` for the hold's pooled variance, the
gauge's infinite).
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
from scipy import stats

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
    #: the hold's standard deviation of one reading (mm, per coordinate) and the slope's noise share from it
    #: (None without a hold); the coverage factor and its degrees of freedom
    hold_sd_mm: float | None = None
    noise_se_mm_per_N: float | None = None
    k: float = 2.0
    dof: float | None = None

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


def correlated_noise_factor(c) -> float:
    """``max over rho in [0, 1) of sum_ij c_i c_j rho^|i - j|`` for a reading weight vector ``c`` (its sum 0)."""
    from scipy.optimize import minimize_scalar

    c = np.asarray(c, dtype=float).reshape(-1)
    n = c.size
    lag = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    cc = np.outer(c, c)

    def neg(rho: float) -> float:
        return -float(np.sum(cc * rho ** lag))

    grid = np.linspace(0.0, 0.999, 200)
    best = grid[int(np.argmin([neg(r) for r in grid]))]
    res = minimize_scalar(neg, bounds=(max(0.0, best - 0.01), min(0.9999, best + 0.01)), method="bounded")
    return max(-float(res.fun), -neg(best), float(c @ c))


def direction_compliance(direction: str, load_N, position_mm, loading, *, u_F_rel: float = 0.005,
                         hold_mm=None) -> DirectionCompliance:
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
    hold_mm : array_like, shape (n_h, 3), optional
        Stationary points of the unloaded tool taken at the loading's pace (the tracker's scatter on the
        loading's time scale); None: the residuals alone.
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
    hold_sd = noise_se = None
    scatter, scatter_dof = se, float(dof)
    if hold_mm is not None:
        H = np.asarray(hold_mm, dtype=float)
        if H.ndim != 2 or H.shape[1] != 3 or H.shape[0] < 3 or not np.all(np.isfinite(H)):
            raise DataError(f"{direction}: the hold needs at least 3 finite points (n, 3), got shape {H.shape}")
        hold_dof = 3 * (H.shape[0] - 1)
        hold_sd = math.sqrt(float(np.sum((H - H.mean(axis=0)) ** 2)) / hold_dof)
        c = np.linalg.solve(A.T @ A, A.T)[1]
        noise_se = hold_sd * math.sqrt(correlated_noise_factor(c))
        if noise_se > se:
            scatter, scatter_dof = noise_se, float(hold_dof)
    uc = math.hypot(scatter, slope * u_F_rel)
    nu = uc ** 4 / (scatter ** 4 / scatter_dof) if scatter > 0 else math.inf
    k = float(stats.t.ppf(0.975, nu)) if math.isfinite(nu) else 2.0
    return DirectionCompliance(
        direction=direction, compliance_mm_per_N=slope, se_mm_per_N=se, u_mm_per_N=uc, U_mm_per_N=k * uc,
        hold_sd_mm=hold_sd, noise_se_mm_per_N=noise_se, k=k, dof=None if not math.isfinite(nu) else nu,
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
           "correlated_noise_factor",
           "characteristic_rows"]
