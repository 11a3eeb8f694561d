"""How fast the tool points go: each controller's timing law for a move that translates and turns,
the speed and acceleration bounds it implies for a point carried by the flange, and the commanded
speed and acceleration lowered so that EVERY tool point (and the flange) stays under the
envelope's caps (docs/safety.md, "Speed of the tool points").

A point q of the controller's frame, at distance ρ from the rotation axis through the frame's
origin, moves at v + ω × (R·q): at most |v| + |ω|·ρ, and accelerates at most at
|a| + |α|·ρ + |ω|²·ρ. Each law bounds |v|, |ω|, |a|, |α| from the commanded speed v (mm/s) and
acceleration a (mm/s²):

* :class:`SharedProfile` — one path share f(t) runs on a trapezoid over D = max(d, K·θ)
  (d: the frame's translation, mm; θ: its rotation, rad) at caps (v, a), and the translation
  and the rotation both follow f. UR ``moveL``: the controller fits a trapezoid to the
  translation at (v, a) and one to the rotation at (4·v rad/s per m/s, 4·a) and runs the longer
  (the UR mock, docs/devices.md: CHECK at a rig), so K = 1000/4 = 250 mm/rad. DENSO ``MOVE L``:
  only the translation is timed (the DENSO mock; what an RC8 does with a pure rotation is not
  modelled: CHECK at a rig), K = 0, and a turn without translation cannot be bounded, so it is
  refused when a tool point would move. Then ḟ ≤ min(v, √(D·a))/D, |f̈| ≤ a/D, and the point's
  speed is ≤ ḟ·(d + θ·ρ), its acceleration ≤ f̈·(d + θ·ρ) + ḟ²·θ²·ρ.
* :class:`AxisProfile` — franky (Franka): each axis of the translation and of the rotation
  vector runs within factor × its own limit, the factor set from the commanded speed so that
  |v| ≤ v; the rotation then turns at |ω| ≤ v/K_v with K_v = 1000·(translation limit m/s)/
  (rotation limit rad/s) mm/rad, and |α| ≤ a/K_a + ½·|ω|² (the rotation-vector rate maps to the
  angular velocity with a norm ≤ 1, and its derivative adds at most ½·|ṙ|²; see
  tests/unit/test_path_laws.py). The axis of rotation is not fixed, so ρ = |q|.

:func:`scale` lowers (v, a) so that the bound holds for the farthest point; it never raises
them. A move in which no point travels more than ``NEGLIGIBLE_MM`` (0.01 mm) is left as it is.
Units: mm, mm/s, mm/s², rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import SafetyError

__all__ = ["SharedProfile", "AxisProfile", "ROTVEC_RATE_TERM", "NEGLIGIBLE_MM", "point_bounds",
           "scale"]

#: |α| ≤ |r̈| + ROTVEC_RATE_TERM · |ṙ|² for a rotation vector r(t) (numerically ≈ 0.32 at most)
ROTVEC_RATE_TERM = 0.5
#: a move in which no point travels more than this (mm: d + θ·ρ) is sent as it is: its speed
#: cannot matter (a pose re-commanded after a reconnect differs from the reported one by
#: rounding, and a DENSO could not time that rounding's rotation at all)
NEGLIGIBLE_MM = 0.01


@dataclass(frozen=True)
class SharedProfile:
    """One path share on the longer of a translation trapezoid and a rotation trapezoid whose
    caps are the translation's divided by ``rotation_mm_per_rad`` (K, mm per rad; 0: the
    rotation is not timed). ``min_speed_mm_s`` / ``min_accel_mm_s2``: the slowest the
    controller can be commanded (below it the move is refused). ``name`` for messages."""

    rotation_mm_per_rad: float
    min_speed_mm_s: float = 0.0
    min_accel_mm_s2: float = 0.0
    name: str = "a linear move"


@dataclass(frozen=True)
class AxisProfile:
    """Per-axis limits scaled by one factor (franky): the rotation turns at most at v/K_v rad/s
    and accelerates at most at a/K_a rad/s² (K in mm per rad: translation limit / rotation
    limit). Minimums and ``name`` as for :class:`SharedProfile`."""

    speed_mm_per_rad: float
    accel_mm_per_rad: float
    min_speed_mm_s: float = 0.0
    min_accel_mm_s2: float = 0.0
    name: str = "a per-axis Cartesian move"


Timing = SharedProfile | AxisProfile


def point_bounds(law: Timing, d: float, theta: float, rho: float, v: float, a: float
                 ) -> tuple[float, float]:
    """(highest speed mm/s, highest acceleration mm/s²) of a point at distance ``rho`` (mm)
    from the rotation axis (``AxisProfile``: from the frame's origin) during a move of ``d`` mm
    and ``theta`` rad commanded at speed ``v`` and acceleration ``a``; inf when the law cannot
    time the move (a pure rotation that ``SharedProfile`` with K = 0 leaves untimed)."""
    turns = theta > 0 and rho > 0
    if isinstance(law, AxisProfile):
        w = v / law.speed_mm_per_rad if theta > 0 else 0.0
        lin_v, lin_a = (v, a) if d > 0 else (0.0, 0.0)
        alpha = (a / law.accel_mm_per_rad + ROTVEC_RATE_TERM * w * w) if theta > 0 else 0.0
        return lin_v + w * rho, lin_a + alpha * rho + w * w * rho
    D = max(d, law.rotation_mm_per_rad * theta)
    if D <= 0:
        return (math.inf, math.inf) if turns else (0.0, 0.0)
    fd = min(v, math.sqrt(D * a)) / D
    fdd = a / D
    way = d + theta * rho
    return fd * way, fdd * way + fd * fd * theta * theta * rho


def scale(law: Timing, d: float, theta: float, rho: float, v: float, a: float,
          cap_v: float | None, cap_a: float | None, what: str) -> tuple[float, float]:
    """The speed (mm/s) and acceleration (mm/s²) to command, at most ``v`` and ``a``, so that
    a point at ``rho`` mm (the farthest one) stays at or under ``cap_v`` and ``cap_a`` (None:
    no cap) during a move of ``d`` mm and ``theta`` rad. ``SafetyError`` naming ``what`` when
    the law cannot time the move or the controller cannot go slow enough."""
    if (cap_v is None and cap_a is None) or d + theta * rho <= NEGLIGIBLE_MM:
        return v, a
    if isinstance(law, AxisProfile):
        v2, a2 = _scale_axis(law, d, theta, rho, v, a, cap_v, cap_a)
    else:
        v2, a2 = _scale_shared(law, d, theta, rho, v, a, cap_v, cap_a, what)
    if v2 < law.min_speed_mm_s or a2 < law.min_accel_mm_s2:
        raise SafetyError(f"{what} refused: its tool points would need {v2:.3g} mm/s and "
                          f"{a2:.3g} mm/s² to stay under the caps, below what {law.name} can "
                          f"be commanded ({law.min_speed_mm_s:.3g} mm/s, "
                          f"{law.min_accel_mm_s2:.3g} mm/s²). Nothing was moved.")
    return v2, a2


def _scale_shared(law: SharedProfile, d: float, theta: float, rho: float, v: float, a: float,
                  cap_v: float | None, cap_a: float | None, what: str) -> tuple[float, float]:
    D = max(d, law.rotation_mm_per_rad * theta)
    way = d + theta * rho
    if D <= 0:
        if theta > 0 and rho > 0:
            raise SafetyError(
                f"{what} refused: it turns {math.degrees(theta):.1f}° without translating, and "
                f"{law.name} times only the translation, so the speed of a point "
                f"{rho:.0f} mm from the axis cannot be bounded (docs/safety.md). Nothing was "
                "moved.")
        return v, a
    if cap_v is not None and way > 0:
        v = min(v, cap_v * D / way)
    if cap_a is not None and way > 0:
        turn = theta * theta * rho
        # either bound on ḟ² is valid: (v/D)², or a/D (the peak rate of any trapezoid)
        room = cap_a - turn * (v / D) ** 2
        a_with_v = room * D / way if room > 0 else 0.0
        a_alone = cap_a * D / (way + turn)
        a = min(a, max(a_with_v, a_alone))
    return v, a


def _scale_axis(law: AxisProfile, d: float, theta: float, rho: float, v: float, a: float,
                cap_v: float | None, cap_a: float | None) -> tuple[float, float]:
    lin = 1.0 if d > 0 else 0.0
    rot = rho / law.speed_mm_per_rad if theta > 0 else 0.0
    if cap_v is not None and lin + rot > 0:
        v = min(v, cap_v / (lin + rot))
    if cap_a is not None and theta > 0 and rho > 0:
        w_per_v = 1.0 / law.speed_mm_per_rad
        turn = (1.0 + ROTVEC_RATE_TERM) * rho * w_per_v * w_per_v     # × v²
        if turn * v * v > 0.5 * cap_a:          # keep half the cap for the acceleration
            v = math.sqrt(0.5 * cap_a / turn)
        a = min(a, (cap_a - turn * v * v) / (lin + rho / law.accel_mm_per_rad))
    elif cap_a is not None:
        a = min(a, cap_a)
    return v, a
