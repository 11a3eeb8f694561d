"""Where a calibration was made (docs/safety.md, docs/lab-day.md): its P0 (the centre of the
plan its session was acquired around) and region, the distance of another P0 from it, and the
envelope that always lets the arm go back to it inside the workspace box.

A calibration is valid where it was made: the arm's repeatability, the tracker's accuracy and
any kinematic error differ over the workspace, so the daily check and a partial
re-registration are measured around the calibration's P0, not wherever the arm was left.
``plan.start: current`` alone would let P0 walk from session to session (each run starts at
the last pose of the one before); ``tmscal acquire --calib CAL`` runs around the calibration's
P0 instead, and the daily check warns with the distance when a session's P0 is elsewhere.

Frames and units: P0 is base_from_flange, 4×4, mm; distances mm and degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..geometry import angle_between, check_pose
from .envelope import Envelope

__all__ = ["CalibratedP0", "P0_TOL_MM", "P0_TOL_DEG", "p0_distance", "same_p0",
           "return_envelope"]

#: a session's P0 within this distance (mm) AND rotation (deg) of the calibration's counts as
#: the same place: 10× a robot's pose repeatability (≤ 0.1 mm for the arms of the registry),
#: far below the plan's radius (tens of mm), so a P0 that was really re-used always passes and
#: a P0 that walked by one pose of a plan never does
P0_TOL_MM = 1.0
P0_TOL_DEG = 0.5


def p0_distance(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """The distance between two poses (base_from_flange 4×4 mm): the flange origins' (mm) and
    the rotation angle between them (degrees)."""
    A, B = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return (float(np.linalg.norm(A[:3, 3] - B[:3, 3])),
            float(np.degrees(angle_between(A, B))))


def same_p0(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two P0 (base_from_flange 4×4 mm) are the same place: within ``P0_TOL_MM`` and
    ``P0_TOL_DEG``."""
    mm, deg = p0_distance(a, b)
    return mm <= P0_TOL_MM and deg <= P0_TOL_DEG


@dataclass(frozen=True, eq=False)
class CalibratedP0:
    """A calibration's P0 and region: ``pose`` (base_from_flange 4×4 mm, the plan's centre),
    the plan's ``kind``, ``radius_mm`` and ``rotation_deg`` (the ranges it was drawn in), and
    the extent of the poses the calibration was solved from: ``offset_max_mm`` (the largest
    distance of a flange origin from P0) and ``rotation_max_deg`` (the largest rotation from
    P0), or None where not known."""

    pose: np.ndarray
    kind: str
    radius_mm: float
    rotation_deg: float
    offset_max_mm: float | None = None
    rotation_max_deg: float | None = None

    @classmethod
    def from_plan(cls, plan: Any, poses: np.ndarray | None = None) -> CalibratedP0:
        """From a session header's ``plan`` entry (its ``p0``, ``kind``, ``radius_mm``,
        ``rotation_deg``) and the robot poses A of the session (N×4×4 base_from_flange mm;
        their extent around P0). ValueError naming the key when the entry is not a plan."""
        if not isinstance(plan, dict) or "p0" not in plan:
            raise ValueError("plan: the session header records no plan with a P0 (not made by "
                             "tmscal acquire)")
        p0 = check_pose(plan["p0"], "plan.p0")
        off = rot = None
        if poses is not None and len(poses):
            P = np.asarray(poses, dtype=float)
            off = float(np.linalg.norm(P[:, :3, 3] - p0[:3, 3], axis=1).max())
            rot = float(np.degrees(angle_between(p0, P)).max())
        return cls(p0, str(plan.get("kind", "?")), _number(plan.get("radius_mm"), "plan.radius_mm"),
                   _number(plan.get("rotation_deg"), "plan.rotation_deg"), off, rot)

    def to_doc(self) -> dict[str, Any]:
        """The calibration file's ``p0`` section (plain types; mm, deg)."""
        out: dict[str, Any] = {"pose": np.asarray(self.pose, dtype=float).tolist(),
                               "plan": {"kind": self.kind, "radius_mm": self.radius_mm,
                                        "rotation_deg": self.rotation_deg}}
        if self.offset_max_mm is not None:
            out["extent"] = {"offset_max_mm": self.offset_max_mm,
                             "rotation_max_deg": self.rotation_max_deg}
        return out

    @classmethod
    def from_doc(cls, d: Any) -> CalibratedP0:
        """The section :meth:`to_doc` wrote; ValueError naming the key (``p0.pose`` …)."""
        if not isinstance(d, dict):
            raise ValueError("p0: expected a mapping (pose, plan, extent)")
        raw: Any = d.get("pose")   # the file's value, whatever it is: check_pose names it
        pose = check_pose(raw, "p0.pose")
        plan = d.get("plan")
        if not isinstance(plan, dict):
            raise ValueError("p0.plan: expected a mapping (kind, radius_mm, rotation_deg)")
        ext = d.get("extent")
        if ext is not None and not isinstance(ext, dict):
            raise ValueError("p0.extent: expected a mapping (offset_max_mm, rotation_max_deg)")
        ext = ext or {}
        off, rot = ext.get("offset_max_mm"), ext.get("rotation_max_deg")
        return cls(pose, str(plan.get("kind", "?")),
                   _number(plan.get("radius_mm"), "p0.plan.radius_mm"),
                   _number(plan.get("rotation_deg"), "p0.plan.rotation_deg"),
                   None if off is None else _number(off, "p0.extent.offset_max_mm"),
                   None if rot is None else _number(rot, "p0.extent.rotation_max_deg"))

    def where(self) -> str:
        """P0's position and the region, for messages: "(500.0, 0.0, 400.0) mm, poses within
        98.7 mm and 9.9° of it"."""
        x, y, z = (float(v) for v in self.pose[:3, 3])
        out = f"({x:.1f}, {y:.1f}, {z:.1f}) mm"
        if self.offset_max_mm is not None:
            out += (f", poses within {self.offset_max_mm:.1f} mm and "
                    f"{self.rotation_max_deg:.1f}° of it")
        return out

    def elsewhere(self, p0: np.ndarray, what: str,
                  hint: str = "acquire with --calib CAL to run around the calibration's P0"
                  ) -> str | None:
        """None when ``p0`` (base_from_flange 4×4 mm) is this P0 (``same_p0``); else the
        warning naming ``what`` (e.g. "this session's P0"), the distance and ``hint``."""
        if same_p0(self.pose, p0):
            return None
        mm, deg = p0_distance(self.pose, p0)
        return (f"{what} is {mm:.1f} mm and {deg:.1f}° from the calibration's P0 "
                f"{self.where()} (the same place is within {P0_TOL_MM:g} mm and "
                f"{P0_TOL_DEG:g}°): measured elsewhere than the calibration was made; "
                f"{hint}")


def _number(v: Any, key: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
        raise ValueError(f"{key}: expected a finite number ≥ 0, got {v!r}")
    return float(v)


def return_envelope(envelope: Envelope, p0: np.ndarray, here: np.ndarray) -> Envelope:
    """The envelope for going back to a calibration's ``p0`` from ``here`` (both
    base_from_flange 4×4 mm): ``envelope`` (the config's limits) centred at ``p0``, its offset
    and rotation limits widened as far as ``here`` is from ``p0`` so that the way back is
    always allowed, while the workspace box, the tool points and the speed caps stay as they
    are (the straight way to ``p0`` only comes closer to it; ``Robot.move_to`` still checks
    every point of it against the box)."""
    mm, deg = p0_distance(p0, here)
    off, rot = envelope.max_offset_mm, envelope.max_rotation_deg
    return replace(envelope, center=np.asarray(p0, dtype=float),
                   max_offset_mm=None if off is None else max(off, mm * (1 + 1e-6) + 1e-6),
                   max_rotation_deg=None if rot is None else max(rot, deg * (1 + 1e-6) + 1e-6))
