"""The trapezoidal velocity profile (tmscal.motion) against the kinematics it must obey."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.geometry import make_pose, rot_z
from tmscal.motion import Trapezoid, move_duration, trapezoid_duration

finite_pos = st.floats(min_value=1e-3, max_value=1e4, allow_nan=False, allow_infinity=False)


def test_long_move_cruises_at_the_cap() -> None:
    # 1000 mm at 250 mm/s, 1000 mm/s²: ramps of 0.25 s cover 31.25 mm each, the cruise
    # covers the other 937.5 mm in 3.75 s
    p = Trapezoid(1000.0, 250.0, 1000.0)
    assert p.peak_speed == 250.0
    assert p.duration == pytest.approx(0.25 + 3.75 + 0.25)
    assert p.position(0.25) == pytest.approx(31.25)
    assert p.position(p.duration - 0.25) == pytest.approx(1000.0 - 31.25)


def test_short_move_is_triangular() -> None:
    # 10 mm at 1000 mm/s² never reaches 250 mm/s: peak √(d·a) = 100 mm/s after 0.1 s
    p = Trapezoid(10.0, 250.0, 1000.0)
    assert p.peak_speed == pytest.approx(100.0)
    assert p.duration == pytest.approx(0.2)
    assert p.position(0.1) == pytest.approx(5.0)


def test_zero_distance_takes_no_time() -> None:
    assert trapezoid_duration(0.0, 100.0, 100.0) == 0.0
    assert Trapezoid(0.0, 1.0, 1.0).fraction(0.0) == 1.0


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_caps_must_be_finite_and_positive(bad: float) -> None:
    with pytest.raises(ValueError, match="speed"):
        Trapezoid(1.0, bad, 1.0)
    with pytest.raises(ValueError, match="accel"):
        Trapezoid(1.0, 1.0, bad)


@fuzz_settings()
@given(d=finite_pos, v=finite_pos, a=finite_pos, s=st.floats(0.0, 1.0))
def test_profile_respects_its_caps(d: float, v: float, a: float, s: float) -> None:
    p = Trapezoid(d, v, a)
    T = p.duration
    # never faster than the cap, never shorter than the distance at the cap allows
    assert T >= d / v * (1 - 1e-9)
    assert T >= 2 * math.sqrt(d / a) * (1 - 1e-9)
    # monotone position from 0 to d, speeds within the cap (finite differences)
    t = s * T
    h = T * 1e-4
    x0, x1 = p.position(t), p.position(min(t + h, T))
    assert 0.0 <= x0 <= x1 <= d * (1 + 1e-12)
    if h > 0:
        assert (x1 - x0) / h <= v * (1 + 1e-6) + 1e-9
    assert p.position(T) == d


def test_rotation_can_set_the_duration() -> None:
    start = make_pose(np.eye(3), [0.0, 0.0, 0.0])
    target = make_pose(rot_z(np.radians(90.0)), [1.0, 0.0, 0.0])
    lin = move_duration(start, target, 100.0, 1000.0)
    both = move_duration(start, target, 100.0, 1000.0, rot_speed_deg_s=30.0,
                         rot_accel_deg_s2=60.0)
    assert lin == pytest.approx(trapezoid_duration(1.0, 100.0, 1000.0))
    assert both == pytest.approx(trapezoid_duration(90.0, 30.0, 60.0))
