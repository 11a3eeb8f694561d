"""The OpenIGTLink tracker on the mock rig, as a user runs it: `tmscal mock` serving
configs/mock-ur-igtl.yaml (a mock UR and a PlusServer-like OpenIGTLink mock, one sim rig) in a
child process, and `tmscal track`, `acquire`, `solve` and `demo` as commands in child
processes, through the real drivers and wire protocols (ur_rtde, OpenIGTLink over loopback
TCP). The sim rig's truth (X = flange_from_marker, Y = flange_from_probe, Z =
base_from_tracker, 4×4 mm) comes from the same config, as in tests/e2e/test_acquire.py. A
tool the source never sends, or re-sends stale, is a skipped sample, as with the NDI."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tmscal.acquisition.run import acquire
from tmscal.config import load_config
from tmscal.exports import load_calibration
from tmscal.geometry import angle_between
from tmscal.mocks.launch import build_sim_rig, spawn_mock_rig
from tmscal.session import read_session

from ..rigs import NOISE_FREE_MOCK, endpoints_kwargs
from .test_acquire import check_truth

pytestmark = pytest.mark.e2e

BASE = "mock-ur-igtl.yaml"


def _cli(*args: str | Path, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tmscal.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)


def _rig(mock_config, **changes) -> Path:
    """configs/mock-ur-igtl.yaml with every mock on an address of the test's own (the UR's
    fixed ports and the OpenIGTLink port bind there: ``tests.rigs.unique_addresses``),
    ``changes`` over it."""
    return mock_config(BASE, **changes)


def test_track_on_a_running_tmscal_mock_shows_the_true_tool_poses(mock_config):
    """`tmscal track` against `tmscal mock` serving the config's own host and port: the tools
    by their TRANSFORM names, and on a noise-free rig the marker and the probe where the sim
    rig puts them (tracker frame, mm; OpenIGTLink's float32 rounds at about 1e-4 mm)."""
    cfg_path = _rig(mock_config, mock={"noise": NOISE_FREE_MOCK})
    cfg = load_config(cfg_path)
    rig = build_sim_rig(cfg)  # the child builds the same rig from the same config
    with spawn_mock_rig(cfg_path, transport="config") as mp:
        assert mp.endpoints["tracker"] == cfg.tracker.settings.address()
        r = _cli("track", cfg_path, "--frames", "3", "--plain", timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "driver igtl" in r.stdout
    assert "tool marker   device MarkerToTracker" in r.stdout
    assert "tool probe    device ProbeToTracker" in r.stdout
    for body in ("marker", "probe"):
        rows = [ln.split() for ln in r.stdout.splitlines() if ln.startswith(f"  {body} ")]
        assert len(rows) == 3 and all(row[1] == "yes" for row in rows), r.stdout
        true_xyz = rig.true_body(body)[:3, 3]
        for row in rows:
            np.testing.assert_allclose([float(v) for v in row[2:5]], true_xyz, atol=0.006)


def test_acquire_then_solve_through_the_commands_recovers_the_truth(mock_config, tmp_path):
    """`tmscal acquire` on the running mock records every pose with the igtl driver's
    identity; `tmscal solve -o` writes a calibration whose X, Y and Z are the sim rig's truth
    (within the noise: 0.05 mm fiducials, 0.05 mm / 0.05° robot, 30 poses of 10 frames)."""
    cfg_path = _rig(mock_config, plan={"poses": 30}, sampling={"samples": 10})
    out, calib = tmp_path / "s.jsonl", tmp_path / "c.yaml"
    with spawn_mock_rig(cfg_path, transport="config"):
        r = _cli("acquire", cfg_path, "-o", out)
    assert r.returncode == 0, r.stderr[-2000:]
    s = read_session(out)
    tracker = s.header["devices"]["tracker"]
    assert tracker["driver"] == "igtl" and tracker["transform_status"] is True
    assert tracker["tools"] == {"marker": "MarkerToTracker", "probe": "ProbeToTracker"}
    assert len(s.poses) == 30 and all(p.skipped is None for p in s.poses)
    assert all(p.samples["B"] == 10 and p.samples["C"] == 10 for p in s.poses)
    check_truth(cfg_path, out, 30)

    r = _cli("solve", out, "-o", calib)
    assert r.returncode == 0, r.stderr[-2000:]
    cal, truth = load_calibration(calib), build_sim_rig(load_config(cfg_path)).truth
    for k, tol_mm in (("X", 0.5), ("Y", 0.5), ("Z", 1.0)):
        got, want = getattr(cal, k), getattr(truth, k)
        assert np.linalg.norm(got[:3, 3] - want[:3, 3]) < tol_mm, k
        assert np.degrees(angle_between(got, want)) < 0.1, k


@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_demo_json_on_the_igtl_config_recovers_the_truth(mock_config, transport):
    """`tmscal demo --config mock-ur-igtl.yaml --json`; with ``--transport pty`` the
    OpenIGTLink mock, which has no serial line, is still served on loopback TCP."""
    cfg = mock_config(BASE)
    r = _cli("demo", "--config", cfg, "--poses", "25", "--samples", "10", "--json",
             "--transport", transport)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res["method"] == "qr36" and res["n_solve"] == 25 and res["n_skipped"] == 0
    assert res["truth"]["coil_placement_mm"] < 0.3
    assert res["truth"]["Y"]["trans_mm"] < 0.5 and res["truth"]["X"]["trans_mm"] < 0.5


@pytest.mark.parametrize("fault", ["drop_tools", "stale_tools"])
def test_a_tool_never_sent_or_stale_is_skipped_with_the_reason(mock_config, tmp_path, fault):
    """A probe the source never sends (not among PlusServer's transform names) or re-sends
    with an old timestamp is missing from every frame: every pose is skipped, naming it."""
    cfg_path = _rig(mock_config, plan={"poses": 3}, sampling={"samples": 5},
                    mock={"tracker": {"faults": {fault: ["probe"]}}})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="config") as mp:
        res = acquire(load_config(cfg_path), out, **endpoints_kwargs(mp.endpoints))
    assert (res.recorded, res.skipped) == (0, 3)
    s = read_session(out)
    assert all("probe seen in 0 of 5 frames" in p.skipped for p in s.poses), \
        [p.skipped for p in s.poses]


def test_missing_tools_are_skipped_samples_and_the_session_completes(mock_config, tmp_path):
    """Tools missing from some frames (PlusServer's MISSING status, sent as invalid): those
    frames are skipped samples, the poses are recorded with fewer samples."""
    cfg_path = _rig(mock_config, plan={"poses": 10},
                    sampling={"samples": 10, "min_share": 0.5},
                    mock={"tracker": {"send_invalid": True,
                                      "faults": {"missing_fraction": 0.1}}})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="config") as mp:
        res = acquire(load_config(cfg_path), out, **endpoints_kwargs(mp.endpoints))
    assert (res.recorded, res.skipped, res.total) == (10, 0, 10)
    s = read_session(out)
    assert min(min(p.samples["B"], p.samples["C"]) for p in s.poses) < 10
