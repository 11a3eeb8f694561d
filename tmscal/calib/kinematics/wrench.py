"""Wrench rows of the kinematic estimator (docs/kinematics.md, "Wrench rows"): where a session
records a wrist force-torque wrench at every pose, its gravity wrench enters the same
likelihood as the tracker poses (:mod:`tmscal.calib.kinematics.estimate`). Pure numerics, no
I/O.

Model (that of force-torque self-calibration, :mod:`tmscal.calib.selfcal.model`, Joubair et
al. 2016; docs/selfcal.md): the world has z up and gravity (0, 0, −g); the robot's base is
tilted in it by world_R_base = Rz(yaw) Ry(pitch) Rx(roll) (yaw is invisible to gravity and
not a parameter); the sensor sits on the flange rotated by flange_R_sensor; the tool weighs
mg N with its centre of gravity c (mm, sensor frame); the sensor has a bias [f0 N; τ0 N·m].
At joints q_i the sensor frame's orientation in the world is

    R_i = world_R_base · R_A(q_i; p0 + δ) · flange_R_sensor,

R_A the rotation of base_from_flange of the arm with its deviations δ, so the world's up in
the sensor frame is u_i = R_iᵀ e_z and the sensor reads

    f_i = −mg u_i + f0,     τ_i = (c · 10⁻³) × (−mg u_i) + τ0     [N, N·m].

The residual (model − measured) per channel is whitened by its σ (the spread of the samples /
√samples, or a default). Extra parameters (:data:`WRENCH_NAMES`, 15, no prior): base_roll,
base_pitch (rad), the sensor rotation as a rotation vector on the right of flange_R_sensor
(rad), mg (N), cog_x/y/z (mm), f0_x/y/z (N), t0_x/y/z (N·m). The deviations δ enter through
the arm's rotation only: a body twist η = [η_ω; η_v] of the flange (A' = A exp(η),
:func:`tmscal.calib.kinematics.jacobian.deviation_twists`) changes u by
flange_R_sensorᵀ [R_Aᵀ u_b]× η_ω with u_b = world_R_baseᵀ e_z (lengths do not enter).

The starting point (:func:`initial_wrench`) is linear: with a level base, f_i = M v_i + f0
(v_i = R_Aᵢᵀ e_z, M = −mg flange_R_sensorᵀ) by least squares, M's polar factor and mean
singular value give the sensor rotation and mg; then τ_i = −[f_i − f0]× c + τ0 gives c, τ0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import CalibrationError
from ...geometry import matrix_from_rotvec, rotvec_from_matrix, skew
from ..gravity import wrench_from_up

__all__ = ["WRENCH_NAMES", "WRENCH_UNITS", "DEFAULT_SIGMA", "SIGMA_FLOOR", "WrenchData",
           "WrenchParams", "initial_wrench", "gravity_up", "predict_wrench", "wrench_rows",
           "wrench_block", "wrench_report"]

WRENCH_NAMES = ["base_roll", "base_pitch", "sensor_rx", "sensor_ry", "sensor_rz", "mg",
                "cog_x", "cog_y", "cog_z", "f0_x", "f0_y", "f0_z", "t0_x", "t0_y", "t0_z"]
WRENCH_UNITS = ["rad"] * 5 + ["N"] + ["mm"] * 3 + ["N"] * 3 + ["N·m"] * 3
#: σ of an averaged wrench when the session gives none: [N]*3 + [N·m]*3
DEFAULT_SIGMA = np.array([0.1] * 3 + [0.005] * 3)
#: the smallest σ of an averaged wrench taken from recorded spreads (a noise-free reading
#: would otherwise weigh infinitely): [N]*3 + [N·m]*3
SIGMA_FLOOR = np.array([1e-3] * 3 + [1e-4] * 3)


@dataclass(frozen=True)
class WrenchData:
    """The measured wrenches (n, 6) [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame, one
    per pose, and their σ (n, 6) (same units, > 0)."""

    wrench: np.ndarray
    sigma: np.ndarray

    @classmethod
    def make(cls, wrench: object, sigma: object, n: int) -> WrenchData:
        """Checked data for n poses: ``sigma`` None (:data:`DEFAULT_SIGMA`), (6,) or (n, 6).
        Raises CalibrationError naming what is wrong."""
        W = np.asarray(wrench, dtype=float)
        if W.shape != (n, 6) or not np.all(np.isfinite(W)):
            raise CalibrationError(f"kinematics: wrench must be ({n}, 6) finite "
                                   f"[Fx, Fy, Fz N, Tx, Ty, Tz N·m], got shape {W.shape}")
        S = DEFAULT_SIGMA if sigma is None else np.asarray(sigma, dtype=float)
        try:
            S = np.broadcast_to(S, (n, 6)).copy()
        except ValueError:
            raise CalibrationError(f"kinematics: wrench_sigma must be (6,) or ({n}, 6), got "
                                   f"shape {S.shape}") from None
        if not np.all(np.isfinite(S)) or np.any(S <= 0):
            raise CalibrationError("kinematics: wrench_sigma must be finite and > 0 "
                                   "(N, N·m)")
        return cls(W, S)

    def subset(self, keep: np.ndarray) -> WrenchData:
        return WrenchData(self.wrench[keep], self.sigma[keep])


@dataclass(frozen=True)
class WrenchParams:
    """The wrench model's parameters: ``tilt`` (2,) base roll, pitch rad; ``R_fs`` 3×3
    flange_R_sensor; ``mg`` N; ``cog_mm`` (3,) in the sensor frame; ``bias`` (6,) [N; N·m]."""

    tilt: np.ndarray
    R_fs: np.ndarray
    mg: float
    cog_mm: np.ndarray
    bias: np.ndarray

    def step(self, d: np.ndarray) -> WrenchParams:
        """Moved by d (15,) in the order of :data:`WRENCH_NAMES` (rotation on the right)."""
        return WrenchParams(self.tilt + d[0:2], self.R_fs @ matrix_from_rotvec(d[2:5]),
                            self.mg + float(d[5]), self.cog_mm + d[6:9], self.bias + d[9:15])


def gravity_up(tilt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u_b (3,), du_b/d(roll, pitch) (3, 2)): the world's up in the robot's base frame,
    u_b = (Rz(yaw) Ry(pitch) Rx(roll))ᵀ e_z (yaw drops out)."""
    a, b = float(tilt[0]), float(tilt[1])
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    u = np.array([-sb, sa * cb, ca * cb])
    du = np.array([[0.0, -cb], [ca * cb, -sa * sb], [-sa * cb, -ca * sb]])
    return u, du


def predict_wrench(p: WrenchParams, R_A: np.ndarray) -> np.ndarray:
    """The gravity wrench (n, 6) [N, N·m] in the sensor frame for flange rotations R_A
    (n, 3, 3) (base_from_flange)."""
    u_b, _ = gravity_up(p.tilt)
    u = np.einsum("ji,nkj,k->ni", p.R_fs, R_A, u_b)      # R_fsᵀ R_Aᵀ u_b
    return wrench_from_up(u, p.mg, p.cog_mm, p.bias)


def wrench_rows(p: WrenchParams, data: WrenchData, R_A: np.ndarray, Jk_w: np.ndarray | None
                ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(r (n, 6), J_w (n, 6, 15), J_δ (n, 6, k)): the whitened residuals (model − measured)/σ,
    their Jacobian with respect to the wrench parameters (:data:`WRENCH_NAMES`) and to the
    deviations whose body twists' rotation parts are ``Jk_w`` (n, 3, k) rad per unit
    (None: no Jacobian)."""
    w = predict_wrench(p, R_A)
    r = (w - data.wrench) / data.sigma
    if Jk_w is None:
        return r, None, None
    n = len(R_A)
    u_b, du_b = gravity_up(p.tilt)
    v = np.einsum("nji,j->ni", R_A, u_b)                       # R_Aᵀ u_b (flange frame)
    u = v @ p.R_fs                                             # R_fsᵀ v
    c = p.cog_mm * 1e-3
    Gu = np.concatenate([-p.mg * np.eye(3), -p.mg * skew(c)], axis=0)   # dw/du (6, 3)
    Jw = np.zeros((n, 6, len(WRENCH_NAMES)))
    du_tilt = np.einsum("ji,nkj,kl->nil", p.R_fs, R_A, du_b)   # R_fsᵀ R_Aᵀ du_b
    Jw[:, :, 0:2] = Gu @ du_tilt
    Jw[:, :, 2:5] = Gu @ skew(u)                              # u' = u + [u]× ω
    Jw[:, :3, 5] = -u
    Jw[:, 3:, 5] = np.cross(c, -u)
    Jw[:, 3:, 6:9] = -skew(-p.mg * u) * 1e-3                  # dτ = dc × f_grav
    Jw[:, :, 9:15] = np.eye(6)
    Jd = Gu @ (p.R_fs.T @ skew(v)) @ Jk_w                     # du = R_fsᵀ [v]× η_ω
    s = data.sigma[:, :, None]
    return r, Jw / s, Jd / s


def wrench_block(p: WrenchParams, data: WrenchData, R_A: np.ndarray, Jk: np.ndarray | None,
                 c_w: int, c_delta: int, n_params: int, jac: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The estimator's wrench rows: whitened residuals (6n,) and, with ``jac``, their
    Jacobian (6n, ``n_params``) with the wrench parameters in columns ``c_w``…``c_delta`` − 1
    and the deviations from ``c_delta`` on, whose body twists are ``Jk`` (n, 6, k) [ω; v].
    Without ``jac`` (``Jk`` may then be None) the Jacobian is all zeros."""
    r, Jw, Jd = wrench_rows(p, data, R_A, Jk[:, :3, :] if jac and Jk is not None else None)
    J = np.zeros((r.size, n_params))
    if Jw is not None and Jd is not None:
        J[:, c_w:c_delta] = Jw.reshape(r.size, -1)
        J[:, c_delta:] = Jd.reshape(r.size, -1)
    return r.ravel(), J


def initial_wrench(data: WrenchData, R_A: np.ndarray) -> WrenchParams:
    """The linear starting point (module docstring) from the nominal arm's flange rotations
    R_A (n, 3, 3), level base. Raises CalibrationError when the poses do not turn gravity
    enough in the sensor to separate the tool's weight from the bias."""
    n = len(R_A)
    v = R_A[:, 2, :]                                           # R_Aᵀ e_z
    D = np.concatenate([v, np.ones((n, 1))], axis=1)
    if n < 4 or np.linalg.matrix_rank(D, tol=1e-3 * np.sqrt(n)) < 4:
        raise CalibrationError(f"kinematics: the wrench rows need poses whose gravity "
                               f"directions in the flange span 3-D space ({n} poses do "
                               f"not); tilt the wrist more, or solve without the wrench")
    sol, *_ = np.linalg.lstsq(D, data.wrench[:, :3], rcond=None)
    M, f0 = sol[:3].T, sol[3]
    U, S, Vt = np.linalg.svd(-M)
    R_t = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt   # ≈ R_fsᵀ
    mg = float(S.mean())
    fg = data.wrench[:, :3] - f0
    T = np.concatenate([-skew(fg) * 1e-3, np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)
    sol2, *_ = np.linalg.lstsq(T.reshape(-1, 6), data.wrench[:, 3:].ravel(), rcond=None)
    return WrenchParams(np.zeros(2), R_t.T, mg, sol2[:3], np.concatenate([f0, sol2[3:]]))


def wrench_report(w: WrenchParams, sd: np.ndarray, rows: np.ndarray) -> dict[str, object]:
    """The fitted wrench model: {"estimate": {name: value}, "sd": {name: posterior SD}
    (names and units of :data:`WRENCH_NAMES` / :data:`WRENCH_UNITS`; the sensor rotation as
    the rotation vector of flange_R_sensor), "params": ``w``, "rows": 6n, "chi2": of the
    whitened wrench ``rows``}. CalibrationError when the posterior SDs say the poses do not
    identify the tool and the bias (a near-singular problem)."""
    if not np.all(np.isfinite(sd)) or sd.max(initial=0.0) > 1e6:
        raise CalibrationError("kinematics: the wrench rows do not identify the tool's weight, "
                               "centre of gravity and the sensor's bias from these poses; "
                               "turn the wrist more, or solve without the wrench")
    vals = np.concatenate([w.tilt, rotvec_from_matrix(w.R_fs), [w.mg], w.cog_mm, w.bias])
    return {"estimate": dict(zip(WRENCH_NAMES, map(float, vals), strict=True)),
            "sd": dict(zip(WRENCH_NAMES, map(float, sd), strict=True)),
            "params": w, "rows": int(rows.size), "chi2": float(rows @ rows)}
