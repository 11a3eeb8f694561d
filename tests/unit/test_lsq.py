"""The one least-squares loop (tmscal.calib.lsq): minima known in closed form, a state on
SO(3) stepped by its exponential map, each stopping rule, and the caps."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from tmscal.calib.lsq import levenberg_marquardt
from tmscal.geometry import matrix_from_rotvec, rotvec_from_matrix


def _plus(x, dx):
    return x + dx


def test_linear_problem_lands_on_the_normal_equations_solution():
    rng = np.random.default_rng(0)
    # columns of very different scale (mm against rad): the column scaling must not matter
    A = rng.normal(size=(40, 4)) * np.array([1.0, 1e3, 1e-3, 10.0])
    b = rng.normal(size=40)
    sol = levenberg_marquardt(lambda x, jac: (A @ x - b, A if jac else None), np.zeros(4),
                              _plus, ftol=1e-15)
    ref = np.linalg.lstsq(A, b, rcond=None)[0]
    np.testing.assert_allclose(sol.state, ref, rtol=1e-8)
    assert sol.converged
    assert sol.cost == pytest.approx(float(np.sum((A @ ref - b) ** 2)), rel=1e-10)


def test_rosenbrock_from_a_far_start_agrees_with_scipy():
    def ev(x, jac):
        r = np.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])
        J = np.array([[-20.0 * x[0], 10.0], [-1.0, 0.0]])
        return r, (J if jac else None)

    sol = levenberg_marquardt(ev, np.array([-1.9, 2.5]), _plus, max_iter=500, ftol=0.0,
                              xtol=1e-14)
    ref = least_squares(lambda x: ev(x, False)[0], [-1.9, 2.5], xtol=1e-15, ftol=1e-15).x
    np.testing.assert_allclose(sol.state, ref, atol=1e-7)
    np.testing.assert_allclose(sol.state, [1.0, 1.0], atol=1e-7)


def test_rotation_fit_on_the_manifold_recovers_the_rotation():
    # the state is a 3×3 rotation, stepped on the left by exp: the Wahba problem, whose
    # answer the SVD gives in closed form
    rng = np.random.default_rng(3)
    R_true = matrix_from_rotvec([0.4, -1.2, 2.0])
    p = rng.normal(size=(30, 3)) * 100.0
    q = p @ R_true.T + rng.normal(scale=0.01, size=p.shape)

    def ev(R, jac):
        Rp = p @ R.T
        r = (Rp - q).ravel()
        if not jac:
            return r, None
        J = np.zeros((len(p), 3, 3))       # d(exp(ω) R p)/dω = −[R p]×
        J[:, 0, 1], J[:, 0, 2] = Rp[:, 2], -Rp[:, 1]
        J[:, 1, 0], J[:, 1, 2] = -Rp[:, 2], Rp[:, 0]
        J[:, 2, 0], J[:, 2, 1] = Rp[:, 1], -Rp[:, 0]
        return r, J.reshape(-1, 3)

    sol = levenberg_marquardt(ev, np.eye(3), lambda R, w: matrix_from_rotvec(w) @ R,
                              ftol=1e-14)
    U, _, Vt = np.linalg.svd(q.T @ p)
    R_ref = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    assert np.linalg.norm(rotvec_from_matrix(sol.state.T @ R_ref)) < 1e-9
    np.testing.assert_allclose(sol.state @ sol.state.T, np.eye(3), atol=1e-12)


def test_solved_stops_at_the_start_and_small_step_stops_early():
    ev = lambda x, jac: (x - 3.0, np.eye(2) if jac else None)  # noqa: E731
    sol = levenberg_marquardt(ev, np.array([3.0, 3.0]), _plus,
                              solved=lambda r: bool(np.all(np.abs(r) < 1e-3)))
    assert sol.iterations == 0 and sol.converged
    calls = []
    sol = levenberg_marquardt(ev, np.zeros(2), _plus, ftol=0.0,
                              small_step=lambda x, dx: calls.append(dx) or True)
    assert sol.iterations == 1 and sol.converged and len(calls) >= 1
    np.testing.assert_allclose(sol.state, [3.0, 3.0], atol=1e-5)


def test_caps_end_the_loop_unconverged():
    # a residual no step can lower (the Jacobian points the wrong way): no descent at any
    # damping; the state stays at the start and nothing claims convergence
    def ev(x, jac):
        return np.array([1.0 + abs(x[0])]), (np.array([[-1.0]]) if jac else None)

    sol = levenberg_marquardt(ev, np.array([0.0]), _plus)
    assert not sol.converged and sol.state[0] == 0.0 and sol.cost == 1.0
    # the evaluation cap bounds the work of a problem that keeps improving slowly
    n = []

    def slow(x, jac):
        n.append(1)
        return np.array([np.exp(-x[0])]), (np.array([[-np.exp(-x[0])]]) if jac else None)

    sol = levenberg_marquardt(slow, np.array([0.0]), _plus, max_iter=1000, ftol=0.0,
                              max_evaluations=25)
    assert not sol.converged and len(n) <= 25
    sol = levenberg_marquardt(slow, np.array([0.0]), _plus, max_iter=3, ftol=0.0)
    assert not sol.converged and sol.iterations == 3


def test_max_step_bounds_every_step():
    seen = []
    ev = lambda x, jac: (x - 100.0, np.eye(1) if jac else None)  # noqa: E731

    def step(x, dx):
        seen.append(float(abs(dx[0])))
        return x + dx

    sol = levenberg_marquardt(ev, np.zeros(1), step, max_iter=1000, max_step=0.3, ftol=0.0,
                              xtol=1e-12)
    assert max(seen) <= 0.3 + 1e-15
    assert sol.state[0] == pytest.approx(100.0, abs=1e-9)
