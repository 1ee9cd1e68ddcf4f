"""Motion diagnosis: where the motion model disagrees with a measured stream near the stops, and why.

1. The stream is cut into moves and approach windows along the travel
   (:mod:`.windows`); moves are held out per pair of poses (from, to): the
   2nd, 5th, 8th ... move of each pair, so every pair has training and
   held-out moves (:func:`split`; the JSON lists them).
2. Baseline (the station's motion model, refitted as ``diagnose arm``
   refits geometry): the command's deceleration and jerk time and a
   second-order position loop (frequency, damping), fitted on the training
   moves (:mod:`.fit`). An underdamped loop rings: that is the baseline's.
3. Candidates ``creep``, ``structural_mode``, ``tracker_drift`` are tested
   one at a time against the current model. A candidate is named when (a)
   on the training moves its refit lowers the approach RSS by more than the
   noise explains, ``F = (dRSS / k) / (RSS / (n - p))`` against
   ``F(k, n - p)`` at ``1 - alpha / m`` (``m`` candidates of the round), and
   (b) on the held-out moves, which chose nothing, the mean-square residual
   falls: per block of :data:`BLOCK_S` of their approach parts, the
   reduction's one-sided Wilcoxon signed-rank test at ``alpha`` (stated as
   a normal quantile, :func:`signed_rank_z`; with fewer than
   :data:`CROSS_FIT_BELOW` held-out moves, cross-fitted: every fold of the
   moves held out in turn, :class:`_CrossFit`),
   and the reduction at least ``(RELEVANCE * noise)^2``; a mode on the loop's own pole or a creep no slower
   than the loop settles and no larger than its lag is the loop's response reshaped, never named
   (:func:`_same_pole`). Of those, the one
   with the lowest held-out RMS is named and the model refitted; again until
   none is left.
4. Time figures per held-out pose (:mod:`.figures`): POS, time to band, PST,
   MPT of the measured curve, the baseline's prediction (``simulated``) and
   the extended model's (``extended``). A clock that failed its check
   (``time_refused``) states no time figure.

RMS and the noise floor are along the travel, mm, over the approach parts
(from :data:`~.fit.TIMING_MM` short of the end to the window's end).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from station.errors import DataError, InsufficientDataError

from . import fit as F
from .figures import approach_figures, mean_figures
from .windows import Windows, cut_windows, decimated

#: blocks of the held-out approach parts the held-out test compares, s
BLOCK_S = 0.1
#: a named effect lowers the held-out mean square by at least (RELEVANCE * noise)^2
RELEVANCE = 0.25
#: most training moves a fit uses (evenly spread), and the rate it decimates them to
MAX_FIT_MOVES = 30
FIT_RATE_HZ = 150.0
#: the held-out moves are compared at this rate or below while choosing (the time figures use every sample)
HELDOUT_RATE_HZ = 350.0
#: starts of each candidate's refit (the best of a grid of starting values)
STARTS = 2
#: ... of a structural mode's: its phase trades with the loop's jerk time and damping, and the grid's order by
#: RSS at the start says little of where a fit ends (a stream of test seed 501, mode 8.05 Hz: the best two
#: starts, 8.66 and 8.16 Hz, ended at 8.53 Hz with a jerk time of 30 ms, truth 0, at 110 times the RSS that the
#: third, 8.16 Hz at damping 0.03, reached at the truth; a "creep" was then named to make up part of it). Four:
#: test seed 1734659580 (mode 8.69 Hz, damping 0.07, under a loop of 6.5 Hz, 0.68) ended all three refits at
#: 5.6 Hz, damping 0.49, held-out z 0.90, nothing named; the fourth start reached a held-out RMS of 1.06 um at a
#: noise of 1.01 um (z 5.6)
STARTS_OF = {"structural_mode": 4}
#: ... but a refit's later starts are skipped once one has left no more than the noise on the training moves:
#: a mean square within (1 + RELEVANCE^2) of the stream's white noise squared (:func:`_at_noise`). The starts
#: that stalled (test seeds 501 and 1734659580 above) stalled far above it. The hour's bench: the mode's three
#: later starts after the creep, none of which converged (about 6 s each, at 58 to 64 times the first's RSS),
#: skipped
#: a winner's refit that lowers the current model's RSS by more than this share of the winner's gain shows
#: the current fit stopped short (:func:`_polished_null`); at most MAX_POLISH such refits a diagnosis
POLISH_SHARE = 0.1
MAX_POLISH = 3
#: fewest training and held-out moves
MIN_TRAIN, MIN_HELDOUT = 3, 1
#: folds of the moves (:func:`folds`); the held-out moves are fold 1
FOLDS = 3
#: with fewer held-out moves than this, the held-out test is cross-fitted (:class:`_CrossFit`)
CROSS_FIT_BELOW = 12


@dataclass
class MotionTest:
    """One candidate tested against the current model."""

    effect: str
    testable: bool = True
    reason: str = ""
    statistic: float = math.nan
    threshold: float = math.nan
    heldout_t: float = math.nan
    heldout_threshold: float = math.nan
    heldout_rms_after: float = math.nan
    relevant: bool = False
    #: why the fitted effect cannot be told from the current model ("" when it can)
    same_as: str = ""
    params: F.Params | None = None
    #: blocks the held-out test compared, and whether they pooled the cross-fitted folds (:class:`_CrossFit`)
    heldout_blocks: int = 0
    cross_fitted: bool = False

    @property
    def significant(self) -> bool:
        return self.testable and self.statistic > self.threshold

    @property
    def wins(self) -> bool:
        return self.significant and self.heldout_t > self.heldout_threshold and self.relevant and not self.same_as

    def to_json(self) -> dict:
        d = {"candidate": self.effect, "effect": self.effect, "joint": None, "testable": self.testable}
        if not self.testable:
            d["reason"] = self.reason
            return d
        return d | {"statistic": _f(self.statistic), "threshold": _f(self.threshold), "significant": self.significant,
                    "heldout_t": _f(self.heldout_t), "heldout_threshold": _f(self.heldout_threshold),
                    "heldout_rms_after": _f(self.heldout_rms_after), "relevant": self.relevant,
                    "heldout_blocks": self.heldout_blocks, "heldout_cross_fitted": self.cross_fitted,
                    "wins_on_heldout": self.wins} | ({"same_as": self.same_as} if self.same_as else {})


def _f(x):
    return float(x) if x is not None and math.isfinite(x) else None


@dataclass
class MotionStep:
    effect: str
    params: dict
    heldout_rms_before: float
    heldout_rms_after: float
    statistic: float
    threshold: float
    heldout_t: float
    heldout_threshold: float
    details: dict = field(default_factory=dict)

    @property
    def gain(self) -> float:
        return 1.0 - self.heldout_rms_after / self.heldout_rms_before if self.heldout_rms_before > 0 else 0.0

    def to_json(self) -> dict:
        return {"effect": self.effect, "joint": None, "params": self.params, "ci": {},
                "heldout_rms_before": self.heldout_rms_before, "heldout_rms_after": self.heldout_rms_after,
                "gain": self.gain, "gain_percent": 100.0 * self.gain, "statistic": self.statistic,
                "threshold": self.threshold, "heldout_t": self.heldout_t, "heldout_threshold": self.heldout_threshold,
                "test": "F on the training moves' approach RSS at 1 - alpha/m, then a one-sided Wilcoxon "
                        f"signed-rank test of the held-out mean-square reduction over {BLOCK_S:g} s blocks at "
                        "alpha (heldout_t: its p value as a normal quantile)",
                "ambiguous_with": [], "details": self.details}


@dataclass
class MotionDiagnosis:
    steps: list
    rounds: list
    not_testable: dict
    simulation_heldout_rms: float
    final_heldout_rms: float
    noise_floor: float
    baseline: F.Params
    final: F.Params
    windows: Windows
    train: np.ndarray
    heldout: np.ndarray
    poses: list
    curves: list
    drift_rate_sd_mm_s: float
    #: the rests' scatter consecutive rests share (:func:`drift_level_sd`), per axis, mm
    drift_level_sd_mm: float
    fits: list
    time_refused: str = ""
    alpha: float = 0.01
    elapsed_s: float = 0.0
    #: what a held-pose record of the tracker says of its drift over an approach window (None: no record given)
    hold: dict | None = None
    #: the named model extended by the effects the training moves support but the held-out moves did not confirm
    #: (:func:`_training_supported`), and those effects in the order added (not named: see there)
    supported: F.Params | None = None
    supported_only: list = field(default_factory=list)
    #: the cross-fitted held-out test's folds (None: the held-out moves alone; :class:`_CrossFit`)
    cross_fit: dict | None = None

    @property
    def gain(self) -> float:
        return 1.0 - self.final_heldout_rms / self.simulation_heldout_rms if self.simulation_heldout_rms > 0 else 0.0

    @property
    def named(self) -> list[str]:
        return [s.effect for s in self.steps]

    def motion_model(self, model: F.Params | None = None) -> dict:
        """The extended motion model as ``--model-out`` writes it (read by :mod:`station.models.motion_effects`)."""
        p = self.final if model is None else model
        effects = {e: p.named(e) for e in p.active if e != "servo"}
        if "tracker_drift" in effects:
            effects["tracker_drift"]["rate_sd_mm_per_s"] = self.drift_rate_sd_mm_s
            effects["tracker_drift"]["level_sd_mm"] = self.drift_level_sd_mm
        return {"kind": "station motion model", "version": 1,
                "units": "mm, s, Hz; gain_s2 is mm of deflection per mm/s^2 of deceleration",
                "servo": p.named("servo"),
                "deceleration_mm_s2": float(np.median(self.windows.a0_mm_s2)),
                "noise_mm": self.noise_floor, "rate_hz": self.windows.rate_hz,
                "effects": effects}

    def to_json(self) -> dict:
        from station.analysis.diagnose.summary_json import core_json

        w = self.windows
        mv = lambda idx: [{"move": int(w.move_index[i]) + 1, "from": w.from_pose[i], "to": w.to_pose[i]}  # noqa: E731
                          for i in idx]
        return {**core_json(self, lambda ct: ct.effect),
                "noise_floor_source": "robust second differences of the stream (white part, per axis)",
                "units": "rms and noise_floor: mm along the travel over the approach parts; figures mm and s",
                "baseline": {"servo": self.baseline.named("servo"),
                             "deceleration_mm_s2_median": float(np.median(w.a0_mm_s2))},
                "extended": {e: self.final.named(e) for e in self.final.active},
                "heldout_moves": mv(self.heldout), "training_moves": mv(self.train),
                "heldout_rule": "per pair of poses (from, to), its 2nd, 5th, 8th ... move",
                "cross_fit": self.cross_fit,
                "n_moves": {"train": int(self.train.size), "heldout": int(self.heldout.size),
                            "skipped": [{"move": k + 1, "reason": r} for k, r in w.skipped]},
                "poses": self.poses, "time_refused": self.time_refused or None,
                "rate_hz": w.rate_hz, "alpha": self.alpha, "fits": self.fits,
                "converged": all(f["converged"] for f in self.fits),
                "extended_model": self.motion_model(), "elapsed_s": self.elapsed_s,
                "hold_drift": self.hold,
                "training_supported": {"effects": list(self.supported_only),
                                       "model": ({e: self.supported.named(e) for e in self.supported.active}
                                                 if self.supported is not None else None),
                                       "note": "significant on the training moves (F at 1 - alpha/m), not confirmed "
                                               "on the held-out moves: not named"}}


def folds(w: Windows) -> np.ndarray:
    """Each move's fold (0, 1, 2): per pair of poses (from, to), its occurrence modulo 3 (the 1st, 4th ... in
    fold 0, the 2nd, 5th ... in fold 1, the 3rd, 6th ... in fold 2); where fold 1 would be empty (every pair
    once), the moves' order modulo 3."""
    seen: dict = {}
    fold = np.zeros(w.n, int)
    for i, key in enumerate(zip(w.from_pose, w.to_pose)):
        occ = seen.get(key, 0)
        seen[key] = occ + 1
        fold[i] = occ % FOLDS
    if np.count_nonzero(fold == 1) < MIN_HELDOUT:
        fold = np.arange(w.n) % FOLDS
    return fold


def split(w: Windows) -> tuple[np.ndarray, np.ndarray]:
    """Training and held-out moves: per pair of poses, the 2nd, 5th, 8th ... held out (fold 1 of :func:`folds`)."""
    held = folds(w) == 1
    train, heldout = np.flatnonzero(~held), np.flatnonzero(held)
    if train.size < MIN_TRAIN or heldout.size < MIN_HELDOUT:
        raise InsufficientDataError(f"the stream holds {w.n} usable move(s); the diagnosis needs at least "
                                    f"{MIN_TRAIN} training and {MIN_HELDOUT} held-out moves")
    return train, heldout


def _spread(idx: np.ndarray, k: int) -> np.ndarray:
    if idx.size <= k:
        return idx
    return idx[np.unique(np.round(np.linspace(0, idx.size - 1, k)).astype(int))]


def training_windows(w: Windows, train: np.ndarray) -> Windows:
    """The windows a fit uses of the moves ``train``: at most :data:`MAX_FIT_MOVES` of them, evenly spread,
    decimated to :data:`FIT_RATE_HZ` or below."""
    return decimated(w.select(_spread(train, MAX_FIT_MOVES)), FIT_RATE_HZ)


def _rms(r) -> float:
    v = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(v * v))) if v.size else math.nan


def _block_reductions(w: Windows, r0: np.ndarray, r1: np.ndarray) -> list:
    """The mean-square reduction from ``r0`` to ``r1`` in each block of :data:`BLOCK_S` of each move's approach
    part."""
    d = []
    for i in range(w.n):
        m = np.isfinite(r0[i]) & np.isfinite(r1[i])
        if not m.any():
            continue
        tt = w.t_s[i][m]
        b = np.floor((tt - tt[0]) / BLOCK_S).astype(int)
        s0 = np.bincount(b, r0[i][m] ** 2)
        s1 = np.bincount(b, r1[i][m] ** 2)
        c = np.bincount(b)
        ok = c > 0
        d.extend(((s0[ok] - s1[ok]) / c[ok]).tolist())
    return d


def signed_rank_z(d) -> tuple[float, int]:
    """``(z, n)``: the one-sided Wilcoxon signed-rank test that the reductions ``d`` lie above 0, its p value as
    the standard normal quantile ``z = Phi^-1(1 - p)`` (compared with ``Phi^-1(1 - alpha)``); NaN under 3.

    The blocks' reductions are anything but normal: a creep of 0.3 s lowers a few early blocks of each
    approach by orders of magnitude more than the late ones, so a t statistic's spread grew with the effect
    and, on the lab's two held-out moves (about 20 blocks), could not pass 2.8 however large the gain was
    (2.49-2.80 against 2.52 for a tenfold lower held-out error). Ranks keep the evidence of every block that
    improves without letting the largest set the scale.
    """
    d = np.asarray(d, dtype=float)
    d = d[np.isfinite(d) & (d != 0.0)]
    if d.size < 3:
        return math.nan, int(d.size)
    p = float(stats.wilcoxon(d, alternative="greater").pvalue)
    return float(stats.norm.isf(max(p, 1e-300))), int(d.size)


#: a mode whose pole lies within this fraction of the loop's (|s_mode - s_loop| / |s_loop|) is the loop's
SAME_POLE = 0.1


def _same_pole(p: F.Params, effect: str = "structural_mode", decel_mm_s2: float | None = None) -> str:
    """Why a fitted structural mode is the position loop's own ringing, or a fitted creep (``effect`` the
    candidate tested) the loop's own approach (:func:`_creep_inside_loop`); "" when neither is.

    A mode at the loop's frequency *and* damping is the loop's complex pole pair counted twice: its term only
    reshapes the loop's response, which the loop's own parameters (and their misfit) already describe, so it
    names no second physical cause. The pairs are compared by their characteristic polynomials
    ``s^2 + 2 zeta w s + w^2``, i.e. by natural frequency ``w`` and decay rate ``zeta w``, both relative to the
    loop's ``w``: that distance is the poles' own where the loop rings (``zeta`` well under 1) and stays well
    conditioned at critical damping, where the poles' imaginary parts ``w sqrt(1 - zeta^2)`` move by a fifth of
    ``w`` for a 2 % change of ``zeta``.
    """
    if effect == "creep" and "servo" in p.values:
        why = _creep_inside_loop(p, decel_mm_s2)
        if why:
            return why
    if "structural_mode" not in p.values or "servo" not in p.values:
        return ""
    f, z, _ = p.values["servo"]
    fm, zm, _ = p.values["structural_mode"]
    d = math.hypot(fm / f - 1.0, (zm * fm - z * f) / f)
    if d < SAME_POLE:
        return (f"the mode's pole ({fm:.3g} Hz, damping {zm:.2g}) is the position loop's ({f:.3g} Hz, {z:.2g}): "
                f"{d:.2g} apart, under {SAME_POLE:g}")
    return ""


def loop_time_constant_s(frequency_hz: float, damping: float) -> float:
    """The position loop's slowest time constant, s: ``1 / (zeta w)`` where it rings, the slow real pole's
    ``1 / (w (zeta - sqrt(zeta^2 - 1)))`` where it is overdamped."""
    w = 2.0 * math.pi * frequency_hz
    if damping < 1.0:
        return 1.0 / (damping * w)
    return 1.0 / (w * (damping - math.sqrt(damping * damping - 1.0)))


#: a creep up to this multiple of the loop's lag ``a / w^2`` (and no slower than the loop) is the lag taken back
LAG_SHARE = 2.0


def loop_settling_s(frequency_hz: float, damping: float) -> float:
    """How long the position loop takes to approach, s: the larger of its slowest time constant
    (:func:`loop_time_constant_s`) and the time after which its step error ``e(t)`` stays under ``1/e`` of the
    step (a first-order lag's time constant by the same measure).

    Near critical damping the two differ: the double pole's error ``(1 + w t) exp(-w t)`` falls to ``1/e`` at
    ``2.15 / w``, not ``1 / w``. ``e(t)``: ``exp(-zeta w t) (cos w_d t + zeta / sqrt(1 - zeta^2) sin w_d t)``
    below critical damping, ``(p2 exp(-p1 t) - p1 exp(-p2 t)) / (p2 - p1)`` above (poles ``p1 < p2``).
    """
    w = 2.0 * math.pi * frequency_hz
    z = float(damping)
    t_env = loop_time_constant_s(frequency_hz, z)
    t = np.linspace(0.0, 12.0 * max(t_env, 2.15 / w), 24001)
    if abs(z - 1.0) < 1e-6:
        e = (1.0 + w * t) * np.exp(-w * t)
    elif z < 1.0:
        wd = w * math.sqrt(1.0 - z * z)
        e = np.exp(-z * w * t) * (np.cos(wd * t) + z / math.sqrt(1.0 - z * z) * np.sin(wd * t))
    else:
        r = math.sqrt(z * z - 1.0)
        p1, p2 = w * (z - r), w * (z + r)
        e = (p2 * np.exp(-p1 * t) - p1 * np.exp(-p2 * t)) / (p2 - p1)
    above = np.flatnonzero(np.abs(e) >= math.exp(-1.0))
    i = int(above[-1]) if above.size else 0
    return max(t_env, float(t[min(i + 1, t.size - 1)]))


def _creep_inside_loop(p: F.Params, decel_mm_s2: float | None = None) -> str:
    """Why a fitted creep is the position loop's own approach ("" when it is not).

    A creep creeps in *after* the loop has settled: its time constant is longer than the loop's approach
    (:func:`loop_settling_s`). An exponential that dies out while the loop still rings or converges, and is no larger
    than :data:`LAG_SHARE` times the loop's own lag behind the command (``a / w^2`` at the moves' median deceleration
    ``decel_mm_s2``; not checked without it), only reshapes the loop's transient: it stands for a misfit of the loop's
    form (an approach faster than the fit's loop can follow, a deceleration's ramp), not for a second physical cause. On
    a lab look-alike with no dynamics at all (the profile's stop exact, test seed 1442964155 of the CLI's test), a
    baseline loop of 27.8 Hz, damping 0.14 (decaying in 42 ms) took a "creep" of 16 um in 10 ms, on its bound, which
    lowered the held-out RMS from 0.93 to 0.60 um (refitted with it, the loop's damping rose to 1.2: 10.1 ms). A time
    constant on its floor is no creep either way: the fit wanted it faster still. The lag matters where a loop without
    the arm's dynamics runs to the damping's floor and rings for longer than any creep: a look-alike of issue 42's UR
    arm at 50 % (draw 203) fitted a creep of 213 um in 185 ms under a loop of 18.7 Hz at damping 0.03 (284 ms), whose
    lag at 149 mm/s^2 is 11 um: a creep twenty times the loop's whole transient reshapes nothing. Where the fit trades
    the creep against the loop, the creep takes the lag back: a look-alike with no dynamics (CI seed 1118271384, test
    seed 1049121489) named a "creep" of 23.0 um in 10.4 ms beside a loop refitted to 23.7 Hz at damping 0.997, whose lag
    was 23.2 um and whose error falls to 1/e in 14.5 ms (its pole's 6.7 ms was the old measure); candidates of that kind
    sat at 0.99-1.03 of the lag on other look-alike draws, hence the margin of :data:`LAG_SHARE`.
    """
    f, z, _ = p.values["servo"]
    A, tc = p.values["creep"]
    t_loop = loop_settling_s(f, z)
    floor = next(lo for name, lo, _ in F.EFFECT_PARAMS["creep"] if name == "tau_s")
    if tc <= floor * (1.0 + 1e-3):
        return (f"the creep's time constant ran to its floor ({1e3 * floor:.3g} ms): faster than any creep, a "
                f"reshaping of the loop's approach ({f:.3g} Hz, damping {z:.2g})")
    lag = math.inf if decel_mm_s2 is None else float(decel_mm_s2) / (2.0 * math.pi * f) ** 2
    if tc <= t_loop and abs(A) <= LAG_SHARE * lag:
        return (f"the creep's time constant ({1e3 * tc:.3g} ms) is within the position loop's ({1e3 * t_loop:.3g} ms, "
                f"{f:.3g} Hz, damping {z:.2g}) and its amplitude ({1e3 * abs(A):.3g} um) within the loop's lag"
                + (f" ({1e3 * lag:.3g} um, x{LAG_SHARE:g})" if math.isfinite(lag) else "")
                + ": it reshapes the loop's approach, no creep after it")
    return ""


def hold_drift(w: Windows, hold: dict) -> dict:
    """What a held-pose record of the tracker says of the reading's drift over one approach window.

    ``hold``: the record's fit of eq. (N2) (:mod:`station.analysis.iso9283.tracker_noise_fit`): ``white_mm``,
    ``wander_mm`` and ``wander_tau_s`` (None without wander). Over a window of ``D`` s (the windows' median
    span) the wander moves the reading by ``sqrt(2 gamma_w(D)) = wander sqrt(2 (1 - exp(-D / tau)))`` per axis
    (1 sd; eq. (N2) without its white part). The ``tracker_drift`` candidate is tested only when that
    exceeds what the held-out test can see, ``RELEVANCE`` times the stream's noise: a tracker that does not
    wander so much cannot be the cause of a drift the stream shows (``reason`` says why it is left out).
    """
    spans = np.nanmax(w.t_s, axis=1) - np.nanmin(w.t_s, axis=1) if w.n else np.zeros(0)
    D = float(np.median(spans)) if spans.size else 0.0
    wander, tau = float(hold.get("wander_mm") or 0.0), hold.get("wander_tau_s")
    moved = wander * math.sqrt(2.0 * (1.0 - math.exp(-D / tau))) if wander > 0.0 and tau else 0.0
    visible = RELEVANCE * w.noise_mm
    out = {"source": hold.get("source", "a held-pose record"), "white_mm": hold.get("white_mm"),
           "wander_mm": wander, "wander_tau_s": tau, "window_s": D, "expected_drift_mm": moved,
           "visible_mm": visible, "reason": ""}
    if moved < visible:
        out["reason"] = (f"the held-pose record ({out['source']}) shows the tracker's reading wander by "
                         f"{1000 * moved:.2g} um over a {D:.2g} s window, under the {1000 * visible:.2g} um the "
                         "held-out test can see: a drift in the stream is not the tracker's")
    return out


def _not_testable(w: Windows, tr: Windows) -> dict:
    out = {}
    if w.rate_hz < 4.0 * F.EFFECT_PARAMS["structural_mode"][0][1]:
        out["structural_mode"] = f"{w.rate_hz:.4g} Hz sampling cannot show a mode of a few Hz"
    if not np.all(np.isfinite(tr.drift_mm_s)):
        out["tracker_drift"] = "no late dwell to measure the reading's drift on"
    return out


def diagnose_motion(t_s, xyz_mm, poses_mm, names, *, valid=None, alpha: float = 0.01, time_refused: str = "",
                    max_steps: int = 3, hold: dict | None = None) -> MotionDiagnosis:
    """Diagnose the motion model against a measured stream (see the module's docstring).

    Parameters
    ----------
    t_s : (N,) sample times, s (on a checked clock; see ``time_refused``).
    xyz_mm : (N, 3) measured positions, mm.
    poses_mm, names : the commanded poses (P, 3) mm in the stream's frame, and their names.
    valid : (N,) bool, optional; rows to leave out are False.
    alpha : family-wise false-discovery rate of a round (training test) and of each held-out test.
    time_refused : why the clock may not give time figures ("" when it may).
    hold : a held-pose record's fit of the tracker's noise (:func:`hold_drift`), optional: the
        ``tracker_drift`` candidate is tested only when the tracker wanders enough to be seen.
    """
    t0 = time.perf_counter()
    if not (0.0 < alpha < 0.5):
        raise DataError(f"`alpha` must be in (0, 0.5), got {alpha!r}")
    w = cut_windows(t_s, xyz_mm, poses_mm, names, valid)
    train, held = split(w)
    tr = training_windows(w, train)
    ho_full = w.select(held)
    ho = decimated(ho_full, HELDOUT_RATE_HZ)
    noise = w.noise_mm
    fits = []

    def refit(p, label, on=None):
        q, ok, msg = F.fit(tr if on is None else on, p)
        fits.append({"fit": label, "converged": ok, "message": msg})
        return q

    base = _baseline(tr, fits)
    r_sim, _ = F.approach_residual(ho, base)
    sim_rms = _rms(F.approach_residual(ho_full, base)[0])
    not_testable = _not_testable(w, tr)
    hd = hold_drift(w, hold) if hold is not None else None
    if hd is not None and hd["reason"] and "tracker_drift" not in not_testable:
        not_testable["tracker_drift"] = hd["reason"]
    remaining = [e for e in F.EFFECTS if e not in not_testable]
    cur, r_cur, full_rms = base, r_sim, sim_rms
    steps, rounds = [], []
    n_app = int(np.count_nonzero(F.parts(tr)[1]))
    polished = 0
    xf = _CrossFit(w, folds(w), refit) if held.size < CROSS_FIT_BELOW else None
    while True:  # rounds: one effect named per round, until none wins or max_steps are named
        tests = []
        rss0 = F.rss(tr, cur)
        for e in remaining:
            ct = _trained(e, tr, cur, rss0, refit, "", n_app, alpha / max(len(remaining), 1))
            q = ct.params
            r1, _ = F.approach_residual(ho, q)
            ct.heldout_rms_after = _rms(r1)
            pairs = [(ho, r_cur, r1)]
            if xf is not None and ct.significant and not ct.same_as:  # only a candidate that can win
                pairs += xf.pairs(cur, ct)
                ct.cross_fitted = True
            ct.heldout_t, ct.heldout_blocks = signed_rank_z(
                np.array([d for pp in pairs for d in _block_reductions(*pp)]))
            ct.heldout_threshold = float(stats.norm.isf(alpha))
            ms0, ms1 = _pooled_ms([pp[1] for pp in pairs]), _pooled_ms([pp[2] for pp in pairs])
            ct.relevant = bool(ms0 - ms1 >= (RELEVANCE * noise) ** 2)
            tests.append(ct)
        rounds.append(tests)
        wins = [ct for ct in tests if ct.wins]
        better = _polished_null(wins, tr, refit, rss0) if wins and polished < MAX_POLISH else None
        if better is not None:  # the current model's own fit had stopped short: the round again, from there
            polished += 1
            rounds.pop()
            cur = better
            r_cur, _ = F.approach_residual(ho, cur)
            full_rms = _rms(F.approach_residual(ho_full, cur)[0])
            if not steps:  # the baseline itself
                base, r_sim, sim_rms = cur, r_cur, full_rms
            continue
        if not wins or len(steps) >= max_steps:
            break
        best = min(wins, key=lambda ct: ct.heldout_rms_after)
        r_new, _ = F.approach_residual(ho, best.params)
        full_new = _rms(F.approach_residual(ho_full, best.params)[0])
        steps.append(MotionStep(best.effect, best.params.named(best.effect), full_rms, full_new,
                                best.statistic, best.threshold, best.heldout_t, best.heldout_threshold,
                                {"heldout_blocks": best.heldout_blocks, "heldout_cross_fitted": best.cross_fitted}))
        cur, r_cur, full_rms = best.params, r_new, full_new
        remaining = [e for e in remaining if e != best.effect]
        if not remaining:
            break
    supported, extra = _training_supported(rounds[-1] if rounds else [], remaining, steps, max_steps, refit, tr,
                                           alpha, n_app, cur)
    sd_drift, level_drift = _drift_sd(w), drift_level_sd(w)
    if "tracker_drift" in cur.active:
        steps[[s.effect for s in steps].index("tracker_drift")].details.update(
            rate_sd_mm_per_s=sd_drift, level_sd_mm=level_drift)
    poses, curves = _figures(ho_full, base, cur, time_refused)
    return MotionDiagnosis(steps, rounds, not_testable, sim_rms, full_rms, noise, base, cur, w, train, held,
                           poses, curves, sd_drift, level_drift, fits, time_refused, alpha, time.perf_counter() - t0, hd,
                           supported, extra, xf.to_json(w) if xf is not None else None)


def _pooled_ms(rs) -> float:
    """The mean square of the finite values of the residual arrays ``rs`` together."""
    v = np.concatenate([r[np.isfinite(r)] for r in rs])
    return float(np.mean(v * v)) if v.size else math.nan


class _CrossFit:
    """The held-out test cross-fitted, where the held-out moves are few (under :data:`CROSS_FIT_BELOW`).

    The moves' other folds (:func:`folds`: fold 1 is the held-out moves) are held out in turn: fold ``k``'s
    training moves are every move outside it; the current model and a candidate's model (each from its fit on
    the training moves) are refitted there and predict fold ``k``'s moves, which chose neither. The held-out
    test then pools the blocks of every fold (:func:`_block_reductions`), each move predicted by models that never
    saw it: on the lab's program (six moves a speed) the held-out moves are two, about 20 blocks of 0.1 s, too
    few for a signed-rank test to pass at alpha 0.01 however large the gain (a look-alike of issue 42's UR arm,
    draw 107: the creep lowered the held-out RMS from 38 to 3 um and scored z 1.82 against 2.33); pooled, all
    six moves are held out once. Only a candidate that could win (significant on the training moves, not the
    loop's own) is cross-fitted: each costs one refit a fold, and the current model one a fold a round.
    """

    def __init__(self, w: Windows, fold: np.ndarray, refit):
        self.refit, self.parts, self._null_of, self._null = refit, [], None, []
        for k in range(FOLDS):
            held, train = np.flatnonzero(fold == k), np.flatnonzero(fold != k)
            if k == 1 or held.size < MIN_HELDOUT or train.size < MIN_TRAIN:
                continue
            tr = training_windows(w, train)
            self.parts.append((k, held, tr, decimated(w.select(held), HELDOUT_RATE_HZ)))

    def pairs(self, cur: F.Params, ct: MotionTest) -> list:
        """``[(held-out windows, current model's residual, candidate's residual)]`` of each other fold."""
        if self._null_of is not cur:  # the current model refitted without each fold, once a round
            self._null = [F.approach_residual(ho, self.refit(cur, f"cross-fit fold {k}: {'+'.join(cur.active)}",
                                                             on=tr))[0] for k, _, tr, ho in self.parts]
            self._null_of = cur
        out = []
        for (k, _, tr, ho), r0 in zip(self.parts, self._null):
            q = self.refit(ct.params, f"cross-fit fold {k}: {'+'.join(ct.params.active)}", on=tr)
            out.append((ho, r0, F.approach_residual(ho, q)[0]))
        return out

    def to_json(self, w: Windows) -> dict:
        return {"folds": [{"fold": k, "heldout_moves": [int(w.move_index[i]) + 1 for i in held]}
                          for k, held, _, _ in self.parts],
                "rule": "per pair of poses, the 1st, 4th ... move (fold 0) and the 3rd, 6th ... (fold 2; where "
                        "every pair occurs once, the moves' order modulo 3) held out in turn as the 2nd, 5th ... "
                        "are: the current model and each candidate that could win refitted without the fold "
                        "predict it; the held-out test pools the blocks of every fold",
                "used_below_heldout_moves": CROSS_FIT_BELOW}


#: a baseline whose start holds the jerk time on its lower bound (0) is also fitted from this jerk time, s
JERK_LIFT_S = 0.02
#: the baseline is refitted from this many of the grid's best starts, the lowest RSS kept
BASELINE_STARTS = 4


def _at_noise(tr: Windows, rss: float, p: F.Params) -> bool:
    """Whether a fit's training RSS ``rss`` is the noise's alone: its mean square over the approach samples'
    degrees of freedom no more than ``(1 + RELEVANCE^2)`` times the stream's white noise squared.

    The noise is the stream's robust second differences, which read high: on 25 clean test streams the
    refitted loop's training mean square was 0.57-0.90 of it (the hour's bench, with its effects fitted: 0.95),
    so a fit that leaves the noise alone passes, and one judged at the noise may still leave up to about a
    third of it unexplained. The stalled starts seen (:data:`STARTS_OF`) left 25 to 450 times the noise's mean
    square. A tracker's wander, which the white estimate leaves out, keeps the mean square of the lab's
    look-alikes above it: their every start is fitted."""
    dof = int(np.count_nonzero(F.parts(tr)[1])) - p.vector().size
    return dof > 0 and rss <= dof * (1.0 + RELEVANCE ** 2) * tr.noise_mm ** 2


def _baseline(tr: Windows, fits: list) -> F.Params:
    """The baseline (the loop and the profile's jerk time) refitted on the training moves from the
    :data:`BASELINE_STARTS` best starts of the grid (a start with the jerk time on its bound 0 also from
    :data:`JERK_LIFT_S`), the lowest RSS kept; ``fits`` gets the kept fit's status.

    The jerk time moves the prediction by its square near 0 (the deceleration's ramp shifts the command by
    ``a tj^2``: the RSS of draw 5's stalled loop fell by 1e-6 at 0.1 ms, 9e-5 at 1 ms, 19 % at 90 ms), so at 0
    the RSS's gradient in it vanishes and a fit started there, as the grid's best starts were, cannot leave it.
    Whether a fit got away was a matter of rounding: on look-alikes of issue 42's UR arm the in-memory stream
    stalled at 0 where its lab export (the same samples to 1 nm, the same clock) did not, or the other way
    round, and the two paths' baselines differed by up to 73 % in training RSS (draw 17 at 100 %: 27.8 Hz,
    damping 0.185 in memory against 27.6 Hz, 0.054 through the export; draw 23 at 50 %: held-out RMS 34.9 um
    against 26.4 um); draw 11 at 50 % stalled on both, at 2.2 times the RSS the fit reaches off the bound.
    Off the bound, a baseline without the arm's creep and mode lies in a long, flat valley (the loop at
    12-28 Hz, damping at its floor, within 0.5 % of RSS): one start from the grid ended at 13.2 Hz on one path
    and 15.9 Hz on the other; the best of four ended within 2 % on both in the draws measured.
    """
    best, best_rss, n, skipped = None, math.inf, 0, ""
    starts = F.best_starts(tr, F.Params({}), "servo", F.start_grid("servo", tr, F.Params({})), n=BASELINE_STARTS)
    for i, start in enumerate(starts):
        f, z, tj = start.values["servo"]
        for s in [start] + ([start.with_("servo", (f, z, JERK_LIFT_S))] if tj <= 0.0 else []):
            q, ok, msg = F.fit(tr, s)
            r, n = F.rss(tr, q), n + 1
            if r < best_rss:
                best, best_rss, status = q, r, (ok, msg)
        if i + 1 < len(starts) and _at_noise(tr, best_rss, best):
            skipped = f"; the other {len(starts) - i - 1} of the grid's best skipped: it left the noise alone"
            break
    fits.append({"fit": f"baseline (the best of {n} starts{skipped})", "converged": status[0], "message": status[1]})
    return best


def _training_supported(last: list, remaining: list, steps: list, max_steps: int, refit, tr: Windows,
                        alpha: float, n_app: int, cur: F.Params) -> tuple[F.Params, list]:
    """The named model extended, one effect at a time, by what the training moves' F test alone supports.

    Where the held-out moves are few (the lab's program: two of six), an effect can lower the held-out error
    fivefold and still miss the held-out test, and an effect left out biases the rest: a structural mode left
    to the loop refitted a loop of 15.3 Hz, damping 0.84 at 13.2 Hz, 0.60, and a dry run with it overshot
    into the 0.02 mm band (PST 0.24 s against 0.034 s measured). Starting from the last round's candidates
    (tested against the named model), the most significant one is added while any passes the training F test
    at ``1 - alpha / m``; the result is a model for a dry run, stated as not confirmed (nothing is named by it).
    """
    if len(steps) >= max_steps:
        return cur, []
    tests = [ct for ct in last if ct.effect in remaining]
    extra = []
    while True:
        sig = [ct for ct in tests if ct.significant and not ct.same_as]
        if not sig:
            return cur, extra
        best = max(sig, key=lambda ct: ct.statistic)
        cur = best.params
        extra.append(best.effect)
        remaining = [e for e in remaining if e != best.effect]
        rss0 = F.rss(tr, cur)
        tests = [_trained(e, tr, cur, rss0, refit, "supported ", n_app, alpha / max(len(remaining), 1))
                 for e in remaining]


def _trained(e: str, tr: Windows, cur: F.Params, rss0: float, refit, label: str, n_app: int,
             level: float) -> MotionTest:
    """Candidate ``e`` refitted with ``cur`` on the training moves (the best of :data:`STARTS` starts) and its
    F test against ``cur`` (RSS ``rss0``) at ``1 - level``; the held-out fields left to the caller."""
    ct = MotionTest(e)
    q, best_rss = None, math.inf
    for start in F.best_starts(tr, cur, e, F.start_grid(e, tr, cur), n=STARTS_OF.get(e, STARTS)):
        qq = refit(start, f"{label}{'+'.join(cur.active[1:] + [e])}")
        s1 = F.rss(tr, qq)
        if s1 < best_rss:
            q, best_rss = qq, s1
        if _at_noise(tr, best_rss, q):  # later starts could not gain what the held-out test would count
            break
    k, p_all = len(F.EFFECT_PARAMS[e]), q.vector().size
    ct.statistic = ((rss0 - best_rss) / k) / max(best_rss / max(n_app - p_all, 1), 1e-300)
    ct.threshold = float(stats.f.isf(level, k, max(n_app - p_all, 1)))
    ct.params, ct.same_as = q, _same_pole(q, e, float(np.median(tr.a0_mm_s2)))
    return ct


def _polished_null(wins: list, tr: Windows, refit, rss0: float) -> F.Params | None:
    """The current model refitted from each winning candidate's fit with the candidate's effect taken out;
    the best of them when it lowers the training RSS ``rss0`` by more than :data:`POLISH_SHARE` of what its
    candidate did, else None.

    A candidate's refit moves the current model's parameters too; where the current fit had stopped short of
    its optimum (a loop's jerk time held at 7 ms, truth 0, its RSS 6 % above what a second refit reached), the
    candidate wins by that part alone: the clean stream of test seed 1771004305 named a tracker drift of
    shrinkage 7e-6 (F 145 against 8.6, held-out z 3.3). The F test and the held-out test compare an effect
    with the current model at its own optimum.
    """
    best, best_rss = None, rss0
    for ct in wins:  # loop over winners: the current model from each one's fit
        null = F.Params({k: v for k, v in ct.params.values.items() if k != ct.effect})
        q = refit(null, f"polish of the current model from +{ct.effect}")
        s = F.rss(tr, q)
        if rss0 - s > POLISH_SHARE * max(rss0 - F.rss(tr, ct.params), 0.0) and s < best_rss:
            best, best_rss = q, s
    return best


def drift_level_sd(w: Windows) -> float:
    """The part of the rests' scatter that consecutive rests share, per axis, mm: the reading's slow drift.

    Each rest's attained position (``p_end_mm``) less its pose's mean over the stream; the mean over pairs of
    consecutive moves' rests of the dot product of those deviations, over 3. A stop's scatter is its own, and a
    wander much shorter than the time between two rests (the tracker's, ~1 s) decorrelates between them: neither
    is shared, and both leave this near 0. A drift slower than the time between rests moves both alike (the
    tracker's reading drifts at every pose): it is its variance. Negative sums (noise) give 0. This sets the
    size of the dry run's drift (:func:`station.models.motion_effects.approach_offsets_mm`); the rests' drift
    rates (:func:`_drift_sd`) set its time scale. 0 when no two consecutive rests are at poses visited twice.
    """
    dev = np.full((w.n, 3), np.nan)
    to = np.asarray(w.to_pose, dtype=object)
    for pose in set(w.to_pose):
        i = np.flatnonzero(to == pose)
        if i.size >= 2:
            dev[i] = w.p_end_mm[i] - np.mean(w.p_end_mm[i], axis=0)
    o = np.argsort(w.move_index, kind="stable")
    a, b = dev[o][:-1], dev[o][1:]
    ok = (np.diff(w.move_index[o]) == 1) & np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    if not ok.any():
        return 0.0
    c = float(np.mean(np.sum(a[ok] * b[ok], axis=1))) / 3.0
    return math.sqrt(c) if c > 0.0 else 0.0


def _drift_sd(w: Windows) -> float:
    """The spread of the late dwells' drift rates beyond what the noise gives them, mm/s."""
    v = w.drift_mm_s[np.isfinite(w.drift_mm_s)]
    if v.size < 3:
        return 0.0
    # a least-squares slope over D s at r Hz has the variance 12 sigma^2 / (r D^3)
    se2 = float(np.mean(12.0 * w.noise_mm ** 2 / (w.rate_hz * np.maximum(w.late_s, 1e-3) ** 3)))
    return float(math.sqrt(max(float(np.var(v, ddof=1)) - se2, 0.0)))


def _figures(ho: Windows, base: F.Params, ext: F.Params, time_refused: str):
    """Per held-out pose the mean figures of the measured, simulated and extended curves; the curves."""
    a_b, T_b, v_b = F.nuisances(ho, base)
    a_e, T_e, v_e = F.nuisances(ho, ext)
    xs, xe = F.predict(ho, base, a_b, T_b, v_b), F.predict(ho, ext, a_e, T_e, v_e)
    per: dict = {}
    curves = []
    for i in range(ho.n):
        m = np.isfinite(ho.x_mm[i])
        t = ho.t_s[i][m]
        figs = {k: approach_figures(t, x[i][m], ho.t_leave_s[i]) for k, x in
                (("measured", ho.x_mm), ("simulated", xs), ("extended", xe))}
        per.setdefault(ho.to_pose[i], []).append(figs)
        curves.append({"move": int(ho.move_index[i]) + 1, "from": ho.from_pose[i], "to": ho.to_pose[i],
                       "tau_s": t - T_e[i], "measured": ho.x_mm[i][m], "simulated": xs[i][m],
                       "extended": xe[i][m]})
    out = []
    for pose, figs in per.items():
        d = {"pose": pose, "n_moves": len(figs)}
        for k in ("measured", "simulated", "extended"):
            f = mean_figures([g[k] for g in figs])
            if time_refused:
                f.update({"time_to_band_s": None, "PST_s": None, "MPT_s": None})
            d[k] = f
        out.append(d)
    return out, curves
