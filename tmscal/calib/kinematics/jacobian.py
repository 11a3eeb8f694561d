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

A joint value q_i moves the flange exactly as θ0_i does: :func:`joint_jacobian` is those
columns. Roll/pitch/yaw columns are singular at pitch = ±π/2 (gimbal lock).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...geometry import rot_y, rot_z
from .model import Arm, check_joints, joint_frames, rpy_from_matrix

__all__ = ["pose_jacobian", "joint_jacobian", "rpy_axes"]


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
    order of ``arm.geometry_names()`` (module docstring)."""
    q = np.atleast_2d(check_joints(arm, q))
    if q.ndim != 2:
        raise ValueError(f"q must be (m, {arm.n_joints}), got shape {q.shape}")
    m, n = q.shape
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
    dω (rad) in the world frame per rad (the θ0 columns of :func:`pose_jacobian`)."""
    return pose_jacobian(arm, q)[:, :, 0:4 * arm.n_joints:4]
