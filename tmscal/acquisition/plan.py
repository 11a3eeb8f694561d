"""Pose plans: where the robot flange goes, as base_from_flange 4×4 poses in mm.

* ``eq14_poses``: seed 000's Eq. 14, P_i = P0 · T(t) · Rx(θ1) · Ry(θ2) · Rz(θ3), with t uniform
  in ±r mm per axis and θ uniform in ±d degrees (the experiment's plan: 100 mm, 10°).
* ``sphere_poses``: seed 001's protocol, positions uniform in a ball of radius r around P0,
  yaw/pitch/roll uniform in ±d degrees.
* ``random_poses``: seed 000's simulation ("totally random" robot poses): Haar-random
  rotations, translations uniform in ±r mm per axis.

Every generator takes an explicit ``numpy.random.Generator``; nothing here does I/O.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..drivers.base import Envelope, SafetyError
from ..geometry import compose, make_pose, random_rotation, rot_x, rot_y, rot_z


def eq14_poses(p0: np.ndarray, n: int, rng: np.random.Generator, r_mm: float = 100.0,
               d_deg: float = 10.0) -> np.ndarray:
    """n poses (n, 4, 4) mm by seed 000's Eq. 14 around P0 (base_from_flange, mm).

    The translation T(t) is applied in the P0 flange frame, then Rx·Ry·Rz (radians drawn
    uniformly from ±d_deg)."""
    t = rng.uniform(-r_mm, r_mm, size=(n, 3))
    th = np.radians(rng.uniform(-d_deg, d_deg, size=(n, 3)))
    R = rot_x(th[:, 0]) @ rot_y(th[:, 1]) @ rot_z(th[:, 2])
    return compose(np.asarray(p0, dtype=float), make_pose(np.eye(3), t), make_pose(R))


def sphere_poses(p0: np.ndarray, n: int, rng: np.random.Generator, r_mm: float = 100.0,
                 d_deg: float = 10.0) -> np.ndarray:
    """n poses (n, 4, 4) mm with the flange origin uniform in a ball of radius r_mm around
    P0's origin (P0 frame) and yaw/pitch/roll uniform in ±d_deg (seed 001's protocol)."""
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t = u * (r_mm * rng.uniform(0.0, 1.0, size=(n, 1)) ** (1.0 / 3.0))
    th = np.radians(rng.uniform(-d_deg, d_deg, size=(n, 3)))
    R = rot_z(th[:, 0]) @ rot_y(th[:, 1]) @ rot_x(th[:, 2])
    return compose(np.asarray(p0, dtype=float), make_pose(np.eye(3), t), make_pose(R))


def random_poses(n: int, rng: np.random.Generator, r_mm: float = 500.0) -> np.ndarray:
    """n fully random poses (n, 4, 4) mm: Haar-random rotations, translations uniform in
    ±r_mm per axis (seed 000's simulation; its text does not give the translation range)."""
    return make_pose(random_rotation(rng, n), rng.uniform(-r_mm, r_mm, size=(n, 3)))


# --- plans from a config, the safety envelope, and the dry-run summary -----------------------

def make_plan(kind: str, p0: np.ndarray, n: int, seed: int, radius_mm: float,
              rotation_deg: float) -> np.ndarray:
    """The acquisition plan: n poses (n, 4, 4) base_from_flange in mm around P0, reproducible
    from (kind, P0, n, seed, ranges) alone so that ``--resume`` regenerates the same plan.
    The first n of a longer plan with the same seed are the same poses."""
    gen = {"eq14": eq14_poses, "sphere": sphere_poses}.get(kind)
    if gen is None:
        raise ValueError(f"unknown plan kind {kind!r}; expected 'eq14' or 'sphere'")
    # pose i comes from its own generator seeded by (seed, i): any prefix of a plan is the
    # plan of that length, and a resumed run regenerates exactly the poses it skipped
    out = np.empty((n, 4, 4))
    for i in range(n):
        out[i] = gen(p0, 1, np.random.default_rng([seed, i]), r_mm=radius_mm,
                     d_deg=rotation_deg)[0]
    return out


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
