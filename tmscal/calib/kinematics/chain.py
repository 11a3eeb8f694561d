"""A serial arm's DH chain with the flange's sensitivity to every geometric parameter: the
forward kinematics the tracker-based kinematic calibration fits (docs/kinematics.md).

Conventions. Joint i (1…n) of a **standard** DH chain (Denavit and Hartenberg 1955) moves by

    T_i = Rz(q_i + θ0_i) · Tz(d_i) · Tx(a_i) · Rx(α_i) · Ry(β_i),

of a **modified** chain (Craig 1989) by

    T_i = Rx(α_i) · Ry(β_i) · Tx(a_i) · Rz(q_i + θ0_i) · Tz(d_i),

with angles in rad and lengths in mm. β_i (Hayati and Mirmirani 1985) is zero in every
nominal model; it is the misalignment about y that DH cannot express when two consecutive
joint axes are parallel (UR joints 2–4). The flange pose in the robot's base frame is
base_from_flange = T_1 ⋯ T_n · F, where F (``flange``, 4×4 mm) takes the last DH frame to
the controller's flange frame. A (possibly tilted) mounting of the base in a world frame is
not part of the chain: in a hand/eye calibration it is the robot/world transform Z.

Sensitivity. A small change δp of one parameter moves the flange by a body twist
ξ = [ω (rad); v (mm)] in the flange frame, A' = A · exp(ξ^δp) to first order:
``parameter_twists`` gives ξ per pose and parameter, exactly (analytically), from the
parameter's place in the chain: every parameter is a left perturbation exp(s^) at an
intermediate frame G of the chain (e.g. θ0_i: s = [e_z; 0] at frame i − 1), so
ξ = Ad(A⁻¹ G) s. Pure numerics, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Chain", "PARAMETER_KINDS", "adjoint", "parameter_twists", "parallel_joints",
           "parameter_units"]

#: per-joint geometric parameters, in this order; "beta" only where consecutive axes are
#: parallel (``parallel_joints``)
PARAMETER_KINDS = ("theta0", "d", "a", "alpha", "beta")
_UNITS = {"theta0": "rad", "d": "mm", "a": "mm", "alpha": "rad", "beta": "rad"}
_EX, _EY, _EZ = np.eye(3)


def _rot(axis: int, angle: np.ndarray) -> np.ndarray:
    """(…, 4, 4) rotations about x (0), y (1) or z (2) by ``angle`` (…,) rad."""
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    T = np.zeros(angle.shape + (4, 4))
    T[..., 3, 3] = 1.0
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    T[..., axis, axis] = 1.0
    T[..., i, i], T[..., i, j], T[..., j, i], T[..., j, j] = c, -s, s, c
    return T


def _trans(axis: int, dist: np.ndarray) -> np.ndarray:
    """(…, 4, 4) translations along x, y or z by ``dist`` (…,) mm."""
    dist = np.asarray(dist, dtype=float)
    T = np.zeros(dist.shape + (4, 4))
    T[..., [0, 1, 2, 3], [0, 1, 2, 3]] = 1.0
    T[..., axis, 3] = dist
    return T


def adjoint(T: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Ad(T) s for poses T (…, 4, 4) and twists s (…, 6) = [ω; v]: [R ω; R v + t × R ω]."""
    R, t = T[..., :3, :3], T[..., :3, 3]
    w = np.einsum("...ij,...j->...i", R, s[..., :3])
    v = np.einsum("...ij,...j->...i", R, s[..., 3:]) + np.cross(t, w)
    return np.concatenate([w, v], axis=-1)


def _invert(T: np.ndarray) -> np.ndarray:
    R, t = T[..., :3, :3], T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


@dataclass(frozen=True)
class Chain:
    """The geometry of a serial arm: ``dh`` (n, 4) rows [θ0 rad, d mm, a mm, α rad] in the
    ``convention`` "standard" or "modified" (module docstring), ``beta`` (n,) rad (zero in a
    nominal model), ``flange`` 4×4 mm (last DH frame → the controller's flange frame)."""

    dh: np.ndarray
    convention: str = "standard"
    beta: np.ndarray | None = None
    flange: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        dh = np.array(self.dh, dtype=float)
        if dh.ndim != 2 or dh.shape[1] != 4 or not np.all(np.isfinite(dh)):
            raise ValueError(f"dh must be a finite (n, 4) array, got shape {dh.shape}")
        if self.convention not in ("standard", "modified"):
            raise ValueError(f"convention must be 'standard' or 'modified', got "
                             f"{self.convention!r}")
        beta = np.zeros(len(dh)) if self.beta is None else np.array(self.beta, dtype=float)
        if beta.shape != (len(dh),) or not np.all(np.isfinite(beta)):
            raise ValueError(f"beta must be a finite ({len(dh)},) array")
        F = np.array(self.flange, dtype=float)
        if F.shape != (4, 4) or not np.all(np.isfinite(F)):
            raise ValueError("flange must be a finite 4×4 pose")
        object.__setattr__(self, "dh", dh)
        object.__setattr__(self, "beta", beta)
        object.__setattr__(self, "flange", F)

    @property
    def n_joints(self) -> int:
        return len(self.dh)

    def vector(self, names: list[str]) -> np.ndarray:
        """The values of the named parameters ("theta0_1", "beta_3", …; rad and mm)."""
        return np.array([self._get(n) for n in names])

    def _get(self, name: str) -> float:
        kind, i = _split(name, self.n_joints)
        return float(self.beta[i] if kind == "beta" else self.dh[i, PARAMETER_KINDS.index(kind)])

    def shifted(self, names: list[str], delta: np.ndarray) -> Chain:
        """A copy with the named parameters changed by ``delta`` (rad, mm)."""
        dh, beta = self.dh.copy(), self.beta.copy()
        for n, d in zip(names, np.asarray(delta, dtype=float), strict=True):
            kind, i = _split(n, self.n_joints)
            if kind == "beta":
                beta[i] += d
            else:
                dh[i, PARAMETER_KINDS.index(kind)] += d
        return Chain(dh, self.convention, beta, self.flange)

    def _steps(self, q: np.ndarray) -> list[list[tuple[str, np.ndarray]]]:
        """Per joint the elementary transforms in chain order, each named by the parameter
        that enters it ("theta0" for the joint rotation, which also carries q)."""
        out = []
        for i in range(self.n_joints):
            th0, d, a, al = self.dh[i]
            m = q.shape[:-1]
            rz = _rot(2, q[..., i] + th0)
            tz = _trans(2, np.full(m, d))
            tx = _trans(0, np.full(m, a))
            rx = _rot(0, np.full(m, al))
            ry = _rot(1, np.full(m, self.beta[i]))
            if self.convention == "standard":
                out.append([("theta0", rz), ("d", tz), ("a", tx), ("alpha", rx), ("beta", ry)])
            else:
                out.append([("alpha", rx), ("beta", ry), ("a", tx), ("theta0", rz), ("d", tz)])
        return out

    def forward(self, q: Any) -> np.ndarray:
        """base_from_flange (…, 4, 4) mm for joint values q (…, n) rad."""
        q = _check_q(q, self.n_joints)
        T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
        for joint in self._steps(q):
            for _, M in joint:
                T = T @ M
        return T @ self.flange

    def frames(self, q: Any) -> np.ndarray:
        """base_from_frame_i (…, n + 1, 4, 4) mm for i = 0…n (frame 0 the base, frame i the
        DH frame after joint i; the flange transform not applied)."""
        q = _check_q(q, self.n_joints)
        out = np.empty(q.shape[:-1] + (self.n_joints + 1, 4, 4))
        T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
        out[..., 0, :, :] = T
        for i, joint in enumerate(self._steps(q)):
            for _, M in joint:
                T = T @ M
            out[..., i + 1, :, :] = T
        return out


def _check_q(q: Any, n: int) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.ndim == 0 or q.shape[-1] != n:
        raise ValueError(f"q must have {n} joint values on its last axis, got shape {q.shape}")
    return q


def _split(name: str, n: int) -> tuple[str, int]:
    kind, _, idx = name.rpartition("_")
    if kind not in PARAMETER_KINDS or not idx.isdigit() or not 1 <= int(idx) <= n:
        raise ValueError(f"unknown kinematic parameter {name!r} (expected e.g. theta0_1 … "
                         f"{PARAMETER_KINDS[-1]}_{n})")
    return kind, int(idx) - 1


def parameter_units(names: list[str]) -> list[str]:
    """"rad" or "mm" for each parameter name."""
    return [_UNITS[n.rpartition("_")[0]] for n in names]


#: the unit twist s = [ω; v] each elementary transform's parameter moves along (left
#: perturbation exp(s^) at the frame just before the transform)
_UNIT = {"theta0": np.r_[_EZ, 0, 0, 0], "d": np.r_[0, 0, 0, _EZ],
         "a": np.r_[0, 0, 0, _EX], "alpha": np.r_[_EX, 0, 0, 0], "beta": np.r_[_EY, 0, 0, 0]}


def parameter_twists(chain: Chain, q: Any, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(A, J): the flange poses A (m, 4, 4) base_from_flange mm at joints q (m, n) rad, and
    J (m, 6, k): per pose and named parameter the flange's body twist [ω rad; v mm] per unit
    change of the parameter (rad or mm), A(p + δ) = A · exp(Σ_j J_j δ_j) to first order."""
    q = np.atleast_2d(_check_q(q, chain.n_joints))
    m = q.shape[0]
    wanted = {}
    for col, nm in enumerate(names):
        kind, i = _split(nm, chain.n_joints)
        wanted[(i, kind)] = col
    pre: dict[int, np.ndarray] = {}
    T = np.broadcast_to(np.eye(4), (m, 4, 4)).copy()
    for i, joint in enumerate(chain._steps(q)):
        for kind, M in joint:
            if (i, kind) in wanted:
                pre[wanted[(i, kind)]] = T
            T = T @ M
    A = T @ chain.flange
    A_inv = _invert(A)
    J = np.zeros((m, 6, len(names)))
    for col, nm in enumerate(names):
        kind = nm.rpartition("_")[0]
        J[:, :, col] = adjoint(A_inv @ pre[col], np.broadcast_to(_UNIT[kind], (m, 6)))
    return A, J


def parallel_joints(chain: Chain, tol_deg: float = 1.0) -> list[int]:
    """Joints i (1-based) whose axis is parallel (within ``tol_deg``) to the next joint's axis,
    at the nominal geometry: there the β_i of Hayati and Mirmirani (1985) completes DH. For a
    standard chain joint i's link carries axis z_{i−1} to z_i; for a modified chain joint i's
    transform carries axis i − 1 to axis i, so β_i serves the pair (i − 1, i)."""
    F = chain.frames(np.zeros(chain.n_joints))
    if chain.convention == "standard":
        z = F[:, :3, 2]            # z_0 … z_n: z_{i−1} is joint i's axis
        pairs = [(i, z[i - 1], z[i]) for i in range(1, chain.n_joints)]
    else:
        z = F[1:, :3, 2]           # frame i's z is joint i's axis
        pairs = [(i, z[i - 2], z[i - 1]) for i in range(2, chain.n_joints + 1)]
    c = np.cos(np.radians(tol_deg))
    return [i for i, u, w in pairs if abs(float(u @ w)) >= c]
