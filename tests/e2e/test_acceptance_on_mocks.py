"""The rig acceptance suite (``tests/acceptance``, ``docs/acceptance.md``) run as a lab runs
it, ``python -m pytest tests/acceptance --rig CONFIG --rig-report PATH`` in a child process,
against the mock rigs the suite starts from a config's ``mock:`` section (real sockets, the
real drivers and client libraries). The real-time runs take a few seconds each."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tmscal.acceptance.checks import CHECK_NAMES

from ..rigs import REPO

pytestmark = pytest.mark.e2e


def run_suite(cwd: Path, *args: str) -> tuple[int, str]:
    """``python -m pytest tests/acceptance ARGS`` from ``cwd``; (exit code, stdout+stderr)."""
    cmd = [sys.executable, "-m", "pytest", str(REPO / "tests" / "acceptance"), "-q", "-ra",
           "-p", "no:cacheprovider", *args]
    p = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=240,
                       stdin=subprocess.DEVNULL)
    return p.returncode, p.stdout + p.stderr


def check_report(text: str, cfg: Path, robot: str, verdicts: dict[str, str],
                 tracker: str = "ndi") -> None:
    """The report names the config, both identities and every check with its verdict."""
    assert f"config: {cfg}" in text and "date: " in text
    assert f"driver: {robot}" in text and f"driver: {tracker}" in text
    for key, title in CHECK_NAMES.items():
        assert f"[{verdicts.get(key, 'PASS')}] {title}" in text, (key, text)
    assert "frame_rate_hz: " in text and "configured_rate_hz: 60.0" in text


@pytest.mark.parametrize("base, robot", [
    pytest.param("mock-denso-polaris.yaml", {"port": 0}, id="denso"),
    pytest.param("mock-ur-polaris.yaml", {}, id="ur"),
])
def test_suite_passes_on_real_time_mock_rig(tmp_path, mock_config, base, robot):
    cfg = mock_config(base, robot=robot, mock={"clock": "real"}, sampling={"settle_s": 0.2})
    report = tmp_path / "report.txt"
    # the rate is a benchmark's figure (benchmarks/tracker.py), not this test's: a loaded
    # machine delays the host's reads of the real-time tracker, so the check's tolerance is
    # opened to 90 % (only a clock or frame counter off by a factor of ten fails it)
    rc, out = run_suite(tmp_path, "--rig", str(cfg), "--rig-report", str(report),
                        "--rig-rate-tolerance", "0.9")
    assert rc == 0 and re.search(r"^5 passed in ", out, re.M), out
    text = report.read_text()
    assert "result: PASS (5 passed, 0 failed, 0 skipped)" in text
    check_report(text, cfg, "denso" if "denso" in base else "ur", {})
    assert "rate_error: " in text  # asserted in real time, so its measure is reported
    assert "rig acceptance report" in out and f"report written to {report}" in out


@pytest.mark.parametrize("base, robot, tracker", [
    pytest.param("mock-denso-polaris.yaml", "denso", "ndi", id="denso"),
    pytest.param("mock-ur-igtl.yaml", "ur", "igtl", id="ur-igtl"),
])
def test_fast_clock_skips_only_the_stop_check(tmp_path, mock_config, base, robot, tracker):
    # every mock on an address of the test's own (tests.rigs.unique_addresses)
    cfg = mock_config(base) if tracker == "igtl" else mock_config(base, robot={"port": 0})
    report = tmp_path / "report.txt"
    rc, out = run_suite(tmp_path, "--rig", str(cfg), "--rig-report", str(report))
    assert rc == 0 and re.search(r"^4 passed, 1 skipped in ", out, re.M), out
    assert "the mock's fast clock completes a move at once" in out
    text = report.read_text()
    check_report(text, cfg, robot, {"stop": "SKIP"}, tracker)
    assert "rate_error: " not in text  # the fast clock's rate is reported, never judged


def test_a_failing_device_fails_its_check_and_the_report_says_so(tmp_path, mock_config):
    cfg = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                      mock={"robot": {"faults": {"fail_move_at": 1}}})
    report = tmp_path / "report.txt"
    rc, out = run_suite(tmp_path, "--rig", str(cfg), "--rig-report", str(report))
    assert rc == 1 and "1 failed" in out, out
    text = report.read_text()
    assert "result: FAIL (3 passed, 1 failed, 1 skipped)" in text
    check_report(text, cfg, "denso", {"move": "FAIL", "stop": "SKIP"})
    assert "RobotFault" in text and "Robot_Move failed" in text


def test_without_rig_every_test_skips_with_the_reason_and_no_report(tmp_path):
    rc, out = run_suite(tmp_path)
    assert rc == 0 and "5 skipped" in out, out
    assert out.count("no --rig CONFIG given: ") == 5
    assert list(tmp_path.iterdir()) == []


def test_default_report_name_never_overwrites(tmp_path, mock_config):
    cfg = mock_config("mock-polaris.yaml")
    for _ in range(2):
        rc, out = run_suite(tmp_path, "--rig", str(cfg))
        assert rc == 0, out
    names = sorted((p.name for p in tmp_path.glob("acceptance-report-*.txt")), key=len)
    assert len(names) == 2, names  # the second run did not overwrite the first report
    if names[0][:28] == names[1][:28]:  # the same date (the runs did not straddle midnight)
        assert names[1] == names[0][:-4] + "-2.txt", names
    for n in names:
        assert "[PASS] tool visibility and frame rate" in (tmp_path / n).read_text()


def run_selftest(cwd: Path, *args: str) -> tuple[int, str]:
    """``tmscal selftest ARGS`` from ``cwd`` (the installed command, no pytest, no tests/);
    (exit code, stdout+stderr)."""
    p = subprocess.run([sys.executable, "-m", "tmscal.cli", "selftest", *args], cwd=cwd,
                       capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL)
    return p.returncode, p.stdout + p.stderr


def test_tmscal_selftest_runs_the_same_checks_and_report(tmp_path, mock_config):
    cfg = mock_config("mock-denso-polaris.yaml", robot={"port": 0})
    rc, out = run_selftest(tmp_path, "--rig", str(cfg), "--report", "rig.txt")
    assert rc == 0, out
    for key, title in CHECK_NAMES.items():
        assert f"{'SKIP' if key == 'stop' else 'PASS'}  {title}" in out, (title, out)
    assert "result: PASS (4 passed, 0 failed, 1 skipped)" in out
    assert "report written to rig.txt" in out
    check_report((tmp_path / "rig.txt").read_text(), cfg, "denso", {"stop": "SKIP"})
    rc, out = run_selftest(tmp_path, "--rig", str(cfg), "--report", "rig.txt")
    assert rc == 2 and "rig.txt already exists" in out  # the one rule for output files
    rc, out = run_selftest(tmp_path, "--rig", str(cfg))  # the default name, as pytest's
    assert rc == 0 and list(tmp_path.glob("acceptance-report-*.txt")), out


def test_tmscal_selftest_failing_check_exits_3_and_the_report_says_so(tmp_path, mock_config):
    cfg = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                      mock={"robot": {"faults": {"fail_move_at": 1}}})
    rc, out = run_selftest(tmp_path, "--rig", str(cfg), "--report", "rig.txt")
    assert rc == 3, out
    assert "FAIL  small move inside the envelope and back: RobotFault" in out
    text = (tmp_path / "rig.txt").read_text()
    assert "result: FAIL (3 passed, 1 failed, 1 skipped)" in text
    check_report(text, cfg, "denso", {"move": "FAIL", "stop": "SKIP"})


def test_tmscal_selftest_without_a_robot_skips_its_checks_naming_why(tmp_path, mock_config):
    cfg = mock_config("mock-polaris.yaml")
    rc, out = run_selftest(tmp_path, "--rig", str(cfg), "--report", "rig.txt")
    assert rc == 0, out
    assert f"SKIP  small move inside the envelope and back: {cfg} has no robot section" in out
    text = (tmp_path / "rig.txt").read_text()
    assert "[PASS] tool visibility and frame rate" in text and "[SKIP] stop while moving" in text
