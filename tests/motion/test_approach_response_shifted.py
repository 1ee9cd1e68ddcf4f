"""The shifted evaluation of the approach responses (one exp, cos and sin per call) against the direct one.

:func:`station.models.approach_response.decel_response` and
:func:`~station.models.approach_response.mode_response` evaluate the four edges
of the trapezoid from one set of transcendental functions at ``tau`` moved to
each edge by the angle-sum formulas; :func:`~station.models.approach_response._edges`
with :func:`~station.models.approach_response.ramp_response` (and the poles'
integrals) is the direct evaluation they replace. Both must agree to rounding
on random windows, profiles, loops and modes, underdamped and overdamped, with
and without a jerk time, NaN padding kept.
"""

from __future__ import annotations

import math

import numpy as np

from station.models import approach_response as ar


def _draw(rng):
    M, L = int(rng.integers(1, 6)), int(rng.integers(20, 400))
    tau = np.sort(rng.uniform(-1.5, 1.0, (M, L)), axis=1)
    tau[:, L - int(rng.integers(0, L // 4 + 1)):] = np.nan  # the windows' padding
    a = rng.uniform(200.0, 3000.0, (M, 1))
    v = rng.uniform(50.0, 1000.0, (M, 1))
    D = rng.uniform(10.0, 800.0, (M, 1))
    tj = 0.0 if rng.random() < 0.3 else float(rng.uniform(1e-3, 0.4))
    omega = 2.0 * math.pi * rng.uniform(0.3, 80.0)
    zeta = float(rng.uniform(0.03, 0.95) if rng.random() < 0.5 else rng.uniform(1.05, 4.0))
    mode = (2.0 * math.pi * rng.uniform(1.5, 80.0), float(rng.uniform(0.003, 0.6)))
    return tau, a, v, D, tj, omega, zeta, mode


def _direct_mode(tau, a, v, D, tj, loop, mode):
    p, R = ar._mode_poles(loop[0], loop[1], mode[0], mode[1])

    def ramp(x):
        if tj <= ar.STEP_TJ_S:
            return ar._pr_decay(x, p, R)
        return (ar._pr_integral(x + tj, p, R) - ar._pr_integral(x, p, R)) / tj

    return ar._edges(tau, a, v, D, tj, ramp)


def _close(new, old):
    assert new.shape == old.shape
    assert np.array_equal(np.isnan(new), np.isnan(old))
    scale = max(1.0, float(np.nanmax(np.abs(old))))
    assert float(np.nanmax(np.abs(new - old))) <= 1e-9 * scale


def test_shifted_servo_and_mode_equal_the_direct_evaluation(rng):
    used = 0
    for _ in range(60):  # loop over random windows and models
        tau, a, v, D, tj, omega, zeta, mode = _draw(rng)
        fast = ar._ShiftedEdges.of(tau, a, v, D, tj, ar._decay_rates(omega, zeta))
        used += fast is not None
        direct = ar._edges(tau, a, v, D, tj, lambda x: ar.ramp_response(x, omega, zeta, tj))
        _close(ar.decel_response(tau, a, v, D, tj, omega, zeta), direct)
        _close(ar.mode_response(tau, a, v, D, tj, (omega, zeta), mode),
               _direct_mode(tau, a, v, D, tj, (omega, zeta), mode))
    assert used > 0  # the shifted path ran (an overdamped fast pole may send a draw to the direct one)


def test_a_pole_too_fast_for_the_shift_falls_back_to_the_direct_evaluation(rng):
    tau, a, v, D, tj, _, _, _ = _draw(rng)
    omega, zeta = 2.0 * math.pi * 80.0, 4.0  # a decay rate of ~4000 / s over a move: exp would overflow
    assert ar._ShiftedEdges.of(tau, a, v, D, tj, ar._decay_rates(omega, zeta)) is None
    out = ar.decel_response(tau, a, v, D, tj, omega, zeta)
    assert np.all(np.isfinite(out[np.isfinite(tau)]))
    _close(out, ar._edges(tau, a, v, D, tj, lambda x: ar.ramp_response(x, omega, zeta, tj)))


def test_a_critically_damped_loop_drives_a_mode_without_a_double_pole(rng):
    """A loop at damping 1 (a start of the mode's scan) has a double pole, where the residues' closed form
    divides by zero: the response is finite there and lies between those of damping 1 -/+ 1e-3."""
    import warnings

    tau = np.linspace(-0.5, 1.0, 301)
    a, v, D, tj = rng.uniform(500, 2500), rng.uniform(200, 500), rng.uniform(100, 400), rng.uniform(0.0, 0.05)
    w, mode = 2 * math.pi * rng.uniform(6, 20), (2 * math.pi * rng.uniform(8, 12), rng.uniform(0.05, 0.1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        x = ar.mode_response(tau, a, v, D, tj, (w, 1.0), mode)
    lo, hi = (ar.mode_response(tau, a, v, D, tj, (w, z), mode) for z in (1.0 - 1e-3, 1.0 + 1e-3))
    assert np.all(np.isfinite(x))
    assert np.all(np.abs(x - 0.5 * (lo + hi)) <= np.abs(hi - lo) + 1e-9)
