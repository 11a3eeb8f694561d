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

import numpy as np

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
