"""The rig commands through click's runner (tracker and DENSO mocks in this process: our
drivers are pure Python) and `tmscal demo` in a subprocess (ur_rtde needs the mock in another
process)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.config import load_config
from tmscal.mocks.launch import start_mock_rig
from tmscal.sim import TMS_RIG_P0

from ..rigs import NOISE_FREE_MOCK, point_config


def test_track_robot_dry_run_and_jog(tmp_path, mock_config):
    base_cfg = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           mock={"noise": NOISE_FREE_MOCK})
    with start_mock_rig(load_config(base_cfg), tracker_transport="pty") as mr:
        cfg = point_config(base_cfg, mr.endpoints, "pointed.yaml")
        r = CliRunner().invoke(main, ["track", str(cfg), "--frames", "3"])
        assert r.exit_code == 0, r.output
        # the tracker's identity as the configs write values, not Python's dict repr
        ident = r.output.splitlines()[0]
        assert ident.startswith("tracker: driver ndi") and "handles {marker: 1, probe: 2}" \
            in ident and "'" not in ident, ident
        lines = [ln for ln in r.output.splitlines() if ln.startswith("frame")]
        assert len(lines) == 3
        marker = [ln.split() for ln in r.output.splitlines() if ln.startswith("  marker ")]
        truth_marker = mr.rig.true_body("marker")[:3, 3]
        assert len(marker) == 3 and marker[0][4] == f"{truth_marker[2]:.2f}"

        r = CliRunner().invoke(main, ["robot", str(cfg)])
        assert r.exit_code == 0, r.output
        assert "x    500.00" in r.output and "z    400.00" in r.output  # P0 of the TMS rig
        # P0 points the flange down: roll 180° about the base x axis, labelled as such
        assert "roll/pitch/yaw 180.000 0.000 0.000 deg" in r.output.replace("-0.000", "0.000")
        assert "R = Rz(yaw)·Ry(pitch)·Rx(roll)" in r.output
        assert " rx " not in r.output and "UR pendant" not in r.output  # a DENSO

        r = CliRunner().invoke(main, ["acquire", str(cfg), "-o", str(tmp_path / "s.jsonl"),
                                      "--dry-run", "--poses", "50"])
        assert r.exit_code == 0, r.output
        assert "50 poses" in r.output and "every pose inside" in r.output
        # the box from the config, in the base frame, beside the flange's and tool's extent
        safety = load_config(cfg).safety
        box = next(ln for ln in r.output.splitlines() if "workspace box" in ln)
        for lo, hi in zip(safety.workspace_min_mm, safety.workspace_max_mm):
            assert f"{lo:.1f}…{hi:.1f}" in box.replace(" ", ""), box
        tool = next(ln for ln in r.output.splitlines() if "tool points over" in ln)
        flange = next(ln for ln in r.output.splitlines() if "flange over" in ln)
        z_tool_min = float(tool.split()[-1].split("…")[0])
        z_flange_min = float(flange.split()[-1].split("…")[0])
        assert z_tool_min < z_flange_min - 50  # the coil hangs below the flange
        assert not (tmp_path / "s.jsonl").exists()
        assert mr.devices[-1].stats["moves"] == 0

        # a jog outside the envelope is refused before anything is sent
        r = CliRunner().invoke(main, ["robot", str(cfg), "--move-to", "500,0,900,180,0,0",
                                      "--yes"])
        assert r.exit_code == 1 and "refused" in r.output
        assert mr.devices[-1].stats["moves"] == 0
        # a jog inside it, confirmed on stdin
        r = CliRunner().invoke(main, ["robot", str(cfg), "--move-to", "520,10,420,180,0,0"],
                               input="y\n")
        assert r.exit_code == 0, r.output
        np.testing.assert_allclose(mr.rig.flange[:3, 3], [520, 10, 420], atol=1e-6)
        np.testing.assert_allclose(mr.rig.flange[:3, :3], TMS_RIG_P0[:3, :3], atol=1e-9)


def test_demo_json_recovers_truth(mock_config):
    cfg = mock_config("mock-ur-polaris.yaml")
    out = subprocess.run([sys.executable, "-m", "tmscal.cli", "demo", "--config", str(cfg),
                          "--poses", "25", "--samples", "10", "--json"],
                         capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr[-2000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["method"] == "qr36" and res["n_solve"] == 25
    assert res["truth"]["coil_placement_mm"] < 0.3
    assert res["truth"]["Y"]["trans_mm"] < 0.5


def test_robot_on_a_ur_labels_rpy_and_prints_the_pendant_rotation_vector(mock_config):
    from tmscal.geometry import rotvec_pose_from_matrix
    from tmscal.mocks.launch import spawn_mock_rig

    cfg = mock_config("mock-ur-polaris.yaml", mock={"noise": NOISE_FREE_MOCK})
    with spawn_mock_rig(cfg, transport="tcp") as mp:
        host = mp.endpoints["robot"]
        out = subprocess.run([sys.executable, "-m", "tmscal.cli", "robot", str(cfg),
                              "--host", host], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "roll/pitch/yaw" in out.stdout and "R = Rz(yaw)·Ry(pitch)·Rx(roll)" in out.stdout
    pendant = next(ln for ln in out.stdout.splitlines() if "UR pendant" in ln)
    v = rotvec_pose_from_matrix(TMS_RIG_P0)  # the mock's TCP offset is zero: TCP = flange
    assert f"RX {v[3]:.4f}  RY {v[4]:.4f}  RZ {v[5]:.4f} rad (rotation vector)" in pendant
    assert f"X {v[0] * 1000:.2f}  Y {v[1] * 1000:.2f}  Z {v[2] * 1000:.2f} mm" in pendant


def test_robot_on_a_ur_whose_dashboard_reply_is_not_utf8_names_it(mock_config):
    """`tmscal robot` on a UR whose dashboard answers a query with bytes that are not UTF-8:
    one line naming the command and the bytes (escaped), exit status 1, no traceback."""
    from tmscal.mocks.launch import spawn_mock_rig

    cfg = mock_config("mock-ur-polaris.yaml",
                      mock={"noise": NOISE_FREE_MOCK,
                            "robot": {"faults": {"non_utf8_dashboard_reply": "robotmode"}}})
    with spawn_mock_rig(cfg, transport="tcp") as mp:
        out = subprocess.run([sys.executable, "-m", "tmscal.cli", "robot", str(cfg),
                              "--host", mp.endpoints["robot"]], capture_output=True, text=True,
                             timeout=120)
    text = out.stdout + out.stderr
    assert out.returncode == 1, text[-2000:]
    assert "Traceback" not in text and "UnicodeDecodeError" not in text
    assert "'robotmode'" in text and "not UTF-8" in text and "\\xff\\xfe" in text


def test_robot_needs_only_the_robot_section(tmp_path, mock_config):
    """A real-rig config whose tracker ROM files are not there yet: `tmscal robot` still
    connects (it needs no tracker), while `tmscal track` names the missing ROM."""
    import yaml

    base = mock_config("mock-denso-polaris.yaml", robot={"port": 0})
    with start_mock_rig(load_config(base), tracker_transport="pty") as mr:
        cfg = point_config(base, mr.endpoints, "pointed.yaml")
        data = yaml.safe_load(cfg.read_text())
        data["tracker"]["tools"]["marker"] = str(tmp_path / "not-yet" / "marker.rom")
        cfg.write_text(yaml.safe_dump(data))
        r = CliRunner().invoke(main, ["robot", str(cfg)])
        assert r.exit_code == 0, r.output
        assert "x    500.00" in r.output
        r = CliRunner().invoke(main, ["track", str(cfg), "--frames", "1", "--plain"])
        assert r.exit_code == 1
        assert "tracker.tools.marker" in r.output and "ROM file not found" in r.output


def test_acquire_force_keeps_the_old_session_when_the_run_cannot_start(tmp_path, mock_config):
    """--force replaces an existing session only when the new run's header is written: with
    the robot unreachable the run fails and the old session is as it was; with the rig there
    it is replaced by the new run."""
    from tmscal.session import read_session

    from ..rigs import free_port, unique_host

    base_cfg = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           mock={"noise": NOISE_FREE_MOCK})
    out = tmp_path / "s.jsonl"
    old = tmp_path / "old.jsonl"
    r = CliRunner().invoke(main, ["simulate", "-o", str(old), "--poses", "12", "--seed", 3])
    assert r.exit_code == 0, r.output
    out.write_bytes(old.read_bytes())
    with start_mock_rig(load_config(base_cfg), tracker_transport="pty") as mr:
        cfg = point_config(base_cfg, mr.endpoints, "pointed.yaml")
        host = unique_host()
        nobody = f"{host}:{free_port(host)}"      # a loopback address nothing listens on
        r = CliRunner().invoke(main, ["acquire", str(cfg), "-o", str(out), "--poses", "6",
                                      "--samples", "5", "--force", "--robot-host", nobody])
        assert r.exit_code == 1, r.output
        assert out.read_bytes() == old.read_bytes()
        assert mr.devices[-1].stats["moves"] == 0
        r = CliRunner().invoke(main, ["acquire", str(cfg), "-o", str(out), "--poses", "6",
                                      "--samples", "5", "--force"])
        assert r.exit_code == 0, r.output
    s = read_session(out)
    assert len(s.poses) == 6 and s.header.get("plan", {}).get("poses") == 6
    assert not [f for f in tmp_path.iterdir() if f.name.startswith(".tmscal-")]
