"""The classic rigid methods beside QR24/QR36: QUAT, SHAH, LI and handheld coil calibration.

Frames (docs/conventions.md): A = base_from_flange, B = tracker_from_marker,
C = tracker_from_probe, X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker;
A X = Z B and A Y = Z C; 4×4 mm. Every method here returns rigid X, Y, Z (``X_raw = X`` …),
except ``handheld``, whose raw matrices are those of its base method.

- ``quat``: Dornaika & Horaud (1998). Rotations from unit quaternions, a_i ⊗ x = z ⊗ b_i, as
  the top singular pair of Σ s_i Q(a_i)ᵀ W(b_i) (the closed form of their 8×8 eigenproblem);
  the quaternion signs s_i are made consistent from the sign-free rank-one fit of
  Σ (xᵀ K_i z)² first. Translations by linear least squares. ``refine=True`` (default) then
  minimises Σ ‖R_Ai R_X − R_Z R_Bi‖²_F + Σ ‖R_Ai t_X + t_Ai − R_Z t_Bi − t_Z‖² / s² over
  SO(3) × ℝ³ (s = ``trans_scale_mm``, default 100 mm) with scipy's least_squares.
- ``shah``: Shah (2013), as OpenCV's ``calibrateRobotWorldHandEye`` (CALIB_ROBOT_WORLD_HAND_EYE_
  SHAH) implements it: R_X, R_Z from the top singular pair of Σ R_Bi ⊗ R_Ai, then a 3n × 6 least
  squares for the translations. Two bodies: the SVD of [Σ R_Bi ⊗ R_Ai, Σ R_Ci ⊗ R_Ai] (9 × 18)
  gives one R_Z and R_X, R_Y together; the translations are solved jointly with one t_Z.
- ``li``: Li, Wang & Wu (2010), as OpenCV's LI: one 12n × 24 linear system in vec R_X, vec R_Z,
  t_X, t_Z (no side inverted), solved by least squares (QR; OpenCV uses the SVD, the same
  minimiser at full rank); the rotations are orthonormalised
  and, as in OpenCV, the translations are kept (``resolve=True`` re-solves them with the
  rotations fixed). Two bodies: the 24n × 36 system with a shared Z. Its rows are QR24's rows
  (docs/methods.md) times R_Ai per pose, an orthogonal map, so the least-squares minimiser is
  the same: ``resolve=True`` gives QR24's (QR36's) orthonormal solution, and OpenCV's kept
  translations are what costs LI its accuracy.
- ``handheld``: X, Z from a marker-only calibration (``base``, default ``qr24``) and
  Y = X · B_a⁻¹ · C_a from one extra measurement (``handheld_B``, ``handheld_C``) with the probe
  held at the coil centre (the comparison of Wang et al. 2018).

OpenCV solves cTw · wTb = cTg · gTb; with A_i as world2cam and B_i as base2gripper it returns
base2world = X and gripper2cam = Z (the tests compare ours with it on the same poses).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import least_squares

from ..errors import CalibrationError
from ..geometry import (
    RIGID_TOL_DEFAULT,
    check_poses,
    invert,
    make_pose,
    matrix_from_quaternion,
    matrix_from_rotvec,
    quaternion_from_matrix,
    right_jacobian,
    skew,
)
from .calibration import Applied, Calibration
from .linear import check_rotation_diversity, resolve_translations
from .methods import get_method, register_method

__all__ = ["check_rotations", "rigid_calibration", "normalize_rotation", "quat_rotations"]


def check_rotations(A: np.ndarray) -> None:
    """The checks QR36 makes before solving, with its wording: at least 3 poses and relative
    robot rotations about at least two non-parallel axes (CalibrationError otherwise)."""
    if len(A) < 3:
        raise CalibrationError(f"need at least 3 poses, got {len(A)}")
    check_rotation_diversity(A)


def bodies_of(A: np.ndarray, B: np.ndarray, C: np.ndarray | None) -> list[np.ndarray]:
    """The tracked bodies to solve: [B] or [B, C]."""
    check_rotations(A)
    return [B] if C is None else [B, C]


def rigid_calibration(method: str, A: np.ndarray, Z: np.ndarray, Xs: list[np.ndarray],
                      orthonormal: bool, **extra: Any) -> Calibration:
    """A Calibration of rigid X(, Y), Z: the raw matrices are the rigid ones."""
    X = Xs[0]
    Y = Xs[1] if len(Xs) > 1 else None
    return Calibration(method, len(A), X=X, Z=Z, X_raw=X.copy(), Z_raw=Z.copy(), Y=Y,
                       Y_raw=None if Y is None else Y.copy(),
                       applied=Applied.ORTHONORMAL if orthonormal else Applied.RAW, extra=extra)


def normalize_rotation(M: np.ndarray) -> np.ndarray:
    """OpenCV's ``normalizeRotation``: scale to |det| = 1 (the sign of det kept positive), then
    the nearest orthogonal U Vᵀ, with a reflection flipped by diag(1, 1, −1)."""
    det = np.linalg.det(M)
    if abs(det) < np.finfo(np.float32).eps:
        raise CalibrationError("rotation normalisation failed: the estimated 3×3 block is "
                               "singular (degenerate poses)")
    M = np.cbrt(np.sign(det) / abs(det)) * M
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    return R


# --- Shah (2013) ---------------------------------------------------------------------------

@register_method("shah")
def solve_shah(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, orthonormal: bool
               ) -> Calibration:
    """Shah (2013), Kronecker closed form as OpenCV implements it; shared Z for two bodies."""
    bodies = bodies_of(A, B, C)
    RA = A[:, :3, :3]
    T = np.hstack([np.einsum("nab,ncd->acbd", N[:, :3, :3], RA).reshape(9, 9)
                   for N in bodies])
    U, _, Vt = np.linalg.svd(T)
    R_Z = normalize_rotation(U[:, 0].reshape(3, 3, order="F"))
    R_Xs = [normalize_rotation(Vt[0, 9 * j:9 * (j + 1)].reshape(3, 3, order="F"))
            for j in range(len(bodies))]
    Z, Xs = resolve_translations(A, bodies, R_Z, R_Xs)
    return rigid_calibration("shah", A, Z, Xs, orthonormal)


# --- Li, Wang & Wu (2010) ----------------------------------------------------------------

def li_system(A: np.ndarray, bodies: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Li, Wang & Wu's linear system (OpenCV's layout, row-major vec): unknowns
    [vec R_X (, vec R_Y), vec R_Z, t_X (, t_Y), t_Z]; 12 rows per pose and body."""
    n, m = len(A), len(bodies)
    k = 12 * (m + 1)
    RA, tA = A[:, :3, :3], A[:, :3, 3]
    I3 = np.eye(3)
    M = np.zeros((n, m, 12, k))
    b = np.zeros((n, m, 12))
    rz, tz = 9 * m, 9 * (m + 1) + 3 * m
    for j, N in enumerate(bodies):
        M[:, j, :9, 9 * j:9 * (j + 1)] = np.einsum("nab,cd->nacbd", RA, I3).reshape(n, 9, 9)
        M[:, j, :9, rz:rz + 9] = -np.einsum("ab,ndc->nacbd", I3, N[:, :3, :3]).reshape(n, 9, 9)
        M[:, j, 9:, rz:rz + 9] = np.einsum("ab,nc->nabc", I3, N[:, :3, 3]).reshape(n, 3, 9)
        tj = 9 * (m + 1) + 3 * j
        M[:, j, 9:, tj:tj + 3] = -RA
        M[:, j, 9:, tz:tz + 3] = I3
        b[:, j, 9:] = tA
    return M.reshape(n * m * 12, k), b.reshape(-1)


@register_method("li")
def solve_li(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, orthonormal: bool,
             resolve: bool = False) -> Calibration:
    """Li, Wang & Wu (2010) as OpenCV implements it (translations kept unless ``resolve``)."""
    bodies = bodies_of(A, B, C)
    m = len(bodies)
    M, b = li_system(A, bodies)
    Qm, Rm = np.linalg.qr(M)  # full column rank after the diversity check
    if abs(np.diag(Rm)).min() <= 1e-12 * abs(np.diag(Rm)).max():
        raise CalibrationError("the linear system is rank deficient (degenerate poses: too "
                               "little rotation or translation diversity)")
    w = np.linalg.solve(Rm, Qm.T @ b)
    R_Xs = [normalize_rotation(w[9 * j:9 * (j + 1)].reshape(3, 3)) for j in range(m)]
    R_Z = normalize_rotation(w[9 * m:9 * (m + 1)].reshape(3, 3))
    if resolve:
        Z, Xs = resolve_translations(A, bodies, R_Z, R_Xs)
    else:
        t0 = 9 * (m + 1)
        Xs = [make_pose(R_Xs[j], w[t0 + 3 * j:t0 + 3 * j + 3]) for j in range(m)]
        Z = make_pose(R_Z, w[t0 + 3 * m:t0 + 3 * m + 3])
    return rigid_calibration("li", A, Z, Xs, orthonormal, resolved_translations=resolve)


# --- Dornaika & Horaud (1998) --------------------------------------------------------------

def _left(q: np.ndarray) -> np.ndarray:
    """Q(q) (…, 4, 4) with q ⊗ p = Q(q) p (scalar-first quaternions)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([np.stack([w, -x, -y, -z], -1), np.stack([x, w, -z, y], -1),
                     np.stack([y, z, w, -x], -1), np.stack([z, -y, x, w], -1)], -2)


def _right(q: np.ndarray) -> np.ndarray:
    """W(q) (…, 4, 4) with p ⊗ q = W(q) p (scalar-first quaternions)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([np.stack([w, -x, -y, -z], -1), np.stack([x, w, z, -y], -1),
                     np.stack([y, -z, w, x], -1), np.stack([z, y, -x, w], -1)], -2)


def quat_rotations(RA: np.ndarray, RNs: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Dornaika & Horaud's closed-form rotations: R_Z and one R per body (3×3) from the
    quaternion equations a_i ⊗ x = z ⊗ n_i (a shared z over the bodies).

    A quaternion's sign is arbitrary, so the per-pose terms K_i = Q(a_i)ᵀ W(n_i) are first
    given consistent signs s_i: a sign-free rank-one fit of Σ (xᵀ K_i z)² (16 × 16, the first
    body) gives z₀, the top eigenvector of Σ (K_i z₀)(K_i z₀)ᵀ gives x₀ per body, and
    s_i = sign(x₀ᵀ K_i z₀). Then x, z are the top singular pair of Σ s_i K_i (stacked over the
    bodies, each x normalised), the minimiser of Σ ‖Q(a_i) x − W(n_i) z‖² over unit x, z."""
    a = quaternion_from_matrix(RA)
    Ks = [np.swapaxes(_left(a), -1, -2) @ _right(quaternion_from_matrix(RN)) for RN in RNs]
    kv = Ks[0].reshape(len(RA), 16)  # xᵀ K z = (x ⊗ z) · vec_row(K)
    _, V = np.linalg.eigh(kv.T @ kv)
    z0 = np.linalg.svd(V[:, -1].reshape(4, 4))[2][0]
    Cs = []
    for K in Ks:
        v = K @ z0
        x0 = np.linalg.eigh(v.T @ v)[1][:, -1]
        s = np.sign(v @ x0)
        Cs.append(np.einsum("n,nab->ab", np.where(s == 0, 1.0, s), K))
    U, _, Vt = np.linalg.svd(np.vstack(Cs))
    xs = U[:, 0].reshape(len(Ks), 4)
    R_Xs = [matrix_from_quaternion(x / np.linalg.norm(x)) for x in xs]
    return matrix_from_quaternion(Vt[0]), R_Xs


def _refine(A: np.ndarray, bodies: list[np.ndarray], Z: np.ndarray, Xs: list[np.ndarray],
            trans_scale_mm: float) -> tuple[np.ndarray, list[np.ndarray], dict[str, Any]]:
    """Nonlinear least squares over (R, t) of Z and each X: rotation residuals
    R_Ai R_X − R_Z R_Bi (Frobenius), translation residuals (R_Ai t_X + t_Ai − R_Z t_Bi − t_Z) / s.
    Rotations are updated as R exp(ŵ) from the start; scipy least_squares (trust region) with
    the analytic Jacobian."""
    m, n = len(bodies), len(A)
    RA, tA = A[:, :3, :3], A[:, :3, 3]
    R0 = np.stack([Z[:3, :3]] + [X[:3, :3] for X in Xs])
    k = 3 * (m + 1)

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return R0 @ matrix_from_rotvec(p[:k].reshape(m + 1, 3)), p[k:].reshape(m + 1, 3)

    def residuals(p: np.ndarray) -> np.ndarray:
        R, t = unpack(p)
        out = []
        for j, N in enumerate(bodies):
            out.append((RA @ R[j + 1] - R[0] @ N[:, :3, :3]).reshape(-1))
            tr = RA @ t[j + 1] + tA - N[:, :3, 3] @ R[0].T - t[0]
            out.append(tr.reshape(-1) / trans_scale_mm)
        return np.concatenate(out)

    def jacobian(p: np.ndarray) -> np.ndarray:
        R, _ = unpack(p)
        # dR_k/dw_k[a] = R_k hat(J_r(w_k)[:, a])
        dR = [R[i] @ skew(right_jacobian(p[3 * i:3 * i + 3]).T) for i in range(m + 1)]
        blocks = []
        for j, N in enumerate(bodies):
            Jr = np.zeros((n, 3, 3, 2 * k))
            Jr[..., 3 * (j + 1):3 * (j + 2)] = np.einsum("nab,cbd->nadc", RA, dR[j + 1])
            Jr[..., 0:3] = -np.einsum("cab,nbd->nadc", dR[0], N[:, :3, :3])
            Jt = np.zeros((n, 3, 2 * k))
            Jt[..., k + 3 * (j + 1):k + 3 * (j + 2)] = RA
            Jt[..., k:k + 3] = -np.eye(3)
            Jt[..., 0:3] = -np.einsum("cab,nb->nac", dR[0], N[:, :3, 3])
            blocks += [Jr.reshape(9 * n, 2 * k), Jt.reshape(3 * n, 2 * k) / trans_scale_mm]
        return np.vstack(blocks)

    p0 = np.concatenate([np.zeros(k), np.stack([Z[:3, 3]] + [X[:3, 3] for X in Xs]).ravel()])
    res = least_squares(residuals, p0, jac=jacobian, method="trf", x_scale="jac")
    R, t = unpack(res.x)
    poses = [make_pose(R[i], t[i]) for i in range(m + 1)]
    return poses[0], poses[1:], {"refine_nfev": int(res.nfev), "refine_status": int(res.status)}


@register_method("quat")
def solve_quat(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, orthonormal: bool,
               refine: bool = True, trans_scale_mm: float = 100.0) -> Calibration:
    """Dornaika & Horaud (1998): closed form (``refine=False``) or refined (default)."""
    do_refine = bool(refine)
    if not trans_scale_mm > 0:
        raise CalibrationError(f"quat: trans_scale_mm must be > 0, got {trans_scale_mm}")
    bodies = bodies_of(A, B, C)
    R_Z, R_Xs = quat_rotations(A[:, :3, :3], [N[:, :3, :3] for N in bodies])
    Z, Xs = resolve_translations(A, bodies, R_Z, R_Xs)
    extra: dict[str, Any] = {"refined": do_refine}
    if do_refine:
        Z, Xs, info = _refine(A, bodies, Z, Xs, trans_scale_mm)
        extra.update(info)
    return rigid_calibration("quat", A, Z, Xs, orthonormal, **extra)


# --- handheld coil calibration -------------------------------------------------------------

@register_method("handheld")
def solve_handheld(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, orthonormal: bool,
                   handheld_B: Any = None, handheld_C: Any = None, base: str = "qr24"
                   ) -> Calibration:
    """X, Z from ``base`` on the marker alone; Y = X · B_a⁻¹ · C_a from one measurement with the
    probe held at the coil centre (``handheld_B``, ``handheld_C``: 4×4 mm tracker poses)."""
    if handheld_B is None or handheld_C is None:
        raise CalibrationError("handheld needs the extra measurement with the probe at the coil "
                               "centre: options handheld_B and handheld_C (4×4 mm)")
    base = str(base).lower()
    if base == "handheld":
        raise CalibrationError("handheld: option base cannot be 'handheld' itself")
    base_solver = get_method(base, "handheld: option base")
    try:
        Ba, Ca = (check_poses(np.asarray(M, dtype=np.float64)[None], name,
                              tol=RIGID_TOL_DEFAULT)[0]
                  for M, name in ((handheld_B, "handheld_B"), (handheld_C, "handheld_C")))
    except ValueError as e:
        raise CalibrationError(str(e)) from None
    cal = base_solver(A, B, None, orthonormal)
    rel = invert(Ba) @ Ca
    cal.Y = cal.X @ rel
    cal.Y_raw = cal.X_raw @ rel
    cal.Y[3] = cal.Y_raw[3] = (0.0, 0.0, 0.0, 1.0)
    cal.method = "handheld"
    cal.extra["base"] = base
    return cal
