"""The in-process sim drivers (``robot: {driver: sim}``, ``tracker: {driver: sim}``,
docs/devices.md "sim (in-process)"): ``tmscal acquire`` on a config using them records a
session that ``tmscal solve`` solves to the rig's ground truth; the safety envelope refuses
through them exactly as for a real robot (nothing reaches the rig); their options are checked
when the config is read, each error naming the key; the injected faults end or retry a run as
the fault kinds say; robot and tracker share one rig per channel and only with the same rig
options.

Poses 4×4 mm: X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker. A test
watches a rig by holding a sim tracker open on the run's channel (the channel's rig lives
while a driver on it is open), as a python-can virtual bus hears another on its channel.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.acquisition.devices import make_robot, make_tracker
from tmscal.acquisition.run import AcquisitionStopped, acquire
from tmscal.cli import main
from tmscal.config import load_config, parse_config
from tmscal.drivers.sim.channel import open_channels, rig_on
from tmscal.drivers.sim.robot import SimRobot
from tmscal.drivers.sim.tracker import SimTracker
from tmscal.errors import ConfigError, ConnectionLost, RobotFault, SafetyError
from tmscal.geometry import invert, make_pose, rotvec_from_matrix
from tmscal.session import read_session
from tmscal.sim import TMS_RIG_P0, tms_rig_truth

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
SAFETY = {"max_offset_mm": 200, "max_rotation_deg": 20, "workspace_min_mm": [100, -400, 0],
          "workspace_max_mm": [900, 400, 800], "max_speed_mm_s": 250, "max_accel_mm_s2": 1500,
          "tool_points_mm": [[3, 5, 110]]}


def sim_config(channel: str, robot: dict[str, Any] | None = None,
               tracker: dict[str, Any] | None = None, **sections: Any) -> dict[str, Any]:
    """A rig config of the sim robot and tracker on ``channel``; ``robot``/``tracker`` are
    their options beside the channel, ``sections`` replace whole sections."""
    data: dict[str, Any] = {
        "name": "sim rig",
        "robot": {"driver": "sim", "speed_mm_s": 250, "accel_mm_s2": 1200,
                  "options": {"channel": channel, **(robot or {})}},
        "tracker": {"driver": "sim", "frame_rate_hz": 60, "tools": {"marker": None,
                                                                      "probe": None},
                    "options": {"channel": channel, **(tracker or {})}},
        "plan": {"kind": "eq14", "poses": 30, "radius_mm": 100, "rotation_deg": 10, "seed": 1,
                 "start": "current"},
        "sampling": {"samples": 10, "settle_s": 0.0},
        "safety": dict(SAFETY),
        "run": {"retries": 3, "reconnect_wait_s": 0.0},
    }
    data.update(sections)
    return data


def write(tmp_path: Path, data: dict[str, Any]) -> Path:
    p = tmp_path / "sim.yaml"
    p.write_text(yaml.safe_dump(data), encoding="utf-8")
    return p


def run(*args: Any):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(autouse=True)
def every_channel_closed():
    """Every driver a test opens is closed by its end: no rig outlives it."""
    before = open_channels()
    yield
    assert open_channels() == before


def _errors(T: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(translation error mm, rotation error deg) of T against truth."""
    D = invert(truth) @ T
    return (float(np.linalg.norm(T[:3, 3] - truth[:3, 3])),
            float(np.degrees(np.linalg.norm(rotvec_from_matrix(D[:3, :3])))))


# --- acquire → solve -------------------------------------------------------------------------

def test_acquire_then_solve_recovers_the_rigs_truth(tmp_path):
    """The shipped configs/sim.yaml, shortened to 30 poses of 10 frames, on a channel of
    this test's own."""
    data = yaml.safe_load((CONFIGS / "sim.yaml").read_text(encoding="utf-8"))
    for kind in ("robot", "tracker"):
        data[kind]["options"]["channel"] = "acquire-solve"
    data["plan"]["poses"], data["sampling"]["samples"] = 30, 10
    cfg = write(tmp_path, data)
    out = tmp_path / "s.jsonl"
    r = run("acquire", cfg, "-o", out)
    assert r.exit_code == 0, r.output
    s = read_session(out)
    assert [p.index for p in s.poses] == list(range(30)) and not any(p.skipped for p in s.poses)
    assert s.header["devices"]["robot"]["driver"] == "sim"
    assert s.header["devices"]["tracker"]["tools"] == {"marker": "marker", "probe": "probe"}
    assert s.poses[0].samples["B"] == 10
    r = run("solve", out, "--json")
    assert r.exit_code == 0, r.output
    res = json.loads(r.output)
    truth = tms_rig_truth()
    # noise: 0.05 mm fiducials, 0.05 mm / 0.05° robot; 10 frames a pose; 30 poses ±100 mm/±10°
    for k, T in (("X", truth.X), ("Y", truth.Y), ("Z", truth.Z)):
        mm, deg = _errors(np.asarray(res[k]), T)
        assert mm < (1.0 if k == "Z" else 0.5) and deg < 0.1, (k, mm, deg)
    # and the noise was there: the errors are not those of an exact rig
    assert max(_errors(np.asarray(res[k]), getattr(truth, k))[0] for k in "XY") > 1e-6


def test_the_same_seed_records_the_same_session_and_another_seed_does_not(tmp_path):
    def poses(seed: int, name: str) -> np.ndarray:
        d = tmp_path / name
        d.mkdir()
        cfg = load_config(write(d, sim_config(name, {"seed": seed}, {"seed": seed},
                                              plan={"poses": 5, "seed": 1,
                                                    "start": "current"})))
        res = acquire(cfg, d / "s.jsonl")
        assert res.recorded == 5
        return np.array([p.B for p in read_session(d / "s.jsonl").poses])

    a, b, c = poses(4, "a"), poses(4, "b"), poses(5, "c")
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c, atol=1e-6)


def test_a_noise_free_rig_observes_exactly_z_inverse_a_x():
    exact = {"channel": "exact", "fiducial_sigma_mm": 0.0}
    with SimRobot(channel="exact", rot_sigma_deg=0.0, trans_sigma_mm=0.0) as rob, \
            SimTracker({"marker": "marker", "probe": "probe"}, **exact) as tr:
        assert tr.rig is rob.rig
        target = TMS_RIG_P0 @ make_pose(np.eye(3), [10.0, -5.0, 3.0])
        rob.move_to(target)
        truth = rob.rig.truth
        fr = tr.read()
        A = rob.flange_pose()
        np.testing.assert_allclose(A, target, atol=1e-9)
        np.testing.assert_allclose(fr.pose("marker"), invert(truth.Z) @ A @ truth.X,
                                   atol=1e-9)
        np.testing.assert_allclose(fr.pose("probe"), invert(truth.Z) @ A @ truth.Y,
                                   atol=1e-9)
        assert tr.read().frame == fr.frame + 1   # every read is a new frame


def test_each_side_sets_its_own_noise_on_the_shared_rig():
    """The tracker's fiducial σ and the robot's σ reach the one rig; a four-sphere tool's
    fitted origin (the spheres' centroid) then scatters by σ/√4 per axis."""
    sigma = 0.2
    with SimRobot(channel="noise", rot_sigma_deg=0.0, trans_sigma_mm=0.3) as rob, \
            SimTracker({"marker": "marker"}, channel="noise", fiducial_sigma_mm=sigma) as tr:
        n = rob.rig.noise
        assert (n.fiducial_sigma_mm, n.robot_rot_sigma_deg, n.robot_trans_sigma_mm) == \
            (sigma, 0.0, 0.3)
        truth = tr.rig.truth
        exact = invert(truth.Z) @ tr.rig.true_flange() @ truth.X
        e = np.array([tr.read().pose("marker")[:3, 3] - exact[:3, 3] for _ in range(600)])
        sd = float(np.sqrt(np.mean(e ** 2)))
        # seeded: a fixed margin of about 4 relative standard errors (1/√(2·1800) ≈ 1.7 %)
        assert abs(sd / (sigma / 2) - 1) < 0.07, sd


# --- the envelope, through the sim robot ----------------------------------------------------

def test_a_plan_outside_the_envelope_is_refused_and_nothing_moves(tmp_path):
    data = sim_config("envelope-plan", plan={"poses": 30, "radius_mm": 150,
                                             "rotation_deg": 10, "seed": 1,
                                             "start": "current"},
                      safety={**SAFETY, "max_offset_mm": 100})
    cfg = write(tmp_path, data)
    out = tmp_path / "s.jsonl"
    with SimTracker({"marker": "marker"}, channel="envelope-plan") as watch:
        r = run("acquire", cfg, "-o", out)
        assert r.exit_code != 0 and "max_offset_mm 100" in r.output, r.output
        assert len(watch.rig.moves) == 0
    assert not out.exists()


def test_a_jog_outside_the_workspace_box_is_refused_before_it_is_sent(tmp_path):
    cfg = write(tmp_path, sim_config("envelope-jog"))
    with SimTracker({"marker": "marker"}, channel="envelope-jog") as watch:
        r = run("robot", cfg, "--move-to", "950,0,400,180,0,0", "--yes")
        assert r.exit_code != 0 and "workspace" in r.output, r.output
        assert len(watch.rig.moves) == 0
        r = run("robot", cfg, "--move-to", "520,0,400,180,0,0", "--yes")
        assert r.exit_code == 0, r.output
        assert len(watch.rig.moves) == 1
        np.testing.assert_allclose(watch.rig.moves[0][:3, 3], [520, 0, 400], atol=1e-9)


def test_the_config_envelope_and_speed_caps_apply_through_make_robot(tmp_path):
    cfg = load_config(write(tmp_path, sim_config("envelope-caps")))
    with make_robot(cfg) as rob:
        assert isinstance(rob, SimRobot)
        assert rob.envelope.max_speed_mm_s == 250 and rob.envelope.box_max_mm == (900, 400, 800)
        with pytest.raises(SafetyError, match="speed 300.0 mm/s > max_speed_mm_s 250"):
            rob.move_to(TMS_RIG_P0, 300.0)
        # the coil centre (tool point, 110 mm below the flange) leaves the box at z < 0
        low = TMS_RIG_P0.copy()
        low[2, 3] = 100.0
        with pytest.raises(SafetyError, match="tool point"):
            rob.move_to(low)
        assert len(rob.rig.moves) == 0 and rob.moves_sent == 0


# --- options: checked when the config is read -----------------------------------------------

@pytest.mark.parametrize("section, options, key", [
    ("robot", {"seed": -1}, "robot.options.seed"),
    ("robot", {"seed": 1.5}, "robot.options.seed"),
    ("robot", {"truth": "lab"}, "robot.options.truth"),
    ("robot", {"arm": "kuka"}, "robot.options.arm"),
    ("robot", {"rot_sigma_deg": -0.1}, "robot.options.rot_sigma_deg"),
    ("robot", {"fail_after_moves": -1}, "robot.options.fail_after_moves"),
    ("robot", {"fault": "estop"}, "robot.options.fault"),
    ("robot", {"fiducial_sigma_mm": 0.1}, "robot.options"),   # the tracker's, not the robot's
    ("robot", {"envelope": None}, "robot.options.envelope"),
    ("tracker", {"fiducial_sigma_mm": 6}, "tracker.options.fiducial_sigma_mm"),
    ("tracker", {"drop_tool": "coil"}, "tracker.options.drop_tool"),
    ("tracker", {"drop_after_moves": 100_001}, "tracker.options.drop_after_moves"),
    ("tracker", {"channel": 3}, "tracker.options.channel"),
    ("tracker", {"fail_after_moves": 2}, "tracker.options"),
])
def test_option_errors_name_the_key(section, options, key):
    data = sim_config("options")
    data[section]["options"].update(options)
    with pytest.raises(ConfigError) as e:
        parse_config(data, "sim.yaml")
    msg = str(e.value)
    assert msg.startswith("sim.yaml") and f"key '{key}" in msg, msg
    name = next(iter(options))
    assert name in msg, msg


@pytest.mark.parametrize("value", ["coil", 3])
def test_a_tool_that_is_no_rig_body_is_refused_naming_it(value):
    data = sim_config("tools")
    data["tracker"]["tools"] = {"marker": value}
    with pytest.raises(ConfigError, match=r"key 'tracker.tools.marker'.*marker or probe"):
        parse_config(data, "sim.yaml")
    data["tracker"]["tools"] = {"coil": None}   # null: the body of the tool's own name
    with pytest.raises(ConfigError, match=r"key 'tracker.tools.coil'.*'coil' \(its name\)"):
        parse_config(data, "sim.yaml")


def test_valid_options_reach_the_drivers():
    data = sim_config("valid", {"seed": 9, "truth": "random", "fail_after_moves": 4,
                                "fault": "connection_lost", "trans_sigma_mm": 0.2},
                      {"seed": 9, "truth": "random", "drop_tool": "probe",
                       "drop_after_moves": 2})
    data["tracker"]["tools"] = {"marker": None, "coil": "probe"}
    data["tracker"]["options"]["drop_tool"] = "coil"
    cfg = parse_config(data, "sim.yaml")
    rob, tr = make_robot(cfg), make_tracker(cfg)
    assert (rob.spec.seed, rob.spec.truth, rob.fail_after_moves, rob.fault,
            rob.trans_sigma_mm) == (9, "random", 4, "connection_lost", 0.2)
    assert tr.bodies == {"marker": "marker", "coil": "probe"}
    assert (tr.drop_tool, tr.drop_after_moves, tr.spec) == ("coil", 2, rob.spec)


def test_a_robot_and_tracker_with_other_rig_options_are_refused_on_one_channel():
    with SimRobot(channel="mismatch", seed=1) as rob:
        with pytest.raises(ConfigError, match=r"sim channel 'mismatch'.*robot vs tracker: "
                                              r"seed 1 vs 2"):
            SimTracker({"marker": "marker"}, channel="mismatch", seed=2).open()
        # on another channel it is another rig
        with SimTracker({"marker": "marker"}, channel="mismatch-2", seed=2) as tr:
            assert tr.rig is not rob.rig
    assert rig_on("mismatch") is None      # the last driver closed: the rig is gone


# --- injected faults ------------------------------------------------------------------------

def test_a_protective_stop_after_k_moves_stops_the_run_with_k_poses(tmp_path):
    cfg = load_config(write(tmp_path, sim_config("fault-stop", {"fail_after_moves": 4},
                                                 plan={"poses": 10, "seed": 1,
                                                       "start": "current"})))
    out = tmp_path / "s.jsonl"
    with pytest.raises(AcquisitionStopped, match="pose 4: robot fault: sim: protective stop"):
        acquire(cfg, out)
    assert [p.index for p in read_session(out).poses] == [0, 1, 2, 3]


def test_a_lost_connection_every_k_moves_is_reconnected(tmp_path):
    cfg = load_config(write(tmp_path, sim_config("fault-lost", {"fail_after_moves": 4,
                                                                "fault": "connection_lost"},
                                                 plan={"poses": 10, "seed": 1,
                                                       "start": "current"})))
    res = acquire(cfg, tmp_path / "s.jsonl")
    assert (res.recorded, res.skipped, res.stopped) == (10, 0, False)
    assert res.faults == 2      # after poses 3 and 7: each reconnect counts afresh


def test_the_robot_fault_kinds_at_the_driver():
    with SimRobot(channel="kinds", fail_after_moves=1) as rob:
        target = TMS_RIG_P0 @ make_pose(np.eye(3), [5.0, 0.0, 0.0])
        rob.move_to(target)
        with pytest.raises(RobotFault, match="protective stop"):
            rob.move_to(TMS_RIG_P0)
        with pytest.raises(RobotFault):  # it stays stopped until opened again
            rob.move_to(TMS_RIG_P0)
        np.testing.assert_allclose(rob.flange_pose(), target, atol=1e-9)  # still readable
        assert rob.moves_sent == 1 and len(rob.rig.moves) == 1
    with SimRobot(channel="kinds", fail_after_moves=0, fault="connection_lost") as rob:
        with pytest.raises(ConnectionLost):
            rob.move_to(TMS_RIG_P0)
        with pytest.raises(ConnectionLost):
            rob.flange_pose()


def test_a_dropped_tool_skips_the_poses_after_k_moves(tmp_path):
    cfg = load_config(write(tmp_path, sim_config(
        "drop", None, {"drop_tool": "probe", "drop_after_moves": 3},
        plan={"poses": 6, "seed": 1, "start": "current"},
        run={"retries": 0, "reconnect_wait_s": 0.0, "stop_skip_share": 1.0})))
    out = tmp_path / "s.jsonl"
    res = acquire(cfg, out)     # stop_skip_share 1: the skipped poses do not end the run
    assert (res.recorded, res.skipped, res.total) == (3, 3, 6)
    s = read_session(out)
    assert [p.skipped is None for p in s.poses[:3]] == [True, True, True]
    assert all(p.skipped is not None and "probe" in p.skipped for p in s.poses[3:]), \
        [p.skipped for p in s.poses]


# --- the arm --------------------------------------------------------------------------------

def test_an_arm_reports_joints_and_no_arm_says_which_option():
    with SimRobot(channel="arm", arm="ur5e") as rob:
        q = rob.joint_positions()
        assert q.shape == (6,) and np.all(np.isfinite(q))
        assert rob.identity()["arm"] == "ur5e"
        rob.move_to(TMS_RIG_P0 @ make_pose(np.eye(3), [20.0, 0.0, 0.0]))
        assert not np.allclose(rob.joint_positions(), q)
    with SimRobot(channel="arm") as rob, pytest.raises(NotImplementedError,
                                                       match="robot.options.arm"):
        rob.joint_positions()


# --- the acceptance suite ---------------------------------------------------------------------

def test_selftest_on_the_sim_rig_passes_and_judges_no_timing(tmp_path):
    """``tmscal selftest`` on the shipped sim config: connect, tools, the small move and
    reconnect pass; the frame rate is reported, not judged, and the stop mid-move is skipped
    (a sim move takes no time), each saying so."""
    report = tmp_path / "report.txt"
    r = run("selftest", "--rig", CONFIGS / "sim.yaml", "--report", report)
    assert r.exit_code == 0, r.output
    assert "PASS (4 passed, 0 failed, 1 skipped)" in r.output
    assert "frame rate reported only (an in-process sim device)" in r.output
    assert "SKIP  stop while moving: an in-process sim device completes a move at once" in \
        r.output
    text = report.read_text(encoding="utf-8")
    assert "in-process sim devices" in text and "rate_error" not in text


def test_tmscal_mock_refuses_a_sim_config_naming_the_driver_key(tmp_path):
    """A sim driver speaks no protocol: there is nothing for ``tmscal mock`` to serve."""
    cfg = write(tmp_path, sim_config("no-mock", mock={"seed": 1}))
    r = run("mock", cfg)
    assert r.exit_code != 0
    assert "key 'robot.driver': driver 'sim' has no mock to serve" in r.output, r.output
