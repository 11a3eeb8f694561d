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
