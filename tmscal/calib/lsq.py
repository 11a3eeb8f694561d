"""The one least-squares loop of tmscal: damped Gauss–Newton (Levenberg–Marquardt) over a
residual-and-Jacobian callback, with the step applied by the caller (so a state on a manifold,
X ∈ SE(3) or an arm with its deviations, steps by its own exponential map). Pure numerics,
no I/O.

Used by the maximum-likelihood solve (:mod:`tmscal.calib.ml`), the kinematic estimate
(:mod:`tmscal.calib.kinematics.estimate`), the force-sensor identification
(:mod:`tmscal.calib.selfcal.identify`) and the inverse kinematics
(:mod:`tmscal.calib.kinematics.ik`); docs/architecture.md.

One iteration (Marquardt 1963; Hollerbach and Wampler 1996 for the column scaling):

* the Jacobian J (m, k) at the current state, its columns scaled to unit norm (d_j = ‖J_:,j‖;
  a zero column keeps d_j = 1), so that parameters in mm, rad, N and N·m weigh alike and the
  damping λ·I of the scaled problem is Marquardt's λ·diag(JᵀJ) of the unscaled one;
* JₛᵀJₛ = V diag(w) Vᵀ factorised once, so that each damping tried is a product, not a solve:
  Δ = −V (Vᵀ Jₛᵀ r / (w + λ)) / d;
* the step is taken when it does not raise the cost rᵀr (λ divided by ``lam_down`` after it,
  to ``LAM_MIN`` at least); otherwise λ × 10 until it does or λ passes ``lam_max`` (then the
  loop stops at the last accepted state: no descent at any damping).

Stopping rules (any of them ends the loop with ``converged`` True): the cost fell by no more than
``ftol`` of itself; the scaled step ‖Δ·d‖ is below ``xtol``; the caller's ``small_step(state,
Δ)``; the caller's ``solved(r)`` on the residuals (checked at the start too). The rows are
whitened by the caller: the cost is the plain sum of squares of what ``evaluate`` returns.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

__all__ = ["Solution", "levenberg_marquardt", "LAM_MIN"]

S = TypeVar("S")

#: the smallest damping after a run of accepted steps
LAM_MIN = 1e-12
#: the factor by which a refused step raises the damping
_LAM_UP = 10.0


@dataclass
class Solution(Generic[S]):
    """The state at the minimum, the residuals r (m,) and Jacobian J (m, k) there (J None when
    the loop stopped before evaluating it), the cost rᵀr, the iterations (Jacobians
    evaluated) and whether a stopping rule fired (False: the iteration cap, or no descent at
    any damping)."""

    state: S
    residuals: np.ndarray
    jacobian: np.ndarray | None
    cost: float
    iterations: int
    converged: bool


def levenberg_marquardt(
        evaluate: Callable[[S, bool], tuple[np.ndarray, np.ndarray | None]],
        state: S,
        step: Callable[[S, np.ndarray], S],
        *,
        max_iter: int = 50,
        lam0: float = 1e-6,
        lam_max: float = 1e8,
        lam_down: float = 10.0,
        ftol: float = 1e-12,
        xtol: float = 0.0,
        max_step: float | None = None,
        max_evaluations: int | None = None,
        small_step: Callable[[S, np.ndarray], bool] | None = None,
        solved: Callable[[np.ndarray], bool] | None = None,
        on_iteration: Callable[[int, float], None] | None = None,
) -> Solution[S]:
    """Minimise ‖r(state)‖² from ``state``.

    ``evaluate(state, jac)`` returns (r (m,), J (m, k) or None when ``jac`` is False): the
    whitened residuals and their derivative with respect to the k step coordinates at
    ``state``. ``step(state, Δ)`` returns the state moved by Δ (k,) (in the callers' units: mm,
    rad, …; on a manifold, its exponential map). ``max_step`` caps the largest |Δ_j| (the step
    is shrunk as a whole). See the module docstring for the iteration and the stopping rules;
    ``max_iter`` counts Jacobians, ``max_evaluations`` (None: no cap) every call of
    ``evaluate``, trials included (a cap on the cost of a problem that does not converge).
    ``on_iteration(it, cost)``, when given, is called after each accepted step with the
    iteration's number (from 1) and the cost rᵀr it reached (a progress report; it does not
    steer the loop)."""
    cap = np.inf if max_evaluations is None else max_evaluations
    r, J = evaluate(state, True)
    evals = 1
    cost = float(r @ r)
    if solved is not None and solved(r):
        return Solution(state, r, J, cost, 0, True)
    lam = lam0
    for it in range(1, max_iter + 1):
        assert J is not None
        d = np.linalg.norm(J, axis=0)
        d[d == 0] = 1.0
        Js = J / d
        w, V = np.linalg.eigh(Js.T @ Js)
        gV = V.T @ (Js.T @ r)
        while True:
            dx = -(V @ (gV / (w + lam))) / d
            if max_step is not None:
                big = float(np.abs(dx).max(initial=0.0))
                if big > max_step:
                    dx *= max_step / big
            cand = step(state, dx)
            r_new, _ = evaluate(cand, False)
            evals += 1
            c_new = float(r_new @ r_new)
            if c_new <= cost or lam > lam_max or evals >= cap:
                break
            lam *= _LAM_UP
        if not c_new <= cost:                       # no descent at any damping (or NaN)
            done = small_step is not None and small_step(state, dx)
            return Solution(state, r, J, cost, it, bool(done))
        done = (cost - c_new <= ftol * cost + 1e-30
                or float(np.linalg.norm(dx * d)) < xtol
                or (small_step is not None and small_step(state, dx)))
        state, cost, lam = cand, c_new, max(lam / lam_down, LAM_MIN)
        if on_iteration is not None:
            on_iteration(it, cost)
        r, J = evaluate(state, True)
        evals += 1
        if evals >= cap and not (done or (solved is not None and solved(r))):
            return Solution(state, r, J, cost, it, False)
        if done or (solved is not None and solved(r)):
            return Solution(state, r, J, cost, it, True)
    return Solution(state, r, J, cost, max_iter, False)
