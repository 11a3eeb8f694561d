"""The rig acceptance suite (``docs/acceptance.md``): the driver contract of
``tmscal.drivers.base`` on the devices of ``--rig CONFIG``, real or mock, in this order:
connect and identity, tool visibility and frame rate, a small move and back, stop while
moving, reconnect. The checks and their order live in the package
(``tmscal.acceptance.checks`` and ``tmscal.acceptance.rig``; ``tmscal selftest --rig CONFIG`` runs
the same ones from an installed tmscal); each test here runs one, keeps it for the report, and
passes, fails or skips as it says. Without ``--rig`` every test is skipped with the reason."""

from __future__ import annotations

from .conftest import RigUnderTest


def test_connect_and_identity(rig: RigUnderTest) -> None:
    rig.check("connect")


def test_tool_visibility_and_frame_rate(rig: RigUnderTest) -> None:
    rig.check("tools")


def test_small_move_inside_envelope_and_back(rig: RigUnderTest) -> None:
    rig.check("move")


def test_stop_while_moving(rig: RigUnderTest) -> None:
    rig.check("stop")


def test_reconnect_keeps_identity(rig: RigUnderTest) -> None:
    rig.check("reconnect")
