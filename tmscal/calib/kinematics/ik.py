"""Inverse kinematics of an :class:`~tmscal.calib.kinematics.model.Arm`: the joints at which
it puts its flange at a wanted pose (base_from_flange, 4×4 mm, the robot's own base frame;
``arm.base`` not applied; joints rad), by damped least squares (Levenberg–Marquardt,
:mod:`tmscal.calib.lsq`) on the joint Jacobian. Pure numerics, no I/O. The one
inverse kinematics of tmscal: the mock and simulated robots' controllers
(:func:`tmscal.sim.arm.inverse`) solve with it too, and :func:`inverse_of` serves an arm
given only by its forward kinematics (the mock Franka's URDF model).

A controller keeps the arm's configuration on a linear move, so the solution sought is the one
nearest the seed (the joints the arm has, or those of the calibration's poses); seeds further
away are tried only when the nearest does not converge.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ...geometry import rotvec_from_matrix
from ..lsq import levenberg_marquardt
from .model import Arm, base_from_flange

__all__ = ["inverse", "inverse_of", "Forward", "IK_TOL_MM", "IK_TOL_RAD"]

#: converged when the flange is this close to the target (mm, rad): far below any
#: calibration's accuracy, and reachable in double precision on a metre-sized arm
IK_TOL_MM = 1e-6
IK_TOL_RAD = 1e-9
#: the largest joint step of one iteration (rad): stays on the seed's branch
_MAX_STEP_RAD = 0.3
#: rotation errors (rad) weighed as mm × this length in the damped step
_ROT_WEIGHT_MM = 100.0
#: the joint step (rad) of the Jacobian's central differences
_H_RAD = 1e-6


#: a batched forward kinematics: joints (m, n) rad → base_from_flange (m, 4, 4) mm
Forward = Callable[[np.ndarray], np.ndarray]


def _error(forward: Forward, q: np.ndarray, target: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """(e, J): the body-frame error twist from A(q) to ``target`` [rotation vector rad;
    translation mm] and the joint Jacobian (6, n) of the flange's body twist, by central
    differences of ``_H_RAD`` on one batched forward kinematics (2n + 1 configurations: about
    ten times faster than the analytic deviation twists, and the mock robots solve this on
    every move)."""
    n = len(q)
    Q = np.concatenate([q[None], q + _H_RAD * np.eye(n), q - _H_RAD * np.eye(n)])
    T = forward(Q)
    A_inv = np.linalg.inv(T[0])
    D = A_inv @ np.concatenate([target[None], T[1:]])
    # through the quaternion: exact near 0 and right near π, where the skew part of R
    # vanishes (a seed turned half a turn from the target would otherwise look converged)
    xi = np.concatenate([rotvec_from_matrix(D[:, :3, :3]), D[:, :3, 3]], axis=1)
    J = (xi[1:n + 1] - xi[n + 1:]).T / (2.0 * _H_RAD)
    return xi[0], J


def inverse(chain: Arm, target: np.ndarray, seeds: list[np.ndarray],
            limits_rad: np.ndarray | None = None, max_iter: int = 200) -> np.ndarray | None:
    """Joints q (rad) with ``base_from_flange(chain, q)`` = ``target`` (4×4 mm) within
    ``IK_TOL_MM`` and ``IK_TOL_RAD``, inside ``limits_rad`` ((n, 2) rad; None: the arm's
    joint limits), from the first of
    ``seeds`` (rad) that converges; None when none does (out of reach, or only across a
    limit). For a redundant arm (7 joints) the solution is the one the damped steps reach
    from the seed."""
    lim = chain.joint_limits_rad if limits_rad is None else np.asarray(limits_rad, dtype=float)
    return inverse_of(lambda Q: base_from_flange(chain, Q), target, seeds, lim, max_iter)


def inverse_of(forward: Forward, target: np.ndarray, seeds: list[np.ndarray],
               limits_rad: np.ndarray, max_iter: int = 200) -> np.ndarray | None:
    """:func:`inverse` for any serial arm given by its batched forward kinematics
    ``forward`` (joints (m, n) rad → base_from_flange (m, 4, 4) mm) and joint limits
    ``limits_rad`` (n, 2): damped least squares with the one least-squares loop
    (:func:`tmscal.calib.lsq.levenberg_marquardt`) on the error twist, rotation weighed as mm
    × ``_ROT_WEIGHT_MM``, each step at most ``_MAX_STEP_RAD`` per joint and clipped to the
    limits."""
    target = np.asarray(target, dtype=np.float64)
    lim = np.asarray(limits_rad, dtype=float)
    lo, hi = lim[:, 0], lim[:, 1]
    wts = np.array([_ROT_WEIGHT_MM] * 3 + [1.0] * 3)
    last: list[tuple[bytes, np.ndarray, np.ndarray]] = []

    def evaluate(q: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        # the residual is the (weighted) error to the target; a joint step dq changes it by
        # −J dq. One batched forward kinematics gives both, so a trial's Jacobian is kept for
        # the step that accepts it
        key = q.tobytes()
        if last and last[0][0] == key:
            e, J = last[0][1], last[0][2]
        else:
            e, J = _error(forward, q, target)
            last[:] = [(key, e, J)]
        return -wts * e, (wts[:, None] * J if jac else None)

    for seed in seeds:
        q0 = np.clip(np.asarray(seed, dtype=np.float64), lo, hi)
        sol = levenberg_marquardt(
            evaluate, q0, lambda q, dq: np.clip(q + dq, lo, hi), max_iter=max_iter,
            max_evaluations=2 * max_iter, lam0=1e-3, lam_down=5.0, ftol=0.0,
            max_step=_MAX_STEP_RAD, solved=lambda r: _converged(-r / wts))
        if _converged(-sol.residuals / wts):  # converged, or stalled in round-off there
            return sol.state
    return None


def _converged(e: np.ndarray) -> bool:
    return bool(np.linalg.norm(e[3:]) <= IK_TOL_MM and np.linalg.norm(e[:3]) <= IK_TOL_RAD)
