"""The measurement model of the ``ml`` solver (:mod:`tmscal.calib.ml`, whose docstring states
it): the tracker distortion and its undoing, the residuals of one problem (``Problem``), the
noise covariance per pose that whitens them, and the parameters' names and covariance. Shared
by the solver, the Cramér–Rao bound (:mod:`.bound`), the adaptive prediction
(:mod:`.prediction`) and ``Calibration.errors`` (which undistorts with a solver's distortion).

Frames and units as everywhere: A = base_from_flange, B = tracker_from_marker, C =
tracker_from_probe, X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker;
4×4, mm; rotations as rotation vectors in rad.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import CalibrationError
from ..geometry import (
    make_pose,
    matrix_from_rotvec,
    orthonormalize,
    right_jacobian_inv,
    rotvec_from_matrix,
    skew,
)

__all__ = ["BodyResidual", "body_residual", "DISTORTION_MODELS", "STEPS", "G_STEP",
           "undistortion", "g_of", "tool_moment",
           "undistort", "Problem", "whiten_residuals", "check_sigma", "tracker_covs",
           "noise_covariance", "robot_parts", "tracker_part", "whitener",
           "covariance_from_jacobian", "parameter_names"]

#: distortion model → number of parameters
DISTORTION_MODELS = {"none": 0, "scale": 1, "axis": 3, "affine": 6}
_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # affine: symmetric G
STEPS = (1e-6, 1e-4)  # finite-difference steps: rotation (rad), translation (mm)
G_STEP = 1e-7


def undistortion(model: str, g: np.ndarray) -> np.ndarray:
    """G = D⁻¹ (3×3) from the model's parameters g."""
    if model == "none":
        return np.eye(3)
    if model == "scale":
        return (1.0 + g[0]) * np.eye(3)
    if model == "axis":
        return np.diag(1.0 + g)
    G = np.eye(3)
    for v, (i, j) in zip(g, _SYM, strict=True):
        G[i, j] += v
        if i != j:
            G[j, i] += v
    return G


def tool_moment(tool_mm: Any) -> np.ndarray:
    """Second moment Σ q qᵀ (3×3, normalised) of a tool's fiducials (k, 3) mm about their
    centroid."""
    q = np.asarray(tool_mm, dtype=float)
    if q.ndim != 2 or q.shape[1] != 3 or len(q) < 3 or not np.all(np.isfinite(q)):
        raise CalibrationError("method 'ml': tools_mm must be (k ≥ 3, 3) fiducial positions, mm")
    q = q - q.mean(axis=0)
    M = q.T @ q
    return M / np.trace(M)


def undistort(N: np.ndarray, G: np.ndarray, model: str, M: np.ndarray | None = None
              ) -> np.ndarray:
    """Tracker poses N (n, 4, 4) with the distortion undone. The tracker fits each tool
    rigidly to distorted fiducials, so it reports t = D t₀ and R = polar(D R₀ M) (M the tool's
    second moment, :func:`tool_moment`); this returns G t and polar(G R M), which is R₀ to
    first order in D − I (exactly for the isotropic scale, where R is left alone). Without M
    (tool unknown) M = I, i.e. polar(G) R."""
    if model == "none":
        return N
    out = N.copy()
    out[:, :3, 3] = N[:, :3, 3] @ G.T
    if model != "scale":
        out[:, :3, :3] = (orthonormalize(G) @ N[:, :3, :3] if M is None else
                          orthonormalize(G[None] @ N[:, :3, :3] @ M))
    return out


@dataclass(frozen=True)
class BodyResidual:
    """The residual of one tracked body at every pose, E = W⁻¹ A⁻¹ Z N (W = X or Y, N = B or
    C undistorted): ``r`` (n, 6) [log R_E rad; t_E mm], and, when asked, its derivatives
    (n, 6, 6) with respect to W and Z turned on the right (R exp(ω), t + p; columns [ω rad,
    p mm]) and to a body twist ξ = [ξ_ω rad; ξ_v mm] of the flange (A' = A exp(ξ))."""

    r: np.ndarray
    dW: np.ndarray | None = None
    dZ: np.ndarray | None = None
    dA: np.ndarray | None = None


def body_residual(A: np.ndarray, W: np.ndarray, Z: np.ndarray, N: np.ndarray,
                  jac: bool = True, flange: bool = False) -> BodyResidual:
    """The one ML residual of tmscal (module docstring; used by :class:`Problem` and the
    kinematic estimate, :mod:`tmscal.calib.kinematics.estimate`): poses A (n, 4, 4)
    base_from_flange, W (4, 4) flange_from_body, Z (4, 4) base_from_tracker, tracker poses N
    (n, 4, 4) tracker_from_body (undistorted), all mm.

    With φ = log R_E, J_r⁻¹ its inverse right Jacobian (exact) and R_M, t_M the rotation and
    translation of W⁻¹A⁻¹: ∂φ/∂ω_W = −J_r⁻¹ R_Eᵀ, ∂t_E/∂ω_W = [t_E]×, ∂t_E/∂p_W = −R_Wᵀ;
    ∂φ/∂ω_Z = J_r⁻¹ R_Nᵀ, ∂t_E/∂ω_Z = −R_M R_Z [t_N]×, ∂t_E/∂p_Z = R_M; the flange's twist
    enters as η = Ad(W⁻¹) ξ: ∂φ = −J_r⁻¹ R_Eᵀ η_ω, ∂t_E = [t_E]× η_ω − η_v (``dA`` only
    with ``flange``: the ml solve keeps A fixed)."""
    R_A, t_A = A[:, :3, :3], A[:, :3, 3]
    RZ, tZ = Z[:3, :3], Z[:3, 3]
    RW, tW = W[:3, :3], W[:3, 3]
    R_M = RW.T @ np.swapaxes(R_A, 1, 2)                       # rotation of W⁻¹A⁻¹
    t_M = -RW.T @ tW - np.einsum("nij,nj->ni", R_M, t_A)
    R_E = R_M @ (RZ @ N[:, :3, :3])
    t_E = np.einsum("nij,nj->ni", R_M, N[:, :3, 3] @ RZ.T + tZ) + t_M
    phi = rotvec_from_matrix(R_E)
    r = np.concatenate([phi, t_E], axis=1)
    if not jac:
        return BodyResidual(r)
    n = len(A)
    Jr = right_jacobian_inv(phi)
    JrEt = Jr @ np.swapaxes(R_E, 1, 2)
    tEx = skew(t_E)
    dW = np.zeros((n, 6, 6))
    dW[:, :3, :3] = -JrEt
    dW[:, 3:, :3] = tEx
    dW[:, 3:, 3:] = -RW.T
    dZ = np.zeros((n, 6, 6))
    dZ[:, :3, :3] = Jr @ np.swapaxes(N[:, :3, :3], 1, 2)
    dZ[:, 3:, :3] = -(R_M @ RZ) @ skew(N[:, :3, 3])
    dZ[:, 3:, 3:] = R_M
    if not flange:
        return BodyResidual(r, dW, dZ)
    # η_ω = R_Wᵀ ξ_ω, η_v = R_Wᵀ ξ_v + [t_W⁻¹]× R_Wᵀ ξ_ω with t_W⁻¹ = −R_Wᵀ t_W
    tWi_x = skew(-RW.T @ tW)
    dA = np.zeros((n, 6, 6))
    dA[:, :3, :3] = -JrEt @ RW.T
    dA[:, 3:, :3] = (tEx - tWi_x) @ RW.T
    dA[:, 3:, 3:] = -RW.T
    return BodyResidual(r, dW, dZ, dA)


@dataclass
class Problem:
    """One ML problem: poses A (n, 4, 4), bodies [B, (C)], start transforms Ws [X0, (Y0)],
    Z0, and the distortion model."""

    A: np.ndarray
    bodies: list[np.ndarray]
    Ws: list[np.ndarray]
    Z0: np.ndarray
    model: str = "none"
    g0: np.ndarray | None = None
    moments: list[np.ndarray | None] | None = None

    @property
    def n_params(self) -> int:
        return 6 * (len(self.Ws) + 1) + DISTORTION_MODELS[self.model]

    def unpack(self, th: np.ndarray) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """(Ws, Z, G) at parameters th (offsets from the start)."""
        def pose(T0: np.ndarray, p: np.ndarray) -> np.ndarray:
            return make_pose(T0[:3, :3] @ matrix_from_rotvec(p[:3]), T0[:3, 3] + p[3:])
        m = len(self.Ws)
        Ws = [pose(W, th[6 * j:6 * j + 6]) for j, W in enumerate(self.Ws)]
        Z = pose(self.Z0, th[6 * m:6 * m + 6])
        g = th[6 * m + 6:] if self.g0 is None else self.g0 + th[6 * m + 6:]
        return Ws, Z, undistortion(self.model, g)

    def residuals(self, th: np.ndarray) -> np.ndarray:
        """Raw residuals (n, 6m): per body [rotation vector (rad), translation (mm)]."""
        Ws, Z, G = self.unpack(th)
        out = []
        Ms = self.moments or [None] * len(Ws)
        for W, N, M in zip(Ws, self.bodies, Ms, strict=True):
            out.append(body_residual(self.A, W, Z, undistort(N, G, self.model, M), False).r)
        return np.concatenate(out, axis=1)

    def raw_jacobian(self) -> np.ndarray:
        """Raw Jacobian (n, 6m, k) of :meth:`residuals` at θ = 0 (the start), analytically
        (the distortion's g by :meth:`_distortion_columns`).

        Per body j, E = W⁻¹ A⁻¹ Z Ñ (Ñ undistorted): the blocks of :func:`body_residual`
        for W and Z; the distortion's columns as :meth:`_distortion_columns` says."""
        k, m = self.n_params, len(self.Ws)
        Ws, Z, G = self.unpack(np.zeros(k))
        n = len(self.A)
        J = np.zeros((n, 6 * m, k))
        Ms = self.moments or [None] * m
        RAt = np.swapaxes(self.A[:, :3, :3], 1, 2)
        for j, (W, N, M) in enumerate(zip(Ws, self.bodies, Ms, strict=True)):
            Nt = undistort(N, G, self.model, M)
            br = body_residual(self.A, W, Z, Nt)
            assert br.dW is not None and br.dZ is not None
            r = 6 * j
            J[:, r:r + 6, r:r + 6] = br.dW
            J[:, r:r + 6, 6 * m:6 * m + 6] = br.dZ
            if k > 6 * (m + 1):
                WAZ = W[:3, :3].T[None] @ RAt @ Z[:3, :3][None]
                half = 0.5 * skew(br.r[:, :3])
                J[:, r:r + 6, 6 * (m + 1):] = self._distortion_columns(N, Nt, M, WAZ, half)
        return J

    def _distortion_columns(self, N: np.ndarray, Nt: np.ndarray, M: np.ndarray | None,
                            WAZ: np.ndarray, half: np.ndarray) -> np.ndarray:
        """∂r/∂g (n, 6, k_g) of one body, analytically. t(Ñ) = G t(N), so ∂t_E/∂g_i =
        R_Wᵀ R_Aᵀ R_Z (∂G/∂g_i) t(N). The orientation (not for "scale", which leaves it) is
        U = polar(F), F = G R_N M (F = G, U R_N without the tool's moment M): with
        S = Uᵀ F symmetric, dU = U [ω]× where ((tr S) I − S) ω = vee(Uᵀ dF − dFᵀ U) (from
        Uᵀ dF = [ω]× S + dS), dF = (∂G/∂g_i) R_N M; that turns R(Ñ) on the right by ω
        (by R_Nᵀ ω without M), and ∂φ/∂g_i = J_r⁻¹(φ) ω as for Z."""
        kg = DISTORTION_MODELS[self.model]
        n = len(N)
        out = np.zeros((n, 6, kg))
        dGs = [undistortion(self.model, np.eye(kg)[i]) - np.eye(3) for i in range(kg)]
        RN = N[:, :3, :3]
        for i, dG in enumerate(dGs):
            out[:, 3:, i] = np.einsum("nij,nj->ni", WAZ, N[:, :3, 3] @ dG.T)
        if self.model == "scale":
            return out
        G = self.unpack(np.zeros(self.n_params))[2]
        if M is None:
            U = np.broadcast_to(orthonormalize(G), (n, 3, 3))
            F = np.broadcast_to(G, (n, 3, 3))
        else:
            U, F = Nt[:, :3, :3], G[None] @ RN @ M
        S = np.swapaxes(U, 1, 2) @ F
        S = 0.5 * (S + np.swapaxes(S, 1, 2))
        Kinv = np.linalg.inv(np.trace(S, axis1=1, axis2=2)[:, None, None] * np.eye(3) - S)
        for i, dG in enumerate(dGs):
            dF = np.broadcast_to(dG, (n, 3, 3)) if M is None else dG[None] @ RN @ M
            K = np.swapaxes(U, 1, 2) @ dF
            K = K - np.swapaxes(K, 1, 2)
            w = np.einsum("nij,nj->ni", Kinv, np.stack([K[:, 2, 1], K[:, 0, 2], K[:, 1, 0]],
                                                        axis=1))
            if M is None:
                w = np.einsum("nji,nj->ni", RN, w)  # R_Nᵀ ω
            out[:, :3, i] = w + np.einsum("nij,nj->ni", half, w)
        return out

    def recentred(self, th: np.ndarray) -> Problem:
        """The same problem started at the parameters ``th`` (θ = 0 there)."""
        Ws, Z, G = self.unpack(th)
        return Problem(self.A, self.bodies, Ws, Z, self.model, g_of(self.model, G),
                       self.moments)

    def jacobian(self, th: np.ndarray, whiten: np.ndarray) -> np.ndarray:
        """Whitened Jacobian (n·6m, k) by central differences."""
        cols = []
        for j in range(len(th)):
            h = G_STEP if j >= 6 * (len(self.Ws) + 1) else STEPS[(j % 6) // 3]
            e = np.zeros_like(th)
            e[j] = h
            d = (self.residuals(th + e) - self.residuals(th - e)) / (2 * h)
            cols.append(whiten_residuals(whiten, d).ravel())
        return np.stack(cols, axis=1)


def whiten_residuals(whiten: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Whiten residuals r (n, q) with L⁻¹ (q, q) or per pose (n, q, q)."""
    if whiten.ndim == 2:
        return r @ whiten.T
    return np.einsum("nij,nj->ni", whiten, r)


def check_sigma(name: str, v: Any) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise CalibrationError(f"method 'ml': option {name} must be a number, got {v!r}") from None
    if not np.isfinite(f) or f <= 0:
        raise CalibrationError(f"method 'ml': option {name} must be finite and > 0, got {v!r}")
    return f


def tracker_covs(n: int, names: list[str], opts: dict[str, Any]) -> np.ndarray:
    """Tracker covariance per pose and body (n, m, 6, 6), body frame [rot rad; trans mm]."""
    m = len(names)
    if opts.get("spreads") is not None:
        sp = list(opts["spreads"])
        if len(sp) != n:
            raise CalibrationError(f"method 'ml': spreads has {len(sp)} entries for {n} poses")
        out = np.zeros((n, m, 6, 6))
        for i, rec in enumerate(sp):
            spread = rec.get("spread", rec)
            samples = rec.get("samples", {})
            for j, (nm, key) in enumerate(zip(names, ("B", "C"), strict=False)):
                s = spread.get(nm) or {}
                k = max(1.0, float(samples.get(key, 1)))
                st = max(float(s.get("trans_mm", 0.0)), 1e-4) / np.sqrt(3 * k)
                sr = max(np.radians(float(s.get("rot_deg", 0.0))), 1e-6) / np.sqrt(3 * k)
                out[i, j] = np.diag([sr * sr] * 3 + [st * st] * 3)
        return out
    if opts.get("tracker_cov") is not None:
        cov = np.asarray(opts["tracker_cov"], dtype=float)
        if cov.shape != (6, 6) or not np.all(np.isfinite(cov)) or \
                np.linalg.eigvalsh((cov + cov.T) / 2)[0] <= 0:
            raise CalibrationError("method 'ml': tracker_cov must be a finite positive-definite "
                                   "6×6 matrix (body frame, [rot rad; trans mm])")
    else:
        st = check_sigma("tracker_sigma_mm", opts["tracker_sigma_mm"])
        sr = np.radians(check_sigma("tracker_sigma_deg", opts["tracker_sigma_deg"]))
        cov = np.diag([sr * sr] * 3 + [st * st] * 3)
    return np.broadcast_to(cov, (n, m, 6, 6))


def robot_parts(Ws: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(Q_rot, Q_trans) (6m, 6m): the residual covariance of one pose per unit variance of the
    robot's rotation error (rad², per axis of its rotation vector, flange frame) and of its
    translation error (mm², per component): the flange error δ, shared by the bodies of a
    pose, carried through each W."""
    m = len(Ws)
    J = np.zeros((6 * m, 6))
    for j, W in enumerate(Ws):
        R, t = W[:3, :3], W[:3, 3]
        J[6 * j:6 * j + 3, :3] = R.T
        J[6 * j + 3:6 * j + 6, :3] = -R.T @ skew(t)
        J[6 * j + 3:6 * j + 6, 3:] = R.T
    return J[:, :3] @ J[:, :3].T, J[:, 3:] @ J[:, 3:].T


def tracker_part(tracker: np.ndarray) -> np.ndarray:
    """The tracker's residual covariance per pose (n, 6m, 6m) from its per-body covariances
    (n, m, 6, 6), block diagonal (the bodies' errors are independent)."""
    n, m = tracker.shape[:2]
    T = np.zeros((n, 6 * m, 6 * m))
    for j in range(m):
        T[:, 6 * j:6 * j + 6, 6 * j:6 * j + 6] = tracker[:, j]
    return T


def noise_covariance(Ws: list[np.ndarray], robot_sigma_mm: float, robot_sigma_rad: float,
                     tracker: np.ndarray) -> np.ndarray:
    """Residual covariance per pose (n, 6m, 6m): the robot's error δ (shared by the bodies of
    a pose) carried through each W, plus the tracker's (n, m, 6, 6) on the diagonal blocks."""
    Qr, Qt = robot_parts(Ws)
    return robot_sigma_rad ** 2 * Qr + robot_sigma_mm ** 2 * Qt + tracker_part(tracker)


def whitener(S: np.ndarray) -> np.ndarray:
    """L⁻¹ per pose for S = L Lᵀ (collapsed to one matrix when all poses share S)."""
    if np.all(S == S[0]):
        return np.linalg.inv(np.linalg.cholesky(S[0]))
    return np.linalg.inv(np.linalg.cholesky(S))


def covariance_from_jacobian(J: np.ndarray, what: str) -> np.ndarray:
    """(JᵀJ)⁻¹ through column scaling; CalibrationError when J is rank deficient."""
    d = np.linalg.norm(J, axis=0)
    d[d == 0] = 1.0
    Js = J / d
    w, V = np.linalg.eigh(Js.T @ Js)  # columns scaled to unit norm: well conditioned
    if w[0] < 1e-14 * w[-1]:
        raise CalibrationError(f"{what} is not identifiable from these poses (the Jacobian is "
                               "rank deficient): use more poses with more rotation and "
                               "translation diversity, or a simpler distortion model")
    return (V / w) @ V.T / np.outer(d, d)


def g_of(model: str, G: np.ndarray) -> np.ndarray:
    """The parameters g of an undistortion G (inverse of :func:`undistortion`)."""
    if model == "none":
        return np.zeros(0)
    if model == "scale":
        return np.array([G[0, 0] - 1.0])
    if model == "axis":
        return np.diag(G) - 1.0
    return np.array([G[i, j] - (i == j) for i, j in _SYM])


def parameter_names(bodies: int, model: str) -> list[str]:
    """Names (with units) of the parameters, in the covariance's order."""
    names = []
    for T in ["X", "Y"][:bodies] + ["Z"]:
        names += [f"{T}.r{a} (rad)" for a in "xyz"] + [f"{T}.t{a} (mm)" for a in "xyz"]
    k = DISTORTION_MODELS[model]
    if model == "scale":
        names.append("G.s (1)")
    elif k:
        names += [f"G.{i} (1)" for i in (("xx", "yy", "zz") if model == "axis" else
                                          ("xx", "yy", "zz", "xy", "xz", "yz"))]
    return names
