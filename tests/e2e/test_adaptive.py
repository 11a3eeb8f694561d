"""End to end, adaptive acquisition (docs/adaptive.md) on the protocol-level mocks (real
sockets and ptys; the CLI and the mocks in child processes where a test kills or runs the
command): the stopping rule stops at the bootstrap on a noise-free rig and at max_poses on a
very noisy one, saying which; Ctrl-C leaves a resumable session; kill -9 then --resume loses
and repeats no pose and reaches the same decision as an uninterrupted run; ``demo --adaptive
--json`` recovers the mock rig's truth within the predicted error; every pose commanded is
inside the envelope (random envelopes and seeds)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from tmscal.acquisition.adaptive_run import acquire_adaptive, settings_for
from tmscal.acquisition.devices import envelope_for
from tmscal.config import load_config
from tmscal.errors import SafetyError
from tmscal.mocks.launch import spawn_mock_rig, start_mock_rig
from tmscal.poses import PlanSpec
from tmscal.session import read_session

from ..fuzz import fuzz_settings
from ..rigs import NOISE_FREE_MOCK, endpoints_kwargs, point_config, wait_for_lines, write_config

#: the mock rig's noise, far above the target: no dozen poses can reach 0.05 mm
VERY_NOISY = {"fiducial_sigma_mm": 1.0, "robot_rot_sigma_deg": 0.5, "robot_trans_sigma_mm": 1.0}


def _cli(*args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tmscal.cli", *args], capture_output=True,
                          text=True, timeout=timeout)


def check_adaptive_session(path, pool_size: int | None = None) -> list:
    """The session's invariants: indices 0…n−1 in order of acquisition, every commanded pose
    a distinct pool pose (the pool regenerated from the header) and inside the envelope the
    header's config gives around P0. Returns the records in index order."""
    from tmscal.config import parse_config

    s = read_session(path)
    recs = sorted(s.poses, key=lambda p: p.index)
    assert [p.index for p in recs] == list(range(len(recs)))
    spec = PlanSpec.from_header(s.header)
    assert spec.n == s.header["adaptive"]["pool"] == (pool_size or spec.n)
    pool = spec.poses()
    js = [p.pool for p in recs]
    assert len(set(js)) == len(js), js
    for p in recs:
        np.testing.assert_allclose(p.commanded, pool[p.pool], atol=1e-9)
    env = envelope_for(parse_config(s.header["config"], check_files=False), spec.p0)
    assert not any(env.violations(p.commanded) for p in recs)
    return recs


@pytest.mark.e2e
def test_noise_free_rig_stops_at_the_bootstrap(mock_config):
    """No noise: the first prediction (after the bootstrap's 4 poses) is far below the
    target, and the run stops there with reason "target"."""
    cfg = load_config(mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                                  sampling={"samples": 5}, mock={"noise": NOISE_FREE_MOCK}))
    out = cfg.path.parent / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        res = acquire_adaptive(cfg, out, **endpoints_kwargs(mr.endpoints))
    boot = settings_for(cfg).bootstrap_poses(2)
    assert (res.stop, res.recorded, res.skipped, res.stopped) == ("target", boot, 0, False)
    assert res.prediction.coil_mm <= 0.05 and "≤ target 0.05 mm at 95 %" in res.message
    assert len(check_adaptive_session(out, 1000)) == boot


@pytest.mark.e2e
def test_very_noisy_rig_stops_at_max_poses_and_says_so(mock_config, tmp_path):
    """Through the command: a rig 20× noisier than the target stops at --max-poses, with
    the reason and the prediction above the target in the report."""
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           sampling={"samples": 5}, mock={"noise": VERY_NOISY})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="tcp") as mp:
        run_cfg = point_config(cfg_path, mp.endpoints)
        r = _cli("acquire", str(run_cfg), "-o", str(out), "--adaptive", "--max-poses", "7")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "reached max_poses 7 with predicted" in r.stdout and "> target 0.05 mm" in r.stdout
    assert "robot time" in r.stdout and "moving" in r.stdout and "sampling" in r.stdout
    assert len(check_adaptive_session(out)) == 7
    # solve prints the same prediction, recomputed from the session
    s = _cli("solve", str(out), "--json")
    assert s.returncode == 0, s.stderr[-2000:]
    pred = json.loads(s.stdout)["adaptive"]
    assert pred["n_poses"] == 7 and pred["predicted_coil_mm"] > 0.05
    assert f"predicted {pred['predicted_coil_mm']:.3g} mm" in r.stdout
    assert pred["method"] == "ml" and pred["options"] == {"distortion": "scale"}
    # the calibration the report's last line names is the one that prediction is about
    assert f"next: tmscal solve {out} --method ml --option distortion=scale" in r.stdout
    t = _cli("solve", str(out))  # QR36: its own prediction, once; the run's named, no number
    assert t.returncode == 0, t.stderr[-2000:]
    assert t.stdout.count("predicted coil-placement error") == 1
    assert "predicted coil-placement error of the QR36 calibration: " in t.stdout
    assert (f"the run stopped on the prediction of the calibration tmscal solve {out} "
            "--method ml --option distortion=scale writes") in t.stdout
    ml = _cli("solve", str(out), "--method", "ml", "--option", "distortion=scale", "--json")
    assert ml.returncode == 0, ml.stderr[-2000:]
    assert json.loads(ml.stdout)["prediction"]["coil_placement_mm"] == pytest.approx(
        pred["predicted_coil_mm"], rel=1e-9)


@pytest.mark.e2e
def test_ctrl_c_finishes_the_pose_in_flight_and_leaves_a_resumable_session(mock_config,
                                                                          tmp_path):
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           sampling={"samples": 3})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="tcp") as mp:
        run_cfg = point_config(cfg_path, mp.endpoints)
        proc = subprocess.Popen([sys.executable, "-m", "tmscal.cli", "acquire", str(run_cfg),
                                 "-o", str(out), "--adaptive"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        wait_for_lines(out, 6, proc)
        assert proc.poll() is None, "the run ended before Ctrl-C"
        proc.send_signal(signal.SIGINT)
        stdout, _ = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert "stopped early (resumable)" in stdout and f"-o {out} --resume" in stdout
    recs = check_adaptive_session(out)
    assert len(recs) >= 5 and not read_session(out).torn_tail


def _uninterrupted_stop(cfg_path, tmp_path) -> tuple[str, int]:
    out, cfg = tmp_path / "whole.jsonl", load_config(cfg_path)
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        res = acquire_adaptive(cfg, out, **endpoints_kwargs(mr.endpoints))
    return res.stop, res.recorded


@pytest.mark.e2e
def test_kill_9_then_resume_loses_and_repeats_nothing(mock_config, tmp_path):
    """``tmscal acquire --adaptive`` in a child, killed with SIGKILL after a few poses; the
    resumed run keeps every pose recorded, repeats no pool pose, numbers the new poses on,
    and stops for the same reason as an uninterrupted run of the same config and rig seed."""
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           sampling={"samples": 5},
                           adaptive={"max_poses": 30, "target_mm": 0.07})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="tcp") as mp:
        run_cfg = point_config(cfg_path, mp.endpoints)
        proc = subprocess.Popen([sys.executable, "-m", "tmscal.cli", "acquire", str(run_cfg),
                                 "-o", str(out), "--adaptive"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE)
        wait_for_lines(out, 8, proc)  # the header and 7 poses: past the bootstrap
        assert proc.poll() is None, "the run ended before it could be killed"
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        before = sorted(read_session(out).poses, key=lambda p: p.index)
        assert 7 <= len(before) < 30
        r = _cli("acquire", str(run_cfg), "-o", str(out), "--resume")  # adaptive by header
    assert r.returncode == 0, r.stderr[-2000:]
    recs = check_adaptive_session(out)
    assert len(recs) > len(before)
    for a, b in zip(before, recs):  # the poses recorded before the kill are untouched
        assert (a.index, a.pool) == (b.index, b.pool)
        np.testing.assert_array_equal(a.C, b.C)
    stop, n = _uninterrupted_stop(cfg_path, tmp_path)
    assert stop == "target" and "≤ target 0.07 mm" in r.stdout, (stop, n, r.stdout)


@pytest.mark.e2e
def test_demo_adaptive_json_recovers_the_truth_within_the_prediction(mock_config):
    """Seeded (mock.seed 7; target 0.07 mm to keep it short): the run stops at the target,
    and the true coil-placement error of its calibration, against the mock rig's truth over
    the same region, is within twice the predicted error at 95 %. (True ≤ predicted fails
    in about 1 run of 20 for an honest prediction, and the poses chosen depend on measured
    robot time, so one run cannot check the share; benchmarks/adaptive_coverage.py and
    tests/unit/test_adaptive_math.py do, over many runs. Twice the 95 % quantile is far out
    in the tail: an honest prediction essentially never exceeds it.)"""
    cfg = mock_config("mock-ur-polaris.yaml")
    r = _cli("demo", "--config", str(cfg), "--adaptive", "--samples", "20", "--target-mm",
             "0.07", "--json")
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res["stop_reason"] == "target" and res["poses_used"] <= 40
    assert set(res["robot_time_s"]) == {"moving", "settling", "sampling", "total"}
    assert res["robot_time_s"]["total"] == pytest.approx(
        sum(res["robot_time_s"][k] for k in ("moving", "settling", "sampling")))
    assert 0 < res["predicted_coil_mm"] <= 0.07
    assert 0 < res["true_coil_mm"] <= 2 * res["predicted_coil_mm"]
    # the calibration reported is the one whose prediction stopped the run (issue 31)
    assert res["method"] == res["prediction"]["method"] == res["adaptive_method"] == "ml"
    assert res["distortion"]["model"] == "scale" and res["prediction"]["arm"] is None
    assert res["prediction"]["coil_placement_mm"] == pytest.approx(res["predicted_coil_mm"],
                                                                   rel=1e-9)
    assert res["truth"]["coil_placement_mm"] == res["true_coil_mm"]
    assert res["n_solve"] == res["poses_used"]


@pytest.mark.e2e
def test_demo_adaptive_reports_a_calibration_that_meets_its_target(mock_config):
    """The demo as a user runs it (the packaged mock rig, the default target 0.05 mm): it
    stops at the target and reports (text and --json) the calibration whose prediction
    stopped it, whose true coil-placement error on the mock rig's truth meets the target
    (before issue 31 it reported QR36, 0.076 mm true). The text prints that prediction once
    for that calibration."""
    cfg = mock_config("mock-ur-polaris.yaml")
    r = _cli("demo", "--config", str(cfg), "--adaptive", "--json")
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res["stop_reason"] == "target" and res["method"] == "ml"
    assert res["prediction"]["coil_placement_mm"] == pytest.approx(res["predicted_coil_mm"],
                                                                   rel=1e-9)
    assert res["predicted_coil_mm"] <= 0.05
    assert 0 < res["true_coil_mm"] <= 0.05
    t = _cli("demo", "--config", str(cfg), "--adaptive")
    assert t.returncode == 0, t.stderr[-2000:]
    assert t.stdout.count("predicted coil-placement error of the ML calibration: "
                          f"{res['predicted_coil_mm']:.3g} mm at 95 %") == 1
    assert "QR36" not in t.stdout


@pytest.mark.e2e
def test_demo_adaptive_on_an_arm_with_kinematic_error_names_the_arm_and_the_command(
        mock_config, tmp_path):
    """A UR5e with realistic kinematic errors (the packaged -kin config): the prediction,
    which counts the arm's error and does not estimate it, cannot reach 0.05 mm; the run
    says that the arm is the cause and names the solve that estimates it, and its report
    prints one predicted coil-placement error, the ml calibration's."""
    out = tmp_path / "s.jsonl"
    cfg = mock_config("mock-ur-polaris-kin.yaml")
    r = _cli("demo", "--adaptive", "--config", str(cfg), "--max-poses", "12", "-o", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    first = r.stdout.splitlines()[1]
    assert first.startswith("reached max_poses 12 with predicted"), r.stdout[:2000]
    assert "the cause is model error, the arm's kinematic error" in first
    assert f"tmscal solve {out} --kinematics estimate" in first
    assert r.stdout.count("predicted coil-placement error of the ML calibration") == 1


_SHRINK = st.tuples(*[st.floats(0, 330)] * 5, st.floats(0, 350))  # box sides: −x −y −z +x +y +z


@pytest.mark.e2e
@fuzz_settings(examples=2)
@given(seed=st.integers(0, 2**16), radius=st.floats(10, 120), rotation=st.floats(1, 15),
       offset=st.floats(40, 250), max_rot=st.floats(4, 25), shrink=_SHRINK)
@example(seed=1, radius=40, rotation=5, offset=200, max_rot=20, shrink=(0,) * 6)  # runs
@example(seed=2, radius=100, rotation=10, offset=200, max_rot=20,
         shrink=(300, 0, 0, 0, 0, 0))  # the pool leaves the box: refused
def test_every_pose_an_adaptive_run_commands_is_inside_the_envelope(
        tmp_path_factory, seed, radius, rotation, offset, max_rot, shrink):
    """Random envelopes (offset and rotation limits, a workspace box shrunk around P0 and the
    coil) and rig and plan seeds: the run is refused before anything moves, or every pose
    the robot mock was told to go to is inside the envelope around P0."""
    lo = np.array([100.0, -400.0, 0.0]) + shrink[:3]
    hi = np.array([900.0, 400.0, 800.0]) - shrink[3:]
    tmp = tmp_path_factory.mktemp("env")
    cfg = load_config(write_config(
        tmp, "mock-denso-polaris.yaml", robot={"port": 0}, sampling={"samples": 3},
        plan={"seed": seed, "radius_mm": radius, "rotation_deg": rotation},
        safety={"max_offset_mm": offset, "max_rotation_deg": max_rot,
                "workspace_min_mm": lo.tolist(), "workspace_max_mm": hi.tolist()},
        adaptive={"max_poses": 6, "pool": 150, "region": 50}, mock={"seed": seed}))
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        p0 = mr.rig.commanded.copy()
        try:
            acquire_adaptive(cfg, tmp / "s.jsonl", **endpoints_kwargs(mr.endpoints))
        except SafetyError as e:
            assert "Nothing was moved" in str(e)
            assert not mr.rig.moves
            return
        moves = list(mr.rig.moves)
    assert len(moves) >= 4
    env = envelope_for(cfg, p0)
    assert not [env.violations(M) for M in moves if env.violations(M)]
