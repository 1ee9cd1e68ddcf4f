"""Trailer records with chosen effects switched on, for the trailer diagnosis.

The front unit drives at a slowly varying speed along a smooth random
curvature (a few sinusoids inside the joint-angle limit); the joint angle
follows eq. (D) of :mod:`station.models.trailer` with its rate scaled so that
it relaxes over ``relaxation_m`` (``L2`` is the ideal trailer of (D); 0 is a
trailer that sits at the steady state of eq. (23) at every instant, the
patent's static world), integrated by RK4 with the curvature interpolated
linearly between samples. The sensors add Gaussian noise, a joint-angle zero
offset and a curvature scale error. An independent integrator from the
diagnosis's own (which uses an exponential step).

Units: m, rad, 1/m, s, m/s.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["simulate_trailer_record", "make_trailer_case"]


def _curvature(t: np.ndarray, rng: np.random.Generator, peak: float) -> np.ndarray:
    w = rng.uniform(0.03, 0.2, 3)
    ph = rng.uniform(0, 2 * np.pi, 3)
    a = rng.uniform(0.3, 1.0, 3)
    k = sum(ai * np.sin(wi * t + pi) for ai, wi, pi in zip(a, w, ph))
    return peak * k / np.max(np.abs(k))


def _integrate(t, kappa, v, L1, L2, ell, substeps: int = 4) -> np.ndarray:
    r = np.sqrt(1.0 + (kappa * L1) ** 2)
    psi0 = float(np.arctan(kappa[0] * L1) + np.arcsin(kappa[0] * L2 / r[0]))
    out = np.empty(t.size)
    out[0] = p = psi0
    kl, vl, tl = kappa.tolist(), v.tolist(), t.tolist()

    def f(p_, k_, v_):
        return v_ / ell * (k_ * (L2 + L1 * math.cos(p_)) - math.sin(p_))

    for i in range(1, t.size):  # sequential in time
        h = (tl[i] - tl[i - 1]) / substeps
        for j in range(substeps):
            a0, am, a1 = j / substeps, (j + 0.5) / substeps, (j + 1) / substeps
            ka, kb, kc = (kl[i - 1] + s * (kl[i] - kl[i - 1]) for s in (a0, am, a1))
            va, vb, vc = (vl[i - 1] + s * (vl[i] - vl[i - 1]) for s in (a0, am, a1))
            f1 = f(p, ka, va)
            f2 = f(p + 0.5 * h * f1, kb, vb)
            f3 = f(p + 0.5 * h * f2, kb, vb)
            f4 = f(p + h * f3, kc, vc)
            p += h / 6.0 * (f1 + 2 * f2 + 2 * f3 + f4)
        out[i] = p
    return out


def simulate_trailer_record(rng: np.random.Generator, *, L1_m: float = 1.25, L2_m: float = 2.48,
                            offset_rad: float = 0.0, gain: float = 1.0, relaxation_m: float = 0.0,
                            duration_s: float = 180.0, rate_hz: float = 20.0, v_m_s: float | None = None,
                            psi_sigma: float | None = None, kappa_sigma: float | None = None,
                            peak_kappa: float = 0.18) -> dict:
    """A record ``t, kappa, psi, v`` of the true trailer, plus ``psi_true`` and ``kappa_true``.

    ``gain``: the path curvature is ``gain`` x the measured one (the
    diagnosis's ``curvature_gain``); ``offset_rad`` adds to the measured
    joint angle. Noise defaults: joint angle U(2, 5) mrad, curvature
    U(0.001, 0.002) 1/m (an encoder on the hitch,
    odometry averaged over 1/20 s).
    """
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    k_true = _curvature(t, rng, peak_kappa)
    v0 = float(rng.uniform(0.8, 1.5)) if v_m_s is None else float(v_m_s)
    v = v0 * (1.0 + 0.1 * np.sin(rng.uniform(0.01, 0.05) * t + rng.uniform(0, 2 * np.pi)))
    if relaxation_m > 0:
        psi_true = _integrate(t, k_true, v, L1_m, L2_m, float(relaxation_m))
    else:
        r = np.sqrt(1.0 + (k_true * L1_m) ** 2)
        psi_true = np.arctan(k_true * L1_m) + np.arcsin(k_true * L2_m / r)
    sp = float(rng.uniform(0.002, 0.005)) if psi_sigma is None else float(psi_sigma)
    sk = float(rng.uniform(0.001, 0.002)) if kappa_sigma is None else float(kappa_sigma)
    kappa = k_true / gain + rng.normal(0.0, sk, n)
    psi = psi_true + offset_rad + rng.normal(0.0, sp, n)
    return {"t": t, "kappa": kappa, "psi": psi, "v": v, "kappa_true": k_true, "psi_true": psi_true,
            "psi_sigma": sp, "kappa_sigma": sk}


#: a unit size of each effect the diagnosis names (scaled to the drawn strength)
_UNITS = {"link_lengths": 0.01, "hitch_angle_offset": 1e-3, "curvature_gain": 1e-3, "hitch_dynamics": 0.01}


def _effect_kwargs(effect: str, size: float, direction: float, L1: float, L2: float) -> dict:
    if effect == "link_lengths":
        return {"L1_m": L1 + size * math.cos(direction), "L2_m": L2 + size * math.sin(direction)}
    if effect == "hitch_angle_offset":
        return {"offset_rad": size}
    if effect == "curvature_gain":
        return {"gain": 1.0 + size}
    return {"relaxation_m": size}


def make_trailer_case(hidden, rng: np.random.Generator, *, strength=(0.2, 0.35), L1_m: float = 1.25,
                      L2_m: float = 2.48, ideal: bool = False, **record_kw) -> dict:
    """A record with the effects ``hidden`` (names of the diagnosis's candidates) switched on.

    Each effect's own change of the joint angle has an RMS of ``U(strength)``
    times the RMS of the noise the static model sees (joint-angle noise plus
    the curvature noise through eq. (23)); a link-length error points in a
    random direction of (L1, L2) (not along L1 = -L2, which eq. (23) hardly
    sees), an offset or gain error has a random sign. ``ideal``: the trailer
    relaxes over its own (true) ``L2`` as the ideal trailer of eq. (D) does,
    unless ``hitch_dynamics`` is hidden. Returns the record of
    :func:`simulate_trailer_record` plus ``truth`` (its keyword arguments)
    and ``noise_rms``.
    """
    seed = int(rng.integers(2 ** 32))
    if ideal and "hitch_dynamics" not in hidden:
        record_kw = dict(record_kw, relaxation_m=L2_m)
    probe = simulate_trailer_record(np.random.default_rng(seed), L1_m=L1_m, L2_m=L2_m, **record_kw)
    k = probe["kappa_true"]
    r = np.sqrt(1.0 + (k * L1_m) ** 2)
    psi = np.arctan(k * L1_m) + np.arcsin(k * L2_m / r)
    slope = (L2_m + L1_m * np.cos(psi)) / (r * np.cos(psi - np.arctan(k * L1_m)))
    noise_rms = math.sqrt(probe["psi_sigma"] ** 2 + float(np.mean(slope ** 2)) * probe["kappa_sigma"] ** 2)
    quiet = dict(record_kw, psi_sigma=0.0, kappa_sigma=0.0)

    def static_residual(rec):  # what the station's static model leaves, noise-free
        kk = rec["kappa"]
        rr = np.sqrt(1.0 + (kk * L1_m) ** 2)
        return rec["psi"] - np.arctan(kk * L1_m) - np.arcsin(np.clip(kk * L2_m / rr, -1.0, 1.0))

    base = static_residual(simulate_trailer_record(np.random.default_rng(seed), L1_m=L1_m, L2_m=L2_m, **quiet))
    truth: dict = {"L1_m": L1_m, "L2_m": L2_m}
    for effect in hidden:
        direction = float(rng.uniform(-math.pi / 6, 2 * math.pi / 3))
        sign = 1.0 if effect in ("link_lengths", "hitch_dynamics") else float(rng.choice([-1.0, 1.0]))
        unit = _UNITS[effect] * sign
        kw = _effect_kwargs(effect, unit, direction, L1_m, L2_m)
        args = dict(quiet, L1_m=L1_m, L2_m=L2_m)
        args.update(kw)
        if ideal and "hitch_dynamics" not in hidden:
            args["relaxation_m"] = args["L2_m"]
        moved = static_residual(simulate_trailer_record(np.random.default_rng(seed), **args))
        eff_rms = math.sqrt(float(np.mean((moved - base) ** 2)))
        size = unit * rng.uniform(*strength) * noise_rms / eff_rms
        truth.update(_effect_kwargs(effect, size, direction, L1_m, L2_m))
    rec_kw = dict(record_kw)
    rec_kw.update(truth)
    if ideal and "hitch_dynamics" not in hidden:
        rec_kw["relaxation_m"] = truth["relaxation_m"] = truth["L2_m"]
    rec = simulate_trailer_record(np.random.default_rng(seed), **rec_kw)
    rec["truth"] = truth
    rec["noise_rms"] = noise_rms
    return rec
