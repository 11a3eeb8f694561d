"""The arm model of force-torque self-calibration (Joubair, Zhao, Bigras and Bonev 2016):
a standard-DH serial arm on a (possibly tilted) base, a wrist force-torque sensor on its flange
and a tool whose weight the sensor reads. Pure numerics, no I/O; docs/selfcal.md ("The model").

Frames and units: the world has z up and gravity (0, 0, −g); ``base`` is world ← robot base;
joint i moves by T_i = Rz(q_i + θ0_i) · Tz(d_i) · Tx(a_i) · Rx(α_i) (standard DH, angles rad,
lengths mm); ``forward`` gives world ← flange (4×4, mm); ``flange_from_sensor`` places the
sensor; the tool's centre of gravity is in the sensor frame (mm); wrenches are
[Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame.

The parameter vector p (``ArmModel.vector``, names from ``ArmModel.parameter_names``), in
this one order: per joint i = 1…n ``theta0_i`` rad, ``d_i`` mm, ``a_i`` mm, ``alpha_i`` rad;
``base_roll/pitch/yaw`` rad and ``base_x/y/z`` mm (base = Trans(xyz) · Rz(yaw) Ry(pitch)
Rx(roll)); ``sensor_roll/pitch/yaw`` rad and ``sensor_x/y/z`` mm (the same form for
``flange_from_sensor``); ``mg`` N (tool weight: the wrench depends on m·g only); ``cog_x/y/z``
mm; ``f0_x/y/z`` N and ``t0_x/y/z`` N·m (sensor bias). 4n + 22 parameters (46 for six joints).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ...geometry import rot_x, rot_y, rot_z

__all__ = ["ArmModel", "G_STANDARD", "UR5E", "VS060", "NOMINAL", "forward", "joint_frames",
           "wrench", "jacobian", "perturb", "rpy_from_matrix", "pose_from_rpy"]

#: standard gravity, m/s²; the tool weight parameter is ``tool_mass_kg · G_STANDARD`` (N)
G_STANDARD = 9.80665
_TAIL = ["base_roll", "base_pitch", "base_yaw", "base_x", "base_y", "base_z",
         "sensor_roll", "sensor_pitch", "sensor_yaw", "sensor_x", "sensor_y", "sensor_z",
         "mg", "cog_x", "cog_y", "cog_z", "f0_x", "f0_y", "f0_z", "t0_x", "t0_y", "t0_z"]
_TAIL_UNITS = ["rad"] * 3 + ["mm"] * 3 + ["rad"] * 3 + ["mm"] * 3 + ["N"] + ["mm"] * 3 \
    + ["N"] * 3 + ["N·m"] * 3


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


@dataclass(frozen=True)
class ArmModel:
    """A serial arm with a wrist force-torque sensor and a tool (docs/selfcal.md).

    ``dh``: (n, 4) rows [θ0 rad, d mm, a mm, α rad], standard DH
    (T_i = Rz(q_i + θ0) Tz(d) Tx(a) Rx(α)); ``base``: 4×4 mm, world ← base (world z up,
    gravity (0, 0, −g)); ``flange_from_sensor``: 4×4 mm, the sensor mounting;
    ``tool_mass_kg``: the mass the sensor carries; ``tool_cog_mm``: its centre of gravity in
    the sensor frame (3,) mm; ``bias``: (6,) the sensor offset [f0 N; τ0 N·m];
    ``joint_limits_rad``: (n, 2) [low, high] rad."""

    name: str
    dh: np.ndarray
    base: np.ndarray = field(default_factory=lambda: np.eye(4))
    flange_from_sensor: np.ndarray = field(default_factory=lambda: np.eye(4))
    tool_mass_kg: float = 1.5
    tool_cog_mm: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 60.0]))
    bias: np.ndarray = field(default_factory=lambda: np.zeros(6))
    joint_limits_rad: np.ndarray | None = None

    def __post_init__(self) -> None:
        dh = np.array(self.dh, dtype=float)
        if dh.ndim != 2 or dh.shape[1] != 4 or not np.all(np.isfinite(dh)):
            raise ValueError(f"dh must be a finite (n, 4) array, got shape {dh.shape}")
        lim = self.joint_limits_rad
        lim = np.tile([-2 * math.pi, 2 * math.pi], (len(dh), 1)) if lim is None \
            else np.array(lim, dtype=float)
        if lim.shape != (len(dh), 2) or np.any(lim[:, 0] > lim[:, 1]):
            raise ValueError(f"joint_limits_rad must be ({len(dh)}, 2) with low ≤ high")
        for key, val, shape in (("base", self.base, (4, 4)),
                                ("flange_from_sensor", self.flange_from_sensor, (4, 4)),
                                ("tool_cog_mm", self.tool_cog_mm, (3,)), ("bias", self.bias, (6,))):
            arr = np.array(val, dtype=float)
            if arr.shape != shape or not np.all(np.isfinite(arr)):
                raise ValueError(f"{key} must be a finite array of shape {shape}")
            object.__setattr__(self, key, arr)
        object.__setattr__(self, "dh", dh)
        object.__setattr__(self, "joint_limits_rad", lim)
        object.__setattr__(self, "tool_mass_kg", float(self.tool_mass_kg))

    @property
    def n_joints(self) -> int:
        """Number of joints n."""
        return len(self.dh)

    def parameter_names(self) -> list[str]:
        """Names of the parameter vector p, in its one order (module docstring)."""
        per = [f"{k}_{i + 1}" for i in range(self.n_joints)
               for k in ("theta0", "d", "a", "alpha")]
        return per + list(_TAIL)

    def parameter_units(self) -> list[str]:
        """Unit of each entry of p: "rad", "mm", "N" or "N·m"."""
        return ["rad", "mm", "mm", "rad"] * self.n_joints + list(_TAIL_UNITS)

    def vector(self) -> np.ndarray:
        """The parameter vector p (4n + 22,), in the order of :meth:`parameter_names`."""
        return np.concatenate([
            self.dh.ravel(), rpy_from_matrix(self.base), self.base[:3, 3],
            rpy_from_matrix(self.flange_from_sensor), self.flange_from_sensor[:3, 3],
            [self.tool_mass_kg * G_STANDARD], self.tool_cog_mm, self.bias])

    def with_vector(self, p: Any) -> ArmModel:
        """A copy of this model with the parameters p (order of :meth:`parameter_names`);
        the tool mass becomes p["mg"] / ``G_STANDARD``."""
        p = np.asarray(p, dtype=float)
        k = 4 * self.n_joints
        if p.shape != (k + len(_TAIL),):
            raise ValueError(f"p must have {k + len(_TAIL)} entries, got shape {p.shape}")
        return replace(self, dh=p[:k].reshape(-1, 4),
                       base=pose_from_rpy(p[k:k + 3], p[k + 3:k + 6]),
                       flange_from_sensor=pose_from_rpy(p[k + 6:k + 9], p[k + 9:k + 12]),
                       tool_mass_kg=p[k + 12] / G_STANDARD, tool_cog_mm=p[k + 13:k + 16],
                       bias=p[k + 16:k + 22])

    def to_dict(self) -> dict[str, Any]:
        """Plain lists and floats (for YAML/JSON): name, dh, base, flange_from_sensor,
        tool_mass_kg, tool_cog_mm, bias, joint_limits_rad — the keys of :meth:`from_dict`."""
        return {"name": self.name, "dh": self.dh.tolist(), "base": self.base.tolist(),
                "flange_from_sensor": self.flange_from_sensor.tolist(),
                "tool_mass_kg": self.tool_mass_kg, "tool_cog_mm": self.tool_cog_mm.tolist(),
                "bias": self.bias.tolist(), "joint_limits_rad": self.joint_limits_rad.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ArmModel:
        """The model :meth:`to_dict` wrote. Raises ValueError naming a missing or bad key."""
        try:
            return cls(**{k: d[k] for k in ("name", "dh", "base", "flange_from_sensor",
                                              "tool_mass_kg", "tool_cog_mm", "bias",
                                              "joint_limits_rad")})
        except KeyError as e:
            raise ValueError(f"arm model: missing key {e.args[0]!r}") from None
        except TypeError as e:
            raise ValueError(f"arm model: {e}") from None


_HALF_PI = math.pi / 2
#: Universal Robots UR5e, the DH parameters Universal Robots publishes for it (d1 162.5,
#: a2 −425, a3 −392.2, d4 133.3, d5 99.7, d6 99.6 mm; α = π/2, 0, 0, π/2, −π/2, 0); joint
#: ranges ±360° as specified, the elbow ±180° (the arm cannot pass through itself). Base at
#: the world origin, sensor on the flange, a 1.5 kg tool 60 mm out along the sensor axis.
UR5E = ArmModel(
    name="ur5e",
    dh=np.array([[0.0, 162.5, 0.0, _HALF_PI], [0.0, 0.0, -425.0, 0.0],
                 [0.0, 0.0, -392.2, 0.0], [0.0, 133.3, 0.0, _HALF_PI],
                 [0.0, 99.7, 0.0, -_HALF_PI], [0.0, 99.6, 0.0, 0.0]]),
    joint_limits_rad=np.array([[-2 * math.pi, 2 * math.pi]] * 2 + [[-math.pi, math.pi]]
                              + [[-2 * math.pi, 2 * math.pi]] * 3))

#: DENSO VS-060, an approximation: DENSO publishes link lengths rather than DH parameters;
#: these are built from the joint origins of DENSO's own ROS description of the VS-060
#: (denso_robot_ros, vs060 URDF): J2 345 mm above the base, upper arm 305 mm, forearm 300 mm
#: (164.5 + 135.5) with a 10 mm offset, flange 70 mm past J5; q = 0 is the arm straight up
#: with the flange frame parallel to the base frame, as there. Joint limits from the same
#: description (±170°, ±120°, −125°…+155°, ±270°, ±120°, ±360°).
VS060 = ArmModel(
    name="vs060",
    dh=np.array([[0.0, 345.0, 0.0, -_HALF_PI], [-_HALF_PI, 0.0, 305.0, 0.0],
                 [-_HALF_PI, 0.0, 10.0, -_HALF_PI], [0.0, 300.0, 0.0, _HALF_PI],
                 [0.0, 0.0, 0.0, -_HALF_PI], [math.pi, 70.0, 0.0, 0.0]]),
    joint_limits_rad=np.array([[-2.96706, 2.96706], [-2.094395, 2.094395],
                               [-2.181662, 2.70526], [-4.712389, 4.712389],
                               [-2.094395, 2.094395], [-6.283185, 6.283185]]))

#: nominal models by name ("ur5e", "vs060")
NOMINAL: dict[str, ArmModel] = {"ur5e": UR5E, "vs060": VS060}


def _check_q(model: ArmModel, q: Any) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.ndim == 0 or q.shape[-1] != model.n_joints:
        raise ValueError(f"q must have {model.n_joints} joint values on its last axis, "
                         f"got shape {q.shape}")
    return q


def _dh_matrices(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(…, n, 4, 4) standard-DH joint transforms for joint values q (…, n) rad."""
    th = q + dh[:, 0]
    d, a, al = dh[:, 1], dh[:, 2], dh[:, 3]
    ct, st = np.cos(th), np.sin(th)
    ca, sa = np.broadcast_to(np.cos(al), th.shape), np.broadcast_to(np.sin(al), th.shape)
    T = np.zeros(th.shape + (4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2], T[..., 0, 3] = ct, -st * ca, st * sa, a * ct
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = st, ct * ca, -ct * sa, a * st
    T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = sa, ca, np.broadcast_to(d, th.shape)
    T[..., 3, 3] = 1.0
    return T


def joint_frames(model: ArmModel, q: Any) -> np.ndarray:
    """World ← frame i for i = 0…n, shape (…, n + 1, 4, 4) mm: frame 0 is the base
    (``model.base``), frame n the flange, frame i the DH frame after joint i; q (…, n) rad."""
    q = _check_q(model, q)
    T = _dh_matrices(model.dh, q)
    out = np.empty(q.shape[:-1] + (model.n_joints + 1, 4, 4))
    out[..., 0, :, :] = model.base
    for i in range(model.n_joints):
        out[..., i + 1, :, :] = out[..., i, :, :] @ T[..., i, :, :]
    return out


def forward(model: ArmModel, q: Any) -> np.ndarray:
    """World ← flange (…, 4, 4) mm for joint values q (…, n) rad, ``model.base`` included
    (the tmscal A, base_from_flange, when the base is the world)."""
    q = _check_q(model, q)
    T = _dh_matrices(model.dh, q)
    out = np.broadcast_to(model.base, q.shape[:-1] + (4, 4)).copy()
    for i in range(model.n_joints):
        out = out @ T[..., i, :, :]
    return out


def _up_in_sensor(model: ArmModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(frames (…, n+1, 4, 4), u (…, 3)): u = R_wsᵀ e_z, the world's up in the sensor frame."""
    F = joint_frames(model, q)
    R_ws = F[..., -1, :3, :3] @ model.flange_from_sensor[:3, :3]
    return F, R_ws[..., 2, :]


def wrench(model: ArmModel, q: Any) -> np.ndarray:
    """The gravity wrench the sensor reads, (…, 6) [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor
    frame, for joint values q (…, n) rad: f = R_wsᵀ (m g_w) + f0, τ = c × (R_wsᵀ m g_w) + τ0
    with g_w = (0, 0, −g), R_ws the world ← sensor rotation and c the tool's centre of gravity
    (mm, converted to m)."""
    _, u = _up_in_sensor(model, _check_q(model, q))
    f = -model.tool_mass_kg * G_STANDARD * u
    tau = np.cross(model.tool_cog_mm * 1e-3, f)
    return np.concatenate([f + model.bias[:3], tau + model.bias[3:]], axis=-1)


def _rotation_axes(model: ArmModel, F: np.ndarray) -> np.ndarray:
    """World axes ω (…, 4n + 6, 3) of the rotational parameters, in the order θ0_i, α_i (per
    joint, interleaved), base roll/pitch/yaw, sensor roll/pitch/yaw: d R_ws / d φ = [ω]× R_ws."""
    n = model.n_joints
    shape = F.shape[:-3]
    axes = np.zeros(shape + (2 * n + 6, 3))
    axes[..., 0:2 * n:2, :] = F[..., :n, :3, 2]          # θ0_i: z of frame i−1
    axes[..., 1:2 * n:2, :] = F[..., 1:, :3, 0]          # α_i: x of frame i
    r, p, y = rpy_from_matrix(model.base)
    axes[..., 2 * n, :] = rot_z(y) @ rot_y(p) @ [1.0, 0, 0]
    axes[..., 2 * n + 1, :] = rot_z(y) @ [0, 1.0, 0]
    axes[..., 2 * n + 2, :] = [0, 0, 1.0]
    r, p, y = rpy_from_matrix(model.flange_from_sensor)
    R_wf = F[..., -1, :3, :3]
    axes[..., 2 * n + 3, :] = R_wf @ (rot_z(y) @ rot_y(p) @ [1.0, 0, 0])
    axes[..., 2 * n + 4, :] = R_wf @ (rot_z(y) @ [0, 1.0, 0])
    axes[..., 2 * n + 5, :] = R_wf @ [0, 0, 1.0]
    return axes


def jacobian(model: ArmModel, q: Any) -> np.ndarray:
    """d wrench / d p, analytic, shape (6m, 4n + 22) for q (m, n) rad: rows are the six
    channels of configuration 0, then of 1, …; columns in the order of
    ``model.parameter_names()`` (units: N or N·m per rad, mm, N, N·m). Lengths (d, a, base and
    sensor positions) do not enter the gravity wrench: their columns are zero."""
    q = np.atleast_2d(_check_q(model, q))
    if q.ndim != 2:
        raise ValueError(f"q must be (m, {model.n_joints}), got shape {q.shape}")
    m, n = q.shape[0], model.n_joints
    F, u = _up_in_sensor(model, q)
    mg = model.tool_mass_kg * G_STANDARD
    c = model.tool_cog_mm * 1e-3
    R_ws = F[:, -1, :3, :3] @ model.flange_from_sensor[:3, :3]          # (m, 3, 3)
    omega = _rotation_axes(model, F)                                     # (m, K, 3)
    # du/dφ = −R_wsᵀ (ω × e_z); df = −mg du; dτ = c × df
    w_x_ez = np.stack([omega[..., 1], -omega[..., 0], np.zeros_like(omega[..., 0])], -1)
    du = -np.einsum("mji,mkj->mki", R_ws, w_x_ez)
    df = -mg * du
    dtau = np.cross(c, df)
    J = np.zeros((m, 6, 4 * n + len(_TAIL)))
    rot_cols = [4 * i for i in range(n)] + [4 * i + 3 for i in range(n)]
    rot_cols = sorted(rot_cols) + [4 * n + k for k in (0, 1, 2, 6, 7, 8)]
    J[:, :3, rot_cols] = df.transpose(0, 2, 1)
    J[:, 3:, rot_cols] = dtau.transpose(0, 2, 1)
    k = 4 * n + 12
    f_grav = -mg * u
    J[:, :3, k] = -u
    J[:, 3:, k] = np.cross(c, -u)
    # τ = c × f: dτ/dc (per mm) = −[f]× · 1e-3
    fx, fy, fz = f_grav[:, 0], f_grav[:, 1], f_grav[:, 2]
    zero = np.zeros(m)
    skew_f = np.stack([np.stack([zero, -fz, fy], -1), np.stack([fz, zero, -fx], -1),
                       np.stack([-fy, fx, zero], -1)], -2)
    J[:, 3:, k + 1:k + 4] = -skew_f * 1e-3
    J[:, :, k + 4:k + 10] = np.eye(6)
    return J.reshape(6 * m, -1)


def perturb(model: ArmModel, rng: np.random.Generator, names: list[str] | None = None,
            length_mm: float = 2.0, angle_deg: float = 1.0) -> ArmModel:
    """A copy of ``model`` with uniform errors on the named parameters (all of them when
    ``names`` is None): ±``length_mm`` on those in mm (link lengths, base and sensor
    positions, centre of gravity), ±``angle_deg`` on those in rad; the weight and the bias
    (N, N·m) are never changed. Joubair et al. 2016 simulate ±2 mm / ±1°."""
    all_names = model.parameter_names()
    chosen = set(all_names if names is None else names)
    unknown = chosen - set(all_names)
    if unknown:
        raise ValueError(f"unknown parameter names: {sorted(unknown)}")
    p = model.vector()
    for i, (name, unit) in enumerate(zip(all_names, model.parameter_units(), strict=True)):
        if name not in chosen or unit not in ("mm", "rad"):
            continue
        size = length_mm if unit == "mm" else math.radians(angle_deg)
        p[i] += rng.uniform(-size, size)
    return model.with_vector(p)
