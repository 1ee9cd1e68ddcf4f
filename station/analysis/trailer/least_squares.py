"""Link lengths of the two-link trailer by the seed's least squares (seed 003).

Least squares (eq. (1)-(20)), all vectorised over leading axes (runs):

* :func:`ols` — OLS1, eq. (8) ``beta = (A^T A)^-1 A^T Y`` (computed by SVD),
  condition number eq. (17) ``mu_1 / mu_n`` of ``A``.
* :func:`tls` — TLS by the SVD of ``C = [A Y]``, eq. (14)-(15)
  ``beta = -V12 V22^-1``, condition number eq. (20) (Jia & Li):
  ``||V11^-T diag(s_i)||_2 sqrt(||beta||^2 + 1)`` with
  ``s_i = sqrt(mu_i^2 + mu_{n+1}^2) / (mu_i^2 - mu_{n+1}^2)``, ``mu`` the
  singular values of ``C``. (The seed's printed ``s_i`` is garbled; this form
  reproduces every TLS condition number of its Figs. 8, 10, 11.)
* OLS2 exists only for the straight line (eq. (11)-(13)): input and output
  swapped, ``A = [Y 1]``, ``beta = [1/a, -b/a]``.

Models:

* Prediction models (Table 2): PM1 ``psi = a kappa``, PM2 ``psi = a kappa + b``
  (eq. (26)-(27)), by OLS1, OLS2 or TLS: :func:`fit_prediction_model`.
* Exact models (Table 1, eq. (24)) from eq. (23):
  EM1 ``sin psi = L1 kappa cos psi + L2 kappa``,
  EM2 ``kappa cos psi = (1/L1) sin psi - (L2/L1) kappa``,
  EM3 ``kappa = (1/L2) sin psi - (L1/L2) kappa cos psi``, by OLS1 or TLS:
  :func:`fit_exact_model`. TLS gives the same lengths for all three (the
  three share one column set ``[sin psi, kappa cos psi, kappa]``), hence the
  seed's "TLS(EM1, 2, 3)"; their condition numbers differ.
* Combined methods M1-M24 (Table 3): a prediction model is fitted (step
  S130), its *model values* — the ``x_i, y_i`` of eq. (5) for the least
  squares used (OLS1: ``(kappa_i, a kappa_i + b)``; OLS2:
  ``((psi_i - b)/a, psi_i)``; TLS: the orthogonal foot point of eq. (16)) —
  are the predicted data of step S140, and an exact model is fitted to them
  (step S150): :func:`combined_fit`, :func:`estimate_combined`. This reading
  reproduces the estimation errors printed in Figs. 10-11.

Note what the combined methods measure: their predicted data lie on a
straight line, so the exact model only splits the fitted slope ``a`` (which
is close to ``L1 + L2``, eq. (26)) in the ratio that makes eq. (23) closest
to a straight line over the data range — about ``L1 = a/3``. They are
accurate when the true ``L1`` is near ``L2 / 2`` (the seed's 1.25 m and
2.48 m) and biased otherwise. Their uncertainties here are the statistical
part only (delta method through the slope); the split bias is not in them.

Inputs are validated (:func:`validate_samples`): equal lengths, finite, at
least :data:`MIN_SAMPLES`, joint angles within 45 deg (beyond what the noise
explains), a curvature that varies more than its noise (a constant command
gives one point of eq. (23)). Results are checked against eq. (25).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from station.errors import ConfigError, DataError, InsufficientDataError
from station.models.trailer import (
    PSI_LIMIT_RAD, CurvatureBoundError, DegenerateCommandError, JointAngleLimitError,
)

#: fewest samples accepted for a link-length estimate
MIN_SAMPLES = 20
#: least-squares kinds
LS_METHODS = ("OLS1", "OLS2", "TLS")
PREDICTION_MODELS = ("PM1", "PM2")
EXACT_MODELS = ("EM1", "EM2", "EM3")
#: an estimated noise this many sigmas beyond a limit is an error
LIMIT_SIGMAS = 4.0


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True)
class LSResult:
    """One least-squares solve.

    Attributes
    ----------
    method : str
        ``"OLS1"`` or ``"TLS"``.
    beta : ndarray, shape (..., n)
    condition_number : ndarray, shape (...)
        Eq. (17) for OLS, eq. (20) for TLS.
    singular_values : ndarray, shape (..., n) or (..., n+1)
        Of ``A`` (OLS) or of ``C = [A Y]`` (TLS), descending.
    residual_ss : ndarray, shape (...)
        Sum of squared fitting errors of eq. (4).
    cov : ndarray, shape (..., n, n)
        First-order covariance of ``beta``.
    """

    method: str
    beta: np.ndarray
    condition_number: np.ndarray
    singular_values: np.ndarray
    residual_ss: np.ndarray
    cov: np.ndarray


@dataclass(frozen=True)
class PredictionFit:
    """A prediction model fitted by one least squares (Table 2, step S130-S140).

    ``kappa_model``/``psi_model`` (shape (..., p)) are the model values of
    eq. (5), i.e. the predicted data; ``cov_ab`` (..., 2, 2) the covariance of
    ``(a, b)`` (zero row/column for PM1).
    """

    model: str
    method: str
    a: np.ndarray
    b: np.ndarray
    condition_number: np.ndarray
    singular_values: np.ndarray
    kappa_model: np.ndarray
    psi_model: np.ndarray
    cov_ab: np.ndarray


@dataclass(frozen=True)
class ExactFit:
    """An exact model (Table 1) fitted by OLS1 or TLS."""

    model: str
    method: str
    L1_m: np.ndarray
    L2_m: np.ndarray
    beta: np.ndarray
    condition_number: np.ndarray
    singular_values: np.ndarray
    cov_L: np.ndarray


@dataclass(frozen=True)
class CombinedSpec:
    """One row of Table 3: ``pm_method(pm_model) + em_method(em_model)``."""

    name: str
    pm_method: str
    pm_model: str
    em_method: str
    em_model: str

    @property
    def label(self) -> str:
        em = "EM1, 2, 3" if self.em_method == "TLS" else self.em_model
        return f"{self.pm_method}({self.pm_model})+{self.em_method}({em})"


def _table3() -> dict[str, CombinedSpec]:
    specs = {}
    n = 1
    for pm_model in ("PM2", "PM1"):
        for pm_method in LS_METHODS:
            for em_method, em_model in (("OLS1", "EM1"), ("OLS1", "EM2"), ("OLS1", "EM3"), ("TLS", "EM1")):
                specs[f"M{n}"] = CombinedSpec(f"M{n}", pm_method, pm_model, em_method, em_model)
                n += 1
    return specs


#: Table 3, ``"M1"`` .. ``"M24"``
METHODS: dict[str, CombinedSpec] = _table3()
#: the seed's recommended combinations (para. [0138])
BEST_METHODS = tuple(f"M{i}" for i in range(17, 25))


@dataclass(frozen=True)
class CombinedFit:
    """Raw result of a combined method (vectorised)."""

    spec: CombinedSpec
    prediction: PredictionFit
    exact: ExactFit

    @property
    def L1_m(self) -> np.ndarray:
        return self.exact.L1_m

    @property
    def L2_m(self) -> np.ndarray:
        return self.exact.L2_m


@dataclass(frozen=True)
class TrailerEstimate:
    """Link lengths with their standard uncertainties.

    Attributes
    ----------
    method : str
        ``"M1"``..``"M24"``, ``"odr"``, ``"dynamic"`` or an EMLS label.
    L1_m, L2_m : float
        Estimated link lengths, m.
    L1_sigma_m, L2_sigma_m : float
        Standard uncertainties (1 sigma), m.
    L1_L2_corr : float
        Correlation of the two estimates.
    condition_number : float
        The method's headline condition number (see ``details``).
    n_samples : int
    details : dict
        Method-specific numbers (slopes, stage condition numbers, noise...).
    warnings : tuple of str
        Things the user must know (e.g. uncertainty excludes model bias).
    """

    method: str
    L1_m: float
    L2_m: float
    L1_sigma_m: float
    L2_sigma_m: float
    L1_L2_corr: float
    condition_number: float
    n_samples: int
    details: dict = field(default_factory=dict)
    warnings: tuple = ()

    def to_json(self) -> dict:
        """Stable JSON keys (lengths in m)."""
        def clean(v):
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, (list, tuple)):
                return [clean(x) for x in v]
            if isinstance(v, np.ndarray):
                return clean(v.tolist())
            if isinstance(v, (np.floating, float)):
                return float(v) if math.isfinite(v) else None
            if isinstance(v, np.integer):
                return int(v)
            return v
        return clean({
            "method": self.method,
            "L1_m": self.L1_m, "L2_m": self.L2_m,
            "L1_sigma_m": self.L1_sigma_m, "L2_sigma_m": self.L2_sigma_m,
            "L1_L2_corr": self.L1_L2_corr,
            "condition_number": self.condition_number,
            "n_samples": self.n_samples,
            "details": self.details,
            "warnings": list(self.warnings),
        })


# ----------------------------------------------------------------------------- least squares
def _as_system(A, Y) -> tuple[np.ndarray, np.ndarray]:
    A = np.asarray(A, dtype=float)
    Y = np.asarray(Y, dtype=float)
    if A.ndim < 2:
        raise DataError(f"A must have shape (..., p, n), got {A.shape}")
    if Y.shape != A.shape[:-1]:
        raise DataError(f"Y must have shape {A.shape[:-1]} to match A {A.shape}, got {Y.shape}")
    p, n = A.shape[-2:]
    if p <= n:
        raise InsufficientDataError(f"least squares needs more samples ({p}) than parameters ({n})")
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(Y))):
        raise DataError("A or Y contains NaN or infinite values")
    return A, Y


def _rank_check(s: np.ndarray, what: str) -> None:
    tol = s[..., :1] * max(s.shape[-1], 1) * 1e-13
    if np.any(s[..., -1:] <= tol):
        raise DegenerateCommandError(
            f"{what} is rank deficient (condition number infinite): the columns are "
            "proportional, e.g. a constant curvature command gives one point of eq. (23)")


def ols(A, Y) -> LSResult:
    """OLS1 of eq. (6)-(8) with the condition number of eq. (17).

    Parameters
    ----------
    A : array_like, shape (..., p, n)
    Y : array_like, shape (..., p)
    """
    A, Y = _as_system(A, Y)
    p, n = A.shape[-2:]
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    _rank_check(s, "the regressor matrix A")
    uy = np.einsum("...pn,...p->...n", U, Y)
    beta = np.einsum("...kn,...k->...n", Vt, uy / s)
    r = Y - np.einsum("...pn,...n->...p", A, beta)
    ssr = np.einsum("...p,...p->...", r, r)
    s2 = ssr / (p - n)
    vinv = Vt.swapaxes(-1, -2) / s[..., None, :]
    cov = s2[..., None, None] * vinv @ vinv.swapaxes(-1, -2)
    return LSResult("OLS1", beta, s[..., 0] / s[..., -1], s, ssr, cov)


def tls(A, Y) -> LSResult:
    """TLS of eq. (14)-(16) by SVD, condition number of eq. (20).

    Parameters
    ----------
    A : array_like, shape (..., p, n)
    Y : array_like, shape (..., p)
    """
    A, Y = _as_system(A, Y)
    p, n = A.shape[-2:]
    C = np.concatenate([A, Y[..., None]], axis=-1)
    _, mu, Vt = np.linalg.svd(C, full_matrices=False)
    V = Vt.swapaxes(-1, -2)
    V11 = V[..., :n, :n]
    V12 = V[..., :n, n]
    V22 = V[..., n, n]
    if np.any(np.abs(V22) < 1e-12):
        raise DataError("TLS has no solution: V22 of eq. (14) is singular (the output is "
                        "uncorrelated with the inputs)")
    beta = -V12 / V22[..., None]
    mu_n1 = mu[..., n]
    mu_i = mu[..., :n]
    if np.any(mu_i[..., -1] - mu_n1 <= mu[..., :1] * 1e-13):
        raise DegenerateCommandError("TLS is not unique: the two smallest singular values of "
                                     "[A Y] coincide (degenerate data)")
    s_i = np.sqrt(mu_i ** 2 + mu_n1[..., None] ** 2) / (mu_i ** 2 - mu_n1[..., None] ** 2)
    M = np.linalg.inv(V11).swapaxes(-1, -2) * s_i[..., None, :]
    cond = np.linalg.norm(M, ord=2, axis=(-2, -1)) * np.sqrt(1.0 + np.einsum("...n,...n->...", beta, beta))
    # first-order covariance of the TLS solution (noise of equal variance in every column)
    sigma2 = mu_n1 ** 2 / (p - n)
    G = np.einsum("...pi,...pj->...ij", A, A) - (mu_n1 ** 2)[..., None, None] * np.eye(n)
    try:
        Ginv = np.linalg.inv(G)
    except np.linalg.LinAlgError as exc:
        raise DegenerateCommandError("TLS covariance is singular (degenerate data)") from exc
    cov = (sigma2 * (1.0 + np.einsum("...n,...n->...", beta, beta)))[..., None, None] * Ginv
    return LSResult("TLS", beta, cond, mu, mu_n1 ** 2, cov)


# ----------------------------------------------------------------------------- validation
def noise_sigma(x, axis: int = -1) -> np.ndarray:
    """Robust white-noise sigma of a smooth signal from its second differences.

    ``median(|d2 x|) / 0.6745 / sqrt(6)`` (``d2`` of white noise has variance
    ``6 sigma^2``). Samples must be in time order.
    """
    d2 = np.diff(np.asarray(x, dtype=float), n=2, axis=axis)
    return np.median(np.abs(d2), axis=axis) / 0.6745 / math.sqrt(6.0)


def validate_samples(kappa, psi, *, min_samples: int = MIN_SAMPLES,
                     psi_limit_rad: float = PSI_LIMIT_RAD) -> tuple[np.ndarray, np.ndarray, dict]:
    """Check one run of measured curvature and joint angle (time order).

    Returns
    -------
    kappa, psi : ndarray, shape (p,)
    info : dict
        ``kappa_noise``, ``psi_noise`` (estimated sigmas), ``kappa_span``.

    Raises
    ------
    DataError, InsufficientDataError, JointAngleLimitError, DegenerateCommandError
    """
    k = np.asarray(kappa, dtype=float)
    p = np.asarray(psi, dtype=float)
    if k.ndim != 1 or p.ndim != 1:
        raise DataError(f"kappa and psi must be 1-D arrays, got shapes {k.shape} and {p.shape}")
    if k.size != p.size:
        raise DataError(f"kappa has {k.size} samples but psi has {p.size}")
    if k.size < min_samples:
        raise InsufficientDataError(f"{k.size} samples; a link-length estimate needs at least {min_samples}")
    bad = ~(np.isfinite(k) & np.isfinite(p))
    if np.any(bad):
        raise DataError(f"{int(bad.sum())} sample(s) have NaN or infinite kappa/psi "
                        f"(first at index {int(np.argmax(bad))})")
    sk, sp = float(noise_sigma(k)), float(noise_sigma(p))
    worst = float(np.max(np.abs(p)))
    if worst > psi_limit_rad + LIMIT_SIGMAS * sp:
        n_over = int(np.sum(np.abs(p) > psi_limit_rad + LIMIT_SIGMAS * sp))
        raise JointAngleLimitError(
            f"{n_over} joint angle(s) beyond {math.degrees(psi_limit_rad):.1f} deg (max "
            f"{math.degrees(worst):.2f} deg, noise {math.degrees(sp):.3f} deg): outside the range "
            "of seed 003 (|psi| < 45 deg)")
    var_k = float(np.var(k))
    if var_k <= 0.0 or var_k <= sk * sk * (1.0 + 8.0 * math.sqrt(2.0 / k.size)):
        raise DegenerateCommandError(
            f"degenerate command: the curvature varies by {math.sqrt(var_k):.3g} 1/m (std), no more "
            f"than its noise ({sk:.3g} 1/m); a constant curvature gives one point of eq. (23) and "
            "cannot separate L1 from L2")
    return k, p, {"kappa_noise": sk, "psi_noise": sp, "kappa_span": float(np.ptp(k))}


def check_curvature_bound(kappa: np.ndarray, L1_m: float, L2_m: float, kappa_noise: float) -> None:
    """Raise CurvatureBoundError if data pass eq. (25) for the estimated lengths."""
    if not (math.isfinite(L1_m) and math.isfinite(L2_m)) or L2_m <= abs(L1_m):
        return  # no jackknife bound (flagged by the estimators' warnings)
    bound = 1.0 / math.sqrt(L2_m ** 2 - L1_m ** 2)
    over = np.abs(kappa) > bound + LIMIT_SIGMAS * kappa_noise
    if np.any(over):
        raise CurvatureBoundError(
            f"{int(over.sum())} curvature sample(s) beyond the bound of eq. (25), |kappa| < "
            f"{bound:.4g} 1/m for the estimated L1={L1_m:.4g} m, L2={L2_m:.4g} m (max "
            f"{float(np.max(np.abs(kappa))):.4g} 1/m): the data contradict the trailer model")


def physical_warnings(L1_m: float, L2_m: float) -> list[str]:
    w = []
    if not (math.isfinite(L1_m) and math.isfinite(L2_m)):
        raise DataError(f"the estimate is not finite (L1={L1_m}, L2={L2_m})")
    if L1_m < 0 or L2_m <= 0:
        w.append(f"non-physical lengths L1={L1_m:.4g} m, L2={L2_m:.4g} m")
    elif L2_m <= L1_m:
        w.append(f"L2 ({L2_m:.4g} m) <= L1 ({L1_m:.4g} m): outside the seed's L2 > L1")
    return w


# ----------------------------------------------------------------------------- prediction models
def _check_name(name: str, value: str, allowed) -> None:
    if value not in allowed:
        raise ConfigError(f"{name} must be one of {tuple(allowed)}, got {value!r}")


def _pair(kappa, psi) -> tuple[np.ndarray, np.ndarray]:
    k = np.asarray(kappa, dtype=float)
    p = np.asarray(psi, dtype=float)
    if k.shape != p.shape or k.ndim < 1:
        raise DataError(f"kappa and psi must have the same shape (..., p), got {k.shape} and {p.shape}")
    return k, p


def model_values(kappa, psi, a, b, method: str) -> tuple[np.ndarray, np.ndarray]:
    """Model values ``(x_i, y_i)`` of eq. (5) on the line ``psi = a kappa + b``.

    OLS1: ``(kappa, a kappa + b)``; OLS2: ``((psi - b)/a, psi)``; TLS: the
    orthogonal foot points of eq. (16). Shapes (..., p); ``a``, ``b`` (...).
    """
    k, p = _pair(kappa, psi)
    a = np.asarray(a, dtype=float)[..., None]
    b = np.asarray(b, dtype=float)[..., None]
    if method == "OLS1":
        return np.broadcast_to(k, np.broadcast_shapes(k.shape, a.shape)).copy(), a * k + b
    if method == "OLS2":
        return (p - b) / a, np.broadcast_to(p, np.broadcast_shapes(p.shape, a.shape)).copy()
    if method == "TLS":
        r = p - a * k - b
        return k + a * r / (1.0 + a * a), p - r / (1.0 + a * a)
    raise ConfigError(f"method must be one of {LS_METHODS}, got {method!r}")


def fit_prediction_model(kappa, psi, model: str = "PM1", method: str = "TLS") -> PredictionFit:
    """Fit PM1 (eq. (26)) or PM2 (eq. (27)) by OLS1, OLS2 or TLS (Table 2).

    Parameters
    ----------
    kappa, psi : array_like, shape (..., p)
        Measured curvature (1/m) and joint angle (rad).
    model : {"PM1", "PM2"}
    method : {"OLS1", "OLS2", "TLS"}

    Returns
    -------
    PredictionFit
        Slope ``a`` (m), intercept ``b`` (rad), the condition number of the
        solve (eq. (17) or (20); 1 for a one-column OLS, where the seed
        reports the singular value ``mu_1`` instead) and the predicted data.
    """
    _check_name("model", model, PREDICTION_MODELS)
    _check_name("method", method, LS_METHODS)
    k, p = _pair(kappa, psi)
    ones = np.ones_like(k)
    x, y = (p, k) if method == "OLS2" else (k, p)
    A = x[..., None] if model == "PM1" else np.stack([x, ones], axis=-1)
    res = ols(A, y) if method != "TLS" else tls(A, y)
    beta = res.beta
    cov = np.zeros(beta.shape[:-1] + (2, 2))
    if method == "OLS2":
        a = 1.0 / beta[..., 0]
        b = -beta[..., 1] * a if model == "PM2" else np.zeros_like(a)
        # (a, b) = (1/b0, -b1/b0): Jacobian rows d(a, b)/d(b0, b1)
        J = np.zeros(beta.shape[:-1] + (2, beta.shape[-1]))
        J[..., 0, 0] = -a * a
        if model == "PM2":
            J[..., 1, 0] = -a * b
            J[..., 1, 1] = -a
        cov = J @ res.cov @ J.swapaxes(-1, -2)
    else:
        a = beta[..., 0]
        b = beta[..., 1] if model == "PM2" else np.zeros_like(a)
        n = beta.shape[-1]
        cov[..., :n, :n] = res.cov
    km, pm = model_values(k, p, a, b, method)
    return PredictionFit(model, method, a, b, res.condition_number, res.singular_values, km, pm, cov)


# ----------------------------------------------------------------------------- exact models
def exact_model_system(kappa, psi, model: str) -> tuple[np.ndarray, np.ndarray]:
    """Regressors ``A`` (..., p, 2) and output ``Y`` (..., p) of Table 1."""
    _check_name("model", model, EXACT_MODELS)
    k, p = _pair(kappa, psi)
    s, c = np.sin(p), np.cos(p)
    if model == "EM1":
        return np.stack([k * c, k], axis=-1), s
    if model == "EM2":
        return np.stack([s, -k], axis=-1), k * c
    return np.stack([s, -k * c], axis=-1), k


def lengths_from_beta(beta, model: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(L1, L2, J)`` from the unknowns of Table 1; ``J`` = d(L1, L2)/d(beta), (..., 2, 2)."""
    _check_name("model", model, EXACT_MODELS)
    b0, b1 = beta[..., 0], beta[..., 1]
    J = np.zeros(beta.shape[:-1] + (2, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        if model == "EM1":  # [L1, L2]
            J[..., 0, 0] = 1.0
            J[..., 1, 1] = 1.0
            return b0, b1, J
        if model == "EM2":  # [1/L1, L2/L1]
            L1, L2 = 1.0 / b0, b1 / b0
            J[..., 0, 0] = -L1 * L1
            J[..., 1, 0] = -b1 / (b0 * b0)
            J[..., 1, 1] = L1
            return L1, L2, J
        L2, L1 = 1.0 / b0, b1 / b0  # EM3: [1/L2, L1/L2]
        J[..., 1, 0] = -L2 * L2
        J[..., 0, 0] = -b1 / (b0 * b0)
        J[..., 0, 1] = L2
        return L1, L2, J


def fit_exact_model(kappa, psi, model: str = "EM1", method: str = "OLS1") -> ExactFit:
    """Fit EM1, EM2 or EM3 (Table 1) by OLS1 or TLS (the EMLS of para. [0122]).

    Parameters
    ----------
    kappa, psi : array_like, shape (..., p)
    model : {"EM1", "EM2", "EM3"}
    method : {"OLS1", "TLS"}
    """
    _check_name("method", method, ("OLS1", "TLS"))
    A, Y = exact_model_system(kappa, psi, model)
    res = ols(A, Y) if method == "OLS1" else tls(A, Y)
    L1, L2, J = lengths_from_beta(res.beta, model)
    cov_L = J @ res.cov @ J.swapaxes(-1, -2)
    return ExactFit(model, method, L1, L2, res.beta, res.condition_number, res.singular_values, cov_L)


def exact_condition_numbers(kappa, psi, method: str) -> dict[str, np.ndarray]:
    """Condition numbers of EM1, EM2, EM3 under ``method`` (the columns of Fig. 8)."""
    out = {}
    for model in EXACT_MODELS:
        A, Y = exact_model_system(kappa, psi, model)
        out[model] = (ols(A, Y) if method == "OLS1" else tls(A, Y)).condition_number
    return out


# ----------------------------------------------------------------------------- combined (Table 3)
def _spec(method: str) -> CombinedSpec:
    if method not in METHODS:
        raise ConfigError(f"method must be one of M1..M24 (Table 3), got {method!r}")
    return METHODS[method]


def combined_fit(kappa, psi, method: str = "M17") -> CombinedFit:
    """A combined method of Table 3 on raw arrays (vectorised over leading axes).

    Step S130 fits the prediction model; S140 takes its model values (eq. (5))
    as predicted data; S150 fits the exact model to them.
    """
    spec = _spec(method)
    pred = fit_prediction_model(kappa, psi, spec.pm_model, spec.pm_method)
    exact = fit_exact_model(pred.kappa_model, pred.psi_model, spec.em_model, spec.em_method)
    return CombinedFit(spec, pred, exact)


def _lengths_given_line(k, p, a, b, spec: CombinedSpec) -> np.ndarray:
    km, pm = model_values(k, p, a, b, spec.pm_method)
    fit = fit_exact_model(km, pm, spec.em_model, spec.em_method)
    return np.stack([fit.L1_m, fit.L2_m], axis=-1)


def estimate_combined(kappa, psi, method: str = "M17") -> TrailerEstimate:
    """Link lengths of one run by a combined method of Table 3, validated.

    Parameters
    ----------
    kappa, psi : array_like, shape (p,)
        Measured curvature (1/m) and joint angle (rad), in time order.
    method : str
        ``"M1"`` .. ``"M24"``; the seed recommends M17-M24.

    Returns
    -------
    TrailerEstimate
        Uncertainties by the delta method through the prediction model's
        ``(a, b)``; they exclude the bias of splitting a straight line
        (see the module docstring), which ``warnings`` says.
    """
    spec = _spec(method)
    k, p, info = validate_samples(kappa, psi)
    fit = combined_fit(k, p, method)
    pred = fit.prediction
    a, b = float(pred.a), float(pred.b)
    L = np.array([float(fit.L1_m), float(fit.L2_m)])
    # delta method: derivative of the lengths with respect to (a, b)
    G = np.zeros((2, 2))
    for j, (da, db) in enumerate(((1.0, 0.0), (0.0, 1.0))):
        if spec.pm_model == "PM1" and j == 1:
            continue
        h = 1e-6 * max(1.0, abs(a)) if j == 0 else 1e-6
        up = _lengths_given_line(k, p, a + h * da, b + h * db, spec)
        dn = _lengths_given_line(k, p, a - h * da, b - h * db, spec)
        G[:, j] = (up - dn) / (2 * h)
    cov = G @ pred.cov_ab @ G.T
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = float(cov[0, 1] / (sig[0] * sig[1])) if sig[0] > 0 and sig[1] > 0 else 0.0
    warnings = physical_warnings(float(L[0]), float(L[1]))
    check_curvature_bound(k, float(L[0]), float(L[1]), info["kappa_noise"])
    warnings.append("uncertainty is statistical only: the combined methods split the slope a "
                    "~ L1 + L2 by a straight-line fit of eq. (23) and are biased unless L1 ~ L2/2")
    em_conds = exact_condition_numbers(pred.kappa_model, pred.psi_model, spec.em_method)
    details = {
        "label": spec.label,
        "slope_a_m": a, "intercept_b_rad": b,
        "slope_a_sigma_m": float(math.sqrt(max(pred.cov_ab[0, 0], 0.0))),
        "pm_condition_number": float(pred.condition_number),
        "pm_singular_value_1": float(pred.singular_values[0]),
        "em_condition_number": float(fit.exact.condition_number),
        "em_condition_numbers": {m: float(v) for m, v in em_conds.items()},
        "kappa_noise": info["kappa_noise"], "psi_noise": info["psi_noise"],
    }
    return TrailerEstimate(method, float(L[0]), float(L[1]), float(sig[0]), float(sig[1]), corr,
                           float(fit.exact.condition_number), int(k.size), details, tuple(warnings))


def estimate_exact(kappa, psi, model: str = "EM1", method: str = "OLS1") -> TrailerEstimate:
    """EMLS alone (para. [0122]) on one validated run; sensitive to noise (Fig. 9)."""
    k, p, info = validate_samples(kappa, psi)
    fit = fit_exact_model(k, p, model, method)
    L1, L2 = float(fit.L1_m), float(fit.L2_m)
    sig = np.sqrt(np.maximum(np.diag(fit.cov_L), 0.0))
    corr = float(fit.cov_L[0, 1] / (sig[0] * sig[1])) if sig[0] > 0 and sig[1] > 0 else 0.0
    warnings = physical_warnings(L1, L2)
    check_curvature_bound(k, L1, L2, info["kappa_noise"])
    label = f"{method}({'EM1, 2, 3' if method == 'TLS' else model})"
    return TrailerEstimate(label, L1, L2, float(sig[0]), float(sig[1]), corr,
                           float(fit.condition_number), int(k.size),
                           {"kappa_noise": info["kappa_noise"], "psi_noise": info["psi_noise"]},
                           tuple(warnings))


__all__ = [
    "MIN_SAMPLES", "LS_METHODS", "PREDICTION_MODELS", "EXACT_MODELS", "METHODS", "BEST_METHODS",
    "LSResult", "PredictionFit", "ExactFit", "CombinedSpec", "CombinedFit", "TrailerEstimate",
    "ols", "tls", "noise_sigma", "validate_samples", "check_curvature_bound", "physical_warnings",
    "model_values", "fit_prediction_model", "exact_model_system", "lengths_from_beta",
    "fit_exact_model", "exact_condition_numbers", "combined_fit", "estimate_combined",
    "estimate_exact",
]
