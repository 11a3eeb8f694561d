"""DensoRobot's percentage conversions (SPEED, acceleration) and its refusal of unusable
values: the arm is never commanded faster or harder than configured."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.drivers.denso.robot import (
    DEFAULT_MAX_LINEAR_ACCEL_MM_S2,
    DensoRobot,
    accel_percent,
    speed_option,
)

BAD = [float("nan"), float("inf"), -float("inf"), 0.0, -1.0]


def test_accel_percent_rounds_down() -> None:
    assert accel_percent(1234.0, 20000.0) == 6.17
    assert accel_percent(1200.0, 7000.0) == 17.14      # 17.1428… never rounded up
    assert accel_percent(700.0, 7000.0) == 10.0        # exact values stay exact
    assert accel_percent(1e6, 7000.0) == 100.0         # capped at 100 %
    assert accel_percent(2.0, 20000.0) == 0.01


@pytest.mark.parametrize("bad", BAD)
def test_accel_percent_refuses_unusable_values(bad: float) -> None:
    with pytest.raises(ValueError, match="accel_mm_s2 must be a finite number > 0"):
        accel_percent(bad, 20000.0)
    with pytest.raises(ValueError, match="max_linear_accel_mm_s2"):
        accel_percent(500.0, bad)


def test_accel_percent_refuses_what_no_percentage_can_express() -> None:
    with pytest.raises(ValueError, match="below 0.01 %"):
        accel_percent(1.0, 20000.0)


@pytest.mark.parametrize("bad", BAD)
def test_speed_option_refuses_unusable_values(bad: float) -> None:
    with pytest.raises(ValueError, match="speed_mm_s"):
        speed_option(bad, 1000.0)
    with pytest.raises(ValueError, match="max_linear_speed_mm_s"):
        speed_option(100.0, bad)


_pos = st.floats(min_value=1e-3, max_value=1e7, allow_nan=False, allow_infinity=False)


@fuzz_settings(300)
@given(_pos, _pos)
def test_accel_percent_never_above_the_configured_accel(accel: float, full: float) -> None:
    try:
        pct = accel_percent(accel, full)
    except ValueError:
        assert accel / full * 100.0 < 0.01 + 1e-9
        return
    assert 0.01 <= pct <= 100.0
    assert pct / 100.0 * full <= accel * (1 + 1e-12)
    assert round(pct, 2) == pct
    assert pct == 100.0 or (pct + 0.01) / 100.0 * full > accel * (1 - 1e-9)  # tightest


@fuzz_settings(300)
@given(_pos, _pos)
def test_speed_option_never_above_the_configured_speed(speed: float, full: float) -> None:
    pct = float(speed_option(speed, full).removeprefix("SPEED="))
    assert 0.01 <= pct <= 100.0
    assert pct == 0.01 or pct / 100.0 * full <= speed * (1 + 1e-12)


@pytest.mark.parametrize("kw, key", [
    ({"max_linear_accel_mm_s2": float("nan")}, "max_linear_accel_mm_s2"),
    ({"max_linear_accel_mm_s2": 0.0}, "max_linear_accel_mm_s2"),
    ({"max_linear_speed_mm_s": float("inf")}, "max_linear_speed_mm_s"),
    ({"accel_mm_s2": float("nan")}, "accel_mm_s2"),
    ({"accel_mm_s2": -5.0}, "accel_mm_s2"),
    ({"speed_mm_s": float("nan")}, "speed_mm_s"),
    ({"ext_speed_percent": 0.0}, "ext_speed_percent"),
    ({"ext_speed_percent": float("nan")}, "ext_speed_percent"),
    ({"ext_speed_percent": 101.0}, "ext_speed_percent"),
    ({"watchdog_ms": -1}, "watchdog_ms"),
    ({"watchdog_ms": float("nan")}, "watchdog_ms"),
])
def test_denso_robot_refuses_unusable_motion_settings(kw: dict, key: str) -> None:
    with pytest.raises(ValueError, match=key):
        DensoRobot(**kw)


def test_default_max_linear_accel_is_documented_and_high() -> None:
    r = DensoRobot()
    assert r.max_linear_accel_mm_s2 == DEFAULT_MAX_LINEAR_ACCEL_MM_S2
    assert math.isfinite(DEFAULT_MAX_LINEAR_ACCEL_MM_S2)
    # the default errs on the gentle side: the config's default 500 mm/s² is a few percent
    assert r.accel_percent() == 2.5


def test_move_to_sends_speed_as_a_percent_of_the_arms_full_speed() -> None:
    """What the controller receives (the DENSO mock over b-CAP): SPEED = speed_mm_s /
    max_linear_speed_mm_s × 100, the configured speed by default, the move's own when given;
    ExtSpeed's accel = accel_mm_s2 / max_linear_accel_mm_s2 × 100. A unit slip fails here."""
    from tmscal.geometry import make_pose
    from tmscal.mocks.clock import FAST
    from tmscal.mocks.denso import DensoMock
    from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)
    with DensoMock(rig, clock=FAST, max_linear_speed_mm_s=800.0) as m:
        port = int(m.start().rpartition(":")[2])
        with DensoRobot(port=port, speed_mm_s=50.0, accel_mm_s2=600.0,
                        max_linear_speed_mm_s=800.0, max_linear_accel_mm_s2=12000.0,
                        watchdog_ms=None) as robot:
            robot.move_to(TMS_RIG_P0 @ make_pose(t=[10.0, 0.0, 0.0]))
            robot.move_to(TMS_RIG_P0 @ make_pose(t=[0.0, 20.0, 0.0]), speed_mm_s=200.0)
        assert m.move_speed_log == [6.25, 25.0]          # 50 / 800, 200 / 800
        assert m.ext_speed_log == [(100.0, 5.0, 5.0)]    # 600 / 12000
