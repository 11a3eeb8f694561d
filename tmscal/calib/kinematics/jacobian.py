"""The pose Jacobian of an arm's flange with respect to its geometric parameters, analytic and
batched. Pure numerics, no I/O; docs/kinematics.md ("The pose Jacobian").

A small change δp of the geometric parameters (order of ``Arm.geometry_names``) moves the
flange's world pose T = ``forward(arm, q)`` to T' with, to first order,

    t' = t + J_t δp   (mm)        R' = exp([J_ω δp]×) · R   (J_ω δp: a rotation vector, rad)

both in the WORLD frame (a spatial, left perturbation). ``pose_jacobian`` returns
J = [J_t; J_ω] as (m, 6, 4n + 12): rows (dt_x, dt_y, dt_z mm, dω_x, dω_y, dω_z rad) per unit of
each parameter (rad or mm). A parameter that rotates the chain beyond it about a world axis ω
through a point o gives J_t = ω × (t − o), J_ω = ω; one that shifts it along a direction u
gives J_t = u, J_ω = 0. With F_i the world ← DH frame i (F_0 the base):

* standard DH (T_i = Rz Tz Tx Rx): θ0_i turns about z of F_{i−1} through its origin, d_i
  shifts along that z, a_i along x of F_i, α_i turns about x of F_i through its origin;
* modified DH (T_i = Rx Tx Rz Tz): α_i turns about x of F_{i−1} through its origin, a_i shifts
  along that x, θ0_i turns about z of F_i through its origin, d_i shifts along that z;
* base = Trans(xyz) Rz(yaw) Ry(pitch) Rx(roll): x, y, z shift along the world axes; yaw turns
  about world z, pitch about Rz(yaw) y, roll about Rz(yaw) Ry(pitch) x, all through the base
  origin;
* flange (the same form in frame F_n): x, y, z shift along F_n's axes; yaw, pitch, roll turn
  about F_n z, F_n Rz(yaw) y, F_n Rz(yaw) Ry(pitch) x through the flange origin (J_t = 0).

A joint value q_i moves the flange exactly as θ0_i does (d_i for a prismatic joint; through
the joint map M, docs of :mod:`.model`, the columns combine as J_q = J_rows · M):
:func:`joint_jacobian` is those columns. The root transform of a chain read from a URDF is
fixed (not a parameter); the base's columns turn about the base origin, before it.
Roll/pitch/yaw columns are singular at pitch = ±π/2 (gimbal lock). This Jacobian is
that of an arm without Hayati angles (``arm.beta`` zero, every nominal model).

Body twists of named deviations (:func:`deviation_twists`, the tracker-based kinematic
calibration and inverse kinematics): a change δp of one DH parameter or Hayati angle β moves
the flange in the robot's base frame, A = base_from_flange, by a body twist
ξ = [ω (rad); v (mm)] in the flange frame, A' = A · exp(ξ^ δp) to first order. Every such
parameter enters the chain as one elementary transform (Rz, Tz, Tx, Rx, Ry), i.e. as a left
perturbation exp(s^) at the frame G just before that transform (θ0_i: s = [e_z; 0], d_i:
[0; e_z], a_i: [0; e_x], α_i: [e_x; 0], β_i: [e_y; 0]), so ξ = Ad(A⁻¹ G) s exactly, with
Ad(T) [ω; v] = [R ω; R v + t × R ω].
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...geometry import rot_y, rot_z
from .model import (
    Arm,
    check_joints,
    joint_frames,
    rpy_from_matrix,
    split_deviation,
)

__all__ = ["pose_jacobian", "joint_jacobian", "rpy_axes", "adjoint", "deviation_twists",
           "parallel_joints"]


def _rotation(omega: np.ndarray, origin: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(…, 6) columns of turns about axes ``omega`` (…, 3) through ``origin`` (…, 3) for a
    flange at ``t`` (…, 3)."""
    return np.concatenate([np.cross(omega, t - origin), omega], axis=-1)


def _shift(u: np.ndarray) -> np.ndarray:
    return np.concatenate([u, np.zeros_like(u)], axis=-1)


def rpy_axes(R: Any) -> np.ndarray:
    """(3, 3): the axes (rows: roll, pitch, yaw) of Rz(yaw) Ry(pitch) Rx(roll) = R, in the
    frame the rotation is expressed in."""
    _, p, y = rpy_from_matrix(R)
    return np.array([rot_z(y) @ rot_y(p) @ [1.0, 0.0, 0.0], rot_z(y) @ [0.0, 1.0, 0.0],
                     [0.0, 0.0, 1.0]])


def pose_jacobian(arm: Arm, q: Any) -> np.ndarray:
    """d(flange pose)/d(geometric parameters), shape (m, 6, 4n + 12), for joint values q
    (m, n) (or (n,): m = 1) rad: rows dt (mm) and dω (rad) in the world frame, columns in the
    order of ``arm.geometry_names()`` (module docstring). ValueError for an arm with Hayati
    angles (use :func:`deviation_twists`)."""
    if np.any(arm.beta != 0):
        raise ValueError(f"pose_jacobian: arm {arm.name!r} has Hayati angles β; use "
                         "deviation_twists")
    q = np.atleast_2d(check_joints(arm, q))
    if q.ndim != 2:
        raise ValueError(f"q must be (m, {arm.n_joints}), got shape {q.shape}")
    m, n = q.shape[0], arm.n_rows
    F = joint_frames(arm, q)                                   # (m, n+1, 4, 4)
    flange = F[:, -1] @ arm.flange                             # (m, 4, 4)
    t = flange[:, None, :3, 3]                                 # (m, 1, 3)
    o, x, z = F[..., :3, 3], F[..., :3, 0], F[..., :3, 2]      # (m, n+1, 3)
    J = np.empty((m, 6, 4 * n + 12))
    cols = J.transpose(0, 2, 1)                                # (m, P, 6), a view of J
    if arm.convention == "standard":
        cols[:, 0:4 * n:4] = _rotation(z[:, :-1], o[:, :-1], t)   # θ0_i about z of F_{i−1}
        cols[:, 1:4 * n:4] = _shift(z[:, :-1])                    # d_i along z of F_{i−1}
        cols[:, 2:4 * n:4] = _shift(x[:, 1:])                     # a_i along x of F_i
        cols[:, 3:4 * n:4] = _rotation(x[:, 1:], o[:, 1:], t)     # α_i about x of F_i
    else:
        cols[:, 0:4 * n:4] = _rotation(z[:, 1:], o[:, 1:], t)     # θ0_i about z of F_i
        cols[:, 1:4 * n:4] = _shift(z[:, 1:])                     # d_i along z of F_i
        cols[:, 2:4 * n:4] = _shift(x[:, :-1])                    # a_i along x of F_{i−1}
        cols[:, 3:4 * n:4] = _rotation(x[:, :-1], o[:, :-1], t)   # α_i about x of F_{i−1}
    k = 4 * n
    base_axes = np.broadcast_to(rpy_axes(arm.base), (m, 3, 3))
    cols[:, k:k + 3] = _rotation(base_axes, arm.base[:3, 3], t)
    cols[:, k + 3:k + 6] = _shift(np.broadcast_to(np.eye(3), (m, 3, 3)))
    Rn = F[:, -1, :3, :3]                                      # (m, 3, 3) world ← frame n
    flange_axes = np.einsum("mij,kj->mki", Rn, rpy_axes(arm.flange))
    cols[:, k + 6:k + 9] = _rotation(flange_axes, t, t)
    cols[:, k + 9:k + 12] = _shift(Rn.transpose(0, 2, 1))     # F_n's x, y, z axes
    return J


def joint_jacobian(arm: Arm, q: Any) -> np.ndarray:
    """d(flange pose)/d(joint values), shape (m, 6, n), for q (m, n) rad: rows dt (mm) and
    dω (rad) in the world frame per rad (per mm for a prismatic joint): the θ0 columns of
    :func:`pose_jacobian` (d for a prismatic row), combined by the joint map."""
    J = pose_jacobian(arm, q)
    if arm.joint_types is None and arm.joint_map is None:
        return J[:, :, 0:4 * arm.n_joints:4]
    cols = np.stack([J[:, :, 4 * i + (1 if t == "prismatic" else 0)]
                     for i, t in enumerate(arm.types)], axis=-1)       # (m, 6, rows)
    return cols if arm.joint_map is None else cols @ arm.joint_map


# --- body twists of named deviations ------------------------------------------------------------

def adjoint(T: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Ad(T) s for poses T (…, 4, 4) and twists s (…, 6) = [ω; v]: [R ω; R v + t × R ω]."""
    R, t = T[..., :3, :3], T[..., :3, 3]
    w = np.einsum("...ij,...j->...i", R, s[..., :3])
    v = np.einsum("...ij,...j->...i", R, s[..., 3:]) + np.cross(t, w)
    return np.concatenate([w, v], axis=-1)


def _elementary(axis: int, rotate: bool, value: np.ndarray) -> np.ndarray:
    """(m, 4, 4) rotations about (``rotate``) or translations along x/y/z (axis 0/1/2)."""
    value = np.asarray(value, dtype=float)
    T = np.zeros(value.shape + (4, 4))
    T[..., [0, 1, 2, 3], [0, 1, 2, 3]] = 1.0
    if rotate:
        c, s = np.cos(value), np.sin(value)
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        T[..., i, i], T[..., i, j], T[..., j, i], T[..., j, j] = c, -s, s, c
    else:
        T[..., axis, 3] = value
    return T


def _steps(arm: Arm, q: np.ndarray) -> list[list[tuple[str, np.ndarray]]]:
    """Per joint its elementary transforms in chain order, each named by the parameter that
    enters it ("theta0": the joint rotation, which also carries q)."""
    out = []
    m = q.shape[0]
    x = arm.row_values(q)
    for i, kind in enumerate(arm.types):
        th0, d, a, al = arm.dh[i]
        if kind == "revolute":
            rz = _elementary(2, True, x[:, i] + th0)
            tz = _elementary(2, False, np.full(m, d))
        else:
            rz = _elementary(2, True, np.full(m, th0))
            tz = _elementary(2, False, x[:, i] + d)
        tx = _elementary(0, False, np.full(m, a))
        rx = _elementary(0, True, np.full(m, al))
        ry = _elementary(1, True, np.full(m, arm.beta[i]))
        out.append([("theta0", rz), ("d", tz), ("a", tx), ("alpha", rx), ("beta", ry)]
                   if arm.convention == "standard" else
                   [("alpha", rx), ("beta", ry), ("a", tx), ("theta0", rz), ("d", tz)])
    return out


#: the unit twist [ω; v] each kind of parameter moves along (left perturbation at the frame
#: just before its elementary transform)
_UNIT = {"theta0": np.array([0, 0, 1, 0, 0, 0.0]), "d": np.array([0, 0, 0, 0, 0, 1.0]),
         "a": np.array([0, 0, 0, 1, 0, 0.0]), "alpha": np.array([1, 0, 0, 0, 0, 0.0]),
         "beta": np.array([0, 1, 0, 0, 0, 0.0])}


def deviation_twists(arm: Arm, q: Any, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(A, J): the flange poses A (m, 4, 4) base_from_flange mm (``arm.base`` not applied) at
    joints q (m, n) rad, and J (m, 6, k): per pose and named deviation ("theta0_1", "d_2",
    "a_3", "alpha_4", "beta_2") the flange's body twist [ω rad; v mm] per unit change of it
    (rad or mm): A(p + δ) = A · exp(Σ_j J_j δ_j) to first order (module docstring)."""
    q = np.atleast_2d(check_joints(arm, q))
    m = q.shape[0]
    wanted = {}
    for col, nm in enumerate(names):
        kind, i = split_deviation(nm, arm.n_rows)
        wanted[(i, kind)] = col
    pre: dict[int, np.ndarray] = {}
    T = np.broadcast_to(np.eye(4) if arm.root is None else arm.root, (m, 4, 4)).copy()
    for i, joint in enumerate(_steps(arm, q)):
        for kind, M in joint:
            if (i, kind) in wanted:
                pre[wanted[(i, kind)]] = T
            T = T @ M
    A = T @ arm.flange
    R, t = A[:, :3, :3], A[:, :3, 3]
    A_inv = np.zeros_like(A)
    A_inv[:, :3, :3] = np.swapaxes(R, 1, 2)
    A_inv[:, :3, 3] = -np.einsum("nji,nj->ni", R, t)
    A_inv[:, 3, 3] = 1.0
    J = np.zeros((m, 6, len(names)))
    for col, nm in enumerate(names):
        J[:, :, col] = adjoint(A_inv @ pre[col],
                               np.broadcast_to(_UNIT[nm.rpartition("_")[0]], (m, 6)))
    return A, J


def parallel_joints(arm: Arm, tol_deg: float = 1.0) -> list[int]:
    """Joints i (1-based) whose transform carries a joint axis to a parallel one (within
    ``tol_deg``) at the nominal geometry: there β_i (Hayati and Mirmirani 1985) completes DH.
    Standard DH: joint i's link carries axis z_{i−1} (joint i) to z_i (joint i + 1);
    modified: joint i's transform carries axis i − 1 to axis i."""
    F = joint_frames(replace_base(arm), np.zeros(arm.n_joints))
    if arm.convention == "standard":
        z = F[:, :3, 2]
        pairs = [(i, z[i - 1], z[i]) for i in range(1, arm.n_rows)]
    else:
        z = F[1:, :3, 2]
        pairs = [(i, z[i - 2], z[i - 1]) for i in range(2, arm.n_rows + 1)]
    c = np.cos(np.radians(tol_deg))
    return [i for i, u, w in pairs if abs(float(u @ w)) >= c]


def replace_base(arm: Arm) -> Arm:
    """The same arm with ``base`` the identity (its robot frame as the world)."""
    from dataclasses import replace

    return replace(arm, base=np.eye(4))
