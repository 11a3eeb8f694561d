"""``tmscal solve SESSION --kinematics estimate`` on a session that recorded a wrist wrench at
every pose: the wrench rows join the likelihood (docs/kinematics.md, "Wrench rows"), the
report says so and gives the tool, the bias and the base tilt. Sessions come from a sim rig
whose UR5e has realistic hidden errors (tmscal.sim.arm); the wrench is the mock sensor's
(tmscal.mocks.wrench: the TRUE arm's gravity wrench) plus noise. Poses 4×4 mm, joints rad,
wrenches N, N·m."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.geometry import pose_mean
from tmscal.mocks.wrench import gravity_wrench_source
from tmscal.poses import eq14_poses
from tmscal.session import PoseRecord, make_header, write_session
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, make_arm, tms_rig_truth

SPREAD = np.array([0.1] * 3 + [0.005] * 3)       # per sample; 100 samples averaged


def _session(path: Path, n: int = 40, seed: int = 3, wrench_on: int | None = None) -> SimRig:
    """n Eq. 14 poses (±100 mm, ±25°) of a UR5e rig with realistic errors; every pose
    records its averaged wrench (or only the first ``wrench_on``)."""
    rig = SimRig(tms_rig_truth(), noise=Noise(), rng=np.random.default_rng(seed),
                 start=TMS_RIG_P0, arm=make_arm("ur5e", "realistic", seed))
    source = gravity_wrench_source(rig)
    rng = np.random.default_rng(seed + 2)
    plan = eq14_poses(TMS_RIG_P0, n, np.random.default_rng(seed + 1), r_mm=100.0, d_deg=25.0)
    recs = []
    for i, P in enumerate(plan):
        rig.move_flange(P)
        has = wrench_on is None or i < wrench_on
        w = source() + rng.normal(0, 1, 6) * SPREAD / 10 if has else None
        recs.append(PoseRecord(
            index=i, A=rig.reported_flange(), B=pose_mean(rig.observe("marker", 10)),
            C=pose_mean(rig.observe("probe", 10)), commanded=P, time=float(i),
            samples={"A": 1, "B": 10, "C": 10} | ({"wrench": 100} if has else {}),
            joints_rad=rig.joints(), wrench=None if w is None else w.tolist(),
            wrench_spread=SPREAD.tolist() if has else None))
    write_session(path, make_header(["marker", "probe"], truth=rig.truth.as_dict()), recs)
    return rig


def _solve(*args: str) -> tuple[int, str]:
    r = CliRunner().invoke(main, ["solve", *args])
    return r.exit_code, r.output


def test_the_wrench_rows_identify_the_tool_and_the_tilt(tmp_path) -> None:
    s = tmp_path / "s.jsonl"
    rig = _session(s)
    true = rig.arm_true
    code, out = _solve(str(s), "--kinematics", "estimate", "--arm", "ur5e", "--level", "full",
                       "--json")
    assert code == 0, out
    got = json.loads(out)
    w = got["arm"]["wrench"]
    assert w["rows"] == 6 * 40
    assert abs(w["tool_mass_kg"] - true.tool_mass_kg) < 0.002
    e, sd = w["estimate"], w["sd"]
    for k, want in zip(("cog_x", "cog_y", "cog_z"), true.tool_cog_mm, strict=True):
        assert abs(e[k] - want) < max(4 * sd[k], 0.05), (k, e[k], want, sd[k])
    for k, want in zip(("f0_x", "f0_y", "f0_z", "t0_x", "t0_y", "t0_z"), true.bias,
                       strict=True):
        assert abs(e[k] - want) < max(4 * sd[k], 1e-4), (k, e[k], want, sd[k])
    # the true base's tilt against gravity (its roll and pitch; the yaw is invisible)
    from tmscal.calib.kinematics import rpy_from_matrix
    roll, pitch, _ = rpy_from_matrix(true.base)
    assert abs(e["base_roll"] - roll) < max(4 * sd["base_roll"], 2e-4)
    assert abs(e["base_pitch"] - pitch) < max(4 * sd["base_pitch"], 2e-4)
    assert got["truth"]["coil_placement_mm"] < 0.2
    code, text = _solve(str(s), "--kinematics", "estimate", "--arm", "ur5e", "--level", "full")
    assert code == 0, text
    assert "wrench rows: 240" in text and "tool: mass 1.5" in text


def test_a_pose_without_a_wrench_leaves_the_rows_out(tmp_path) -> None:
    s = tmp_path / "s.jsonl"
    _session(s, n=20, wrench_on=19)
    code, out = _solve(str(s), "--kinematics", "estimate", "--arm", "ur5e", "--level", "offsets",
                       "--json")
    assert code == 0, out
    assert json.loads(out)["arm"].get("wrench") is None
