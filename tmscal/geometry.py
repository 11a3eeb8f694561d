"""SE(3) / SO(3) helpers.

Conventions (the one page of them; see also ``docs/conventions.md``):

* A pose is a 4×4 homogeneous matrix, float64, translations in **millimetres**. A batch of
  poses is an array of shape (n, 4, 4). ``a_from_b`` maps coordinates in frame b into frame a,
  so ``compose(a_from_b, b_from_c) == a_from_c``.
* Angles inside tmscal are radians; degrees appear only at the edges and are named ``_deg``.
* Quaternions are scalar first, (q0, qx, qy, qz), as NDI sends them.
* Rotation vectors (UR) are axis × angle in radians.
* DENSO P-type angles are degrees, R = Rz(rz) · Ry(ry) · Rx(rx) (rotations about the fixed
  base axes, RX first).

All functions are pure and accept single poses or batches where stated.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

__all__ = [
    "check_pose",
    "check_poses",
    "make_pose",
    "compose",
    "invert",
    "rotation",
    "translation",
    "orthonormalize",
    "matrix_from_quaternion",
    "quaternion_from_matrix",
    "matrix_from_rotvec",
    "rotvec_from_matrix",
    "right_jacobian",
    "right_jacobian_inv",
    "pose_from_rotvec",
    "rotvec_pose_from_matrix",
    "matrix_from_denso_p",
    "denso_p_from_matrix",
    "rot_x",
    "rot_y",
    "rot_z",
    "skew",
    "rotation_angle",
    "angle_between",
    "rotation_mean",
    "pose_mean",
    "random_rotation",
    "absolute_orientation",
    "RIGID_TOL_DEFAULT",
]

#: Rigidity tolerance of :func:`check_poses` and the calibration inputs: the largest accepted
#: entry of |R Rᵀ − I| and of |det R − 1|. Poses that went through a quaternion, a rotation
#: vector, Euler angles or a JSON round trip are rigid to ~1e-15; 1e-5 also admits matrices
#: printed with six or more decimals.
RIGID_TOL_DEFAULT = 1e-5
_OFF_L = np.array([0, 1, 2, 0, 1, 2, 3, 4, 5])
_OFF_R = np.array([3, 4, 5, 6, 7, 8, 6, 7, 8])


def check_poses(poses: ArrayLike, name: str = "poses", rigid: bool = True,
                tol: float = RIGID_TOL_DEFAULT) -> Array:
    """Validate and return a batch of 4×4 poses as float64, shape (n, 4, 4).

    A single 4×4 is promoted to (1, 4, 4). Raises ``ValueError`` naming ``name`` and quoting
    the actual shape when the array is not (n, 4, 4), holds NaN/inf, has a last row other
    than [0, 0, 0, 1] or (when ``rigid``) a rotation block that is not orthonormal with
    determinant +1 within ``tol``.
    """
    a = np.asarray(poses, dtype=np.float64)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3 or a.shape[1:] != (4, 4):
        raise ValueError(f"{name}: expected 4×4 poses of shape (n, 4, 4), got shape {a.shape}")
    if not np.isfinite(a).all():
        bad = ~np.isfinite(a).all(axis=(1, 2))
        raise ValueError(f"{name}: pose {int(np.argmax(bad))} contains NaN or infinity")
    last = np.abs(a[:, 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=1)
    if (last > 1e-9).any():
        i = int(np.argmax(last > 1e-9))
        raise ValueError(f"{name}: pose {i} has last row {a[i, 3].tolist()}, "
                         "expected [0, 0, 0, 1]")
    if rigid:
        R = a[:, :3, :3]
        R9 = R.reshape(-1, 9)  # rows r0 | r1 | r2, contiguous copy
        diag = (R9 * R9).reshape(-1, 3, 3).sum(axis=2) - 1.0  # |r_i|² − 1
        off = (R9[:, _OFF_L] * R9[:, _OFF_R]).reshape(-1, 3, 3).sum(axis=2)  # r0·r1, r0·r2, r1·r2
        err = np.maximum(np.abs(diag).max(axis=1), np.abs(off).max(axis=1))
        det = _det3(R)
        badr = (err > tol) | (np.abs(det - 1.0) > tol)
        if badr.any():
            i = int(np.argmax(badr))
            raise ValueError(f"{name}: pose {i} is not rigid (max |R Rᵀ − I| = {err[i]:.2e}, "
                             f"det R = {det[i]:.6f})")
    return a


def _det3(R: np.ndarray) -> np.ndarray:
    """Determinants of (n, 3, 3) matrices (cofactor expansion; faster than LAPACK for 3×3)."""
    return (R[:, 0, 0] * (R[:, 1, 1] * R[:, 2, 2] - R[:, 1, 2] * R[:, 2, 1])
            - R[:, 0, 1] * (R[:, 1, 0] * R[:, 2, 2] - R[:, 1, 2] * R[:, 2, 0])
            + R[:, 0, 2] * (R[:, 1, 0] * R[:, 2, 1] - R[:, 1, 1] * R[:, 2, 0]))


def check_pose(pose: ArrayLike, name: str = "pose", rigid: bool = True,
               tol: float = RIGID_TOL_DEFAULT) -> Array:
    """Validate one 4×4 pose (mm) and return it as float64 (4, 4); see :func:`check_poses`."""
    a = np.asarray(pose, dtype=np.float64)
    if a.shape != (4, 4):
        raise ValueError(f"{name}: expected a 4×4 pose, got shape {a.shape}")
    return check_poses(a, name, rigid, tol)[0]


def make_pose(R: ArrayLike | None = None, t: ArrayLike | None = None) -> Array:
    """Build 4×4 poses from rotations (…, 3, 3) and translations (…, 3) in mm."""
    Ra = np.eye(3) if R is None else np.asarray(R, dtype=np.float64)
    ta = np.zeros(3) if t is None else np.asarray(t, dtype=np.float64)
    shape = np.broadcast_shapes(Ra.shape[:-2], ta.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = Ra
    T[..., :3, 3] = ta
    T[..., 3, 3] = 1.0
    return T


def compose(*poses: ArrayLike) -> Array:
    """Compose poses left to right: ``compose(a_from_b, b_from_c) -> a_from_c``. Batched."""
    out = np.asarray(poses[0], dtype=np.float64)
    for p in poses[1:]:
        out = out @ np.asarray(p, dtype=np.float64)
    return out


def invert(pose: ArrayLike) -> Array:
    """Invert rigid poses (…, 4, 4): ``invert(a_from_b) -> b_from_a``; mm in, mm out."""
    T = np.asarray(pose, dtype=np.float64)
    R = T[..., :3, :3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def rotation(pose: ArrayLike) -> Array:
    """The 3×3 rotation block(s) of pose(s) (…, 4, 4)."""
    return np.asarray(pose, dtype=np.float64)[..., :3, :3]


def translation(pose: ArrayLike) -> Array:
    """The translation(s) of pose(s) (…, 4, 4), in mm, shape (…, 3)."""
    return np.asarray(pose, dtype=np.float64)[..., :3, 3]


def orthonormalize(M: ArrayLike) -> Array:
    """Nearest rotation(s) to 3×3 matrices, or the pose(s) with their 3×3 block projected.

    Uses the SVD M = U Σ Vᵀ and returns U diag(1, 1, det(U Vᵀ)) Vᵀ, so the result is a proper
    rotation (det +1) even for reflections. Accepts (…, 3, 3) or (…, 4, 4); for 4×4 input the
    translation column is kept and the last row reset to [0, 0, 0, 1].
    """
    A = np.asarray(M, dtype=np.float64)
    if A.shape[-2:] == (4, 4):
        out = A.copy()
        out[..., :3, :3] = orthonormalize(A[..., :3, :3])
        out[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
        return out
    if A.shape[-2:] != (3, 3):
        raise ValueError(f"orthonormalize: expected (…, 3, 3) or (…, 4, 4), got {A.shape}")
    U, _, Vt = np.linalg.svd(A)
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0, 1.0, d)
    D = np.zeros(A.shape[:-2] + (3,))
    D[..., 0] = 1.0
    D[..., 1] = 1.0
    D[..., 2] = d
    return (U * D[..., None, :]) @ Vt


# --- elementary rotations -------------------------------------------------------------

def skew(v: ArrayLike) -> Array:
    """The cross-product matrices [v]× (…, 3, 3) of vectors v (…, 3): [v]× u = v × u."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return out - np.swapaxes(out, -1, -2)


def _elementary_rotation(a: ArrayLike, axis: int) -> Array:
    """Rotation(s) about coordinate axis ``axis`` (0 = x, 1 = y, 2 = z) by angle(s) ``a`` in
    radians, shape (…, 3, 3): the right-handed rotation, R e_i = cos a e_i + sin a e_j for the
    cyclic successors (i, j) of the axis."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    R = np.zeros(a.shape + (3, 3))
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    R[..., j, j] = c
    return R


def rot_x(a: ArrayLike) -> Array:
    """Rotation(s) about x by angle(s) ``a`` in radians, shape (…, 3, 3)."""
    return _elementary_rotation(a, 0)


def rot_y(a: ArrayLike) -> Array:
    """Rotation(s) about y by angle(s) ``a`` in radians, shape (…, 3, 3)."""
    return _elementary_rotation(a, 1)


def rot_z(a: ArrayLike) -> Array:
    """Rotation(s) about z by angle(s) ``a`` in radians, shape (…, 3, 3)."""
    return _elementary_rotation(a, 2)


# --- quaternions (scalar first, as NDI) -------------------------------------------------
#
# Hand-written rather than scipy.spatial.transform.Rotation: the NDI codec converts every tool
# of every frame (``benchmarks/tracker.py`` prints how many frames/s) and the metrics take one
# rotation angle per test pose; scipy's per-call overhead (and its from_matrix, which
# re-orthonormalises first) costs more on single rotations. tests/unit/test_geometry.py checks
# both against scipy.


def _matrix_terms(w: float, x: float, y: float, z: float) -> np.ndarray:
    """|q|² R(q) for q = (w, x, y, z): the Euler–Rodrigues formula (as in Horn 1987)."""
    return np.array([[w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]])


#: 4 q_k q_m of a unit quaternion q = (w, x, y, z) of R, linear in R (Shepperd 1978):
#: ((k, m), identity term, [(coefficient, row, column) of R]).
_OUTER_FROM_R = (
    ((0, 0), 1.0, [(1, 0, 0), (1, 1, 1), (1, 2, 2)]),    # 4w² = 1 + R00 + R11 + R22
    ((1, 1), 1.0, [(1, 0, 0), (-1, 1, 1), (-1, 2, 2)]),  # 4x² = 1 + R00 − R11 − R22
    ((2, 2), 1.0, [(-1, 0, 0), (1, 1, 1), (-1, 2, 2)]),  # 4y² = 1 − R00 + R11 − R22
    ((3, 3), 1.0, [(-1, 0, 0), (-1, 1, 1), (1, 2, 2)]),  # 4z² = 1 − R00 − R11 + R22
    ((0, 1), 0.0, [(1, 2, 1), (-1, 1, 2)]),              # 4wx = R21 − R12
    ((0, 2), 0.0, [(1, 0, 2), (-1, 2, 0)]),              # 4wy = R02 − R20
    ((0, 3), 0.0, [(1, 1, 0), (-1, 0, 1)]),              # 4wz = R10 − R01
    ((1, 2), 0.0, [(1, 0, 1), (1, 1, 0)]),               # 4xy = R01 + R10
    ((1, 3), 0.0, [(1, 0, 2), (1, 2, 0)]),               # 4xz = R02 + R20
    ((2, 3), 0.0, [(1, 1, 2), (1, 2, 1)]),               # 4yz = R12 + R21
)


def _quat_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constant tables turning both conversions into one matrix product each:
    |q|² vec R(q) = (q ⊗ q) · _Q2R (16 × 9, from :func:`_matrix_terms` on basis quaternions)
    and vec(4 q qᵀ) = _R2Q_C + vec(R) · _R2Q_L (from :data:`_OUTER_FROM_R`)."""
    E = np.eye(4)
    q2r = np.zeros((16, 9))
    for k in range(4):
        for m in range(4):
            if k == m:
                q2r[4 * k + m] = _matrix_terms(*E[k]).reshape(9)
            else:  # symmetric split of the cross term
                cross = _matrix_terms(*(E[k] + E[m])) - _matrix_terms(*E[k]) - _matrix_terms(*E[m])
                q2r[4 * k + m] = (cross / 2).reshape(9)
    c = np.zeros((4, 4))
    L = np.zeros((9, 4, 4))
    for (k, m), const, terms in _OUTER_FROM_R:
        c[k, m] = const
        for coef, i, j in terms:
            L[3 * i + j, k, m] = L[3 * i + j, m, k] = coef
    return q2r, c.reshape(16), L.reshape(9, 16)


_Q2R, _R2Q_C, _R2Q_L = _quat_tables()


def matrix_from_quaternion(q: ArrayLike) -> Array:
    """Rotation matrices (…, 3, 3) from quaternions (…, 4) = (q0, qx, qy, qz), scalar first as
    in the NDI Polaris Application Program Interface Guide (BX/TX replies).

    The quaternion is normalised first; a zero quaternion raises ``ValueError``. The formula
    is Euler–Rodrigues' (as in Horn 1987), evaluated as one product with a constant table.
    """
    q = np.asarray(q, dtype=np.float64)
    n2 = (q * q).sum(axis=-1)
    if np.any(n2 < 1e-24):
        raise ValueError("matrix_from_quaternion: zero-length quaternion")
    qq = (q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,))
    return ((qq @ _Q2R) / n2[..., None]).reshape(q.shape[:-1] + (3, 3))


def quaternion_from_matrix(R: ArrayLike) -> Array:
    """Unit quaternions (…, 4) = (q0, qx, qy, qz), q0 ≥ 0, from rotation matrices (…, 3, 3).

    Accepts 4×4 poses too (the rotation block is used). Robust for all angles: 4 q qᵀ is
    linear in R, and q is read off its column with the largest diagonal entry (Shepperd 1978,
    "Quaternion from rotation matrix", J. Guidance and Control 1(3):223), so no square root of
    a small number is taken.
    """
    M = np.asarray(R, dtype=np.float64)
    if M.shape[-2:] == (4, 4):
        M = M[..., :3, :3]
    lead = M.shape[:-2]
    m = M.reshape(-1, 9)
    Q = (_R2Q_C + m @ _R2Q_L).reshape(-1, 4, 4)
    diag = np.diagonal(Q, axis1=1, axis2=2)
    k = np.argmax(diag, axis=1)
    col = Q[np.arange(len(k)), :, k]
    q = col / np.linalg.norm(col, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(lead + (4,))


# --- rotation vectors (UR) -------------------------------------------------------------

def _batched_rotation(values: np.ndarray, build: str, *args: Any, **kw: Any) -> Array:
    """(…, 3, 3) matrices from (…, k) values through ``scipy.spatial.transform.Rotation.<build>``.

    scipy is imported on first use: it adds ~0.3 s to the import of every tmscal command.
    """
    from scipy.spatial.transform import Rotation

    lead = values.shape[:-1]
    flat = values.reshape(-1, values.shape[-1])
    return getattr(Rotation, build)(*args, flat, **kw).as_matrix().reshape(lead + (3, 3))


def matrix_from_rotvec(rv: ArrayLike) -> Array:
    """Rotation matrices (…, 3, 3) from rotation vectors (…, 3), axis × angle in radians (the
    pose vector of the Universal Robots script manual): the exponential map of SO(3),
    Rodrigues' formula R = I + (sin θ/θ) K + ((1 − cos θ)/θ²) K² with K = [rv]×, its Taylor
    series below θ = 1e-4 rad (exact to round-off there). The one SO(3) exponential of tmscal
    (tested against scipy's ``Rotation.from_rotvec``)."""
    rv = np.asarray(rv, dtype=np.float64)
    if rv.shape[-1:] != (3,):
        raise ValueError(f"matrix_from_rotvec: expected (…, 3), got shape {rv.shape}")
    th2 = np.einsum("...i,...i->...", rv, rv)
    th = np.sqrt(th2)
    small = th < 1e-4
    ts = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(ts) / ts)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ts)) / (ts * ts))
    K = skew(rv)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def rotvec_from_matrix(R: ArrayLike) -> Array:
    """Rotation vectors (…, 3), axis × angle in radians (angle in [0, π]), from (…, 3, 3) (or
    poses (…, 4, 4)): the logarithm of SO(3), the one of tmscal.

    Below 120° from the skew part w and the trace, θ = atan2(|w|, (tr R − 1)/2), rv = θ w/|w|
    (well conditioned there, and ~2.5× faster than through the quaternion: the ml solve takes
    the log of every residual); beyond, through :func:`quaternion_from_matrix`: angle =
    2 atan2(|v|, w), axis = v / |v|, right up to π where the skew part vanishes. Hand-written
    because scipy's ``Rotation.from_matrix`` re-orthonormalises and is ~2× slower; the UR mock
    calls this on every servo step. Tested against scipy's ``as_rotvec``."""
    M = np.asarray(R, dtype=np.float64)
    if M.shape[-2:] == (4, 4):
        M = M[..., :3, :3]
    w = 0.5 * np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0],
                        M[..., 1, 0] - M[..., 0, 1]], axis=-1)
    s = np.linalg.norm(w, axis=-1)
    c = 0.5 * (np.trace(M, axis1=-2, axis2=-1) - 1.0)
    f = np.where(s < 1e-12, 1.0, np.arctan2(s, c) / np.where(s < 1e-12, 1.0, s))
    out = w * f[..., None]
    far = c < -0.5
    if np.any(far):
        q = quaternion_from_matrix(M[far])
        v = q[..., 1:]
        sv = np.linalg.norm(v, axis=-1)
        angle = 2 * np.arctan2(sv, np.clip(q[..., 0], -1.0, 1.0))
        out[far] = v * (angle / np.where(sv < 1e-12, 1.0, sv))[..., None]
    return out


def right_jacobian(rv: ArrayLike) -> Array:
    """Right Jacobians J_r (…, 3, 3) of SO(3) at rotation vectors rv (…, 3) rad:
    exp(rv + δ) = exp(rv) exp(J_r δ) + O(δ²)."""
    rv = np.asarray(rv, dtype=np.float64)
    th2 = np.einsum("...i,...i->...", rv, rv)
    th = np.sqrt(th2)
    small = th < 1e-4
    ts = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ts)) / (ts * ts))
    b = np.where(small, 1.0 / 6.0 - th2 / 120.0, (ts - np.sin(ts)) / (ts ** 3))
    W = skew(rv)
    return np.eye(3) - a[..., None, None] * W + b[..., None, None] * (W @ W)


def right_jacobian_inv(rv: ArrayLike) -> Array:
    """Inverse right Jacobians J_r⁻¹ (…, 3, 3) at rotation vectors rv (…, 3) rad (angle < π):
    log(exp(rv) exp(η)) = rv + J_r⁻¹ η + O(η²)."""
    rv = np.asarray(rv, dtype=np.float64)
    th2 = np.einsum("...i,...i->...", rv, rv)
    th = np.sqrt(th2)
    small = th < 1e-4
    ts = np.where(small, 1.0, th)
    coef = np.where(small, 1.0 / 12.0 + th2 / 720.0,
                    1.0 / (ts * ts) - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(ts)))
    W = skew(rv)
    return np.eye(3) + 0.5 * W + coef[..., None, None] * (W @ W)


def pose_from_rotvec(xyz_m_rv: ArrayLike) -> Array:
    """4×4 pose (mm) from a UR pose vector [x, y, z (metres), rx, ry, rz (rotation vector, rad)]."""
    v = np.asarray(xyz_m_rv, dtype=np.float64)
    if v.shape[-1] != 6:
        raise ValueError(f"pose_from_rotvec: expected 6 values, got shape {v.shape}")
    return make_pose(matrix_from_rotvec(v[..., 3:]), v[..., :3] * 1000.0)


def rotvec_pose_from_matrix(pose: ArrayLike) -> Array:
    """UR pose vector [x, y, z (metres), rx, ry, rz (rad)] from a 4×4 pose in mm."""
    T = np.asarray(pose, dtype=np.float64)
    return np.concatenate([T[..., :3, 3] / 1000.0, rotvec_from_matrix(T[..., :3, :3])], axis=-1)


# --- DENSO P-type ---------------------------------------------------------------------------

def matrix_from_denso_p(p: ArrayLike) -> Array:
    """4×4 pose (mm) from DENSO P-type values [x, y, z (mm), rx, ry, rz (deg)].

    R = Rz(rz) · Ry(ry) · Rx(rx): rotations about the fixed base axes, RX applied first (the
    DENSO RC8 programmer's manual, P-type; scipy's extrinsic "xyz" Euler angles). Extra
    trailing values (the ``fig`` code) are ignored.
    """
    v = np.asarray(p, dtype=np.float64)
    if v.shape[-1] < 6:
        raise ValueError(f"matrix_from_denso_p: expected ≥ 6 values, got shape {v.shape}")
    R = _batched_rotation(v[..., 3:6], "from_euler", "xyz", degrees=True)
    return make_pose(R, v[..., :3])


def denso_p_from_matrix(pose: ArrayLike) -> Array:
    """DENSO P-type [x, y, z (mm), rx, ry, rz (deg)] from a 4×4 pose in mm.

    Inverse of :func:`matrix_from_denso_p`; ry is returned in [−90°, 90°], and at gimbal lock
    (|ry| = 90°) rz = 0. The closed form of the fixed-axis XYZ angles (Craig, Introduction to
    Robotics, sect. 2.8), hand-written because scipy's ``as_euler`` re-orthonormalises (~2×
    slower) and warns at gimbal lock; tested against scipy's ``as_euler("xyz")``.
    """
    T = np.asarray(pose, dtype=np.float64)
    R = T[..., :3, :3]
    ry = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    cy = np.cos(ry)
    gimbal = np.abs(cy) < 1e-9
    rx = np.where(gimbal, np.arctan2(-R[..., 1, 2], R[..., 1, 1]),
                  np.arctan2(R[..., 2, 1], R[..., 2, 2]))
    rz = np.where(gimbal, 0.0, np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    ang = np.degrees(np.stack([rx, ry, rz], axis=-1))
    return np.concatenate([T[..., :3, 3], ang], axis=-1)


# --- angles, means, sampling --------------------------------------------------------------------

def rotation_angle(R: ArrayLike) -> Array:
    """Rotation angle(s) in radians, in [0, π], of rotation matrices or poses (…, 3|4, 3|4).

    Computed from the quaternion (atan2), accurate for small angles too.
    """
    q = quaternion_from_matrix(R)
    return 2 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))


def angle_between(a: ArrayLike, b: ArrayLike) -> Array:
    """Angle(s) in radians of the relative rotation Rᵃᵀ Rᵇ between poses/rotations a and b."""
    Ra = np.asarray(a, dtype=np.float64)[..., :3, :3]
    Rb = np.asarray(b, dtype=np.float64)[..., :3, :3]
    return rotation_angle(np.swapaxes(Ra, -1, -2) @ Rb)


def rotation_mean(R: ArrayLike) -> Array:
    """Chordal L2 mean of rotations (n, 3, 3) (or poses (n, 4, 4)): the rotation nearest to
    their arithmetic mean, found by SVD with the determinant fix. Returns (3, 3)."""
    M = np.asarray(R, dtype=np.float64)
    if M.ndim != 3 or M.shape[0] == 0:
        raise ValueError(f"rotation_mean: expected (n, 3, 3) with n ≥ 1, got {M.shape}")
    return orthonormalize(M[:, :3, :3].mean(axis=0))


def pose_mean(poses: ArrayLike) -> Array:
    """Mean of poses (n, 4, 4) in mm: arithmetic mean translation, chordal mean rotation."""
    P = np.asarray(poses, dtype=np.float64)
    return make_pose(rotation_mean(P), P[:, :3, 3].mean(axis=0))


def random_rotation(rng: np.random.Generator, n: int | None = None) -> Array:
    """Uniformly distributed random rotation(s) (Haar measure) from the given generator."""
    q = rng.standard_normal((1 if n is None else n, 4))
    R = matrix_from_quaternion(q)
    return R[0] if n is None else R


def absolute_orientation(model: ArrayLike, measured: ArrayLike) -> Array:
    """Horn's closed-form absolute orientation (unit quaternions, no scale), batched.

    ``model`` (k, 3) are points in the body frame (mm); ``measured`` (…, k, 3) the same points
    seen in the sensor frame (mm). Returns sensor_from_body poses (…, 4, 4) minimising the
    sum of squared distances (Horn 1987, J. Opt. Soc. Am. A 4(4):629).
    """
    P = np.asarray(model, dtype=np.float64)
    Q = np.asarray(measured, dtype=np.float64)
    pc = P.mean(axis=-2)
    qc = Q.mean(axis=-2)
    S = np.einsum("ki,...kj->...ij", P - pc, Q - qc[..., None, :])
    Sxx, Sxy, Sxz = S[..., 0, 0], S[..., 0, 1], S[..., 0, 2]
    Syx, Syy, Syz = S[..., 1, 0], S[..., 1, 1], S[..., 1, 2]
    Szx, Szy, Szz = S[..., 2, 0], S[..., 2, 1], S[..., 2, 2]
    N = np.empty(S.shape[:-2] + (4, 4))
    N[..., 0, 0] = Sxx + Syy + Szz
    N[..., 0, 1] = N[..., 1, 0] = Syz - Szy
    N[..., 0, 2] = N[..., 2, 0] = Szx - Sxz
    N[..., 0, 3] = N[..., 3, 0] = Sxy - Syx
    N[..., 1, 1] = Sxx - Syy - Szz
    N[..., 1, 2] = N[..., 2, 1] = Sxy + Syx
    N[..., 1, 3] = N[..., 3, 1] = Szx + Sxz
    N[..., 2, 2] = -Sxx + Syy - Szz
    N[..., 2, 3] = N[..., 3, 2] = Syz + Szy
    N[..., 3, 3] = -Sxx - Syy + Szz
    _, vecs = np.linalg.eigh(N)
    R = matrix_from_quaternion(vecs[..., :, -1])
    t = qc - (R @ pc[:, None])[..., 0]
    return make_pose(R, t)
