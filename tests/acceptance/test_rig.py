"""The rig acceptance suite (``docs/acceptance.md``): the driver contract of
``tmscal.drivers.base`` on the devices of ``--rig CONFIG``, real or mock, in this order:
connect and identity, tool visibility and frame rate, a small move and back, stop while
moving, reconnect. The checks live in ``tmscal.acquisition.selftest`` (``tmscal selftest``
runs the same ones); each test here runs one, keeps it for the report, and passes, fails or
skips as it says. Without ``--rig`` every test is skipped with the reason."""

from __future__ import annotations

from tmscal.acquisition.selftest import (
    check_connect,
    check_reconnect,
    check_small_move,
    check_stop,
    check_tools,
)

from .conftest import RigUnderTest


def test_connect_and_identity(rig: RigUnderTest) -> None:
    c = rig.run(check_connect, rig.tracker, rig.robot)
    rig.verdict(c)


def test_tool_visibility_and_frame_rate(rig: RigUnderTest) -> None:
    tracker = rig.need("tracker")
    rig.verdict(rig.run(check_tools, tracker, rig.cfg.sampling.min_share, rig.settings))


def test_small_move_inside_envelope_and_back(rig: RigUnderTest) -> None:
    robot = rig.need("robot")
    rig.verdict(rig.run(check_small_move, robot, rig.cfg, rig.settings))


def test_stop_while_moving(rig: RigUnderTest) -> None:
    robot = rig.need("robot")
    rig.verdict(rig.run(check_stop, robot, rig.cfg, rig.settings))


def test_reconnect_keeps_identity(rig: RigUnderTest) -> None:
    rig.need("tracker" if rig.tracker is not None else "robot")
    rig.verdict(rig.run(check_reconnect, rig.tracker, rig.robot, rig.settings))
