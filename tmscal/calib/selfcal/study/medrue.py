"""MedRUE, the 6-DOF hybrid robot of Joubair, Zhao, Bigras and Bonev (2016), as one more arm of
the force-torque self-calibration. Pure numerics, no I/O; docs/selfcal.md ("MedRUE").

The mechanism (Joubair et al. 2016, section 2): a linear guide along the base's x axis (joint
q1, mm) carries two five-bar mechanisms (left i = 1: actuated joints q2, q3; right i = 2: q4,
q5, rad) in planes normal to the guide; the end points E1, E2 of the five-bars hold the probe
support through a universal joint at each end G1, G2; a sixth motor, on the link of length L14,
turns the probe about the axis x6 through G1 and G2 (q6, rad). F6 has its origin midway
between G1 and G2, x6 along G1 → G2 and z6 toward the probe.

The model here, per five-bar i, in its plane (coordinates y, z of the base frame, mm):
B_i = A_i + L_i1 (cos(q_a + q_a0), sin(q_a + q_a0)), D_i = C_i + L_i3 (cos(q_c + q_c0),
sin(q_c + q_c0)) with (a, c) = (2, 3) for i = 1 and (4, 5) for i = 2, and E_i the intersection
of the circles (B_i, L_i2) and (D_i, L_i4) on the side away from the anchors (closed form, the
one assembly mode of the robot's workspace). G_i = (q1 + d1 + d4i, E_i). The probe frame:
R_06 = R_min(x0 → x6) · Rx(φ14 + q6 + q6_0), where R_min is the smallest rotation taking the
guide axis to x6 and φ14 the angle of the link D1 → E1 in its plane (the motor sits on it);
its origin is F6's moved d6 along z6 (the probe centre, the TCP).

ASSUMPTIONS where the paper is silent or its values could not be found (its Table 1 of
nominal values was not available): the dimensions below (anchors ±60 mm, proximal links
200 mm, distal 250 mm, planes 200 mm apart, probe centre 100 mm below F6), the joint ranges
(±150 mm on the guide, ±25° around the home pose on the five-bar motors, ±180° on the probe),
the guide along the base x axis exactly (its direction is the base frame's definition), G_i
= E_i (the universal joint centred on the five-bar's end joint), a probe support whose length
follows |G1G2| (a sliding fit; two universal joints and a fixed length would over-constrain
the five-bars), and the roll transmitted through the universal joint as a rotation about x6
added to the link's angle (exact when x6 is along the guide, and to second order in the tilt
otherwise). The parameters are those the paper names: link lengths L_ij, anchor coordinates
(A_iy, A_iz, C_iy, C_iz), the guide offset d1, the planes' offsets d4i, the joint offsets and
the probe offset — 25 geometric parameters; with the base pose, the sensor mounting, the tool
and the sensor bias (as on the serial arms, docs/selfcal.md) 47 in all (the paper: 46).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ...gravity import G_STANDARD, gravity_wrench
from ...kinematics import pose_from_rpy, rpy_from_matrix

__all__ = ["MedRUE", "MEDRUE", "GEOMETRY_NAMES", "five_bar_point"]

#: the geometric parameters, in the order of ``MedRUE.geometry``
GEOMETRY_NAMES: list[str] = ["d1"]
for _i, (_a, _c) in ((1, (2, 3)), (2, (4, 5))):
    GEOMETRY_NAMES += [f"A{_i}y", f"A{_i}z", f"C{_i}y", f"C{_i}z", f"L{_i}1", f"L{_i}2",
                       f"L{_i}3", f"L{_i}4", f"q{_a}_0", f"q{_c}_0", f"d4{_i}"]
GEOMETRY_NAMES += ["q6_0", "d6"]
_GEOMETRY_UNITS = ["mm"] + (["mm"] * 8 + ["rad", "rad", "mm"]) * 2 + ["rad", "mm"]
_TAIL = ["base_roll", "base_pitch", "base_yaw", "base_x", "base_y", "base_z",
         "sensor_roll", "sensor_pitch", "sensor_yaw", "sensor_x", "sensor_y", "sensor_z",
         "mg", "cog_x", "cog_y", "cog_z", "f0_x", "f0_y", "f0_z", "t0_x", "t0_y", "t0_z"]
_TAIL_UNITS = ["rad"] * 3 + ["mm"] * 3 + ["rad"] * 3 + ["mm"] * 3 + ["N"] + ["mm"] * 3 \
    + ["N"] * 3 + ["N·m"] * 3
#: a five-bar closer than this (mm) to its singularity (E on the line B–D, or B on D) is out
#: of the workspace of the candidate pool
SINGULAR_MARGIN_MM = 40.0
#: the largest tilt of x6 from the guide axis in the candidate pool (rad)
MAX_TILT_RAD = math.radians(30.0)


def five_bar_point(A: np.ndarray, C: np.ndarray, L: np.ndarray, qa: np.ndarray,
                   qc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form position analysis of one five-bar in its plane (mm, rad): anchors A, C
    (2,), lengths L = (L1 A–B, L2 B–E, L3 C–D, L4 D–E), actuated angles qa, qc (m,) from the
    plane's y axis. Returns (B, D, E, h) (m, 2) ×3 and (m,): E is the intersection of the
    circles (B, L2) and (D, L4) on the right of B → D (away from the anchors when B is left of
    D and the links hang below), h its distance from the line B–D (NaN where the circles do
    not meet: the mechanism cannot be assembled)."""
    B = A + L[0] * np.stack([np.cos(qa), np.sin(qa)], -1)
    D = C + L[2] * np.stack([np.cos(qc), np.sin(qc)], -1)
    v = D - B
    s = np.linalg.norm(v, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = v / s[:, None]
        a = (L[1] ** 2 - L[3] ** 2 + s ** 2) / (2 * s)
        h = np.sqrt(L[1] ** 2 - a ** 2)
    perp = np.stack([u[:, 1], -u[:, 0]], -1)             # u turned by −90°: below B → D
    E = B + a[:, None] * u + h[:, None] * perp
    return B, D, E, h


def _rot_x(t: np.ndarray) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    R = np.zeros(t.shape + (3, 3))
    R[..., 0, 0] = 1.0
    R[..., 1, 1], R[..., 1, 2], R[..., 2, 1], R[..., 2, 2] = c, -s, s, c
    return R


def _min_rotation(x6: np.ndarray) -> np.ndarray:
    """(m, 3, 3): the smallest rotation taking (1, 0, 0) to the unit vectors x6 (m, 3)
    (Rodrigues: R = I + [k]× + [k]×² / (1 + c), k = x0 × x6, c = x0 · x6; x6 never opposite
    the guide in the workspace)."""
    k = np.stack([np.zeros(len(x6)), -x6[:, 2], x6[:, 1]], -1)
    c = x6[:, 0]
    K = np.zeros((len(x6), 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -k[:, 2], k[:, 1]
    K[:, 1, 0], K[:, 1, 2] = k[:, 2], -k[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -k[:, 1], k[:, 0]
    return np.eye(3) + K + (K @ K) / (1.0 + c)[:, None, None]


@dataclass(frozen=True)
class MedRUE:
    """The MedRUE hybrid robot with a force-torque sensor and a tool (module docstring).

    ``geometry`` (25,): the geometric parameters in the order of ``GEOMETRY_NAMES`` (mm,
    rad); ``base``: 4×4 mm world ← base (world z up, gravity (0, 0, −g)); ``flange_from_sensor``:
    4×4 mm probe frame ← sensor; ``tool_mass_kg``; ``tool_cog_mm`` (3,) in the sensor frame;
    ``bias`` (6,) [f0 N; τ0 N·m]; ``joint_limits_rad`` (6, 2): q1 in mm (the guide is
    prismatic), q2…q6 in rad. The parameter vector has the interface of
    :class:`~tmscal.calib.selfcal.model.ArmModel` (``vector``, ``with_vector``,
    ``parameter_names``, ``parameter_units``)."""

    geometry: np.ndarray
    base: np.ndarray = field(default_factory=lambda: np.eye(4))
    flange_from_sensor: np.ndarray = field(default_factory=lambda: np.eye(4))
    tool_mass_kg: float = 1.5
    tool_cog_mm: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 60.0]))
    bias: np.ndarray = field(default_factory=lambda: np.zeros(6))
    joint_limits_rad: np.ndarray = field(default_factory=lambda: np.zeros((6, 2)))
    name: str = "medrue"

    def __post_init__(self) -> None:
        for key, shape in (("geometry", (len(GEOMETRY_NAMES),)), ("base", (4, 4)),
                           ("flange_from_sensor", (4, 4)), ("tool_cog_mm", (3,)),
                           ("bias", (6,)), ("joint_limits_rad", (6, 2))):
            arr = np.array(getattr(self, key), dtype=float)
            if arr.shape != shape or not np.all(np.isfinite(arr)):
                raise ValueError(f"{key} must be a finite array of shape {shape}")
            object.__setattr__(self, key, arr)
        object.__setattr__(self, "tool_mass_kg", float(self.tool_mass_kg))

    @property
    def n_joints(self) -> int:
        return 6

    def parameter_names(self) -> list[str]:
        """The geometric names (``GEOMETRY_NAMES``), then those of the serial arms' tail."""
        return list(GEOMETRY_NAMES) + list(_TAIL)

    def parameter_units(self) -> list[str]:
        return list(_GEOMETRY_UNITS) + list(_TAIL_UNITS)

    def vector(self) -> np.ndarray:
        """The parameter vector (47,), in the order of :meth:`parameter_names`."""
        return np.concatenate([
            self.geometry, rpy_from_matrix(self.base), self.base[:3, 3],
            rpy_from_matrix(self.flange_from_sensor), self.flange_from_sensor[:3, 3],
            [self.tool_mass_kg * G_STANDARD], self.tool_cog_mm, self.bias])

    def with_vector(self, p: Any) -> MedRUE:
        p = np.asarray(p, dtype=float)
        k = len(GEOMETRY_NAMES)
        if p.shape != (k + len(_TAIL),):
            raise ValueError(f"p must have {k + len(_TAIL)} entries, got shape {p.shape}")
        return replace(self, geometry=p[:k], base=pose_from_rpy(p[k:k + 3], p[k + 3:k + 6]),
                       flange_from_sensor=pose_from_rpy(p[k + 6:k + 9], p[k + 9:k + 12]),
                       tool_mass_kg=p[k + 12] / G_STANDARD, tool_cog_mm=p[k + 13:k + 16],
                       bias=p[k + 16:k + 22])

    # --- kinematics ---------------------------------------------------------------------

    def _g(self, name: str) -> float:
        return float(self.geometry[GEOMETRY_NAMES.index(name)])

    def five_bars(self, q: Any) -> dict[str, np.ndarray]:
        """The mechanism at joints q (m, 6): ``G1``, ``G2`` (m, 3) mm in the base frame,
        ``phi14`` (m,) rad (the angle of link D1 → E1 in its plane), ``h1``, ``h2`` (m,) mm
        (each end point's distance from the line B–D: 0 at the singularity, NaN where a
        five-bar cannot be assembled)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if q.ndim != 2 or q.shape[1] != 6:
            raise ValueError(f"q must be (m, 6) (q1 mm, q2…q6 rad), got shape {q.shape}")
        out: dict[str, np.ndarray] = {}
        x_carriage = q[:, 0] + self._g("d1")
        for i, (a, c) in ((1, (2, 3)), (2, (4, 5))):
            A = np.array([self._g(f"A{i}y"), self._g(f"A{i}z")])
            C = np.array([self._g(f"C{i}y"), self._g(f"C{i}z")])
            L = np.array([self._g(f"L{i}{j}") for j in (1, 2, 3, 4)])
            _, D, E, h = five_bar_point(A, C, L, q[:, a - 1] + self._g(f"q{a}_0"),
                                        q[:, c - 1] + self._g(f"q{c}_0"))
            out[f"G{i}"] = np.column_stack([x_carriage + self._g(f"d4{i}"), E])
            out[f"h{i}"] = h
            if i == 1:
                out["phi14"] = np.arctan2(E[:, 1] - D[:, 1], E[:, 0] - D[:, 0])
        return out

    def probe_poses(self, q: Any) -> np.ndarray:
        """(m, 4, 4) mm: base ← probe frame (F6's axes, origin at the probe centre d6 along
        z6) at joints q (m, 6)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        fb = self.five_bars(q)
        d = fb["G2"] - fb["G1"]
        x6 = d / np.linalg.norm(d, axis=-1, keepdims=True)
        R = _min_rotation(x6) @ _rot_x(fb["phi14"] + q[:, 5] + self._g("q6_0"))
        T = np.tile(np.eye(4), (len(q), 1, 1))
        T[:, :3, :3] = R
        T[:, :3, 3] = 0.5 * (fb["G1"] + fb["G2"]) + self._g("d6") * R[:, :, 2]
        return T

    def forward(self, q: Any) -> np.ndarray:
        """(…, 4, 4) mm: world ← probe frame (the "flange" of the serial arms) at q (…, 6)."""
        q = np.asarray(q, dtype=float)
        T = self.base @ self.probe_poses(q.reshape(-1, 6))
        return T.reshape(q.shape[:-1] + (4, 4))

    def wrench(self, q: Any) -> np.ndarray:
        """(…, 6) [N ×3, N·m ×3] in the sensor frame: the gravity wrench of the tool, as
        :func:`tmscal.calib.selfcal.model.wrench` computes it for a serial arm."""
        q = np.asarray(q, dtype=float)
        R_ws = (self.base[:3, :3] @ self.probe_poses(q.reshape(-1, 6))[:, :3, :3]
                @ self.flange_from_sensor[:3, :3])
        w = gravity_wrench(R_ws, self.tool_mass_kg, self.tool_cog_mm, self.bias)
        return w.reshape(q.shape[:-1] + (6,))

    def jacobian(self, q: Any) -> np.ndarray:
        """d wrench / d p (6m, 47) at q (m, 6), by central differences (steps 1e-7 rad,
        1e-5 mm, 1e-6 N or N·m; the wrench is linear in weight, centre of gravity and bias,
        and smooth in the rest away from the five-bars' singularities)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        p = self.vector()
        steps = {"rad": 1e-7, "mm": 1e-5, "N": 1e-6, "N·m": 1e-6}
        J = np.empty((6 * len(q), len(p)))
        for j, unit in enumerate(self.parameter_units()):
            dp = np.zeros_like(p)
            dp[j] = steps[unit]
            hi = self.with_vector(p + dp).wrench(q)
            lo = self.with_vector(p - dp).wrench(q)
            J[:, j] = ((hi - lo) / (2 * steps[unit])).ravel()
        return J

    def reachable(self, q: Any) -> np.ndarray:
        """(m,) bool: both five-bars assembled at least ``SINGULAR_MARGIN_MM`` from their
        singularity, x6 within ``MAX_TILT_RAD`` of the guide, and q within the limits."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        fb = self.five_bars(q)
        d = fb["G2"] - fb["G1"]
        tilt = np.arccos(np.clip(d[:, 0] / np.linalg.norm(d, axis=-1), -1, 1))
        lim = self.joint_limits_rad
        inside = np.all((q >= lim[:, 0]) & (q <= lim[:, 1]), axis=-1)
        with np.errstate(invalid="ignore"):
            ok = (fb["h1"] > SINGULAR_MARGIN_MM) & (fb["h2"] > SINGULAR_MARGIN_MM)
        return ok & (tilt < MAX_TILT_RAD) & inside

    def candidate_pool(self, count: int, rng: np.random.Generator | int | None = None
                       ) -> np.ndarray:
        """``count`` configurations (count, 6) drawn uniformly within the joint limits, those
        :meth:`reachable` rejects drawn again."""
        if count < 1:
            raise ValueError(f"candidate pool: count = {count}; expected at least 1")
        gen = np.random.default_rng(rng)
        lim = self.joint_limits_rad
        out: list[np.ndarray] = []
        have = 0
        while have < count:
            q = lim[:, 0] + gen.random((2 * count, 6)) * (lim[:, 1] - lim[:, 0])
            q = q[self.reachable(q)]
            out.append(q)
            have += len(q)
        return np.concatenate(out)[:count]


def _nominal() -> MedRUE:
    """The nominal MedRUE (dimensions ASSUMED, module docstring): anchors at y = ±60 mm,
    proximal links 200 mm, distal 250 mm, the five-bar planes 100 mm either side of the
    carriage, the probe centre 100 mm below F6; at home (q = 0) the proximal links point
    120° and 60° below the y axis, E is 365 mm below the anchors, x6 is along the guide and
    z6 points down."""
    g = dict.fromkeys(GEOMETRY_NAMES, 0.0)
    for i in (1, 2):
        g.update({f"A{i}y": -60.0, f"A{i}z": 0.0, f"C{i}y": 60.0, f"C{i}z": 0.0,
                  f"L{i}1": 200.0, f"L{i}2": 250.0, f"L{i}3": 200.0, f"L{i}4": 250.0})
    g.update({"d41": -100.0, "d42": 100.0, "d6": 100.0,
              "q2_0": math.radians(-120.0), "q3_0": math.radians(-60.0),
              "q4_0": math.radians(-120.0), "q5_0": math.radians(-60.0)})
    lim = np.array([[-150.0, 150.0]] + [[-math.radians(25), math.radians(25)]] * 4
                   + [[-math.pi, math.pi]])
    model = MedRUE(geometry=np.array([g[n] for n in GEOMETRY_NAMES]), joint_limits_rad=lim)
    phi14 = float(model.five_bars(np.zeros((1, 6)))["phi14"][0])
    g["q6_0"] = math.pi - phi14                  # z6 down at home
    return replace(model, geometry=np.array([g[n] for n in GEOMETRY_NAMES]))


#: the nominal MedRUE of the simulation study (dimensions assumed; module docstring)
MEDRUE = _nominal()
