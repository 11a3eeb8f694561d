"""The one gravity wrench model of tmscal (Joubair et al. 2016; docs/selfcal.md): what a wrist
force-torque sensor reads of a tool at rest. Pure numerics, no I/O.

The world has z up and gravity (0, 0, −g). With u the world's up in the sensor frame (a unit
vector, u = R_wsᵀ e_z for the sensor's orientation R_ws in the world), a tool of weight mg N
whose centre of gravity is c (mm, sensor frame), and the sensor's bias [f0 N; τ0 N·m]:

    f = −mg u + f0,     τ = (c · 10⁻³) × (−mg u) + τ0     [N, N·m].

Used by the force-sensor self-calibration's arm models (:mod:`tmscal.calib.selfcal.model`,
:mod:`tmscal.calib.selfcal.study.medrue`), the kinematic estimate's wrench rows
(:mod:`tmscal.calib.kinematics.wrench`) and the mock sensors (:mod:`tmscal.mocks.wrench`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["G_STANDARD", "gravity_wrench", "wrench_from_up"]

#: standard gravity, m/s² (CGPM 1901): a tool's weight is its mass (kg) × G_STANDARD (N)
G_STANDARD = 9.80665


def wrench_from_up(up: Any, mg_n: float, cog_mm: Any, bias: Any = None) -> np.ndarray:
    """The wrenches (…, 6) [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame for the world's
    up ``up`` (…, 3) in the sensor frame, a tool weight ``mg_n`` (N), its centre of gravity
    ``cog_mm`` (3,) mm in the sensor frame and the sensor's ``bias`` (6,) [N, N·m] (None:
    zero)."""
    f = -float(mg_n) * np.asarray(up, dtype=np.float64)
    tau = np.cross(np.asarray(cog_mm, dtype=np.float64) * 1e-3, f)
    w = np.concatenate([f, tau], axis=-1)
    return w if bias is None else w + np.asarray(bias, dtype=np.float64)


def gravity_wrench(world_from_sensor_rot: Any, mass_kg: float, cog_mm: Any,
                   bias: Any = None) -> np.ndarray:
    """The wrench(es) (…, 6) [N, N·m] of a load of ``mass_kg`` with centre of gravity
    ``cog_mm`` (sensor frame, mm) for a sensor whose orientation in a z-up world (or base)
    frame is ``world_from_sensor_rot`` (…, 3, 3), plus the sensor's ``bias`` (6,) or None."""
    R = np.asarray(world_from_sensor_rot, dtype=np.float64)
    return wrench_from_up(R[..., 2, :], mass_kg * G_STANDARD, cog_mm, bias)
