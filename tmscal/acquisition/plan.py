"""Acquisition plans: which poses a run visits (``PlanSpec``), the safety check of a whole
plan before anything moves (``check_plan``), and the dry run's summary (``dry_run``), all as
values: nothing here prints. Poses are base_from_flange 4×4 in mm; the generators live in
:mod:`tmscal.poses`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..drivers.base import Envelope, SafetyError
from ..errors import SessionError
from ..geometry import check_pose
from ..poses import PLAN_KINDS, make_plan

__all__ = ["MAX_PLAN_POSES", "PlanSpec", "check_plan", "plan_summary", "make_plan"]

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

def check_plan(poses: np.ndarray, envelope: Envelope) -> None:
    """Check every pose of a plan against the envelope before anything moves. Raises
    SafetyError naming the first offending pose (index, position in mm) and the limits."""
    for i, P in enumerate(poses):
        v = envelope.violations(P)
        if v:
            pos = np.round(P[:3, 3], 1).tolist()
            raise SafetyError(f"plan pose {i} (flange at {pos} mm in the base frame) leaves "
                              f"the safety envelope: {'; '.join(v)}. Nothing was moved.")


def plan_summary(poses: np.ndarray, p0: np.ndarray, speed_mm_s: float, settle_s: float,
                 samples: int, frame_rate_hz: float, start: np.ndarray | None = None,
                 envelope: Envelope | None = None) -> dict[str, Any]:
    """Extent of a plan and an estimate of its duration (for ``--dry-run``).

    Offsets are flange positions relative to P0 (mm, base frame), rotations relative to P0
    (deg). Duration = straight-line travel at ``speed_mm_s`` (from ``start``, default P0,
    through every pose) + settle + samples / frame rate, per pose (s).

    In the robot base frame (mm): ``box_min_mm``/``box_max_mm`` the envelope's workspace box
    (None without an envelope or box); ``flange_min_mm``/``flange_max_mm`` the extent of the
    flange origins over the plan; ``tool_min_mm``/``tool_max_mm`` the extent of the
    envelope's tool points (flange frame, carried by every pose), or None without them.
    Lists of 3 floats [x, y, z]."""
    from ..geometry import angle_between

    d = poses[:, :3, 3] - p0[:3, 3]
    rot = np.degrees(angle_between(p0, poses))
    path = np.concatenate([[(p0 if start is None else start)[:3, 3]], poses[:, :3, 3]])
    travel = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    per_pose = settle_s + samples / frame_rate_hz
    flange = poses[:, :3, 3]
    box = envelope is not None and envelope.box_min_mm is not None
    tools = None
    if envelope is not None and envelope.tool_points_mm is not None and len(poses):
        q = np.asarray(envelope.tool_points_mm, dtype=np.float64)
        tools = (np.einsum("nij,kj->nki", poses[:, :3, :3], q)
                 + poses[:, None, :3, 3]).reshape(-1, 3)

    def extent(a: np.ndarray | None, f: Any) -> list[float] | None:
        return None if a is None or not len(a) else [float(x) for x in f(a, axis=0)]

    return {
        "poses": int(len(poses)),
        "offset_max_mm": float(np.linalg.norm(d, axis=1).max()) if len(d) else 0.0,
        "x_range_mm": (float(d[:, 0].min()), float(d[:, 0].max())),
        "y_range_mm": (float(d[:, 1].min()), float(d[:, 1].max())),
        "z_range_mm": (float(d[:, 2].min()), float(d[:, 2].max())),
        "rotation_max_deg": float(rot.max()) if len(rot) else 0.0,
        "travel_mm": travel,
        "motion_s": travel / speed_mm_s,
        "sampling_s": per_pose * len(poses),
        "duration_s": travel / speed_mm_s + per_pose * len(poses),
        "box_min_mm": [float(x) for x in envelope.box_min_mm] if box else None,
        "box_max_mm": [float(x) for x in envelope.box_max_mm] if box else None,
        "flange_min_mm": extent(flange, np.min),
        "flange_max_mm": extent(flange, np.max),
        "tool_min_mm": extent(tools, np.min),
        "tool_max_mm": extent(tools, np.max),
    }
