"""``tmscal selfcal simulate`` end to end: the command in a child process, its JSON and its
one-line usage errors (the simulation study of Joubair et al. 2016; docs/selfcal.md)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from ..rigs import REPO


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tmscal.cli", "selfcal", *args],
                          capture_output=True, text=True, cwd=REPO, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(REPO)})


def test_simulate_json_keys_and_calibration_helps():
    p = _run("simulate", "--json", "--pool", "400", "--k", "40", "--trials", "1",
             "--seed", "3")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert {"identifiable", "before", "after", "before_absorbed", "after_absorbed",
            "indices"} <= set(out)
    assert "floor" not in out
    assert all(isinstance(n, str) for n in out["identifiable"])
    assert "theta0_2" in out["identifiable"] and "a_2" not in out["identifiable"]
    for key in ("before", "after"):
        assert set(out[key]) == {"mean_mm", "max_mm", "sd_mm"}
    assert set(out["indices"]) == {"detmax", "O1", "O2", "O3", "O4", "O5", "random"}
    assert all(set(v["after"]) == {"mean_mm", "max_mm", "sd_mm"}
               for v in out["indices"].values())
    assert out["after_absorbed"]["mean_mm"] < out["before_absorbed"]["mean_mm"]


def test_simulate_medrue_json_and_the_table_prints():
    p = _run("simulate", "--json", "--arm", "medrue", "--pool", "300", "--k", "30",
             "--trials", "1", "--no-compare")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert set(out["after_absorbed"]) == {"mean_mm", "max_mm", "sd_mm"}
    assert out["settings"]["errors"] == "all" and "L11" in out["in_error"]
    assert out["after_absorbed"]["mean_mm"] < out["before_absorbed"]["mean_mm"]
    assert list(out["indices"]) == ["detmax"]
    p = _run("simulate", "--pool", "200", "--k", "20", "--trials", "1", "--no-compare")
    assert p.returncode == 0, p.stderr
    assert "before (nominal model)" in p.stdout and "after  (identified)" in p.stdout
    assert "after the hand/eye" in p.stdout


def test_simulate_usage_errors_are_one_line():
    p = _run("simulate", "--pool", "100", "--k", "100")
    assert p.returncode == 2
    assert p.stderr.startswith("error:") and "--k" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
    p = _run("simulate", "--arm", "kuka")
    assert p.returncode == 2 and "--arm" in p.stderr
    p = _run("simulate", "--force-noise", "nan")
    assert p.returncode == 2 and "--force-noise" in p.stderr
