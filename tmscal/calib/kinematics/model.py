"""The serial-arm model: a Denavit–Hartenberg chain (standard or modified), a base and a flange,
joint limits, and batched forward kinematics. Pure numerics, no I/O; docs/kinematics.md.

Frames and units (mm, rad; poses 4×4 float64):

* ``base`` is world ← robot base (DH frame 0). The world is the rig's frame (for self-
  calibration: z up, gravity (0, 0, −g)); with ``base`` = identity the world IS the robot's
  base frame, the frame the controller reports in.
* joint i (1…n) moves its row ``dh[i-1] = [θ0_i rad, d_i mm, a_i mm, α_i rad]`` by the joint
  value q_i (rad):

  - ``"standard"`` DH (Denavit and Hartenberg 1955; Universal Robots, DENSO here):
    T_i = Rz(q_i + θ0_i) · Tz(d_i) · Tx(a_i) · Rx(α_i);
  - ``"modified"`` DH (Craig 1989; Franka here): T_i = Rx(α_i) · Tx(a_i) · Rz(q_i + θ0_i) ·
    Tz(d_i), where row i holds the a and α Craig writes a_{i−1}, α_{i−1} (the ones that come
    before joint i).

* ``flange`` is DH frame n ← mechanical flange (the controller's flange frame, UR's
  ``tool0``, Franka's F): it makes the DH convention and the controller's flange agree.
* ``beta`` (n,) rad (Hayati and Mirmirani 1985), zero in every nominal model: a rotation
  Ry(β_i) appended to joint i's transform (standard: … Rx(α_i) Ry(β_i); modified:
  Rx(α_i) Ry(β_i) Tx(a_i) …) — the misalignment about y that DH cannot express when two
  consecutive joint axes are parallel; an identified arm (docs/kinematics.md) may carry it.

* joint types, signs and couplings (``joint_types``, ``joint_map``; both optional): row i's
  joint value is x_i = Σ_j M_ij q_j with ``joint_map`` M (m rows × n joints; None: the
  identity, x = q), so a sign is M_ii = −1, FANUC's J2/J3 coupling θ3 = q3 + c·q2 is M_32 = c,
  and a passive row that mimics another joint (a URDF ``<mimic>``) has no column of its own
  (m > n). A ``"revolute"`` row adds x_i (rad) to θ; a ``"prismatic"`` row adds x_i (mm) to d
  (its θ0 is then the fixed angle). Joint limits are per joint q_j (rad, or mm for a
  prismatic one).
* ``root`` (optional, None: identity) is robot base ← DH frame 0, a fixed transform inside the
  controller's A: a chain read from a URDF whose base link is not DH frame 0 has it.

So the flange in the world is ``forward(arm, q)`` = base · root · T_1 ⋯ T_m · flange, and in the
robot's own base frame (what a controller reports, the tmscal A) ``base_from_flange(arm, q)`` =
root · T_1 ⋯ T_m · flange.

The geometric parameter vector (``Arm.geometry_vector``, names ``Arm.geometry_names``), in this
one order: per joint i = 1…n ``theta0_i`` rad, ``d_i`` mm, ``a_i`` mm, ``alpha_i`` rad (the DH
row); ``base_roll/pitch/yaw`` rad and ``base_x/y/z`` mm (base = Trans(xyz) · Rz(yaw) Ry(pitch)
Rx(roll)); ``flange_roll/pitch/yaw`` rad and ``flange_x/y/z`` mm (the same form for
``flange``). 4m + 12 parameters (m DH rows; m = n without passive rows). Their pose
Jacobian: :mod:`.jacobian`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ...geometry import rot_x, rot_y, rot_z

__all__ = ["Arm", "CONVENTIONS", "JOINT_TYPES", "forward", "base_from_flange", "joint_frames",
           "pose_from_rpy", "rpy_from_matrix", "dh_matrices", "row_transforms", "check_joints",
           "DEVIATION_KINDS", "split_deviation", "deviation_units"]

#: the DH conventions an arm's table may be written in (module docstring)
CONVENTIONS = ("standard", "modified")
#: the joint types a DH row may have (module docstring)
JOINT_TYPES = ("revolute", "prismatic")
_POSE_NAMES = ("roll", "pitch", "yaw", "x", "y", "z")
_POSE_UNITS = ("rad",) * 3 + ("mm",) * 3


def pose_from_rpy(rpy: Any, xyz: Any) -> np.ndarray:
    """4×4 pose (mm) Trans(xyz) · Rz(yaw) · Ry(pitch) · Rx(roll) from ``rpy`` = (roll, pitch,
    yaw) rad and ``xyz`` mm (fixed axes, roll applied first)."""
    r, p, y = (float(v) for v in rpy)
    T = np.eye(4)
    T[:3, :3] = rot_z(y) @ rot_y(p) @ rot_x(r)
    T[:3, 3] = np.asarray(xyz, dtype=float)
    return T


def rpy_from_matrix(R: Any) -> np.ndarray:
    """(roll, pitch, yaw) rad of a rotation R = Rz(yaw) Ry(pitch) Rx(roll) (3×3 or the 3×3 block
    of a 4×4); pitch in [−π/2, π/2]. At pitch = ±π/2 (gimbal lock) roll is set to 0."""
    R = np.asarray(R, dtype=float)[:3, :3]
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(R[2, 0]) < 1.0 - 1e-12:
        return np.array([math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])])
    return np.array([0.0, pitch, math.atan2(-R[0, 1], R[1, 1])])


def _pose6(T: np.ndarray) -> np.ndarray:
    return np.concatenate([rpy_from_matrix(T), T[:3, 3]])


@dataclass(frozen=True)
class Arm:
    """A serial arm's geometry (module docstring; docs/kinematics.md).

    ``name``: the arm's name (a registry name such as ``"ur5e"``, or any label); ``dh``: (m, 4)
    rows [θ0 rad, d mm, a mm, α rad] in ``convention`` ("standard" or "modified"); ``base``:
    4×4 mm, world ← robot base; ``flange``: 4×4 mm, DH frame m ← the controller's flange;
    ``joint_limits_rad``: (n, 2) [low, high] per joint, rad (mm for a prismatic joint; None:
    ±2π each, ±1000 mm for a prismatic one); ``joint_types``: one of :data:`JOINT_TYPES` per DH
    row (None: all revolute); ``joint_map``: (m, n) joint values → row values (None: the
    identity); ``root``: 4×4 mm, robot base ← DH frame 0 (None: identity) (module
    docstring)."""

    name: str
    dh: np.ndarray
    base: np.ndarray = field(default_factory=lambda: np.eye(4))
    joint_limits_rad: np.ndarray | None = None
    convention: str = "standard"
    flange: np.ndarray = field(default_factory=lambda: np.eye(4))
    beta: np.ndarray | None = None
    joint_types: tuple[str, ...] | None = None
    joint_map: np.ndarray | None = None
    root: np.ndarray | None = None

    def __post_init__(self) -> None:
        dh = np.array(self.dh, dtype=float)
        if dh.ndim != 2 or dh.shape[1] != 4 or len(dh) == 0 or not np.all(np.isfinite(dh)):
            raise ValueError(f"dh must be a finite (n, 4) array, got shape {dh.shape}")
        if self.convention not in CONVENTIONS:
            raise ValueError(f"convention must be one of {', '.join(CONVENTIONS)}, got "
                             f"{self.convention!r}")
        m = len(dh)
        types = ("revolute",) * m if self.joint_types is None else tuple(self.joint_types)
        if len(types) != m or any(t not in JOINT_TYPES for t in types):
            raise ValueError(f"joint_types must name {m} joint types, each one of "
                             f"{', '.join(JOINT_TYPES)}")
        jmap = None
        if self.joint_map is not None:
            jmap = np.array(self.joint_map, dtype=float)
            if jmap.ndim != 2 or jmap.shape[0] != m or not 1 <= jmap.shape[1] <= m \
                    or not np.all(np.isfinite(jmap)):
                raise ValueError(f"joint_map must be a finite ({m}, n) array with 1 ≤ n ≤ {m}, "
                                 f"got shape {jmap.shape}")
            for i in range(m):
                if not jmap[i].any():
                    raise ValueError(f"joint_map: DH row {i + 1} is moved by no joint")
            for j in range(jmap.shape[1]):
                rows = {types[i] for i in np.flatnonzero(jmap[:, j])}
                if not rows:
                    raise ValueError(f"joint_map: joint {j + 1} moves no DH row")
                if len(rows) > 1:
                    raise ValueError(f"joint_map: joint {j + 1} moves a revolute and a "
                                     "prismatic row (a coupling within one joint type only)")
            if jmap.shape == (m, m) and np.array_equal(jmap, np.eye(m)):
                jmap = None
        n = m if jmap is None else jmap.shape[1]
        qtypes = types if jmap is None else \
            tuple(types[int(np.flatnonzero(jmap[:, j])[0])] for j in range(n))
        lim = self.joint_limits_rad
        lim = np.array([[-1000.0, 1000.0] if t == "prismatic" else [-2 * math.pi, 2 * math.pi]
                        for t in qtypes]) if lim is None else np.array(lim, dtype=float)
        if lim.shape != (n, 2) or not np.all(np.isfinite(lim)) \
                or np.any(lim[:, 0] > lim[:, 1]):
            raise ValueError(f"joint_limits_rad must be finite, ({n}, 2), with low ≤ high")
        root = None
        if self.root is not None:
            root = np.array(self.root, dtype=float)
            if root.shape != (4, 4) or not np.all(np.isfinite(root)):
                raise ValueError("root must be a finite 4×4 array")
            if np.array_equal(root, np.eye(4)):
                root = None
        for key in ("base", "flange"):
            arr = np.array(getattr(self, key), dtype=float)
            if arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
                raise ValueError(f"{key} must be a finite 4×4 array")
            object.__setattr__(self, key, arr)
        beta = np.zeros(len(dh)) if self.beta is None else np.array(self.beta, dtype=float)
        if beta.shape != (len(dh),) or not np.all(np.isfinite(beta)):
            raise ValueError(f"beta must be a finite array of {len(dh)} angles (rad)")
        object.__setattr__(self, "dh", dh)
        object.__setattr__(self, "joint_limits_rad", lim)
        object.__setattr__(self, "beta", beta)
        object.__setattr__(self, "joint_types", None if all(t == "revolute" for t in types)
                           else types)
        object.__setattr__(self, "joint_map", jmap)
        object.__setattr__(self, "root", root)

    @property
    def n_joints(self) -> int:
        """Number of joints n (the joint values q a controller reports)."""
        return len(self.dh) if self.joint_map is None else int(self.joint_map.shape[1])

    @property
    def n_rows(self) -> int:
        """Number of DH rows m (n, plus the passive rows that mimic a joint)."""
        return len(self.dh)

    @property
    def types(self) -> tuple[str, ...]:
        """The joint type of each DH row ("revolute" or "prismatic")."""
        return ("revolute",) * len(self.dh) if self.joint_types is None else self.joint_types

    @property
    def joint_kinds(self) -> tuple[str, ...]:
        """The type of each joint q_j (that of the rows it moves)."""
        if self.joint_map is None:
            return self.types
        return tuple(self.types[int(np.flatnonzero(self.joint_map[:, j])[0])]
                     for j in range(self.n_joints))

    def row_values(self, q: Any) -> np.ndarray:
        """The row values x (…, m) of joint values q (…, n): x = M q (module docstring); rad
        for a revolute row, mm for a prismatic one."""
        q = np.asarray(q, dtype=float)
        return q if self.joint_map is None else q @ self.joint_map.T

    # --- the geometric parameter vector ------------------------------------------------------

    def geometry_names(self) -> list[str]:
        """Names of the geometric parameters, in their one order (module docstring)."""
        per = [f"{k}_{i + 1}" for i in range(self.n_rows)
               for k in ("theta0", "d", "a", "alpha")]
        return per + [f"base_{k}" for k in _POSE_NAMES] + [f"flange_{k}" for k in _POSE_NAMES]

    def geometry_units(self) -> list[str]:
        """Unit of each geometric parameter: "rad" or "mm"."""
        return ["rad", "mm", "mm", "rad"] * self.n_rows + list(_POSE_UNITS) * 2

    def geometry_vector(self) -> np.ndarray:
        """The geometric parameters (4n + 12,), in the order of :meth:`geometry_names`."""
        return np.concatenate([self.dh.ravel(), _pose6(self.base), _pose6(self.flange)])

    def with_geometry(self, p: Any) -> Any:
        """A copy with the geometric parameters ``p`` (order of :meth:`geometry_names`); every
        other field (of a subclass too) is kept."""
        p = np.asarray(p, dtype=float)
        k = 4 * self.n_rows
        if p.shape != (k + 12,):
            raise ValueError(f"p must have {k + 12} entries, got shape {p.shape}")
        return replace(self, dh=p[:k].reshape(-1, 4),
                       base=pose_from_rpy(p[k:k + 3], p[k + 3:k + 6]),
                       flange=pose_from_rpy(p[k + 6:k + 9], p[k + 9:k + 12]))

    def deviation(self, name: str) -> float:
        """The value of one DH parameter or β by name ("theta0_1", "d_2", "a_3", "alpha_4",
        "beta_2"; rad or mm)."""
        kind, i = split_deviation(name, self.n_rows)
        return float(self.beta[i] if kind == "beta" else self.dh[i, DEVIATION_KINDS.index(kind)])

    def with_deviations(self, names: list[str], delta: Any) -> Any:
        """A copy with the named DH parameters and β changed by ``delta`` (rad or mm, one per
        name); every other field (of a subclass too) is kept."""
        dh, beta = self.dh.copy(), self.beta.copy()
        for n, d in zip(names, np.asarray(delta, dtype=float).ravel(), strict=True):
            kind, i = split_deviation(n, self.n_rows)
            if kind == "beta":
                beta[i] += d
            else:
                dh[i, DEVIATION_KINDS.index(kind)] += d
        return replace(self, dh=dh, beta=beta)

    # --- plain types ---------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """Plain lists and strings (for YAML/JSON): name, convention, dh, base, flange,
        joint_limits_rad (and beta, joint_types, joint_map, root when not the default) — the
        keys of :meth:`from_dict`."""
        out = {"name": self.name, "convention": self.convention, "dh": self.dh.tolist(),
               "base": self.base.tolist(), "flange": self.flange.tolist(),
               "joint_limits_rad": self.joint_limits_rad.tolist()}
        if np.any(self.beta != 0):
            out["beta"] = self.beta.tolist()
        if self.joint_types is not None:
            out["joint_types"] = list(self.joint_types)
        for key in ("joint_map", "root"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key).tolist()
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Arm:
        """The arm :meth:`to_dict` wrote (``convention`` and ``flange`` optional: standard,
        identity). Raises ValueError naming a missing or bad key."""
        try:
            return cls(name=d["name"], dh=d["dh"], base=d["base"],
                       joint_limits_rad=d["joint_limits_rad"],
                       convention=d.get("convention", "standard"),
                       flange=d.get("flange", np.eye(4)), beta=d.get("beta"),
                       joint_types=d.get("joint_types"), joint_map=d.get("joint_map"),
                       root=d.get("root"))
        except KeyError as e:
            raise ValueError(f"arm: missing key {e.args[0]!r}") from None
        except TypeError as e:
            raise ValueError(f"arm: {e}") from None


#: the per-joint parameters a deviation may name, in each joint's order; "beta" is the
#: Hayati angle (module docstring)
DEVIATION_KINDS = ("theta0", "d", "a", "alpha", "beta")


def split_deviation(name: str, n: int) -> tuple[str, int]:
    """("theta0", 0) for "theta0_1": the kind and the 0-based joint of a deviation's name;
    ValueError naming it when it is not one of an n-joint arm's."""
    kind, _, idx = str(name).rpartition("_")
    if kind not in DEVIATION_KINDS or not idx.isdigit() or not 1 <= int(idx) <= n:
        raise ValueError(f"unknown kinematic parameter {name!r} (expected theta0_i, d_i, a_i, "
                         f"alpha_i or beta_i with i in 1…{n})")
    return kind, int(idx) - 1


def deviation_units(names: list[str]) -> list[str]:
    """"rad" or "mm" for each deviation name."""
    return ["mm" if str(n).rpartition("_")[0] in ("d", "a") else "rad" for n in names]


def check_joints(arm: Arm, q: Any) -> np.ndarray:
    """q (…, n) as a float array; ValueError when its last axis is not the arm's n joints."""
    q = np.asarray(q, dtype=float)
    if q.ndim == 0 or q.shape[-1] != arm.n_joints:
        raise ValueError(f"q must have {arm.n_joints} joint values on its last axis, "
                         f"got shape {q.shape}")
    return q


def dh_matrices(dh: np.ndarray, q: np.ndarray, convention: str = "standard",
                beta: np.ndarray | None = None,
                prismatic: np.ndarray | None = None) -> np.ndarray:
    """(…, m, 4, 4) joint transforms T_i (module docstring) of the DH rows ``dh`` (m, 4) for
    row values q (…, m) (rad; mm for a row where the boolean ``prismatic`` (m,) is set: it
    adds to d, not θ), with the Hayati angles ``beta`` (m,) rad when given and not zero;
    lengths in mm."""
    if prismatic is None or not np.any(prismatic):
        th = q + dh[:, 0]
        d = dh[:, 1]
    else:
        th = np.where(prismatic, 0.0, q) + dh[:, 0]
        d = np.where(prismatic, q, 0.0) + dh[:, 1]
    a, al = dh[:, 2], dh[:, 3]
    ct, st = np.cos(th), np.sin(th)
    ca, sa = np.broadcast_to(np.cos(al), th.shape), np.broadcast_to(np.sin(al), th.shape)
    d, a = np.broadcast_to(d, th.shape), np.broadcast_to(a, th.shape)
    T = np.zeros(th.shape + (4, 4))
    if convention == "standard":   # Rz(θ) Tz(d) Tx(a) Rx(α)
        T[..., 0, 0], T[..., 0, 1], T[..., 0, 2], T[..., 0, 3] = ct, -st * ca, st * sa, a * ct
        T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = st, ct * ca, -ct * sa, a * st
        T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = sa, ca, d
    elif convention == "modified":  # Rx(α) Tx(a) Rz(θ) Tz(d)
        T[..., 0, 0], T[..., 0, 1], T[..., 0, 3] = ct, -st, a
        T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = st * ca, ct * ca, -sa, -sa * d
        T[..., 2, 0], T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = st * sa, ct * sa, ca, ca * d
    else:
        raise ValueError(f"convention must be one of {', '.join(CONVENTIONS)}, got "
                         f"{convention!r}")
    T[..., 3, 3] = 1.0
    if beta is not None and np.any(beta != 0):
        Ry = np.zeros((len(beta), 4, 4))
        Ry[:, :3, :3] = rot_y(np.asarray(beta, dtype=float))
        Ry[:, 3, 3] = 1.0
        if convention == "standard":   # … Rx(α) Ry(β)
            T = T @ Ry
        else:                          # Rx(α) Ry(β) Tx(a) Rz Tz = Rx(α) Ry(β) Rx(α)ᵀ · T
            Rx = np.zeros((len(beta), 4, 4))
            Rx[:, :3, :3] = rot_x(dh[:, 3])
            Rx[:, 3, 3] = 1.0
            T = (Rx @ Ry @ np.swapaxes(Rx, -1, -2)) @ T
    return T


def row_transforms(arm: Arm, q: Any) -> np.ndarray:
    """(…, m, 4, 4) the transforms T_i of the arm's DH rows (module docstring) for joint
    values q (…, n) rad (mm for a prismatic joint)."""
    q = check_joints(arm, q)
    pris = None if arm.joint_types is None else \
        np.array([t == "prismatic" for t in arm.joint_types])
    return dh_matrices(arm.dh, arm.row_values(q), arm.convention, arm.beta, pris)


def joint_frames(arm: Arm, q: Any) -> np.ndarray:
    """World ← frame i for i = 0…m, shape (…, m + 1, 4, 4) mm, for joint values q (…, n) rad:
    frame 0 is DH frame 0 (``arm.base`` · ``arm.root``), frame i the DH frame after row i
    (frame m is the last DH frame; the flange is frame m · ``arm.flange``)."""
    q = check_joints(arm, q)
    T = row_transforms(arm, q)
    out = np.empty(q.shape[:-1] + (arm.n_rows + 1, 4, 4))
    out[..., 0, :, :] = arm.base if arm.root is None else arm.base @ arm.root
    for i in range(arm.n_rows):
        out[..., i + 1, :, :] = out[..., i, :, :] @ T[..., i, :, :]
    return out


def base_from_flange(arm: Arm, q: Any) -> np.ndarray:
    """Robot base ← flange (…, 4, 4) mm for joint values q (…, n) rad: root · T_1 ⋯ T_m ·
    flange, without ``arm.base`` (what the controller reports: the tmscal A)."""
    q = check_joints(arm, q)
    T = row_transforms(arm, q)
    out = np.broadcast_to(np.eye(4) if arm.root is None else arm.root,
                          q.shape[:-1] + (4, 4)).copy()
    for i in range(arm.n_rows):
        out = out @ T[..., i, :, :]
    return out @ arm.flange


def forward(arm: Arm, q: Any) -> np.ndarray:
    """World ← flange (…, 4, 4) mm for joint values q (…, n) rad: base · root · T_1 ⋯ T_m · flange
    (equal to :func:`base_from_flange` when ``arm.base`` is the identity)."""
    return arm.base @ base_from_flange(arm, q)
