"""The sim rig's serial arm (tmscal.sim.arm; docs/selfcal.md, "On the rig"): inverse
kinematics on the nominal model, the controller reporting the nominal flange while the tracker
sees the true arm, out-of-reach moves refused, the hidden-error protocols, mock.kinematics in a
config, and no change at all without it. Poses 4×4 mm, joints rad."""

from __future__ import annotations

import numpy as np
import pytest

from tests.rigs import NOISE_FREE_MOCK, write_config
from tmscal.calib.kinematics import ARM_NAMES
from tmscal.calib.selfcal.model import NOMINAL, forward
from tmscal.config import load_config
from tmscal.errors import ConfigError
from tmscal.geometry import invert, make_pose
from tmscal.mocks.launch import build_sim_rig
from tmscal.poses import eq14_poses
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, Unreachable, make_arm, tms_rig_truth
from tmscal.sim.arm import IK_TOL_MM, inverse


@pytest.mark.parametrize("arm", ["ur5e", "vs060"])
def test_inverse_round_trip_on_the_nominal_model(arm: str) -> None:
    """forward(nominal, inverse(T)) = T for poses made by forward kinematics of joints near
    the home configuration, from a seed 0.2 rad away; the solution is inside the limits."""
    pair = make_arm(arm, "none", 0)
    rng = np.random.default_rng(3)
    home = np.array(pair.home_q)
    lim = pair.nominal.joint_limits_rad
    for _ in range(20):
        q_true = np.clip(home + rng.uniform(-0.4, 0.4, 6), lim[:, 0], lim[:, 1])
        T = forward(pair.nominal, q_true)
        q = inverse(pair.nominal, T, q_true + rng.uniform(-0.2, 0.2, 6))
        assert q is not None
        assert np.all(q >= lim[:, 0]) and np.all(q <= lim[:, 1])
        back = forward(pair.nominal, q)
        assert np.linalg.norm(back[:3, 3] - T[:3, 3]) < 10 * IK_TOL_MM
        assert np.abs(back[:3, :3] - T[:3, :3]).max() < 1e-8


def test_rig_reaches_configurations_spread_over_the_joint_space() -> None:
    """A self-calibration plan sends flange poses of joint configurations anywhere within the
    limits (tmscal selfcal acquire); from the rig's P0 joints the mock reaches at least 90 %
    of 30 such poses (seeded), each within the IK tolerance."""
    rig = _arm_rig("ur5e", "none")
    lim = rig.arm_nominal.joint_limits_rad
    rng = np.random.default_rng(21)
    ok = 0
    for q in rng.uniform(lim[:, 0], lim[:, 1], (30, 6)):
        T = rig.arm.reported(q)
        got = rig.reach(T)
        if got is not None:
            ok += 1
            back = rig.arm.reported(got)
            assert np.linalg.norm(back[:3, 3] - T[:3, 3]) < 10 * IK_TOL_MM
    assert ok >= 27


def test_out_of_reach_is_none() -> None:
    pair = make_arm("ur5e", "none", 0)
    far = make_pose(np.diag([1.0, -1.0, -1.0]), [3000.0, 0.0, 400.0])
    assert inverse(pair.nominal, far, np.array(pair.home_q)) is None


def _arm_rig(arm: str = "ur5e", errors: str = "paper", seed: int = 5) -> SimRig:
    return SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0,
                  arm=make_arm(arm, errors, seed))


@pytest.mark.parametrize("arm", ["ur5e", "vs060"])
def test_controller_reports_nominal_tracker_sees_true(arm: str) -> None:
    """After each move the reported flange is the command (IK tolerance) and the nominal
    DH chain at the reported joints, placed by the mount; the tracker's marker pose is
    Z⁻¹ · mount · (DH chain of the TRUE model) · X, so tracker and controller differ by
    exactly the two models' chains at the same joints — a few mm with the paper's errors."""
    rig = _arm_rig(arm)
    X, Z = rig.truth.X, rig.truth.Z
    P = eq14_poses(TMS_RIG_P0, 15, np.random.default_rng(2), r_mm=100.0, d_deg=10.0)
    gaps = []
    for cmd in P:
        rig.move_flange(cmd)
        q = rig.joints()
        assert q is not None and q.shape == (6,)
        rep = rig.reported_flange()
        assert np.linalg.norm(rep[:3, 3] - cmd[:3, 3]) < 1e-6
        M = rig.arm.mount
        chain_nominal = invert(rig.arm_nominal.base) @ forward(rig.arm_nominal, q)
        chain_true = invert(rig.arm_true.base) @ forward(rig.arm_true, q)
        np.testing.assert_allclose(rep, M @ chain_nominal, atol=1e-9)
        seen = rig.observe("marker")
        np.testing.assert_allclose(seen, invert(Z) @ M @ chain_true @ X, atol=1e-9)
        # what a hand/eye calibration sees as the robot's error
        A_seen = Z @ seen @ invert(X)
        gaps.append(np.linalg.norm(A_seen[:3, 3] - rep[:3, 3]))
    assert 0.1 < np.median(gaps) < 20.0


def test_unreachable_move_raises_and_nothing_moves() -> None:
    rig = _arm_rig()
    before = (rig.joints(), rig.reported_flange(), rig.true_flange())
    far = make_pose(np.diag([1.0, -1.0, -1.0]), [3000.0, 0.0, 400.0])
    assert rig.reach(far) is None
    with pytest.raises(Unreachable, match="out of"):
        rig.move_flange(far)
    np.testing.assert_array_equal(rig.joints(), before[0])
    np.testing.assert_array_equal(rig.reported_flange(), before[1])
    np.testing.assert_array_equal(rig.true_flange(), before[2])


def test_error_protocols() -> None:
    """"none": true = nominal; "all": every geometric parameter in error (±2 mm / ±1°),
    weight, centre of gravity and bias untouched; "paper": a strict subset, the wrench-
    identifiable ones, never the base yaw (about gravity) nor a base position."""
    none = make_arm("ur5e", "none", 1)
    np.testing.assert_array_equal(none.true.vector(), none.nominal.vector())
    allp = make_arm("ur5e", "all", 1)
    names = allp.nominal.parameter_names()
    diff = dict(zip(names, allp.true.vector() - allp.nominal.vector(), strict=True))
    units = dict(zip(names, allp.nominal.parameter_units(), strict=True))
    for n in allp.perturbed:
        bound = 2.0 if units[n] == "mm" else np.radians(1.0)
        assert 0 < abs(diff[n]) <= bound + 1e-9, n
    for n in ("mg", "cog_x", "cog_y", "cog_z", "f0_x", "t0_z"):
        assert n not in allp.perturbed and diff[n] == pytest.approx(0.0, abs=1e-12)
    assert {"d_1", "a_2", "a_3", "base_x", "base_yaw"} <= set(allp.perturbed)
    paper = make_arm("ur5e", "paper", 1)
    assert set(paper.perturbed) < set(allp.perturbed)
    assert not {"base_yaw", "base_x", "base_y", "base_z", "a_2", "d_1"} & set(paper.perturbed)
    # the seed decides the draw
    assert not np.array_equal(make_arm("ur5e", "paper", 2).true.vector(), paper.true.vector())
    np.testing.assert_array_equal(make_arm("ur5e", "paper", 1).true.vector(),
                                  paper.true.vector())


def test_vs060_mount_places_p0_inside_the_reach() -> None:
    """The VS-060 stands nearer P0 than the rig origin; its wrist centre at P0 is well
    inside the shoulder-to-wrist reach (upper arm + forearm)."""
    pair = make_arm("vs060", "none", 0)
    dh = NOMINAL["vs060"].dh
    shoulder = pair.mount[:3, 3] + [0.0, 0.0, dh[0, 1]]
    wrist = (TMS_RIG_P0 @ [0.0, 0.0, -dh[5, 1], 1.0])[:3]
    reach = abs(dh[1, 2]) + np.hypot(dh[3, 1], dh[2, 2])
    assert np.linalg.norm(wrist - shoulder) < 0.75 * reach


def test_config_kinematics_builds_the_arm(tmp_path) -> None:
    cfg = load_config(write_config(tmp_path, "mock-ur-polaris.yaml", mock={
        "kinematics": {"arm": "ur5e", "errors": "all", "seed": 4}, "noise": NOISE_FREE_MOCK}))
    rig = build_sim_rig(cfg)
    assert rig.arm is not None and rig.arm.errors == "all"
    np.testing.assert_array_equal(rig.arm_true.vector(), make_arm("ur5e", "all", 4).true.vector())
    np.testing.assert_allclose(rig.reported_flange(), TMS_RIG_P0, atol=1e-6)


@pytest.mark.parametrize("bad, key", [({"arm": "ur30"}, "mock.kinematics.arm"),
                                      ({"arm": "ur5e", "errors": "some"},
                                       "mock.kinematics.errors"),
                                      ({"arm": "ur5e", "seed": -1}, "mock.kinematics.seed"),
                                      ({"arm": "ur5e", "seeds": 1}, "mock.kinematics.seeds"),
                                      ("ur5e", "mock.kinematics")])
def test_config_kinematics_errors_name_the_key(tmp_path, bad, key) -> None:
    with pytest.raises(ConfigError, match=f"key '{key}'"):
        load_config(write_config(tmp_path, "mock-ur-polaris.yaml", mock={"kinematics": bad}))


def test_start_out_of_reach_is_a_config_error(tmp_path) -> None:
    far = make_pose(np.diag([1.0, -1.0, -1.0]), [2500.0, 0.0, 400.0])
    cfg = load_config(write_config(tmp_path, "mock-ur-polaris.yaml",
                                   mock={"kinematics": {"arm": "ur5e"}},
                                   plan={"start": far.tolist()}))
    with pytest.raises(ConfigError, match="mock.kinematics.*reach"):
        build_sim_rig(cfg)


def test_without_kinematics_nothing_changes(tmp_path) -> None:
    """A shipped mock config (no mock.kinematics) builds a rig without an arm that draws
    and reports exactly what the rig built by hand the way it always was does: same
    commanded = reported poses, same noisy observations, move after move."""
    cfg = load_config(write_config(tmp_path, "mock-ur-polaris.yaml"))
    assert cfg.mock is not None and cfg.mock.kinematics is None
    rig = build_sim_rig(cfg)
    assert rig.arm is None and rig.joints() is None and rig.arm_true is None
    from tmscal.sim import Noise as N
    by_hand = SimRig(tms_rig_truth(), noise=N(**cfg.mock.noise),
                     rng=np.random.default_rng(cfg.mock.seed), start=TMS_RIG_P0)
    P = eq14_poses(TMS_RIG_P0, 10, np.random.default_rng(8), r_mm=100.0, d_deg=10.0)
    for cmd in P:
        rig.move_flange(cmd)
        by_hand.move_flange(cmd)
        np.testing.assert_array_equal(rig.reported_flange(), cmd)
        np.testing.assert_array_equal(rig.observe("marker", 3), by_hand.observe("marker", 3))
        np.testing.assert_array_equal(rig.true_flange(), by_hand.true_flange())


@pytest.mark.parametrize("arm", ARM_NAMES)
def test_every_registered_arm_is_placed_to_reach_the_mock_start_and_plan(arm: str) -> None:
    """The registry's mock placement (mount, home) puts the shipped P0 inside every arm's
    reach, and the 60 poses of an Eq. 14 plan around it (±100 mm, ±10°) too, except the
    COBOTTA's (342 mm from shoulder to wrist: at least 50 of them)."""
    rig = SimRig(tms_rig_truth(), noise=Noise(), rng=np.random.default_rng(0), start=TMS_RIG_P0,
                 arm=make_arm(arm, "none", 0))
    np.testing.assert_allclose(rig.reported_flange(), TMS_RIG_P0, atol=1e-6)
    poses = eq14_poses(TMS_RIG_P0, 60, np.random.default_rng(1))
    reached = sum(rig.reach(P) is not None for P in poses)
    assert reached >= (50 if arm == "cobotta" else 60), reached
