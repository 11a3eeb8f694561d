"""The joints plan (plan kind ``joints``; ``tmscal.calib.kinematics.excite`` and
``tmscal.acquisition.plan.plan_poses``), without devices: every pose inside the safety envelope
and the plan's own ranges, the configurations the nominal arm's around P0; the plan re-derived
from what the session header records (written as JSON and read back), any prefix the shorter
plan; clear errors for an unknown arm, an arm the robot does not name, an impossible envelope,
an edited header. Poses base_from_flange 4×4 mm, joints rad, angles deg."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tmscal.acquisition.devices import envelope_for
from tmscal.acquisition.plan import JointsSpec, PlanSpec, joints_spec, plan_poses
from tmscal.calib.kinematics import ARMS, arm_by_name, base_from_flange
from tmscal.calib.kinematics.excite import farthest_points
from tmscal.config import load_config
from tmscal.errors import ConfigError, SessionError
from tmscal.geometry import angle_between

from ..rigs import write_config

JOINTS = {"kind": "joints", "poses": 12, "radius_mm": 200, "rotation_deg": 20, "seed": 3,
          "pool": 1500}


class _Controller:
    """What ``joints_spec`` asks a connected robot driver (its identity, joints and flange),
    answered from the nominal arm at ``q`` (rad) in the frame ``mount`` (4×4 mm)."""

    def __init__(self, arm: str | None, q: np.ndarray, mount: np.ndarray, name: str) -> None:
        self.arm, self.q, self.mount = arm, np.asarray(q, dtype=float), mount
        self.model = arm_by_name(name)

    def identity(self) -> dict:
        return {"arm": self.arm}

    def joint_positions(self) -> np.ndarray:
        return self.q.copy()

    def flange_pose(self) -> np.ndarray:
        return self.mount @ base_from_flange(self.model, self.q)


def _setup(tmp_path, base: str, arm: str, **plan):
    cfg = load_config(write_config(tmp_path, base, plan={**JOINTS, **plan}))
    spec = ARMS[arm]
    robot = _Controller(arm, np.array(spec.home_q), spec.mount, arm)
    p0 = robot.flange_pose()
    return cfg, robot, p0


@pytest.mark.parametrize("base, arm", [("mock-ur-polaris-kin.yaml", "ur5e"),
                                       ("mock-denso-polaris-kin.yaml", "vs060")])
def test_every_pose_inside_the_envelope_and_the_ranges(tmp_path, base, arm):
    cfg, robot, p0 = _setup(tmp_path, base, arm)
    j = joints_spec(cfg, robot, p0)
    assert j.arm == arm and j.span_deg == 30.0 and j.pool == 1500
    assert np.allclose(j.frame, ARMS[arm].mount, atol=1e-9)  # the controller's frame
    spec = PlanSpec.from_config(cfg.plan, p0, None, j)
    env = envelope_for(cfg, p0)
    poses = plan_poses(spec, env)
    assert poses.shape == (12, 4, 4)
    nominal = arm_by_name(arm)
    tool = np.array(cfg.safety.tool_points_mm)
    lo, hi = np.array(cfg.safety.workspace_min_mm), np.array(cfg.safety.workspace_max_mm)
    for P in poses:
        assert env.violations(P) == []
        assert np.linalg.norm(P[:3, 3] - p0[:3, 3]) <= 200 + 1e-9
        assert np.degrees(angle_between(p0, P)) <= 20 + 1e-9
        pts = np.vstack([P[:3, 3], tool @ P[:3, :3].T + P[:3, 3]])
        assert (pts >= lo).all() and (pts <= hi).all()
        # a configuration of the nominal arm within ±span of the joints of P0
        from tmscal.calib.kinematics.ik import inverse
        q = inverse(nominal, np.linalg.inv(j.frame) @ P, [j.q0])
        assert q is not None and np.degrees(np.abs(q - j.q0)).max() <= 30 + 1e-6
    # the joints of P0 are P0's
    assert np.abs(j.frame @ base_from_flange(nominal, j.q0) - p0).max() < 1e-6
    # the joints spread: each moves over a wider range than a fifth of the span
    qs = np.array([inverse(nominal, np.linalg.inv(j.frame) @ P, [j.q0]) for P in poses])
    assert (np.degrees(qs.max(0) - qs.min(0)) > 12).all(), np.degrees(qs.max(0) - qs.min(0))


def test_plan_rederived_from_the_header_and_prefixes(tmp_path):
    cfg, robot, p0 = _setup(tmp_path, "mock-ur-polaris-kin.yaml", "ur5e")
    env = envelope_for(cfg, p0)
    spec = PlanSpec.from_config(cfg.plan, p0, None, joints_spec(cfg, robot, p0))
    poses = plan_poses(spec, env)
    header = json.loads(json.dumps({"plan": spec.to_header()}))
    assert header["plan"]["kind"] == "joints" and header["plan"]["joints"]["arm"] == "ur5e"
    again = PlanSpec.from_header(header)
    assert np.array_equal(plan_poses(again, env), poses)
    assert np.array_equal(plan_poses(again.with_n(5), env), poses[:5])
    # another seed, another plan
    other = PlanSpec.from_header({"plan": {**header["plan"], "seed": 4}})
    assert np.abs(plan_poses(other, env) - poses).max() > 1.0


def test_header_errors(tmp_path):
    cfg, robot, p0 = _setup(tmp_path, "mock-ur-polaris-kin.yaml", "ur5e")
    spec = PlanSpec.from_config(cfg.plan, p0, None, joints_spec(cfg, robot, p0))
    h = json.loads(json.dumps(spec.to_header()))
    with pytest.raises(SessionError, match="'plan' is incomplete or invalid.*joints"):
        PlanSpec.from_header({"plan": {k: v for k, v in h.items() if k != "joints"}})
    with pytest.raises(SessionError, match="span_deg"):
        PlanSpec.from_header({"plan": {**h, "joints": {**h["joints"], "span_deg": -1}}})
    edited = {**h, "joints": {**h["joints"], "q0_rad": [x + 0.01 for x in h["joints"]["q0_rad"]]}}
    with pytest.raises(SessionError, match="q0_rad put the ur5e arm's flange at .* not at "
                                           "its P0"):
        plan_poses(PlanSpec.from_header({"plan": edited}), envelope_for(cfg, p0))
    with pytest.raises(ConfigError, match="the plan's joints.arm.*ur99"):
        plan_poses(PlanSpec.from_header({"plan": {**h, "joints": {**h["joints"], "arm": "ur99"}}}),
                   envelope_for(cfg, p0))


def test_unknown_arm_and_an_arm_nobody_names(tmp_path):
    with pytest.raises(ConfigError, match=r"plan\.arm.*ur5e.*got 'ur99'"):
        load_config(write_config(tmp_path, "mock-ur-polaris-kin.yaml",
                                 plan={**JOINTS, "arm": "ur99"}))
    with pytest.raises(ConfigError, match=r"plan\.span_deg.*goes with plan.kind 'joints'"):
        load_config(write_config(tmp_path, "mock-ur-polaris-kin.yaml", plan={"span_deg": 20}))
    with pytest.raises(ConfigError, match=r"plan\.span_deg"):
        load_config(write_config(tmp_path, "mock-ur-polaris-kin.yaml",
                                 plan={**JOINTS, "span_deg": 0}))
    cfg, _, p0 = _setup(tmp_path, "mock-ur-polaris-kin.yaml", "ur5e")
    silent = _Controller(None, np.array(ARMS["ur5e"].home_q), np.eye(4), "ur5e")
    with pytest.raises(ConfigError, match=r"plan\.arm': the robot driver does not say"):
        joints_spec(cfg, silent, p0)
    # the config names a seven-joint arm for a six-joint robot
    cfg7 = load_config(write_config(tmp_path, "mock-ur-polaris-kin.yaml",
                                    plan={**JOINTS, "arm": "fr3"}))
    with pytest.raises(ConfigError, match="reports 6 joint angles; the fr3 arm has 7"):
        joints_spec(cfg7, silent, p0)


def test_impossible_envelope_is_a_config_error(tmp_path):
    cfg, robot, p0 = _setup(tmp_path, "mock-ur-polaris-kin.yaml", "ur5e", radius_mm=2,
                            rotation_deg=0.5)
    spec = PlanSpec.from_config(cfg.plan, p0, None, joints_spec(cfg, robot, p0))
    with pytest.raises(ConfigError, match=r"only \d+ of 1500 joint configurations.*12 are "
                                          r"needed.*plan.pool"):
        plan_poses(spec, envelope_for(cfg, p0))
    # P0 out of the arm's reach
    far = p0.copy()
    far[:3, 3] += [3000.0, 0.0, 0.0]
    with pytest.raises(ConfigError, match="cannot reach P0"):
        joints_spec(cfg, robot, far)


def test_farthest_points_spread_and_prefix():
    rng = np.random.default_rng(0)
    q = rng.uniform(-1, 1, (300, 3))
    idx = farthest_points(q, 10, np.zeros(3))
    assert len(set(idx.tolist())) == 10
    assert np.array_equal(farthest_points(q, 4, np.zeros(3)), idx[:4])
    # the chosen set's smallest gap beats that of random picks of the same size
    def gap(sel):
        d = np.linalg.norm(q[sel][:, None] - q[sel][None], axis=-1)
        return d[np.triu_indices(len(sel), 1)].min()
    assert gap(idx) > max(gap(rng.choice(300, 10, replace=False)) for _ in range(50))
    # duplicates are not chosen twice
    assert len(farthest_points(np.zeros((5, 2)), 3, np.ones(2))) == 1


def test_joints_spec_round_trip():
    j = JointsSpec("vs060", np.array([0.1, 0.2, 1.0, 0.0, 0.5, 0.0]), np.eye(4), 25.0, 100)
    back = JointsSpec.from_header(json.loads(json.dumps(j.to_header())))
    assert back.arm == "vs060" and np.array_equal(back.q0, j.q0)
    assert (back.span_deg, back.pool) == (25.0, 100)


def test_not_with_adaptive(tmp_path):
    from tmscal.acquisition.adaptive_run import AdaptiveStrategy

    cfg = load_config(write_config(tmp_path, "mock-ur-polaris-kin.yaml", plan=JOINTS))
    with pytest.raises(ConfigError, match=r"plan\.kind': the adaptive run's candidates"):
        AdaptiveStrategy(cfg).check()
