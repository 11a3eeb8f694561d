"""The speed of the tool points (tmscal.safety.laws): the speed and acceleration plan_move commands
keep every tool point under the caps on each controller's own timing, measured here by finite
differences of the motion the mocks model (the UR mock's ``Motion``: translation and rotation
trapezoids, the longer one timing both; the DENSO mock's translation trapezoid), of franky-like
per-axis motions, and against closed forms; the rotation-vector bound franky's law rests on is
checked numerically."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.fuzz import fuzz_settings
from tmscal.errors import SafetyError
from tmscal.geometry import make_pose, rot_z
from tmscal.mocks.ur.motion import Motion
from tmscal.motion import Trapezoid
from tmscal.safety import (
    AxisPath,
    AxisProfile,
    Envelope,
    LinearPath,
    MotionLaw,
    SharedProfile,
    plan_move,
)
from tmscal.safety.laws import ROTVEC_RATE_TERM
from tmscal.sim.rig import straight_path

DOWN = np.diag([1.0, -1.0, -1.0])
UR = MotionLaw(LinearPath(), SharedProfile(250.0))
DENSO = MotionLaw(LinearPath(), SharedProfile(0.0))


def fastest(poses_of_t, t: np.ndarray, q: np.ndarray) -> tuple[float, float]:
    """(highest speed mm/s, highest acceleration mm/s²) of the flange origin and the points q
    (flange frame) over flange poses sampled at times t (central differences)."""
    P = np.array([poses_of_t(ti) for ti in t])
    pts = np.einsum("nij,kj->nki", P[:, :3, :3], np.vstack([np.zeros(3), q])) + P[:, None, :3, 3]
    dt = t[1] - t[0]
    v = np.linalg.norm(np.diff(pts, axis=0), axis=2) / dt
    a = np.linalg.norm(pts[2:] - 2 * pts[1:-1] + pts[:-2], axis=2) / dt ** 2
    return float(v.max()), float(a.max())


def ur_motion(S: np.ndarray, T: np.ndarray, v_mm_s: float, a_mm_s2: float):
    """The UR mock's own model of moveL from S to T at v, a (what ur_rtde sends: m/s, m/s²)."""
    m = Motion(S, T, 0.0, False, v_mm_s / 1000.0, a_mm_s2 / 1000.0, instant=True)
    return m.pose_at_time, m.modelled_s


@st.composite
def moves(draw):
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    S = make_pose(DOWN @ Rotation.random(random_state=rng).as_matrix(), [500.0, 0.0, 400.0])
    axis = rng.normal(size=3)
    turn = math.radians(rng.uniform(0, 170)) if rng.random() < 0.9 else 0.0
    T = make_pose(S[:3, :3] @ Rotation.from_rotvec(axis / np.linalg.norm(axis) * turn)
                  .as_matrix(), S[:3, 3] + rng.uniform(-300, 300, 3) * rng.uniform(0.01, 1))
    q = rng.uniform(-200, 200, (int(rng.integers(1, 4)), 3))
    cap_v, cap_a = rng.uniform(50, 400), rng.uniform(300, 3000)
    return S, T, q, cap_v, cap_a


@fuzz_settings(40)
@given(moves())
def test_ur_moves_keep_every_tool_point_under_the_caps_on_the_mocks_profile(move):
    S, T, q, cap_v, cap_a = move
    env = Envelope(max_speed_mm_s=cap_v, max_accel_mm_s2=cap_a, tool_points_mm=q)
    (leg,) = plan_move(env, S, T, UR, cap_v, cap_a).legs
    assert leg.speed_mm_s <= cap_v and leg.accel_mm_s2 <= cap_a
    pose_at, duration = ur_motion(S, T, leg.speed_mm_s, leg.accel_mm_s2)
    v, a = fastest(pose_at, np.linspace(0, duration, 1201), q)
    assert v <= cap_v * (1 + 1e-6) + 1e-6, (v, cap_v)
    assert a <= cap_a * (1 + 1e-3) + 1e-3, (a, cap_a)


@fuzz_settings(40)
@given(moves())
def test_denso_moves_keep_every_tool_point_under_the_caps_on_the_mocks_profile(move):
    # the DENSO mock times a MOVE L by its translation alone (docs/devices.md): the share of
    # the way follows one trapezoid over the distance
    S, T, q, cap_v, cap_a = move
    env = Envelope(max_speed_mm_s=cap_v, max_accel_mm_s2=cap_a, tool_points_mm=q)
    d = float(np.linalg.norm(T[:3, 3] - S[:3, 3]))
    if d == 0:
        return
    (leg,) = plan_move(env, S, T, DENSO, cap_v, cap_a).legs
    prof = Trapezoid(d, leg.speed_mm_s, leg.accel_mm_s2)
    v, a = fastest(lambda t: straight_path(S, T, prof.fraction(t)),
                   np.linspace(0, prof.duration, 1201), q)
    assert v <= cap_v * (1 + 1e-6) + 1e-6, (v, cap_v)
    assert a <= cap_a * (1 + 1e-3) + 1e-3, (a, cap_a)


def test_the_audits_coil_speed_before_and_after():
    # 300 mm along x while turning 0.8 rad about the vertical, a coil point 125 mm from the
    # flange axis, level with the motion at the start: the translation times the move
    # (300 mm > 250·0.8), and the point moves at up to ḟ·(300 + 0.8·125) = 400/300 of the
    # commanded speed: 333 mm/s at 250. The law lowers the command to 250·300/400.
    S = make_pose(np.eye(3), [400.0, 0.0, 400.0])
    T = make_pose(rot_z(0.8), [700.0, 0.0, 400.0])
    q = np.array([[0.0, -125.0, 0.0]])        # ω × r is along +x, with the translation
    pose_at, duration = ur_motion(S, T, 250.0, 1200.0)
    before, _ = fastest(pose_at, np.linspace(0, duration, 6001), q)
    assert before > 250.0 and before == pytest.approx(250 * 400 / 300, rel=0.01)
    env = Envelope(max_speed_mm_s=250.0, max_accel_mm_s2=1500.0, tool_points_mm=q)
    (leg,) = plan_move(env, S, T, UR, 250.0, 1200.0).legs
    assert leg.speed_mm_s == pytest.approx(250.0 * 300.0 / 400.0, rel=1e-12)
    pose_at, duration = ur_motion(S, T, leg.speed_mm_s, leg.accel_mm_s2)
    after, _ = fastest(pose_at, np.linspace(0, duration, 6001), q)
    assert after <= 250.0 * (1 + 1e-6)


def test_a_ur_turn_on_the_spot_is_timed_by_its_rotation():
    # no translation: the rotation profile (4 rad/s per m/s: 250 mm per rad) times the move,
    # so a point ρ mm from the axis moves at most at ρ/250 of the commanded speed: 125 mm
    # needs no lowering, 400 mm needs 250 · 250/400 = 156.25 mm/s
    S = make_pose(DOWN, [500.0, 0.0, 400.0])
    T = S @ make_pose(rot_z(1.5))
    for rho, want in ((125.0, 250.0), (400.0, 156.25)):
        q = np.array([[rho, 0.0, 0.0]])
        env = Envelope(max_speed_mm_s=250.0, max_accel_mm_s2=1500.0, tool_points_mm=q)
        (leg,) = plan_move(env, S, T, UR, 250.0, 1200.0).legs
        assert leg.speed_mm_s == pytest.approx(want, rel=1e-12)
        pose_at, duration = ur_motion(S, T, leg.speed_mm_s, leg.accel_mm_s2)
        v, _ = fastest(pose_at, np.linspace(0, duration, 3001), q)
        assert v <= 250.0 * (1 + 1e-6) and v == pytest.approx(rho / 250.0 * want, rel=1e-3)


def test_a_denso_turn_without_translation_is_refused_and_a_slight_one_is_slowed():
    S = make_pose(DOWN, [500.0, 0.0, 400.0])
    env = Envelope(max_speed_mm_s=250.0, max_accel_mm_s2=1500.0,
                   tool_points_mm=[[0.0, 100.0, 0.0]])
    with pytest.raises(SafetyError, match="turns 57.3° without translating"):
        plan_move(env, S, S @ make_pose(rot_z(1.0)), DENSO, 250.0, 1200.0)
    # the same pose again, up to the rounding of a reported pose (10⁻⁸ rad: 10⁻⁶ mm of travel)
    again = S @ make_pose(rot_z(1e-8))
    assert plan_move(env, S, again, DENSO, 250.0, 1200.0).legs[0].speed_mm_s == 250.0
    # 10 mm while turning 1 rad: the point travels up to 10 + 100 mm while the translation
    # travels 10, so the command is 250 · 10/110
    T = S @ make_pose(rot_z(1.0), [10.0, 0.0, 0.0])
    (leg,) = plan_move(env, S, T, DENSO, 250.0, 1200.0).legs
    assert leg.speed_mm_s == pytest.approx(250.0 * 10.0 / 110.0, rel=1e-9)


def test_a_controller_that_cannot_go_slow_enough_refuses():
    S = make_pose(DOWN, [500.0, 0.0, 400.0])
    T = S @ make_pose(rot_z(1.0), [0.01, 0.0, 0.0])
    env = Envelope(max_speed_mm_s=250.0, tool_points_mm=[[0.0, 100.0, 0.0]])
    slow = MotionLaw(LinearPath(), SharedProfile(0.0, min_speed_mm_s=0.1, name="a DENSO"))
    with pytest.raises(SafetyError, match=r"below what a DENSO can be commanded \(0.1 mm/s"):
        plan_move(env, S, T, slow, 250.0, 1200.0)


# --- franky: per-axis limits ---------------------------------------------------------------------

def _omega(r: np.ndarray, rd: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Angular velocity (rad/s) of R(t) = exp([r + t·rd]) at t = 0, by central differences."""
    R0 = Rotation.from_rotvec(r - h * rd).as_matrix()
    R1 = Rotation.from_rotvec(r + h * rd).as_matrix()
    W = Rotation.from_rotvec(r).as_matrix().T @ (R1 - R0) / (2 * h)
    return np.array([W[2, 1], W[0, 2], W[1, 0]])


def test_a_rotation_vectors_rate_bounds_the_angular_velocity_and_acceleration():
    # |ω| ≤ |ṙ| and |α| ≤ |r̈| + ROTVEC_RATE_TERM·|ṙ|², over random r (|r| < π), ṙ, r̈
    rng = np.random.default_rng(3)
    worst_w = worst_a = 0.0
    for _ in range(3000):
        r = rng.normal(size=3)
        r *= rng.uniform(0, math.pi - 1e-3) / np.linalg.norm(r)
        rd, rdd = rng.normal(size=3), rng.normal(size=3) * rng.uniform(0, 1)
        h = 1e-4
        w = _omega(r, rd)
        alpha = (_omega(r + h * rd + 0.5 * h * h * rdd, rd + h * rdd)
                 - _omega(r - h * rd + 0.5 * h * h * rdd, rd - h * rdd)) / (2 * h)
        worst_w = max(worst_w, np.linalg.norm(w) / np.linalg.norm(rd))
        bound = np.linalg.norm(rdd) + ROTVEC_RATE_TERM * np.linalg.norm(rd) ** 2
        worst_a = max(worst_a, np.linalg.norm(alpha) - bound)
    assert worst_w <= 1 + 1e-6 and worst_a <= 1e-5


@fuzz_settings(30)
@given(moves())
def test_franka_moves_keep_every_tool_point_under_the_caps_on_per_axis_profiles(move):
    """A franky-like motion: each translation axis (start frame) and each rotation-vector
    component on its own trapezoid within factor × its limit, all stretched to end together
    (Ruckig's time synchronisation); factor from the commanded speed as the driver sets it."""
    S, T, q, cap_v, cap_a = move
    vlim, alim, rvlim, ralim = 1.7, 9.0, 2.5, 17.0        # m/s, m/s², rad/s, rad/s²
    law = MotionLaw(AxisPath(), AxisProfile(1000 * vlim / rvlim, 1000 * alim / ralim))
    env = Envelope(max_speed_mm_s=cap_v, max_accel_mm_s2=cap_a, tool_points_mm=q)
    (leg,) = plan_move(env, S, T, law, cap_v, cap_a).legs
    fv = leg.speed_mm_s / 1000 / (math.sqrt(3) * vlim)
    fa = leg.accel_mm_s2 / 1000 / (math.sqrt(3) * alim)
    du = S[:3, :3].T @ (T[:3, 3] - S[:3, 3])
    dr = Rotation.from_matrix(S[:3, :3].T @ T[:3, :3]).as_rotvec()
    caps = [(abs(x), fv * vlim * 1000, fa * alim * 1000) for x in du] + \
           [(abs(x), fv * rvlim, fa * ralim) for x in dr]
    T_end = max(Trapezoid(d, v, a).duration for d, v, a in caps)
    if T_end == 0:
        return
    profs = []
    for d, v, a in caps:           # the same acceleration, the cruise slowed to end at T_end
        if d == 0:
            profs.append(lambda t: 1.0)
            continue
        lo, hi = 0.0, v
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if Trapezoid(d, mid, a).duration > T_end else (lo, mid)
        profs.append(Trapezoid(d, hi, a).fraction)

    def pose_at(t: float) -> np.ndarray:
        f = np.array([p(t) for p in profs])
        R = S[:3, :3] @ Rotation.from_rotvec(f[3:] * dr).as_matrix()
        return make_pose(R, S[:3, 3] + S[:3, :3] @ (f[:3] * du))

    v, a = fastest(pose_at, np.linspace(0, T_end, 801), q)
    assert v <= cap_v * (1 + 1e-3) + 1e-3, (v, cap_v)
    assert a <= cap_a * (1 + 2e-2) + 1e-2, (a, cap_a)
