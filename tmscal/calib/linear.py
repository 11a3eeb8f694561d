"""QR24 and QR36: linear least squares for AX = ZB (and AY = ZC) with the robot side inverted.

Notation (DESIGN.md): A_i = base_from_flange, B_i = tracker_from_marker,
C_i = tracker_from_probe, X = flange_from_marker, Y = flange_from_probe,
Z = base_from_tracker; 4×4, mm.

Robot side inverted (seed 000, after Ernst et al. 2012): A_i⁻¹ Z B_i = X. With R, t the
rotation and translation of A_i⁻¹ and the unknowns' top 3×4 blocks vectorised column-major
(vec M[3·col + row] = M[row, col]), each pose contributes 12 rows

    [B_iᵀ ⊗ R  | −I₁₂] · [vec Z; vec X] = [0₉; −t]

and QR36 stacks the marker and probe rows over w = [vec Z; vec X; vec Y] ∈ ℝ³⁶ (the paper's
order), 24 rows per pose. The unknowns are general 3×4 matrices ("non-orthogonal"); they
absorb tracker scale and shear.

Solving. ``design_matrix`` builds the dense 12n × 24 / 24n × 36 system (for tests and for
users who want it). The solvers exploit its structure instead: X (and Y) enter every block
through −I₁₂, so for a fixed Z the least-squares X is the mean over poses. Projecting X and
Y out (variable projection) leaves a (12·bodies·n) × 12 problem in vec Z alone, built from
the pose-wise centred Kronecker blocks and solved by Householder QR; X and Y then follow in
closed form. This is the same minimiser as the dense QR, at a fraction of the cost.
"""

from __future__ import annotations

import numpy as np

from ..errors import CalibrationError
from ..geometry import invert, make_pose, orthonormalize

__all__ = [
    "kron_blocks",
    "design_matrix",
    "solve_linear",
    "resolve_translations",
    "vec34",
    "unvec34",
]


def vec34(M: np.ndarray) -> np.ndarray:
    """vec of the top 3×4 block of 4×4 matrices (…, 4, 4), column-major → (…, 12)."""
    M = np.asarray(M, dtype=np.float64)
    return np.swapaxes(M[..., :3, :], -1, -2).reshape(M.shape[:-2] + (12,))


def unvec34(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`vec34`: (…, 12) → 4×4 with last row [0, 0, 0, 1]."""
    v = np.asarray(v, dtype=np.float64)
    top = np.swapaxes(v.reshape(v.shape[:-1] + (4, 3)), -1, -2)
    out = np.zeros(v.shape[:-1] + (4, 4))
    out[..., :3, :] = top
    out[..., 3, 3] = 1.0
    return out


def kron_blocks(A: np.ndarray, N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose blocks of the robot-side-inverted system for one body.

    Returns K (n, 12, 12) = N_iᵀ ⊗ R_i and r (n, 12) = [0₉; −t_i], with R_i, t_i from A_i⁻¹,
    so that K_i vec Z − vec X = r_i holds exactly for the true Z, X (N = B or C, 4×4 mm).
    """
    Ainv = invert(A)
    R = Ainv[:, :3, :3]
    t = Ainv[:, :3, 3]
    n = R.shape[0]
    # (Nᵀ ⊗ R)[3a + b, 3c + d] = Nᵀ[a, c] R[b, d] = N[c, a] R[b, d]
    K = np.einsum("nca,nbd->nabcd", N, R).reshape(n, 12, 12)
    r = np.zeros((n, 12))
    r[:, 9:] = -t
    return K, r


def design_matrix(A: np.ndarray, *bodies: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The dense system D w = b of QR24 (one body: 12n × 24, w = [vec Z; vec X]) or QR36
    (two bodies: 24n × 36, w = [vec Z; vec X; vec Y]); rows ordered pose by pose, marker
    block then probe block."""
    n = A.shape[0]
    m = len(bodies)
    D = np.zeros((n, m, 12, 12 * (m + 1)))
    b = np.zeros((n, m, 12))
    for j, N in enumerate(bodies):
        K, r = kron_blocks(A, N)
        D[:, j, :, :12] = K
        D[:, j, :, 12 * (j + 1):12 * (j + 2)] = -np.eye(12)
        b[:, j] = r
    return D.reshape(n * m * 12, 12 * (m + 1)), b.reshape(-1)


def _check_diversity(A: np.ndarray) -> None:
    """Raise CalibrationError when the robot rotations give no unique solution: fewer than
    two distinct rotation axes among the relative motions A_0⁻¹ A_i."""
    R = A[:, :3, :3]
    rel = np.swapaxes(R[0], -1, -2)[None] @ R[1:]
    w = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0],
                  rel[:, 1, 0] - rel[:, 0, 1]], axis=1) / 2.0  # sin(θ)·axis
    s = np.linalg.svd(w, compute_uv=False) if len(w) else np.zeros(1)
    if len(s) < 2 or s[0] < 1e-6 or s[1] < 1e-6 * max(1.0, s[0]) or s[1] < 1e-9:
        raise CalibrationError(
            "the robot poses lack rotation diversity: all relative rotations share one axis "
            "(or there are none); AX = ZB then has no unique solution. Use poses rotated about "
            "at least two non-parallel axes.")


def solve_linear(A: np.ndarray, *bodies: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Least-squares Z and one X per body (general 3×4, as 4×4 with last row 0001).

    ``A`` (n, 4, 4) base_from_flange; ``bodies`` one or two arrays (n, 4, 4) of
    tracker_from_body (mm). One body is QR24, two bodies QR36 (shared Z). Returns
    (Z_raw, [X_raw, (Y_raw)]) minimising the stacked residual of :func:`design_matrix`.
    """
    n = A.shape[0]
    if n < 3:
        raise CalibrationError(f"need at least 3 poses, got {n}")
    _check_diversity(A)
    blocks = [kron_blocks(A, N) for N in bodies]
    rows, rhs = [], []
    for K, r in blocks:
        rows.append((K - K.mean(axis=0)).reshape(-1, 12))
        rhs.append((r - r.mean(axis=0)).reshape(-1))
    M = np.concatenate(rows)
    y = np.concatenate(rhs)
    # column scaling (mm vs unitless) keeps the triangular solve well conditioned
    scale = np.linalg.norm(M, axis=0)
    scale[scale == 0] = 1.0
    Q, Rq = np.linalg.qr(M / scale)
    d = np.abs(np.diag(Rq))
    if d.min() < 1e-10 * d.max():
        raise CalibrationError("the linear system is rank deficient (degenerate poses: too "
                               "little rotation or translation diversity)")
    z = np.linalg.solve(Rq, Q.T @ y) / scale
    Z = unvec34(z)
    Xs = [unvec34(K.mean(axis=0) @ z - r.mean(axis=0)) for K, r in blocks]
    return Z, Xs


def resolve_translations(A: np.ndarray, bodies: list[np.ndarray], R_Z: np.ndarray,
                         R_bodies: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Orthonormal variant: with rotations fixed (R_Z and one R per body, 3×3), solve the
    translations t_Z, t_X(, t_Y) in mm by linear least squares over
    R_Ai t_X − t_Z = R_Z t_Bi − t_Ai (one 3-row block per pose and body).
    Returns rigid (Z, [X, (Y)]) 4×4 mm."""
    n = A.shape[0]
    m = len(bodies)
    RA = A[:, :3, :3]
    tA = A[:, :3, 3]
    D = np.zeros((n, m, 3, 3 * (m + 1)))
    b = np.zeros((n, m, 3))
    for j, N in enumerate(bodies):
        D[:, j, :, :3] = -np.eye(3)
        D[:, j, :, 3 * (j + 1):3 * (j + 2)] = RA
        b[:, j] = (R_Z @ N[:, :3, 3].T).T - tA
    sol, *_ = np.linalg.lstsq(D.reshape(-1, 3 * (m + 1)), b.reshape(-1), rcond=None)
    Z = make_pose(R_Z, sol[:3])
    Xs = [make_pose(R_bodies[j], sol[3 * (j + 1):3 * (j + 2)]) for j in range(m)]
    return Z, Xs


def orthonormal_from_raw(A: np.ndarray, bodies: list[np.ndarray], Z_raw: np.ndarray,
                         X_raws: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Project each raw 3×3 block to SO(3) (SVD with det fix) and re-solve the translations."""
    return resolve_translations(A, bodies, orthonormalize(Z_raw[:3, :3]),
                                [orthonormalize(X[:3, :3]) for X in X_raws])
