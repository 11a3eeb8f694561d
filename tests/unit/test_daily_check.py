"""The daily check decides: ``tmscal solve SESSION --calib CALIB --tolerance-mm MM
--tolerance-deg DEG`` (tmscal.check.verdict): a PASS or FAIL line, the verdict in the
JSON, exit status 0 or 3. One simulated rig: a calibration solved on its first 60 poses is
checked on its next 40 (the same rig: within 1 mm and 0.5°) and on those 40 as a tracker
bumped by 3 mm and 1° sees them (the rig moved: over both). Poses 4×4 mm."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.check import verdict
from tmscal.cli import main
from tmscal.errors import CalibrationError
from tmscal.geometry import make_pose, rot_x
from tmscal.session import read_session, write_session

EXIT_FAIL = 3


def _run(*args: object) -> tuple[int, str]:
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.output


@pytest.fixture(scope="module")
def rig(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("daily")
    code, out = _run("simulate", "-o", d / "all.jsonl", "--poses", 100, "--seed", 4,
                     "--samples", 10)
    assert code == 0, out
    s = read_session(d / "all.jsonl")
    write_session(d / "calib.jsonl", s.header, s.poses[:60])
    write_session(d / "today.jsonl", s.header, s.poses[60:])
    # the tracker bumped: it sees every tool through D (3 mm, 1°), i.e. Z became Z D⁻¹
    D = make_pose(rot_x(np.radians(1.0)), [3.0, 0.0, 0.0])
    bumped = [replace(p, B=D @ p.B, C=D @ p.C) for p in s.poses[60:]]
    write_session(d / "bumped.jsonl", s.header, bumped)
    # a daily session that tracked the marker only (no probe on the coil today)
    write_session(d / "marker.jsonl", {**s.header, "bodies": ["marker"]},
                  [replace(p, C=None) for p in s.poses[60:]])
    # one pose of today's session with its marker knocked by 2 mm: session pose index 70, the
    # 11th pose of the file
    knocked = [replace(p, B=p.B @ make_pose(np.eye(3), [2.0, 0.0, 0.0])) if p.index == 70
               else p for p in s.poses[60:]]
    write_session(d / "knocked.jsonl", s.header, knocked)
    code, out = _run("solve", d / "calib.jsonl", "-o", d / "cal.yaml", "--folds", 2)
    assert code == 0, out
    return ({k: d / f"{k}.jsonl" for k in ("today", "bumped", "marker", "knocked")}
            | {"cal": d / "cal.yaml"})


@pytest.mark.parametrize("command", ["check", "solve"])
def test_same_rig_passes_a_moved_tracker_fails(rig, command) -> None:
    code, out = _run(command, rig["today"], "--calib", rig["cal"], "--tolerance-mm", 1,
                     "--tolerance-deg", 0.5)
    assert code == 0, out
    last = out.strip().splitlines()[-1]
    assert last.startswith("PASS: e_t ") and "≤ 1 mm" in last and "≤ 0.5°" in last, last
    code, out = _run(command, rig["bumped"], "--calib", rig["cal"], "--tolerance-mm", 1,
                     "--tolerance-deg", 0.5)
    assert code == EXIT_FAIL, out
    last = out.strip().splitlines()[-1]
    assert last.startswith("FAIL: e_t ") and "> 1 mm" in last and "> 0.5°" in last, last
    assert "what moved" in last


@pytest.mark.parametrize("args", [
    ["today", "--tolerance-mm", 1],
    ["bumped", "--tolerance-mm", 1, "--json"],
    ["bumped", "--update", "z"],
    ["bumped", "--update", "x", "--json"],
])
def test_check_and_solve_calib_are_the_same_command(rig, args) -> None:
    """``tmscal check`` and its alias ``tmscal solve --calib``: the same output and exit
    status, for a verdict, the JSON and a re-registration (accepted or refused)."""
    rest = [rig[args[0]], "--calib", rig["cal"], *args[1:]]
    as_check, as_solve = _run("check", *rest), _run("solve", *rest)
    assert as_check == as_solve
    assert as_check[0] in (0, EXIT_FAIL) and as_check[1].strip()


def test_check_refuses_what_only_a_solve_does(rig) -> None:
    """``tmscal check`` has no fitting options, and needs the calibration to check."""
    code, out = _run("check", rig["today"], "--method", "qr24", "--calib", rig["cal"])
    assert code == 2 and "--method" in out
    code, out = _run("check", rig["today"])
    assert code == 2 and "--calib" in out


def test_json_carries_the_verdict_and_the_exit_status_follows_it(rig) -> None:
    code, out = _run("solve", rig["bumped"], "--calib", rig["cal"], "--json",
                     "--tolerance-mm", 1)
    assert code == EXIT_FAIL, out
    v = json.loads(out)["verdict"]
    assert v["result"] == "FAIL" and v["failed"] == ["e_t_mm"]
    assert v["tolerance_mm"] == 1 and v["tolerance_deg"] is None and v["e_t_mm"] > 1
    code, out = _run("solve", rig["today"], "--calib", rig["cal"], "--json",
                     "--tolerance-deg", 0.5)
    assert code == 0, out
    v = json.loads(out)["verdict"]
    assert v["result"] == "PASS" and v["failed"] == [] and v["theta_t_deg"] <= 0.5
    code, out = _run("solve", rig["today"], "--calib", rig["cal"], "--json")
    assert code == 0 and json.loads(out)["verdict"] is None  # no tolerance: no verdict


@pytest.mark.parametrize("args, hint", [
    (["--tolerance-mm", "1"], "--tolerance-mm"),          # not a check: nothing to decide
    (["--calib", "CAL", "--tolerance-mm", "0"], "--tolerance-mm"),
    (["--calib", "CAL", "--tolerance-deg", "nan"], "--tolerance-deg"),
])
def test_tolerance_refusals_name_the_option(rig, args, hint) -> None:
    code, out = _run("solve", rig["today"], *[str(rig["cal"]) if a == "CAL" else a
                                              for a in args])
    assert code == 2 and hint in out and len(out.strip().splitlines()) == 1, out


def test_verdict_rule_each_total_within_its_tolerance() -> None:
    errs = {"e_t_mm": 0.8, "theta_t_deg": 0.3}
    assert verdict(errs) is None
    assert verdict(errs, 0.8)["result"] == "PASS"           # at the tolerance: within it
    assert verdict(errs, 0.79)["failed"] == ["e_t_mm"]
    assert verdict(errs, None, 0.2)["failed"] == ["theta_t_deg"]
    assert verdict(errs, 0.5, 0.2)["failed"] == ["e_t_mm", "theta_t_deg"]
    assert verdict({"e_t_mm": float("nan"), "theta_t_deg": 0.1}, 1.0)["result"] == "FAIL"
    with pytest.raises(CalibrationError, match="tolerance_mm"):
        verdict(errs, -1.0)


def _row(out: str, label: str) -> list[float]:
    """The numbers of the check table's row that starts with ``label``."""
    line = next(ln for ln in out.splitlines() if ln.strip().startswith(label))
    return [float(x) for x in line[len(line) - len(line.lstrip()) + len(label):].split()
            if x[0].isdigit()]


def test_marker_only_session_is_compared_with_the_stored_marker_row(rig) -> None:
    """A session without the probe has a marker-only total: it stands beside the stored
    marker row (like with like), not the stored two-body total, and the output says so; a
    two-body session's total stands beside the stored total."""
    stored = yaml.safe_load(rig["cal"].read_text())["errors"]
    code, out = _run("solve", rig["marker"], "--calib", rig["cal"])
    assert code == 0, out
    total = _row(out, "total  e_t, θ_t (marker only)")
    marker = _row(out, "marker")
    assert total[:2] == marker[:2]  # the session's total is the marker's alone
    assert total[2:] == [round(stored["marker"]["trans_mm"], 4),
                         round(stored["marker"]["rot_deg"], 4)]
    # the stored two-body total is larger: beside it a marker-only total looks too good
    assert total[2] < round(stored["e_t_mm"], 4)
    assert "stands beside the stored marker row" in " ".join(out.split())
    code, out = _run("solve", rig["today"], "--calib", rig["cal"])
    assert code == 0, out
    assert _row(out, "total  e_t, θ_t")[2:] == [round(stored["e_t_mm"], 4),
                                                 round(stored["theta_t_deg"], 4)]
    assert "marker only" not in out


def test_outlier_poses_are_labelled_as_session_pose_indices(rig) -> None:
    """The knocked pose is named by its session pose index (70), not by its place in the
    file (the 11th) nor read as a count."""
    code, out = _run("solve", rig["knocked"], "--calib", rig["cal"])
    assert code == 0, out
    assert "  outlier poses (session pose index): 70\n" in out
    code, out = _run("solve", rig["today"], "--calib", rig["cal"])
    assert "  outlier poses (session pose index): none\n" in out
