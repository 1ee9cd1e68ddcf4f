"""The arm's least-squares solver (station.analysis.arm.lm_solver): when no damped step lowers the cost."""

from __future__ import annotations

import numpy as np

from station.analysis.arm.lm_solver import Normal, levenberg_marquardt


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


def test_a_lazy_jacobian_is_computed_only_for_accepted_states_and_changes_nothing(rng):
    """A sine fit from a start that overshoots (rejected trial steps): the Jacobian given as a function is called
    once per accepted state and never for a rejected one, the path is the eager one's, and a given start is not
    evaluated again."""
    t = np.linspace(0.0, 3.0, int(rng.integers(20, 60)))
    truth = np.array([rng.uniform(1, 3), rng.uniform(0.5, 2.0)])
    y = truth[0] * np.sin(truth[1] * t) + rng.normal(0, 0.01, t.size)
    calls = {"r": 0, "J": 0}

    def residual(x):
        return y - x[0] * np.sin(x[1] * t)

    def jac(x):
        return np.column_stack([np.sin(x[1] * t), x[0] * t * np.cos(x[1] * t)])   # J s = r: -dr/dx

    def eager(x):
        return residual(x), jac(x)

    def lazy(x):
        calls["r"] += 1

        def J():
            calls["J"] += 1
            return jac(x)

        return residual(x), J

    start = np.array([0.2 * truth[0], 0.7 * truth[1]])
    a = levenberg_marquardt(eager, lambda x, s: x + s, start, keep_states=True)
    b = levenberg_marquardt(lazy, lambda x, s: x + s, start, keep_states=True)
    assert a.converged and b.converged
    assert np.array_equal(a.state, b.state) and a.iterations == b.iterations and np.array_equal(a.J, b.J)
    assert calls["J"] == len(b.states) and calls["r"] > calls["J"]  # rejected trials cost the residual only
    calls["r"] = calls["J"] = 0
    c = levenberg_marquardt(lazy, lambda x, s: x + s, b.state, start=(b.r, b.J), keep_states=True)
    assert calls["J"] == len(c.states) - 1   # the start's Jacobian was given
    assert c.converged and np.allclose(c.state, b.state, rtol=1e-6)


def test_a_jacobian_given_by_its_normal_equations_takes_the_same_path(rng):
    """The solver needs only ``J^T J`` and ``J^T r`` of a state (the arm's absolute problem sums them over blocks
    of poses): given so, from a start far off and with a column held, the fit takes the same steps as with
    ``J`` itself, to rounding."""
    t = np.linspace(0.0, 3.0, int(rng.integers(20, 60)))
    truth = np.array([rng.uniform(1, 3), rng.uniform(0.5, 2.0), rng.uniform(-0.5, 0.5)])
    y = truth[0] * np.sin(truth[1] * t) + truth[2] + rng.normal(0, 0.01, t.size)

    def eager(x):
        return y - x[0] * np.sin(x[1] * t) - x[2], np.column_stack([np.sin(x[1] * t), x[0] * t * np.cos(x[1] * t),
                                                                     np.ones_like(t)])

    def normal(x):
        r, J = eager(x)
        return r, Normal(J.T @ J, J.T @ r)

    start = np.array([0.2 * truth[0], 0.7 * truth[1], 0.0])
    for free in (None, np.array([0, 1])):
        a = levenberg_marquardt(eager, lambda x, s: x + s, start, free=free, keep_states=True)
        b = levenberg_marquardt(normal, lambda x, s: x + s, start, free=free, keep_states=True)
        assert a.converged and b.converged and a.iterations == b.iterations >= 3
        np.testing.assert_allclose(np.array(b.states), np.array(a.states), rtol=1e-9, atol=1e-12)
        assert isinstance(b.J, Normal) and np.allclose(b.J.JtJ, a.J.T @ a.J, rtol=1e-12)
