"""The extended motion model (``station diagnose motion --model-out``): checked on read, applied to a simulation.

A model file is JSON::

    {"kind": "station motion model", "version": 1,
     "servo": {"frequency_hz": F, "damping": Z, "jerk_time_s": TJ},
     "deceleration_mm_s2": A,
     "effects": {"creep": {"amplitude_mm": .., "tau_s": ..},
                 "structural_mode": {"frequency_hz": .., "damping": .., "gain_s2": ..},
                 "tracker_drift": {"shrinkage": .., "rate_sd_mm_per_s": .., "level_sd_mm": ..}},
     ...}

Every number is range-checked like an arm's model file
(:mod:`station.models.arm_ranges`): a value no arm has is a unit or export
error and is refused naming the key. :func:`approach_offsets_mm` adds the
named effects to a simulated stream along each move's travel, with the closed
forms the diagnosis fitted (:mod:`station.models.approach_response`); the
loop itself (frequency, damping) is the simulated arm's servo and
:func:`servo_of` gives it. Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from station.errors import ConfigError
from station.models import approach_response as ar
from station.numeric import short_repr

__all__ = ["MotionModel", "check_motion_model", "approach_offsets_mm", "servo_of", "KIND"]

KIND = "station motion model"
#: (lowest, highest, unit) of every number a motion model holds
LIMITS = {
    ("servo", "frequency_hz"): (0.1, 200.0, "Hz"),
    ("servo", "damping"): (0.01, 10.0, ""),
    ("servo", "jerk_time_s"): (0.0, 2.0, "s"),
    ("deceleration_mm_s2",): (1e-3, 1e6, "mm/s^2"),
    ("creep", "amplitude_mm"): (-5.0, 5.0, "mm"),
    ("creep", "tau_s"): (1e-3, 60.0, "s"),
    ("structural_mode", "frequency_hz"): (0.5, 500.0, "Hz"),
    ("structural_mode", "damping"): (1e-4, 1.0, ""),
    ("structural_mode", "gain_s2"): (-0.1, 0.1, "s^2"),
    ("tracker_drift", "shrinkage"): (0.0, 10.0, ""),
    ("tracker_drift", "rate_sd_mm_per_s"): (0.0, 10.0, "mm/s"),
    ("tracker_drift", "level_sd_mm"): (0.0, 1.0, "mm"),
}
EFFECT_KEYS = {"creep": ("amplitude_mm", "tau_s"), "structural_mode": ("frequency_hz", "damping", "gain_s2"),
               "tracker_drift": ("shrinkage", "rate_sd_mm_per_s", "level_sd_mm")}
#: periods of the simulated reading's drift, s: their spread always, their scale only for a model without
#: ``level_sd_mm`` (written before it was measured), where the rate alone sizes the drift
DRIFT_PERIODS_S = (10.0, 40.0)


@dataclass(frozen=True)
class MotionModel:
    servo_hz: float
    servo_zeta: float
    jerk_time_s: float
    deceleration_mm_s2: float
    effects: dict = field(default_factory=dict)


def _number(v, where: str, key: tuple) -> float:
    lo, hi, unit = LIMITS[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise ConfigError(f"{where} must be a finite number, got {short_repr(v)}")
    if not lo <= float(v) <= hi:
        raise ConfigError(f"{where} = {short_repr(v)} {unit} is beyond what an arm has ({lo:g} to {hi:g} {unit}; "
                          "units? export error?)")
    return float(v)


def check_motion_model(doc, source: str = "the motion model") -> MotionModel:
    """The model of a parsed file, every number range-checked; ConfigError naming the key."""
    if not isinstance(doc, dict) or doc.get("kind") != KIND:
        raise ConfigError(f"{source}: not a motion model (its 'kind' must be {KIND!r}; written by "
                          "station diagnose motion --model-out)")
    servo = doc.get("servo")
    if not isinstance(servo, dict):
        raise ConfigError(f"{source}: 'servo' must be a table of frequency_hz, damping, jerk_time_s")
    s = [_number(servo.get(k), f"{source}: servo.{k}", ("servo", k)) for k in ("frequency_hz", "damping",
                                                                            "jerk_time_s")]
    dec = _number(doc.get("deceleration_mm_s2"), f"{source}: deceleration_mm_s2", ("deceleration_mm_s2",))
    eff = doc.get("effects", {})
    if not isinstance(eff, dict):
        raise ConfigError(f"{source}: 'effects' must be a table")
    unknown = sorted(set(eff) - set(EFFECT_KEYS))
    if unknown:
        raise ConfigError(f"{source}: unknown effect(s) {', '.join(repr(u)[:40] for u in unknown[:3])}; "
                          f"known: {', '.join(EFFECT_KEYS)}")
    out = {}
    for name, params in eff.items():
        if not isinstance(params, dict):
            raise ConfigError(f"{source}: effects.{name} must be a table")
        out[name] = {k: _number(params.get(k), f"{source}: effects.{name}.{k}", (name, k))
                     for k in EFFECT_KEYS[name] if k in params or name != "tracker_drift"}
    return MotionModel(*s, dec, out)


def servo_of(model: MotionModel) -> tuple[float, float]:
    """``(omega rad/s, zeta)`` of the model's position loop, for the simulated arm's axes."""
    return 2.0 * math.pi * model.servo_hz, model.servo_zeta


def _trapezoid_speed(T: float, D: float, a: float) -> float:
    """The peak speed of a trapezoid of length ``D`` lasting ``T`` at acceleration ``a`` (a triangle when short)."""
    disc = T * T - 4.0 * D / a
    if disc <= 0.0:
        return math.sqrt(a * D)
    return 0.5 * a * (T - math.sqrt(disc))


def approach_offsets_mm(t_s, moves, model: MotionModel, seed: int = 0) -> np.ndarray:
    """Offsets (N, 3) mm of the measured position at times ``t_s`` from the model's effects.

    ``moves``: dicts with ``t_start_s``, ``t_end_s`` (the command's start and end), ``from_mm`` and
    ``to_mm`` (3,) in the frame of the offsets. Along each move's travel: the creep (short while it moves,
    creeping in after the end) and the structural mode (driven by the loop's acceleration of a trapezoid at
    the model's deceleration). The tracker's drift: :func:`_drift_mm`.
    """
    t = np.asarray(t_s, dtype=float)
    out = np.zeros((t.size, 3))
    eff = model.effects
    a = model.deceleration_mm_s2
    loop = servo_of(model)
    for m in moves:
        d = np.asarray(m["to_mm"], dtype=float) - np.asarray(m["from_mm"], dtype=float)
        D = float(np.linalg.norm(d))
        if D <= 0.0:
            continue
        u = d / D
        tau = t - float(m["t_end_s"])
        along = np.zeros(t.size)
        if "creep" in eff:
            along += np.where(t >= float(m["t_start_s"]), ar.creep(tau, eff["creep"]["amplitude_mm"],
                                                                   eff["creep"]["tau_s"]), 0.0)
        if "structural_mode" in eff:
            sm = eff["structural_mode"]
            v = _trapezoid_speed(float(m["t_end_s"]) - float(m["t_start_s"]), D, a)
            along += sm["gain_s2"] * a * ar.mode_response(tau, a, v, D, model.jerk_time_s, loop,
                                                          (2.0 * math.pi * sm["frequency_hz"], sm["damping"]))
        out += along[:, None] * u
    if "tracker_drift" in eff:
        out += _drift_mm(t, eff["tracker_drift"], seed)
    return out


def _drift_mm(t: np.ndarray, drift: dict, seed: int) -> np.ndarray:
    """The reading's drift (N, 3) mm: three sinusoids per axis, phases and relative periods seeded by ``seed``.

    Its size per axis is the model's ``level_sd_mm`` (what consecutive rests of the measured stream shared:
    :func:`station.analysis.motion.diagnose.drift_level_sd`) and its periods are scaled so that its rate's
    standard deviation is the model's ``rate_sd_mm_per_s``: a drift of the measured size and time scale. The
    simulated tracker's own wander is not in it (a wander that decorrelates between rests is not shared), so
    it is counted once. A model without ``level_sd_mm`` (older files) keeps the periods
    :data:`DRIFT_PERIODS_S` and the rate alone sizes the drift.
    """
    out = np.zeros((t.size, 3))
    rate = float(drift.get("rate_sd_mm_per_s", 0.0))
    level = drift.get("level_sd_mm")
    if (rate <= 0.0 and level is None) or (level is not None and level <= 0.0):
        return out
    rng = np.random.default_rng(seed)
    per = rng.uniform(*DRIFT_PERIODS_S, (3, 3))
    ph = rng.uniform(0.0, 2.0 * math.pi, (3, 3))
    w = 2.0 * math.pi / per
    # three sinusoids of amplitude A per axis: position variance 3 A^2 / 2, rate variance A^2 sum(w^2) / 2
    if level is None:
        amp = rate * math.sqrt(2.0 / 3.0) / w
    else:
        amp = np.full(w.shape, float(level) * math.sqrt(2.0 / 3.0))
        w = w * (rate / float(level)) / np.sqrt(np.mean(w * w, axis=1, keepdims=True))
    for j in range(3):
        out[:, j] = np.sum(amp[j][:, None] * np.sin(w[j][:, None] * t[None, :] + ph[j][:, None]), axis=0)
    return out
