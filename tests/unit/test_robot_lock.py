"""One tmscal process per robot (tmscal.drivers.robot_lock, taken in Robot.open): a second
opener of the same robot address, in this process or another, is refused before anything is
sent, naming the address and the holder's pid; close releases it, and so does the end of the
holder's process (kill -9 included). DensoRobot against the DENSO mock over real sockets."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tmscal.drivers.denso.robot import DensoRobot
from tmscal.drivers.robot_lock import LOCK_DIR_ENV, RobotLock, lock_dir, normalise_address
from tmscal.errors import DeviceError, SafetyError
from tmscal.mocks.clock import FAST
from tmscal.mocks.denso import DensoMock
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def mock() -> Iterator[DensoMock]:
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)
    with DensoMock(rig, clock=FAST) as m:
        m.start()
        yield m


def test_second_robot_on_the_same_address_is_refused_before_connecting(mock: DensoMock
                                                                        ) -> None:
    with DensoRobot(port=mock.port, watchdog_ms=None):
        before = mock.stats["connections"]
        second = DensoRobot(port=mock.port, watchdog_ms=None)
        with pytest.raises(SafetyError) as ei:
            second.open()
        msg = str(ei.value)
        assert f"127.0.0.1:{mock.port}" in msg and f"pid {os.getpid()}" in msg
        assert "in use by another tmscal" in msg
        assert mock.stats["connections"] == before      # nothing reached the controller
        assert not second.is_open
    # closed: the same robot opens again, in sequence, as often as wanted
    for _ in range(2):
        with DensoRobot(port=mock.port, watchdog_ms=None) as robot:
            assert robot.is_open
    # no lock file left behind (a holder killed with SIGKILL leaves one, unlocked)
    assert not (lock_dir() / RobotLock("denso", f"127.0.0.1:{mock.port}").name).exists()


def test_other_addresses_do_not_conflict(mock: DensoMock) -> None:
    rig2 = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)
    with DensoMock(rig2, clock=FAST) as m2:
        m2.start()
        with DensoRobot(port=mock.port, watchdog_ms=None), \
                DensoRobot(port=m2.port, watchdog_ms=None) as r2:
            assert r2.is_open


def test_failed_open_releases_the_lock(mock: DensoMock) -> None:
    bad = DensoRobot(port=mock.port, robot_name="Arm", provider="NoSuchProvider")
    with pytest.raises(DeviceError):
        bad.open()
    with DensoRobot(port=mock.port, watchdog_ms=None) as robot:
        assert robot.is_open


_HOLDER = """
import sys, time
from tmscal.drivers.denso.robot import DensoRobot
robot = DensoRobot(port=int(sys.argv[1]), watchdog_ms=None).open()
print("open", flush=True)
time.sleep(600)
"""


def test_lock_is_per_process_and_dies_with_its_holder(mock: DensoMock) -> None:
    """Another process holds the robot: the open here is refused naming that process's pid;
    once it is killed (SIGKILL: no close, no cleanup) the robot opens here."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    assert env.get(LOCK_DIR_ENV)        # the child shares this session's lock directory
    child = subprocess.Popen([sys.executable, "-c", _HOLDER, str(mock.port)], cwd=ROOT,
                             env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None
        assert child.stdout.readline().strip() == "open"
        robot = DensoRobot(port=mock.port, watchdog_ms=None)
        with pytest.raises(SafetyError, match=f"pid {child.pid}\\b"):
            robot.open()
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(30)
        child.stdout.close()
    with robot:
        assert robot.is_open


def test_lock_names_and_addresses() -> None:
    assert normalise_address(" LOCALHOST ") == "localhost"
    assert normalise_address("0:0:0:0:0:0:0:1") == "::1"
    assert normalise_address("[0:0::1]:5007") == "[::1]:5007"
    assert normalise_address("127.0.0.1:5007") == "127.0.0.1:5007"
    # the same address written two ways is one lock; another driver or address is another
    a, b = RobotLock("ur", "127.0.0.2"), RobotLock("ur", " 127.0.0.2")
    assert a.name == b.name
    assert RobotLock("denso", "127.0.0.2").name != a.name
    assert RobotLock("ur", "127.0.0.20").name != a.name
    a.acquire()
    try:
        with pytest.raises(SafetyError, match="127.0.0.2"):
            b.acquire()
        a.acquire()          # idempotent for its holder
    finally:
        a.release()
        a.release()          # safe twice
    b.acquire().release()


def test_lock_directory_of_another_user_or_not_a_directory_is_refused(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    not_dir = tmp_path / "file"
    not_dir.write_text("x")
    monkeypatch.setenv(LOCK_DIR_ENV, str(not_dir))
    with pytest.raises(SafetyError, match=LOCK_DIR_ENV):
        RobotLock("ur", "127.0.0.2").acquire()
    link = tmp_path / "link"
    link.symlink_to(tmp_path)
    monkeypatch.setenv(LOCK_DIR_ENV, str(link))
    with pytest.raises(SafetyError, match="not a directory of this user"):
        RobotLock("ur", "127.0.0.2").acquire()
