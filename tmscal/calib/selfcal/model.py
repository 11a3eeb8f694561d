"""The arm model of force-torque self-calibration (Joubair, Zhao, Bigras and Bonev 2016):
a serial arm (:class:`tmscal.calib.kinematics.Arm`: its DH chain, standard or modified, base,
flange and joint limits) on a (possibly tilted) base, a wrist force-torque sensor on its flange
and a tool whose weight the sensor reads. Pure numerics, no I/O; docs/selfcal.md ("The model").

Frames and units: the world has z up and gravity (0, 0, −g); ``base`` is world ← robot base;
joint i moves by its DH transform T_i (standard: Rz(q_i + θ0_i) · Tz(d_i) · Tx(a_i) · Rx(α_i);
docs/kinematics.md for the modified form; angles rad, lengths mm); ``forward`` gives world ←
flange (4×4, mm; ``tmscal.calib.kinematics.forward``, the one DH chain); ``flange_from_sensor``
places the sensor on the flange; the tool's centre of gravity is in the sensor frame (mm);
wrenches are [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame.

The parameter vector p (``ArmModel.vector``, names from ``ArmModel.parameter_names``), in
this one order: per joint i = 1…n ``theta0_i`` rad, ``d_i`` mm, ``a_i`` mm, ``alpha_i`` rad;
``base_roll/pitch/yaw`` rad and ``base_x/y/z`` mm (base = Trans(xyz) · Rz(yaw) Ry(pitch)
Rx(roll)); ``sensor_roll/pitch/yaw`` rad and ``sensor_x/y/z`` mm (the same form for
``flange_from_sensor``); ``mg`` N (tool weight: the wrench depends on m·g only); ``cog_x/y/z``
mm; ``f0_x/y/z`` N and ``t0_x/y/z`` N·m (sensor bias). 4n + 22 parameters (46 for six joints).
The arm's ``flange`` transform is not among them: it is fixed (the sensor mounting absorbs it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..gravity import G_STANDARD, wrench_from_up
from ..kinematics import (
    ARMS,
    Arm,
    joint_frames,
    pose_from_rpy,
    pose_jacobian,
    rpy_from_matrix,
)
from ..kinematics import forward as _serial_forward
from ..kinematics.jacobian import rpy_axes
from ..kinematics.model import check_joints

__all__ = ["ArmModel", "G_STANDARD", "UR5E", "VS060", "NOMINAL", "forward", "joint_frames",
           "wrench", "jacobian", "perturb", "rpy_from_matrix", "pose_from_rpy"]

_TAIL = ["base_roll", "base_pitch", "base_yaw", "base_x", "base_y", "base_z",
         "sensor_roll", "sensor_pitch", "sensor_yaw", "sensor_x", "sensor_y", "sensor_z",
         "mg", "cog_x", "cog_y", "cog_z", "f0_x", "f0_y", "f0_z", "t0_x", "t0_y", "t0_z"]
_TAIL_UNITS = ["rad"] * 3 + ["mm"] * 3 + ["rad"] * 3 + ["mm"] * 3 + ["N"] + ["mm"] * 3 \
    + ["N"] * 3 + ["N·m"] * 3
_KEYS = ("name", "dh", "base", "flange_from_sensor", "tool_mass_kg", "tool_cog_mm", "bias",
         "joint_limits_rad")


@dataclass(frozen=True)
class ArmModel(Arm):
    """A serial arm (an :class:`~tmscal.calib.kinematics.Arm`: ``dh`` rows [θ0 rad, d mm,
    a mm, α rad] in ``convention``, ``base`` 4×4 mm world ← base (world z up, gravity
    (0, 0, −g)), ``flange`` 4×4 mm last DH frame ← flange, ``joint_limits_rad`` (n, 2)) with a
    wrist force-torque sensor and a tool (docs/selfcal.md): ``flange_from_sensor``: 4×4 mm,
    the sensor mounting; ``tool_mass_kg``: the mass the sensor carries; ``tool_cog_mm``: its
    centre of gravity in the sensor frame (3,) mm; ``bias``: (6,) the sensor offset
    [f0 N; τ0 N·m]."""

    flange_from_sensor: np.ndarray = field(default_factory=lambda: np.eye(4))
    tool_mass_kg: float = 1.5
    tool_cog_mm: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 60.0]))
    bias: np.ndarray = field(default_factory=lambda: np.zeros(6))

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.n_rows != self.n_joints:
            raise ValueError(f"{self.name}: self-calibration needs an arm whose every DH row is "
                             f"a joint of its own ({self.n_rows} rows, {self.n_joints} joints: "
                             "a passive, mimicking row)")
        for key, val, shape in (("flange_from_sensor", self.flange_from_sensor, (4, 4)),
                                ("tool_cog_mm", self.tool_cog_mm, (3,)), ("bias", self.bias, (6,))):
            arr = np.array(val, dtype=float)
            if arr.shape != shape or not np.all(np.isfinite(arr)):
                raise ValueError(f"{key} must be a finite array of shape {shape}")
            object.__setattr__(self, key, arr)
        object.__setattr__(self, "tool_mass_kg", float(self.tool_mass_kg))

    @classmethod
    def from_arm(cls, arm: Arm, **sensor: Any) -> ArmModel:
        """The self-calibration model of ``arm`` (its DH chain, convention, base, flange,
        Hayati angles and limits) with the sensor and tool fields ``sensor`` (defaults: sensor
        on the flange, a 1.5 kg tool 60 mm out along the sensor axis, no bias)."""
        return cls(name=arm.name, dh=arm.dh, base=arm.base, joint_limits_rad=arm.joint_limits_rad,
                   convention=arm.convention, flange=arm.flange, beta=arm.beta,
                   joint_types=arm.joint_types, joint_map=arm.joint_map, root=arm.root,
                   **sensor)

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
        """Plain lists, floats and strings (for YAML/JSON): name, convention, dh, base, flange,
        flange_from_sensor, tool_mass_kg, tool_cog_mm, bias, joint_limits_rad — the keys of
        :meth:`from_dict`."""
        return {**super().to_dict(), "flange_from_sensor": self.flange_from_sensor.tolist(),
                "tool_mass_kg": self.tool_mass_kg, "tool_cog_mm": self.tool_cog_mm.tolist(),
                "bias": self.bias.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ArmModel:
        """The model :meth:`to_dict` wrote (``convention`` and ``flange`` optional: standard,
        identity, as older dicts have neither). Raises ValueError naming a missing or bad
        key."""
        try:
            return cls(**{k: d[k] for k in _KEYS},
                       convention=d.get("convention", "standard"),
                       flange=d.get("flange", np.eye(4)))
        except KeyError as e:
            raise ValueError(f"arm model: missing key {e.args[0]!r}") from None
        except TypeError as e:
            raise ValueError(f"arm model: {e}") from None


#: self-calibration models of every registered arm (``tmscal.calib.kinematics.ARMS``), by
#: name: the nominal arm on a level base at the world origin, the sensor on the flange, a
#: 1.5 kg tool 60 mm out along the sensor axis
NOMINAL: dict[str, ArmModel] = {name: ArmModel.from_arm(spec.arm) for name, spec in ARMS.items()}
#: Universal Robots UR5e (``NOMINAL["ur5e"]``; the DH parameters Universal Robots publishes)
UR5E = NOMINAL["ur5e"]
#: DENSO VS-060 (``NOMINAL["vs060"]``), an approximation: DENSO publishes link lengths rather
#: than DH parameters (``tmscal.calib.kinematics.arms`` says where the table comes from)
VS060 = NOMINAL["vs060"]


def forward(model: Any, q: Any) -> np.ndarray:
    """World ← flange (…, 4, 4) mm at joints q (…, n): the DH chain of a serial arm
    (``tmscal.calib.kinematics.forward``), or another mechanism's own ``forward`` (the probe
    frame of :class:`~tmscal.calib.selfcal.study.medrue.MedRUE`)."""
    if isinstance(model, Arm):
        return _serial_forward(model, q)
    return model.forward(q)


def _up_in_sensor(model: ArmModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R_wf (…, 3, 3) world ← flange, R_ws (…, 3, 3) world ← sensor, u (…, 3) = R_wsᵀ e_z,
    the world's up in the sensor frame)."""
    F = joint_frames(model, q)
    R_wf = F[..., -1, :3, :3] @ model.flange[:3, :3]
    R_ws = R_wf @ model.flange_from_sensor[:3, :3]
    return R_wf, R_ws, R_ws[..., 2, :]


def wrench(model: ArmModel, q: Any) -> np.ndarray:
    """The gravity wrench the sensor reads, (…, 6) [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor
    frame, for joint values q (…, n) rad: f = R_wsᵀ (m g_w) + f0, τ = c × (R_wsᵀ m g_w) + τ0
    with g_w = (0, 0, −g), R_ws the world ← sensor rotation and c the tool's centre of gravity
    (mm, converted to m)."""
    if not isinstance(model, ArmModel):          # another mechanism (medrue.MedRUE)
        return model.wrench(q)
    _, _, u = _up_in_sensor(model, check_joints(model, q))
    return wrench_from_up(u, model.tool_mass_kg * G_STANDARD, model.tool_cog_mm, model.bias)


def _rotation_axes(model: ArmModel, q: np.ndarray, R_wf: np.ndarray) -> np.ndarray:
    """World axes ω (m, 2n + 6, 3) of the rotational parameters, in the order θ0_i, α_i (per
    joint, interleaved), base roll/pitch/yaw, sensor roll/pitch/yaw: d R_ws / d φ = [ω]× R_ws.
    The joints' and the base's are the rotation rows of the arm's pose Jacobian
    (``tmscal.calib.kinematics.pose_jacobian``: either DH convention)."""
    n = model.n_joints
    Jw = pose_jacobian(model, q)[:, 3:, :]                  # (m, 3, 4n + 12)
    cols = sorted([4 * i for i in range(n)] + [4 * i + 3 for i in range(n)]) \
        + [4 * n, 4 * n + 1, 4 * n + 2]
    axes = np.empty((len(q), 2 * n + 6, 3))
    axes[:, :2 * n + 3] = Jw[:, :, cols].transpose(0, 2, 1)
    axes[:, 2 * n + 3:] = np.einsum("mij,kj->mki", R_wf, rpy_axes(model.flange_from_sensor))
    return axes


def jacobian(model: ArmModel, q: Any) -> np.ndarray:
    """d wrench / d p, analytic, shape (6m, 4n + 22) for q (m, n) rad: rows are the six
    channels of configuration 0, then of 1, …; columns in the order of
    ``model.parameter_names()`` (units: N or N·m per rad, mm, N, N·m). Lengths (d, a, base and
    sensor positions) do not enter the gravity wrench: their columns are zero."""
    if not isinstance(model, ArmModel):          # another mechanism (medrue.MedRUE)
        return model.jacobian(q)
    q = np.atleast_2d(check_joints(model, q))
    if q.ndim != 2:
        raise ValueError(f"q must be (m, {model.n_joints}), got shape {q.shape}")
    m, n = q.shape[0], model.n_joints
    R_wf, R_ws, u = _up_in_sensor(model, q)
    mg = model.tool_mass_kg * G_STANDARD
    c = model.tool_cog_mm * 1e-3
    omega = _rotation_axes(model, q, R_wf)                               # (m, K, 3)
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
