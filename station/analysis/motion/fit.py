"""The approach model of the motion diagnosis and its fit (pure: arrays in, parameters out).

Every approach window is predicted by the closed forms of
:mod:`station.models.approach_response`, with time from the command's end
``tau = t - T_m``:

* baseline (``servo``): the command (deceleration ``a_m`` falling to 0 over
  ``jerk_time_s``) followed by a second-order position loop
  (``frequency_hz``, ``damping``; an underdamped loop rings and overshoots
  here, it is no effect of its own);
* ``creep``: short by ``amplitude_mm`` while moving, in as ``exp(-tau / tau_s)``;
* ``structural_mode``: a mode (``frequency_hz``, ``damping``) driven by the
  deceleration, its deflection ``gain_s2 * a_m`` ringing out after the end;
* ``tracker_drift``: the reading wanders: the late dwell's drift rate
  (:mod:`.windows`), changing at the rate it changed since the previous
  rest's, carried back over the window, times ``shrinkage`` (0: none, 1:
  all of the measured drift).

Per move, ``a_m``, ``T_m`` and the cruise speed ``v_m`` are nuisances: they are fitted (Gauss-Newton,
all moves at once) on the window's *timing part*, the samples more than
:data:`TIMING_MM` and less than :data:`TIMING_FAR_MM` short of the end, given the global parameters; the global
parameters are fitted on the *approach part* (the rest of the window) of the
training moves with the nuisances so profiled out. A held-out move is
predicted the same way: its own timing part sets its ``a_m, T_m, v_m``, its
approach part is never fitted. The speed is a nuisance because the loop's
transients of the profile's earlier edges (:func:`~station.models.approach_response.servo_position`)
are placed by it: a ringing loop lifts the stream's speed around the cruise
(3.5 % on a loop of 6 Hz, damping 0.24), and the speed read off it put those
transients 0.3 mm out of place (the windows' estimate is the start).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from station.models import approach_response as ar

from .windows import Windows

#: samples more than this short of the end time the move (set a_m and T_m), mm
TIMING_MM = 1.0
#: ... and no further than this short of it, mm: far out, a joint move's chord is not its path (a circle of
#: 500 mm radius: arc - chord = s^3 / (24 R^2), 1.3 um at 20 mm, 21 um at 50 mm) and the tool's deceleration
#: varies along it, so one deceleration and end time fitted over the whole deceleration misplaced the end (by
#: 76 um at 1 mm short on a look-alike of issue 42's UR arm, its draw 23), and the loop's fit took up the misfit
TIMING_FAR_MM = 20.0
#: most rounds of a fit (the nuisances' start re-profiled at each)
FIT_ROUNDS = 6
#: a round that does not lower the fully profiled RSS by this fraction of the best round's ends a fit that has
#: not converged, and the best round's parameters are kept (:func:`fit`)
STALL_RTOL = 1e-4
#: Gauss-Newton iterations of the nuisances inside the fit's objective (from the round's start)
OBJECTIVE_ITERATIONS = 3
#: a round's end is the fit's when its objective's RSS and the fully profiled RSS agree within this fraction
PROFILE_RTOL = 1e-2
#: halvings of a per-move Gauss-Newton step that raises the move's cost (then no step for that move)
NUISANCE_HALVINGS = 3
#: Gauss-Newton iterations of the per-move nuisances
NUISANCE_ITERATIONS = 15
#: (name, lowest, highest) of each effect's parameters
EFFECT_PARAMS = {
    "servo": (("frequency_hz", 0.3, 80.0), ("damping", 0.03, 4.0), ("jerk_time_s", 0.0, 0.4)),
    "creep": (("amplitude_mm", -1.0, 1.0), ("tau_s", 0.01, 2.0)),
    "structural_mode": (("frequency_hz", 1.5, 80.0), ("damping", 0.003, 0.6), ("gain_s2", -0.01, 0.01)),
    "tracker_drift": (("shrinkage", 0.0, 1.5),),
}
EFFECTS = ("creep", "structural_mode", "tracker_drift")


@dataclass
class Params:
    """Global parameters of the active effects: ``values[effect]`` arrays in the order of :data:`EFFECT_PARAMS`."""

    values: dict

    @property
    def active(self) -> list[str]:
        return list(self.values)

    def with_(self, effect: str, v) -> "Params":
        d = dict(self.values)
        d[effect] = np.asarray(v, dtype=float)
        return Params(d)

    def vector(self) -> np.ndarray:
        return np.concatenate([self.values[e] for e in self.values])

    def from_vector(self, x) -> "Params":
        out, i = {}, 0
        for e in self.values:
            k = len(EFFECT_PARAMS[e])
            out[e] = np.asarray(x[i:i + k], dtype=float)
            i += k
        return Params(out)

    def bounds(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = [], []
        for e in self.values:
            for name, a, b in EFFECT_PARAMS[e]:
                if name == "frequency_hz":
                    b = min(b, rate_hz / 4.0)
                lo.append(a)
                hi.append(b)
        return np.array(lo), np.array(hi)

    def named(self, effect: str) -> dict:
        return {name: float(v) for (name, _, _), v in zip(EFFECT_PARAMS[effect], self.values[effect])}


def predict(w: Windows, p: Params, a, T, v=None) -> np.ndarray:
    """The model's position along the travel (M, L), mm (``v``: the moves' cruise speeds, the windows' without)."""
    tau = w.t_s - np.asarray(T)[:, None]
    a2 = np.asarray(a)[:, None]
    f, z, tj = p.values["servo"]
    v = (w.v_mm_s if v is None else np.asarray(v, dtype=float))[:, None]
    D = w.D_mm[:, None]
    x = ar.servo_position(tau, a2, tj, 2.0 * math.pi * f, z, v, D)
    if "creep" in p.values:
        A, tc = p.values["creep"]
        x = x + ar.creep(tau, A, tc)
    if "structural_mode" in p.values:
        fm, zm, g = p.values["structural_mode"]
        x = x + g * a2 * ar.mode_response(tau, a2, v, D, tj, (2.0 * math.pi * f, z), (2.0 * math.pi * fm, zm))
    if "tracker_drift" in p.values:
        (k,) = p.values["tracker_drift"]
        dt = w.t_s - w.t_late_s[:, None]
        x = x + k * (w.drift_mm_s[:, None] * dt + 0.5 * w.drift_change_mm_s2[:, None] * dt * dt)
    return x


def parts(w: Windows) -> tuple[np.ndarray, np.ndarray]:
    """Masks (M, L) of the timing part (from :data:`TIMING_FAR_MM` to :data:`TIMING_MM` short of the end) and
    of the approach part (the rest of the window after it)."""
    fin = np.isfinite(w.x_mm)
    x = np.nan_to_num(w.x_mm, nan=0.0)
    timing = fin & (x < -TIMING_MM) & (x > -TIMING_FAR_MM)
    return timing, fin & (x >= -TIMING_MM)


#: the cruise speed's prior sd as a fraction of the windows' estimate (holds it where the timing part has no cruise)
V_PRIOR_FRACTION = 0.05


def nuisances(w: Windows, p: Params, a=None, T=None, v=None, *, iterations: int = NUISANCE_ITERATIONS
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(a_m, T_m, v_m)`` of every move fitted on its timing part, the global parameters ``p`` given.

    Gauss-Newton on the three per move at once (3 x 3 normal equations per move); the speed carries a weak prior
    at the windows' estimate (sd :data:`V_PRIOR_FRACTION` of it, in units of the stream's noise), which only
    matters where the timing part holds no cruise.
    """
    w = _timing_columns(w)
    timing, _ = parts(w)
    a = w.a0_mm_s2.copy() if a is None else np.array(a, dtype=float)
    T = w.T0_s.copy() if T is None else np.array(T, dtype=float)
    v = w.v_mm_s.copy() if v is None else np.array(v, dtype=float)
    m = timing.astype(float)
    X = np.nan_to_num(w.x_mm)
    dt = np.gradient(np.nan_to_num(w.t_s), axis=1)  # the same at every iteration
    prior = _speed_prior(w)
    x0 = None  # the prediction at (a, T, v): the last step's accepted one, else computed
    for _ in range(iterations):
        if x0 is None:
            x0 = predict(w, p, a, T, v)
        r = np.where(timing, X - x0, 0.0)
        da, dv = 1e-4 * a, 1e-4 * v
        ja = np.where(timing, (predict(w, p, a + da, T, v) - x0) / da[:, None], 0.0)
        jv = np.where(timing, (predict(w, p, a, T, v + dv) - x0) / dv[:, None], 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):  # the padding's zeros; a later end moves the curve later
            jT = np.where(timing, -np.gradient(np.nan_to_num(x0), axis=1) / dt, 0.0)
        J = np.stack([ja, jT, jv], axis=2) * np.sqrt(m)[:, :, None]
        H = np.einsum("mli,mlj->mij", J, J)
        g = np.einsum("mli,ml->mi", J, r)
        H[:, 2, 2] += prior
        g[:, 2] -= prior * (v - w.v_mm_s)
        step = _solve_per_move(H, g[:, :, None])[:, :, 0]
        step[:, 1] = np.clip(step[:, 1], -0.05, 0.05)
        cost0 = _move_cost(r, v, w, prior)

        def stepped(f):
            return (np.clip(a + f * step[:, 0], 0.2 * w.a0_mm_s2, 5.0 * w.a0_mm_s2), T + f * step[:, 1],
                    np.clip(v + f * step[:, 2], 0.7 * w.v_mm_s, 1.3 * w.v_mm_s))

        f, x0 = np.ones(len(a)), None
        for _h in range(NUISANCE_HALVINGS + 1):  # a move's step is halved while it raises the move's cost
            a1, T1, v1 = stepped(f)
            x1 = predict(w, p, a1, T1, v1)
            worse = _move_cost(np.where(timing, X - x1, 0.0), v1, w, prior) > cost0
            if not worse.any():
                x0 = x1  # the next iteration's prediction
                break
            f = np.where(worse, 0.5 * f if _h < NUISANCE_HALVINGS else 0.0, f)
        a, T, v = stepped(f)
        if np.max(np.abs(f * step[:, 1])) < 1e-7:
            break
    return a, T, v


def _speed_prior(w: Windows) -> np.ndarray:
    """The weight of each move's speed prior (sd :data:`V_PRIOR_FRACTION` of the windows' speed, in units of the
    stream's noise)."""
    return (max(w.noise_mm, 1e-6) / (V_PRIOR_FRACTION * w.v_mm_s)) ** 2


def _solve_per_move(H: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``H^-1 B`` of each move's 3 x 3 normal equations (``H`` (M, 3, 3), ``B`` (M, 3, k)), scaled to a unit
    diagonal; 0 for a move whose scaled ``H`` is singular (condition number 1e10 or more)."""
    scale = np.sqrt(np.maximum(np.einsum("mii->mi", H), 1e-300))
    Hs = H / scale[:, :, None] / scale[:, None, :]
    good = np.linalg.cond(Hs) < 1e10
    out = np.zeros(B.shape)
    if good.any():
        out[good] = np.linalg.solve(Hs[good], B[good] / scale[good][:, :, None]) / scale[good][:, :, None]
    return out


def _timing_columns(w: Windows) -> Windows:
    """``w`` cut to the columns of its timing parts and one on each side (the slope at their edges); the
    nuisances see nothing else, and a prediction costs by its columns (a tenth of a window's at 150 Hz)."""
    timing, _ = parts(w)
    cols = np.flatnonzero(timing.any(axis=0))
    if cols.size == 0:
        return w
    c0, c1 = max(int(cols[0]) - 1, 0), min(int(cols[-1]) + 2, w.t_s.shape[1])
    return replace(w, t_s=w.t_s[:, c0:c1], x_mm=w.x_mm[:, c0:c1])


def _move_cost(r, v, w: Windows, prior) -> np.ndarray:
    """Each move's timing-part residual sum of squares plus its speed prior's term."""
    return np.einsum("ml,ml->m", r, r) + prior * (v - w.v_mm_s) ** 2


def approach_residual(w: Windows, p: Params) -> tuple[np.ndarray, np.ndarray]:
    """``(residual (M, L) with NaN outside the approach part, prediction (M, L))``, nuisances profiled."""
    a, T, v = nuisances(w, p)
    x = predict(w, p, a, T, v)
    _, app = parts(w)
    return np.where(app, w.x_mm - x, np.nan), x


def _objective(w: Windows, p: Params):
    """``(f, jac)``: the approach residual as a function of the parameters' vector, and its Jacobian.

    ``f`` re-profiles the nuisances from those of ``p`` by :data:`OBJECTIVE_ITERATIONS` Gauss-Newton steps at
    every evaluation (from the same start: a deterministic function). ``jac`` differentiates the profiled
    residual by the implicit function theorem instead of re-profiling per parameter: with the nuisances ``n``
    held, ``dr/dx = -(dP/dx + dP/dn dn/dx)`` on the approach part, where ``dn/dx = -H^-1 J_n' dP/dx`` solves
    each move's normal equations on its timing part (``H = J_n' J_n`` and the speed's prior, as in
    :func:`nuisances`). It costs ``k + 4`` predictions for ``k`` parameters where finite differences of ``f``
    cost ``k`` re-profilings (each 3 to 7 predictions an iteration, 3,074 of the 4,083 evaluations of ``f``
    that made the diagnosis of 5 minutes of a 1 kHz stream take 266 s CPU). Gauss-Newton's normal equations
    leave out the timing part's residual times the second derivatives: at a fit's optimum on a test stream
    ``jac`` was 1-18 % off the difference quotient of the re-profiled ``f`` (0.02 % for the creep's time
    constant, which the timing part does not see), and the trust region's steps are judged on ``f`` itself;
    the fits of test streams reached the same RSS or lower (a loop, creep and mode from a distant start:
    0.085 against 0.160).
    """
    timing, app = parts(w)
    start = nuisances(w, p)
    lo, hi = p.bounds(w.rate_hz)
    X = np.nan_to_num(w.x_mm)
    mt = timing.astype(float)
    prior = _speed_prior(w)
    memo: dict = {}

    def state(x):
        key = np.asarray(x, dtype=float).tobytes()
        if key not in memo:
            memo.clear()
            q = p.from_vector(x)
            a, T, v = nuisances(w, q, *start, iterations=OBJECTIVE_ITERATIONS)
            memo[key] = (q, a, T, v, predict(w, q, a, T, v))
        return memo[key]

    def f(x):
        *_, P = state(x)
        return (X - P)[app]

    def jac(x):
        q, a, T, v, P = state(x)
        x = np.asarray(x, dtype=float)
        h = 1e-4 * np.maximum(1.0, np.abs(x))
        h = np.where(x + h > hi, -h, h)
        dP = np.stack([(predict(w, p.from_vector(x + hk * e), a, T, v) - P) / hk
                       for hk, e in zip(h, np.eye(x.size))], axis=2)  # (M, L, k)
        da, dv = 1e-4 * a, 1e-4 * v
        ja = (predict(w, q, a + da, T, v) - P) / da[:, None]
        jv = (predict(w, q, a, T, v + dv) - P) / dv[:, None]
        dT = 1e-5
        jT = (predict(w, q, a, T + dT, v) - P) / dT
        Jall = np.nan_to_num(np.stack([ja, jT, jv], axis=2))  # (M, L, 3)
        Jn = Jall * mt[:, :, None]  # on the timing part
        H = np.einsum("mli,mlj->mij", Jn, Jn)
        H[:, 2, 2] += prior
        B = np.einsum("mli,mlk->mik", Jn, np.nan_to_num(dP) * mt[:, :, None])
        dn = -_solve_per_move(H, B)
        total = dP + np.einsum("mli,mik->mlk", Jall, dn)
        return -total[app]

    return f, jac


def fit(w: Windows, p: Params) -> tuple[Params, bool, str]:
    """Refit all of ``p``'s parameters on the approach parts of ``w`` (from ``p``).

    Each round minimises :func:`_objective`, whose nuisances start from the round's parameters; the fit ends
    on a round that converged *and* whose objective agrees with the fully profiled RSS (within
    :data:`PROFILE_RTOL`). A round that converged on nuisances still far from their profile has found the
    minimum of a stale objective, not the fit's: with two Gauss-Newton steps there, a loop's jerk time stalled
    at 0.018 s (truth 0) with 35 times the optimum's RSS, and any candidate's refit, which went on fitting
    the loop, then won by the loop's gain (the clean stream of test seed 189560781 named a creep of 2 um).

    A fit that has not converged keeps the round with the lowest profiled RSS, and ends at the first round
    that does not lower it by :data:`STALL_RTOL`. Rounds can cycle: on the hour's bench at seed 2, a mode
    fitted without the stream's creep alternated between two points (objective 0.394 and 0.648 mm^2) for all
    six rounds and returned whichever the sixth round reached, so two starts that found the same pair of
    points ended 60 % apart in RSS (0.499 and 0.799 mm^2). Each such fit took about 5 s of the bench's minute.
    """
    lo, hi = p.bounds(w.rate_hz)
    sol, best, best_rss = None, p, math.inf
    for _ in range(FIT_ROUNDS):  # each round re-profiles the nuisances' start at the round's parameters
        x0 = np.clip(p.vector(), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        f, jac = _objective(w, p)
        sol = least_squares(f, x0, jac=jac, bounds=(lo, hi), x_scale="jac", max_nfev=15, xtol=1e-8, ftol=1e-9)
        p = p.from_vector(sol.x)
        full = rss(w, p)
        if sol.status in (2, 3, 4) and sol.nfev < 15:  # converged within the round: on the profiled RSS?
            if abs(2.0 * sol.cost - full) <= PROFILE_RTOL * max(full, 1e-300):
                return p, bool(sol.success), str(sol.message)
        if not full < best_rss * (1.0 - STALL_RTOL):  # no better than a round before: a cycle, or a stall
            return best, False, f"stopped: a round did not lower the profiled RSS below {best_rss:.6g} (kept)"
        best, best_rss = p, full
    return best, bool(sol.success), str(sol.message)


def rss(w: Windows, p: Params) -> float:
    r, _ = approach_residual(w, p)
    return float(np.nansum(r * r))


def best_starts(w: Windows, p: Params, effect: str, grid, n: int = 1) -> list[Params]:
    """Of the starting values ``grid`` of ``effect`` (with the loop's own rescanned when ``effect`` rings too:
    a mode and a ringing loop trade places), the ``n`` whose models leave the least approach RSS."""
    starts = [p.with_(effect, v) for v in grid]
    if effect == "structural_mode" and "servo" in p.values:
        f, _, tj = p.values["servo"]
        starts += [q.with_("servo", (f, z, tj)) for q in starts for z in (0.7, 1.0)]
    if p.values:  # the current model's nuisances, held while the grid is scanned
        a, T, v = nuisances(w, p)
    else:
        a, T, v = w.a0_mm_s2, w.T0_s, w.v_mm_s
    _, app = parts(w)
    scored = []
    for q in starts:
        if effect == "structural_mode":  # the gain is linear: fitted at each frequency and damping
            q0 = q.with_(effect, (q.values[effect][0], q.values[effect][1], 0.0))
            r = (w.x_mm - predict(w, q0, a, T, v))[app]
            c = (predict(w, q.with_(effect, (q.values[effect][0], q.values[effect][1], 1.0)), a, T, v)
                 - predict(w, q0, a, T, v))[app]
            g = float(c @ r) / max(float(c @ c), 1e-300)
            q = q.with_(effect, (q.values[effect][0], q.values[effect][1], g))
            r = r - g * c
        else:
            r = (w.x_mm - predict(w, q, a, T, v))[app]
        scored.append((float(r @ r), q))
    scored.sort(key=lambda sq: sq[0])
    return [q for _, q in scored[:n]]


def best_start(w: Windows, p: Params, effect: str, grid) -> Params:
    """Of the starting values ``grid`` of ``effect``, the one whose model leaves the least approach RSS."""
    return best_starts(w, p, effect, grid, 1)[0]


def start_grid(effect: str, w: Windows, p: Params) -> list:
    """Starting values of an effect's parameters; amplitudes from the residual's size."""
    nyq = w.rate_hz / 4.0
    if effect == "servo":
        return [(f, z, tj) for f in (2.0, 4.0, 8.0, 16.0, 32.0) if f < nyq for z in (0.3, 0.7, 1.3)
                for tj in (0.0, 0.06)]
    if effect == "creep":
        return [(A, tc) for A in (-0.05, -0.01, 0.01, 0.05) for tc in (0.05, 0.15, 0.4)]
    if effect == "structural_mode":  # frequencies 6 % apart (the gain is fitted linearly at each)
        return [(f, z, 0.0) for f in np.geomspace(3.0, 40.0, 45) if f < nyq for z in (0.03, 0.08)]
    if effect == "tracker_drift":
        return [(0.5,), (1.0,)]
    raise KeyError(effect)
