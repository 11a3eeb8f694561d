"""How the simulation study compares identified arms (Joubair et al. 2016, as tmscal
reproduces it; docs/selfcal.md, "The simulation study"): the maximum a posteriori model of every
parameter of :class:`~tmscal.calib.selfcal.model.ArmModel` (:func:`canonical`, with the prior
:func:`prior_scale`) — which makes two fits that kept different equivalent columns comparable —
and the TCP error left after a hand/eye calibration absorbs what it can
(:func:`absorbed_errors`). Pure numerics, no I/O. A session's arm is identified by the one
kinematic estimator instead (:mod:`tmscal.calib.selfcal.estimate`).

Units: parameters as ``ArmModel.parameter_names`` / ``parameter_units`` (rad, mm, N, N·m);
wrenches [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame; positions mm.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ....geometry import matrix_from_rotvec, skew
from ...lsq import levenberg_marquardt
from ..identify import check_data
from ..model import forward, jacobian, wrench

__all__ = ["canonical", "prior_scale", "absorbed_errors"]


def prior_scale(model: Any, length_mm: float = 2.0, angle_deg: float = 1.0) -> np.ndarray:
    """The prior standard deviation of each parameter's deviation from the nominal, in its
    unit (``parameter_units``): ``length_mm`` for mm, ``angle_deg`` (in rad) for rad, 1 N and
    0.1 N·m for the weight and the bias. The metric of :func:`canonical`."""
    size = {"mm": length_mm, "rad": np.radians(angle_deg), "N": 1.0, "N·m": 0.1}
    return np.array([size[u] for u in model.parameter_units()])


def canonical(model0: Any, q: Any, wrench_meas: Any, sigma: Any, start: Any = None,
              length_mm: float = 2.0, angle_deg: float = 1.0, max_iter: int = 50) -> Any:
    """The identification's answer in a form that does not depend on which of the equivalent
    columns :func:`identifiable` kept: the maximum a posteriori model of every parameter at
    once, with independent Gaussian priors around ``model0`` (the nominal) of the sizes
    :func:`prior_scale` gives, and the wrenches ``wrench_meas`` (m, 6) [N, N·m] at q (m, n)
    with the noise ``sigma`` (6,) of each such (averaged) wrench.

    What the wrench determines comes from the data; what it does not see, or sees only in a
    combination (θ0_2 + θ0_3 + θ0_4 of parallel joints, θ0_6 and the sensor's yaw), is shared
    out as the prior says: the smallest deviation in prior units that fits. No column is
    chosen, so two fits that kept different but equivalent columns give the same answer from
    the same data (``start``, e.g. one of their models, only speeds the solve; default
    ``model0``). Gauss–Newton with Levenberg–Marquardt damping on the stacked residuals
    [(w(p) − w_meas)/σ; (p − p0)/τ]; parameters no wrench changes stay nominal."""
    q, w, sigma = check_data(model0, q, wrench_meas, sigma)
    p0 = model0.vector()
    tau = prior_scale(model0, length_mm, angle_deg)
    inv_s = np.tile(1.0 / sigma, len(q))
    x = np.zeros_like(p0) if start is None else (start.vector() - p0) / tau

    def evaluate(xv: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        m = model0.with_vector(p0 + tau * xv)
        r = np.concatenate([(wrench(m, q) - w).ravel() * inv_s, xv])
        if not jac:
            return r, None
        return r, np.vstack([jacobian(m, q) * inv_s[:, None] * tau, np.eye(len(xv))])

    # the prior rows keep every column's norm ≥ 1: the scaled damping is λ·diag(JᵀJ + I)
    x = levenberg_marquardt(
        evaluate, x, lambda xv, dx: xv + dx, max_iter=max_iter, ftol=0.0,
        small_step=lambda xv, dx: bool(np.linalg.norm(dx)
                                       <= 1e-12 * max(1.0, float(np.linalg.norm(xv + dx))))
    ).state
    return model0.with_vector(p0 + tau * x)


def absorbed_errors(model_true: Any, model_est: Any, q: Any, tcp_mm: Any = (0.0, 0.0, 0.0),
                    iterations: int = 4) -> np.ndarray:
    """(m,) mm: the TCP position errors of ``model_est`` against ``model_true`` at joints q
    (m, n) after a hand/eye calibration absorbs what it can — the best rigid transform of the
    base (rotation and translation: the robot/world calibration) and the best offset of the
    TCP in the flange frame (the hand/eye calibration), fitted by least squares on these
    configurations themselves (Gauss–Newton on the rotation's exponential coordinates). A
    rigid error of the base or the flange (base position and heading, θ0_1 of a level arm)
    costs nothing here; an error of the arm's shape does."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    tcp = np.asarray(tcp_mm, dtype=float)
    Ft = forward(model_true, q)
    target = Ft[:, :3, :3] @ tcp + Ft[:, :3, 3]
    Fe = forward(model_est, q)
    m = len(q)

    def evaluate(x: tuple[np.ndarray, np.ndarray, np.ndarray], jac: bool
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        R, t, u = x
        RP = (Fe[:, :3, :3] @ (tcp + u) + Fe[:, :3, 3]) @ R.T
        r = (target - (RP + t)).ravel()
        if not jac:
            return r, None
        J = np.zeros((m, 3, 9))                 # d(RP + t)/d(ω, t, u); ω on the left of R
        J[:, :, :3] = -skew(RP)
        J[:, :, 3:6] = np.eye(3)
        J[:, :, 6:9] = R @ Fe[:, :3, :3]
        return r, -J.reshape(-1, 9)

    def moved(x: tuple[np.ndarray, np.ndarray, np.ndarray], d: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return matrix_from_rotvec(d[:3]) @ x[0], x[1] + d[3:6], x[2] + d[6:9]

    R, t, u = levenberg_marquardt(evaluate, (np.eye(3), np.zeros(3), np.zeros(3)), moved,
                                  max_iter=iterations, ftol=0.0).state
    P = Fe[:, :3, :3] @ (tcp + u) + Fe[:, :3, 3]
    return np.linalg.norm(target - (P @ R.T + t), axis=-1)
