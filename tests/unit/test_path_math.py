"""The path between two poses (tmscal.safety.paths, route): a sweep that leaves the box mid-path
with both ends inside, the controller's frame (TCP) versus the flange, the sampling bound against
very fine sampling done here by hand (scipy), the rotation from P0 along the geodesic, the split
route through P0 and its refusal, franky's per-axis hull, and a joint-space move of a planar arm
whose sweep is known in closed form. Expectations are worked by hand or sampled independently,
never read back from the code under test."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.fuzz import fuzz_settings
from tmscal.errors import SafetyError
from tmscal.geometry import make_pose, rot_x, rot_y, rot_z
from tmscal.safety import (
    AxisPath,
    Envelope,
    LinearPath,
    MotionLaw,
    SharedProfile,
    check_axis,
    check_joint_path,
    check_linear,
    plan_move,
)

DOWN = np.diag([1.0, -1.0, -1.0])     # flange z pointing down, x along base x
BOX = ((300.0, -200.0, 200.0), (700.0, 200.0, 600.0))   # the audit's box (mm)
COIL = [[0.0, 0.0, 150.0]]            # a coil point 150 mm below the flange (flange frame)
UR_LAW = MotionLaw(LinearPath(), SharedProfile(250.0))


def turned(x: float, y: float, z: float, deg: float) -> np.ndarray:
    """The flange pointing down at (x, y, z) mm, turned ``deg`` about its own y axis."""
    return make_pose(DOWN @ rot_y(math.radians(deg)), [x, y, z])


def straight(A: np.ndarray, B: np.ndarray, f: np.ndarray,
             flange_from_frame: np.ndarray | None = None) -> np.ndarray:
    """Flange poses (n, 4, 4) of a linear move of the frame ``flange_from_frame``, written here
    with scipy: the frame's origin on the line, its rotation on the geodesic, one share."""
    phi = np.eye(4) if flange_from_frame is None else flange_from_frame
    FA, FB = A @ phi, B @ phi
    rv = Rotation.from_matrix(FA[:3, :3].T @ FB[:3, :3]).as_rotvec()
    out = np.zeros((len(f), 4, 4))
    out[:, 3, 3] = 1
    out[:, :3, :3] = FA[:3, :3] @ Rotation.from_rotvec(f[:, None] * rv).as_matrix()
    out[:, :3, 3] = FA[:3, 3] + f[:, None] * (FB[:3, 3] - FA[:3, 3])
    return out @ np.linalg.inv(phi)


def points(poses: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Base-frame places (n, k, 3) of flange-frame points q (k, 3)."""
    return np.einsum("nij,kj->nki", poses[:, :3, :3], q) + poses[:, None, :3, 3]


# --- a sweep that leaves the box between two poses inside it ------------------------------------

def test_the_audit_sweep_leaves_the_box_mid_path_although_both_ends_are_inside():
    # the wrist turns 127° about the flange's y axis: the coil point is at
    # x = 420 − 150·sin φ, z = 450 − 150·cos φ (φ the turn so far), so both ends are inside
    # (x = 420 and 300.2) but at φ = 90° (share 90/127) it is at x = 270: 30 mm out
    env = Envelope(box_min_mm=BOX[0], box_max_mm=BOX[1], tool_points_mm=COIL)
    S, T = turned(420, 0, 450, 0), turned(420, 0, 450, -127)
    assert env.violations(S) == [] and env.violations(T) == []
    v = check_linear(env, S, T, LinearPath())
    assert v is not None and v.certain
    assert v.what.startswith("tool point 0") and "x-min wall (300.0 mm)" in v.limit
    assert v.excess == pytest.approx(30.0, abs=0.05)
    assert v.share == pytest.approx(90 / 127, abs=0.002)
    np.testing.assert_allclose(v.where_mm, [270.0, 0.0, 450.0], atol=0.5)
    # a box 31 mm wider on that side holds the whole sweep
    wide = Envelope(box_min_mm=(269.0, -200.0, 200.0), box_max_mm=BOX[1], tool_points_mm=COIL)
    assert check_linear(wide, S, T, LinearPath()) is None


def test_a_wall_between_two_samples_is_found_by_the_sag_margin():
    # the sweep's extreme (x = 270.000 at φ = 90°) lies between two samples of the first pass,
    # which are 0.03–0.06 mm further in; a wall 0.02 mm inside the extreme is crossed
    S, T = turned(420, 0, 450, 0), turned(420, 0, 450, -127)
    for inside_by, crossed in ((0.02, True), (-0.02, False)):
        env = Envelope(box_min_mm=(270.0 + inside_by, -200.0, 200.0), box_max_mm=BOX[1],
                       tool_points_mm=COIL)
        v = check_linear(env, S, T, LinearPath())
        assert (v is not None) == crossed, (inside_by, v)
        if crossed:
            assert v.certain and v.excess == pytest.approx(inside_by, abs=2e-3)


# --- the controller's frame -----------------------------------------------------------------------

def test_a_controller_that_moves_the_tcp_swings_the_flange_instead():
    # TCP at the coil point, 150 mm below the flange; a 90° turn about the TCP's y axis keeps
    # the TCP at (500, 0, 300) and swings the flange on a circle around it:
    # flange = (500 + 150 sin φ, 0, 300 + 150 cos φ). A controller that moved the flange on
    # the straight line instead would swing the coil point to x = 575 − 150·sin 45° = 468.9
    # at half way.
    tcp = make_pose(np.eye(3), [0.0, 0.0, 150.0])
    S = make_pose(DOWN, [500.0, 0.0, 450.0])
    T = S @ tcp @ make_pose(rot_y(math.radians(-90.0))) @ np.linalg.inv(tcp)
    np.testing.assert_allclose(T[:3, 3], [650.0, 0.0, 300.0], atol=1e-9)
    half = straight(S, T, np.array([0.5]), tcp)[0]
    s45 = 150 * math.sin(math.pi / 4)
    np.testing.assert_allclose(half[:3, 3], [500 + s45, 0.0, 300 + s45], atol=1e-9)
    env = Envelope(box_min_mm=(480.0, -200.0, 280.0), box_max_mm=(700.0, 200.0, 600.0),
                   tool_points_mm=COIL)
    assert check_linear(env, S, T, LinearPath(tcp)) is None
    v = check_linear(env, S, T, LinearPath())          # the flange's straight line
    assert v is not None and v.what.startswith("tool point 0")
    # x = 500 + 150 f − 150 sin(πf/2) is least where cos(πf/2) = 2/π
    u = math.acos(2 / math.pi)
    assert v.excess == pytest.approx(480 - (500 + 150 * (2 * u / math.pi) - 150 * math.sin(u)),
                                     abs=0.05)


# --- the sampling bound, against very fine sampling ---------------------------------------------

@st.composite
def sweeps(draw):
    """A random linear move (any turn up to 179°, any frame) and one checked point."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    S = make_pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-100, 100, 3))
    axis = rng.normal(size=3)
    turn = Rotation.from_rotvec(axis / np.linalg.norm(axis) * math.radians(rng.uniform(1, 179)))
    T = make_pose(S[:3, :3] @ turn.as_matrix(), S[:3, 3] + rng.uniform(-200, 200, 3))
    phi = make_pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-80, 80, 3)) \
        if rng.random() < 0.5 else np.eye(4)
    q = rng.uniform(-200, 200, 3)
    return S, T, phi, q, rng


@fuzz_settings(60)
@given(sweeps(), st.floats(0.001, 0.04), st.booleans())
def test_every_wall_the_fine_sampled_path_crosses_is_found(sweep, eps, crossed):
    """Put one wall ``eps`` mm inside (or outside) the point's most extreme place along one
    axis, found by 50,001 samples (they miss the extreme by < 10⁻⁶ mm); the check must report
    it exactly when it is crossed."""
    S, T, phi, q, rng = sweep
    f = np.linspace(0, 1, 50_001)
    p = points(straight(S, T, f, phi), np.vstack([np.zeros(3), q]))   # flange origin, point
    ax, side = int(rng.integers(0, 3)), int(rng.integers(0, 2))
    far = p[:, :, ax].max() if side else p[:, :, ax].min()
    wall = far - eps if crossed == bool(side) else far + eps   # crossed: wall inside extreme
    lo, hi = p.min(axis=(0, 1)) - 20.0, p.max(axis=(0, 1)) + 20.0
    (hi if side else lo)[ax] = wall
    env = Envelope(box_min_mm=tuple(lo), box_max_mm=tuple(hi), tool_points_mm=[q.tolist()])
    v = check_linear(env, S, T, LinearPath(phi))
    if crossed:
        assert v is not None, "a crossed wall was not found"
        assert v.excess == pytest.approx(eps, abs=1e-3)
    else:
        assert v is None, f"a path {eps:.3f} mm inside was refused: {v}"


# --- the rotation from P0 along the way ---------------------------------------------------------

def test_the_rotation_from_p0_can_peak_mid_path():
    # ±100° about x from P0: both ends 100° away, but the geodesic between them (160°) goes
    # the short way round, through 180° from P0, half way
    env = Envelope(center=np.eye(4), max_rotation_deg=120.0)
    S, T = make_pose(rot_x(math.radians(100))), make_pose(rot_x(math.radians(-100)))
    v = check_linear(env, S, T, LinearPath())
    assert v is not None and v.what == "the flange's rotation" and v.unit == "°"
    assert v.excess == pytest.approx(60.0, abs=1e-6) and v.share == pytest.approx(0.5, abs=1e-9)
    # ±50°: the geodesic passes P0 itself; the ends are the farthest
    assert check_linear(env, make_pose(rot_x(0.87)), make_pose(rot_x(-0.87)), LinearPath()) is None


@fuzz_settings(100)
@given(sweeps(), st.floats(0.02, 1.0), st.booleans())
def test_the_largest_rotation_from_p0_matches_fine_sampling(sweep, eps, above):
    """The largest rotation from P0 along the way, against 20,001 samples (which can miss a
    peak at 180°, a cusp, by up to 180°/20,000 = 0.009°)."""
    S, T, phi, _, rng = sweep
    C = make_pose(Rotation.random(random_state=rng).as_matrix())
    R = straight(S, T, np.linspace(0, 1, 20_001), phi)[:, :3, :3]
    ang = np.degrees(Rotation.from_matrix(C[:3, :3].T @ R).magnitude())
    worst = float(ang.max())
    limit = worst + eps if above else worst - eps
    if not 0 < limit <= 180:
        return
    env = Envelope(center=C, max_rotation_deg=limit)
    v = check_linear(env, S, T, LinearPath(phi))
    ends = max(float(ang[0]), float(ang[-1]))
    if above:
        assert v is None
    elif ends <= limit:                      # only the way there breaks the limit
        assert v is not None and v.excess == pytest.approx(eps, abs=0.01)


# --- the split route ---------------------------------------------------------------------------

def test_the_split_route_goes_through_p0_and_stays_inside():
    # P0 at the box's centre; turning there keeps the coil point within 150 mm of it
    p0 = make_pose(DOWN, [500.0, 0.0, 400.0])
    env = Envelope(center=p0, max_offset_mm=300.0, max_rotation_deg=170.0, box_min_mm=BOX[0],
                   box_max_mm=BOX[1], tool_points_mm=COIL)
    S, T = turned(420, 0, 450, 0), turned(420, 0, 450, -127)
    route = plan_move(env, S, T, UR_LAW, 250.0, 1200.0)
    assert route.split and "x-min wall" in route.why
    want = [turned(500, 0, 400, 0), turned(500, 0, 400, -127), T]
    assert len(route.legs) == 3
    prev = S
    for leg, w in zip(route.legs, want, strict=True):
        np.testing.assert_allclose(leg.start, prev, atol=1e-12)
        np.testing.assert_allclose(leg.target, w, atol=1e-9)
        p = points(straight(leg.start, leg.target, np.linspace(0, 1, 5001)),
                   np.array([[0, 0, 0], *COIL], dtype=float))
        assert (p >= np.array(BOX[0]) - 1e-9).all() and (p <= np.array(BOX[1]) + 1e-9).all()
        prev = leg.target


@pytest.mark.parametrize("early", [True, False])
def test_a_controller_that_cannot_turn_on_the_spot_turns_while_translating(early):
    # a DENSO MOVE L times only the translation: the turn at the centre could not be timed,
    # so the route turns on the way to the centre (or, when that leaves, on the way out);
    # every leg translates, stays inside (sampled finely, by hand) and gets a finite speed
    denso = MotionLaw(LinearPath(), SharedProfile(0.0, min_speed_mm_s=0.01,
                                                  min_accel_mm_s2=0.01, name="a DENSO MOVE L"))
    p0 = make_pose(DOWN, [500.0, 0.0, 400.0])
    env = Envelope(center=p0, max_offset_mm=300.0, max_rotation_deg=170.0, box_min_mm=BOX[0],
                   box_max_mm=BOX[1], tool_points_mm=COIL, max_speed_mm_s=250.0,
                   max_accel_mm_s2=1500.0)
    S, T = turned(420, 0, 450, 0), turned(420, 0, 450, -127)
    if not early:
        S, T = T, S
    with pytest.raises(SafetyError, match="without translating"):
        plan_move(env, turned(500, 0, 400, 0), turned(500, 0, 400, -127), denso, 250.0, 1200.0)
    route = plan_move(env, S, T, denso, 250.0, 1200.0)
    assert route.split and "x-min wall" in route.why and len(route.legs) == 2
    np.testing.assert_allclose(route.legs[0].target[:3, 3], [500.0, 0.0, 400.0], atol=1e-9)
    np.testing.assert_allclose(route.legs[-1].target, T, atol=1e-12)
    for leg in route.legs:
        assert np.linalg.norm(leg.target[:3, 3] - leg.start[:3, 3]) > 1.0
        assert 0 < leg.speed_mm_s <= 250.0 and 0 < leg.accel_mm_s2 <= 1200.0
        p = points(straight(leg.start, leg.target, np.linspace(0, 1, 5001)),
                   np.array([[0, 0, 0], *COIL], dtype=float))
        assert (p >= np.array(BOX[0]) - 1e-9).all() and (p <= np.array(BOX[1]) + 1e-9).all()


def test_a_turn_past_the_rotation_limit_goes_back_through_p0s_orientation():
    # +100° and −100° about P0's x axis are both inside a 120° limit, but the geodesic between
    # them (and the same turn at the centre) passes 180° from P0: the route turns back to
    # P0's orientation at the centre, then on to the target's, never more than 100° from P0
    p0 = make_pose(DOWN, [500.0, 0.0, 400.0])
    env = Envelope(center=p0, max_rotation_deg=120.0, box_min_mm=BOX[0], box_max_mm=BOX[1])
    S = make_pose(DOWN @ rot_x(math.radians(100)), [450.0, 50.0, 420.0])
    T = make_pose(DOWN @ rot_x(math.radians(-100)), [560.0, -40.0, 380.0])
    route = plan_move(env, S, T, UR_LAW, 250.0, 1200.0)
    want = [make_pose(S[:3, :3], [500.0, 0.0, 400.0]), p0,
            make_pose(T[:3, :3], [500.0, 0.0, 400.0]), T]
    assert route.split and "rotation" in route.why and len(route.legs) == 4
    for leg, w in zip(route.legs, want, strict=True):
        np.testing.assert_allclose(leg.target, w, atol=1e-9)
        R = straight(leg.start, leg.target, np.linspace(0, 1, 2001))[:, :3, :3]
        assert np.degrees(Rotation.from_matrix(DOWN.T @ R).magnitude()).max() <= 100 + 1e-6


def test_a_move_whose_split_also_leaves_is_refused_naming_move_point_and_wall():
    # a box only 240 mm wide: turning at P0 (x = 500) swings the coil point to x = 350 < 380
    p0 = make_pose(DOWN, [500.0, 0.0, 450.0])
    env = Envelope(center=p0, box_min_mm=(380.0, -200.0, 250.0), box_max_mm=(620.0, 200.0, 600.0),
                   tool_points_mm=COIL)
    S, T = turned(420, 0, 450, 0), turned(520, 0, 450, -127)
    assert env.violations(S) == [] and env.violations(T) == []
    with pytest.raises(SafetyError) as ei:
        plan_move(env, S, T, UR_LAW, 250.0, 1200.0, "ur move")
    msg = str(ei.value)
    assert "ur move (420.0, 0.0, 450.0) → (520.0, 0.0, 450.0) mm refused" in msg
    assert "tool point 0 [0.0, 0.0, 150.0] (flange frame)" in msg
    assert "x-min wall (380.0 mm)" in msg and "leg 2 (turn at the centre)" in msg
    assert "30.0 mm beyond" in msg        # 380 − (500 − 150) at the turn
    assert msg.endswith("Nothing was moved.")


def test_a_robot_outside_the_envelope_is_not_moved():
    env = Envelope(box_min_mm=BOX[0], box_max_mm=BOX[1], tool_points_mm=COIL)
    with pytest.raises(SafetyError, match="the robot is outside the safety envelope now"):
        plan_move(env, turned(420, 0, 340, 0), turned(500, 0, 450, 0), UR_LAW, 100.0, 500.0)


# --- franky's per-axis hull ---------------------------------------------------------------------

def test_the_per_axis_hull_reaches_the_corners_of_the_start_frame():
    # the start frame is turned 45° about z; a 100 mm move along base x is (70.7, −70.7, 0)
    # in it, so x and y of that frame may each finish first: the hull's corners are at
    # base y = ±50 mm although the straight line stays at y = 0
    S = make_pose(rot_z(math.pi / 4), [500.0, 0.0, 400.0])
    T = make_pose(rot_z(math.pi / 4), [600.0, 0.0, 400.0])
    env = Envelope(box_min_mm=(400.0, -30.0, 300.0), box_max_mm=(700.0, 30.0, 500.0))
    assert check_linear(env, S, T, LinearPath()) is None
    v = check_axis(env, S, T, AxisPath())
    assert v is not None and v.what == "flange origin" and "y-" in v.limit
    assert v.excess == pytest.approx(20.0, abs=1e-6)
    roomy = Envelope(box_min_mm=(400.0, -51.0, 300.0), box_max_mm=(700.0, 51.0, 500.0))
    assert check_axis(roomy, S, T, AxisPath()) is None


@fuzz_settings(40)
@given(st.integers(0, 2**32 - 1))
def test_any_per_axis_monotone_motion_stays_in_a_hull_found_inside(seed):
    """franky moves each axis on its own monotone profile: sample many such motions (each axis
    its own random monotone curve) and check that none leaves a box the hull check passed."""
    rng = np.random.default_rng(seed)
    ee = make_pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-50, 50, 3))
    S = make_pose(Rotation.random(random_state=rng).as_matrix(), [500.0, 0.0, 400.0])
    du, dr = rng.uniform(-80, 80, 3), rng.uniform(-0.6, 0.6, 3)
    T = S @ ee @ make_pose(Rotation.from_rotvec(dr).as_matrix(), du) @ np.linalg.inv(ee)
    q = rng.uniform(-120, 120, (3, 3))
    half = rng.uniform(150, 320)
    env = Envelope(box_min_mm=(500 - half, -half, 400 - half),
                   box_max_mm=(500 + half, half, 400 + half), tool_points_mm=q)
    if check_axis(env, S, T, AxisPath(ee)) is not None:
        return
    s = np.linspace(0, 1, 400)
    for _ in range(20):
        prof = np.sort(rng.uniform(0, 1, (6, len(s) - 2)), axis=1)   # monotone, 0 → 1
        prof = np.concatenate([np.zeros((6, 1)), prof, np.ones((6, 1))], axis=1)
        frame = np.zeros((len(s), 4, 4))
        frame[:, 3, 3] = 1
        A = S @ ee
        frame[:, :3, :3] = A[:3, :3] @ Rotation.from_rotvec((prof[3:] * dr[:, None]).T).as_matrix()
        frame[:, :3, 3] = A[:3, 3] + (prof[:3] * du[:, None]).T @ A[:3, :3].T
        p = points(frame @ np.linalg.inv(ee), np.vstack([np.zeros(3), q]))
        assert (p >= np.array(env.box_min_mm) - 1e-6).all()
        assert (p <= np.array(env.box_max_mm) + 1e-6).all()


# --- a joint-space move --------------------------------------------------------------------------

L1, L2 = 300.0, 200.0     # a planar arm in the base xy plane at z = 400 mm


def planar_fk(q: np.ndarray) -> np.ndarray:
    """base_from_flange of a two-link planar arm: joint 1 at the origin, joint 2 at the end
    of link 1, flange at the end of link 2 (x along the link), both about base z."""
    a, b = q[0], q[0] + q[1]
    return make_pose(rot_z(b), [L1 * math.cos(a) + L2 * math.cos(b),
                                L1 * math.sin(a) + L2 * math.sin(b), 400.0])


def planar_places(q0: np.ndarray, q1: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The flange origin (n, 3) mm of the planar arm along q0 + s·(q1 − q0), vectorised."""
    q = q0[None] + s[:, None] * (q1 - q0)[None]
    a, b = q[:, 0], q[:, 0] + q[:, 1]
    return np.stack([L1 * np.cos(a) + L2 * np.cos(b), L1 * np.sin(a) + L2 * np.sin(b),
                     np.full(len(s), 400.0)], axis=1)


def test_a_joint_move_is_checked_along_its_arc():
    # joint 1 from −60° to +60° with the arm straight: the flange (and a tool point 100 mm
    # further along the link) sweep circles of radius 500 and 600 mm; the tool point's x
    # peaks at 600 half way, while both ends are at 600·cos 60° = 300
    tool = [[100.0, 0.0, 0.0]]
    q0, q1 = np.radians([-60.0, 0.0]), np.radians([60.0, 0.0])
    reach = [600.0, 300.0]            # from joint 1's and joint 2's axes to the farthest point
    env = Envelope(box_min_mm=(0.0, -600.0, 300.0), box_max_mm=(580.0, 600.0, 500.0),
                   tool_points_mm=tool)
    assert env.violations(planar_fk(q0)) == [] and env.violations(planar_fk(q1)) == []
    v = check_joint_path(env, planar_fk, q0, q1, reach)
    assert v is not None and v.what.startswith("tool point 0") and "x-max wall" in v.limit
    assert v.share == pytest.approx(0.5, abs=0.01) and v.excess == pytest.approx(20.0, abs=0.2)
    roomy = Envelope(box_min_mm=(0.0, -600.0, 300.0), box_max_mm=(601.0, 600.0, 500.0),
                     tool_points_mm=tool)
    assert check_joint_path(roomy, planar_fk, q0, q1, reach) is None


@fuzz_settings(40)
@given(st.integers(0, 2**32 - 1), st.floats(0.05, 3.0))
def test_a_joint_move_passed_stays_inside_at_every_fine_sample(seed, eps):
    rng = np.random.default_rng(seed)
    q0, q1 = rng.uniform(-2.5, 2.5, 2), rng.uniform(-2.5, 2.5, 2)
    P = planar_places(q0, q1, np.linspace(0, 1, 20_001))
    hi = P.max(axis=0) + (eps if rng.random() < 0.5 else -eps)
    hi[2] = 410.0                       # the arm stays at z = 400
    lo = P.min(axis=0) - 4.0            # below hi even when the path is short and hi lowered
    lo[2] = 390.0
    env = Envelope(box_min_mm=tuple(lo), box_max_mm=tuple(hi))
    v = check_joint_path(env, planar_fk, q0, q1, [L1 + L2, L2])
    if (P <= hi).all():
        assert v is None
    else:
        assert v is not None and v.excess == pytest.approx(eps, abs=1e-3)
