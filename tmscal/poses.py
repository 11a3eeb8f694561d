"""Pose generators: where a robot flange goes, as base_from_flange 4×4 poses in mm. Pure
functions of an explicit ``numpy.random.Generator``; no I/O. Both the simulator
(:mod:`tmscal.sim`) and the acquisition plans (:mod:`tmscal.acquisition`) use them.

* ``eq14_poses``: Eq. 14 of Wang et al. (2018), P_i = P0 · T(t) · Rx(θ1) · Ry(θ2) · Rz(θ3),
  t uniform in ±r mm per axis, θ uniform in ±d degrees (their experiment: 100 mm, 10°).
* ``sphere_poses``: positions uniform in a ball of radius r around P0, yaw/pitch/roll uniform
  in ±d degrees (the sphere workspace of the Panda/Vicra TMS comparison of QR24, SGO and
  QUAT).
* ``random_poses``: fully random robot poses (the simulation of Wang et al. 2018): Haar-random
  rotations, translations uniform in ±r mm per axis.
* ``make_plan``: an acquisition plan of any of the first two kinds, reproducible pose by pose.
* ``PlanSpec``: everything that fixes such a plan, as a config, a command line or a session
  header records it; also the plan kind ``joints`` (joint configurations spread inside the
  safety envelope, for the arm's kinematic estimate), whose parameters ``JointsSpec`` holds
  and whose poses the arm's nominal kinematics give: ``tmscal.acquisition.plan.plan_poses``
  draws them (:mod:`tmscal.calib.kinematics.excite`; this module, at the bottom layer, knows
  no arm).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import SessionError
from .geometry import check_pose, compose, make_pose, random_rotation, rot_x, rot_y, rot_z

__all__ = ["PLAN_KINDS", "ALL_PLAN_KINDS", "JOINTS_KIND", "MAX_PLAN_POSES", "PlanSpec",
           "JointsSpec", "eq14_poses", "sphere_poses", "random_poses", "make_plan"]


def eq14_poses(p0: np.ndarray, n: int, rng: np.random.Generator, r_mm: float = 100.0,
               d_deg: float = 10.0) -> np.ndarray:
    """n poses (n, 4, 4) mm by Eq. 14 of Wang et al. (2018) around P0 (base_from_flange, mm).

    The translation T(t) is applied in the P0 flange frame, then Rx·Ry·Rz (radians drawn
    uniformly from ±d_deg)."""
    t = rng.uniform(-r_mm, r_mm, size=(n, 3))
    th = np.radians(rng.uniform(-d_deg, d_deg, size=(n, 3)))
    R = rot_x(th[:, 0]) @ rot_y(th[:, 1]) @ rot_z(th[:, 2])
    return compose(np.asarray(p0, dtype=float), make_pose(np.eye(3), t), make_pose(R))


def sphere_poses(p0: np.ndarray, n: int, rng: np.random.Generator, r_mm: float = 100.0,
                 d_deg: float = 10.0) -> np.ndarray:
    """n poses (n, 4, 4) mm with the flange origin uniform in a ball of radius r_mm around
    P0's origin (P0 frame) and yaw/pitch/roll uniform in ±d_deg (the sphere workspace of the
    Panda/Vicra TMS comparison of QR24, SGO and QUAT)."""
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t = u * (r_mm * rng.uniform(0.0, 1.0, size=(n, 1)) ** (1.0 / 3.0))
    th = np.radians(rng.uniform(-d_deg, d_deg, size=(n, 3)))
    R = rot_z(th[:, 0]) @ rot_y(th[:, 1]) @ rot_x(th[:, 2])
    return compose(np.asarray(p0, dtype=float), make_pose(np.eye(3), t), make_pose(R))


def random_poses(n: int, rng: np.random.Generator, r_mm: float = 500.0) -> np.ndarray:
    """n fully random poses (n, 4, 4) mm: Haar-random rotations, translations uniform in
    ±r_mm per axis (the simulation of Wang et al. 2018; its text does not give the
    translation range)."""
    return make_pose(random_rotation(rng, n), rng.uniform(-r_mm, r_mm, size=(n, 3)))


#: plan kind → its pose generator ``gen(p0, n, rng, r_mm=, d_deg=)``: the one list of plan
#: kinds (config's ``plan.kind``, session headers, ``make_plan``)
PLAN_KINDS = {"eq14": eq14_poses, "sphere": sphere_poses}
#: the plan kind drawn in joint space on the arm's nominal kinematics (module docstring)
JOINTS_KIND = "joints"
#: every plan kind a config or a session header may name
ALL_PLAN_KINDS = (*PLAN_KINDS, JOINTS_KIND)


def make_plan(kind: str, p0: np.ndarray, n: int, seed: int, radius_mm: float,
              rotation_deg: float) -> np.ndarray:
    """The acquisition plan: n poses (n, 4, 4) base_from_flange in mm around P0, reproducible
    from (kind, P0, n, seed, ranges) alone so that ``--resume`` regenerates the same plan.
    The first n of a longer plan with the same seed are the same poses."""
    gen = PLAN_KINDS.get(kind)
    if kind == JOINTS_KIND:
        raise ValueError("a joints plan is drawn on the arm's nominal kinematics inside the "
                         "safety envelope: tmscal.acquisition.plan.plan_poses")
    if gen is None:
        known = " or ".join(repr(k) for k in PLAN_KINDS)
        raise ValueError(f"unknown plan kind {kind!r}; expected {known}")
    # pose i comes from its own generator seeded by (seed, i): any prefix of a plan is the
    # plan of that length, and a resumed run regenerates exactly the poses it skipped
    out = np.empty((n, 4, 4))
    for i in range(n):
        out[i] = gen(p0, 1, np.random.default_rng([seed, i]), r_mm=radius_mm,
                     d_deg=rotation_deg)[0]
    return out


#: the most poses a plan may have (a config, a command line or a session header)
MAX_PLAN_POSES = 100_000


@dataclass(frozen=True)
class JointsSpec:
    """What fixes a ``joints`` plan beside the kind, length, seed, ranges and P0 of its
    ``PlanSpec`` (:mod:`tmscal.calib.kinematics.excite`): the registered ``arm`` (its nominal
    kinematics), ``q0`` (dof,) rad the joints of P0 on it, ``frame`` (4×4 mm, the controller's
    frame ← the arm's DH base), the candidates' ``span_deg`` around q0 and their number
    ``pool``. The safety envelope the candidates must be inside is the config's."""

    arm: str
    q0: np.ndarray
    frame: np.ndarray
    span_deg: float
    pool: int

    def to_header(self) -> dict[str, Any]:
        """The plan header's "joints" entry (plain types; rad, mm)."""
        return {"arm": self.arm, "q0_rad": np.asarray(self.q0, dtype=float).tolist(),
                "frame": np.asarray(self.frame, dtype=float).tolist(),
                "span_deg": self.span_deg, "pool": self.pool}

    @classmethod
    def from_header(cls, j: Any) -> JointsSpec:
        """The entry :meth:`to_header` wrote; ValueError/KeyError/TypeError when invalid."""
        if not isinstance(j, dict):
            raise ValueError("a joints plan needs its 'joints' entry (arm, q0_rad, frame, "
                             "span_deg, pool)")
        arm, pool = j["arm"], j["pool"]
        if not isinstance(arm, str) or not arm:
            raise ValueError(f"joints.arm: expected an arm's name, got {arm!r}")
        if isinstance(pool, bool) or not isinstance(pool, int) or \
                not 1 <= pool <= MAX_PLAN_POSES:
            raise ValueError(f"joints.pool: expected 1..{MAX_PLAN_POSES}, got {pool!r}")
        q0 = np.array(j["q0_rad"], dtype=float)
        if q0.ndim != 1 or not 1 <= len(q0) <= 12 or not np.isfinite(q0).all():
            raise ValueError("joints.q0_rad: expected the finite joint angles of P0 (rad)")
        span = float(j["span_deg"])
        if not (np.isfinite(span) and 0 < span <= 180):
            raise ValueError(f"joints.span_deg: expected 0 < span ≤ 180, got {span}")
        return cls(arm, q0, check_pose(j["frame"], "joints.frame"), span, pool)


@dataclass(frozen=True)
class PlanSpec:
    """Everything that fixes a plan: ``kind`` ("eq14", "sphere" or "joints"), ``n`` poses,
    ``seed``, ``radius_mm``, ``rotation_deg`` and P0 (``p0``, base_from_flange 4×4 mm); for
    "joints" also ``joints`` (:class:`JointsSpec`). Pose i of "eq14" and "sphere" depends only
    on (kind, P0, seed, ranges, i); a "joints" plan on these, its ``joints`` and the config's
    safety envelope. Either way a resumed run regenerates the same plan from the session
    header (and the config), and any prefix of a plan is the shorter plan."""

    kind: str
    n: int
    seed: int
    radius_mm: float
    rotation_deg: float
    p0: np.ndarray
    joints: JointsSpec | None = None

    def poses(self) -> np.ndarray:
        """The plan, (n, 4, 4) base_from_flange in mm ("eq14" and "sphere"; a "joints" plan
        is ``tmscal.acquisition.plan.plan_poses``'s: ValueError here)."""
        return make_plan(self.kind, self.p0, self.n, self.seed, self.radius_mm,
                         self.rotation_deg)

    def with_n(self, n: int) -> PlanSpec:
        """The same plan with ``n`` poses (the first ones are the same)."""
        return PlanSpec(self.kind, n, self.seed, self.radius_mm, self.rotation_deg, self.p0,
                        self.joints)

    def to_header(self) -> dict[str, Any]:
        """The session header's "plan" entry."""
        out = {"kind": self.kind, "poses": self.n, "seed": self.seed,
               "radius_mm": self.radius_mm, "rotation_deg": self.rotation_deg,
               "p0": np.asarray(self.p0, dtype=float).tolist()}
        if self.joints is not None:
            out["joints"] = self.joints.to_header()
        return out

    @classmethod
    def from_config(cls, plan: Any, p0: np.ndarray, n: int | None = None,
                    joints: JointsSpec | None = None) -> PlanSpec:
        """The plan of a config's ``plan`` section around ``p0`` (``n`` overrides its
        length; ``joints``: a joints plan's arm, q0 and frame, with the section's span and
        pool)."""
        return cls(plan.kind, int(n or plan.poses), plan.seed, plan.radius_mm,
                   plan.rotation_deg, np.asarray(p0, dtype=float), joints)

    @classmethod
    def from_header(cls, header: Any) -> PlanSpec:
        """The plan a session header records; SessionError when it is missing or invalid
        (an edited header, or a session not made by ``tmscal acquire``)."""
        p = header.get("plan") if isinstance(header, dict) else None
        if not isinstance(p, dict):
            raise SessionError("the session header has no 'plan' (was it made by tmscal "
                               "acquire?); it cannot be resumed")
        try:
            n, seed, kind = p["poses"], p["seed"], p["kind"]
            if (isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_PLAN_POSES
                    or isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
                raise ValueError(f"poses must be 1..{MAX_PLAN_POSES} and seed ≥ 0, got "
                                 f"{n!r}, {seed!r}")
            if kind not in ALL_PLAN_KINDS:
                raise ValueError(f"unknown kind {kind!r}")
            r, d = float(p["radius_mm"]), float(p["rotation_deg"])
            if not (np.isfinite(r) and np.isfinite(d) and r >= 0 and d >= 0):
                raise ValueError(f"ranges must be finite and ≥ 0, got {r}, {d}")
            joints = JointsSpec.from_header(p.get("joints")) if kind == JOINTS_KIND else None
            return cls(kind, n, seed, r, d, check_pose(p["p0"], "p0"), joints)
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            raise SessionError(f"the session header's 'plan' is incomplete or invalid ({e})") \
                from None
