"""``tmscal solve TODAY --calib CAL`` says what moved, and ``--update`` repairs it
(docs/lab-day.md). One simulated rig: a calibration solved on its first 60 poses (10 tracker
frames averaged per pose); "today" is 10 of the next poses as the unchanged rig, as a tracker
moved by 3 mm and 1°, and as that tracker move with the marker knocked on the coil as well;
"later" is the remaining poses of the moved rig, on which the updated calibration is checked.
The changes are applied here to the recorded tracker poses (the tracker moved by D sees every
tool through D), not by the code under test."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.formats.calibfile import read_calibration
from tmscal.geometry import make_pose, rot_x
from tmscal.session import read_session, sha256_of, write_session

EXIT_FAIL = 3
D = make_pose(rot_x(np.radians(1.0)), [3.0, 0.0, 0.0])   # the tracker's move
K = make_pose(rot_x(np.radians(0.3)), [0.5, 0.0, 0.0])   # the marker knocked on the coil


def _run(*args: object) -> tuple[int, str]:
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.output


@pytest.fixture(scope="module")
def rig(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("labday")
    code, out = _run("simulate", "-o", d / "all.jsonl", "--poses", 100, "--seed", 4,
                     "--samples", 10)
    assert code == 0, out
    s = read_session(d / "all.jsonl")
    write_session(d / "calib.jsonl", s.header, s.poses[:60])
    write_session(d / "today.jsonl", s.header, s.poses[60:70])
    write_session(d / "moved.jsonl", s.header,
                  [replace(p, B=D @ p.B, C=D @ p.C) for p in s.poses[60:70]])
    write_session(d / "two.jsonl", s.header,
                  [replace(p, B=D @ p.B @ K, C=D @ p.C) for p in s.poses[60:70]])
    write_session(d / "later.jsonl", s.header,
                  [replace(p, B=D @ p.B, C=D @ p.C) for p in s.poses[70:100]])
    code, out = _run("solve", d / "calib.jsonl", "-o", d / "cal.yaml", "--folds", 2)
    assert code == 0, out
    return {k: d / f"{k}.jsonl" for k in ("today", "moved", "two", "later")} | {
        "cal": d / "cal.yaml", "dir": d}


def _diagnosis(rig, name: str) -> dict:
    code, out = _run("solve", rig[name], "--calib", rig["cal"], "--json")
    assert code == 0, out
    return json.loads(out)


def test_the_calibration_file_stores_its_noise_model(rig) -> None:
    cf = read_calibration(rig["cal"])
    nm = cf.noise_model
    assert nm is not None and nm.bodies == ("marker", "probe") and nm.n_poses == 60
    assert nm.cal_cov is not None and nm.cal_blocks == ("z", "x", "y")
    # 10 frames of 0.05 mm fiducials and 0.05 mm / 0.05° of robot noise: residuals of a few
    # hundredths of a millimetre per axis
    assert 0.005 < nm.sigmas()["marker"]["mm"] < 0.2


def test_an_unchanged_rig_is_nothing_and_a_moved_tracker_is_the_tracker(rig) -> None:
    j = _diagnosis(rig, "today")
    assert j["diagnosis"]["changed"] == "none" and j["diagnosis"]["next_command"] is None
    tol = j["suggested_tolerances"]
    assert tol["n_poses"] == 10 and tol["tolerance_mm"] > j["errors"]["e_t_mm"]
    j = _diagnosis(rig, "moved")
    dx = j["diagnosis"]
    assert dx["changed"] == "tracker", dx
    assert abs(dx["delta_deg"] - 1.0) < 3 * dx["sigma"]["deg"] + 0.01
    assert abs(dx["delta_mm"] - 3.0) < 3 * dx["sigma"]["mm"] + 0.05
    assert dx["runner_up"] in ("coil", "marker", "coil_centre") and dx["evidence_ratio"] > 100
    assert "--update z" in dx["next_command"]
    code, out = _run("solve", rig["moved"], "--calib", rig["cal"])
    assert "what moved: the tracker moved" in out and "--update z" in out, out


def test_update_z_repairs_the_move_and_the_lineage_names_the_parent(rig) -> None:
    new = rig["dir"] / "cal-z.yaml"
    code, out = _run("solve", rig["moved"], "--calib", rig["cal"], "--update", "z", "-o", new)
    assert code == 0, out
    assert "z re-registered" in out and f"written to {new}" in out
    doc = yaml.safe_load(new.read_text())
    parent = yaml.safe_load(rig["cal"].read_text())
    assert doc["provenance"]["lineage"][0]["sha256"] == sha256_of(rig["cal"])
    assert doc["update"]["blocks"] == ["z"] and doc["X"] == parent["X"] and \
        doc["Y"] == parent["Y"] and doc["raw"]["X"] == parent["raw"]["X"]
    assert doc["Z"] != parent["Z"]
    # the updated calibration on later poses of the moved rig: nothing moved, and it passes
    # the tolerance it suggests for itself
    code, out = _run("solve", rig["later"], "--calib", new, "--json")
    j = json.loads(out)
    assert j["diagnosis"]["changed"] == "none", j["diagnosis"]
    code, out = _run("solve", rig["later"], "--calib", new, "--tolerance-mm",
                     j["suggested_tolerances"]["tolerance_mm"])
    assert code == 0 and out.strip().splitlines()[-1].startswith("PASS"), out
    # the parent itself fails there
    code, out = _run("solve", rig["later"], "--calib", rig["cal"], "--tolerance-mm",
                     j["suggested_tolerances"]["tolerance_mm"])
    assert code == EXIT_FAIL
    # an update of the update: the chain grows
    newer = rig["dir"] / "cal-zz.yaml"
    code, out = _run("solve", rig["later"], "--calib", new, "--update", "z", "-o", newer)
    assert code == 0, out
    chain = yaml.safe_load(newer.read_text())["provenance"]["lineage"]
    assert [c["sha256"] for c in chain] == [sha256_of(new), sha256_of(rig["cal"])]


def test_a_second_change_is_refused_and_nothing_is_written(rig) -> None:
    j = _diagnosis(rig, "two")
    assert j["diagnosis"]["changed"] == "unexplained"
    assert j["diagnosis"]["pair"] == ["tracker", "marker"], j["diagnosis"]
    out_file = rig["dir"] / "never.yaml"
    code, out = _run("solve", rig["two"], "--calib", rig["cal"], "--update", "z", "-o",
                     out_file)
    assert code == EXIT_FAIL and out.startswith("REFUSED: --update z") and "marker" in out
    assert not out_file.exists()
    code, out = _run("solve", rig["two"], "--calib", rig["cal"], "--update", "z", "--json")
    j = json.loads(out)
    assert code == EXIT_FAIL and j["diagnosis"]["changed"] == "unexplained"
    # both named: z and x
    code, out = _run("solve", rig["two"], "--calib", rig["cal"], "--update", "z",
                     "--update", "x", "--json")
    assert code == 0, out
    assert json.loads(out)["update"]["blocks"] == ["z", "x"]


@pytest.mark.parametrize("args, hint", [
    (["--update", "z"], "--update"),                                    # no --calib
    (["--calib", "CAL", "--update", "coil", "--update", "x"], "leave out"),
    (["--calib", "CAL", "--update", "z", "--method", "ml"], "--update"),
    (["--calib", "CAL", "--update", "z", "--tolerance-mm", "1"], "--tolerance"),
    (["--calib", "CAL", "--update", "q"], "--update"),
])
def test_bad_update_requests_are_named(rig, args, hint) -> None:
    code, out = _run("solve", rig["moved"], *[str(rig["cal"]) if a == "CAL" else a
                                              for a in args])
    assert code != 0 and hint in out, out


def test_an_older_calibration_without_a_noise_model_falls_back_to_its_errors(rig) -> None:
    doc = yaml.safe_load(rig["cal"].read_text())
    del doc["noise_model"]
    old = rig["dir"] / "old.yaml"
    old.write_text(yaml.safe_dump(doc))
    code, out = _run("solve", rig["moved"], "--calib", old, "--json")
    dx = json.loads(out)["diagnosis"]
    assert code == 0 and dx["changed"] == "tracker" and "stored errors" in dx["noise_model"]


def test_too_few_poses_for_an_update_is_a_clear_error(rig) -> None:
    s = read_session(rig["moved"])
    two = rig["dir"] / "two-poses.jsonl"
    write_session(two, s.header, s.poses[:2])
    code, out = _run("solve", two, "--calib", rig["cal"], "--update", "z", "-o",
                     rig["dir"] / "x.yaml")
    assert code != 0 and "at least 3 usable poses" in out and "has 2" in out, out
    assert not (rig["dir"] / "x.yaml").exists()
