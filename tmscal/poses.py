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
  header records it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import SessionError
from .geometry import check_pose, compose, make_pose, random_rotation, rot_x, rot_y, rot_z

__all__ = ["PLAN_KINDS", "MAX_PLAN_POSES", "PlanSpec", "eq14_poses", "sphere_poses",
           "random_poses", "make_plan"]


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


def make_plan(kind: str, p0: np.ndarray, n: int, seed: int, radius_mm: float,
              rotation_deg: float) -> np.ndarray:
    """The acquisition plan: n poses (n, 4, 4) base_from_flange in mm around P0, reproducible
    from (kind, P0, n, seed, ranges) alone so that ``--resume`` regenerates the same plan.
    The first n of a longer plan with the same seed are the same poses."""
    gen = PLAN_KINDS.get(kind)
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
class PlanSpec:
    """Everything that fixes a plan: ``kind`` ("eq14" or "sphere"), ``n`` poses, ``seed``,
    ``radius_mm``, ``rotation_deg`` and P0 (``p0``, base_from_flange 4×4 mm). Pose i depends
    only on (kind, P0, seed, ranges, i), so a resumed run regenerates the same plan from the
    session header, and any prefix of a plan is the shorter plan."""

    kind: str
    n: int
    seed: int
    radius_mm: float
    rotation_deg: float
    p0: np.ndarray

    def poses(self) -> np.ndarray:
        """The plan, (n, 4, 4) base_from_flange in mm."""
        return make_plan(self.kind, self.p0, self.n, self.seed, self.radius_mm,
                         self.rotation_deg)

    def with_n(self, n: int) -> PlanSpec:
        """The same plan with ``n`` poses (the first ones are the same)."""
        return PlanSpec(self.kind, n, self.seed, self.radius_mm, self.rotation_deg, self.p0)

    def to_header(self) -> dict[str, Any]:
        """The session header's "plan" entry."""
        return {"kind": self.kind, "poses": self.n, "seed": self.seed,
                "radius_mm": self.radius_mm, "rotation_deg": self.rotation_deg,
                "p0": np.asarray(self.p0, dtype=float).tolist()}

    @classmethod
    def from_config(cls, plan: Any, p0: np.ndarray, n: int | None = None) -> PlanSpec:
        """The plan of a config's ``plan`` section around ``p0`` (``n`` overrides its
        length)."""
        return cls(plan.kind, int(n or plan.poses), plan.seed, plan.radius_mm,
                   plan.rotation_deg, np.asarray(p0, dtype=float))

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
            if kind not in PLAN_KINDS:
                raise ValueError(f"unknown kind {kind!r}")
            r, d = float(p["radius_mm"]), float(p["rotation_deg"])
            if not (np.isfinite(r) and np.isfinite(d) and r >= 0 and d >= 0):
                raise ValueError(f"ranges must be finite and ≥ 0, got {r}, {d}")
            return cls(kind, n, seed, r, d, check_pose(p["p0"], "p0"))
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            raise SessionError(f"the session header's 'plan' is incomplete or invalid ({e})") \
                from None
