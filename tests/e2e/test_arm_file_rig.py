"""End to end: the config's ``robot.arm`` names an arm file (docs/kinematics.md, "Arm files");
an acquisition on the DENSO mock (b-CAP, the real driver) records its definition in the session
header; ``solve --kinematics estimate`` then takes the recorded arm without the file, refuses
another ``--arm``; a config naming another registered arm than the controller reports is a
ConfigError naming the key."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from tmscal.acquisition.run import acquire
from tmscal.cli import main
from tmscal.config import load_config
from tmscal.errors import ConfigError
from tmscal.formats.armdef import shipped_arm_text
from tmscal.mocks.launch import spawn_mock_rig
from tmscal.session import read_session

from ..rigs import endpoints_kwargs

pytestmark = pytest.mark.e2e


def test_the_session_records_the_arm_file_and_solve_uses_it(tmp_path, mock_config) -> None:
    arm_file = tmp_path / "arms" / "my_vs060.yaml"     # the registry's VS-060 as a file
    arm_file.parent.mkdir()
    arm_file.write_text(shipped_arm_text("vs060"))
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0, "arm": str(arm_file)},
                           plan={"poses": 10}, sampling={"samples": 3},
                           mock={"kinematics": {"arm": "vs060", "errors": "paper", "seed": 3}})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        res = acquire(load_config(cfg_path), out, **endpoints_kwargs(mp.endpoints))
    assert res.recorded == 10
    robot = read_session(out).header["devices"]["robot"]
    rec = robot["arm_definition"]
    assert robot["arm"] == "vs060" and rec["kind"] == "arm-file"
    assert rec["content"] == arm_file.read_text() and rec["path"] == str(arm_file)
    arm_file.unlink()                   # the session holds the arm: no file needed
    runner = CliRunner()
    r = runner.invoke(main, ["solve", str(out), "--kinematics", "estimate", "--level", "none"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(main, ["solve", str(out), "--kinematics", "estimate", "--arm", "cobotta"])
    assert r.exit_code == 1
    assert "recorded with the arm file" in r.output and "devices.robot.arm_definition" in \
        r.output and "cobotta" in r.output


def test_a_config_arm_the_controller_is_not_is_refused(tmp_path, mock_config) -> None:
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0, "arm": "cobotta"},
                           plan={"poses": 4}, sampling={"samples": 2},
                           mock={"kinematics": {"arm": "vs060", "errors": "none", "seed": 3}})
    with spawn_mock_rig(cfg_path, transport="pty") as mp, \
            pytest.raises(ConfigError, match=r"key 'robot\.arm': 'cobotta', but the controller "
                          r"reports a 'vs060'"):
        acquire(load_config(cfg_path), tmp_path / "s.jsonl", **endpoints_kwargs(mp.endpoints))
    assert not (tmp_path / "s.jsonl").exists()


def test_selfcal_acquire_keeps_the_arm_file_and_identify_uses_it(tmp_path, mock_config) -> None:
    """`selfcal acquire --arm FILE` on the mock UR and ATI: the header's selfcal entry keeps
    the file's definition; `selfcal identify` without --arm takes it, the file gone."""
    pytest.importorskip("rtde_control")
    import subprocess
    import sys

    arm_file = tmp_path / "my_ur5e.yaml"
    arm_file.write_text(shipped_arm_text("ur5e").replace("arm: ur5e", "arm: my_ur5e"))
    cfg = mock_config("mock-ur-ati.yaml", ft={"port": 0, "samples": 5},
                      mock={"kinematics": {"arm": "ur5e", "errors": "paper", "seed": 5}})
    out, kin = tmp_path / "sc.jsonl", tmp_path / "kin.yaml"

    def tmscal(*args: object) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "tmscal.cli", *map(str, args)],
                              capture_output=True, text=True, timeout=300)

    with spawn_mock_rig(cfg, transport="tcp") as mp:
        ep = mp.endpoints
        r = tmscal("selfcal", "acquire", cfg, "-o", out, "--robot-host", ep["robot"],
                   "--ft-host", ep["ft"], "--k", 8, "--pool", 300, "--arm", arm_file)
    assert r.returncode == 0, r.stderr[-3000:]
    head = read_session(out).header["selfcal"]
    assert head["arm"] == "my_ur5e" and head["arm_definition"]["kind"] == "arm-file"
    arm_file.unlink()
    r = tmscal("selfcal", "identify", out, "-o", kin)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "configurations of arm my_ur5e" in r.stdout
