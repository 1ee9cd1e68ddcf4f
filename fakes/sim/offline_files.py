"""Offline data of the simulated cell for `station simulate arm|trailer`: measurements and their truth.

* :func:`simulate_arm` - a true arm (the library model plus drawn error effects:
  geometric only, or every effect of :func:`station.models.effects.realistic_effects`)
  measured at random poses in order by a tracker in a random frame
  (:func:`fakes.sim.diagnosis_data.simulate_arm_data`); the rows an arm CSV holds.
* :func:`simulate_trailer` - a trailer record with chosen effects hidden in it
  (:func:`fakes.sim.trailer_diagnosis_data.make_trailer_case`).

Each returns the data and a JSON-ready ``truth`` (what was drawn), so a person
or a test can hold the analysis against it.
"""

from __future__ import annotations

import numpy as np

from station.models.effects import EffectSet, realistic_effects
from station.models.robots import get_robot

ARM_EFFECTS = ("geometric", "realistic", "none")
TRAILER_EFFECTS = ("link_lengths", "hitch_angle_offset", "curvature_gain", "hitch_dynamics")


def simulate_arm(robot: str, *, n: int, effects: str, seed: int) -> tuple[dict, dict]:
    """``(columns of an arm CSV, truth)``: q1..q6 deg, x, y, z mm (tracker frame), t s, temperature degC, load kg."""
    if effects not in ARM_EFFECTS:
        raise ValueError(f"effects must be one of {', '.join(ARM_EFFECTS)}, got {effects!r}")
    spec = get_robot(robot)
    rng = np.random.default_rng(seed)
    drawn = realistic_effects(spec, rng)
    if effects == "geometric":
        eff = EffectSet.from_params({"geometric": drawn.get("geometric")})
    elif effects == "none":
        eff = EffectSet.none()
    else:
        eff = drawn
    from fakes.sim.diagnosis_data import simulate_arm_data

    d = simulate_arm_data(spec, eff, rng, n=n)
    cols = {"q_deg": np.degrees(d.q_rad), "xyz_mm": d.xyz_mm, "t": d.t_s, "temperature": d.temperature_c,
            "load": d.load_kg}
    truth = {"robot": spec.name, "seed": seed, "effects": effects, "n_poses": n,
             "effect_params": eff.to_dict(), "tracker_T_base": d.base_T.tolist(), "noise_mm": d.noise_mm,
             "stop_sigma_rad": np.asarray(d.stop_sigma_rad).tolist(),
             "true_points_mm": d.true_points(spec).tolist()}
    truth["figures"] = true_arm_figures(spec, d.q_rad, d.true_points(spec), d.xyz_mm)
    return cols, truth


def true_arm_figures(spec, q_rad, true_mm, measured_mm) -> dict:
    """The figures ``station calibrate arm`` prints on this file with its defaults (distance errors from the
    first pose, seed 002 eq. (11); the seed's tail split), stated on the noise-free points, and what the
    tracker's noise on this file's distances lets the printed ones differ from them by.

    ``train`` / ``test``: ``mean_abs_before_mm``, ``max_abs_before_mm`` (the library model),
    ``mean_abs_after_mm``, ``max_abs_after_mm`` (the model identified on the noise-free points: what the
    arm's errors leave that the model cannot take, 0 up to the stops' scatter for geometric errors) and
    ``n``. ``U``: per part ``mean_mm`` = 2 rms and ``max_mm`` = max + 2 rms of the noise on the file's
    distances (measured minus true). A before figure differs from its truth by at most the mean and the
    max of that noise (the triangle inequality); an after figure is refitted on the noisy points and over
    20 files of 30-150 poses (geometric and realistic errors, seeds 0-9) differed by at most 0.66 of ``U``.
    """
    from station.analysis.arm.calibration import calibrate_arm

    q = np.asarray(q_rad, dtype=float)
    true_mm, measured_mm = np.asarray(true_mm, dtype=float), np.asarray(measured_mm, dtype=float)
    cal = calibrate_arm(spec.dh_nominal, q, true_mm, joint_limits_rad=spec.joint_limits_rad)
    ref = cal.split.reference
    out = {"errors_are": "distances from the first pose (seed 002 eq. (11)), calibrate arm's default tail split",
           "U": {}}
    for part, stats, idx in (("train", cal.train, np.setdiff1d(cal.split.train, [ref])),
                             ("test", cal.test, cal.split.test)):
        if stats is None:
            continue
        j = stats.to_json()
        out[part] = {k: round(j[k], 6) for k in ("mean_abs_before_mm", "max_abs_before_mm", "mean_abs_after_mm",
                                                 "max_abs_after_mm")} | {"n": j["n"]}
        noise = (np.linalg.norm(measured_mm[idx] - measured_mm[ref], axis=1)
                 - np.linalg.norm(true_mm[idx] - true_mm[ref], axis=1))
        rms = float(np.sqrt(np.mean(noise ** 2)))
        out["U"][part] = {"mean_mm": round(2 * rms, 6), "max_mm": round(float(np.max(np.abs(noise))) + 2 * rms, 6)}
    return out


#: the record is simulated this many times finer than it is written; curvature and speed are then averaged over
#: each written interval, as odometry reports them (``calibrate trailer``'s default ``--sampling interval``)
OVERSAMPLE = 10
#: weights of the fine samples ``end - OVERSAMPLE .. end`` in a written interval's average: the trapezoid, the
#: exact average of the inputs the integrator drives the trailer with (linear between fine samples)
_INTERVAL_WEIGHTS = np.concatenate([[0.5], np.ones(OVERSAMPLE - 1), [0.5]]) / OVERSAMPLE


def simulate_trailer(*, hidden=(), seed: int, duration_s: float = 180.0, rate_hz: float = 20.0,
                     psi_sigma_rad: float | None = None) -> tuple[dict, dict]:
    """``(columns t, kappa, psi, v, truth)`` of a trailer record with the effects ``hidden`` drawn in it.

    The trailer follows the joint-angle dynamics of eq. (D) as an ideal trailer
    (relaxation over L2) unless ``hitch_dynamics`` is hidden (then its drawn
    relaxation length). ``kappa`` and ``v`` are averages over the interval
    ending at ``t``; ``psi`` the angle at ``t``.

    The truth states what ``diagnose trailer`` (a static baseline, eq. (23))
    should find beside the hidden effects: the ideal trailer's own
    relaxation over L2 (``baseline_dynamics``), or with ``hitch_dynamics``
    hidden the drawn relaxation; ``relaxation_m`` is the relaxation the
    diagnosis's interval should contain either way. ``psi_sigma_rad``: the
    joint-angle sensor's noise (default drawn, U(2, 5) mrad); a precise one
    leaves the curvature's noise dominant.
    """
    from fakes.sim.trailer_diagnosis_data import make_trailer_case

    bad = [h for h in hidden if h not in TRAILER_EFFECTS]
    if bad:
        raise ValueError(f"unknown trailer effect(s) {', '.join(bad)} (known: {', '.join(TRAILER_EFFECTS)})")
    rng = np.random.default_rng(seed)
    L2 = 2.48
    rec = make_trailer_case(list(hidden), rng, L2_m=L2, ideal=True, duration_s=duration_s,
                            rate_hz=rate_hz * OVERSAMPLE, psi_sigma=psi_sigma_rad)
    n = (rec["t"].size - 1) // OVERSAMPLE
    end = np.arange(1, n + 1) * OVERSAMPLE  # the fine sample at each written t
    blocks = end[:, None] - np.arange(OVERSAMPLE, -1, -1)[None, :]  # the fine samples spanning the interval
    cols = {"t": rec["t"][end], "kappa": rec["kappa"][blocks] @ _INTERVAL_WEIGHTS, "psi": rec["psi"][end],
            "v": rec["v"][blocks] @ _INTERVAL_WEIGHTS}
    ideal = "hitch_dynamics" not in hidden
    baseline = {"model": "the ideal trailer of eq. (D): the joint angle relaxes over L2",
                "relaxation_m": float(rec["truth"]["L2_m"]) if ideal else None,
                "diagnose_trailer": ("names hitch_dynamics with a relaxation consistent with L2 and says it is the "
                                     "ideal trailer's own (the static model of eq. (23) leaves it out): not an effect "
                                     "beyond the ideal trailer" if ideal else
                                     "names hitch_dynamics with the drawn relaxation (relaxation_m), unlike L2's")}
    truth = {"seed": seed, "hidden": list(hidden),
             **{k: float(v) for k, v in rec["truth"].items()},
             "relaxation_m": float(rec["truth"]["relaxation_m"]),
             # the curvature's interval averaging is modelled by the diagnosis: it fits the relaxation itself
             "expected_fitted_relaxation_m": float(rec["truth"]["relaxation_m"]),
             "baseline_dynamics": baseline,
             "psi_sigma_rad": float(rec["psi_sigma"]),
             "kappa_sigma_per_m": float(rec["kappa_sigma"]) * float(np.linalg.norm(_INTERVAL_WEIGHTS)),
             "duration_s": duration_s, "rate_hz": rate_hz,
             "sampling": "kappa and v: averages over the interval ending at t; psi: at t"}
    return cols, truth


def simulate_hold(*, seed: int, duration_s: float = 60.0, rate_hz: float = 100.0,
                  distance_mm: float = 2500.0, noise=None) -> tuple[dict, dict]:
    """``(columns t, x, y, z, truth)``: a robot holding one pose, measured by the tracker.

    The tool drifts along a random direction at U(0.005, 0.03) mm/min (the
    arm warming up); the tracker (:class:`fakes.sim.tracker.TrackerModel`,
    ``distance_mm`` away) reads it with its session's systematic error and its
    reading noise ``noise`` (a :class:`~station.models.tracker_noise.TrackerNoise`;
    default the measured Leica figures). ``truth["noise_mm"]``: the sd of one
    reading about the truth, white and wander together.
    """
    from fakes.sim.tracker import TrackerModel

    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    tracker = TrackerModel(np.eye(4), rate_hz=rate_hz, noise=noise, seed=int(rng.integers(0, 2**31 - 1)))
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    drift = float(rng.uniform(0.005, 0.03)) * direction  # mm/min
    p0 = rng.uniform(-1000.0, 1000.0, 3) + np.array([0.0, 0.0, distance_mm])
    xyz, _ = tracker.measure(t, lambda tt: p0 + np.outer(tt / 60.0, drift))
    truth = {"seed": seed, "position_mm": p0.tolist(), "drift_mm_per_min": drift.tolist(),
             "noise_mm": tracker.noise.total_um * 1e-3, "tracker_noise": tracker.noise.to_dict(),
             "reading_offset_mm": (tracker.reading(p0[None])[0] - p0).tolist(),
             "duration_s": duration_s, "rate_hz": rate_hz}
    return {"t": t, "xyz_mm": xyz}, truth
