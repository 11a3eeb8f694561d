"""Where a calibration was made (``tmscal.safety.origin``, docs/safety.md): the distance rule,
the calibration file's ``p0`` section and its errors, the envelope of the way back, and the
P0 a run chooses with and without a calibration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.acquisition.dryrun import dry_run
from tmscal.acquisition.run import PlanStrategy
from tmscal.cli import main
from tmscal.config import load_config
from tmscal.errors import CalibrationError
from tmscal.formats.calibfile import read_calibration
from tmscal.geometry import make_pose
from tmscal.safety import Envelope
from tmscal.safety.origin import (
    P0_TOL_DEG,
    P0_TOL_MM,
    CalibratedP0,
    p0_distance,
    return_envelope,
    same_p0,
)
from tmscal.sim import TMS_RIG_P0


@pytest.fixture(scope="module")
def solved_calibration(tmp_path_factory) -> Path:
    """A calibration file ``tmscal solve -o`` wrote (of a simulated session)."""
    d = tmp_path_factory.mktemp("p0")
    for args in (["simulate", "-o", d / "s.jsonl", "--poses", 20, "--samples", 5],
                 ["solve", d / "s.jsonl", "-o", d / "cal.yaml", "--folds", 2]):
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exit_code == 0, r.output
    return d / "cal.yaml"


def _rot(axis: int, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _moved(P: np.ndarray, mm=(0.0, 0.0, 0.0), deg: float = 0.0, axis: int = 2) -> np.ndarray:
    """P translated by ``mm`` in the base frame and turned by ``deg`` about its own axis."""
    out = P @ make_pose(_rot(axis, deg), [0.0, 0.0, 0.0])
    out[:3, 3] += np.asarray(mm, dtype=float)
    return out


def test_distance_is_the_origins_and_the_rotation_angle() -> None:
    mm, deg = p0_distance(TMS_RIG_P0, _moved(TMS_RIG_P0, (3.0, 4.0, 0.0), 30.0, axis=0))
    assert mm == pytest.approx(5.0) and deg == pytest.approx(30.0)


@pytest.mark.parametrize("mm,deg,same", [
    (0.9 * P0_TOL_MM, 0.0, True), (1.1 * P0_TOL_MM, 0.0, False),
    (0.0, 0.9 * P0_TOL_DEG, True), (0.0, 1.1 * P0_TOL_DEG, False),
    (0.9 * P0_TOL_MM, 0.9 * P0_TOL_DEG, True)])
def test_the_same_place_is_within_both_tolerances(mm, deg, same) -> None:
    assert same_p0(TMS_RIG_P0, _moved(TMS_RIG_P0, (0.0, mm, 0.0), deg, axis=1)) is same


def test_region_from_a_plan_header_and_its_poses() -> None:
    poses = np.stack([_moved(TMS_RIG_P0, (10.0, 0.0, 0.0)), _moved(TMS_RIG_P0, (0.0, -20.0, 0.0)),
                      _moved(TMS_RIG_P0, deg=7.0)])
    plan = {"kind": "eq14", "radius_mm": 50.0, "rotation_deg": 10.0,
            "p0": TMS_RIG_P0.tolist()}
    o = CalibratedP0.from_plan(plan, poses)
    assert o.offset_max_mm == pytest.approx(20.0) and o.rotation_max_deg == pytest.approx(7.0)
    back = CalibratedP0.from_doc(yaml.safe_load(yaml.safe_dump(o.to_doc())))
    assert np.array_equal(back.pose, TMS_RIG_P0) and back.radius_mm == 50.0
    assert back.offset_max_mm == pytest.approx(20.0)
    with pytest.raises(ValueError, match="no plan with a P0"):
        CalibratedP0.from_plan({"kind": "eq14"})


@pytest.mark.parametrize("doc,key", [
    ({"pose": [[1, 0], [0, 1]], "plan": {"radius_mm": 1, "rotation_deg": 1}}, "p0.pose"),
    ({"pose": np.eye(4).tolist(), "plan": {"radius_mm": "far", "rotation_deg": 1}},
     "p0.plan.radius_mm"),
    ({"pose": np.eye(4).tolist()}, "p0.plan"),
    ({"pose": np.eye(4).tolist(), "plan": {"radius_mm": 1, "rotation_deg": 1},
      "extent": {"offset_max_mm": float("nan"), "rotation_max_deg": 1}},
     "p0.extent.offset_max_mm"),
])
def test_a_bad_p0_section_names_the_file_and_key(tmp_path, solved_calibration, doc,
                                                  key) -> None:
    d = yaml.safe_load(solved_calibration.read_text())
    d["p0"] = doc
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(d))
    with pytest.raises(CalibrationError, match=rf"bad\.yaml: key '{key}'"):
        read_calibration(bad)


def test_elsewhere_names_the_distance_and_the_fix() -> None:
    o = CalibratedP0(TMS_RIG_P0, "eq14", 50.0, 10.0)
    assert o.elsewhere(_moved(TMS_RIG_P0, (0.3, 0.0, 0.0)), "this session's P0") is None
    w = o.elsewhere(_moved(TMS_RIG_P0, (12.0, 0.0, 0.0), 2.0), "this session's P0")
    assert w is not None and "12.0 mm and 2.0°" in w and "--calib" in w


def test_the_way_back_is_allowed_and_nothing_else_is() -> None:
    env = Envelope(center=None, max_offset_mm=100.0, max_rotation_deg=20.0,
                   box_min_mm=(0.0, -600.0, 0.0), box_max_mm=(900.0, 600.0, 900.0))
    p0 = TMS_RIG_P0
    here = _moved(p0, (0.0, 150.0, 0.0), 30.0)          # beyond both limits of P0's envelope
    around = Envelope(**{**env.__dict__, "center": p0})
    assert around.violations(here)
    back = return_envelope(around, p0, here)
    for s in np.linspace(0.0, 1.0, 11):                 # every pose of the straight way back
        assert not back.violations(_moved(p0, (0.0, 150.0 * s, 0.0), 30.0 * s)), s
    assert back.violations(_moved(p0, (0.0, 160.0, 0.0)))        # no farther than here
    assert back.violations(_moved(p0, deg=35.0))
    assert back.violations(_moved(p0, (500.0, 0.0, 0.0)))        # the box stays
    assert back.max_speed_mm_s == around.max_speed_mm_s
    near = _moved(p0, (5.0, 0.0, 0.0), 2.0)             # from inside, the limits stay the config's
    assert return_envelope(around, p0, near).max_offset_mm == 100.0


def test_a_run_with_a_calibration_starts_at_its_p0(mock_config) -> None:
    cfg = load_config(mock_config("mock-ur-polaris.yaml"))
    o = CalibratedP0(_moved(TMS_RIG_P0, (20.0, 0.0, 0.0)), "eq14", 50.0, 10.0)
    s = PlanStrategy(cfg, origin=o)
    p0 = s.start_pose(None)        # type: ignore[arg-type]  (no robot is read)
    assert np.array_equal(p0, o.pose) and "the calibration's" in s.start_notes[0]
    assert "--move-to p0" in s.where_hint


def test_a_fixed_start_elsewhere_is_warned_about(mock_config) -> None:
    start = _moved(TMS_RIG_P0, (0.0, 0.0, 30.0))
    cfg = load_config(mock_config("mock-ur-polaris.yaml", plan={"start": start.tolist()}))
    s = PlanStrategy(cfg, origin=CalibratedP0(TMS_RIG_P0, "eq14", 50.0, 10.0))
    assert np.array_equal(s.start_pose(None), start)   # type: ignore[arg-type]
    assert s.start_notes[0].startswith("WARNING:") and "30.0 mm" in s.start_notes[0]


def test_dry_run_with_a_calibration_needs_no_robot_for_p0(mock_config) -> None:
    """With ``--calib`` and ``plan.start: current`` the dry run plans around the calibration's
    P0, which it knows without asking the robot (no mock is running here)."""
    cfg = load_config(mock_config("mock-ur-polaris.yaml", plan={"poses": 10}))
    o = CalibratedP0(TMS_RIG_P0, "eq14", 50.0, 10.0)
    d = dry_run(cfg, origin=o)
    assert d.p0_known and np.array_equal(d.spec.p0, TMS_RIG_P0) and "--calib" in d.p0_source
