"""Variance components of the ``ml`` residuals: the robot's rotation and translation noise (and,
without recorded sample spreads, the tracker's level) estimated from the calibration's own
residuals by restricted maximum likelihood (REML), and the parameter covariance split by
component (docs/methods.md, "Noise from the data").

The residuals of pose i (per body [rotation vector rad; translation mm], q = 6 per body) have
the covariance S_i = Σ_k θ_k Q_ki: Q_rot and Q_trans the robot's flange error per unit
variance (rad² per axis, mm² per component; :func:`tmscal.calib.ml_model.robot_parts`),
Q_tracker the tracker's covariance (from the sample spreads, or ml's defaults;
:func:`tmscal.calib.ml_model.tracker_part`). The robot's error is shared by the marker and the
probe of one pose and enters their rotations and, through the lever arms of X and Y, their
translations; the tracker's is independent per body. That difference in structure is what
separates the components.

Estimator: REML by Förstner's (1979) iteration of the variance-component estimate,
θ_k ← θ_k · vᵀ S⁻¹ Q_k S⁻¹ v / tr(P Q_k), P = S⁻¹ − S⁻¹ J (Jᵀ S⁻¹ J)⁻¹ Jᵀ S⁻¹, v the
residuals of the weighted least-squares fit of the model linearised at the estimate (Koch
1999, §3.6). A fixed point is a REML stationary point; every step keeps θ_k > 0. The
component covariance is the inverse REML information, V = 2 T⁻¹, T_kl = tr(P Q_k P Q_l), and
each component's effective degrees of freedom ν_k = 2 θ_k² / V_kk (Satterthwaite 1946): the
prediction draws θ_k as θ̂_k ν_k / χ²_ν_k. Why not the per-pose robot reads: a robot reports
the pose its joints encode, so its reads spread only by encoder jitter and never show the
positioning or kinematic error that reaches the tracker; the residuals do.

Rows of known variance (a prior's pseudo-observations, :mod:`tmscal.calib.kinematics.noise`)
join the least-squares fit and the projection P but no component (``fixed``).

References: Förstner W (1979). Ein Verfahren zur Schätzung von Varianz- und
Kovarianzkomponenten. Allgemeine Vermessungs-Nachrichten 86:446–453. — Koch KR (1999).
Parameter Estimation and Hypothesis Testing in Linear Models, 2nd ed. Springer. —
Satterthwaite FE (1946). An approximate distribution of estimates of variance components.
Biometrics Bulletin 2(6):110–114.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["COMPONENTS", "Components", "estimate_components"]

#: the variance components, in order
COMPONENTS = ("robot_rot", "robot_trans", "tracker")


@dataclass
class Components:
    """The result of :func:`estimate_components`: ``theta`` (K,) the variance factors (robot
    rotation rad² per axis, robot translation mm² per component, tracker factor on its
    covariance), ``estimated`` (K,) bool, ``dof`` (K,) effective degrees of freedom (inf for a
    fixed component), ``parts`` {name: (k, k)} the parameter covariance per component
    (Σ parts = (Jᵀ S⁻¹ J)⁻¹ at ``theta``; with fixed rows also their part "fixed"),
    ``iterations``."""

    theta: np.ndarray
    estimated: np.ndarray
    dof: np.ndarray
    parts: dict[str, np.ndarray]
    iterations: int


def _trace_sum(Q: np.ndarray, n: int) -> float:
    """Σ_i tr(Q_i) of per-pose blocks (n, q, q), or n tr(Q) of one shared (q, q)."""
    return float(n * np.trace(Q) if Q.ndim == 2 else np.trace(Q, axis1=1, axis2=2).sum())


def _left(L: np.ndarray, X: np.ndarray) -> np.ndarray:
    """L_i X_i (n, q, k) for one L (q, q), as a single product, or per pose L (n, q, q)."""
    if L.ndim == 3:
        return L @ X
    n, q, k = X.shape
    return (L @ np.swapaxes(X, 0, 1).reshape(q, n * k)).reshape(q, n, k).swapaxes(0, 1)


def estimate_components(J: np.ndarray, r: np.ndarray, Qs: list[np.ndarray],
                        theta0: np.ndarray, estimate: np.ndarray, max_iter: int = 60,
                        tol: float = 1e-3,
                        fixed: tuple[np.ndarray, np.ndarray] | None = None,
                        floor: np.ndarray | None = None) -> Components:
    """REML variance components (module docstring) of the residuals ``r`` (n, q) with raw
    Jacobian ``J`` (n, q, k) at the estimate and the cofactors ``Qs`` (each (q, q) or
    (n, q, q)), from ``theta0`` (K,) > 0; ``estimate`` (K,) bool says which are estimated
    (the others stay at theta0). Stops when no factor changes by more than ``tol``
    (relative) or after ``max_iter`` iterations.

    ``fixed`` = (J_f (p, k), r_f (p,)): further rows of KNOWN unit variance, already
    whitened (e.g. a Gaussian prior's pseudo-observations δ/τ = 0 + e, e ~ N(0, 1)): they
    enter the least-squares fit and P (so the data's J need not have full rank alone; the
    prior makes the normal matrix regular), but no component: the REML of this augmented
    model is that of the mixed model with the prior as a random effect (the pseudo-
    observations integrate the prior out). Their share of the parameter covariance is
    ``parts["fixed"]``. ``floor`` (K,): the least value of each factor (default 1e-12 of
    theta0)."""
    n, q, k = J.shape
    Jp, rp = (np.zeros((0, k)), np.zeros(0)) if fixed is None else \
        (np.asarray(fixed[0], dtype=float), np.asarray(fixed[1], dtype=float))
    shared = all(Q.ndim == 2 for Q in Qs)  # one S for every pose: one factorisation
    Qn = [Q if shared or Q.ndim == 3 else np.broadcast_to(Q, (n, q, q)) for Q in Qs]
    theta = np.asarray(theta0, dtype=float).copy()
    est = np.asarray(estimate, dtype=bool)
    floor = 1e-12 * np.maximum(theta, 1e-300) if floor is None else np.asarray(floor, float)
    it = 0
    while True:
        S = sum(t * Q for t, Q in zip(theta, Qn, strict=True))
        Li = np.linalg.inv(np.linalg.cholesky(S))
        Jw = _left(Li, J)
        rw = r @ Li.T if shared else (Li @ r[..., None])[..., 0]
        Jf = Jw.reshape(-1, k)
        d = np.linalg.norm(Jf, axis=0)
        d = np.sqrt(d * d + np.sum(Jp * Jp, axis=0))
        d[d == 0] = 1.0
        H = np.linalg.inv((Jf / d).T @ (Jf / d) + (Jp / d).T @ (Jp / d)) / np.outer(d, d)
        v = rw - (Jf @ (H @ (Jf.T @ rw.ravel() + Jp.T @ rp))).reshape(rw.shape)
        JH = (Jf @ H).reshape(Jw.shape)
        # the hat matrix's diagonal blocks (n, q, q), or only their sum with one shared S
        M = (np.swapaxes(JH, 0, 1).reshape(q, -1) @ np.swapaxes(Jw, 0, 1).reshape(q, -1).T
             if shared else JH @ np.swapaxes(Jw, 1, 2))
        Qw = [Li @ Q @ np.swapaxes(Li, -1, -2) for Q in Qn]
        if it >= max_iter or not est.any():
            break
        new = theta.copy()
        for j in np.flatnonzero(est):
            num = float(np.sum(v * (v @ Qw[j]))) if shared else \
                float(np.sum(v * (Qw[j] @ v[..., None])[..., 0]))
            tr = _trace_sum(Qw[j], n)
            red = float(tr - np.sum(Qw[j] * M))
            if red <= 1e-9 * tr:  # the fit absorbs the component: nothing to estimate from
                continue
            new[j] = max(theta[j] * num / red, floor[j])
        it += 1
        if not np.all(np.isfinite(new)):
            max_iter = it - 1  # no information to estimate from: keep the last θ
            continue
        done = np.all(np.abs(new - theta) <= tol * np.maximum(theta, 1e-300))
        theta = new
        if done:
            max_iter = it  # one more pass evaluates everything at the converged θ
    A = [Jf.T @ _left(Qk, Jw).reshape(-1, k) for Qk in Qw]
    parts = {name: theta[j] * H @ A[j] @ H for j, name in enumerate(COMPONENTS[:len(Qs)])}
    if len(Jp):
        parts["fixed"] = H @ (Jp.T @ Jp) @ H
    dof = np.full(len(Qs), np.inf)
    idx = np.flatnonzero(est)
    if len(idx):
        T = np.zeros((len(idx), len(idx)))
        for a, ja in enumerate(idx):
            for b, jb in enumerate(idx[a:], start=a):
                QQ = Qw[ja] @ Qw[jb]
                t = (_trace_sum(QQ, n) - 2.0 * np.sum(M * np.swapaxes(QQ, -1, -2))
                     + np.sum((H @ A[ja]) * (H @ A[jb]).T))
                T[a, b] = T[b, a] = t
        if np.all(np.isfinite(T)):
            V = 2.0 * np.linalg.pinv(T)
            dof[idx] = 2.0 * theta[idx] ** 2 / np.maximum(np.diag(V), 1e-300)
        else:
            dof[idx] = 1.0
    return Components(theta=theta, estimated=est, dof=dof, parts=parts, iterations=it)
