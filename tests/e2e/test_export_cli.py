"""The daily check and the exports as a user runs them: `tmscal` in a child process on files.

One simulated rig is recorded twice (two sessions of the same truth): the calibration solved
on the first day is checked on the second (`solve --calib`), a calibration whose Z is off by
2 mm is caught. A session acquired on the mock rig (`tmscal demo`) is solved and exported:
the PLUS device set names the rig config's tool ROMs."""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from urllib.parse import urlparse

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.exports import load_calibration
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
    r = CliRunner().invoke(main, ["simulate", "-o", str(d / "all.jsonl"), "--poses", "160",
                                  "--seed", "11"])
    assert r.exit_code == 0, r.output
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


def test_exports_of_a_session_acquired_on_the_mock_rig(tmp_path, mock_config):
    """`tmscal demo` acquires through the real drivers and wire protocols; the calibration
    solved on it records the rig config, so the PLUS export names the config's tool ROMs."""
    cfg_path = mock_config("mock-ur-polaris.yaml")  # the demo rig, mocks on our own addresses
    tmscal("demo", "--config", cfg_path, "--poses", 6, "-o", tmp_path / "s.jsonl")
    tmscal("solve", tmp_path / "s.jsonl", "-o", tmp_path / "c.yaml", "--folds", 2)
    cfg = yaml.safe_load(cfg_path.read_text())
    p = tmscal("export", tmp_path / "c.yaml", "--format", "plus", "-o", tmp_path / "plus.xml")
    assert f"wrote {tmp_path / 'plus.xml'}" in p.stdout and "CHECK" not in p.stdout
    dev = ET.parse(tmp_path / "plus.xml").getroot().find("./DataCollection/Device")
    roms = {s.get("Id"): s.get("RomFile") for s in dev.findall("./DataSources/DataSource")}
    assert roms == {"CoilMarker": cfg["tracker"]["tools"]["marker"],
                    "Probe": cfg["tracker"]["tools"]["probe"]}
    # the config's network Polaris (socket://HOST:PORT), a loopback address of the test's own
    assert dev.get("NetworkHostname") == urlparse(cfg["tracker"]["port"]).hostname
    Z = ET.parse(tmp_path / "plus.xml").getroot().find(
        "./CoordinateDefinitions/Transform[@From='Tracker']").get("Matrix")
    np.testing.assert_array_equal(np.reshape([float(v) for v in Z.split()], (4, 4)),
                                  load_calibration(tmp_path / "c.yaml").Z)
