"""``tmscal solve`` predicts the coil-placement error of the calibration it solves
(tmscal.solving.predict.calibration_prediction) over the region its truth's coil placement
is measured on: the plan's first poses when the header records a plan, else the session's own
poses (issue 21). Sessions from ``tmscal simulate`` (the truth in the header)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.poses import PlanSpec
from tmscal.session import read_session
from tmscal.solving.predict import arm_error_counts, placement_region


def _simulate(path, *extra) -> None:
    r = CliRunner().invoke(main, ["simulate", "-o", str(path), "--poses", "40", "--seed",
                                  "5", *extra])
    assert r.exit_code == 0, r.output


def _solve_json(path) -> dict:
    r = CliRunner().invoke(main, ["solve", str(path), "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.output)


def test_prediction_over_the_sessions_own_poses_without_a_plan(tmp_path):
    p = tmp_path / "s.jsonl"
    _simulate(p)
    res = _solve_json(p)
    pred = res["prediction"]
    assert pred["confidence"] == 0.95 and pred["n_poses"] == 40
    assert "40 usable poses" in pred["region"]
    assert pred["region"] == res["truth"]["coil_placement_region"]
    assert res["truth"]["coil_placement_n"] == 40
    # the simulation's noise (robot 0.05 mm, 0.05° about a random axis: 0.029° per axis),
    # estimated from 40 poses' residuals to within 40 %
    assert pred["robot_sigma_mm"] == pytest.approx(0.05, rel=0.4)
    assert pred["robot_sigma_deg"] == pytest.approx(0.05 / np.sqrt(3), rel=0.4)
    assert pred["model_error_mm"] == 0.0 and pred["model_error"].startswith("none")
    # 40 poses of this noise: the true error of such a calibration is a few hundredths of
    # a mm (benchmarks/ml_selection.py), the 95 % prediction of ml's on the same order
    assert 0.01 < pred["coil_placement_mm"] < 0.2


def test_prediction_and_truth_over_the_plans_region(tmp_path):
    """A header with a plan: both the prediction and the truth's coil placement average over
    the plan's first 200 poses (AdaptiveSettings().region), the truth at the targets where
    the true rig would put the coil there."""
    src, p = tmp_path / "s.jsonl", tmp_path / "plan.jsonl"
    _simulate(src)
    lines = src.read_text().splitlines()
    header = json.loads(lines[0])
    A0 = np.asarray(json.loads(lines[1])["A"], dtype=float)
    header["plan"] = PlanSpec("eq14", 500, 1, 100.0, 10.0, A0).to_header()
    p.write_text("\n".join([json.dumps(header)] + lines[1:]) + "\n")
    session = read_session(p)
    region, where, from_plan = placement_region(session)
    assert from_plan and region.shape == (200, 4, 4) and "first 200 poses" in where
    assert not arm_error_counts(session)
    res = _solve_json(p)
    assert res["prediction"]["region"] == res["truth"]["coil_placement_region"] == where
    assert res["truth"]["coil_placement_n"] == 200
    assert 0 < res["prediction"]["coil_placement_mm"] < 0.3
