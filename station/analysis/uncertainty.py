"""Measurement uncertainty of the ISO 9283 figures (GUM and GUM Supplement 1).

The measurand of each figure is the robot's characteristic, not the value of
this one sample: for AP, eq. (1), the distance from the commanded position to
the robot's true mean attained position; for RP, eq. (2), the limit of
``l_bar + 3 S_l`` over many cycles of the robot's true attained positions (a
perfect instrument in the true base frame).  The figure the station states is
the ISO estimator (eq. (1), (2), ...) computed on the n measured cycles; its
uncertainty says how far that figure may lie from the robot's characteristic.

The budget (:class:`Budget`) names every input:

* **instrument**: each coordinate of each measured point has an independent
  error of standard deviation ``sd(R) = (a + b R)`` (a stated sd) or
  ``(a + b R) / 2`` (a maximum permissible error read as a k = 2 bound, the
  convention of the simulated tracker ``fakes/sim/tracker.py``), ``R`` the
  tracker-reflector distance.  It is in the scatter of the stops (Type A) for
  the means, and it inflates every scatter figure (RP, RD, RT, orientation RP):
  the model takes it out of the robot's scatter (the deflation is part of the
  model, so the figure's bias is part of its uncertainty). Where no
  registration stands between the tracker and the commanded poses, it is also
  counted whole as a shift common to the stops of a pose (AP, AT): a tracker's
  accuracy is mostly a fixed error of its frame within a session, which no
  number of stops averages away (counted twice so, AP's U is a bound);
* **instrument, read apart** (``instrument_noise_um`` given): a tracker's
  accuracy is mostly a fixed error of its frame within one session (scale,
  offset, angles), and its readings scatter far less than it (eq. (N1) of
  :mod:`station.models.tracker_noise`: micrometres). Then each reading has
  the random error ``instrument_noise_um`` (what the scatter figures deflate
  by), and the accuracy ``sd(R)`` above is systematic: a shift common to the
  stops of a pose (for AP, as the registration's), and a scale error ``b``
  (per m, 1 sigma of ``b / 2`` ppm for an MPE) of every distance (AD). Read
  so it is a bound: a registration absorbs the offset and angles of the
  tracker's frame, which the budget still counts;
* **registration**: a rigid fit of n point pairs with residual rms ``r``
  leaves each point of the frame with a per-axis standard deviation
  ``s^2 (1/n + d^2 / sum d_i^2)``, ``s^2 = n r^2 / (3n - 6)`` the per-axis
  residual variance and ``d`` the distance from the fit's centroid: a shift
  common to every stop at a pose (systematic for AP, nothing for RP or AD);
* **registration's rotation** (orientation AP): an error ``delta`` of the
  fitted frame's rotation (a small rotation about the base axes) turns every
  measured orientation by ``delta``; the angles a, b, c of ``R = Rz(c) Ry(b)
  Rx(a)`` move by ``J^-1 delta``, ``J`` the columns ``Rz(c) Ry(b) x, Rz(c) y,
  z`` (the base-frame rotation of a unit step of each angle). Its covariance is
  stated (a jackknife of the fit) or, for a point-pair fit with base-frame
  points ``p_i`` about their centroid ``d_i``, ``s^2 (sum |d_i|^2 I - d_i
  d_i^T)^-1`` with ``s^2`` the per-axis residual variance above: fewer or
  closer points turn the frame more. Systematic, common to every stop and
  every pose (orientation AP), nothing for orientation RP, vAP or drift (a
  fixed rotation changes no scatter and no difference of two means);
* **sampling**: the finite number of cycles, by the posterior of the robot's
  mean and scatter given the n stops (a Type A evaluation in the sense of
  GUM S1 6.4.9: a multivariate t for the mean; the scale of the scatter by a
  scaled inverse chi-square with the effective degrees of freedom of
  :func:`scatter_draws`); at least :data:`MIN_STOPS` stops; the extraction window chooses one
  sample of a stop at rest, its residual motion is in the scatter of the stops;
  time stamps are quantised by the sample interval (PST, MPT);
* **temperature**: an uncertainty ``u_T`` of the air temperature of the
  tracker's refraction compensation gives a scale error of 0.93 ppm/K along
  the line of sight, common to every point.

Propagation is by Monte Carlo (GUM S1): ``trials`` draws of the inputs, with
a stated seed, vectorised.  Each trial gives a value of the measurand; the
standard uncertainty of the figure is the root-mean-square of (measurand -
figure) over the trials (the spread and the bias of the estimator both), the
expanded one ``U = k u`` with k = 2, and the 95 % probabilistically symmetric
coverage interval of the measurand is given beside it.  The first-order law
(GUM 5.1.2, and E.4.3 for the uncertainty of a standard deviation) is computed
too where it applies; the two are reported, and ``agree`` says whether they are
within 10 % of each other.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace

import numpy as np

from station.errors import ConfigError, DataError

#: refraction sensitivity of a tracker's distance to the air temperature, per K
AIR_PPM_PER_K = 0.93

#: default Monte Carlo trials (the relative sd of u from them is about 1 / sqrt(2 trials): 0.5 %)
DEFAULT_TRIALS = 20_000

#: MC and first-order law agree when within this fraction of each other
AGREE_FRACTION = 0.10

#: fewest stops for the Monte Carlo of a mean (a t with n - 1 >= 3 degrees of freedom has a finite variance)
MIN_STOPS = 4

#: directions on the unit sphere for the population RP (a Fibonacci lattice; the integrand is smooth)
_N_DIRS = 256


# --------------------------------------------------------------------------
# the budget
# --------------------------------------------------------------------------


#: largest instrument uncertainty term accepted, um (or um/m): 10 mm, far beyond any tracker's MPE
MAX_INSTRUMENT_UM = 10_000.0
#: largest uncertainty of the air temperature accepted, K (a tracker's weather station is good to a few tenths)
MAX_TEMPERATURE_U_K = 50.0


@dataclass(frozen=True)
class Budget:
    """The stated inputs of the uncertainty (units in the names).

    ``instrument_a_um`` + ``instrument_b_um_per_m`` x R is an MPE (k = 2
    bound, ``instrument_kind = "mpe"``) or a standard deviation (``"sd"``) of
    each coordinate.  ``tracker_origin_mm``: the tracker in the frame of the
    analysis (the origin when the stream is in the tracker's frame).
    ``registration_*``: the rigid fit the measurements were carried through
    (None: none, or a given transform whose uncertainty is not stated).
    """

    instrument_a_um: float = 15.0
    instrument_b_um_per_m: float = 6.0
    instrument_kind: str = "mpe"
    tracker_origin_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    registration_rms_mm: float | None = None
    registration_n: int | None = None
    registration_centroid_mm: tuple[float, float, float] | None = None
    registration_spread_mm2: float | None = None  # sum of squared distances of the pairs from their centroid
    #: the frame's own standard uncertainty at given points, ((x, y, z), sd per axis) each (e.g. a jackknife of
    #: the registration at the test poses): used at the nearest of them instead of the fit's rms
    registration_at_points: tuple | None = None
    #: covariance (3 x 3, deg^2) of the registered frame's small rotation about the base x, y, z axes (a
    #: jackknife of the fit, or :meth:`with_registration` from the point pairs): orientation AP's frame term
    registration_rotation_cov_deg2: tuple | None = None
    #: degrees of freedom of that covariance (3n - 6 of a point-pair fit, n - 1 of a jackknife; None: exact)
    registration_rotation_dof: float | None = None
    temperature_u_K: float = 0.0
    angle_sd_deg: float = 0.0  # instrument sd of a 6-DOF angle
    #: the reading noise of one sample (sd per coordinate, um; white and wander together): when given, the
    #: instrument's a + b R is a systematic error of the session and this the random one
    instrument_noise_um: float | None = None
    rate_hz: float | None = None  # time stamps' quantisation (PST, MPT)
    trials: int = DEFAULT_TRIALS
    seed: int = 0
    k: float = 2.0

    def __post_init__(self) -> None:
        for name, most in (("instrument_a_um", MAX_INSTRUMENT_UM), ("instrument_b_um_per_m", MAX_INSTRUMENT_UM),
                           ("temperature_u_K", MAX_TEMPERATURE_U_K), ("angle_sd_deg", 90.0)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= most):
                raise ConfigError(f"uncertainty budget: {name} must be within 0-{most:g}, got {v!r}")
        if self.instrument_noise_um is not None and not (
                isinstance(self.instrument_noise_um, (int, float)) and math.isfinite(self.instrument_noise_um)
                and 0 <= self.instrument_noise_um <= MAX_INSTRUMENT_UM):
            raise ConfigError(f"uncertainty budget: instrument_noise_um must be within 0-{MAX_INSTRUMENT_UM:g}, "
                              f"got {self.instrument_noise_um!r}")
        if self.instrument_kind not in ("mpe", "sd"):
            raise ConfigError(f"uncertainty budget: instrument_kind must be 'mpe' or 'sd', got {self.instrument_kind!r}")
        if not (isinstance(self.trials, (int, np.integer)) and 200 <= self.trials <= 10_000_000):
            raise ConfigError(f"uncertainty budget: trials must be an integer in 200..10000000, got {self.trials!r}")
        if not (isinstance(self.seed, (int, np.integer)) and self.seed >= 0):
            raise ConfigError(f"uncertainty budget: seed must be a non-negative integer, got {self.seed!r}")
        if not (math.isfinite(self.k) and self.k > 0):
            raise ConfigError(f"uncertainty budget: k must be > 0, got {self.k!r}")
        if self.rate_hz is not None and not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ConfigError(f"uncertainty budget: rate_hz must be > 0, got {self.rate_hz!r}")
        if self.registration_rotation_cov_deg2 is not None:
            c = np.asarray(self.registration_rotation_cov_deg2, dtype=float)
            if c.shape != (3, 3) or not np.all(np.isfinite(c)) or np.any(np.diag(c) < 0) \
                    or not np.allclose(c, c.T, rtol=1e-9, atol=1e-15):
                raise ConfigError("uncertainty budget: registration_rotation_cov_deg2 must be a finite symmetric "
                                  f"3 x 3 covariance (deg^2), got {self.registration_rotation_cov_deg2!r}")
        d = self.registration_rotation_dof
        if d is not None and not (isinstance(d, (int, float)) and math.isfinite(d) and d > 0):
            raise ConfigError(f"uncertainty budget: registration_rotation_dof must be > 0, got {d!r}")

    # -- the instrument -------------------------------------------------
    def accuracy_sd_mm(self, points_mm) -> np.ndarray:
        """Per-coordinate standard deviation of the instrument's accuracy at each of ``points_mm`` (..., 3), mm:
        ``a + b R`` (an sd) or its half (an MPE)."""
        p = np.asarray(points_mm, dtype=float)
        R_m = np.linalg.norm(p - np.asarray(self.tracker_origin_mm), axis=-1) / 1000.0
        v_um = self.instrument_a_um + self.instrument_b_um_per_m * R_m
        return v_um / 1000.0 / (2.0 if self.instrument_kind == "mpe" else 1.0)

    def instrument_sd_mm(self, points_mm) -> np.ndarray:
        """Per-coordinate standard deviation of the random error of one measured point at each of
        ``points_mm`` (..., 3), mm: the reading noise when stated, else the accuracy."""
        if self.instrument_noise_um is not None:
            p = np.asarray(points_mm, dtype=float)
            return np.full(p.shape[:-1], self.instrument_noise_um / 1000.0)
        return self.accuracy_sd_mm(points_mm)

    def systematic_sd_mm(self, points_mm) -> np.ndarray:
        """Per-coordinate standard deviation of the instrument's systematic error at each point, mm: its
        accuracy, a fixed error of its frame within a session, common to the stops of a pose (AP, AT).

        Counted when the reading noise is stated apart (then a bound), and when no registration stands
        between the tracker and the commanded poses (a file whose poses are in the tracker's frame: nothing
        absorbs the frame's error). With a registration fitted on points the same tracker measured, and the
        reading noise unstated, 0: the fit absorbs the frame's offset and angles, and the accuracy is read as
        the readings' random error."""
        registered = self.registration_rms_mm is not None or bool(self.registration_at_points)
        if self.instrument_noise_um is None and registered:
            return np.zeros(np.asarray(points_mm, dtype=float).shape[:-1])
        return self.accuracy_sd_mm(points_mm)

    def systematic_scale_sd(self) -> float:
        """Standard deviation of the instrument's scale error common to every distance (dimensionless): the
        distance term ``b`` (um/m = ppm; halved for an MPE) when the reading noise is stated apart, else 0."""
        if self.instrument_noise_um is None:
            return 0.0
        return self.instrument_b_um_per_m * 1e-6 / (2.0 if self.instrument_kind == "mpe" else 1.0)

    # -- the registration -----------------------------------------------
    def registration_sd_mm(self, points_mm) -> np.ndarray:
        """Per-axis standard deviation of the frame at each point (...,), mm (0 without a fit)."""
        p = np.asarray(points_mm, dtype=float)
        if self.registration_at_points:
            q = np.array([a for a, _ in self.registration_at_points], dtype=float)
            sd = np.array([b for _, b in self.registration_at_points], dtype=float)
            near = np.argmin(np.linalg.norm(p[..., None, :] - q, axis=-1), axis=-1)
            return sd[near]
        if self.registration_rms_mm is None or not self.registration_n or self.registration_n < 3:
            return np.zeros(p.shape[:-1])
        n = int(self.registration_n)
        s2 = n * self.registration_rms_mm ** 2 / max(3 * n - 6, 1)
        var = np.full(p.shape[:-1], s2 / n)
        if self.registration_centroid_mm is not None and self.registration_spread_mm2:
            d2 = np.sum((p - np.asarray(self.registration_centroid_mm)) ** 2, axis=-1)
            var = var + s2 * d2 / self.registration_spread_mm2
        return np.sqrt(var)

    def registration_angle_sd_deg(self, abc_rad) -> np.ndarray:
        """Standard uncertainty (3,), deg, of the angles a, b, c of an orientation ``abc_rad`` (R = Rz(c) Ry(b)
        Rx(a)) from the registered frame's rotation (zeros without a stated one).

        A rotation ``delta`` (base axes) of the frame turns a measured orientation into ``exp([delta]) R``;
        to first order its angles move by ``J^-1 delta``, the columns of ``J`` the base-frame rotations of a unit
        step of a, b and c: ``Rz(c) Ry(b) x``, ``Rz(c) y``, ``z``. Infinite at b = +/-90 deg (a and c are not
        defined there)."""
        if self.registration_rotation_cov_deg2 is None:
            return np.zeros(3)
        _, b, c = (float(v) for v in np.asarray(abc_rad, dtype=float).reshape(3))
        cb, sb, cc, sc = math.cos(b), math.sin(b), math.cos(c), math.sin(c)
        J = np.array([[cc * cb, -sc, 0.0], [sc * cb, cc, 0.0], [-sb, 0.0, 1.0]])
        if abs(cb) < 1e-9:
            return np.full(3, math.inf)
        Ji = np.linalg.inv(J)
        cov = Ji @ np.asarray(self.registration_rotation_cov_deg2, dtype=float) @ Ji.T
        return np.sqrt(np.clip(np.diag(cov), 0.0, None))

    # -- the temperature ------------------------------------------------
    def scale_sd(self) -> float:
        """Standard deviation of the common scale error from the air temperature (dimensionless)."""
        return AIR_PPM_PER_K * 1e-6 * self.temperature_u_K

    def with_registration(self, reg, base_points_mm=None) -> "Budget":
        """This budget for measurements carried through ``reg`` (a
        :class:`~station.analysis.registration.Registration`; None: unchanged).

        The tracker's origin moves into the base frame; a fitted registration
        (residuals present) adds its rms and number of pairs, and with the
        pairs' base-frame points ``base_points_mm`` their centroid and spread
        (the rotation's share) and the covariance of the frame's rotation,
        ``s^2 (sum |d_i|^2 I - d_i d_i^T)^-1`` (:func:`rigid_fit_rotation_cov_rad2`).
        A given transform without residuals adds no registration term (its
        uncertainty is not stated).
        """
        if reg is None:
            return self
        origin = np.asarray(reg.to_base(np.zeros((1, 3))))[0]
        out = replace(self, tracker_origin_mm=tuple(float(x) for x in origin))
        if getattr(reg, "n", 0) < 3 or not len(getattr(reg, "residuals_mm", ())):
            return out
        cen = spread = rot = None
        if base_points_mm is not None:
            b = np.asarray(base_points_mm, dtype=float)
            c = b.mean(axis=0)
            cen, spread = tuple(float(x) for x in c), float(np.sum((b - c) ** 2))
            cov = np.degrees(np.degrees(rigid_fit_rotation_cov_rad2(b, float(reg.rms_mm))))
            rot = tuple(tuple(float(x) for x in row) for row in cov)
        return replace(out, registration_rms_mm=float(reg.rms_mm), registration_n=int(reg.n),
                       registration_centroid_mm=cen, registration_spread_mm2=spread,
                       registration_rotation_cov_deg2=rot,
                       registration_rotation_dof=None if rot is None else float(3 * int(reg.n) - 6))

    def to_dict(self) -> dict:
        return {
            "instrument": {"a_um": self.instrument_a_um, "b_um_per_m": self.instrument_b_um_per_m,
                           "kind": self.instrument_kind,
                           "meaning": ("maximum permissible error of a coordinate, read as a k = 2 bound"
                                       if self.instrument_kind == "mpe" else "standard deviation of a coordinate"),
                           "tracker_origin_mm": list(self.tracker_origin_mm),
                           "reading_noise_um": self.instrument_noise_um,
                           "accuracy_read_as": (("random per reading" if self.registration_rms_mm is not None
                                                 or self.registration_at_points else
                                                 "random per reading in the scatter figures, and systematic for AP "
                                                 "(no registration; a bound)")
                                                if self.instrument_noise_um is None else
                                                "a systematic error of the session; the reading noise is random")},
            "registration": None if self.registration_rms_mm is None and not self.registration_at_points else {
                "rms_mm": self.registration_rms_mm, "n_pairs": self.registration_n,
                "sd_at_points_mm": None if not self.registration_at_points else
                [[list(a), b] for a, b in self.registration_at_points]},
            "registration_rotation_sd_deg": None if self.registration_rotation_cov_deg2 is None else [
                float(math.sqrt(max(self.registration_rotation_cov_deg2[i][i], 0.0))) for i in range(3)],
            "temperature_u_K": self.temperature_u_K,
            "angle_sd_deg": self.angle_sd_deg,
            "rate_hz": self.rate_hz,
            "method": "GUM S1 Monte Carlo, checked against the GUM first-order law",
            "trials": int(self.trials), "seed": int(self.seed), "k": self.k,
        }


def rigid_fit_rotation_cov_rad2(base_points_mm, rms_mm: float) -> np.ndarray:
    """Covariance (3, 3), rad^2, of the rotation of a rigid point-pair fit about the base axes: ``s^2 (sum
    |d_i|^2 I - d_i d_i^T)^-1`` (the normal equations of the linearised fit), ``d_i`` the base-frame points
    about their centroid and ``s^2 = n rms^2 / (3n - 6)`` the per-axis residual variance.

    Raises DataError for fewer than 3 points or collinear ones (the rotation about their line is free)."""
    b = np.asarray(base_points_mm, dtype=float)
    n = b.shape[0]
    d = b - b.mean(axis=0)
    N = np.sum(d * d) * np.eye(3) - d.T @ d
    w = np.linalg.eigvalsh(N)
    if n < 3 or not w[0] > 1e-9 * max(float(w[-1]), 1e-300):
        raise DataError(f"registration points: {n} point(s), collinear or too few: the rotation is not determined")
    s2 = n * float(rms_mm) ** 2 / max(3 * n - 6, 1)
    return s2 * np.linalg.inv(N)


_TRACKER_RE = re.compile(r"^\s*(?:(mpe|sd)\s*:)?\s*([0-9.eE+-]+?)\s*(?:\+\s*([0-9.eE+-]+)\s*/\s*m)?\s*$")


def parse_tracker_uncertainty(text: str) -> dict:
    """``"15+6/m"`` (an MPE in um and um/m) or ``"sd:7.5+3/m"`` -> Budget keyword arguments."""
    m = _TRACKER_RE.match(text or "")
    if not m:
        raise ConfigError(f"--tracker-uncertainty must be like 15+6/m (MPE, um + um/m) or sd:7.5+3/m, got {text!r}")
    kind = m.group(1) or "mpe"
    try:
        a = float(m.group(2))
        b = float(m.group(3)) if m.group(3) is not None else 0.0
    except ValueError:
        raise ConfigError(f"--tracker-uncertainty must be like 15+6/m (MPE, um + um/m; the distance term ends in "
                          f"/m) or sd:7.5+3/m, got {text!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and a >= 0 and b >= 0 and a + b > 0):
        raise ConfigError(f"--tracker-uncertainty: the terms must be finite, >= 0 and not both 0, got {text!r}")
    return {"instrument_a_um": a, "instrument_b_um_per_m": b, "instrument_kind": kind}


# --------------------------------------------------------------------------
# the result of one figure
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class FigureUncertainty:
    """The uncertainty of one figure (units of the figure: mm, s or deg).

    ``u``/``U``: Monte Carlo, ``U = k u``; ``u_gum``: the first-order law (None
    where it does not apply); ``interval``: the 95 % coverage interval of the
    measurand; ``components``: each input's standard uncertainty at the figure
    (first order), for the budget table.
    """

    characteristic: str
    subject: str
    value: float
    u: float
    U: float
    k: float
    u_gum: float | None
    interval: tuple[float, float]
    components: dict = field(default_factory=dict)
    n: int = 0
    trials: int = 0
    seed: int = 0
    note: str = ""
    #: effective degrees of freedom of the first-order u (Welch-Satterthwaite, GUM G.4.1); None: infinite
    dof_gum: float | None = None

    @property
    def U_gum(self) -> float | None:
        """The first-order expanded uncertainty: ``t_95(dof) u_gum`` (GUM G.4), 1.96 u_gum with infinite dof."""
        if self.u_gum is None:
            return None
        from scipy.stats import t as student_t

        kp = 1.959964 if self.dof_gum is None or not math.isfinite(self.dof_gum) else float(
            student_t.ppf(0.975, max(self.dof_gum, 1.0)))
        return kp * self.u_gum

    @property
    def agree(self) -> bool | None:
        """The Monte Carlo U and the first-order U (with its t factor) within 10 % of each other."""
        Ug = self.U_gum
        if Ug is None:
            return None
        return abs(self.U - Ug) <= AGREE_FRACTION * max(self.U, Ug, 1e-15)

    def to_dict(self) -> dict:
        unit = self.characteristic.rsplit("_", 1)[-1]
        r = _r
        return {"characteristic": self.characteristic, "subject": self.subject, "value": r(self.value),
                f"u_{unit}": r(self.u), f"U_{unit}": r(self.U), "k": self.k,
                f"u_gum_{unit}": r(self.u_gum), f"U_gum_{unit}": r(self.U_gum), "dof_gum": r(self.dof_gum, 2),
                "agree": self.agree,
                f"interval_{unit}": [r(self.interval[0]), r(self.interval[1])], "coverage": 0.95,
                "components": {c: r(v) for c, v in self.components.items()}, "n": self.n,
                "trials": self.trials, "seed": self.seed, "note": self.note}


def _r(x, nd=7):
    if x is None:
        return None
    x = float(x)
    return round(x, nd) if math.isfinite(x) else None


def welch_satterthwaite(parts) -> float | None:
    """Effective degrees of freedom of ``sqrt(sum u_i^2)`` from ``[(u_i, dof_i)]`` (None: infinite)."""
    u2 = sum(u * u for u, _ in parts)
    den = sum(u ** 4 / d for u, d in parts if d is not None and math.isfinite(d) and d > 0 and u > 0)
    if den <= 0:
        return None
    return u2 * u2 / den


def _summary(ch, subj, value, draws, budget: Budget, u_gum, components, n, note="",
             dof=None) -> FigureUncertainty:
    draws = np.asarray(draws, dtype=float)
    u = float(np.sqrt(np.mean((draws - value) ** 2)))
    lo, hi = np.quantile(draws, [0.025, 0.975])
    return FigureUncertainty(ch, subj, float(value), u, budget.k * u, budget.k,
                             None if u_gum is None else float(u_gum), (float(lo), float(hi)),
                             {k: float(v) for k, v in components.items()}, int(n), int(budget.trials),
                             int(budget.seed), note, None if dof is None else float(dof))


# --------------------------------------------------------------------------
# draws of the inputs
# --------------------------------------------------------------------------


def _points(x, name):
    a = np.asarray(x, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
        raise DataError(f"{name} must be finite with shape (n, 3), got {a.shape}")
    return a


def scatter_draws(S: np.ndarray, n: int, M: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Draws ``(f (M,), lam (3,))``: the population covariance's eigenvalues are ``f lam``; the eigenvalues of the population covariance behind a sample covariance ``S`` of n points.

    The shape is the sample's; the scale has the posterior ``nu s^2 / chi^2_nu`` of a variance with the
    effective degrees of freedom of the trace, ``nu = (n - 1) tr(S)^2 / tr(S^2)`` (Welch-Satterthwaite,
    GUM G.4.1: between n - 1 for a scatter along one line and 3 (n - 1) for an isotropic one).  An inverse
    Wishart with n - 1 degrees of freedom has no finite mean below 5 stops, so it is not used.
    """
    lam = np.clip(np.linalg.eigvalsh(S), 0.0, None)
    tr, tr2 = float(lam.sum()), float(np.sum(lam ** 2))
    nu = (n - 1) * tr * tr / tr2 if tr2 > 0 else 3.0 * (n - 1)
    return nu / rng.chisquare(nu, size=M), lam


def robot_rp(trace: np.ndarray, lam: np.ndarray, noise_var: float) -> np.ndarray:
    """The robot's RP for measured scatters of total variance ``trace`` (M,), shape ``lam`` (3,), noise ``noise_var``.

    The instrument's noise adds ``noise_var`` to every axis, so the robot's total variance is
    ``trace - 3 noise_var`` (clipped at 0), an unbiased deflation.  Its shape is that of ``lam - noise_var``
    (clipped; isotropic when nothing is left): the sample's eigenvalues spread wider than the population's,
    so taking the noise out of each one would leave a robot where there is only noise.  RP scales with the
    square root of the variance: ``sqrt(trace_robot) * population_rp(shape)``.
    """
    shape = np.clip(np.asarray(lam, dtype=float) - noise_var, 0.0, None)
    if shape.sum() <= 0:
        shape = np.ones(3)
    shape = shape / shape.sum()
    tr_r = np.clip(np.asarray(trace, dtype=float) - 3.0 * noise_var, 0.0, None)
    return np.sqrt(tr_r) * float(population_rp(shape))


def _mean_t_draws(x: np.ndarray, M: int, rng, floor_var: float) -> np.ndarray:
    """Draws (M, 3) of the population mean behind ``x`` (n >= 2): the multivariate t of GUM S1 6.4.9."""
    n = x.shape[0]
    nu = n - 1
    S = np.cov(x.T, ddof=1) + floor_var * np.eye(3)
    L = np.linalg.cholesky(S / n)
    z = rng.standard_normal((M, 3)) @ L.T
    return x.mean(axis=0) + z * np.sqrt(nu / rng.chisquare(nu, size=M))[:, None]


def _mean_scalar_draws(mean: float, s: float, n: int, dof: float, M: int, rng, noise_sd: float = 0.0) -> np.ndarray:
    """Draws (M,) of the population mean behind n observations of mean ``mean`` and sd ``s``: the scaled t of
    GUM S1 6.4.9 with ``dof`` degrees of freedom, drawn as ``mean + sigma / sqrt(n) z`` with the population sd
    ``sigma = s sqrt(dof / chi^2_dof)``.  ``noise_sd`` > 0: the instrument's stated noise in each observation,
    which the population sd cannot be below (the observations carry it): a draw of ``sigma`` under it is
    raised to it.  A few stops that happen to agree then do not state the mean better than the instrument
    reads; with ``noise_sd`` = 0 the draws are the plain t's."""
    if noise_sd <= 0.0:
        return mean + s / math.sqrt(n) * rng.standard_t(dof, size=M)
    sigma = np.maximum(s * np.sqrt(dof / rng.chisquare(dof, size=M)), noise_sd)
    return mean + sigma / math.sqrt(n) * rng.standard_normal(M)


def _floored_sampling(s: float, n: int, dof: float, noise_sd: float) -> tuple[float, float | None]:
    """First-order sampling term of a mean of n observations of sd ``s`` and its degrees of freedom: the
    instrument's stated noise ``noise_sd`` where the scatter is below it (a specification: infinite dof)."""
    if noise_sd > 0.0 and s < noise_sd:
        return noise_sd / math.sqrt(n), None
    return s / math.sqrt(n), dof


def _sphere_dirs(n: int = _N_DIRS) -> np.ndarray:
    """Squared components (n, 3) of a Fibonacci lattice of unit vectors."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    ph = math.pi * (1.0 + 5 ** 0.5) * i
    u = np.stack([r * np.cos(ph), r * np.sin(ph), z], axis=1)
    return u * u


_U2 = _sphere_dirs()
_CHI3_MEAN = 2.0 * math.sqrt(2.0 / math.pi)  # E|w| for w ~ N(0, I_3)


def population_rp(lam) -> np.ndarray:
    """The robot's RP (eq. (2) over infinitely many cycles) for scatter covariances with eigenvalues ``lam`` (..., 3).

    For l = |z|, z ~ N(0, Sigma): ``|z| = r sqrt(u' diag(lam) u)`` with r ~ chi_3 independent of the unit
    vector u, so ``E l = E r * E_u sqrt(...)`` (a smooth mean over the sphere) and ``E l^2 = sum lam``;
    RP = E l + 3 sd(l).
    """
    lam = np.clip(np.asarray(lam, dtype=float), 0.0, None)
    flat = lam.reshape(-1, 3)
    El = np.empty(flat.shape[0])
    step = 4096
    for a in range(0, flat.shape[0], step):  # chunks bound the (dirs x trials) array
        El[a:a + step] = _CHI3_MEAN * np.sqrt(_U2 @ flat[a:a + step].T).mean(axis=0)
    var = np.clip(flat.sum(axis=1) - El ** 2, 0.0, None)
    return (El + 3.0 * np.sqrt(var)).reshape(lam.shape[:-1])


# --------------------------------------------------------------------------
# AP and RP of one pose (and of one block, one path plane)
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class _PoseDraws:
    AP: np.ndarray | None  # (M,) measurand draws
    RP: np.ndarray | None
    ap_gum: float | None
    rp_gum: float | None
    ap_comp: dict
    rp_comp: dict
    ap_dof: float | None = None
    rp_dof: float | None = None


def _pose_draws(x, commanded, budget: Budget, rng, shift=None, need_rp=True) -> _PoseDraws:
    """Measurand draws of AP (eq. (1)) and RP (eq. (2)) at one pose from its n measured stops ``x``.

    ``shift`` (M, 3): a frame error common to several poses (drawn by the caller); None: drawn here from
    the registration and the temperature.
    """
    M = int(budget.trials)
    n = x.shape[0]
    xb = x.mean(axis=0)
    sd_i = float(budget.instrument_sd_mm(xb))
    sd_reg = float(budget.registration_sd_mm(xb))
    d_los = xb - np.asarray(budget.tracker_origin_mm)
    floor = max(sd_i ** 2 * 1e-6, 1e-14)
    if shift is None:
        shift = frame_shift_draws(xb, budget, rng, M)
    S = np.cov(x.T, ddof=1) if n >= 2 else np.zeros((3, 3))
    mu = _mean_t_draws(x, M, rng, floor) if n >= MIN_STOPS else None
    AP = ap_g = ap_dof = rp_dof = None
    ap_comp: dict = {}
    if commanded is not None and mu is not None:
        c = np.asarray(commanded, dtype=float)
        AP = np.linalg.norm(mu + shift - c, axis=1)
        dv = xb - c
        g = dv / max(float(np.linalg.norm(dv)), 1e-15)
        sc = budget.scale_sd()
        # AP: the instrument's accuracy, a fixed error of its frame within a session common to a pose's stops
        # (the simulated tracker draws it so, eq. (N1) of station.models.tracker_noise; Budget.systematic_sd_mm)
        sd_sys = float(budget.systematic_sd_mm(xb))
        ap_comp = {"sampling": math.sqrt(max(float(g @ S @ g) / n, 0.0)),
                   "registration": sd_reg, "temperature": abs(float(g @ d_los)) * sc,
                   "instrument (in sampling)": sd_i / math.sqrt(n)}
        if sd_sys > 0:
            ap_comp["instrument (systematic)"] = sd_sys
        ap_g = math.sqrt(ap_comp["sampling"] ** 2 + sd_reg ** 2 + ap_comp["temperature"] ** 2 + sd_sys ** 2)
        reg_dof = 3 * budget.registration_n - 6 if budget.registration_n else None
        ap_dof = welch_satterthwaite([(ap_comp["sampling"], n - 1), (sd_reg, reg_dof),
                                      (ap_comp["temperature"], None), (sd_sys, None)])
    RP = rp_g = None
    rp_comp: dict = {}
    if need_rp and mu is not None:
        f, lam_s = scatter_draws(S, n, M, rng)
        RP = robot_rp(f * lam_s.sum(), lam_s, sd_i ** 2)
        l = np.linalg.norm(x - xb, axis=1)
        S_l = float(np.std(l, ddof=1))
        rp_meas = float(l.mean() + 3.0 * S_l)
        bias = rp_meas - float(robot_rp(np.array([lam_s.sum()]), lam_s, sd_i ** 2)[0])
        samp = S_l * math.sqrt(1.0 / n + 9.0 / (2.0 * (n - 1)))
        rp_comp = {"sampling": samp, "bias": abs(bias)}
        rp_g = math.sqrt(samp ** 2 + bias ** 2)
        rp_dof = welch_satterthwaite([(samp, n - 1), (abs(bias), None)])
    return _PoseDraws(AP, RP, ap_g, rp_g, ap_comp, rp_comp, ap_dof, rp_dof)


def frame_shift_draws(point_mm, budget: Budget, rng, M: int | None = None) -> np.ndarray:
    """Draws (M, 3) of the frame error at a point: registration, the instrument's systematic error and
    temperature scale (common to its stops)."""
    M = int(budget.trials if M is None else M)
    p = np.asarray(point_mm, dtype=float)
    sd_reg = float(budget.registration_sd_mm(p))
    out = np.zeros((M, 3))
    if sd_reg > 0:
        out += sd_reg * rng.standard_normal((M, 3))
    sd_sys = float(budget.systematic_sd_mm(p))
    if sd_sys > 0:  # the instrument's accuracy read as a fixed error of the session (common to the stops)
        out += sd_sys * rng.standard_normal((M, 3))
    sc = budget.scale_sd()
    if sc > 0:
        out += rng.standard_normal(M)[:, None] * sc * (p - np.asarray(budget.tracker_origin_mm))[None, :]
    return out


def _rng(budget: Budget, *key) -> np.random.Generator:
    """A generator for one figure: the budget's seed and the figure's name, so figures do not share draws."""
    salt = [int(b) for b in "|".join(str(k) for k in key).encode()]
    return np.random.default_rng([int(budget.seed)] + salt)


def pose_uncertainty(attained_mm, commanded_mm, budget: Budget, subject: str = "",
                     AP_mm: float | None = None, RP_mm: float | None = None) -> dict[str, FigureUncertainty]:
    """Uncertainties of AP (eq. (1), needs commanded) and RP (eq. (2)) of one pose (n >= :data:`MIN_STOPS`).

    ``AP_mm``/``RP_mm``: the figures stated (default: computed here from the same stops by eqs. (1), (2)).
    Returns ``{"AP_mm": ..., "RP_mm": ...}`` with the keys that could be computed.
    """
    x = _points(attained_mm, "attained_mm")
    n = x.shape[0]
    out: dict[str, FigureUncertainty] = {}
    if n < MIN_STOPS:
        return out
    rng = _rng(budget, "pose", subject)
    dr = _pose_draws(x, commanded_mm, budget, rng)
    if dr.AP is not None:
        ap = AP_mm if AP_mm is not None else float(np.linalg.norm(x.mean(axis=0) - np.asarray(commanded_mm)))
        out["AP_mm"] = _summary("AP_mm", subject, ap, dr.AP, budget, dr.ap_gum, dr.ap_comp, n, dof=dr.ap_dof)
    if dr.RP is not None:
        if RP_mm is None:
            l = np.linalg.norm(x - x.mean(axis=0), axis=1)
            RP_mm = float(l.mean() + 3.0 * np.std(l, ddof=1))
        out["RP_mm"] = _summary("RP_mm", subject, RP_mm, dr.RP, budget, dr.rp_gum, dr.rp_comp, n, dof=dr.rp_dof)
    return out


# --------------------------------------------------------------------------
# scalar figures: a mean, three standard deviations
# --------------------------------------------------------------------------


def mean_uncertainty(ch, subject, values, value, budget: Budget, *, reference=0.0, systematic_sd=0.0,
                     resolution=0.0, absolute=False) -> FigureUncertainty | None:
    """A figure that is the mean of n observations ``values`` minus a reference (AD eq. (8), PST eq. (6)):
    see :func:`mean_uncertainty_stats`."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size < MIN_STOPS:
        return None
    return mean_uncertainty_stats(ch, subject, float(v.mean()), float(np.std(v, ddof=1)), v.size, value, budget,
                                  reference=reference, systematic_sd=systematic_sd, resolution=resolution,
                                  absolute=absolute)


def mean_uncertainty_stats(ch, subject, mean, s, n, value, budget: Budget, *, dof=None, reference=0.0,
                           systematic_sd=0.0, resolution=0.0, absolute=False,
                           systematic_name: str = "systematic", systematic_dof=None,
                           noise_sd: float = 0.0) -> FigureUncertainty | None:
    """A figure that is the mean of n observations (mean ``mean``, sd ``s``) minus ``reference``.

    The population mean by a t with ``dof`` (default n - 1, at least 3) degrees of freedom and scale
    ``s / sqrt(n)`` (with ``noise_sd`` > 0, the instrument's stated noise in each observation, its population
    sd floored there: :func:`_mean_scalar_draws`); a common systematic error of sd ``systematic_sd`` (its
    component named ``systematic_name``; a sd estimated with ``systematic_dof`` degrees of freedom is drawn as
    a scaled t, GUM S1 6.4.9, with at least 3); a resolution ``resolution`` of each observation (a difference
    of two time stamps: two rectangles; it also stands in for ``s`` when every observation was the same,
    GUM F.2.2.1).  ``absolute``: the figure is ``|mean - reference|``.
    """
    dof = n - 1 if dof is None else dof
    if n < 1 or dof < 3 or not math.isfinite(s):
        return None
    M = int(budget.trials)
    rng = _rng(budget, ch, subject)
    s_eff = s if s > 0 else resolution / math.sqrt(6.0)
    mu = _mean_scalar_draws(mean, s_eff, n, dof, M, rng, noise_sd)
    if systematic_sd > 0:
        mu = mu + systematic_sd * (rng.standard_normal(M) if systematic_dof is None
                                   else rng.standard_t(max(float(systematic_dof), 3.0), size=M))
    if resolution > 0:
        mu = mu + (rng.uniform(-0.5, 0.5, M) - rng.uniform(-0.5, 0.5, M)) * resolution / math.sqrt(n)
    truth = mu - reference
    if absolute:
        truth = np.abs(truth)
    sampling, sampling_dof = _floored_sampling(s_eff, n, dof if s > 0 else None, noise_sd)
    comp = {"sampling": sampling}
    if systematic_sd:
        comp[systematic_name] = systematic_sd
    if resolution:
        comp["resolution"] = resolution / math.sqrt(6.0 * n)
    u_g = math.sqrt(sum(c ** 2 for c in comp.values()))
    nu = welch_satterthwaite([(comp["sampling"], sampling_dof)]
                             + [(c, systematic_dof if k == systematic_name else None)
                                for k, c in comp.items() if k != "sampling"])
    return _summary(ch, subject, value, truth, budget, u_g, comp, n, dof=nu)


def three_s_uncertainty(ch, subject, values, value, budget: Budget, *, noise_var=0.0) -> FigureUncertainty | None:
    """A figure ``3 S`` of n observations (RD eq. (9)): see :func:`three_s_uncertainty_stats`."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size < MIN_STOPS:
        return None
    return three_s_uncertainty_stats(ch, subject, float(np.std(v, ddof=1)), v.size, value, budget,
                                     noise_var=noise_var)


def three_s_uncertainty_stats(ch, subject, s, n, value, budget: Budget, *, noise_var=0.0) -> FigureUncertainty | None:
    """A figure ``3 S`` of n observations with sd ``s`` (RD eq. (9), orientation RP): the measurand is 3 x the
    robot's population sd, its measured variance less the instrument's ``noise_var``; the variance's posterior
    is (n - 1) s^2 / chi^2_{n-1}."""
    if n < MIN_STOPS or not math.isfinite(s):
        return None
    rng = _rng(budget, ch, subject)
    truth = _three_s_draws(s, n, noise_var, int(budget.trials), rng)
    comp = _three_s_components(s, n, noise_var)
    nu = welch_satterthwaite([(comp["sampling"], n - 1), (comp["bias"], None)])
    return _summary(ch, subject, value, truth, budget, math.hypot(*comp.values()), comp, n, dof=nu)


def _three_s_draws(s, n, noise_var, M, rng) -> np.ndarray:
    """Draws (M,) of 3 x the robot's population sd behind n observations of sd ``s``: the variance's posterior
    (n - 1) s^2 / chi^2_{n-1} less the instrument's ``noise_var`` (clipped at 0)."""
    var = (n - 1) * max(s * s, 1e-30) / rng.chisquare(n - 1, size=M)
    return 3.0 * np.sqrt(np.clip(var - noise_var, 0.0, None))


def _three_s_components(s, n, noise_var) -> dict:
    """First-order components of a 3 S figure: its sampling sd and the bias of the noise in it."""
    return {"sampling": 3.0 * s / math.sqrt(2.0 * (n - 1)), "bias": 3.0 * (s - math.sqrt(max(s * s - noise_var, 0.0)))}


# --------------------------------------------------------------------------
# vAP, drift, paths, overshoot
# --------------------------------------------------------------------------


def vap_uncertainty(groups_mm, value, budget: Budget, subject="") -> FigureUncertainty | None:
    """vAP, eq. (7): the largest distance between the robot's mean positions of the approach directions.

    ``groups_mm``: the stops (n_g, 3) of each direction (n_g >= :data:`MIN_STOPS`).  A frame error is common to the
    directions of one pose and cancels.
    """
    gs = [_points(g, "groups_mm") for g in groups_mm]
    if len(gs) < 2 or any(g.shape[0] < MIN_STOPS for g in gs):
        return None
    M = int(budget.trials)
    rng = _rng(budget, "vAP", subject)
    floor = max(float(budget.instrument_sd_mm(gs[0].mean(axis=0))) ** 2 * 1e-6, 1e-14)
    mus = np.stack([_mean_t_draws(g, M, rng, floor) for g in gs], axis=1)  # (M, G, 3)
    d = np.linalg.norm(mus[:, :, None, :] - mus[:, None, :, :], axis=3)
    truth = d.reshape(M, -1).max(axis=1)
    m = np.array([g.mean(axis=0) for g in gs])
    dm = np.linalg.norm(m[:, None] - m[None], axis=2)
    h, k = np.unravel_index(int(np.argmax(dm)), dm.shape)
    gvec = (m[h] - m[k]) / max(float(dm[h, k]), 1e-15)
    parts = [(math.sqrt(max(float(gvec @ np.cov(gs[j].T, ddof=1) @ gvec) / gs[j].shape[0], 0.0)),
              gs[j].shape[0] - 1) for j in (h, k)]
    comp = {"sampling": math.hypot(parts[0][0], parts[1][0])}
    return _summary("vAP_mm", subject, value, truth, budget, comp["sampling"], comp, sum(g.shape[0] for g in gs),
                    dof=welch_satterthwaite(parts))


def spread_uncertainty(ch, subject, groups, value, budget: Budget) -> FigureUncertainty | None:
    """A figure that is the largest minus the smallest of the means of several groups of scalar
    observations (orientation vAP of one angle, eq. (7) per angle): each group's population mean by a t with
    n_g - 1 degrees of freedom and scale ``s_g / sqrt(n_g)`` (n_g >= :data:`MIN_STOPS`); a frame error is
    common to the groups of one pose and cancels."""
    gs = [np.asarray(g, dtype=float).ravel() for g in groups]
    if len(gs) < 2 or any(g.size < MIN_STOPS or not np.all(np.isfinite(g)) for g in gs):
        return None
    M = int(budget.trials)
    rng = _rng(budget, ch, subject)
    means = np.array([g.mean() for g in gs])
    scales = np.array([max(float(np.std(g, ddof=1)), 1e-12) / math.sqrt(g.size) for g in gs])
    mus = means[None, :] + scales[None, :] * np.stack([rng.standard_t(g.size - 1, size=M) for g in gs], axis=1)
    truth = mus.max(axis=1) - mus.min(axis=1)
    h, k = int(np.argmax(means)), int(np.argmin(means))
    parts = [(float(scales[j]), gs[j].size - 1) for j in (h, k)]
    comp = {"sampling": math.hypot(parts[0][0], parts[1][0])}
    return _summary(ch, subject, value, truth, budget, comp["sampling"], comp, sum(g.size for g in gs),
                    dof=welch_satterthwaite(parts))


def drift_uncertainty(blocks_mm, commanded_mm, dAP, dRP, budget: Budget, subject="") -> dict:
    """dAP and dRP: |AP of the last block - AP of the first| and the same of RP (blocks (b, 3), b >= 4).

    The frame error is common to the two blocks (the same pose).
    """
    b0, b1 = _points(blocks_mm[0], "blocks_mm"), _points(blocks_mm[-1], "blocks_mm")
    if min(b0.shape[0], b1.shape[0]) < 4:
        return {}
    rng = _rng(budget, "drift", subject)
    shift = frame_shift_draws(b0.mean(axis=0), budget, rng)
    d0 = _pose_draws(b0, commanded_mm, budget, rng, shift=shift)
    d1 = _pose_draws(b1, commanded_mm, budget, rng, shift=shift)
    out = {}
    n = b0.shape[0] + b1.shape[0]
    if d0.AP is not None:
        comp = {"sampling": math.hypot(d0.ap_comp["sampling"], d1.ap_comp["sampling"])}
        nu = welch_satterthwaite([(d0.ap_comp["sampling"], b0.shape[0] - 1), (d1.ap_comp["sampling"], b1.shape[0] - 1)])
        out["dAP_mm"] = _summary("dAP_mm", subject, dAP, np.abs(d1.AP - d0.AP), budget, comp["sampling"], comp, n,
                                 dof=nu)
    comp = {"sampling": math.hypot(d0.rp_gum, d1.rp_gum)}
    nu = welch_satterthwaite([(d0.rp_gum, d0.rp_dof), (d1.rp_gum, d1.rp_dof)])
    out["dRP_mm"] = _summary("dRP_mm", subject, dRP, np.abs(d1.RP - d0.RP), budget, comp["sampling"], comp, n,
                             dof=nu)
    return out


def angle_drift_uncertainty(first_deg, last_deg, budget: Budget, subject="") -> dict[str, FigureUncertainty]:
    """The drift of the orientation figures between two visits of a pose: dAPa = |APa(t_n) - APa(t_1)| (AP of an
    angle: the mean of its stops less the commanded angle) and dRPa = |RPa(t_n) - RPa(t_1)| (RP = 3 S), and so
    for b and c; keys ``dAPa_deg`` ... ``dRPc_deg``.

    ``first_deg``, ``last_deg`` (n, 3): the stops' angles a, b, c less the commanded ones, deg (n >=
    :data:`MIN_STOPS`). Each visit's mean by a t with n - 1 degrees of freedom, its population sd no lower than
    the instrument's angle noise ``budget.angle_sd_deg`` (:func:`_mean_scalar_draws`), its scatter by the posterior
    of :func:`three_s_uncertainty_stats` (the instrument's angle noise ``budget.angle_sd_deg`` taken out). The
    frame's errors (the registration's rotation, the instrument's systematic angles) are common to the two
    visits of a pose and cancel.
    """
    a0, a1 = (np.asarray(x, dtype=float).reshape(-1, 3) for x in (first_deg, last_deg))
    if min(a0.shape[0], a1.shape[0]) < MIN_STOPS or not (np.all(np.isfinite(a0)) and np.all(np.isfinite(a1))):
        return {}
    M = int(budget.trials)
    noise_var = budget.angle_sd_deg ** 2
    n0, n1 = a0.shape[0], a1.shape[0]
    out = {}
    for j, ax in enumerate("abc"):
        rng = _rng(budget, "angle drift", subject, ax)
        m0, m1 = float(a0[:, j].mean()), float(a1[:, j].mean())
        s0, s1 = float(np.std(a0[:, j], ddof=1)), float(np.std(a1[:, j], ddof=1))
        mu0 = _mean_scalar_draws(m0, max(s0, 1e-12), n0, n0 - 1, M, rng, budget.angle_sd_deg)
        mu1 = _mean_scalar_draws(m1, max(s1, 1e-12), n1, n1 - 1, M, rng, budget.angle_sd_deg)
        parts = [_floored_sampling(s0, n0, n0 - 1, budget.angle_sd_deg),
                 _floored_sampling(s1, n1, n1 - 1, budget.angle_sd_deg)]
        comp = {"sampling": math.hypot(parts[0][0], parts[1][0])}
        out[f"dAP{ax}_deg"] = _summary(f"dAP{ax}_deg", subject, abs(m1 - m0), np.abs(mu1 - mu0), budget,
                                       comp["sampling"], comp, n0 + n1, dof=welch_satterthwaite(parts))
        r0, r1 = _three_s_draws(s0, n0, noise_var, M, rng), _three_s_draws(s1, n1, noise_var, M, rng)
        c0, c1 = _three_s_components(s0, n0, noise_var), _three_s_components(s1, n1, noise_var)
        comp = {"sampling": math.hypot(c0["sampling"], c1["sampling"]), "bias": math.hypot(c0["bias"], c1["bias"])}
        nu = welch_satterthwaite([(c0["sampling"], n0 - 1), (c1["sampling"], n1 - 1), (comp["bias"], None)])
        out[f"dRP{ax}_deg"] = _summary(f"dRP{ax}_deg", subject, abs(3.0 * (s1 - s0)), np.abs(r1 - r0), budget,
                                       math.hypot(*comp.values()), comp, n0 + n1, dof=nu)
    return out


def path_uncertainty(crossings_mm, plane_points_mm, AT, RT, budget: Budget, subject="") -> dict:
    """AT and RT of a linear path: the largest AP-like and RP-like figures over the planes.

    ``crossings_mm`` (n, m, 3): the n traversals' crossing points of the m planes; ``plane_points_mm``
    (m, 3): the commanded points.  The frame error is common to the planes of one path.
    """
    c = np.asarray(crossings_mm, dtype=float)
    if c.ndim != 3 or c.shape[2] != 3 or c.shape[0] < MIN_STOPS:
        return {}
    n, m = c.shape[:2]
    rng = _rng(budget, "path", subject)
    shift = frame_shift_draws(c.reshape(-1, 3).mean(axis=0), budget, rng)
    ats, rts, agum, rgum, adof, rdof = [], [], [], [], [], []
    for i in range(m):  # loop over planes
        d = _pose_draws(c[:, i, :], plane_points_mm[i], budget, rng, shift=shift, need_rp=RT is not None)
        ats.append(d.AP)
        agum.append(d.ap_gum)
        adof.append(d.ap_dof)
        if d.RP is not None:
            rts.append(d.RP)
            rgum.append(d.rp_gum)
            rdof.append(d.rp_dof)
    out = {}
    at_i = np.linalg.norm(c.mean(axis=0) - np.asarray(plane_points_mm), axis=1)
    i_at = int(np.argmax(at_i))
    comp = {"plane of the largest AT_i": agum[i_at]}
    out["AT_mm"] = _summary("AT_mm", subject, AT, np.max(np.stack(ats), axis=0), budget, agum[i_at], comp, n,
                             dof=adof[i_at])
    if rts and RT is not None:
        l = np.linalg.norm(c - c.mean(axis=0)[None], axis=2)
        i_rt = int(np.argmax(l.mean(axis=0) + 3 * l.std(axis=0, ddof=1)))
        comp = {"plane of the largest RT_i": rgum[i_rt]}
        out["RT_mm"] = _summary("RT_mm", subject, RT, np.max(np.stack(rts), axis=0), budget, rgum[i_rt], comp, n,
                                 dof=rdof[i_rt])
    return out


def overshoot_uncertainty(att_mm, max_mm, value, budget: Budget, subject="") -> FigureUncertainty | None:
    """POS, eq. (5): the largest distance from an attained pose to a sample of its approach beyond the band.

    ``att_mm``/``max_mm`` (K, 3): each overshooting stop's attained pose and its farthest sample; the
    measurand is this run's overshoot, its inputs the two measured points of each stop (instrument noise on
    both).  Stops that did not leave the band are not modelled (a noise-made crossing of the band is not).
    """
    a, b = _points(att_mm, "att_mm"), _points(max_mm, "max_mm")
    if a.shape[0] == 0:
        return None
    M = int(budget.trials)
    rng = _rng(budget, "POS", subject)
    sd = np.sqrt(budget.instrument_sd_mm(a) ** 2 + budget.instrument_sd_mm(b) ** 2)  # (K,)
    e = rng.standard_normal((M, a.shape[0], 3)) * sd[None, :, None]
    truth = np.linalg.norm((b - a)[None] + e, axis=2).max(axis=1)
    j = int(np.argmax(np.linalg.norm(b - a, axis=1)))
    comp = {"instrument": float(sd[j])}
    return _summary("POS_mm", subject, value, truth, budget, float(sd[j]), comp, a.shape[0])


def budget_from_options(tracker: str | None = None, *, temperature_u_K: float = 0.0, trials: int | None = None,
                        seed: int = 0, rate_hz: float | None = None, angle_sd_deg: float = 0.0,
                        noise_um: float | None = None) -> Budget:
    """A :class:`Budget` from the options of a command (``tracker``: ``--tracker-uncertainty`` text; None:
    the default 15 um + 6 um/m MPE; ``noise_um``: the reading noise of ``--tracker-noise``, which makes the
    accuracy systematic)."""
    kw = parse_tracker_uncertainty(tracker) if tracker is not None else {}
    return Budget(**kw, temperature_u_K=float(temperature_u_K), trials=int(trials or DEFAULT_TRIALS),
                  seed=int(seed), rate_hz=rate_hz, angle_sd_deg=float(angle_sd_deg), instrument_noise_um=noise_um)
