"""QR24 and QR36: linear least squares for AX = ZB (and AY = ZC) with the robot side inverted.

Notation (README.md, docs/conventions.md): A_i = base_from_flange, B_i = tracker_from_marker,
C_i = tracker_from_probe, X = flange_from_marker, Y = flange_from_probe,
Z = base_from_tracker; 4×4, mm.

Robot side inverted (Wang et al. 2018, after Ernst et al. 2012): A_i⁻¹ Z B_i = X. With R, t the
rotation and translation of A_i⁻¹ and the unknowns' top 3×4 blocks vectorised column-major
(vec M[3·col + row] = M[row, col]), each pose contributes 12 rows

    [B_iᵀ ⊗ R  | −I₁₂] · [vec Z; vec X] = [0₉; −t]

and QR36 stacks the marker and probe rows over w = [vec Z; vec X; vec Y] ∈ ℝ³⁶ (the paper's
order), 24 rows per pose. The unknowns are general 3×4 matrices ("non-orthogonal"); they
absorb tracker scale and shear.

Solving. ``design_matrix`` builds the dense 12n × 24 / 24n × 36 system (for tests and for
users who want it); the paper solves it by QR. The solvers here compute the same
least-squares minimiser from the system's structure: X (and Y) enter every block through
−I₁₂, so for a fixed Z the least-squares X is the mean over poses; projecting X and Y out
leaves 12 unknowns, whose normal equations are sums of 4×4 and 12×12 terms
(K_iᵀK_i = (N_i N_iᵀ) ⊗ I₃ because R_i is orthonormal). An exact change of variables
(centring the flange and tracker translations) keeps those normal equations well
conditioned, so the result matches the dense QR to rounding (checked in the tests) at a
small fraction of its cost.
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
    "check_rotation_diversity",
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


def check_rotation_diversity(A: np.ndarray) -> None:
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


_I3 = np.eye(3)


def _body_terms(R: np.ndarray, t: np.ndarray, N: np.ndarray):
    """Sufficient statistics of one body's blocks K_i = N_iᵀ ⊗ R_i, r_i = [0₉; −t_i]
    (R, t of A_i⁻¹): K̄ (12×12), r̄ (12), G_b = Σ (K_i − K̄)ᵀ(K_i − K̄) (12×12) and
    h_b = Σ (K_i − K̄)ᵀ(r_i − r̄) (12). Uses K_iᵀK_i = (N_i N_iᵀ) ⊗ I₃ (R_i orthonormal) and
    K_iᵀ r_i = vec(−R_iᵀ t_i n_iᵀ), n_i the last column of N_i, so nothing of size n × 144 is
    ever formed."""
    n = len(R)
    # K̄[3a + b, 3c + d] = mean N[c, a] R[b, d]
    Kbar = np.tensordot(N, R, axes=([0], [0])).transpose(1, 2, 0, 3).reshape(12, 12) / n
    S = np.tensordot(N, N, axes=([0, 2], [0, 2]))
    rbar = np.zeros(12)
    rbar[9:] = -t.mean(axis=0)
    Rt_t = (np.swapaxes(R, 1, 2) @ t[:, :, None])[:, :, 0]
    sum_Kr = -(N[:, :, 3].T @ Rt_t).reshape(12)  # vec of Σ −Rᵀt n4ᵀ
    G = (S[:, None, :, None] * _I3[None, :, None, :]).reshape(12, 12) - n * Kbar.T @ Kbar
    h = sum_Kr - n * Kbar.T @ rbar
    return Kbar, rbar, G, h


def solve_linear(A: np.ndarray, *bodies: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Least-squares Z and one X per body (general 3×4, as 4×4 with last row 0001).

    ``A`` (n, 4, 4) base_from_flange; ``bodies`` one or two arrays (n, 4, 4) of
    tracker_from_body (mm). One body is QR24, two bodies QR36 (shared Z). Returns
    (Z_raw, [X_raw, (Y_raw)]), the minimiser of ‖D w − b‖ for :func:`design_matrix`.

    X (and Y) are projected out in closed form; the remaining 12 unknowns of Z come from the
    column-scaled normal equations of the projected system, after an exact change of variables
    that centres the flange and tracker translations (so the ~1.5 m tracker distance does not
    enter the normal equations). The result agrees with a dense Householder QR of D to
    rounding (the tests check this).
    """
    n = A.shape[0]
    if n < 3:
        raise CalibrationError(f"need at least 3 poses, got {n}")
    check_rotation_diversity(A)
    # Exact reparametrisation for conditioning: with S0, T0 pure translations to the mean
    # flange and mean tracked-body positions, A' = S0⁻¹A, N' = T0⁻¹N and Z' = S0⁻¹ Z T0 give
    # the very same residuals A'⁻¹ Z' N' − X = A⁻¹ Z N − X, hence the same minimiser, but
    # the normal equations no longer carry the ~1.5 m tracker distance.
    s0 = A[:, :3, 3].mean(axis=0)
    t0 = np.mean([N[:, :3, 3].mean(axis=0) for N in bodies], axis=0)
    A = A.copy()
    A[:, :3, 3] -= s0
    bodies = tuple(_shifted(N, t0) for N in bodies)
    Ainv = invert(A)
    R, t = Ainv[:, :3, :3], Ainv[:, :3, 3]
    terms = [_body_terms(R, t, N) for N in bodies]
    G = sum(tm[2] for tm in terms)
    h = sum(tm[3] for tm in terms)
    d = np.sqrt(np.abs(np.diag(G)))
    d[d == 0] = 1.0
    Gs = G / np.outer(d, d)
    w = np.linalg.eigvalsh(Gs)
    if w[0] < 1e-13 * w[-1]:
        raise CalibrationError("the linear system is rank deficient (degenerate poses: too "
                               "little rotation or translation diversity)")

    z = np.linalg.solve(Gs, h / d) / d
    Xs = [unvec34(Kbar @ z - rbar) for Kbar, rbar, _, _ in terms]
    Z = unvec34(z)
    Z[:3, 3] += s0 - Z[:3, :3] @ t0  # Z = S0 Z' T0⁻¹
    return Z, Xs


def _shifted(N: np.ndarray, t0: np.ndarray) -> np.ndarray:
    """T0⁻¹ N for a pure translation T0 by t0 (mm): the translations minus t0."""
    out = N.copy()
    out[:, :3, 3] -= t0
    return out


def resolve_translations(A: np.ndarray, bodies: list[np.ndarray], R_Z: np.ndarray,
                         R_bodies: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Orthonormal variant: with rotations fixed (R_Z and one R per body, 3×3), solve the
    translations t_Z, t_X(, t_Y) in mm by linear least squares over
    R_Ai t_X − t_Z = R_Z t_Bi − t_Ai (one 3-row block per pose and body).
    Returns rigid (Z, [X, (Y)]) 4×4 mm. Normal equations (3(m+1) unknowns); the blocks
    R_Aiᵀ R_Ai = I keep them small and well conditioned."""
    n = A.shape[0]
    m = len(bodies)
    RA = A[:, :3, :3]
    tA = A[:, :3, 3]
    sumR = RA.sum(axis=0)
    k = 3 * (m + 1)
    G = np.zeros((k, k))
    G[:3, :3] = m * n * np.eye(3)
    for j in range(m):
        s = slice(3 * (j + 1), 3 * (j + 2))
        G[:3, s] = -sumR
        G[s, :3] = -sumR.T
        G[s, s] = n * np.eye(3)
    rhs_b = [(R_Z @ N[:, :3, 3].T).T - tA for N in bodies]

    def normal_rhs(res: list[np.ndarray]) -> np.ndarray:
        v = np.zeros(k)
        for j, b in enumerate(res):
            v[:3] -= b.sum(axis=0)
            v[3 * (j + 1):3 * (j + 2)] = np.tensordot(RA, b, axes=([0, 1], [0, 1]))
        return v

    u = np.linalg.solve(G, normal_rhs(rhs_b))
    Z = make_pose(R_Z, u[:3])
    Xs = [make_pose(R_bodies[j], u[3 * (j + 1):3 * (j + 2)]) for j in range(m)]
    return Z, Xs


def orthonormal_from_raw(A: np.ndarray, bodies: list[np.ndarray], Z_raw: np.ndarray,
                         X_raws: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Project each raw 3×3 block to SO(3) (SVD with det fix) and re-solve the translations."""
    Rs = orthonormalize(np.stack([Z_raw[:3, :3]] + [X[:3, :3] for X in X_raws]))
    return resolve_translations(A, bodies, Rs[0], list(Rs[1:]))
