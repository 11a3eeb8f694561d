"""End to end on the mocks (docs/lab-day.md): a calibration solved on the UR + Polaris mock
rig; the mock's tracker then stands 2 mm and 0.5° elsewhere (``mock.changes``, the rig's own
rule); the daily check ``tmscal solve TODAY --calib CAL`` names the tracker, ``--update z``
re-registers it from today's 10 poses, and a later session on the moved rig checks clean
against the updated calibration, whose Z is the moved tracker's within the noise. Every
session is acquired through the real drivers and wire protocols (a child process serves the
mock devices)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from tests.rigs import endpoints_kwargs
from tmscal.acquisition.run import acquire
from tmscal.cli import main
from tmscal.config import load_config
from tmscal.formats.calibfile import load_calibration
from tmscal.geometry import rotation_angle
from tmscal.mocks.launch import build_sim_rig, spawn_mock_rig
from tmscal.session import read_session

CHANGE = {"mm": [2.0, 0.0, 0.0], "deg": [0.0, 0.0, 0.5]}


def _run(*args: object) -> tuple[int, str]:
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.output


def _acquire(cfg_path, out) -> None:
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        res = acquire(load_config(cfg_path), out, **endpoints_kwargs(mp.endpoints))
    assert res.skipped == 0


def _calibrate(tmp_path, mock_config) -> None:
    """The calibration of the unchanged mock rig: calib.jsonl (25 poses) solved to cal.yaml."""
    base = mock_config("mock-ur-polaris.yaml", plan={"poses": 25, "seed": 1},
                       sampling={"samples": 10})
    _acquire(base, tmp_path / "calib.jsonl")
    code, out = _run("solve", tmp_path / "calib.jsonl", "-o", tmp_path / "cal.yaml",
                     "--folds", 2)
    assert code == 0, out


@pytest.mark.e2e
def test_a_moved_tracker_is_named_repaired_and_then_passes(tmp_path, mock_config) -> None:
    _calibrate(tmp_path, mock_config)
    moved = {"changes": {"tracker": CHANGE}}
    today = mock_config("mock-ur-polaris.yaml", plan={"poses": 10, "seed": 2},
                        sampling={"samples": 10}, mock=moved)
    _acquire(today, tmp_path / "today.jsonl")
    code, out = _run("solve", tmp_path / "today.jsonl", "--calib", tmp_path / "cal.yaml",
                     "--json")
    d = json.loads(out)["diagnosis"]
    assert code == 0 and d["changed"] == "tracker", d
    assert abs(d["delta_deg"] - 0.5) < 4 * d["sigma"]["deg"] + 0.01, d
    code, out = _run("solve", tmp_path / "today.jsonl", "--calib", tmp_path / "cal.yaml",
                     "--update", "z", "-o", tmp_path / "cal-z.yaml")
    assert code == 0, out
    truth = build_sim_rig(load_config(today)).truth          # the moved rig
    Z = load_calibration(tmp_path / "cal-z.yaml").Z
    dt = float(np.linalg.norm(Z[:3, 3] - truth.Z[:3, 3]))
    dr = math.degrees(float(rotation_angle(Z[:3, :3].T @ truth.Z[:3, :3])))
    assert dt < 0.5 and dr < 0.05, (dt, dr)                  # as a full solve gets it
    later = mock_config("mock-ur-polaris.yaml", plan={"poses": 10, "seed": 3},
                        sampling={"samples": 10}, mock=moved)
    _acquire(later, tmp_path / "later.jsonl")
    code, out = _run("solve", tmp_path / "later.jsonl", "--calib", tmp_path / "cal-z.yaml",
                     "--json")
    j = json.loads(out)
    assert j["diagnosis"]["changed"] == "none", j["diagnosis"]
    code, out = _run("solve", tmp_path / "later.jsonl", "--calib", tmp_path / "cal-z.yaml",
                     "--tolerance-mm", j["suggested_tolerances"]["tolerance_mm"])
    assert code == 0 and out.strip().splitlines()[-1].startswith("PASS"), out


@pytest.mark.e2e
def test_acquire_update_re_registers_a_moved_tracker_at_the_rig(tmp_path, mock_config) -> None:
    """``acquire --calib CAL --update z``: a few well-spread poses around the calibration's P0
    until the update's predicted coil placement meets the target, then the updated calibration,
    whose Z is the moved tracker's; a later session on the moved rig checks clean against it."""
    _calibrate(tmp_path, mock_config)
    moved = {"changes": {"tracker": CHANGE}}
    today = mock_config("mock-ur-polaris.yaml", plan={"seed": 2}, sampling={"samples": 10},
                        mock=moved)
    with spawn_mock_rig(today, transport="pty") as mp:
        code, out = _run("acquire", today, "-o", tmp_path / "today.jsonl", "--calib",
                         tmp_path / "cal.yaml", "--update", "z", "--target-mm", 0.1,
                         "--tracker-port", mp.endpoints["tracker"],
                         "--robot-host", mp.endpoints["robot"])
    assert code == 0, out
    s = read_session(tmp_path / "today.jsonl")
    assert 3 <= len(s.poses) <= 10, out                        # min_poses(z) … max_poses
    cal_p0 = np.asarray(read_session(tmp_path / "calib.jsonl").header["plan"]["p0"])
    assert np.abs(np.asarray(s.header["plan"]["p0"]) - cal_p0).max() < 1e-9
    truth = build_sim_rig(load_config(today)).truth          # the moved rig
    new = load_calibration(tmp_path / "today.yaml")
    # the coil placed by the updated calibration: targets T (tracker ← coil) where the coil
    # truly is at the session's poses; the flange commanded Z̃ T Ỹ⁻¹; the coil truly ends up
    # at Z⁻¹ F Y (Z, Y: the moved rig's truth)
    A = np.stack([p.commanded for p in s.poses])
    T = np.linalg.inv(truth.Z) @ A @ truth.Y
    F = new.Z @ T @ np.linalg.inv(new.Y)
    got = np.linalg.inv(truth.Z) @ F @ truth.Y
    placement = np.linalg.norm(got[:, :3, 3] - T[:, :3, 3], axis=1)
    assert placement.mean() < 0.1 and placement.max() < 0.2, placement
    later = mock_config("mock-ur-polaris.yaml", plan={"poses": 10, "seed": 3},
                        sampling={"samples": 10}, mock=moved)
    _acquire(later, tmp_path / "later.jsonl")
    code, out = _run("solve", tmp_path / "later.jsonl", "--calib", tmp_path / "today.yaml",
                     "--json")
    assert json.loads(out)["diagnosis"]["changed"] == "none", out


@pytest.mark.parametrize("args,hint", [
    (["--update", "z"], "--calib"),
    (["--update", "q", "--calib", "CAL"], "--update"),
    (["--update", "z", "--calib", "CAL", "--poses", "5"], "--poses"),
    (["--update-output", "x.yaml"], "--update-output"),
])
def test_acquire_update_refuses_bad_requests_before_connecting(tmp_path, mock_config, args,
                                                               hint) -> None:
    """Each a clear error naming the option, nothing connected (no mock runs) or written."""
    cfg = mock_config("mock-ur-polaris.yaml")
    cal = tmp_path / "cal.yaml"
    cal.write_text("not: a calibration\n")
    code, out = _run("acquire", cfg, "-o", tmp_path / "s.jsonl",
                     *[str(cal) if a == "CAL" else a for a in args])
    assert code != 0 and hint in out, out
    assert not (tmp_path / "s.jsonl").exists()
