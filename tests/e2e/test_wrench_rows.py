"""End to end: a tracker session that records the wrist wrench, and the wrench rows in the
kinematic likelihood (docs/kinematics.md, "Wrench rows"). The mock UR5e with realistic arm
errors (ur_rtde over real sockets), its built-in force-torque sensor (``ur_wrench``: the
mock's ft_raw_wrench, the TRUE arm's gravity wrench plus noise) and the mock Polaris serve
one rig (configs/mock-ur-polaris-kin-ft.yaml); ``tmscal acquire`` records every pose's
averaged wrench beside the tracker samples (and resumes); ``tmscal solve --kinematics
estimate`` uses them and recovers the tool, the sensor's bias and the base tilt of the true
arm, with the coil placed as well as without the wrench. Poses 4×4 mm, joints rad, wrenches
N, N·m."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.acquisition.run import acquire
from tmscal.calib.kinematics import rpy_from_matrix
from tmscal.calib.selfcal.model import wrench as selfcal_wrench
from tmscal.cli import main
from tmscal.config import load_config
from tmscal.mocks.launch import build_sim_rig, spawn_mock_rig
from tmscal.session import read_session, write_session

from ..rigs import SeenPoses, endpoints_kwargs

pytestmark = pytest.mark.e2e

PLAN = {"kind": "joints", "poses": 30, "radius_mm": 150, "rotation_deg": 20, "seed": 4,
        "pool": 2000}


def _solve(*args: str) -> tuple[int, str]:
    r = CliRunner().invoke(main, ["solve", *args])
    return r.exit_code, (r.stdout if r.exit_code == 0 else r.output)


def test_acquire_records_wrenches_and_solve_uses_them(tmp_path, mock_config) -> None:
    cfg_path = mock_config("mock-ur-polaris-kin-ft.yaml", plan=PLAN,
                           sampling={"samples": 10}, ft={"samples": 50})
    cfg = load_config(cfg_path)
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="tcp") as mp:
        kw = endpoints_kwargs(mp.endpoints)
        calls: list = []
        res = acquire(cfg, out, should_stop=lambda: len(calls) >= 5,
                      progress=SeenPoses(calls), **kw)
        assert res.stopped and res.recorded == 5
        res = acquire(cfg, out, resume=True, **kw)
        assert (res.recorded, res.skipped) == (30, 0)
    s = read_session(out)
    assert s.header["devices"]["ft"]["driver"] == "ur_wrench"
    rig = build_sim_rig(cfg)                 # the same rig, its truth (same mock seed)
    true = rig.arm_true
    for p in s.poses:
        assert p.samples["wrench"] == 50 and len(p.wrench_spread) == 6
        # the wrench is the TRUE arm's gravity wrench at the recorded joints (the mock's
        # noise 0.1 N / 0.005 N·m per reading, averaged over 50)
        want = selfcal_wrench(true, np.asarray(p.joints_rad)[None])[0]
        assert np.all(np.abs(np.asarray(p.wrench) - want) < [0.1] * 3 + [0.005] * 3), p.index
    truth = tmp_path / "s-truth.jsonl"
    write_session(truth, {**s.header, "truth": rig.truth.as_dict()}, s.poses)

    code, text = _solve(str(truth), "--kinematics", "estimate", "--level", "full", "--json")
    assert code == 0, text
    got = json.loads(text)
    w = got["arm"]["wrench"]
    assert w["rows"] == 6 * 30
    assert abs(w["tool_mass_kg"] - true.tool_mass_kg) < 0.01
    e, sd = w["estimate"], w["sd"]
    for k, v in zip(("cog_x", "cog_y", "cog_z"), true.tool_cog_mm, strict=True):
        assert abs(e[k] - v) < max(5 * sd[k], 0.5), (k, e[k], v, sd[k])
    for k in ("f0_x", "f0_y", "f0_z"):
        assert abs(e[k]) < max(5 * sd[k], 0.05), (k, e[k], sd[k])
    roll, pitch, _ = rpy_from_matrix(true.base)     # the true base's tilt against gravity
    assert abs(e["base_roll"] - roll) < max(5 * sd["base_roll"], 1e-3)
    assert abs(e["base_pitch"] - pitch) < max(5 * sd["base_pitch"], 1e-3)

    # the same session without the wrenches: the coil lands no worse with them
    plain = read_session(truth)
    for p in plain.poses:
        p.wrench = p.wrench_spread = None
    bare = tmp_path / "s-bare.jsonl"
    write_session(bare, plain.header, plain.poses)
    code, text = _solve(str(bare), "--kinematics", "estimate", "--level", "full", "--json")
    assert code == 0, text
    without = json.loads(text)
    assert without["arm"].get("wrench") is None
    with_mm = got["truth"]["coil_placement_mm"]
    assert with_mm < 0.1
    assert with_mm <= without["truth"]["coil_placement_mm"] * 1.2 + 0.005


def test_resuming_a_wrench_session_without_the_sensor_is_refused(tmp_path, mock_config
                                                                  ) -> None:
    from tmscal.errors import SessionError

    cfg_path = mock_config("mock-ur-polaris-kin-ft.yaml", plan={**PLAN, "poses": 3},
                           sampling={"samples": 5}, ft={"samples": 5})
    cfg = load_config(cfg_path)
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="tcp") as mp:
        kw = endpoints_kwargs(mp.endpoints)
        calls: list = []
        acquire(cfg, out, should_stop=lambda: len(calls) >= 1, progress=SeenPoses(calls), **kw)
        data = yaml.safe_load(cfg_path.read_text())
        del data["ft"], data["mock"]["ft"]
        no_ft = tmp_path / "no-ft.yaml"
        no_ft.write_text(yaml.safe_dump(data))
        with pytest.raises(SessionError, match="recorded a wrench at every pose"):
            acquire(load_config(no_ft), out, resume=True, **kw)
    assert len(read_session(out).poses) == 1
