"""The safety envelope at its boundaries, against hand-computed expectations (never against
Envelope itself): rotation, offset, each face of the workspace box, tool points, speed and
acceleration caps; construction refuses non-finite limits; comparisons fail closed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tmscal.drivers.base import Envelope, Robot, SafetyError
from tmscal.safety import LinearPath, MotionLaw, SharedProfile

# P0: flange 500 mm in front of the base, 400 mm up, tool axis (flange z) pointing down
P0 = np.array([[1.0, 0.0, 0.0, 500.0],
               [0.0, -1.0, 0.0, 0.0],
               [0.0, 0.0, -1.0, 400.0],
               [0.0, 0.0, 0.0, 1.0]])
BOX_MIN = (100.0, -400.0, 0.0)
BOX_MAX = (900.0, 400.0, 800.0)


def rot(axis: str, deg: float) -> np.ndarray:
    """4×4 rotation about a principal axis, written out by hand."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    R = {"x": [[1, 0, 0], [0, c, -s], [0, s, c]],
         "y": [[c, 0, s], [0, 1, 0], [-s, 0, c]],
         "z": [[c, -s, 0], [s, c, 0], [0, 0, 1]]}[axis]
    T = np.eye(4)
    T[:3, :3] = R
    return T


def at(x: float, y: float, z: float, R: np.ndarray | None = None) -> np.ndarray:
    T = np.eye(4) if R is None else R.copy()
    T[:3, 3] = [x, y, z]
    return T


class Recorder(Robot):
    """A robot whose motion hook only records what reached it; it moves like a UR moveL
    (rotation timed at 250 mm per rad) and stands at P0."""

    name = "recorder"

    def __init__(self, **kw):
        super().__init__(**kw)
        self.sent: list[tuple[np.ndarray, float, float]] = []

    def _open(self):
        pass

    def _close(self):
        pass

    def _flange_pose(self):
        return P0.copy()

    def motion_law(self):
        return MotionLaw(LinearPath(), SharedProfile(250.0))

    def _move_to(self, pose, speed_mm_s, accel_mm_s2):
        self.sent.append((pose.copy(), speed_mm_s, accel_mm_s2))

    def _stop(self):
        pass


# --- rotation from P0 ------------------------------------------------------------------------

@pytest.mark.parametrize("axis", ["x", "y", "z"])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_rotation_limit_per_axis(axis, sign):
    env = Envelope(center=P0, max_rotation_deg=20.0)
    # P0 · R(θ): a rotation of exactly |θ| away from P0 (about a flange axis)
    assert env.violations(P0 @ rot(axis, sign * 19.9)) == []
    v = env.violations(P0 @ rot(axis, sign * 20.1))
    assert len(v) == 1 and "max_rotation_deg 20" in v[0]
    # about a base axis: R(θ) · P0 (translation kept at P0's)
    q = rot(axis, sign * 20.1) @ P0
    q[:3, 3] = P0[:3, 3]
    assert env.violations(q) != []


def test_rotation_limit_small_and_large():
    env = Envelope(center=P0, max_rotation_deg=1.0)
    assert env.violations(P0 @ rot("x", 0.9)) == []
    assert env.violations(P0 @ rot("x", 1.1)) != []
    assert Envelope(center=P0, max_rotation_deg=170.0).violations(P0 @ rot("y", 170.1)) != []


# --- offset from P0 --------------------------------------------------------------------------

@pytest.mark.parametrize("direction", [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0),
                                       (0, 0, 1), (0, 0, -1),
                                       (1 / math.sqrt(3),) * 3])
def test_offset_limit(direction):
    env = Envelope(center=P0, max_offset_mm=200.0)
    d = np.asarray(direction)
    inside, outside = P0.copy(), P0.copy()
    inside[:3, 3] += 199.9 * d
    outside[:3, 3] += 200.1 * d
    assert env.violations(inside) == []
    v = env.violations(outside)
    assert len(v) == 1 and "max_offset_mm 200" in v[0]


# --- the workspace box, each face ------------------------------------------------------------

FACES = [(axis, side) for axis in range(3) for side in ("min", "max")]


@pytest.mark.parametrize("axis, side", FACES)
def test_box_faces_flange(axis, side):
    env = Envelope(box_min_mm=BOX_MIN, box_max_mm=BOX_MAX)
    mid = [500.0, 0.0, 400.0]
    face = (BOX_MIN if side == "min" else BOX_MAX)[axis]
    step = -0.1 if side == "min" else 0.1  # outward
    inside, outside = list(mid), list(mid)
    inside[axis] = face - step
    outside[axis] = face + step
    assert env.violations(at(*inside)) == []
    v = env.violations(at(*outside))
    assert len(v) == 1 and "flange origin" in v[0] and "outside workspace box" in v[0]
    assert env.violations(at(*[face if i == axis else m for i, m in enumerate(mid)])) == []


@pytest.mark.parametrize("axis, side", FACES)
def test_box_faces_tool_point_while_flange_inside(axis, side):
    """A tool point 50 mm from the flange along the face normal (identity rotation): the
    flange is 50 mm inside, the point 0.1 mm outside → refused, naming the tool point."""
    outward = np.zeros(3)
    outward[axis] = -1.0 if side == "min" else 1.0
    q = 50.0 * outward  # flange frame
    env = Envelope(box_min_mm=BOX_MIN, box_max_mm=BOX_MAX, tool_points_mm=[[0, 0, 0], q])
    face = (BOX_MIN if side == "min" else BOX_MAX)[axis]
    mid = np.array([500.0, 0.0, 400.0])
    fl_out, fl_in = mid.copy(), mid.copy()
    fl_out[axis] = face - 50.0 * outward[axis] + 0.1 * outward[axis]  # point at face + 0.1
    fl_in[axis] = face - 50.0 * outward[axis] - 0.1 * outward[axis]   # point at face − 0.1
    assert env.violations(at(*fl_in)) == []
    v = env.violations(at(*fl_out))
    assert len(v) == 1 and v[0].startswith("tool point 1 ") and "outside workspace box" in v[0]


def test_tool_point_is_carried_by_the_pose_rotation():
    """Coil centre 110 mm along the flange z; with P0's orientation (z down) it sits 110 mm
    below the flange in the base frame."""
    env = Envelope(box_min_mm=BOX_MIN, box_max_mm=BOX_MAX, tool_points_mm=[[0, 0, 110]])
    ok = P0.copy()
    ok[2, 3] = 110.1      # point at z = 0.1
    bad = P0.copy()
    bad[2, 3] = 109.9     # point at z = −0.1, flange well inside
    assert env.violations(ok) == []
    v = env.violations(bad)
    assert len(v) == 1 and "tool point 0" in v[0]
    # tilted 90° about the flange x: flange z → base +y (R = diag(1,-1,-1)·Rx(90°))
    tilt = P0 @ rot("x", 90.0)
    np.testing.assert_allclose(tilt[:3, :3] @ [0, 0, 110], [0, 110, 0], atol=1e-9)
    tilt[:3, 3] = [500.0, 400.0 - 110.0 + 0.1, 400.0]   # point at y = 400.1
    assert "tool point 0" in " ".join(env.violations(tilt))
    tilt[1, 3] -= 0.2                                      # point at y = 399.9
    assert env.violations(tilt) == []


# --- speed and acceleration caps -------------------------------------------------------------

def test_speed_and_accel_caps():
    env = Envelope(max_speed_mm_s=250.0, max_accel_mm_s2=1500.0)
    env.check_speed(250.0, 1500.0)
    env.check_speed(247.5, 1485.0)
    with pytest.raises(SafetyError, match="max_speed_mm_s"):
        env.check_speed(252.5, 1000.0)        # 1 % over
    with pytest.raises(SafetyError, match="max_accel_mm_s2"):
        env.check_speed(100.0, 1515.0)        # 1 % over
    with pytest.raises(SafetyError, match="max_accel_mm_s2"):
        env.check_speed(100.0, 15000.0)


@pytest.mark.parametrize("accel", [0.0, -1.0, -1500.0, math.nan, math.inf, -math.inf, True])
def test_accel_must_be_positive_finite(accel):
    for env in (Envelope(max_accel_mm_s2=1500.0), Envelope()):
        with pytest.raises(SafetyError, match="acceleration"):
            env.check_speed(100.0, accel)


@pytest.mark.parametrize("speed", [0.0, -5.0, math.nan, math.inf, None, "100"])
def test_speed_must_be_positive_finite(speed):
    with pytest.raises(SafetyError, match="speed"):
        Envelope().check_speed(speed, 100.0)


def test_move_to_refuses_before_the_hook():
    env = Envelope(center=P0, max_offset_mm=200.0, max_rotation_deg=20.0, box_min_mm=BOX_MIN,
                   box_max_mm=BOX_MAX, max_speed_mm_s=250.0, max_accel_mm_s2=1500.0,
                   tool_points_mm=[[0, 0, 110]])
    with Recorder(envelope=env, speed_mm_s=100.0, accel_mm_s2=1515.0) as r:
        with pytest.raises(SafetyError, match="max_accel_mm_s2"):
            r.move_to(P0)
        assert r.sent == []
    with Recorder(envelope=env, speed_mm_s=100.0, accel_mm_s2=1500.0) as r:
        for bad in (P0 @ rot("z", 20.1), at(500, 0, 109.9, P0), np.full((4, 4), np.nan),
                    2 * P0, np.eye(3)):
            with pytest.raises(SafetyError):
                r.move_to(bad)
        with pytest.raises(SafetyError):
            r.move_to(P0, speed_mm_s=252.5)
        assert r.sent == []
        target = P0 @ rot("y", 19.9)
        r.move_to(target, speed_mm_s=250.0)
        assert len(r.sent) == 1
        np.testing.assert_array_equal(r.sent[0][0], target)
        assert r.sent[0][1:] == (250.0, 1500.0)


def test_move_to_sends_the_checked_copy():
    env = Envelope(center=P0, max_offset_mm=10.0)
    with Recorder(envelope=env) as r:
        target = P0.copy()
        r.move_to(target)
        target[0, 3] = 1e6  # mutating the caller's array later changes nothing sent
        assert r.sent[0][0][0, 3] == 500.0


# --- construction and failing closed ---------------------------------------------------------

@pytest.mark.parametrize("kw", [
    {"max_offset_mm": math.nan}, {"max_rotation_deg": math.inf}, {"max_speed_mm_s": -1.0},
    {"max_accel_mm_s2": 0.0}, {"max_accel_mm_s2": math.nan}, {"max_offset_mm": True},
    {"max_offset_mm": "200"}, {"max_speed_mm_s": 10**400},
    {"box_min_mm": (0, 0, math.nan), "box_max_mm": (1, 1, 1)},
    {"box_min_mm": (0, 0, 0), "box_max_mm": (1, math.inf, 1)},
    {"box_min_mm": (0, 0, 0), "box_max_mm": (1, 0, 1)},       # min == max on y
    {"box_min_mm": (0, 0, 2), "box_max_mm": (1, 1, 1)},       # reordered on z
    {"box_min_mm": (0, 0, 0)},                                # half a box
    {"box_min_mm": (0, 0), "box_max_mm": (1, 1)},
    {"tool_points_mm": [[0, 0, math.nan]]}, {"tool_points_mm": [[0, 0]]},
    {"center": np.full((4, 4), np.nan)}, {"center": np.eye(3)},
])
def test_envelope_refuses_bad_limits(kw):
    with pytest.raises(ValueError):
        Envelope(**kw)


def test_violations_fail_closed_on_nan_limits():
    """Even a limit forced to NaN after construction counts as a violation, never a pass."""
    env = Envelope(center=P0, max_offset_mm=200.0, max_rotation_deg=20.0, box_min_mm=BOX_MIN,
                   box_max_mm=BOX_MAX)
    for k in ("max_offset_mm", "max_rotation_deg"):
        e = Envelope(center=P0, max_offset_mm=200.0, max_rotation_deg=20.0)
        object.__setattr__(e, k, math.nan)
        assert e.violations(P0) != [], k
    object.__setattr__(env, "box_max_mm", (900.0, math.nan, 800.0))
    assert env.violations(P0) != []


def test_center_cannot_be_mutated_through_the_caller():
    c = P0.copy()
    env = Envelope(center=c, max_offset_mm=10.0)
    c[0, 3] = 0.0
    assert env.violations(P0) == []
    with pytest.raises(ValueError):
        env.center[0, 3] = 0.0
