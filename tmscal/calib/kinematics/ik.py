"""Inverse kinematics of an :class:`~tmscal.calib.kinematics.model.Arm`: the joints at which
it puts its flange at a wanted pose (base_from_flange, 4×4 mm, the robot's own base frame;
``arm.base`` not applied; joints rad), by damped
least squares (Levenberg–Marquardt) on the joint Jacobian. Pure numerics, no I/O. The one
inverse kinematics of tmscal: the mock and simulated robots' controllers
(:func:`tmscal.sim.arm.inverse`) solve with it too.

A controller keeps the arm's configuration on a linear move, so the solution sought is the one
nearest the seed (the joints the arm has, or those of the calibration's poses); seeds further
away are tried only when the nearest does not converge.
"""

from __future__ import annotations

import numpy as np

from ...geometry import rotvec_from_matrix
from .model import Arm, base_from_flange

__all__ = ["inverse", "IK_TOL_MM", "IK_TOL_RAD"]

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


def _error(chain: Arm, q: np.ndarray, target: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """(e, J): the body-frame error twist from A(q) to ``target`` [rotation vector rad;
    translation mm] and the joint Jacobian (6, n) of the flange's body twist, by central
    differences of ``_H_RAD`` on one batched forward kinematics (2n + 1 configurations: about
    ten times faster than the analytic deviation twists, and the mock robots solve this on
    every move)."""
    n = chain.n_joints
    Q = np.concatenate([q[None], q + _H_RAD * np.eye(n), q - _H_RAD * np.eye(n)])
    T = base_from_flange(chain, Q)
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
    target = np.asarray(target, dtype=np.float64)
    n = chain.n_joints
    lim = chain.joint_limits_rad if limits_rad is None else np.asarray(limits_rad, dtype=float)
    lo, hi = lim[:, 0], lim[:, 1]
    wts = np.array([_ROT_WEIGHT_MM] * 3 + [1.0] * 3)
    for seed in seeds:
        q = np.clip(np.asarray(seed, dtype=np.float64), lo, hi)
        e, J = _error(chain, q, target)
        cost = float(np.sum((wts * e) ** 2))
        lam = 1e-3
        for _ in range(max_iter):
            if _converged(e):
                return q
            Jw = wts[:, None] * J
            H = Jw.T @ Jw
            dq = np.linalg.solve(H + lam * (np.diag(np.diag(H)) + 1e-9 * np.eye(n)),
                                 Jw.T @ (wts * e))
            big = float(np.abs(dq).max())
            if big > _MAX_STEP_RAD:
                dq *= _MAX_STEP_RAD / big
            q_new = np.clip(q + dq, lo, hi)
            e_new, J_new = _error(chain, q_new, target)
            c_new = float(np.sum((wts * e_new) ** 2))
            if c_new < cost:
                q, e, J, cost, lam = q_new, e_new, J_new, c_new, max(lam * 0.2, 1e-12)
            else:
                lam *= 10.0
                if lam > 1e8:
                    break
        if _converged(e):  # stalled in round-off at the solution
            return q
    return None


def _converged(e: np.ndarray) -> bool:
    return bool(np.linalg.norm(e[3:]) <= IK_TOL_MM and np.linalg.norm(e[:3]) <= IK_TOL_RAD)
