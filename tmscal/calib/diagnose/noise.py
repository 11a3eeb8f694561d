"""The calibration's noise model from its data (docs/lab-day.md, "The noise model"): the
residual covariance of the poses it was solved on with the calibration's own uncertainty
(a parametric bootstrap for QR24/QR36, the fit's covariance otherwise;
:func:`calibration_noise`), an isotropic one from stored errors for older files
(:func:`noise_from_errors`), and the tolerances a daily check would use
(:func:`suggested_tolerances`). Units: mm and deg."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ...errors import CalibrationError
from ...geometry import make_pose, matrix_from_rotvec
from ..calibration import Applied, Calibration
from .fitting import fit
from .model import Frames, NoiseModel, _cal_jacobian, _xi, frames, residuals

__all__ = ["noise_from_residuals", "BOOTSTRAP_METHODS", "BOOTSTRAP_REPS", "calibration_noise",
           "noise_from_errors", "suggested_tolerances"]


def noise_from_residuals(r: np.ndarray, bodies: Sequence[str], fitted: int,
                         source: str = "residuals") -> NoiseModel:
    """The noise model from in-sample residuals r (n, q) of a calibration that fitted
    ``fitted`` parameters to them: Σ = Σᵢ rᵢ rᵢᵀ / (n − fitted/q) (each parameter uses up a
    q-th of a pose), shrunk toward its diagonal by λ = min(1, q/n) so that it is positive
    definite on few poses."""
    r = np.asarray(r, dtype=float)
    n, q = r.shape
    if n < 2:
        raise CalibrationError(f"a noise model needs at least 2 poses, got {n}")
    S = r.T @ r / max(n - fitted / q, 1.0)
    lam = min(1.0, q / n)
    S = (1 - lam) * S + lam * np.diag(np.diag(S))
    floor = 1e-12 + 1e-9 * float(np.max(np.diag(S)))
    S = S + floor * np.eye(q)
    return NoiseModel(S, tuple(bodies), source, n)


#: closed-form methods whose own sampling error :func:`calibration_noise` measures by a
#: parametric bootstrap (cheap to re-solve); others use the likelihood's covariance
BOOTSTRAP_METHODS = ("qr36", "qr24")
BOOTSTRAP_REPS = 60


def calibration_noise(cal: Calibration, A: np.ndarray, B: np.ndarray,
                      C: np.ndarray | None = None, source: str = "residuals",
                      seed: int = 0) -> NoiseModel:
    """The noise model of a calibration from the poses it was solved on (A, B, C: (n, 4, 4)
    mm): the residual covariance (:func:`noise_from_residuals`, 6 parameters per solved
    transform) and the calibration's own uncertainty (:attr:`NoiseModel.cal_cov`, blocks z,
    x (y)): for QR24/QR36 a parametric bootstrap — the poses' tracker readings perturbed by
    draws of that residual noise, re-solved ``BOOTSTRAP_REPS`` times by the same method, the
    covariance of the re-solved blocks — since these linear solvers are less efficient than
    the likelihood and the likelihood's covariance understates their error; for other
    methods the likelihood's, (JᵀJ)⁻¹ of the whitened Jacobian on these poses."""
    fr = frames(cal, A, B, C)
    bodies = fr.bodies
    nm = noise_from_residuals(residuals(fr), bodies, 6 * (len(bodies) + 1), source)
    blocks = ("z", "x", "y") if "probe" in bodies else ("z", "x")
    if cal.method in BOOTSTRAP_METHODS and cal.distortion is None and cal.arm is None:
        cov = _bootstrap(cal, A, B, C if "probe" in bodies else None, nm, blocks, seed)
        if cov is not None:
            return replace(nm, cal_cov=cov, cal_blocks=blocks)
    ft = fit(fr, nm, blocks)
    if not ft.rank_ok or not np.all(np.isfinite(ft.cov)):
        return nm
    return replace(nm, cal_cov=ft.cov, cal_blocks=blocks)


def _bootstrap(cal: Calibration, A: np.ndarray, B: np.ndarray, C: np.ndarray | None,
               nm: NoiseModel, blocks: tuple[str, ...], seed: int) -> np.ndarray | None:
    from ..methods import solve

    rng = np.random.default_rng(seed)
    n = len(A)
    ref = {"z": cal.Z, "x": cal.X, "y": cal.Y}
    draws = []
    q6 = len(nm.cov)
    Km = np.linalg.cholesky(nm.cov[:6, :6] / 2)
    Kh = np.linalg.cholesky(nm.cov / 2)
    for _ in range(BOOTSTRAP_REPS):
        # half the residual variance as the robot's (in the flange frame, shared by both
        # bodies: errors in A bias a linear solver, errors in N do not), half the tracker's
        f = rng.standard_normal((n, 6)) @ Km.T
        F = np.stack([cal.X @ make_pose(matrix_from_rotvec(np.radians(f[j, 3:])), f[j, :3])
                      @ np.linalg.inv(cal.X) for j in range(n)])
        e = rng.standard_normal((n, q6)) @ Kh.T
        bodies = [B] + ([] if C is None else [C])
        pert = []
        for i, N in enumerate(bodies):
            d = e[:, 6 * i:6 * i + 6]
            D = np.stack([make_pose(matrix_from_rotvec(np.radians(d[j, 3:])), d[j, :3])
                          for j in range(n)])
            pert.append(N @ D)
        A_p = A @ F
        try:
            c2 = solve(A_p, pert[0], pert[1] if C is not None else None, method=cal.method,
                       orthonormal=cal.applied == Applied.ORTHONORMAL)
        except (CalibrationError, np.linalg.LinAlgError, ValueError):
            return None
        new = {"z": c2.Z, "x": c2.X, "y": c2.Y}
        draws.append(np.concatenate([_xi(np.linalg.inv(ref[b]) @ new[b]) for b in blocks]))
    X = np.asarray(draws)
    S = np.cov(X, rowvar=False)
    S = (S + S.T) / 2 + 1e-12 * np.eye(len(S))
    return S if np.all(np.isfinite(S)) else None


#: E‖t‖ of an isotropic 3-D Gaussian of σ per axis is 2·√(2/π)·σ
_MEAN_NORM = 2 * np.sqrt(2 / np.pi)


def noise_from_errors(errors: dict[str, Any], bodies: Sequence[str]) -> NoiseModel:
    """An isotropic noise model from a calibration's stored mean errors (files written
    before the noise model was stored): per body σ = trans_mm / (2√(2/π)) per axis, and
    likewise in degrees. CalibrationError when the errors have no figure for a body."""
    d = []
    for b in bodies:
        e = errors.get(b) if isinstance(errors, dict) else None
        if not isinstance(e, dict) or not {"trans_mm", "rot_deg"} <= set(e):
            if isinstance(errors, dict) and len(bodies) == 1 and "e_t_mm" in errors:
                e = {"trans_mm": errors["e_t_mm"], "rot_deg": errors["theta_t_deg"]}
            else:
                raise CalibrationError(f"the calibration's stored errors give no {b!r} "
                                       "figures, from which a noise model could come")
        st = max(float(e["trans_mm"]), 1e-6) / _MEAN_NORM
        sr = max(float(e["rot_deg"]), 1e-6) / _MEAN_NORM
        d += [st] * 3 + [sr] * 3
    return NoiseModel(np.diag(np.square(d)), tuple(bodies), "stored errors (isotropic)", 0)


def suggested_tolerances(noise: NoiseModel, n_poses: int, level: float = 0.99,
                         sessions: int = 4000, seed: int = 0,
                         fr: Frames | None = None,
                         stored: dict[str, Any] | None = None) -> dict[str, Any]:
    """Tolerances for the daily check's totals from the noise model: the ``level`` quantile
    of e_t (mm, the sum of the bodies' mean ‖t(E)‖) and θ_t (deg) over ``sessions``
    simulated unchanged sessions of ``n_poses`` poses: each pose's noise drawn from the
    model and, given the session's frames ``fr`` and a model with the calibration's own
    uncertainty, that error too (one draw per session, shared by its poses, through the
    residuals' Jacobian at these poses). A check on an unchanged rig then fails in about
    1 − level of days. ``stored``: the calibration's own held-out errors (e_t_mm,
    theta_t_deg: cross-validated, every pose held out once): where they are larger than the
    simulated sessions' mean (a closed-form solver is less efficient than the likelihood the
    model assumes), the quantiles are scaled up by that ratio. {"tolerance_mm",
    "tolerance_deg", "level", "n_poses", "scaled": the two ratios applied}."""
    rng = np.random.default_rng(seed)
    nm = noise if fr is None else noise.for_bodies(fr.bodies)
    q = len(nm.cov)
    K = np.linalg.cholesky(nm.cov)
    n = max(int(n_poses) if fr is None else fr.n, 1)
    r = rng.standard_normal((sessions, n, q)) @ K.T
    cc = None if fr is None else nm.calibration_for(fr)
    if cc is not None:
        blocks, C = cc
        J = _cal_jacobian(fr, blocks)  # type: ignore[arg-type]
        Lc = np.linalg.cholesky(C + 1e-18 * np.eye(len(C)))
        shared = rng.standard_normal((sessions, len(C))) @ Lc.T @ J.T
        r = r + shared.reshape(sessions, n, q)
    et = np.zeros(sessions)
    th = np.zeros(sessions)
    for i in range(len(nm.bodies)):
        et += np.linalg.norm(r[:, :, 6 * i:6 * i + 3], axis=2).mean(axis=1)
        th += np.linalg.norm(r[:, :, 6 * i + 3:6 * i + 6], axis=2).mean(axis=1)
    f_t = f_r = 1.0
    if stored:
        if np.isfinite(stored.get("e_t_mm", np.nan)):
            f_t = max(1.0, float(stored["e_t_mm"]) / float(et.mean()))
        if np.isfinite(stored.get("theta_t_deg", np.nan)):
            f_r = max(1.0, float(stored["theta_t_deg"]) / float(th.mean()))
    return {"tolerance_mm": f_t * float(np.quantile(et, level)),
            "tolerance_deg": f_r * float(np.quantile(th, level)), "level": level,
            "n_poses": n, "scaled": [f_t, f_r]}
