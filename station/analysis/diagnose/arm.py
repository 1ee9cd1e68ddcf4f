"""Arm diagnosis: where the station's simulation disagrees with measured data, and why.

1. The simulation predicts the measurements: nominal table, base transform
   fitted on the training poses (:mod:`.model`).
2. Train / held-out split spanning the workspace (:mod:`.split`).
3. Every candidate term (:mod:`.terms`) is tested against the residual left
   by the current model: the part of its Jacobian columns the model cannot
   already produce (Frisch-Waugh), least squares, and a cluster-robust Wald
   statistic ``W`` (poses are the clusters; :func:`.model.robust_cov`).
   ``W / k`` is compared with the ``1 - alpha / m`` quantile of
   ``F(k, n_train - p/3)``: ``m`` counts the candidates tested in that round
   (times the ``tau`` grid for a warm-up), so the family-wise false-discovery
   rate of a round is at most ``alpha`` (Bonferroni).
4. Forward selection: of the significant candidates that also lower the
   held-out RMS (linearised refit), the one that lowers it most is added;
   the model is refitted (Gauss-Newton) and the round repeats until nothing
   significant is left.
5. Ambiguity: a candidate that was significant in the round another one was
   chosen, explained at least half as much of the residual alone, and is no
   longer significant after it, explains the same residual: the step names it.

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

from .model import ModelState, fit, initial_state, jacobian, predict, robust_cov
from .block_test import model_basis, refit_step, wald_block
from .split import workspace_split
from .summary_json import core_json
from .terms import Term, joint_terms, last_motion_direction, thermal_terms

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
    heldout_rms_after: float = math.nan
    variant: Term | None = None

    @property
    def significant(self) -> bool:
        return self.testable and self.statistic > self.threshold

    def to_json(self) -> dict:
        d = {"candidate": self.key, "effect": self.effect, "joint": self.joint, "testable": self.testable}
        if self.testable:
            d.update(statistic=finite_or_none(self.statistic), threshold=finite_or_none(self.threshold), significant=self.significant,
                     dof=self.k, heldout_rms_after_mm=finite_or_none(self.heldout_rms_after))
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

    @property
    def gain(self) -> float:
        return 1.0 - self.heldout_rms_after / self.heldout_rms_before if self.heldout_rms_before > 0 else 0.0

    def to_json(self) -> dict:
        d = {"effect": self.term.effect, "joint": self.term.joint, "params": self.params, "ci": self.ci,
             "heldout_rms_before": self.heldout_rms_before, "heldout_rms_after": self.heldout_rms_after,
             "gain": self.gain, "gain_percent": 100.0 * self.gain, "statistic": self.statistic,
             "threshold": self.threshold, "test": self.test, "ambiguous_with": self.ambiguous_with}
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

    @property
    def selected(self) -> list[tuple[str, int | None]]:
        return [(s.term.effect, s.term.joint) for s in self.steps]

    @property
    def gain(self) -> float:
        return 1.0 - self.final_heldout_rms / self.simulation_heldout_rms if self.simulation_heldout_rms > 0 else 0.0

    def extended_effects(self) -> dict:
        """The extended model as :meth:`station.models.effects.EffectSet.to_dict` plus the identified table."""
        from station.models.arm_model_file import model_to_json
        from station.models.effects import EffectSet

        params: dict = {}
        notes = []
        for term, th in zip(self.state.terms, self.state.theta):
            j = (term.joint or 0) - 1
            if term.effect == "encoder_eccentricity":
                v = params.setdefault("encoder_eccentricity", np.zeros(12))
                v[2 * j:2 * j + 2] = th
            elif term.effect == "backlash":
                params.setdefault("backlash", np.zeros(6))[j] = th[0]
            elif term.effect == "joint_compliance":
                if term.param_names[0].startswith("c"):
                    params.setdefault("joint_compliance", np.zeros(6))[j] = th[0]
                notes.append(f"joint_compliance[{term.joint}]: the basis term(s) "
                             f"{', '.join(term.param_names[1:] if term.param_names[0].startswith('c') else term.param_names)}"
                             " have no EffectSet parameter and are not written out")
            elif term.effect == "thermal_drift":
                if "tau_s" in term.extra:
                    params["thermal_drift"] = np.array([th[0], term.extra["tau_s"]])
                else:
                    notes.append("thermal_drift from a temperature column: alpha_per_K given, the simulation's "
                                 "warm-up parameters are not identified")
        effects = EffectSet.from_params(params).to_dict()
        base = np.eye(4)
        base[:3, :3], base[:3, 3] = self.state.R, self.state.t
        return {"model": model_to_json(self.state.dh_static(), base, name="diagnosed"), "effects": effects,
                "notes": notes}

    def to_json(self) -> dict:
        return {
            **core_json(self, lambda ct: ct.key),
            "n_poses": {"train": int(self.train.size), "heldout": int(self.heldout.size)},
            "alpha": self.alpha,
            "extended_model": self.extended_effects(),
            "units": "rms and noise_floor: mm (3-D position error); params: mm, rad, rad per N m, 1/K as named",
            "elapsed_s": self.elapsed_s,
        }


def _rms(resid: np.ndarray) -> float:
    return math.sqrt(float(np.mean(np.sum(resid ** 2, axis=1)))) if resid.size else math.nan


def _geometric_term(dh, q, meas, train) -> tuple[Term | None, str | None]:
    """The geometric candidate: the parameters :func:`identify` finds identifiable on the training poses."""
    from station.analysis.arm.identification import identify

    try:
        res = identify(dh, q[train], meas[train], method="absolute", max_iter=1)
    except InsufficientDataError as exc:
        return None, f"too few poses: {exc}"
    except DataError as exc:
        return None, str(exc)
    free = np.array([i for i in res.identifiability.free if i < kin.N_PARAMS], dtype=np.int64)
    if free.size == 0:
        return None, "no kinematic parameter is identifiable from these poses"
    from station.models.effects import Geometric

    names = tuple(Geometric().param_names[i] for i in free)
    return Term("geometric", None, "geometric", names, index=free,
                extra={"fixed": dict(res.identifiability.fixed)}), None


def _test_round(state: ModelState, q, meas, train, heldout, variants: list[Term], alpha: float,
                m_candidates: int) -> list[CandidateTest]:
    pred, A, extra = jacobian(state, q, train, variants)
    r3 = meas[train] - pred
    r = r3.reshape(-1)
    n = train.size
    p = A.shape[2]
    M = A.reshape(-1, p)
    Q = model_basis(M)
    pred_h, A_h, extra_h = jacobian(state, q, heldout, variants)
    r_h = (meas[heldout] - pred_h).reshape(-1)
    Mh = A_h.reshape(-1, p)
    out = []
    for (term, B), (_, Bh) in zip(extra, extra_h):
        ct = CandidateTest(term.key, term.effect, term.joint, True, k=term.k, variant=term)
        dof_poses = n - (p + term.k) / 3.0
        if dof_poses < MIN_DOF_POSES:
            ct.testable, ct.reason = False, (f"too few training poses ({n}) for {term.k} more parameter(s) on top of "
                                             f"the model's {p} (needs {MIN_DOF_POSES} poses to spare)")
            out.append(ct)
            continue
        Bf = B.reshape(-1, term.k)
        factor = (n - term.k / 3.0) / dof_poses
        bt = wald_block(Bf, r, Q, lambda X, res, k=term.k: robust_cov(X.reshape(n, 3, k), res.reshape(n, 3)) * factor)
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
        # held-out: the linearised refit with the candidate
        step = refit_step(M, Bf, r)
        rh1 = r_h - np.concatenate([Mh, Bh.reshape(-1, term.k)], axis=1) @ step
        ct.heldout_rms_after = _rms(rh1.reshape(-1, 3))
        out.append(ct)
    # one entry per candidate key: the best variant (thermal drift's tau grid)
    best: dict = {}
    for ct in out:
        cur = best.get(ct.key)
        score = ct.statistic / ct.threshold if ct.testable else -1.0
        if cur is None or score > (cur.statistic / cur.threshold if cur.testable else -1.0):
            best[ct.key] = ct
    return list(best.values())


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


def diagnose_arm(dh_nominal, q_rad, xyz_mm, *, t_s=None, temperature_c=None, load_kg=None, robot=None,
                 heldout_fraction: float = 0.25, alpha: float = 0.05, max_steps: int = 20) -> ArmDiagnosis:
    """Diagnose the station's arm model against measured tool points.

    Parameters
    ----------
    dh_nominal : array_like, shape (7, 5)
        The station's model (mm, rad; seed 002 eq. (3)).
    q_rad : array_like, shape (N, 6)
        Joint angles in measurement order (the order gives the direction of the last motion).
    xyz_mm : array_like, shape (N, 3)
        Measured tool points, instrument frame.
    t_s, temperature_c, load_kg : array_like, shape (N,), optional
    robot : RobotSpec, optional
        Mass model for the gravity torque of ``joint_compliance``.
    heldout_fraction : float
        Share of the poses held out (chosen to span the workspace).
    alpha : float
        Family-wise false-discovery rate of each selection round.
    """
    import time

    t0 = time.perf_counter()
    dh = np.asarray(dh_nominal, dtype=float)
    q = np.asarray(q_rad, dtype=float)
    meas = np.asarray(xyz_mm, dtype=float)
    _check_inputs(dh, q, meas, {"t_s": t_s, "temperature_c": temperature_c, "load_kg": load_kg})
    if not (0.0 < alpha < 0.5):
        raise DataError(f"`alpha` must be in (0, 0.5), got {alpha!r}")
    train, heldout = workspace_split(q, meas, heldout_fraction)
    last_dir = last_motion_direction(q)
    not_testable: dict = {}
    candidates: list[Term] = []
    geo, why = _geometric_term(dh, q, meas, train)
    if geo is None:
        not_testable["geometric"] = why
    else:
        candidates.append(geo)
    th_terms, why = thermal_terms(t_s, temperature_c)
    if why:
        not_testable["thermal_drift"] = why
    candidates += th_terms
    jt, why_j = joint_terms(dh, q, last_dir, robot=robot, load_kg=load_kg)
    candidates += jt
    not_testable.update(why_j)

    state = initial_state(dh, q, meas, train)
    state, _ = fit(state, q, meas, train)
    resid_sim = meas - predict(state, q, np.arange(q.shape[0]))
    sim_ho = _rms(resid_sim[heldout])
    steps: list[Step] = []
    rounds: list[list[CandidateTest]] = []
    remaining = list(candidates)
    prev_sig: list[CandidateTest] = []
    chosen_prev: CandidateTest | None = None
    for _ in range(max_steps + 1):
        keys = {t.key for t in remaining}
        tests = _test_round(state, q, meas, train, heldout, remaining, alpha, len(keys)) if remaining else []
        rounds.append(tests)
        if chosen_prev is not None and steps:
            now = {ct.key: ct for ct in tests}
            for ct in prev_sig:
                if ct.key == chosen_prev.key:
                    continue
                later = now.get(ct.key)
                gone = later is None or not later.significant
                if gone and ct.rss_reduction >= AMBIGUITY_SHARE * chosen_prev.rss_reduction:
                    steps[-1].ambiguous_with.append(
                        {"effect": ct.effect, "joint": ct.joint,
                         "share_of_residual_explained": ct.rss_reduction / chosen_prev.rss_reduction,
                         "heldout_rms_alone": ct.heldout_rms_after,
                         "note": "explains the same residual: nothing significant is left of it after this step"})
        if len(steps) >= max_steps:
            break
        ho_now = _rms((meas[heldout] - predict(state, q, heldout)))
        sig = [ct for ct in tests if ct.significant and ct.heldout_rms_after < ho_now]
        if not sig:
            break
        best = min(sig, key=lambda ct: ct.heldout_rms_after)
        new_state, _ = fit(state.with_term(best.variant), q, meas, train)
        params, ci = _step_params(new_state, q, meas, train, len(new_state.terms) - 1)
        all_rows = np.arange(q.shape[0])
        r_before = meas - predict(state, q, all_rows)
        r_after = meas - predict(new_state, q, all_rows)
        steps.append(Step(best.variant, params, ci, ho_now, _rms(r_after[heldout]), best.statistic, best.threshold,
                          f"cluster-robust Wald W/k against F({best.k}, n-p/3) at 1 - {alpha:g}/{len(keys)} "
                          "(Bonferroni over the round's candidates)", resid_before=r_before, resid_after=r_after))
        state = new_state
        remaining = [t for t in remaining if t.key != best.key]
        prev_sig = [ct for ct in tests if ct.significant]
        chosen_prev = best
    all_rows = np.arange(q.shape[0])
    resid_final = meas - predict(state, q, all_rows)
    rss = float(np.sum(resid_final[train] ** 2))
    noise_floor = math.sqrt(rss / max(train.size - state.n_params / 3.0, 1.0))
    variables = {"q_rad": q, "last_dir": last_dir, "t_s": t_s, "temperature_c": temperature_c}
    for term in candidates:
        if term.effect == "joint_compliance":
            variables.setdefault("gravity_torque", {})[term.joint] = -term.features[:, 0]
    return ArmDiagnosis(steps, rounds, not_testable, train, heldout, sim_ho, _rms(resid_final[heldout]), noise_floor,
                        state, resid_sim, resid_final, variables, alpha, time.perf_counter() - t0)
