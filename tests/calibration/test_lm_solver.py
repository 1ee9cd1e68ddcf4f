"""The arm's least-squares solver (station.analysis.arm.lm_solver): when no damped step lowers the cost."""

from __future__ import annotations

import numpy as np

from station.analysis.arm.lm_solver import levenberg_marquardt


def _plateau(rng, step_sigma: float):
    """A cost no step can lower (every other state costs more), with a Jacobian that predicts a full step
    of ``step_sigma`` standard deviations: the line search fails, as it does where the predicted gain is at
    the rounding of the residuals or the Jacobian is off by a little."""
    m, n = int(rng.integers(30, 200)), int(rng.integers(1, 8))
    J = rng.normal(size=(m, n)) * rng.uniform(1.0, 100.0, n)
    e = rng.normal(0.0, 0.05, m)
    e -= J @ np.linalg.lstsq(J, e, rcond=None)[0]  # the part no step can explain
    cost_e = float(e @ e)
    dof = m - n
    # J c with |J c|^2 = step_sigma^2 (cost / dof), cost = |e|^2 + |J c|^2
    gain = step_sigma ** 2 * cost_e / dof / (1.0 - step_sigma ** 2 / dof)
    c = rng.normal(size=n)
    c *= np.sqrt(gain) / np.linalg.norm(J @ c)
    r0 = e + J @ c
    start = np.zeros(n)

    def evaluate(x):
        return (r0 if np.array_equal(x, start) else r0 * 1.001), J

    return evaluate, (lambda x, s: x + s), start


def test_no_lower_cost_within_a_tenth_of_a_sigma_is_converged_and_beyond_it_is_not(rng):
    evaluate, apply, start = _plateau(rng, float(rng.uniform(0.011, 0.09)))
    out = levenberg_marquardt(evaluate, apply, start, step_tol_sigma=0.01)
    assert out.converged and "no step lowers the cost further" in out.message, out.message
    assert out.iterations == 1 and np.array_equal(out.state, start)
    evaluate, apply, start = _plateau(rng, float(rng.uniform(0.11, 2.0)))
    out = levenberg_marquardt(evaluate, apply, start, step_tol_sigma=0.01)
    assert not out.converged and "no damped step lowers the cost" in out.message, out.message
