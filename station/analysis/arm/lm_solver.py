"""The one least-squares solver of the arm's identification and diagnosis: damped Levenberg-Marquardt.

Both problems are ``min ||r(x)||^2`` over a parameter state with an analytic
Jacobian (seed 002 eq. (7)-(8) for the kinematic columns). The solver is
generic over the state: the caller gives ``evaluate(state) -> (r, J)`` and
``apply(state, step) -> state`` (rotations compose, lengths add); the
Jacobian may be given by its normal equations (:class:`Normal`), which is
all the solver uses of it. Each
iteration solves the column-scaled, damped normal equations (Marquardt's
scaling: ``(A + lambda diag(A)) s = g``), accepts a step only when it lowers
the cost, and shrinks ``lambda`` after a success and grows it after a
failure, so a step the linearisation overrates (a start millimetres away)
is shortened instead of taken (the undamped Gauss-Newton step from a
nominal model can throw an angle by hundreds of radians).

Convergence is a status, never an exception: ``converged`` is True when the
next full Gauss-Newton step would lower the cost by less than
``(step_tol_sigma)^2`` of the residual variance (the step is under that many
standard deviations of the parameters), or the relative cost change of an
accepted step falls under ``rtol``, or no damped step lowers the cost while
the full step is under ``10 step_tol_sigma`` standard deviations. The
iteration limit, or damping that finds no lower cost while a larger step is
predicted, is "not converged", with the reason in ``message``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

__all__ = ["LMResult", "Normal", "levenberg_marquardt"]


@dataclass(frozen=True)
class Normal:
    """A Jacobian ``J`` (m, n) at a state given by its normal equations: ``JtJ = J^T J`` (n, n) and
    ``Jtr = J^T r`` (n,), all the solver needs of it. A caller that sums them over blocks of rows never
    holds the whole ``J`` (the arm's absolute problem: 3,000 x 41 for 1,000 poses)."""

    JtJ: np.ndarray
    Jtr: np.ndarray


@dataclass
class LMResult:
    """Outcome of :func:`levenberg_marquardt`."""

    state: Any
    r: np.ndarray
    J: np.ndarray
    cost: float
    iterations: int
    converged: bool
    message: str
    rms_history: list = field(default_factory=list)   # sqrt(cost / m) per accepted state (first: the start)
    states: list = field(default_factory=list)        # accepted states (first: the start)


def _jac(J) -> np.ndarray:
    return J() if callable(J) else J


def levenberg_marquardt(evaluate: Callable, apply: Callable, state, *, free=None, max_iter: int = 100,
                        rtol: float = 1e-10, step_tol_sigma: float = 0.01, lam0: float = 1e-3,
                        keep_states: bool = False, start=None) -> LMResult:
    """Minimise ``||r||^2`` from ``state``.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(state) -> (r (m,), J (m, n))``; ``J = dr/dx`` with the sign of ``-d prediction``
        folded in by the caller so that the step solves ``J s = r`` (the measured minus the modelled).
        ``J`` may be a function of no arguments that returns it: it is then called only for a state the
        solver accepts (a rejected trial step costs the residual alone). ``J`` may also be given by its
        normal equations (:class:`Normal`); the result's ``J`` is then the final state's.
    apply : callable
        ``apply(state, step (n,)) -> state``.
    free : array_like of int, optional
        Columns of ``J`` that move (default all); the step of the others is 0.
    start : tuple, optional
        ``(r, J)`` at ``state`` when the caller has them (the end of a previous fit): not evaluated again.
    """
    r, J = evaluate(state) if start is None else start
    start = None   # the solver alone holds the Jacobian it replaces (its memory is let go with it)
    J = _jac(J)
    n = J.JtJ.shape[0] if isinstance(J, Normal) else J.shape[1]
    free = np.arange(n) if free is None else np.asarray(free, dtype=np.int64)
    m = r.size
    cost = float(r @ r)
    hist = [math.sqrt(cost / max(m, 1))]
    states = [state] if keep_states else []
    lam = lam0
    dof = max(m - free.size, 1)
    it = 0
    converged, message = False, f"not converged: iteration limit ({max_iter}) reached"
    if not math.isfinite(cost):
        return LMResult(state, r, J, cost, 0, False, "not converged: the start gives a non-finite residual", hist,
                        states)
    all_free = free.size == n and np.array_equal(free, np.arange(n))
    for it in range(1, max_iter + 1):
        # the scaled normal equations from one product of the free columns (no scaled copy of J)
        if isinstance(J, Normal):
            A = J.JtJ if all_free else J.JtJ[np.ix_(free, free)]
            A, g = A.copy(), J.Jtr[free]
        else:
            Jf = J if all_free else J[:, free]
            A = Jf.T @ Jf
            g = r @ Jf
            del Jf
        scale = np.sqrt(np.diag(A))
        scale[scale == 0] = 1.0
        A /= np.outer(scale, scale)
        g = g / scale
        try:
            gn = np.linalg.lstsq(A, g, rcond=1e-12)[0]
            decrease = float(g @ gn)
        except np.linalg.LinAlgError:
            decrease = math.inf
        if decrease <= step_tol_sigma ** 2 * cost / dof:
            converged = True
            message = f"converged: the next step is under {step_tol_sigma:g} standard deviations"
            it -= 1
            break
        accepted = False
        D = np.diag(np.maximum(np.diag(A), 1e-12))
        for _ in range(16):
            try:
                s = np.linalg.solve(A + lam * D, g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            full = np.zeros(n)
            full[free] = s / scale
            cand = apply(state, full)
            r_c, J_c = evaluate(cand)
            c_c = float(r_c @ r_c)
            if math.isfinite(c_c) and c_c < cost:
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            # no damped step lowers the cost: a minimum if the predicted gain is at the rounding level, or
            # if the full step is under a tenth of a standard deviation of the parameters (what is left is
            # below what the data resolve; the line search fails there when the gain is at the rounding of
            # the residuals, seen at 0.012 sigma on a FANUC-like pose set)
            if decrease <= max(1e-8 * max(cost, 1e-300), (10.0 * step_tol_sigma) ** 2 * cost / dof):
                converged = True
                message = ("converged: no step lowers the cost further (the next step is "
                           f"{math.sqrt(max(decrease, 0.0) * dof / max(cost, 1e-300)):.2g} standard deviations)")
            else:
                message = ("not converged: no damped step lowers the cost although the gradient is not zero "
                           f"(predicted decrease {decrease:.3g} mm^2 of {cost:.3g})")
            break
        rel = (cost - c_c) / max(cost, 1e-300)
        state, r, J, cost = cand, r_c, _jac(J_c), c_c
        J_c = None   # a lazy Jacobian holds its forward pass
        hist.append(math.sqrt(cost / max(m, 1)))
        if keep_states:
            states.append(state)
        lam = max(lam / 10.0, 1e-12)
        if rel < rtol:
            converged, message = True, f"converged: relative cost change {rel:.1e} < {rtol:g}"
            break
    return LMResult(state, r, J, cost, it, converged, message, hist, states)
