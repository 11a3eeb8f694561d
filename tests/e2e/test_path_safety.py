"""End to end: the envelope holds over the whole motion the mocks EXECUTE, sampled from their own
state (each mock's ``trajectory``: every move it started, with the path and profile it follows).

tmscal's URRobot (real ur_rtde, in a child process: its constructors hold the GIL) drives the UR
mock over loopback; DensoRobot (our b-CAP client) drives the DENSO mock in this process. Random
envelopes (box, tool points, caps, a TCP offset on the UR) and pairs of poses inside them: every
executed move keeps the flange origin and every tool point inside the box, within the offset and
rotation limits around P0, and every point under the speed cap, or the move was refused with
``SafetyError`` and nothing moved. Then the audit's case (docs/safety.md): a 127° wrist turn
between two poses inside the box, which a straight moveL sweeps 30 mm out of it.

The limits are checked here by hand (numpy, scipy), never through tmscal's Envelope."""

from __future__ import annotations

import itertools
import math
import os
from typing import Any

import numpy as np

if __name__ != "__main__":
    import pytest
    from hypothesis import event, given
    from hypothesis import strategies as st

    from tests.fuzz import fuzz_settings

    pytestmark = pytest.mark.e2e

from scipy.spatial.transform import Rotation

from tests.child import child_main, run_child
from tmscal.geometry import make_pose, rot_y
from tmscal.mocks.clock import FAST
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

DOWN = np.diag([1.0, -1.0, -1.0])
_HOSTS = itertools.count(1)


def _host() -> str:
    """A loopback address of this test process's own (ur_rtde's ports are fixed)."""
    n = next(_HOSTS)
    return f"127.{31 + os.getpid() % 200}.{n // 250}.{1 + n % 250}"


def _rig() -> SimRig:
    return SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)


def turned(x: float, y: float, z: float, deg: float) -> np.ndarray:
    """The flange pointing down at (x, y, z) mm, turned ``deg`` about its own y axis."""
    return make_pose(DOWN @ rot_y(math.radians(deg)), [x, y, z])


# --- the oracle: the limits, by hand -------------------------------------------------------------

def worst_excess(poses: np.ndarray, env: dict[str, Any]) -> float:
    """How far (mm; degrees for the rotation) flange poses (n, 4, 4) go beyond the worst of
    the envelope's limits (negative: inside)."""
    R, t = poses[:, :3, :3], poses[:, :3, 3]
    q = np.array([[0.0, 0.0, 0.0], *env.get("tool_points_mm", [])])
    pts = np.einsum("nij,kj->nki", R, q) + t[:, None]
    lo, hi = np.array(env["box_min_mm"]), np.array(env["box_max_mm"])
    worst = float(np.maximum(lo - pts, pts - hi).max())
    C = np.array(env["center"])
    worst = max(worst, float((np.linalg.norm(t - C[:3, 3], axis=1) - env["max_offset_mm"]).max()))
    ang = np.degrees(Rotation.from_matrix(C[:3, :3].T @ R).magnitude())
    return max(worst, float((ang - env["max_rotation_deg"]).max()))


def fastest_point(pose_at_time, duration: float, env: dict[str, Any], n: int = 601
                  ) -> tuple[float, float]:
    """(highest speed mm/s, highest acceleration mm/s²) of the flange origin or a tool point
    over a move whose flange at time t (s) is ``pose_at_time(t)`` (central differences)."""
    if duration <= 0:
        return 0.0, 0.0
    t = np.linspace(0.0, duration, n)
    P = np.array([pose_at_time(ti) for ti in t])
    q = np.array([[0.0, 0.0, 0.0], *env.get("tool_points_mm", [])])
    pts = np.einsum("nij,kj->nki", P[:, :3, :3], q) + P[:, None, :3, 3]
    dt = t[1] - t[0]
    v = np.linalg.norm(np.diff(pts, axis=0), axis=2) / dt
    a = np.linalg.norm(pts[2:] - 2 * pts[1:-1] + pts[:-2], axis=2) / dt ** 2
    return float(v.max()), float(a.max())


def check_executed(motions: list[Any], env: dict[str, Any], duration: str = "modelled_s"
                   ) -> None:
    """Every executed move (``pose_at_time(t)``, the mock's own, over its modelled duration)
    stays inside the envelope ``env`` and under its speed and acceleration caps."""
    for m in motions:
        T = getattr(m, duration)
        poses = np.array([m.pose_at_time(t) for t in np.linspace(0.0, T, 501)])
        assert worst_excess(poses, env) <= 1e-5, "an executed move left the envelope"
        v, a = fastest_point(m.pose_at_time, T, env)
        assert v <= env["max_speed_mm_s"] * (1 + 1e-6) + 1e-6, f"a point moved at {v} mm/s"
        assert a <= env["max_accel_mm_s2"] * (1 + 1e-2), f"a point accelerated at {a} mm/s²"


# --- random envelopes and poses inside them ------------------------------------------------------

def random_case(rng: np.random.Generator) -> dict[str, Any] | None:
    """An envelope around the rig's P0 (box half sizes 150–300 mm, 1–4 tool points up to
    200 mm from the flange, caps) and two flange poses inside it, the second turned 17–166°
    from the first; None when no such pair was drawn."""
    half = rng.uniform(150, 300, 3)
    centre = TMS_RIG_P0[:3, 3] + rng.uniform(-50, 50, 3)
    q = rng.uniform([-120, -120, 0], [120, 120, 200], (int(rng.integers(1, 5)), 3))
    env = {"center": TMS_RIG_P0.tolist(), "max_offset_mm": 600.0, "max_rotation_deg": 175.0,
           "box_min_mm": (centre - half).tolist(), "box_max_mm": (centre + half).tolist(),
           "max_speed_mm_s": float(rng.uniform(80, 400)),
           "max_accel_mm_s2": float(rng.uniform(500, 3000)), "tool_points_mm": q.tolist()}
    for _ in range(400):
        RA = DOWN @ Rotation.from_rotvec(rng.normal(size=3) * rng.uniform(0, 0.8)).as_matrix()
        axis = rng.normal(size=3)
        turn = Rotation.from_rotvec(axis / np.linalg.norm(axis) * rng.uniform(0.3, 2.9))
        A = make_pose(RA, centre + rng.uniform(-half, half))
        B = make_pose(RA @ turn.as_matrix(), centre + rng.uniform(-half, half))
        if worst_excess(np.array([A, B]), env) < -1.0:
            return {"env": env, "A": A.tolist(), "B": B.tolist()}
    return None


def _executed(mock: Any, res: dict[str, Any], before: int) -> list[list[Any]]:
    """The mock's motions per case: each case moved to A first (one motion), then sent its
    legs (none when refused)."""
    motions = list(mock.trajectory)[before:]
    out, i = [], 0
    for case in res["cases"]:
        i += 1                                   # the move to A
        out.append(motions[i:i + case["legs"]])
        i += case["legs"]
    assert i == len(motions), (i, len(motions))
    return out


def _run_ur(cases: list[dict[str, Any]], tcp: np.ndarray | None) -> tuple[dict, list]:
    from tmscal.mocks.ur import URMock

    rig = _rig()
    with URMock(rig, host=_host(), clock=FAST, tcp_offset=tcp) as mock:
        res = run_child(__file__, "cases", mock.host, {"cases": cases})
        assert res.get("error") is None, res.get("error")
        return res, _executed(mock, res, 0)


if __name__ != "__main__":
    @fuzz_settings(6)
    @given(st.integers(0, 2**32 - 1))
    def test_ur_executes_only_paths_inside_the_envelope(seed):
        rng = np.random.default_rng(seed)
        tcp = np.eye(4) if rng.random() < 0.4 else make_pose(
            Rotation.from_rotvec(rng.normal(size=3) * 0.3).as_matrix(),
            rng.uniform([-60, -60, 0], [60, 60, 200]))
        cases = [c for c in (random_case(rng) for _ in range(5)) if c is not None]
        res, executed = _run_ur(cases, tcp)
        for case, out, motions in zip(cases, res["cases"], executed, strict=True):
            if out["refused"] is not None:
                assert motions == [] and "Nothing was moved." in out["refused"]
                event("refused")
                continue
            event(f"legs: {out['legs']}")
            check_executed(motions, case["env"])
            np.testing.assert_allclose(motions[-1].pose_at(1.0), case["B"], atol=1e-6)


def test_the_audits_127_degree_turn_leaves_the_box_on_a_straight_movel_but_not_through_tmscal():
    from tmscal.mocks.ur.motion import Motion

    env = {"center": TMS_RIG_P0.tolist(), "max_offset_mm": 300.0, "max_rotation_deg": 170.0,
           "box_min_mm": [300.0, -200.0, 200.0], "box_max_mm": [700.0, 200.0, 600.0],
           "max_speed_mm_s": 250.0, "max_accel_mm_s2": 1500.0,
           "tool_points_mm": [[0.0, 0.0, 150.0]]}
    A, B = turned(420, 0, 450, 0), turned(420, 0, 450, -127)
    assert worst_excess(np.array([A, B]), env) < 0     # both ends inside: all the old check saw
    # before: the straight moveL the old check let through, on the mock's own model
    straight = Motion(A, B, 0.0, False, 0.25, 1.2, instant=True)
    coil = np.array([straight.pose_at(f)[:3, :3] @ [0, 0, 150.0] + straight.pose_at(f)[:3, 3]
                     for f in np.linspace(0, 1, 2001)])
    assert coil[:, 0].min() < 300.0 - 29.9            # x = 270 mm: 30 mm out of the box
    # after: tmscal splits it through P0, and every executed leg stays inside
    res, (motions,) = _run_ur([{"env": env, "A": A.tolist(), "B": B.tolist()}], None)
    assert res["cases"][0]["refused"] is None and res["cases"][0]["legs"] == 3
    check_executed(motions, env)
    np.testing.assert_allclose(motions[1].pose_at(1.0), turned(500, 0, 400, -127), atol=1e-6)


def test_a_tcp_offset_makes_the_flange_swing_round_the_tcp():
    """TCP at a coil point 150 mm below the flange; a 150° turn about it swings the flange
    out to x = 650 mm half way although both ends are at x ≤ 575: a driver that checked the
    flange's straight line instead of the TCP's would let it through."""
    tcp = make_pose(np.eye(3), [0.0, 0.0, 150.0])
    A = make_pose(DOWN, [500.0, 0.0, 450.0])
    B = A @ tcp @ make_pose(rot_y(math.radians(-150.0))) @ np.linalg.inv(tcp)
    env = {"center": TMS_RIG_P0.tolist(), "max_offset_mm": 600.0, "max_rotation_deg": 175.0,
           "box_min_mm": [380.0, -200.0, 150.0], "box_max_mm": [620.0, 200.0, 600.0],
           "max_speed_mm_s": 250.0, "max_accel_mm_s2": 1500.0,
           "tool_points_mm": [[0.0, 0.0, 150.0]]}
    assert worst_excess(np.array([A, B]), env) < 0
    res, (motions,) = _run_ur([{"env": env, "A": A.tolist(), "B": B.tolist()}], tcp)
    assert res["identity"]["tcp_offset_m_rad"][:3] == pytest.approx([0.0, 0.0, 0.15])
    check_executed(motions, env)
    assert res["cases"][0]["refused"] is not None or len(motions) > 1


# --- DENSO, in this process ---------------------------------------------------------------------

if __name__ != "__main__":
    @fuzz_settings(15)
    @given(st.integers(0, 2**32 - 1))
    def test_denso_executes_only_paths_inside_the_envelope(seed):
        from tmscal.drivers.denso.robot import DensoRobot
        from tmscal.errors import SafetyError
        from tmscal.mocks.denso import DensoMock
        from tmscal.safety import Envelope

        rng = np.random.default_rng(seed)
        cases = [c for c in (random_case(rng) for _ in range(5)) if c is not None]
        with DensoMock(_rig(), clock=FAST) as mock:
            host, port = mock.start().rsplit(":", 1)
            with DensoRobot(host, int(port), speed_mm_s=400.0, accel_mm_s2=3000.0) as robot:
                for case in cases:
                    env = case["env"]
                    robot.envelope, robot.accel_mm_s2 = Envelope(), 3000.0
                    robot.move_to(np.array(case["A"]))
                    n = len(mock.trajectory)
                    robot.envelope = Envelope(**{**env, "center": np.array(env["center"])})
                    robot.accel_mm_s2 = env["max_accel_mm_s2"]
                    try:
                        robot.move_to(np.array(case["B"]), min(400.0, env["max_speed_mm_s"]))
                    except SafetyError as e:
                        assert len(mock.trajectory) == n and "Nothing was moved." in str(e)
                        event("refused")
                        continue
                    legs = list(mock.trajectory)[n:]
                    event(f"legs: {len(legs)}")
                    check_executed(legs, env, "duration_s")


def test_denso_lowers_the_acceleration_of_a_turning_move_for_the_coil():
    """Opened at 3000 mm/s² (ExtSpeed accel 15 % of 20,000), a move that turns 60° with a coil
    point 200 mm from the axis must reach the arm with ACCEL/DECEL below 100 %, and the coil
    point must keep under the 1500 mm/s² cap on the mock's executed profile."""
    from tmscal.drivers.denso.robot import DensoRobot
    from tmscal.mocks.denso import DensoMock
    from tmscal.safety import Envelope

    env = {"center": TMS_RIG_P0.tolist(), "max_offset_mm": 600.0, "max_rotation_deg": 175.0,
           "box_min_mm": [0.0, -600.0, 0.0], "box_max_mm": [1000.0, 600.0, 900.0],
           "max_speed_mm_s": 250.0, "max_accel_mm_s2": 1500.0,
           "tool_points_mm": [[200.0, 0.0, 0.0]]}
    with DensoMock(_rig(), clock=FAST) as mock:
        host, port = mock.start().rsplit(":", 1)
        with DensoRobot(host, int(port), speed_mm_s=250.0, accel_mm_s2=3000.0) as robot:
            robot.envelope = Envelope(**{**env, "center": np.array(env["center"])})
            robot.accel_mm_s2 = 1500.0
            robot.move_to(TMS_RIG_P0 @ make_pose(rot_y(math.radians(60.0)), [100.0, 0, 0]))
            assert mock.move_accel is not None and mock.move_accel < 100.0
            check_executed(list(mock.trajectory), env, "duration_s")


# --- the child: URRobot over ur_rtde -------------------------------------------------------------

def _child(scenario: str, host: str, args: dict[str, Any], res: dict[str, Any]) -> None:
    from tmscal.drivers.ur.robot import URRobot
    from tmscal.errors import SafetyError
    from tmscal.safety import Envelope

    res["error"], res["cases"] = None, []
    assert scenario == "cases"
    with URRobot(host, speed_mm_s=400.0, accel_mm_s2=3000.0, timeout_s=20.0) as robot:
        res["identity"] = robot.identity()
        for case in args["cases"]:
            env = case["env"]
            robot.envelope, robot.accel_mm_s2 = Envelope(), 3000.0     # to A, unchecked
            robot.move_to(np.array(case["A"]))
            robot.envelope = Envelope(**{**env, "center": np.array(env["center"])})
            robot.accel_mm_s2 = env["max_accel_mm_s2"]
            try:
                route = robot.move_to(np.array(case["B"]), min(400.0, env["max_speed_mm_s"]))
                res["cases"].append({"legs": len(route.legs), "refused": None})
            except SafetyError as e:
                res["cases"].append({"legs": 0, "refused": str(e)})


if __name__ == "__main__":
    child_main(_child)
