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
from tmscal.exports.calibfile import load_calibration
from tmscal.geometry import rotation_angle
from tmscal.mocks.launch import build_sim_rig, spawn_mock_rig

CHANGE = {"mm": [2.0, 0.0, 0.0], "deg": [0.0, 0.0, 0.5]}


def _run(*args: object) -> tuple[int, str]:
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.output


def _acquire(cfg_path, out) -> None:
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        res = acquire(load_config(cfg_path), out, **endpoints_kwargs(mp.endpoints))
    assert res.skipped == 0


@pytest.mark.e2e
def test_a_moved_tracker_is_named_repaired_and_then_passes(tmp_path, mock_config) -> None:
    base = mock_config("mock-ur-polaris.yaml", plan={"poses": 25, "seed": 1},
                       sampling={"samples": 10})
    _acquire(base, tmp_path / "calib.jsonl")
    code, out = _run("solve", tmp_path / "calib.jsonl", "-o", tmp_path / "cal.yaml",
                     "--folds", 2)
    assert code == 0, out
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
