"""The verdict the HTML report opens with (``tmscal report``, ``tmscal.report.verdict``;
docs/report.md, "The verdict"), on sessions of the simulated rig solved by the solve service.

Every number the verdict prints is checked against the same quantity worked out here by
another route: the held-out errors by cross-validating the calibration with ``calib.solve``
on contiguous folds, the predicted coil-placement error by ``predict_calibration``, the
adaptive run's usable poses and robot time from what the test put into the session, the
stored calibration's PASS or FAIL from the daily check (``tmscal solve --calib``). Lengths in
mm, angles in degrees; A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tests.rigs import simulated
from tests.unit.test_kinematics_use import _session as arm_session
from tmscal import solving
from tmscal.calib import solve
from tmscal.calib.prediction import AdaptiveSettings
from tmscal.check import verdict
from tmscal.cli import main
from tmscal.report.verdict import verdict_rows
from tmscal.session import Session, make_header, read_session, records_from_arrays, write_session
from tmscal.solving import adaptive_header
from tmscal.solving.predict import predict_calibration

N_POSES = 40
FOLDS = 5


def _write(path: Path, seed: int, truth=None, **header) -> Path:
    """A session of N_POSES Eq. 14 poses of the simulated rig (the paper's noise, ``truth``
    random from ``seed`` unless given), the header carrying the truth (and ``header``)."""
    truth, d = simulated(N_POSES, seed=seed, truth=truth)
    write_session(path, make_header(["marker", "probe"], truth=truth.as_dict(), **header),
                  records_from_arrays(d["A"], d["marker"], d["probe"], d["commanded"]))
    return path


def _cross_validated(session: Session, method: str = "qr36") -> dict[str, float]:
    """Total e_t (mm) and θ_t (deg), the mean over FOLDS contiguous folds of the calibration
    solved on the other poses (Wang et al. 2018's errors, ``Calibration.errors``)."""
    A, B, C, _ = session.arrays(need_probe=True)
    e_t, th_t = [], []
    for test in np.array_split(np.arange(len(A)), FOLDS):
        train = np.setdiff1d(np.arange(len(A)), test)
        e = solve(A[train], B[train], C[train], method=method).errors(A[test], B[test], C[test])
        e_t.append(e["e_t_mm"])
        th_t.append(e["theta_t_deg"])
    return {"e_t_mm": float(np.mean(e_t)), "theta_t_deg": float(np.mean(th_t))}


def _number_after(label: str, line: str) -> float:
    m = re.search(re.escape(label) + r"\s*([0-9.]+(?:e[-+]?\d+)?)", line)
    assert m, f"no number after {label!r} in {line!r}"
    return float(m.group(1))


def _predicted_mm(rows: list[str]) -> float:
    (line,) = [r for r in rows if r.startswith("predicted coil-placement error:")]
    return _number_after("predicted coil-placement error:", line)


class _VerdictItems(HTMLParser):
    """The section ids of a page in order, and the text of each <li> of its verdict
    section."""

    def __init__(self) -> None:
        super().__init__()
        self.sections: list[str] = []
        self.items: list[str] = []
        self._li = False

    def handle_starttag(self, tag, attrs):
        if tag == "section":
            self.sections.append(dict(attrs).get("id", ""))
        elif tag == "li" and self.sections[-1:] == ["verdict"]:
            self._li = True
            self.items.append("")

    def handle_endtag(self, tag):
        if tag == "li":
            self._li = False

    def handle_data(self, data):
        if self._li:
            self.items[-1] += data


def _report(args: list[str]) -> _VerdictItems:
    out = Path(args[args.index("-o") + 1])
    r = CliRunner().invoke(main, ["report", *args])
    assert r.exit_code == 0, r.output
    p = _VerdictItems()
    p.feed(out.read_text(encoding="utf-8"))
    return p


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """(path, session, calibration, result, independent errors) of a QR36 solve of a
    simulated session without an adaptive run and without an arm."""
    path = _write(tmp_path_factory.mktemp("verdict") / "s.jsonl", seed=3)
    session = read_session(path)
    res = solving.solve(session, method="qr36", folds=FOLDS)
    cal = res.calibration
    return path, session, cal, res, _cross_validated(session)


# --- the held-out errors against the tolerance ------------------------------------------------

@pytest.mark.parametrize("mm, deg, result, failed", [
    (1.02, 1.02, "PASS", []),
    (0.98, 1.02, "FAIL", ["e_t"]),
    (1.02, 0.98, "FAIL", ["θ_t"]),
    (0.98, None, "FAIL", ["e_t"]),
    (None, 1.02, "PASS", []),
])
def test_pass_or_fail_against_tolerances_just_above_and_below_the_errors(
        plain, mm, deg, result, failed) -> None:
    """Tolerances 2 % above or below the independently cross-validated totals: the first line
    is the daily check's decision, each judged total beside its tolerance with ≤ or >, the
    unjudged one left out."""
    _, session, _, res, cv = plain
    tol_mm = None if mm is None else mm * cv["e_t_mm"]
    tol_deg = None if deg is None else deg * cv["theta_t_deg"]
    first = verdict_rows(res, verdict(res.errors, tol_mm, tol_deg), session)[0]
    assert first.split(":")[0] == result
    for label, unit, tol, value in (("e_t", " mm", tol_mm, cv["e_t_mm"]),
                                    ("θ_t", "°", tol_deg, cv["theta_t_deg"])):
        if tol is None:
            assert f"{label} " not in first
            continue
        m = re.search(re.escape(label) + r" ([0-9.]+)" + re.escape(unit) + r" ([≤>]) ([0-9.]+)",
                      first)
        assert m, first
        assert float(m.group(1)) == pytest.approx(value, abs=5e-5)
        assert m.group(2) == (">" if label in failed else "≤")
        assert float(m.group(3)) == pytest.approx(tol, rel=1e-5)
    assert f"{N_POSES} poses" in first and "cross-validated" in first


def test_without_a_tolerance_the_totals_and_no_decision(plain) -> None:
    _, session, _, res, cv = plain
    first = verdict_rows(res, None, session)[0]
    assert not first.startswith(("PASS", "FAIL"))
    assert _number_after("e_t", first) == pytest.approx(cv["e_t_mm"], abs=5e-5)
    assert _number_after("θ_t", first) == pytest.approx(cv["theta_t_deg"], abs=5e-5)
    assert "no tolerance given" in first


@pytest.mark.parametrize("above", [True, False])
def test_the_page_opens_with_the_verdict(plain, tmp_path, above) -> None:
    """``tmscal report --tolerance-mm``: the first section is the verdict; its first item is
    PASS for a tolerance just above the cross-validated e_t, FAIL just below, and the
    prediction it shows is the calibration's (``predict_calibration``)."""
    path, session, cal, res, cv = plain
    tol = cv["e_t_mm"] * (1.02 if above else 0.98)
    page = _report([str(path), "--tolerance-mm", f"{tol:.6f}", "-o", str(tmp_path / "r.html")])
    assert page.sections[0] == "verdict"
    first = page.items[0]
    assert first.startswith("PASS:" if above else "FAIL:"), first
    assert _number_after("e_t", first) == pytest.approx(cv["e_t_mm"], abs=5e-5)
    pred = predict_calibration(session, cal, res.n_solve)[0]
    assert _predicted_mm(page.items) == pytest.approx(pred.coil_mm, rel=6e-3)


# --- the predicted coil-placement error -------------------------------------------------------

@pytest.mark.parametrize("method", ["qr36", "ml"])
def test_the_prediction_is_the_one_of_the_calibration_shown(plain, method) -> None:
    """The number is the coil-placement error ``predict_calibration`` predicts for this
    calibration (its method) at the settings' confidence (95 % by default), printed to 3
    significant digits."""
    _, session, _, _, _ = plain
    res = solving.solve(session, method=method, folds=FOLDS)
    cal = res.calibration
    pred, _ = predict_calibration(session, cal, res.n_solve)
    rows = verdict_rows(res, None, session)
    assert _predicted_mm(rows) == pytest.approx(pred.coil_mm, rel=6e-3)
    (line,) = [r for r in rows if r.startswith("predicted coil-placement error:")]
    assert f"at {pred.confidence * 100:g} %" in line


# --- the adaptive run -------------------------------------------------------------------------

def test_a_fixed_plan_is_named_not_adaptive(plain) -> None:
    _, session, _, res, _ = plain
    rows = verdict_rows(res, None, session)
    assert any(r.startswith("acquisition: not an adaptive run") for r in rows)


@pytest.fixture(scope="module")
def adaptive(tmp_path_factory):
    """An adaptive session written by hand: the header's ``adaptive`` entry (confidence 90 %,
    at most 60 poses), each pose's robot time by phase (random, s), poses 5 and 17 skipped.
    Returns (path, settings, the usable poses, the total robot time s)."""
    d = tmp_path_factory.mktemp("adaptive")
    src = read_session(_write(d / "fixed.jsonl", seed=5))
    settings = AdaptiveSettings(target_mm=0.05, confidence=0.9, max_poses=60, pool=300,
                                region=100)
    rng = np.random.default_rng(8)
    poses, total = [], 0.0
    for p in src.poses:
        t = {k: float(rng.uniform(0.2, 3.0)) for k in ("moving", "settling", "sampling")}
        total += sum(t.values())
        p = replace(p, robot_s=t)
        if p.index in (5, 17):
            p = replace(p, B=None, C=None, skipped="marker not visible")
        poses.append(p)
    header = {**src.header, "adaptive": adaptive_header(settings)}
    path = write_session(d / "adaptive.jsonl", header, poses)
    return path, settings, N_POSES - 2, total


@pytest.mark.parametrize("reached", [True, False])
def test_the_adaptive_run_its_target_against_the_prediction(adaptive, tmp_path, reached) -> None:
    """The target set 1.5 times above or half the calibration's prediction: the line says
    whether the prediction reaches it, with the run's confidence, its usable poses against
    max_poses and the robot time summed over the poses' phases."""
    path, settings, usable, total_s = adaptive
    session = read_session(path)
    res = solving.solve(session, method="qr36", folds=FOLDS)
    cal = res.calibration
    pred = predict_calibration(session, cal, res.n_solve)[0]
    assert pred.confidence == settings.confidence  # the header's settings are the prediction's
    target = pred.coil_mm * (1.5 if reached else 0.5)
    header = {**session.header, "adaptive": {**session.header["adaptive"], "target_mm": target}}
    rows = verdict_rows(res, None, replace(session, header=header))
    assert _predicted_mm(rows) == pytest.approx(pred.coil_mm, rel=6e-3)
    (line,) = [r for r in rows if r.startswith("acquisition:")]
    assert "an adaptive run" in line
    assert _number_after("target", line) == pytest.approx(target, rel=1e-5)
    assert "at 90 %" in line
    assert re.search(rf"\b{usable} usable poses of at most {settings.max_poses}\b", line), line
    assert _number_after("robot time", line) == pytest.approx(total_s, abs=0.051)
    if reached:
        assert "reaches the target" in line and "over the target" not in line
    else:
        assert "over the target" in line and "reaches the target" not in line


# --- the arm ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def arm_rig(tmp_path_factory):
    """A session of a VS-060 whose geometry has hidden errors (every parameter, ±2 mm / ±1°;
    the joints recorded, the header naming the arm): (path, rig)."""
    path = tmp_path_factory.mktemp("arm") / "vs060.jsonl"
    rig = arm_session(path, n=24)
    return path, rig


def test_no_arm_the_controllers_poses(plain) -> None:
    _, session, _, res, _ = plain
    (line,) = [r for r in verdict_rows(res, None, session) if r.startswith("arm:")]
    assert line.startswith("arm: none")


def test_an_estimated_arm_is_named_with_its_level(arm_rig) -> None:
    path, _ = arm_rig
    session = read_session(path)
    res = solving.solve(session, method="ml", kinematics="estimate", level="offsets",
                             in_sample=True)
    cal = res.calibration
    rows = verdict_rows(res, None, session)
    (line,) = [r for r in rows if r.startswith("arm:")]
    assert line.startswith("arm: vs060")  # the arm the session header records
    assert "estimated" in line and "(level offsets)" in line  # the level asked for
    pred = predict_calibration(session, cal, res.n_solve)[0]
    assert _predicted_mm(rows) == pytest.approx(pred.coil_mm, rel=6e-3)


def test_an_arm_from_a_kinematics_file_is_named_with_the_file(arm_rig) -> None:
    """The rig's true VS-060 given as the kinematics (as a file of ``tmscal selfcal identify``
    would give it): the robot poses are recomputed from the joints with it."""
    path, rig = arm_rig
    session = read_session(path)
    true_arm = rig.arm.geometry()[1]
    res = solving.solve(session, method="qr36", folds=FOLDS, kinematics=true_arm,
                           kinematics_source="vs060-kin.yaml")
    (line,) = [r for r in verdict_rows(res, None, session) if r.startswith("arm:")]
    assert line.startswith("arm: vs060")
    assert "recomputed from the joints with vs060-kin.yaml" in line


# --- a stored calibration, judged as the daily check ------------------------------------------

@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """A QR36 calibration file solved on one session, a second session of the same rig, and
    the daily check's e_t of the stored calibration on it (``tmscal solve --calib --json``)."""
    d = tmp_path_factory.mktemp("stored")
    truth, _ = simulated(3, seed=30)
    first = _write(d / "monday.jsonl", seed=31, truth=truth)
    today = _write(d / "tuesday.jsonl", seed=32, truth=truth)
    cal = d / "cal.yaml"
    r = CliRunner().invoke(main, ["solve", str(first), "-o", str(cal)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["solve", str(today), "--calib", str(cal), "--json"])
    assert r.exit_code == 0, r.output
    return today, cal, json.loads(r.output)


@pytest.mark.parametrize("factor", [1.02, 0.98])
def test_a_stored_calibration_is_judged_as_the_daily_check(stored, tmp_path, factor) -> None:
    """``tmscal report TODAY --calib CAL --tolerance-mm T`` decides as ``tmscal solve TODAY
    --calib CAL --tolerance-mm T`` does, on the same e_t, every pose of TODAY held out, and
    predicts nothing for a stored calibration."""
    today, cal, check = stored
    e_t = check["errors"]["e_t_mm"]
    tol = f"{e_t * factor:.6f}"
    r = CliRunner().invoke(main, ["solve", str(today), "--calib", str(cal), "--tolerance-mm",
                                  tol, "--json"])
    decided = json.loads(r.output)["verdict"]["result"]
    assert decided == ("PASS" if factor > 1 else "FAIL")
    page = _report([str(today), "--calib", str(cal), "--tolerance-mm", tol,
                    "-o", str(tmp_path / "check.html")])
    assert page.sections[0] == "verdict"
    first = page.items[0]
    assert first.startswith(f"{decided}:"), first
    assert _number_after("e_t", first) == pytest.approx(e_t, abs=5e-5)
    assert f"{N_POSES} poses, every one held out" in first
    (line,) = [r for r in page.items if r.startswith("predicted coil-placement error:")]
    assert line.startswith("predicted coil-placement error: none")
