"""Arm diagnosis: where the station's simulation disagrees with measured data, and why.

1. The simulation predicts the measurements: nominal table, base transform
   fitted on the training poses (:mod:`.arm_fit`).
2. Train / held-out split spanning the workspace (:mod:`.split`); the rows
   are first put in motion order (by ``t``, or as given with
   ``rows_in_motion_order``) or, without one, in a canonical order, so the
   answer does not depend on how the rows were shuffled.
3. Geometry first: the geometric calibration of the training poses
   (:func:`station.analysis.arm_identification.identify`, the shared
   Levenberg-Marquardt solver) is the start of everything else. It is
   *named* when a partial F test of its columns against the simulation's
   residual passes and the calibration, fitted without each fold of the
   training poses, predicts that fold better than the nominal model does
   (:mod:`.geometry_cv`: the question the user asks, with the calibration
   itself rather than a linearised refit), or the nominal model predicts the
   folds' poses to the noise (they hold no geometric error: the folds cannot
   tell and the F test judges alone, said so). The folds respect the poses'
   layout (:mod:`station.analysis.arm.pose_structure`): on one-joint sweeps
   every sweep's ends stay in training, the test is then interpolation only
   and says so, and the sweep ends held out give an extrapolation figure
   that is reported, never judged. When geometry cannot be tested, nothing
   else is named. Geometry that is not named is still adopted (every
   other step starts from the calibration); when effects are then named,
   geometry is judged again by its partial F in the model with them
   (:func:`_geometry_with_effects`): their residual, left in the first
   test's denominator, can hide a geometry the folds said was better.
4. Every other candidate term (:mod:`.terms`) is tested against the
   residual left by the current model: the part of its Jacobian columns the
   model cannot already produce (Frisch-Waugh), least squares, and a
   cluster-robust Wald statistic ``W`` (poses are the clusters;
   :func:`.arm_fit.robust_cov`, never below the classical covariance in
   any direction, :func:`.arm_fit.classical_floor`) against the ``1 - alpha / m`` quantile of
   ``F(k, n_train - p/3)`` (Bonferroni over the round's candidates).
5. Choice (nested): of the significant candidates, those whose linearised
   refit lowers the K-fold cross-validated squared error *inside the
   training poses* by more than one standard error of the paired difference
   (:func:`cv_gain`); the lowest is refitted (the shared solver); a refit
   with no training gain, a zero estimate or a joint error beyond
   :data:`PLAUSIBLE_JOINT_ERROR_RAD` is no step. The held-out poses never
   take part in a choice: they report the gain.
6. Rivals (issue 43 item 4): of the round's chosen candidates, each pair is
   compared by an encompassing test, each one's columns beyond the model and
   the other's, against the residual of the model with both
   (:func:`_order_by_encompassing`): one that explains what the
   other cannot, while the other explains nothing beyond it, goes first
   (encoder eccentricity, once per turn in q, against joint compliance, the
   gravity torque of the arm's configuration); the step says which it told
   apart (``told_apart_from``), and names as candidates with it those neither
   of which explains anything beyond the other (both statistics given; the
   cross-validation chose which of them goes first, and either may: an
   eccentricity in phase with the elbow mass's torque is, on those poses,
   the same columns as a compliance).
7. Ambiguity: a candidate that was significant in the round another one was
   chosen, explained at least half as much of the residual alone, is no
   longer significant after it, and was not told apart from it, explains the
   same residual: the step names it.

The model written out (:meth:`ArmDiagnosis.extended_model`) starts from the
calibration of every pose; the named effects are fitted on it with the
geometry re-identified with them (poses spread over the joint space) or
held (one-joint sweeps, whose unseen poses lie beyond the sweeps' range);
the effects are written only when the same construction on the training
poses predicts the held-out poses no worse than the calibration alone
(``written_model`` says which, with both figures).

The noise floor is the pooled scatter of repeated measurements of the same
joint angles when there are any, otherwise the geometric fit's training
residual corrected for its degrees of freedom (``noise_floor_source``).

Parameters come with 95 % confidence intervals from the cluster-robust
covariance of the refit (t quantile). Lengths mm, angles rad (as the
effects in :mod:`station.models.effects`), ``heldout_rms`` the RMS of the
3-D position error over the held-out poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from scipy import stats

from station.analysis.arm.screen import screen_arm_poses
from station.errors import DataError, InsufficientDataError
from station.models import kinematics as kin
from station.numeric import finite_or_none

from .arm_fit import ModelState, classical_floor, fit_report, initial_state, jacobian, predict, robust_cov
from .candidate_significance import model_basis, wald_block
from station.analysis.arm.pose_structure import pose_structure, structured_folds, sweep_end_folds
from station.analysis.arm.split import workspace_split
from .geometry_cv import beats_nominal, fold_errors, folds_see_geometry
from .summary_json import core_json
from station.models.effects import motion_directions

from .terms import Term, joint_terms, thermal_terms

#: most poses a diagnosis takes (the reader's limit, station.readers.arm_csv.MAX_ROWS)
MAX_POSES = 20_000
#: largest joint angle taken, rad (ten turns)
MAX_ABS_Q_RAD = 20.0 * math.pi

__all__ = ["ArmDiagnosis", "Step", "CandidateTest", "diagnose_arm", "MIN_DOF_POSES"]

#: a candidate needs this many training poses beyond its parameters and the model's (per 3 coordinates)
MIN_DOF_POSES = 10
#: smallest relative size of the part of a candidate's columns the model cannot already produce
#: a second candidate "explains the same residual" when it alone took at least this share of the chosen one's
AMBIGUITY_SHARE = 0.5


@dataclass
class CandidateTest:
    """One candidate tested against the current residual."""

    key: str
    effect: str
    joint: int | None
    testable: bool
    reason: str = ""
    statistic: float = math.nan      # W / k
    threshold: float = math.nan
    k: int = 0
    rss_reduction: float = 0.0      # mm^2, training
    heldout_rms_after: float = math.nan   # cross-validated RMS inside the training poses with the candidate
    cv_gain: bool = False                 # lowers it by more than CV_GAIN_SE standard errors
    variant: Term | None = None
    resid_var: float = math.nan           # geometry: residual variance per coordinate with it, mm^2
    resid_dof: float = math.nan           # ... and its degrees of freedom
    folds_blind: bool = False             # geometry: the folds' poses hold no error to predict (cannot judge)

    @property
    def significant(self) -> bool:
        return self.testable and self.statistic > self.threshold

    def to_json(self) -> dict:
        d = {"candidate": self.key, "effect": self.effect, "joint": self.joint, "testable": self.testable}
        if self.testable:
            d.update(statistic=finite_or_none(self.statistic), threshold=finite_or_none(self.threshold), significant=self.significant,
                     dof=self.k, cv_rms_after_mm=finite_or_none(self.heldout_rms_after), cv_gain=self.cv_gain)
        else:
            d["reason"] = self.reason
        return d


@dataclass
class Step:
    """One selected extension."""

    term: Term
    params: dict
    ci: dict
    heldout_rms_before: float
    heldout_rms_after: float
    statistic: float
    threshold: float
    test: str
    ambiguous_with: list = field(default_factory=list)
    resid_before: np.ndarray | None = None
    resid_after: np.ndarray | None = None
    cv: tuple | None = None          # cross-validated RMS inside the training poses, before and after (chose it)
    told_apart: list = field(default_factory=list)  # rivals of the same residual the encompassing test ruled out

    @property
    def gain(self) -> float:
        return 1.0 - self.heldout_rms_after / self.heldout_rms_before if self.heldout_rms_before > 0 else 0.0

    def to_json(self) -> dict:
        d = {"effect": self.term.effect, "joint": self.term.joint, "params": self.params, "ci": self.ci,
             "heldout_rms_before": self.heldout_rms_before, "heldout_rms_after": self.heldout_rms_after,
             "gain": self.gain, "gain_percent": 100.0 * self.gain, "statistic": self.statistic,
             "threshold": self.threshold, "test": self.test, "ambiguous_with": self.ambiguous_with,
             "told_apart_from": self.told_apart}
        if self.cv is not None:
            d["cv_rms_before"], d["cv_rms_after"] = float(self.cv[0]), float(self.cv[1])
        if self.term.extra:
            d["details"] = {k: v for k, v in self.term.extra.items()}
        return d


@dataclass
class ArmDiagnosis:
    """Outcome of :func:`diagnose_arm`; arrays kept for the report, :meth:`to_json` for the file."""

    steps: list
    rounds: list                 # list of lists of CandidateTest (the structure tests, one list per round)
    not_testable: dict           # key -> reason (from the data, before any round)
    train: np.ndarray
    heldout: np.ndarray
    simulation_heldout_rms: float
    final_heldout_rms: float
    noise_floor: float
    state: ModelState
    resid_simulation: np.ndarray
    resid_final: np.ndarray
    variables: dict
    alpha: float
    elapsed_s: float = 0.0
    noise_floor_source: str = ""
    fit_residual_floor: float = math.nan
    geometry: dict = field(default_factory=dict)
    stop_reason: str | None = None
    row_order: str = ""
    state_all: ModelState | None = None
    refs: dict = field(default_factory=dict)
    fits: list = field(default_factory=list)
    selection: str = ""
    rejected: dict = field(default_factory=dict)   # significant and cross-validated, but implausible: not named
    written: dict = field(default_factory=dict)    # the check of the written model's effects (see _check_effects_on_heldout)

    @property
    def converged(self) -> bool:
        """Every fit of the diagnosis converged (the command exits non-zero otherwise)."""
        return all(f["converged"] for f in self.fits)

    @property
    def selected(self) -> list[tuple[str, int | None]]:
        return [(s.term.effect, s.term.joint) for s in self.steps]

    @property
    def gain(self) -> float:
        return 1.0 - self.final_heldout_rms / self.simulation_heldout_rms if self.simulation_heldout_rms > 0 else 0.0

    def extended_model(self, *, name: str = "diagnosed", gravity_model: str | None = None,
                       joint_limits_rad=None) -> dict:
        """The extended model file (schema of :mod:`station.models.arm_model_file`): from the calibration of
        every pose, the named effects fitted on every pose with the geometry re-identified with them (spread
        poses) or held (one-joint sweeps); ``station predict``/``compensate`` read it."""
        from station.models.arm_extended import EffectTerm, terms_to_json
        from station.models.arm_model_file import model_to_json

        st = self.state_all if self.state_all is not None else self.state
        terms = []
        for term, th in zip(st.terms, st.theta):
            if term.kind == "geometric":
                continue
            params = {name: float(v) for name, v in zip(term.param_names, th)}
            extra = {}
            if term.effect == "thermal_drift":
                if "tau_s" in term.extra:
                    extra = {"tau_s": float(term.extra["tau_s"]), "t0_s": float(self.refs.get("t0_s") or 0.0)}
                else:
                    extra = {"reference_temperature_c": float(self.refs.get("reference_temperature_c") or 20.0)}
            terms.append(EffectTerm(term.effect, term.joint, params, extra))
        base = np.eye(4)
        base[:3, :3], base[:3, 3] = st.R, st.t
        doc = model_to_json(st.dh_static(), base, name=name, joint_limits_rad=joint_limits_rad)
        doc["effects"] = terms_to_json(terms)
        uses_mass = any(t.effect == "joint_compliance" and any(n.startswith("c") for n in t.params) for t in terms)
        if uses_mass:
            doc["gravity_model"] = gravity_model
        return doc

    def to_json(self) -> dict:
        return {
            **core_json(self, lambda ct: ct.key),
            "n_poses": {"train": int(self.train.size), "heldout": int(self.heldout.size)},
            "alpha": self.alpha,
            "extended_model": self.extended_model(),
            "noise_floor_source": self.noise_floor_source,
            "fit_residual_floor": finite_or_none(self.fit_residual_floor),
            "geometry": self.geometry,
            "stop_reason": self.stop_reason,
            "row_order": self.row_order,
            "selection": self.selection,
            "fits": self.fits,
            "rejected": self.rejected,
            "written_model": self.written,
            "converged": self.converged,
            "units": "rms and noise_floor: mm (3-D position error); params: mm, rad, rad per N m, 1/K as named",
            "elapsed_s": self.elapsed_s,
        }


def _rms(resid: np.ndarray) -> float:
    return math.sqrt(float(np.mean(np.sum(resid ** 2, axis=1)))) if resid.size else math.nan


def _geometric_term(dh, q, meas, train):
    """The geometric candidate and its calibration: what :func:`identify` finds identifiable on the training
    poses, fitted by the shared solver from a base/tool fit. ``(term, identification, reason)``."""
    from station.analysis.arm.identification import identify

    try:
        res = identify(dh, q[train], meas[train], method="absolute")
    except InsufficientDataError as exc:
        return None, None, f"too few poses: {exc}"
    except DataError as exc:
        return None, None, str(exc)
    # what the poses see; a parameter the identification held at its start by the prior is left out here
    held = res.extra.get("held", {})
    free = np.array([i for i, nm in zip(res.identifiability.free, res.identifiability.names)
                     if i < kin.N_PARAMS and nm not in held], dtype=np.int64)
    if free.size == 0:
        return None, None, "no kinematic parameter is identifiable from these poses"
    from station.models.effects import Geometric

    names = tuple(Geometric().param_names[i] for i in free)
    return Term("geometric", None, "geometric", names, index=free,
                extra={"fixed": {**res.identifiability.fixed, **held}}), res, None


def _held_at_calibration(dh, res) -> np.ndarray:
    """``dh`` with the parameters the identification held by its prior (the poses barely see them) at their
    calibrated values: the geometric term fits what the poses see around them, as the calibration did."""
    out = np.array(dh, dtype=float).reshape(-1).copy()
    held = res.extra.get("held", {})
    for i, nm in zip(res.identifiability.free, res.identifiability.names):
        if nm in held and i < kin.N_PARAMS:
            out[i] = res.dh.reshape(-1)[i]
    return out.reshape(np.shape(dh))


def _with_geometry(state: ModelState, geo: Term, res, dh) -> ModelState:
    """``state`` with the geometric term at the calibration ``res`` (its base, what it identified and what
    it held)."""
    st = state.with_term(geo)
    st.dh_nominal = _held_at_calibration(dh, res)
    st.theta[-1] = (res.dh.reshape(-1) - dh.reshape(-1))[geo.index].copy()
    st.R, st.t = res.base_T[:3, :3].copy(), res.base_T[:3, 3].copy()
    return st


def _on_calibration(state: ModelState, dh, geo: Term, res) -> ModelState:
    """``state`` (which has a geometric term) with that term and the base at the calibration ``res``."""
    gi = next(i for i, t in enumerate(state.terms) if t.kind == "geometric")
    out = state.copy()
    out.terms[gi] = geo
    out.dh_nominal = _held_at_calibration(dh, res)
    out.theta[gi] = (res.dh.reshape(-1) - dh.reshape(-1))[geo.index].copy()
    out.R, out.t = res.base_T[:3, :3].copy(), res.base_T[:3, 3].copy()
    return out


def _check_effects_on_heldout(state: ModelState, dh, q, meas, train, heldout, geo: Term, res, *,
                              hold_geometry: bool) -> dict:
    """The written model's construction (from the calibration, the named effects fitted with the geometry held
    or re-identified with them, see :func:`diagnose_arm`) made on the training poses, against that calibration
    alone, on the held-out poses: effects are written only when they predict those poses no worse
    (:func:`_worse_on_heldout`; issue 43: the written model is never worse than its own calibration on poses that
    did not choose it). The effects are
    taken in the order they were named: of the calibration with the first k of them (k = 1 .. all), the one
    that predicts the held-out poses best is written, if it is no worse than the calibration alone (a
    later step, named on a few training poses, may fit their noise where the first one holds: 40 lab poses,
    eccentricity on J3 named with a compliance on J3 after it, the two together 1.001x a plain fit on unseen
    poses, the first alone 0.81x). RMS of the 3-D error, mm; ``effects`` the keys written."""
    p_geo = kin.tool_position(res.dh, q[heldout]) @ res.base_T[:3, :3].T + res.base_T[:3, 3]
    rms_geo = _rms(meas[heldout] - p_geo)
    start = _on_calibration(state, dh, geo, res)
    eff = [i for i, t in enumerate(start.terms) if t.kind != "geometric"]
    geo_i = [i for i, t in enumerate(start.terms) if t.kind == "geometric"]
    e_geo = np.sum((meas[heldout] - p_geo) ** 2, axis=1)
    tried, ok_fits = [], []
    for k in range(len(eff), 0, -1):
        sub = start.copy()
        keep = geo_i + eff[:k]
        sub.terms, sub.theta = [sub.terms[i] for i in keep], [sub.theta[i] for i in keep]
        st, _, sol = fit_report(sub, q, meas, train, hold_geometry=hold_geometry)
        e_k = np.sum((meas[heldout] - predict(st, q, heldout)) ** 2, axis=1)
        tried.append((k, _rms(meas[heldout] - predict(st, q, heldout)), sol))
        if sol.converged and not _worse_on_heldout(e_k, e_geo):
            ok_fits.append((tried[-1][1], -k, k))
    names = [start.terms[i].key for i in eff]
    k_all, rms_all, sol_all = tried[0]
    if ok_fits:
        rms_eff, _, k = min(ok_fits)
        kept = names[:k]
        note = (f"the effects ({', '.join(kept)}) are written: added to the calibration of the training poses they "
                f"predict the {heldout.size} held-out poses at {rms_eff:.4g} mm RMS, the calibration alone at "
                f"{rms_geo:.4g} mm")
        if k < len(names):
            note += (f"; {', '.join(names[k:])}, named after them, not written (with them "
                     f"{rms_all:.4g} mm)")
    else:
        rms_eff, kept = rms_all, []
        note = (f"the written model is the calibration alone: the effects ({', '.join(names)}) added to the "
                f"calibration of the training poses predict the {heldout.size} held-out poses at {rms_eff:.4g} mm "
                f"RMS, worse than the calibration alone ({rms_geo:.4g} mm)" if sol_all.converged else
                "the written model is the calibration alone: the effects could not be fitted on it "
                f"({sol_all.message})")
    return {"effects_written": bool(kept), "effects": kept,
            "geometry": "held at the calibration" if hold_geometry else
            "re-identified with the effects (from the calibration)",
            "heldout_rms_with_effects_mm": finite_or_none(rms_eff),
            "heldout_rms_calibration_mm": finite_or_none(rms_geo), "note": note}


def _worse_on_heldout(e_new: np.ndarray, e_old: np.ndarray) -> bool:
    """Squared errors ``e_new`` of the held-out poses larger than ``e_old`` on average (issue 43 item 2: the
    written model is never worse than its own calibration on the poses that did not choose it). An allowance of
    one standard error of the paired difference let a backlash present in the training poses only be written
    although it predicted the 15 held-out poses at 0.60 mm against the calibration's 0.52 (2 of 65 seeds of
    the fall-back test); on effect-free lab sets the allowance made no difference (the same 1 of 100 failing).
    Without held-out poses nothing shows the effects are not worse: counted as worse (the calibration is
    written)."""
    d = e_new - e_old
    return bool(d.size == 0 or d.mean() > 0.0)


def inner_folds(n: int, k: int, seed: int) -> list[np.ndarray]:
    """``k`` folds of positions ``0..n-1`` (seeded: the same data give the same folds)."""
    perm = np.random.default_rng(seed).permutation(n)
    return [np.sort(f) for f in np.array_split(perm, min(k, n)) if f.size]


def cv_errors(M: np.ndarray, r: np.ndarray, folds, B: np.ndarray | None = None) -> np.ndarray:
    """Cross-validated squared 3-D errors per pose (n,), mm^2, of the linearised refit: columns ``M``
    (n, 3, p) [+ ``B`` (n, 3, k)] fitted to the residual ``r`` (n, 3) on all poses but a fold, predicting it."""
    X = M if B is None else np.concatenate([M, B], axis=2)
    n, _, P = X.shape
    out = np.zeros(n)
    for f in folds:
        keep = np.ones(n, bool)
        keep[f] = False
        Xk = X[keep].reshape(-1, P)
        sc = np.linalg.norm(Xk, axis=0)
        sc[sc == 0] = 1.0
        step = np.linalg.lstsq(Xk / sc, r[keep].reshape(-1), rcond=1e-6)[0] / sc
        e = r[f] - np.einsum("nip,p->ni", X[f], step)
        out[f] = np.sum(e ** 2, axis=1)
    return out


def cv_rms(M, r, folds, B=None) -> float:
    return math.sqrt(float(np.mean(cv_errors(M, r, folds, B))))


#: an effect must lower the cross-validated squared error by this many standard errors of the paired difference
CV_GAIN_SE = 1.0


def cv_gain(e_before: np.ndarray, e_after: np.ndarray) -> bool:
    """The paired one-standard-error rule: the candidate predicts the poses left out clearly better."""
    d = e_before - e_after
    if d.size < 2:
        return False
    return float(d.mean()) > CV_GAIN_SE * float(d.std(ddof=1)) / math.sqrt(d.size)


def _test_round(state: ModelState, q, meas, train, variants: list[Term], alpha: float, m_candidates: int,
                folds) -> tuple[list[CandidateTest], float]:
    """Every candidate tested against the current residual; ``(tests, cross-validated RMS of the model now)``."""
    pred, A, extra = jacobian(state, q, train, variants)
    r3 = meas[train] - pred
    r = r3.reshape(-1)
    n = train.size
    p = A.shape[2]
    M = A.reshape(-1, p)
    Q = model_basis(M)
    e_now = cv_errors(A, r3, folds)
    cv_now = math.sqrt(float(np.mean(e_now)))
    out = []
    for term, B in extra:
        ct = CandidateTest(term.key, term.effect, term.joint, True, k=term.k, variant=term)
        dof_poses = n - (p + term.k) / 3.0
        if dof_poses < MIN_DOF_POSES:
            ct.testable, ct.reason = False, (f"too few training poses ({n}) for {term.k} more parameter(s) on top of "
                                             f"the model's {p} (needs {MIN_DOF_POSES} poses to spare)")
            out.append(ct)
            continue
        Bf = B.reshape(-1, term.k)
        factor = (n - term.k / 3.0) / dof_poses
        # the pose-robust covariance, floored at the classical one: with few poses for many parameters the
        # sandwich alone is too small where a few poses of high leverage carry the candidate (issue 43: an
        # effect-free 40-pose set named compliance on J4, another eccentricity on J2 at 2.5x its threshold)
        bt = wald_block(Bf, r, Q, lambda X, res, k=term.k: classical_floor(
            robust_cov(X.reshape(n, 3, k), res.reshape(n, 3)) * factor, X, res, 3 * n - p - k))
        if bt.why is not None:
            ct.testable, ct.reason = False, (
                "it does not move the measured point in these poses" if bt.why == "no effect" else
                "indistinguishable in these poses from parameters already in the model "
                f"({', '.join(t.key for t in state.terms) or 'base transform'})")
            out.append(ct)
            continue
        ct.rss_reduction = bt.rss_reduction
        ct.statistic = bt.wald / term.k
        m = m_candidates * (len(_tau_family(variants)) if term.fitted_dof else 1)
        ct.threshold = float(stats.f.isf(alpha / max(m, 1), term.k, dof_poses))
        e_c = cv_errors(A, r3, folds, B)   # cross-validated inside the training poses
        ct.heldout_rms_after = math.sqrt(float(np.mean(e_c)))
        ct.cv_gain = cv_gain(e_now, e_c)
        out.append(ct)
    # one entry per candidate key: the variant that fits the training poses best (thermal drift's tau grid:
    # the variants have as many parameters, so the largest least-squares reduction is the profile-likelihood
    # choice of tau; the robust Wald statistic, noisier, only decides whether that variant is named)
    best: dict = {}
    for ct in out:
        cur = best.get(ct.key)
        score = ct.rss_reduction if ct.testable else -1.0
        if cur is None or score > (cur.rss_reduction if cur.testable else -1.0):
            best[ct.key] = ct
    return list(best.values()), cv_now


def _geometry_test(state: ModelState, q, meas, train, geo: Term, alpha: float) -> CandidateTest:
    """The geometric candidate's significance: a classical partial F on every coordinate (the robust covariance
    of the joint effects needs more poses than a table of 20-30 parameters leaves on a 30-pose set). Whether it
    predicts poses that did not choose it is :func:`.geometry_cv.fold_errors`' question."""
    pred, A, extra = jacobian(state, q, train, [geo])
    r3 = meas[train] - pred
    r = r3.reshape(-1)
    B = extra[0][1]
    m, p, k = r.size, A.shape[2], geo.k
    ct = CandidateTest(geo.key, geo.effect, None, True, k=k, variant=geo)
    dof = m - p - k
    if dof < max(3.0, k / 2.0):
        ct.testable, ct.reason = False, (f"{train.size} training poses give {m} coordinates for {p + k} parameters "
                                         f"(base transform and geometry): {dof} to spare, the test needs "
                                         f"{max(3, int(math.ceil(k / 2)))}")
        return ct
    Q = model_basis(A.reshape(-1, p))
    bt = wald_block(B.reshape(-1, k), r, Q, lambda X, res: np.eye(X.shape[1]))
    if bt.why is not None:
        ct.testable, ct.reason = False, "it does not move the measured point in these poses"
        return ct
    rss0 = float(r @ r)
    rss1 = max(rss0 - bt.rss_reduction, 1e-300)
    ct.rss_reduction = bt.rss_reduction
    ct.resid_var, ct.resid_dof = rss1 / dof, float(dof)
    ct.statistic = (bt.rss_reduction / k) / (rss1 / dof)
    ct.threshold = float(stats.f.isf(alpha, k, dof))
    return ct


def _geometry_cv(dh, q, meas, train, ct: CandidateTest, structure, folds, alpha: float) -> tuple[float, dict]:
    """The calibration and the nominal model, each fitted without a fold, predicting it (interpolation folds on
    sweeps); on sweeps the sweep ends held out give the extrapolation figure, reported only. Sets ``ct``'s
    cross-validated RMS and gain, and ``folds_blind`` where the nominal model predicts the folds' poses to the
    noise (:func:`.geometry_cv.folds_see_geometry`: the folds cannot tell, they do not judge);
    ``(nominal's cross-validated RMS, the JSON of both)``."""
    qt, mt = q[train], meas[train]
    fe = fold_errors(dh, qt, mt, folds)
    ct.heldout_rms_after = fe.rms_geometry
    ct.cv_gain = beats_nominal(fe)
    sig = folds_see_geometry(fe, ct.resid_var, ct.resid_dof, alpha)
    ct.folds_blind = sig.blind
    how = ("interpolation only: the poses are one-joint sweeps and every sweep's ends stay in training, so each "
           "held-out pose lies inside the range of the poses that calibrate it; beyond a sweep's range the model "
           "extrapolates and these folds do not test it" if structure.interpolation_only else
           "random folds of poses spread over the joint space")
    doc = {"poses": structure.describe(), "folds": len(folds), "held_out_poses": int(fe.rows.size),
           "kind": "interpolation" if structure.interpolation_only else "random", "statement": how,
           "rms_nominal_mm": finite_or_none(fe.rms_nominal), "rms_geometry_mm": finite_or_none(fe.rms_geometry),
           "folds_not_calibrated": fe.failed,
           "nominal_beyond_noise": {
               "what": "the nominal model's mean squared error on the held-out poses over three times the "
                       "calibration's residual variance per coordinate, against F(3 n_held, dof) at 1 - alpha: "
                       "below it the folds' poses hold no geometric error to predict and the folds do not judge",
               "statistic": finite_or_none(sig.statistic), "threshold": finite_or_none(sig.threshold),
               "seen": bool(sig.seen)}}
    if structure.interpolation_only:
        ex = fold_errors(dh, qt, mt, sweep_end_folds(structure))
        doc["extrapolation"] = {
            "what": "every sweep's low ends, then its high ends, held out and predicted from the other poses "
                    "(reported, not used to judge)",
            "held_out_poses": int(ex.rows.size), "rms_nominal_mm": finite_or_none(ex.rms_nominal),
            "rms_geometry_mm": finite_or_none(ex.rms_geometry)}
    return fe.rms_nominal, doc


#: a joint effect whose fit moves a joint by more than this is not named (5 arcmin)
PLAUSIBLE_JOINT_ERROR_RAD = math.radians(5.0 / 60.0)


def _joint_error_size(term: Term, th: np.ndarray, rows) -> float | None:
    """Largest joint-angle change (rad) the fitted joint term makes over ``rows`` (None: not a joint term)."""
    if term.kind != "joint":
        return None
    return float(np.max(np.abs(term.features[rows] @ th)))


def _tau_family(variants: list[Term]) -> list[Term]:
    return [t for t in variants if t.fitted_dof]


def _step_params(state: ModelState, q, meas, train, term_i: int) -> tuple[dict, dict]:
    pred, A, _ = jacobian(state, q, train)
    resid = meas[train] - pred
    cov = robust_cov(A, resid)
    off = 6 + sum(t.k for t in state.terms[:term_i])
    term, th = state.terms[term_i], state.theta[term_i]
    dof = max(train.size - state.n_params / 3.0, 1.0)
    tq = float(stats.t.ppf(0.975, dof))
    sd = np.sqrt(np.maximum(np.diag(cov)[off:off + term.k], 0.0))
    params = {name: float(v) for name, v in zip(term.param_names, th)}
    ci = {name: [float(v - tq * s), float(v + tq * s)] for name, v, s in zip(term.param_names, th, sd)}
    if "tau_s" in term.extra:
        params["tau_s"] = term.extra["tau_s"]
    return params, ci


def _check_inputs(dh, q, meas, optional: dict) -> None:
    kin.validate_dh(dh)
    if q.ndim != 2 or q.shape[1] != 6:
        raise DataError(f"`q_rad` must have shape (N, 6), got {q.shape}")
    if meas.shape != (q.shape[0], 3):
        raise DataError(f"`xyz_mm` must have shape ({q.shape[0]}, 3), got {meas.shape}")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(meas))):
        raise DataError("joint angles and measured points must be finite")
    for name, v in optional.items():
        if v is not None and (np.shape(v) != (q.shape[0],) or not np.all(np.isfinite(v))):
            raise DataError(f"`{name}` must be {q.shape[0]} finite values, got shape {np.shape(v)}")
    if q.shape[0] > MAX_POSES:
        raise DataError(f"{q.shape[0]} poses: a diagnosis takes at most {MAX_POSES} (a calibration measures a few "
                        "thousand at most)")
    big = np.abs(q) > MAX_ABS_Q_RAD
    if big.any():
        k, j = map(int, np.argwhere(big)[0])
        raise DataError(f"pose {k + 1}: q{j + 1} = {np.degrees(q[k, j]):.6g} deg is beyond ten turns: no joint "
                        "gives it (degrees read as radians? an export error?)")
    screen_arm_poses(dh, q, meas)


def canonical_order(q: np.ndarray, meas: np.ndarray, t_s, rows_in_motion_order: bool) -> tuple[np.ndarray, bool, str]:
    """``(perm, motion_known, how)``: the order the diagnosis works in.

    By time when there is a ``t`` column (the motion order, whatever the
    rows' order), the rows' own order when the caller vouches for it, and
    otherwise a canonical order of the joint angles and points: then nothing
    the diagnosis finds depends on how the rows were shuffled, and effects
    that need the order of motion (backlash) are not testable.
    """
    n = q.shape[0]
    if t_s is not None:
        return np.argsort(np.asarray(t_s, float), kind="stable"), True, "sorted by the t column (motion order)"
    if rows_in_motion_order:
        return np.arange(n), True, "rows in motion order (as the caller says)"
    keys = np.round(np.column_stack([q, meas]), 9)
    return np.lexsort(keys.T[::-1]), False, "no motion order: rows taken in a canonical order of q and x,y,z"


def repeat_groups(q: np.ndarray, tol_rad: float = 1e-6) -> list[np.ndarray]:
    """Rows measured at the same joint angles (groups of two or more)."""
    keys = np.round(q / tol_rad).astype(np.int64)
    _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    return [np.flatnonzero(inv == g) for g in np.flatnonzero(counts >= 2)]


def noise_from_repeats(meas: np.ndarray, groups) -> tuple[float, int]:
    """3-D RMS scatter (mm) of repeated measurements of the same pose, pooled; and its degrees of freedom."""
    ss, dof = 0.0, 0
    for g in groups:
        x = meas[g]
        ss += float(np.sum((x - x.mean(axis=0)) ** 2))
        dof += g.size - 1
    return (math.sqrt(ss / dof) if dof else math.nan), dof


def diagnose_arm(dh_nominal, q_rad, xyz_mm, *, t_s=None, temperature_c=None, load_kg=None, robot=None,
                 heldout_fraction: float = 0.25, alpha: float = 0.05, max_steps: int = 20,
                 rows_in_motion_order: bool = False, folds: int = 5, seed: int = 0) -> ArmDiagnosis:
    """Diagnose the station's arm model against measured tool points.

    Parameters
    ----------
    dh_nominal : array_like, shape (7, 5)
        The station's model (mm, rad; seed 002 eq. (3)).
    q_rad : array_like, shape (N, 6)
        Joint angles.
    xyz_mm : array_like, shape (N, 3)
        Measured tool points, instrument frame.
    t_s, temperature_c, load_kg : array_like, shape (N,), optional
        ``t`` also gives the order of motion (backlash).
    robot : RobotSpec, optional
        Mass model for the gravity torque of ``joint_compliance``.
    heldout_fraction : float
        Share of the poses held out (spanning the workspace): they report
        the gain and are never used to choose an effect.
    alpha : float
        Family-wise false-discovery rate of each selection round.
    rows_in_motion_order : bool
        The rows are in the order the arm visited them (backlash testable without ``t``).
    folds, seed
        Inner cross-validation that chooses the effects (folds of the training poses, seeded).
    """
    import time

    t0 = time.perf_counter()
    dh = np.asarray(dh_nominal, dtype=float)
    q_in = np.asarray(q_rad, dtype=float)
    meas_in = np.asarray(xyz_mm, dtype=float)
    _check_inputs(dh, q_in, meas_in, {"t_s": t_s, "temperature_c": temperature_c, "load_kg": load_kg})
    if not (0.0 < alpha < 0.5):
        raise DataError(f"`alpha` must be in (0, 0.5), got {alpha!r}")
    if isinstance(folds, bool) or int(folds) != folds or folds < 2:
        raise DataError(f"`folds` must be an integer >= 2, got {folds!r}")
    perm, motion_known, order_how = canonical_order(q_in, meas_in, t_s, rows_in_motion_order)
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    q, meas = q_in[perm], meas_in[perm]

    def take(v):
        return None if v is None else np.asarray(v, dtype=float)[perm]

    t_w, temp_w, load_w = take(t_s), take(temperature_c), take(load_kg)
    train, heldout = workspace_split(q, meas, heldout_fraction, seed=seed)
    folds_tr = inner_folds(train.size, int(folds), seed)
    structure = pose_structure(q[train])
    folds_geo = structured_folds(structure, int(folds), seed)
    last_dir = motion_directions(q)
    not_testable: dict = {}
    th_terms, why = thermal_terms(t_w, temp_w)
    if why:
        not_testable["thermal_drift"] = why
    jt, why_j = joint_terms(dh, q, last_dir, robot=robot, load_kg=load_w)
    if not motion_known:
        jt = [t for t in jt if t.effect != "backlash"]
        last_dir = np.zeros_like(q)
        for j in range(1, 7):
            if "constant" not in why_j.get(f"backlash[{j}]", ""):
                why_j[f"backlash[{j}]"] = ("needs the order of motion: a t column, or the rows in motion order "
                                           "(--rows-in-motion-order)")
    not_testable.update(why_j)
    others = th_terms + jt

    all_rows = np.arange(q.shape[0])
    state, _, sol0 = fit_report(initial_state(dh, q, meas, train), q, meas, train)
    fits = [("simulation (base transform)", sol0)]
    resid_sim = meas - predict(state, q, all_rows)
    sim_ho = _rms(resid_sim[heldout])
    steps: list[Step] = []
    rounds: list[list[CandidateTest]] = []
    geometry = {"named": False}

    # ---- geometry first: the diagnosis starts from a geometric calibration
    geo, geo_res, why = _geometric_term(dh, q, meas, train)
    stop_why = None
    adopted = None   # (its test, the simulation's state, the calibration's, nominal's cv RMS) when adopted, not named
    if geo is None:
        not_testable["geometric"] = why
        stop_why = f"geometry cannot be tested ({why}): nothing else is named, it could stand in for geometric error"
    else:
        ct = _geometry_test(state, q, meas, train, geo, alpha)
        rounds.append([ct])
        cv_now, cv_doc = (_geometry_cv(dh, q, meas, train, ct, structure, folds_geo, alpha) if ct.testable
                          else (math.nan, {}))
        geometry.update(statistic=finite_or_none(ct.statistic), threshold=finite_or_none(ct.threshold),
                        cv_rms_before=finite_or_none(cv_now), cv_rms_after=finite_or_none(ct.heldout_rms_after),
                        cross_validation=cv_doc, converged=geo_res.converged,
                        message=geo_res.message, warnings=geo_res.extra.get("warnings", []))
        if not ct.testable:
            not_testable["geometric"] = ct.reason
            stop_why = f"geometry cannot be tested ({ct.reason}): nothing else is named"
        elif ct.significant and (ct.cv_gain or ct.folds_blind):
            # geometry is the base of everything else: the calibration predicting the poses each fold held out
            # better than the nominal model suffices (see .geometry_cv); where the nominal model predicts those
            # poses to the noise the folds cannot tell, and the partial F judges alone (issue 43: one-joint
            # sweeps whose interior poses lie near home)
            st = _with_geometry(state, geo, geo_res, dh)
            st, _, sol = fit_report(st, q, meas, train)
            fits.append(("geometric", sol))
            params, ci = _step_params(st, q, meas, train, len(st.terms) - 1)
            r_before, r_after = resid_sim, meas - predict(st, q, all_rows)
            steps.append(Step(geo, params, ci, sim_ho, _rms(r_after[heldout]), ct.statistic, ct.threshold,
                              f"partial F of the {ct.k} geometric parameters against F({ct.k}, 3n-p) at 1 - {alpha:g}; "
                              f"the calibration fitted without each of {len(folds_geo)} folds of the training poses "
                              f"predicts them at {ct.heldout_rms_after:.4g} mm RMS, the nominal model at "
                              f"{cv_now:.4g} mm ({cv_doc['kind']})" + (
                                  "; the nominal model predicts those poses to the noise (statistic "
                                  f"{cv_doc['nominal_beyond_noise']['statistic']:.3g} against "
                                  f"{cv_doc['nominal_beyond_noise']['threshold']:.3g}): they hold no geometric "
                                  "error to predict, the folds cannot tell and the partial F judges alone"
                                  if ct.folds_blind and not ct.cv_gain else ""),
                              resid_before=r_before, resid_after=r_after))
            steps[-1].cv = (cv_now, ct.heldout_rms_after)
            state = st
            geometry["named"] = True
            if not ct.cv_gain:
                geometry["judged_by"] = ("the partial F alone: the nominal model predicts the poses the folds "
                                         "held out to the noise, the folds cannot tell")
        else:
            geometry["why_not"] = ("not significant" if not ct.significant else
                                   "significant, but every training pose ends a sweep: none can be held out without "
                                   "extrapolating, not cross-validated" if not cv_doc.get("folds") else
                                   "significant, but no fold of the training poses could be calibrated without its "
                                   "poses (too few): not cross-validated" if not cv_doc.get("held_out_poses") else
                                   "significant, but the calibration does not predict the poses the folds held out "
                                   "better than the nominal model (cross-validated)")
            # not named, but the diagnosis still starts from the geometric calibration (it costs nothing
            # where the table is right, and joint effects must not stand in for a geometry left out)
            st = _with_geometry(state, geo, geo_res, dh)
            state_sim = state
            state, _, sol = fit_report(st, q, meas, train)
            fits.append(("geometric (adopted, not named)", sol))
            geometry["adopted"] = True
            adopted = (ct, state_sim, state, cv_now)
    # ---- noise floor
    groups = repeat_groups(q)
    n_rep, dof_rep = noise_from_repeats(meas, groups) if groups else (math.nan, 0)
    rss = float(np.sum((meas[train] - predict(state, q, train)) ** 2))
    fit_floor = math.sqrt(rss / max(train.size - state.n_params / 3.0, 1.0))
    if dof_rep >= 3:
        noise_floor, noise_src = n_rep, (f"repeated measurements ({len(groups)} pose(s) measured more than once, "
                                         f"{dof_rep} degrees of freedom)")
    else:
        noise_floor = fit_floor
        noise_src = ("the " + ("geometric" if geometry["named"] or geometry.get("adopted") else "simulation's")
                     + " fit's training residual, "
                     "corrected for its degrees of freedom (no repeated measurements)")

    # ---- the other effects, only where geometry could be tested
    remaining = [] if stop_why else list(others)
    prev_sig: list[CandidateTest] = []
    chosen_prev: CandidateTest | None = None
    rejected: dict = {}
    while remaining and len(steps) < max_steps:
        keys = {t.key for t in remaining}
        tests, cv_now = _test_round(state, q, meas, train, remaining, alpha, len(keys), folds_tr)
        rounds.append(tests)
        if chosen_prev is not None and steps:
            _ambiguity(steps[-1], prev_sig, chosen_prev, tests)
        sig = sorted((ct for ct in tests if ct.significant and ct.cv_gain),
                     key=lambda ct: ct.heldout_rms_after)
        sig, told, apart = _order_by_encompassing(state, q, meas, train, sig, alpha / max(len(keys), 1))
        taken = False
        for best in sig:
            new_state, _, sol = fit_report(state.with_term(best.variant), q, meas, train)
            th = new_state.theta[-1]
            rss_old = float(np.sum((meas[train] - predict(state, q, train)) ** 2))
            rss_new = float(np.sum((meas[train] - predict(new_state, q, train)) ** 2))
            if not np.any(th != 0.0) or rss_new >= rss_old:
                remaining = [t for t in remaining if t.key != best.key]  # no step without gain
                continue
            size = _joint_error_size(best.variant, th, train)
            if size is not None and size > PLAUSIBLE_JOINT_ERROR_RAD:
                remaining = [t for t in remaining if t.key != best.key]
                rejected[best.key] = (f"its fit moves joint {best.joint} by up to {math.degrees(size) * 60:.3g} "
                                      f"arcmin, beyond the {math.degrees(PLAUSIBLE_JOINT_ERROR_RAD) * 60:g} arcmin a "
                                      "real joint shows: it stands in for something else (a joint offset, "
                                      "extrapolation)")
                continue
            fits.append((best.key, sol))
            params, ci = _step_params(new_state, q, meas, train, len(new_state.terms) - 1)
            r_before = meas - predict(state, q, all_rows)
            r_after = meas - predict(new_state, q, all_rows)
            steps.append(Step(best.variant, params, ci, _rms(r_before[heldout]), _rms(r_after[heldout]),
                              best.statistic, best.threshold,
                              f"cluster-robust Wald W/k against F({best.k}, n-p/3) at 1 - {alpha:g}/{len(keys)} "
                              f"(Bonferroni over the round's candidates); {len(folds_tr)}-fold cross-validated RMS "
                              f"inside the training poses {cv_now:.4g} -> {best.heldout_rms_after:.4g} mm",
                              resid_before=r_before, resid_after=r_after))
            steps[-1].cv = (cv_now, best.heldout_rms_after)
            steps[-1].ambiguous_with.extend(told.get(best.key, []))
            steps[-1].told_apart = apart.get(best.key, [])
            state = new_state
            remaining = [t for t in remaining if t.key != best.key]
            prev_sig = [c for c in tests if c.significant]
            chosen_prev = best
            taken = True
            break
        if not taken:
            break
    if adopted is not None and steps and adopted[0].testable and math.isfinite(adopted[0].heldout_rms_after):
        _geometry_with_effects(adopted, state, steps, geometry, fits, q, meas, train, heldout, geo, alpha,
                               resid_sim, sim_ho, folds_geo)
    resid_final = meas - predict(state, q, all_rows)
    # the model written out: the calibration of every pose, and the chosen effects fitted on every pose. On
    # one-joint sweeps with that geometry held: a joint refit moves the geometry with each effect, and on poses
    # beyond the range the training poses span (a random split of one-joint sweeps holds out sweep ends 60 deg
    # beyond it) that moved geometry extrapolates worse than the calibration did: FANUC-like sets, 6 random 70/30 splits each, the
    # mean held-out error against geometry alone was above 1.02x in 7 draws of 60 with the joint refit, in none
    # held (worst 1.010; mean 0.972)
    on_calibration = geometry["named"] or geometry.get("adopted")
    start_all, res_all = state, None
    if on_calibration:
        # the geometry of the written model is the calibration of every pose (its own identifiable set)
        geo_all, res_all, _ = _geometric_term(dh, q, meas, all_rows)
        if geo_all is not None:
            start_all = _on_calibration(state, dh, geo_all, res_all)
    # how the effects meet the geometry in the written model. On poses spread over the joint space the geometry is
    # re-identified with them (from the calibration, under its prior): an effect fitted on the residual the
    # calibration left can explain only its part no geometric error mimics, and the calibration keeps the rest as
    # a distorted table. Lab-shaped sets (RB5-850, 40 poses, one hidden compliance or eccentricity on J2/J3,
    # bench/bench_diagnosis_lab.py): unseen error against a plain fit 0.82x held, 0.64x re-identified, an oracle
    # that knows the effect's form 0.63x (mean of 10 draws).
    hold = structure.interpolation_only
    written = _check_effects_on_heldout(state, dh, q, meas, train, heldout, geo, geo_res, hold_geometry=hold) if (
        on_calibration and len(state.terms) > 1) else None
    if written is not None and len(written["effects"]) < len(state.terms) - 1 and start_all is not state:
        # the effects (or the later ones), added to the calibration of the training poses, predicted the held-out
        # poses worse than that calibration alone (or than the first ones): not written, and it says so
        start_all = start_all.copy()
        keep = [i for i, t in enumerate(start_all.terms) if t.kind == "geometric" or t.key in written["effects"]]
        start_all.terms = [start_all.terms[i] for i in keep]
        start_all.theta = [start_all.theta[i] for i in keep]
    if start_all is not state and len(start_all.terms) == 1:
        # geometry alone: the written model is that calibration itself (a refit under the diagnosis's own
        # prior would extrapolate differently beyond the poses' range)
        state_all, sol_all = start_all, res_all
    else:
        state_all, _, sol_all = fit_report(start_all, q, meas, all_rows, hold_geometry=start_all is not state and hold)
    fits.append(("all poses (model written out)", sol_all))
    variables = {"q_rad": q_in, "last_dir": last_dir[inv], "t_s": t_s, "temperature_c": temperature_c}
    for term in others:
        if term.effect == "joint_compliance":
            variables.setdefault("gravity_torque", {})[term.joint] = -term.features[inv, 0]
    for stp in steps:
        stp.resid_before, stp.resid_after = stp.resid_before[inv], stp.resid_after[inv]
    out = ArmDiagnosis(steps, rounds, not_testable, np.sort(perm[train]), np.sort(perm[heldout]), sim_ho,
                       _rms(resid_final[heldout]), noise_floor, state, resid_sim[inv], resid_final[inv], variables,
                       alpha, time.perf_counter() - t0)
    out.noise_floor_source = noise_src
    out.rejected = rejected
    out.fit_residual_floor = fit_floor
    out.geometry = geometry
    out.stop_reason = stop_why
    out.row_order = order_how
    out.state_all = state_all
    out.written = written or {}
    out.refs = {"t0_s": float(np.min(t_s)) if t_s is not None else None,
                "reference_temperature_c": float(np.min(temperature_c)) if temperature_c is not None else None}
    out.fits = [{"fit": name, "converged": s.converged, "iterations": s.iterations, "message": s.message}
                for name, s in fits]
    out.selection = (f"nested: each effect is chosen on the {train.size} training poses (significance test and "
                     f"{len(folds_tr)}-fold cross-validation inside them); the {heldout.size} held-out poses "
                     "report the gain and never take part in the choice")
    return out


def _cv_with_effects(st_nominal: ModelState, st_geometry: ModelState, q, meas, train, folds) -> tuple[float, float]:
    """RMS (mm) over the folds' poses of the nominal model and of the calibration, each with the named effects,
    fitted without each fold (positions in ``train``) and predicting it: ``(nominal, geometry)``."""
    e_nom, e_geo = [], []
    for f in folds:
        keep = np.ones(train.size, bool)
        keep[f] = False
        rows, out = train[keep], train[f]
        for st, acc in ((st_nominal, e_nom), (st_geometry, e_geo)):
            fitted, _, _ = fit_report(st, q, meas, rows)
            acc.append(np.sum((meas[out] - predict(fitted, q, out)) ** 2, axis=1))
    if not e_nom:
        return math.nan, math.nan
    return math.sqrt(float(np.mean(np.concatenate(e_nom)))), math.sqrt(float(np.mean(np.concatenate(e_geo))))


def _geometry_with_effects(adopted, state: ModelState, steps: list, geometry: dict, fits: list, q, meas, train,
                           heldout, geo: Term, alpha: float, resid_sim, sim_ho: float, folds) -> None:
    """Geometry judged again once the effects are named, when it was adopted but not named: its partial F
    against the model with those effects and without geometry. The first test's residual held the joint
    effects the geometry cannot produce, and they inflated its denominator (FANUC-like sweeps with backlash of
    0.02-0.04 deg on J2 and J3: geometry's statistic 1.84 against 1.89, the calibration predicting the folds
    at 0.99 mm against the nominal model's 1.04). Named when significant there and the calibration predicts the
    poses the folds held out better than the nominal model (the question the user asks): as the first judgement
    found, or, where that found it no better, with the named effects in both (the same residual hid it there:
    36 sweep poses with backlash on J2, the nominal model missing unseen poses by 2x a plain fit, the folds
    0.272 mm for the calibration alone against 0.240 for the nominal). The step goes first, as geometry's
    always does. ``steps``, ``geometry`` and ``fits`` are updated in place."""
    ct0, state_sim, state_geo, cv_nom = adopted
    st = state_sim
    for term, th in zip(state.terms, state.theta):
        if term.kind != "geometric":
            st = st.with_term(term)
            st.theta[-1] = th.copy()
    st, _, sol = fit_report(st, q, meas, train)
    fits.append(("the named effects without geometry (geometry judged again)", sol))
    ct = _geometry_test(st, q, meas, train, geo, alpha)
    if not ct.testable:
        return
    geometry.update(statistic_with_effects=finite_or_none(ct.statistic),
                    threshold_with_effects=finite_or_none(ct.threshold))
    if not (sol.converged and ct.significant):
        return
    cv = (cv_nom, ct0.heldout_rms_after)
    if not ct0.cv_gain:
        # the folds judged the calibration alone against the nominal model alone, the effects' residual in both:
        # judged again with the effects in both
        cv = _cv_with_effects(st, state, q, meas, train, folds)
        cv_doc = geometry.get("cross_validation", {})
        cv_doc["with_effects"] = {"what": "the calibration and the nominal model, each with the named effects, "
                                          "fitted without each fold and predicting it",
                                  "rms_nominal_mm": finite_or_none(cv[0]), "rms_geometry_mm": finite_or_none(cv[1])}
        if not cv[1] < cv[0]:
            return
    all_rows = np.arange(q.shape[0])
    gi = next(i for i, t in enumerate(state.terms) if t.kind == "geometric")
    params, ci = _step_params(state, q, meas, train, gi)
    r_after = meas - predict(state_geo, q, all_rows)
    effects = ", ".join(t.key for t in state.terms if t.kind != "geometric")
    step = Step(geo, params, ci, sim_ho, _rms(r_after[heldout]), ct.statistic, ct.threshold,
                f"partial F of the {ct.k} geometric parameters against F({ct.k}, 3n-p) at 1 - {alpha:g} in the "
                f"model with the named effects ({effects}; without them {ct0.statistic:.3g} against "
                f"{ct0.threshold:.3g}, the folds {ct0.heldout_rms_after:.4g} mm against the nominal's {cv_nom:.4g}: "
                "their residual hid it); the calibration fitted without "
                f"each of {len(folds)} folds of the training poses predicts them at {cv[1]:.4g} mm RMS, the nominal "
                f"model at {cv[0]:.4g} mm" + ("" if ct0.cv_gain else " (both with the named effects)"),
                resid_before=resid_sim, resid_after=r_after)
    step.cv = cv
    steps.insert(0, step)
    geometry["named"] = True
    geometry["named_with_effects"] = (f"not named at first ({geometry.pop('why_not', '')}); named in the model "
                                      f"with the effects ({effects})")


def _ambiguity(step: Step, prev_sig, chosen_prev, tests) -> None:
    now = {ct.key: ct for ct in tests}
    named = {(a["effect"], a["joint"]) for a in step.ambiguous_with + step.told_apart}
    for ct in prev_sig:
        if ct.key == chosen_prev.key or (ct.effect, ct.joint) in named:
            continue
        later = now.get(ct.key)
        gone = later is None or not later.significant
        if gone and ct.rss_reduction >= AMBIGUITY_SHARE * chosen_prev.rss_reduction:
            step.ambiguous_with.append(
                {"effect": ct.effect, "joint": ct.joint,
                 "share_of_residual_explained": ct.rss_reduction / chosen_prev.rss_reduction,
                 "cv_rms_alone": ct.heldout_rms_after,
                 "note": "explains the same residual: nothing significant is left of it after this step"})


#: a direction of a candidate's columns counts as its own beyond another candidate's when this share of it (unit
#: columns) lies outside that candidate's and the model's span
DISTINCT_SHARE = 0.01


def _beyond(M: np.ndarray, r: np.ndarray, n: int, B_cand: np.ndarray, B_other: np.ndarray, alpha_m: float) -> float:
    """Cluster-robust Wald statistic (W / k) of the columns ``B_cand`` (3n, k) on the residual ``r`` beyond the
    model's columns ``M`` and another candidate's ``B_other``, over its ``1 - alpha_m`` threshold (above 1: the
    candidate explains what the other cannot); NaN when not testable. Its covariance is that of the residual of
    the model with both candidates: the residual ``r`` of the model still holds what the other one explains,
    and counted as noise it made the statistic several times too small (240 spread poses with 0.03-0.05 deg of
    eccentricity on J2, test seed 1422158423: 0.05 and 0.02 of the threshold where the residual of both gives
    0.47 and 0.22; over 100 draws a hidden compliance was told apart from eccentricity in 6, now in all 100, and
    a hidden eccentricity from compliance in 66, now 87)."""
    Q = model_basis(np.concatenate([M, B_other], axis=1))
    bn = np.linalg.norm(B_cand, axis=0)
    if np.any(bn <= 0.0):
        return math.nan
    Bp = B_cand - Q @ (Q.T @ B_cand)
    # the directions of the candidate the other cannot produce (a compliance column that is a once-per-turn
    # shape of its joint lies inside the eccentricity's sine and cosine: the other one may not)
    U, sv, _ = np.linalg.svd(Bp / bn, full_matrices=False)
    keep = sv > DISTINCT_SHARE
    k = int(keep.sum())
    if k == 0:
        return 0.0
    dof_poses = n - (M.shape[1] + B_cand.shape[1] + B_other.shape[1]) / 3.0
    if dof_poses < MIN_DOF_POSES:
        return math.nan
    X = U[:, keep]
    th = X.T @ r
    # the residual of the model with both candidates: what the other one explains is no noise of this test
    r1 = r - Q @ (Q.T @ r) - X @ th
    cov = robust_cov(X.reshape(n, 3, k), r1.reshape(n, 3)) * ((n - k / 3.0) / dof_poses)
    try:
        wald = float(th @ np.linalg.solve(cov, th))
    except np.linalg.LinAlgError:
        return math.nan
    return (wald / k) / float(stats.f.isf(alpha_m, k, dof_poses))


def _order_by_encompassing(state: ModelState, q, meas, train, sig: list, alpha_m: float) -> tuple[list, dict]:
    """The round's significant candidates reordered by what each explains beyond the others, and for each the
    candidates it cannot be told from.

    Two candidates of the same residual (encoder eccentricity, once per turn of its joint, and joint compliance,
    the arm's gravity torque: on poses that hardly change the rest of the arm's configuration they are nearly the
    same columns) are told apart by an encompassing test: each one's columns against the residual beyond the
    model and the other's. The one that explains significantly more than its rival, while the rival explains
    nothing beyond it, goes first even when the cross-validation ranked the rival higher (the rival's extra
    parameters fit the noise of a few folds as well). When neither explains anything beyond the other the poses
    cannot tell them apart: the first is chosen and the other is named with it, with both statistics.
    ``(ordered, {key: [cannot be told apart]}, {key: [told apart]})``."""
    if len(sig) < 2:
        return sig, {}, {}
    pred, A, extra = jacobian(state, q, train, [ct.variant for ct in sig])
    n, p = train.size, A.shape[2]
    r = (meas[train] - pred).reshape(-1)
    M = A.reshape(-1, p)
    cols = [B.reshape(-1, B.shape[2]) for _, B in extra]

    def pair(i, j):
        return _beyond(M, r, n, cols[i], cols[j], alpha_m), _beyond(M, r, n, cols[j], cols[i], alpha_m)

    order = list(range(len(sig)))
    top = 0
    for j in range(1, len(sig)):
        top_beyond, other_beyond = pair(top, j)
        if other_beyond > 1.0 and not top_beyond > 1.0:
            top = j  # j explains what the current first cannot, and not the other way round
    order.remove(top)
    order.insert(0, top)
    told: dict = {}
    apart: dict = {}
    for j in order[1:]:
        a_beyond, b_beyond = pair(top, j)
        if a_beyond > 1.0 and not b_beyond > 1.0:
            apart.setdefault(sig[top].key, []).append(
                {"effect": sig[j].effect, "joint": sig[j].joint, "beyond_it": finite_or_none(b_beyond),
                 "it_beyond": finite_or_none(a_beyond),
                 "note": "the chosen one explains significantly more of the residual than this candidate, which "
                         f"explains nothing beyond it (statistic over threshold {a_beyond:.3g} and {b_beyond:.3g})"})
        elif not (a_beyond > 1.0) and not (b_beyond > 1.0):
            told.setdefault(sig[top].key, []).append(
                {"effect": sig[j].effect, "joint": sig[j].joint,
                 "share_of_residual_explained": sig[j].rss_reduction / max(sig[top].rss_reduction, 1e-300),
                 "cv_rms_alone": sig[j].heldout_rms_after,
                 "beyond_it": finite_or_none(b_beyond), "it_beyond": finite_or_none(a_beyond),
                 "note": "cannot be told apart on these poses: neither explains significantly more of the residual "
                         "than the other (statistic over threshold of each beyond the other: "
                         f"{b_beyond:.3g} and {a_beyond:.3g})"})
    return [sig[i] for i in order], told, apart
