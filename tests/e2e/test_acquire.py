"""End to end: our drivers against the protocol-level mocks (real sockets and ptys; the mock in
a child process as `tmscal mock`), acquire → solve recovers the sim rig's truth; kill -9 and
--resume; injected faults; a plan outside the envelope never moves the robot."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tmscal.acquisition.plan import make_plan
from tmscal.acquisition.run import AcquisitionStopped, acquire
from tmscal.config import load_config
from tmscal.errors import SafetyError
from tmscal.mocks.launch import build_sim_rig, spawn_mock_rig, start_mock_rig
from tmscal.session import read_session
from tmscal.solving.solve import solve

from ..rigs import (  # noqa: F401 (write_config re-exported for older importers)
    SeenPoses,
    endpoints_kwargs,
    point_config,
    wait_for_lines,
    write_config,
)


def check_truth(cfg_path: Path, session_path: Path, n: int) -> dict:
    cfg = load_config(cfg_path)
    truth = build_sim_rig(cfg).truth  # the mock child built the same rig from this config
    s = read_session(session_path)
    assert [p.index for p in s.poses] == list(range(n))
    s.header["truth"] = {"X": truth.X.tolist(), "Y": truth.Y.tolist(), "Z": truth.Z.tolist()}
    res = solve(s, method="qr36")
    t = res.truth
    # noise: 0.05 mm fiducials, 0.05 mm / 0.05° robot; averaged frames; n poses ±100 mm/±10°
    assert t["X"]["trans_mm"] < 0.5 and t["Y"]["trans_mm"] < 0.5, t
    assert t["X"]["rot_deg"] < 0.1 and t["Y"]["rot_deg"] < 0.1, t
    assert t["coil_placement_mm"] < 0.25, t
    return res


@pytest.mark.e2e
@pytest.mark.parametrize("base", ["mock-ur-polaris.yaml", "mock-denso-polaris.yaml"])
def test_acquire_then_solve_recovers_truth(tmp_path, base, mock_config):
    robot = {"port": 0} if "denso" in base else {}
    cfg_path = mock_config(base, robot=robot, plan={"poses": 30},
                           sampling={"samples": 10})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        res = acquire(load_config(cfg_path), out, **endpoints_kwargs(mp.endpoints))
    assert (res.recorded, res.skipped, res.total, res.stopped) == (30, 0, 30, False)
    s = read_session(out)
    assert s.header["devices"]["robot"]["driver"] in ("ur", "denso")
    assert s.poses[0].samples["B"] == 10 and "marker" in s.poses[0].spread
    check_truth(cfg_path, out, 30)


@pytest.mark.e2e
def test_kill_9_then_resume_loses_and_duplicates_nothing(tmp_path, mock_config):
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           plan={"poses": 150}, sampling={"samples": 20})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="tcp") as mp:
        kw = endpoints_kwargs(mp.endpoints)
        run_cfg = point_config(cfg_path, mp.endpoints)  # the robot port is ephemeral
        proc = subprocess.Popen([sys.executable, "-m", "tmscal.cli", "acquire", str(run_cfg),
                                 "-o", str(out)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE)
        wait_for_lines(out, 12, proc)
        assert proc.poll() is None, "the run ended before it could be killed"
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        before = read_session(out)
        n_before = len(before.poses)
        assert 10 <= n_before < 150
        res = acquire(load_config(run_cfg), out, resume=True, **kw)
    assert res.new_poses == 150 - n_before and res.recorded == 150
    s = read_session(out)
    assert sorted(p.index for p in s.poses) == list(range(150))
    assert not s.torn_tail
    # the completed session is exactly the uninterrupted run's plan (same P0 and seed)
    plan = make_plan("eq14", np.asarray(s.header["plan"]["p0"]), 150, 1, 100.0, 10.0)
    got = np.stack([p.commanded for p in sorted(s.poses, key=lambda p: p.index)])
    np.testing.assert_allclose(got, plan, atol=1e-9)
    # poses recorded before the kill are untouched
    for a, b in zip(before.poses, s.poses[:n_before]):
        np.testing.assert_array_equal(a.B, b.B)


@pytest.mark.e2e
def test_stop_request_leaves_resumable_session(tmp_path, mock_config):
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           plan={"poses": 12}, sampling={"samples": 5})
    cfg = load_config(cfg_path)
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        kw = endpoints_kwargs(mr.endpoints)
        calls = []
        res = acquire(cfg, out, should_stop=lambda: len(calls) >= 5,
                      progress=SeenPoses(calls), **kw)
        assert res.stopped and res.recorded == 5
        res2 = acquire(cfg, out, resume=True, **kw)
        assert res2.new_poses == 7 and res2.recorded == 12 and not res2.stopped


@pytest.mark.e2e
def test_tracker_faults_end_in_complete_session(tmp_path, mock_config):
    cfg_path = mock_config(
        "mock-denso-polaris.yaml", robot={"port": 0}, plan={"poses": 20},
        sampling={"samples": 10, "min_share": 0.6},
        tracker={"options": {"timeout_s": 0.3, "retries": 5}},
        mock={"tracker": {"model": "spectra",
                          "faults": {"crc_error_prob": 0.05, "drop_reply_prob": 0.02,
                                     "missing_fraction": 0.15,
                                     "ir_interference_fraction": 0.05}}})
    cfg = load_config(cfg_path)
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        res = acquire(cfg, out, **endpoints_kwargs(mr.endpoints))
    assert res.total == 20 and res.recorded + res.skipped == 20 and res.recorded >= 18
    s = read_session(out)
    # missing frames were dropped: fewer than 10 marker samples at some poses
    assert min(p.samples["B"] for p in s.poses if p.skipped is None) < 10


@pytest.mark.e2e
def test_tool_missing_everywhere_is_skipped_with_reason(tmp_path, mock_config):
    cfg_path = mock_config(
        "mock-denso-polaris.yaml", robot={"port": 0}, plan={"poses": 3},
        sampling={"samples": 5},
        mock={"tracker": {"model": "spectra", "faults": {"missing_fraction": 1.0}}})
    cfg = load_config(cfg_path)
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        res = acquire(cfg, tmp_path / "s.jsonl", **endpoints_kwargs(mr.endpoints))
    assert res.skipped == 3 and res.recorded == 0
    s = read_session(tmp_path / "s.jsonl")
    assert "marker seen in 0 of 5 frames" in s.poses[0].skipped


@pytest.mark.e2e
def test_dropped_robot_connection_is_reconnected(tmp_path, mock_config):
    cfg_path = mock_config(
        "mock-denso-polaris.yaml", robot={"port": 0}, plan={"poses": 10},
        sampling={"samples": 5}, run={"retries": 2, "reconnect_wait_s": 0.05},
        mock={"robot": {"faults": {"drop_at_request": 60}}})
    cfg = load_config(cfg_path)
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        res = acquire(cfg, out, **endpoints_kwargs(mr.endpoints))
        assert mr.devices[-1].stats["dropped"] == 1
    assert res.faults == 1 and res.recorded == 10
    assert sorted(p.index for p in read_session(out).poses) == list(range(10))


@pytest.mark.e2e
def test_robot_fault_stops_cleanly_with_cause(tmp_path, mock_config):
    cfg_path = mock_config(
        "mock-denso-polaris.yaml", robot={"port": 0}, plan={"poses": 10},
        sampling={"samples": 5}, mock={"robot": {"faults": {"fail_move_at": 4}}})
    cfg = load_config(cfg_path)
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        with pytest.raises(AcquisitionStopped, match=r"pose 3: robot fault.*--resume"):
            acquire(cfg, out, **endpoints_kwargs(mr.endpoints))
        assert sorted(p.index for p in read_session(out).poses) == [0, 1, 2]
        res = acquire(cfg, out, resume=True, **endpoints_kwargs(mr.endpoints))
    assert res.recorded == 10


@pytest.mark.e2e
def test_ur_protective_stop_stops_cleanly(tmp_path, mock_config):
    cfg_path = mock_config(
        "mock-ur-polaris.yaml", plan={"poses": 8},
        sampling={"samples": 5}, mock={"robot": {"faults": {"protective_stop_at_move": 3}}})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        with pytest.raises(AcquisitionStopped, match=r"pose 2: robot fault.*PROTECTIVE"):
            acquire(load_config(cfg_path), out, **endpoints_kwargs(mp.endpoints))
    s = read_session(out)
    assert sorted(p.index for p in s.poses) == [0, 1]


@pytest.mark.e2e
def test_plan_outside_envelope_never_moves(tmp_path, mock_config):
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           plan={"poses": 50, "radius_mm": 100},
                           safety={"max_offset_mm": 60})
    cfg = load_config(cfg_path)
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        with pytest.raises(SafetyError, match=r"plan pose \d+ .* max_offset_mm 60"):
            acquire(cfg, out, **endpoints_kwargs(mr.endpoints))
        assert mr.devices[-1].stats["moves"] == 0
    assert not out.exists()


@pytest.mark.e2e
def test_mock_command_prints_json_endpoints_first(mock_config):
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0})
    proc = subprocess.Popen([sys.executable, "-m", "tmscal.cli", "mock", str(cfg_path),
                             "--json", "--transport", "pty"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        ep = json.loads(line)
        assert ep["tracker"].startswith("/dev/pts/")
        assert ep["robot"].startswith(f"{load_config(cfg_path).robot.host}:")
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0


@pytest.mark.e2e
def test_ur_dropped_connection_stops_cleanly_and_resumable(tmp_path, mock_config):
    """The UR mock closes every socket (and refuses reconnects) at the 3rd move: the run
    (in a child process, as ur_rtde may misbehave on a dropped link) ends with one error line
    naming the cause and the resume command, and the session keeps the poses before."""
    cfg = mock_config("mock-ur-polaris.yaml", plan={"poses": 8}, sampling={"samples": 5},
                      run={"retries": 2, "reconnect_wait_s": 0.1},
                      mock={"robot": {"faults": {"drop_connection_at_move": 3}}})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg, transport="pty") as mp:
        r = subprocess.run([sys.executable, "-m", "tmscal.cli", "acquire", str(cfg), "-o",
                            str(out), "--tracker-port", mp.endpoints["tracker"],
                            "--robot-host", mp.endpoints["robot"]],
                           capture_output=True, text=True, timeout=180)
    assert r.returncode == 1, r.stderr[-1000:]
    err = [ln for ln in r.stderr.splitlines() if ln.startswith("error: ")]
    assert len(err) == 1 and "connection is lost" in err[0] and "--resume" in err[0]
    assert "Traceback" not in r.stderr
    s = read_session(out)
    assert [p.index for p in s.poses] == [0, 1]


@pytest.mark.e2e
def test_ctrl_c_finishes_the_pose_and_exits_130(tmp_path, mock_config):
    cfg = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                      plan={"poses": 50}, sampling={"samples": 20, "settle_s": 0.1},
                      mock={"clock": "real"})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg, transport="pty") as mp:
        run_cfg = point_config(cfg, mp.endpoints)
        proc = subprocess.Popen([sys.executable, "-m", "tmscal.cli", "acquire", str(run_cfg),
                                 "-o", str(out)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        wait_for_lines(out, 3, proc, poll_s=0.02)  # header + 2 poses
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr[-1000:]
    assert "stopped early (resumable)" in stdout and "--resume" in stdout
    s = read_session(out)
    assert not s.torn_tail and 2 <= len(s.poses) < 50
    assert [p.index for p in s.poses] == list(range(len(s.poses)))


@pytest.mark.e2e
def test_resume_can_extend_the_plan(tmp_path, mock_config):
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           plan={"poses": 6}, sampling={"samples": 3})
    cfg = load_config(cfg_path)
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        kw = endpoints_kwargs(mr.endpoints)
        assert acquire(cfg, out, **kw).recorded == 6
        res = acquire(cfg, out, resume=True, poses=9, **kw)
        assert (res.new_poses, res.recorded, res.total) == (3, 9, 9)
        again = acquire(cfg, out, resume=True, **kw)  # nothing left; the length stays 9
        assert (again.new_poses, again.recorded, again.total) == (0, 9, 9)
    s = read_session(out)
    plan = make_plan("eq14", np.asarray(s.header["plan"]["p0"]), 9, 1, 100.0, 10.0)
    np.testing.assert_allclose(np.stack([p.commanded for p in s.poses]), plan, atol=1e-9)


@pytest.mark.e2e
def test_resume_reacquires_a_damaged_middle_line(tmp_path, mock_config):
    """A complete run whose MIDDLE line (pose 4 of 10) was damaged afterwards: `tmscal acquire
    --resume` acquires pose 4 again (at its planned pose) and nothing else, and the session
    then holds every planned index exactly once among its valid lines. (A resume that started
    after the highest index recorded would end "complete" with a hole at 4.)"""
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           plan={"poses": 10}, sampling={"samples": 3})
    out = tmp_path / "s.jsonl"

    def tmscal(*args: str) -> subprocess.CompletedProcess:
        r = subprocess.run([sys.executable, "-m", "tmscal.cli", "acquire", str(run_cfg), "-o",
                            str(out), *args], capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        return r

    with spawn_mock_rig(cfg_path, transport="tcp") as mp:
        run_cfg = point_config(cfg_path, mp.endpoints)
        tmscal()
        lines = out.read_bytes().split(b"\n")
        assert json.loads(lines[5])["index"] == 4  # line 1 is the header
        lines[5] = lines[5][: len(lines[5]) // 2]  # a torn write in the middle
        out.write_bytes(b"\n".join(lines))
        damaged = read_session(out)
        assert sorted(damaged.indices()) == [0, 1, 2, 3, 5, 6, 7, 8, 9]
        assert [no for no, _ in damaged.damaged] == [6]
        r = tmscal("--resume")
    assert "10 poses recorded" in r.stdout
    s = read_session(out)
    valid = [p.index for p in s.poses]
    assert sorted(valid) == list(range(10))  # every planned index, exactly once
    assert valid[-1] == 4  # the damaged pose, acquired again and appended
    assert [no for no, _ in s.damaged] == [6]  # the damaged line itself is left as it was
    plan = make_plan("eq14", np.asarray(s.header["plan"]["p0"]), 10, 1, 100.0, 10.0)
    np.testing.assert_allclose(s.poses[-1].commanded, plan[4], atol=1e-9)
    for a, b in zip(damaged.poses, s.poses[:9], strict=True):  # the others untouched
        assert a.index == b.index
        np.testing.assert_array_equal(a.B, b.B)
