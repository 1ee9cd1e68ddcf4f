"""Trailer diagnosis: where the patent's static model disagrees with a measured record, and why.

1. The simulation predicts the joint angle: the steady state of eq. (23)
   (seed 003) at the measured curvature, nominal ``L1``, ``L2``. Odometry's
   curvature is the average over the interval ending at each stamp
   (``sampling="interval"``, the default, as ``calibrate trailer`` takes
   it): the curvature at the stamp is taken between the intervals'
   midpoints (:func:`.trailer_fit.stamp_curvature`), so the record's
   half-interval lag is not mistaken for a lag of the trailer (nor, at the
   ideal trailer's relaxation, for a curvature gain).
2. Train / held-out split by time blocks spanning the record: the record is
   cut into ``n_blocks`` equal stretches of time and every fourth one (for a
   quarter held out) is held out, so held-out data sit all along the record.
   The model is always run over the whole record (the hitch's state carries
   through a held-out block driven by the curvature alone); only the
   residuals are split.
3. Candidates (:mod:`.trailer_fit`): ``link_lengths`` (L1, L2),
   ``hitch_angle_offset`` (the joint-angle sensor's zero),
   ``curvature_gain`` (the curvature sensor's scale), ``hitch_dynamics``
   (the joint angle's relaxation of eq. (D) that the static model ignores;
   an ideal trailer relaxes over ``L2``, and a selected relaxation is
   tested against ``L2`` at ``alpha``: one consistent with it is the ideal
   trailer's own dynamics, not an effect beyond the ideal trailer).
   Each is tested against the residual of the current model: the part of
   its columns the model cannot already produce (Frisch-Waugh), least
   squares, and a Wald statistic ``W`` with a heteroscedasticity- and
   autocorrelation-robust covariance (Bartlett weights over ``L`` lags,
   ``L`` twice the lag where the residual's autocorrelation falls below
   0.05: residuals are correlated over the relaxation time while a lag is
   left unmodelled, and their variance grows with the curvature). ``W / k``
   is compared with the ``1 - alpha / m`` quantile of ``F(k, n_train / L)``,
   ``m`` the candidates tested in that round (Bonferroni: a round's
   family-wise false-discovery rate is at most ``alpha``). (Clusters of
   seconds were tried first: a link-length contrast lives in the few
   stretches of large curvature, and with so few effective clusters the
   test rejected a true null 3 to 6 times too often.) The columns are built
   from a leave-one-out smoothing of the curvature, so the curvature noise
   of a sample cannot correlate a column with its own residual.
4. Forward selection: each significant candidate whose linearised step
   lowers the held-out RMS is refitted (nonlinear least squares); of those
   whose refit lowers it, the one that lowers it most is added, until
   nothing significant is left. A candidate whose refit runs a parameter to
   the edge of the model's domain (L2 of 1 mm, a gain of 5) is refused as
   not testable: no trailer is that, and the Wald test holds only at an
   interior optimum. When no significant candidate lowers the
   held-out RMS alone, one that does so together with a second candidate
   (significant after it) is added, and its step says so: an offset and a
   curvature gain of opposite effect can cancel on the held-out blocks. The refit is driven by the same leave-out curvature: driven
   by the measured one, a lag would be fitted long because filtering the
   curvature noise lowers the residual (errors in variables; +2 to 3 cm at
   a relaxation of a few cm). A relaxation longer than the smoothing
   window's travel filters the noise itself and is refitted driven by the
   measured curvature (:func:`_fit_input`); the robust covariance then spans
   at least the relaxation's memory (:func:`_memory`). Held-out RMS values are always of the model
   driven by the measured curvature, as the station runs it.
5. Ambiguity: a candidate significant in the round another was chosen, that
   explained at least half as much of the residual alone and is no longer
   significant (or no longer distinguishable) afterwards, explains the same
   residual and is named in the step. In the static model a curvature gain
   ``g`` is exactly link lengths scaled by ``g`` (eq. (23) depends on
   ``g kappa L1`` and ``g kappa L2`` only): the data cannot tell them apart,
   and the step says so.

Parameters come with 95 % intervals (HAC-robust covariance of the
refit, t quantile with ``n_train / L`` degrees of freedom), the curvature
noise's share that the robust window cannot see propagated through the
model and added (:mod:`.trailer_input_noise`: filtered by the relaxation,
that noise is correlated longer than the window reaches). Units: rad (RMS and
noise floor of the joint angle), m, 1/m, s.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from scipy import stats
from scipy.optimize import least_squares

from station.errors import DataError, InsufficientDataError
from station.models.trailer import check_lengths
from station.numeric import finite_or_none

from .candidate_significance import model_basis, refit_step, wald_block
from .summary_json import core_json
from .trailer_input_noise import unseen_input_meat
from .trailer_fit import (EFFECT_PARAMS, PARAM_NAMES, SAMPLINGS, columns, hac_bandwidth, hac_cov, loo_smooth,
                            null_params, predict, rms, segments, stamp_curvature)

__all__ = ["TrailerDiagnosis", "TrailerStep", "TrailerTest", "diagnose_trailer", "EFFECTS", "MIN_SAMPLES"]

EFFECTS = ("link_lengths", "hitch_angle_offset", "curvature_gain", "hitch_dynamics")
#: fewest samples a trailer diagnosis accepts
MIN_SAMPLES = 200
#: longest correlation of the residual the robust covariance looks for, s
MAX_CORRELATION_S = 20.0
#: fewest degrees of freedom of the robust covariance (training samples / bandwidth) for a test
MIN_DOF = 10
#: smallest relative size of the part of a candidate's columns the model cannot already produce
AMBIGUITY_SHARE = 0.5
#: the relaxation's time constants the robust covariance's bandwidth spans at least (see :func:`_memory`)
MEMORY_SPANS = 4
#: half-width of the curvature smoothing window, s
SMOOTH_HALF_WINDOW_S = 0.25
#: the relaxation's start when a lag is first fitted, m (or s without speed)
_ELL_START = 0.05
_BOUNDS = (np.array([0.0, 1e-3, -math.pi, 0.2, 0.0]), np.array([50.0, 50.0, math.pi, 5.0, 100.0]))


@dataclass
class TrailerTest:
    """One candidate tested against the current residual."""

    effect: str
    testable: bool
    reason: str = ""
    statistic: float = math.nan
    threshold: float = math.nan
    k: int = 0
    rss_reduction: float = 0.0       # rad^2, training
    heldout_rms_after: float = math.nan
    start: np.ndarray | None = None  # linearised estimate of the candidate's parameters

    @property
    def significant(self) -> bool:
        return self.testable and self.statistic > self.threshold

    def to_json(self) -> dict:
        d = {"candidate": self.effect, "effect": self.effect, "joint": None, "testable": self.testable}
        if self.testable:
            d.update(statistic=finite_or_none(self.statistic), threshold=finite_or_none(self.threshold), significant=self.significant,
                     dof=self.k, heldout_rms_after_rad=finite_or_none(self.heldout_rms_after))
        else:
            d["reason"] = self.reason
        return d


@dataclass
class TrailerStep:
    """One selected extension."""

    effect: str
    params: dict
    ci: dict
    heldout_rms_before: float
    heldout_rms_after: float
    statistic: float
    threshold: float
    test: str
    details: dict = field(default_factory=dict)
    ambiguous_with: list = field(default_factory=list)
    resid_before: np.ndarray | None = None
    resid_after: np.ndarray | None = None

    @property
    def gain(self) -> float:
        return 1.0 - self.heldout_rms_after / self.heldout_rms_before if self.heldout_rms_before > 0 else 0.0

    def to_json(self) -> dict:
        d = {"effect": self.effect, "joint": None, "params": self.params, "ci": self.ci,
             "heldout_rms_before": self.heldout_rms_before, "heldout_rms_after": self.heldout_rms_after,
             "gain": self.gain, "gain_percent": 100.0 * self.gain, "statistic": self.statistic,
             "threshold": self.threshold, "test": self.test, "ambiguous_with": self.ambiguous_with}
        if self.details:
            d["details"] = self.details
        return d


@dataclass
class TrailerDiagnosis:
    """Outcome of :func:`diagnose_trailer`; arrays kept for the report, :meth:`to_json` for the file."""

    steps: list
    rounds: list
    not_testable: dict
    train: np.ndarray
    heldout: np.ndarray
    simulation_heldout_rms: float
    final_heldout_rms: float
    noise_floor: float
    theta: np.ndarray
    active: list
    speed_known: bool
    resid_simulation: np.ndarray
    resid_final: np.ndarray
    variables: dict
    sensor_noise: dict
    alpha: float
    sampling: str = "interval"
    elapsed_s: float = 0.0

    @property
    def selected(self) -> list[str]:
        return [s.effect for s in self.steps]

    @property
    def gain(self) -> float:
        return 1.0 - self.final_heldout_rms / self.simulation_heldout_rms if self.simulation_heldout_rms > 0 else 0.0

    def extended_model(self) -> dict:
        """The extended model, and the same as a simulated trailer's settings."""
        L1, L2, off, g, ell = (float(x) for x in self.theta)
        model = {"L1_m": L1, "L2_m": L2, "offset_rad": off, "gain": g,
                 "relaxation_m" if self.speed_known else "relaxation_tau_s": ell, "effects": list(self.active)}
        # the simulated world measures kappa_m = kappa_gain * kappa and psi_m = psi + psi_offset
        model["sim_trailer"] = {"L1_m": L1, "L2_m": L2,
                                "sensor": {"psi_offset": off, "kappa_gain": 1.0 / g},
                                "note": "the simulated trailer's joint angle follows eq. (D), i.e. a relaxation "
                                        "of L2; a fitted relaxation far from L2 is a finding in itself"}
        return model

    def to_json(self) -> dict:
        return {
            **core_json(self, lambda ct: ct.effect),
            "sensor_noise": self.sensor_noise,
            "structure": {"simulation": _structure(self, self.resid_simulation),
                          "extended": _structure(self, self.resid_final)},
            "n_samples": {"train": int(self.train.size), "heldout": int(self.heldout.size)},
            "alpha": self.alpha,
            "sampling": self.sampling,
            "extended_model": self.extended_model(),
            "units": "rms and noise_floor: rad (joint angle); params: m, rad, 1 (gain), m (relaxation; s as "
                     "relaxation_tau_s without a v column); structure bins: 1/m, 1/(m s), s",
            "elapsed_s": self.elapsed_s,
        }


def _structure(res: TrailerDiagnosis, resid: np.ndarray, n_bins: int = 8) -> dict:
    """Held-out residual means in quantile bins of curvature, its rate and time (rad)."""
    out = {}
    h = res.heldout
    for name in ("kappa", "kappa_rate", "t"):
        x = res.variables[name][h]
        edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
        lab = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, max(edges.size - 2, 0))
        bins = []
        for b in range(max(edges.size - 1, 1)):
            m = lab == b
            if m.any():
                bins.append({"centre": float(np.mean(x[m])), "mean_rad": float(np.mean(resid[h][m])),
                             "n": int(m.sum())})
        out[name] = bins
    return out


# ----------------------------------------------------------------------------- inputs
def _check(t, kappa, psi, v, kappa_cmd) -> None:
    n = t.size
    for name, x in (("t_s", t), ("kappa", kappa), ("psi", psi), ("v_m_s", v), ("kappa_cmd", kappa_cmd)):
        if x is None:
            continue
        if x.ndim != 1 or x.size != n:
            raise DataError(f"`{name}` must be {n} values (1-D like t_s), got shape {x.shape}")
        bad = ~np.isfinite(x)
        if bad.any():
            raise DataError(f"`{name}` is not finite at row {int(np.flatnonzero(bad)[0]) + 1}")
    if n < MIN_SAMPLES:
        raise InsufficientDataError(f"a trailer diagnosis needs at least {MIN_SAMPLES} samples, got {n}")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0])
        raise DataError(f"`t_s` must increase strictly; row {i + 2} (t={t[i + 1]}) does not follow row {i + 1}")
    for name, x, lim in (("psi", psi, math.pi), ("kappa", kappa, 20.0)):
        bad = np.abs(x) > lim
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DataError(f"`{name}` row {i + 1} = {x[i]:.6g} is not a trailer's (|{name}| <= {lim:g})")
    if v is not None and np.any(v < 0):
        i = int(np.flatnonzero(v < 0)[0])
        raise DataError(f"`v_m_s` row {i + 1} = {v[i]:.6g}: the diagnosis needs forward motion (v >= 0)")


def _split(t: np.ndarray, heldout_fraction: float, n_blocks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(train, heldout, block)``: every ``round(1/fraction)``-th of ``n_blocks`` equal time stretches held out."""
    if not (0.05 <= heldout_fraction <= 0.5):
        raise DataError(f"`heldout_fraction` must be in [0.05, 0.5], got {heldout_fraction!r}")
    if not (isinstance(n_blocks, int) and 4 <= n_blocks <= 200):
        raise DataError(f"`n_blocks` must be an integer in [4, 200], got {n_blocks!r}")
    edges = np.linspace(t[0], t[-1], n_blocks + 1)
    block = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n_blocks - 1)
    every = max(2, int(round(1.0 / heldout_fraction)))
    held = block % every == every // 2
    return np.flatnonzero(~held), np.flatnonzero(held), block


# ----------------------------------------------------------------------------- fitting
def _idx(active) -> list[int]:
    return [i for e in active for i in EFFECT_PARAMS[e]]


def _at_bound(theta: np.ndarray, active: list) -> str | None:
    """``"name = value"`` of the first active parameter on a bound of the fit's domain, or None."""
    for i in _idx(active):
        lo, hi = _BOUNDS[0][i], _BOUNDS[1][i]
        tol = 1e-6 * max(hi - lo, 1.0)
        if (theta[i] <= lo + tol and not (i == 4 and lo == 0.0)) or theta[i] >= hi - tol:
            return f"{PARAM_NAMES[i]} = {theta[i]:.4g}"
    return None


def _fit(theta: np.ndarray, active: list, kappa, dist, psi, train) -> np.ndarray:
    idx = _idx(active)
    if not idx:
        return theta
    th = theta.copy()

    def resid(x):
        th[idx] = x
        return (psi - predict(th, kappa, dist))[train]

    x0 = np.clip(theta[idx], _BOUNDS[0][idx] + 1e-9, _BOUNDS[1][idx] - 1e-9)
    sol = least_squares(resid, x0, bounds=(_BOUNDS[0][idx], _BOUNDS[1][idx]), method="trf", x_scale="jac",
                        xtol=1e-10, ftol=1e-12, max_nfev=200)
    out = theta.copy()
    out[idx] = sol.x
    return out


def _memory(theta: np.ndarray, ctx: dict) -> int:
    """Samples over which the model's residual is correlated by construction, at least.

    The model is driven by a noisy curvature: its prediction carries that
    noise through the smoothing window (both sides) and through the joint
    angle's relaxation (``relaxation / v dt`` samples, an exponential memory
    whose tail the Bartlett weights reach to about three quarters at
    ``MEMORY_SPANS`` spans). Small in variance beside the joint-angle
    noise, so the residual's own autocorrelation does not show it, but at
    the low frequencies of the columns it is as large as the curvature
    noise times the slope of eq. (23).
    """
    span = float(theta[4]) / ctx["dist_median"]
    return int(math.ceil(MEMORY_SPANS * span)) + 2 * ctx["half_window"] + 1


def _rows(theta: np.ndarray, ctx: dict) -> tuple[np.ndarray, np.ndarray]:
    """Training rows past the model's start-up, and the contiguous stretch of each.

    The record starts wherever the joint angle is; the model starts it at
    the steady state of the first sample. With a relaxation the difference
    dies out over the travel of ``MEMORY_SPANS`` relaxations (to e^-4):
    the rows before that are left out of fits and tests (a start-up error
    would otherwise pull the relaxation by up to a millimetre).
    """
    settled = ctx["travel"][ctx["train"]] >= MEMORY_SPANS * float(theta[4])
    if settled.all():
        return ctx["train"], ctx["seg"]
    rows = ctx["train"][settled]
    return rows, segments(rows)


def _robust(resid_train: np.ndarray, seg: np.ndarray, ctx: dict, theta: np.ndarray) -> tuple[int, float]:
    """HAC bandwidth (samples) for this residual and the degrees of freedom it leaves."""
    L = max(hac_bandwidth(resid_train, seg, ctx["max_lag"]), min(_memory(theta, ctx), ctx["max_lag"]))
    return L, resid_train.size / L


def _cov(theta, active, ctx) -> tuple[list, np.ndarray, float]:
    """``(indices, covariance, dof)`` of the active parameters (HAC-robust, the refit's curvature and rows).

    The curvature noise the model is driven by is correlated in the residual
    over the relaxation's memory, longer than the robust window reaches: its
    share the window cannot see is propagated from the curvature's measured
    noise and added (:mod:`.trailer_input_noise`).
    """
    key = (np.asarray(theta, dtype=float).tobytes(), tuple(active))
    if key in ctx["covariances"]:  # a step's model is the final one's when it is the last step
        return ctx["covariances"][key]
    train, seg = _rows(theta, ctx)
    idx = _idx(active)
    kappa = _fit_input(theta, ctx)
    J = columns(theta, kappa, ctx["dist"], idx)[train]
    r = (ctx["psi"] - predict(theta, kappa, ctx["dist"]))[train]
    L, dof = _robust(r, seg, ctx, theta)
    unseen = unseen_input_meat(theta, J, train, seg, L, kappa_in=kappa, to_input=_input_map(theta, ctx),
                               dist_m=ctx["dist"], sigma=ctx["kappa_sigma"])
    ctx["covariances"][key] = idx, hac_cov(J, r, seg, L, unseen), max(dof, 1.0)
    return ctx["covariances"][key]


def _params_ci(theta, active, effect, ctx, speed_known) -> tuple[dict, dict]:
    """The effect's parameters and their 95 % intervals."""
    idx, cov, dof = _cov(theta, active, ctx)
    tq = float(stats.t.ppf(0.975, dof))
    params, ci = {}, {}
    for j, i in enumerate(idx):
        if i not in EFFECT_PARAMS[effect]:
            continue
        name = PARAM_NAMES[i] if (i != 4 or speed_known) else "relaxation_tau_s"
        sd = math.sqrt(max(float(cov[j, j]), 0.0))
        params[name] = float(theta[i])
        ci[name] = [float(theta[i] - tq * sd), float(theta[i] + tq * sd)]
    return params, ci


def _ideal_trailer(theta, active, ctx, alpha: float) -> dict:
    """Is the fitted relaxation the ideal trailer's (eq. (D): it relaxes over L2)? A two-sided t test at ``alpha``.

    Of the final model: ``relaxation - L2`` with the covariance of both
    when the link lengths are fitted too.
    """
    idx, cov, dof = _cov(theta, active, ctx)
    g = np.zeros(len(idx))
    g[idx.index(4)] = 1.0
    if 1 in idx:
        g[idx.index(1)] = -1.0
    sd = math.sqrt(max(float(g @ cov @ g), 0.0))
    ell, L2 = float(theta[4]), float(theta[1])
    t_stat = abs(ell - L2) / sd if sd > 0 else math.inf
    ideal = bool(t_stat <= float(stats.t.ppf(1.0 - alpha / 2.0, dof)))
    return {"relaxation_expected_m": L2, "ideal_trailer": ideal,
            "ideal_trailer_t": finite_or_none(t_stat),
            "note": ("the ideal trailer of eq. (D) relaxes over L2: a relaxation consistent with L2 (t test at "
                     f"{alpha:g}) is its own dynamics, which the static model of eq. (23) leaves out, not an "
                     "effect beyond the ideal trailer" if ideal else
                     f"the relaxation differs from L2, the ideal trailer's (eq. (D); t test at {alpha:g}): "
                     "the hitch's own dynamics")}


# ----------------------------------------------------------------------------- structure tests
def _test_round(theta, active, remaining, ctx, alpha) -> list[TrailerTest]:
    kap, ks, ksr, dist, v, psi, held = (ctx[k] for k in ("kappa", "kappa_s", "kappa_rate", "dist", "v", "psi",
                                                          "heldout"))
    train, seg = _rows(theta, ctx)
    r = psi - predict(theta, kap, dist)
    rt, rh = r[train], r[held]
    L, dof = _robust(rt, seg, ctx, theta)
    idx = _idx(active)
    M = columns(theta, ks, dist, idx, kappa_rate=ksr, v_m_s=v)
    Mt, Mh = M[train], M[held]
    Q = model_basis(Mt)
    m = len(remaining)
    out = []
    for effect in remaining:
        pidx = list(EFFECT_PARAMS[effect])
        k = len(pidx)
        ct = TrailerTest(effect, True, k=k)
        if dof < MIN_DOF:
            ct.testable, ct.reason = False, (f"the residual is correlated over {L} samples: {train.size} training "
                                             f"samples hold {dof:.1f} independent stretches, the test needs "
                                             f"{MIN_DOF} (a longer record)")
            out.append(ct)
            continue
        Z = columns(theta, ks, dist, pidx, kappa_rate=ksr, v_m_s=v)
        Zt, Zh = Z[train], Z[held]
        bt = wald_block(Zt, rt, Q, lambda X, res: hac_cov(X, res, seg, L))
        if bt.why is not None:
            if bt.why == "no effect":
                why = ("the curvature never changes: there is no lag to see" if effect == "hitch_dynamics"
                       else "it does not change the predicted joint angle in these data (no curvature)")
            else:
                why = f"indistinguishable in these data from parameters already in the model ({', '.join(active) or 'none'})"
            ct.testable, ct.reason = False, why
            out.append(ct)
            continue
        ct.rss_reduction = bt.rss_reduction
        ct.statistic = bt.wald / k
        ct.threshold = float(stats.f.isf(alpha / max(m, 1), k, dof))
        step = refit_step(Mt, Zt, rt)
        ct.heldout_rms_after = rms(rh - np.concatenate([Mh, Zh], axis=1) @ step)
        ct.start = step[len(idx):]
        out.append(ct)
    return out


def _refit(theta, ct: TrailerTest, new_active, ctx) -> np.ndarray:
    start = theta.copy()
    pidx = list(EFFECT_PARAMS[ct.effect])
    start[pidx] += ct.start
    if ct.effect == "hitch_dynamics":
        start[4] = max(float(start[4]), _ELL_START)
    rows = _rows(start, ctx)[0]
    th = _fit(start, new_active, ctx["kappa_s"], ctx["dist"], ctx["psi"], rows)
    now = _rows(th, ctx)[0]
    if _fit_input(th, ctx) is not ctx["kappa_s"] or now.size != rows.size:
        th = _fit(th, new_active, _fit_input(th, ctx), ctx["dist"], ctx["psi"], now)
    return th


def _fit_input(theta: np.ndarray, ctx: dict) -> np.ndarray:
    """The curvature a refit is driven by: the leave-out smoothing, or the measured one behind a long relaxation.

    Driven by the measured curvature, a short relaxation is fitted long
    (it filters the curvature noise: errors in variables, see the module's
    notes). A relaxation longer than the smoothing window's travel filters
    that noise itself (the bias falls as ``v dt / l^2``), while the
    smoothing's own low-pass (its second moment times the curvature's
    second derivative) would shorten the fitted relaxation by a few
    millimetres at the ideal trailer's ``L2``: there the measured curvature
    drives the fit.
    """
    return ctx["kappa_s"] if _smoothed_input(theta, ctx) else ctx["kappa"]


def _smoothed_input(theta: np.ndarray, ctx: dict) -> bool:
    """Is a refit at ``theta`` driven by the leave-out smoothing (see :func:`_fit_input`)?"""
    window_m = (2 * ctx["half_window"] + 1) * ctx["dist_median"]
    return float(theta[4]) <= window_m


def _input_map(theta: np.ndarray, ctx: dict):
    """The linear map from the measured curvature's noise to its part of :func:`_fit_input`."""
    t, sampling = ctx["t"], ctx["sampling"]
    if _smoothed_input(theta, ctx):
        return lambda noise: loo_smooth(t, noise, ctx["half_window"], sampling)[0]
    return lambda noise: stamp_curvature(t, noise, sampling)


def _pair_lookahead(theta, active, remaining, tests, ctx, alpha, ho_now):
    """A significant candidate that lowers the held-out RMS only together with a second one.

    Tried in order of significance: fitted, the next round tested; accepted
    when a candidate of that round is significant and the pair lowers the
    held-out RMS. Returns ``(test, theta, partner)`` or None.
    """
    for ct in sorted((c for c in tests if c.significant), key=lambda c: -c.statistic / c.threshold):
        trial_active = active + [ct.effect]
        trial = _refit(theta, ct, trial_active, ctx)
        rest = [e for e in remaining if e != ct.effect]
        nxt = _test_round(trial, trial_active, rest, ctx, alpha) if rest else []
        ok = [c for c in nxt if c.significant and c.heldout_rms_after < ho_now]
        if ok:
            return ct, trial, min(ok, key=lambda c: c.heldout_rms_after).effect
    return None


def diagnose_trailer(t_s, kappa, psi, *, L1_m: float, L2_m: float, v_m_s=None, kappa_cmd=None,
                     sampling: str = "interval", heldout_fraction: float = 0.25, alpha: float = 0.05,
                     n_blocks: int = 40, max_steps: int = 4) -> TrailerDiagnosis:
    """Diagnose the patent's static trailer model against a measured record.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Strictly increasing sample times, s.
    kappa : array_like, shape (N,)
        Measured path curvature, 1/m (odometry: the average over the interval ending at ``t``).
    sampling : {"interval", "point"}
        ``kappa`` and ``v_m_s`` are averages over the interval ending at
        each stamp (odometry; default) or values at the stamp.
    psi : array_like, shape (N,)
        Measured joint angle, rad.
    L1_m, L2_m : float
        Nominal link lengths, m (the station's model).
    v_m_s : array_like, shape (N,), optional
        Speed, m/s. Without it the speed is taken as 1 m/s and the lag's
        parameter is a time constant (``relaxation_tau_s``).
    kappa_cmd : array_like, shape (N,), optional
        Commanded curvature; checked and kept for the report (the station's
        model predicts from the measured curvature).
    heldout_fraction : float
        Share of the record held out, as every ``round(1/fraction)``-th of ``n_blocks`` time blocks.
    alpha : float
        Family-wise false-discovery rate of each selection round.
    """
    t0 = time.perf_counter()
    L1, L2 = check_lengths(L1_m, L2_m)
    t = np.asarray(t_s, dtype=float)
    kap = np.asarray(kappa, dtype=float)
    ps = np.asarray(psi, dtype=float)
    v = None if v_m_s is None else np.asarray(v_m_s, dtype=float)
    cmd = None if kappa_cmd is None else np.asarray(kappa_cmd, dtype=float)
    if t.ndim != 1:
        raise DataError(f"`t_s` must be 1-D, got shape {t.shape}")
    _check(t, kap, ps, v, cmd)
    if sampling not in SAMPLINGS:
        raise DataError(f"`sampling` must be one of {', '.join(SAMPLINGS)}, got {sampling!r}")
    if not (0.0 < alpha < 0.5):
        raise DataError(f"`alpha` must be in (0, 0.5), got {alpha!r}")
    train, held, _ = _split(t, heldout_fraction, n_blocks)
    speed_known = v is not None
    vv = v if speed_known else np.ones_like(t)
    dt = np.diff(t)
    dt_all = np.concatenate([[float(np.median(dt))], dt])
    # distance over the interval ending at each stamp: an interval's average speed times its length, or the
    # trapezoid between the speeds at its ends
    dist = vv * dt_all if sampling == "interval" else np.concatenate([[vv[0]], 0.5 * (vv[1:] + vv[:-1])]) * dt_all
    half = max(2, int(round(SMOOTH_HALF_WINDOW_S / float(np.median(dt)))))
    ks, ksr = loo_smooth(t, kap, half, sampling)
    from station.analysis.trailer.least_squares import noise_sigma

    sensor_noise = {"psi_sigma_rad": float(noise_sigma(ps)), "kappa_sigma_1_m": float(noise_sigma(kap))}
    kap = stamp_curvature(t, kap, sampling)  # the curvature the model is driven by, at the stamps
    ctx = {"t": t, "sampling": sampling, "kappa_sigma": sensor_noise["kappa_sigma_1_m"], "covariances": {},
           "kappa": kap, "kappa_s": ks, "kappa_rate": ksr, "dist": dist, "v": vv, "psi": ps, "train": train,
           "travel": np.cumsum(dist) - dist[0],
           "dist_median": max(float(np.median(dist[1:])), 1e-9), "half_window": half,
           "heldout": held, "seg": segments(train),
           "max_lag": max(5, min(int(MAX_CORRELATION_S / float(np.median(dt))), train.size // (2 * MIN_DOF)))}
    not_testable: dict = {}
    candidates = list(EFFECTS)
    if float(np.max(np.abs(ks))) < 1e-9:
        for e in ("link_lengths", "curvature_gain", "hitch_dynamics"):
            not_testable[e] = "the curvature is zero throughout: the trailer went straight"
        candidates = ["hitch_angle_offset"]

    theta = null_params(L1, L2)
    active: list[str] = []
    resid_sim = ps - predict(theta, kap, dist)
    sim_ho = rms(resid_sim[held])
    steps: list[TrailerStep] = []
    rounds: list[list[TrailerTest]] = []
    remaining = list(candidates)
    prev_tests: list[TrailerTest] = []
    chosen_prev: TrailerTest | None = None
    test_name = (f"HAC-robust Wald W/k (Bartlett, bandwidth L from the residual's correlation) against "
                 f"F(k, n_train/L) at 1 - {alpha:g}/m, m the round's candidates (Bonferroni)")
    for _ in range(max_steps + 1):
        tests = _test_round(theta, active, remaining, ctx, alpha) if remaining else []
        rounds.append(tests)
        if chosen_prev is not None and steps:
            now = {ct.effect: ct for ct in tests}
            for ct in prev_tests:
                if ct.effect == chosen_prev.effect or not ct.testable or \
                        ct.rss_reduction < AMBIGUITY_SHARE * chosen_prev.rss_reduction:
                    continue
                later = now.get(ct.effect)
                if ct.significant and (later is None or not later.significant):
                    note = "explains the same residual: nothing significant is left of it after this step"
                elif later is not None and not later.testable and later.reason.startswith("indistinguishable"):
                    # not significant alone beside another effect, but the step's parameters now span it:
                    # the step's residual could as well be this effect's (with the other one's)
                    note = ("explains much of the same residual and is indistinguishable in these data from "
                            "this step's parameters")
                else:
                    continue
                steps[-1].ambiguous_with.append(
                    {"effect": ct.effect, "joint": None,
                     "share_of_residual_explained": ct.rss_reduction / chosen_prev.rss_reduction,
                     "heldout_rms_alone": ct.heldout_rms_after, "note": note})
        if len(steps) >= max_steps:
            break
        ho_now = rms((ps - predict(theta, kap, dist))[held])
        sig = sorted((ct for ct in tests if ct.significant and ct.heldout_rms_after < ho_now),
                     key=lambda ct: ct.heldout_rms_after)
        pair_note = None
        best = None
        fits = []
        for ct in sig:
            # the linearised step tests the candidates; their refits choose: a relaxation enters the model far
            # from linearly (its step from 0 ranked an offset first that refitted to about 1 % of its step, and a
            # refit of link lengths after it ran L2 to 1 mm, CI seed 2906433913). One whose refit runs a
            # parameter to the edge of the model's domain (L2 of 1 mm, a gain of 5) is no trailer, and its
            # test, a Wald test at an interior optimum, does not hold there
            trial_active = active + [ct.effect]
            trial = _refit(theta, ct, trial_active, ctx)
            edge = _at_bound(trial, trial_active)
            if edge is not None:
                ct.testable, ct.reason = False, (f"its refit runs {edge} to the edge of the model's domain: no "
                                                 "physical trailer fits these data with it")
                continue
            ho = rms((ps - predict(trial, kap, dist))[held])
            if ho < ho_now:
                fits.append((ho, ct, trial_active, trial))
        if fits:
            _, best, new_active, new_theta = min(fits, key=lambda f: f[0])
        elif not sig:  # (significant ones whose refits lower nothing or run to an edge: nothing is added)
            # two effects whose residuals cancel on the held-out blocks: each alone lowers nothing there
            found = _pair_lookahead(theta, active, remaining, tests, ctx, alpha, ho_now)
            if found is not None:
                best, new_theta, partner = found
                new_active = active + [best.effect]
                pair_note = (f"alone it does not lower the held-out RMS; together with {partner}, significant "
                             "after it, it does")
        if best is None:
            break
        r_before = ps - predict(theta, kap, dist)
        r_after = ps - predict(new_theta, kap, dist)
        params, ci = _params_ci(new_theta, new_active, best.effect, ctx, speed_known)
        details = {"selected_as_pair": pair_note} if pair_note else {}
        if best.effect == "hitch_dynamics" and not speed_known:
            details |= {"relaxation_expected_m": None, "ideal_trailer": None,
                        "note": "no v column: constant speed of 1 m/s assumed, the relaxation is a time "
                                "constant and cannot be held against L2"}
        steps.append(TrailerStep(best.effect, params, ci, ho_now, rms(r_after[held]), best.statistic,
                                 best.threshold, test_name, details, resid_before=r_before, resid_after=r_after))
        theta, active = new_theta, new_active
        remaining = [e for e in remaining if e != best.effect]
        prev_tests = tests
        chosen_prev = best
    if speed_known and "hitch_dynamics" in active:  # held against the final model's L2
        next(s for s in steps if s.effect == "hitch_dynamics").details.update(_ideal_trailer(theta, active, ctx, alpha))
    resid_final = ps - predict(theta, kap, dist)
    n_par = len(_idx(active))
    noise_floor = math.sqrt(float(resid_final[train] @ resid_final[train]) / max(train.size - n_par, 1))
    variables = {"t": t, "kappa": kap, "kappa_rate": ksr, "v": v, "kappa_cmd": cmd}
    return TrailerDiagnosis(steps, rounds, not_testable, train, held, sim_ho, rms(resid_final[held]), noise_floor,
                            theta, active, speed_known, resid_sim, resid_final, variables, sensor_noise, alpha,
                            sampling, time.perf_counter() - t0)
