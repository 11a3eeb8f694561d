"""The daily check and the exports as a user runs them: `tmscal` in a child process on files.

One simulated rig is recorded twice (two sessions of the same truth): the calibration solved
on the first day is checked on the second (`solve --calib`), a calibration whose Z is off by
2 mm is caught, and the exports are written and read back."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from tmscal.calib import load
from tmscal.session import read_session, write_session


def tmscal(*args, ok=True):
    p = subprocess.run([sys.executable, "-m", "tmscal.cli", *map(str, args)],
                       capture_output=True, text=True, timeout=120)
    if ok:
        assert p.returncode == 0, p.stderr + p.stdout
    return p


@pytest.fixture(scope="module")
def days(tmp_path_factory):
    d = tmp_path_factory.mktemp("daily")
    tmscal("simulate", "-o", d / "all.jsonl", "--poses", 160, "--seed", 11)
    s = read_session(d / "all.jsonl")
    header = {k: v for k, v in s.header.items()}
    write_session(d / "day1.jsonl", header, s.poses[:80])
    write_session(d / "day2.jsonl", header, s.poses[80:])
    tmscal("solve", d / "day1.jsonl", "-o", d / "c.yaml")
    return d


def test_daily_check_on_a_new_session(days):
    stored = yaml.safe_load((days / "c.yaml").read_text())
    r = json.loads(tmscal("solve", days / "day2.jsonl", "--calib", days / "c.yaml",
                          "--json").stdout)
    assert r["same_session"] is False and r["session"]["n_poses"] == 80
    assert r["calibration"]["method"] == "qr36" and r["calibration"]["n_poses"] == 80
    # the day-2 hold-out error estimates what the day-1 cross-validation estimated
    # (same rig and noise; seeded, 80 poses each: within 40 %)
    assert r["errors"]["e_t_mm"] == pytest.approx(stored["errors"]["e_t_mm"], rel=0.4)
    # the simulated truth: the stored calibration places the coil within a tenth of a mm
    assert r["truth"]["coil_placement_mm"] < 0.1
    text = tmscal("solve", days / "day2.jsonl", "--calib", days / "c.yaml").stdout
    assert "no fitting" in text and "stored" in text and "WARNING" not in text
    same = tmscal("solve", days / "day1.jsonl", "--calib", days / "c.yaml").stdout
    assert "WARNING: this is the session the calibration was solved on" in same


def test_daily_check_catches_a_moved_tracker(days):
    doc = yaml.safe_load((days / "c.yaml").read_text())
    for M in (doc["Z"], doc["raw"]["Z"]):
        M[0][3] += 2.0  # the tracker moved 2 mm along the base x axis since the calibration
    (days / "moved.yaml").write_text(yaml.safe_dump(doc))
    r = json.loads(tmscal("solve", days / "day2.jsonl", "--calib", days / "moved.yaml",
                          "--json").stdout)
    for body in ("marker", "probe"):
        assert 1.5 < r["errors"][body]["trans_mm"] < 2.6
    assert 1.5 < r["truth"]["coil_placement_mm"] < 2.6


def test_daily_check_refuses_what_it_cannot_do(days):
    def one_line(p):
        assert p.returncode != 0
        lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("error:"), p.stderr
        return lines[0]

    msg = one_line(tmscal("solve", days / "day2.jsonl", "--calib", days / "c.yaml",
                          "--train", 20, ok=False))
    assert "--calib" in msg
    assert "nope.yaml" in one_line(tmscal("solve", days / "day2.jsonl", "--calib",
                                          days / "nope.yaml", ok=False))
    msg = one_line(tmscal("solve", days / "day2.jsonl", "--calib", days / "day1.jsonl",
                          ok=False))
    assert "day1.jsonl" in msg


def test_exports_written_by_the_command(days):
    for fmt, name in (("itk", "Z.tfm"), ("plus", "plus.xml"), ("easy-handeye", "eh.yaml"),
                      ("invesalius", "r.rbtf"), ("json", "c.json")):
        p = tmscal("export", days / "c.yaml", "--format", fmt, "-o", days / name)
        assert f"wrote {days / name}" in p.stdout and (days / name).stat().st_size > 0
    np.testing.assert_array_equal(load(days / "c.json").Z, load(days / "c.yaml").Z)
    again = tmscal("export", days / "c.yaml", "--format", "json", "-o", days / "c.json",
                   ok=False)
    assert again.returncode != 0 and "already exists" in again.stderr
